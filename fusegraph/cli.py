"""``fusegraph`` command line: a thin layer over the library (every command calls one library function)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from . import __version__

EPILOG = """examples:
  fusegraph simulate head --seed 0 --out sessions/head0        write a session directory
  fusegraph run sessions/head0 --solver online --out est.csv   estimate (metrics if truth is known)
  fusegraph report head --seeds 0-9 --plot out/head.png        the paper's Table 1, ours beside it
  fusegraph bench head --duration 600 --repeat 3               speed on a 10-minute session
  fusegraph view sessions/head0 --out out/head0                3D scene, plots, TUM files
"""


def parse_seeds(text: str) -> list[int]:
    """``0-9`` or ``0,3,5`` or ``0-4,8`` -> list of seeds."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if "-" in part[1:]:
            lo, hi = part.split("-", 1) if not part.startswith("-") else (part, part)
            seeds.extend(range(int(lo), int(hi) + 1))
        else:
            seeds.append(int(part))
    if not seeds:
        raise argparse.ArgumentTypeError(f"no seeds in {text!r} (use e.g. 0-9 or 0,2,5)")
    return seeds


def _seeds_arg(text: str) -> list[int]:
    try:
        return parse_seeds(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad seed list {text!r} (use e.g. 0-9 or 0,2,5)") from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fusegraph",
        description="Factor-graph smoothing for human motion: every sensor a factor in one GTSAM graph; "
        "iSAM2 online, batch smoothing offline, and the papers' EKFs beside them.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"fusegraph {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    sim = sub.add_parser("simulate", help="write a simulated session directory (session.toml + CSVs + truth)",
                         description="Simulate a scenario and write it as a session directory you can read and edit.")
    sim.add_argument("scenario", choices=["head", "attitude9", "gaze", "bicycle", "walking"], help="which system to simulate")
    sim.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    sim.add_argument("--out", type=Path, required=True, help="directory to write (created)")
    sim.add_argument("--profile", choices=["ideal", "realistic", "noise_free"], default="realistic",
                     help="sensor error profile (default realistic); head: ideal or realistic; attitude9: realistic or noise_free")
    sim.add_argument("--duration", type=float, default=None, help="seconds of data (default: head, attitude9 10; gaze, bicycle 40; walking: its tour)")
    sim.add_argument("--latency-true", type=float, metavar="S", help="true tracker latency, seconds (default 0.1)")
    sim.add_argument("--latency-assumed", type=float, metavar="S",
                     help="write stamps made with this assumed latency and declare it unknown (latency_sigma_s), so solvers estimate it")

    run = sub.add_parser("run", help="estimate a session with one solver; metrics when it has truth",
                         description="Run one solver over a session directory and write the estimate as CSV "
                         "(t, quaternion, azimuth/elevation/roll in degrees, covariance; gaze sessions: t, wall point X, Z). "
                         "The session's system (session.toml) picks the graph: head, attitude9, gaze, bicycle, walking.",
                         epilog="examples:\n  fusegraph simulate gaze --out sessions/gaze0 && fusegraph run sessions/gaze0 --solver batch\n"
                         "  fusegraph simulate bicycle --seed 1 --out sessions/bike1 && fusegraph run sessions/bike1 --solver ekf --plot bike.png",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("session", type=Path, help="session directory (with session.toml)")
    run.add_argument("--solver", choices=["online", "batch", "ekf", "vqf", "vqf_offline", "no_removal", "dead_reckoning"], default="online",
                     help="online = iSAM2 causal estimate at every gyro sample; batch = smoother over the whole session; ekf = the paper's "
                     "EKF (head: Method II; attitude9: the 9-axis EKF; gaze: (yaw, pitch, roll, GX, GZ); bicycle: frame EKF -> subtract -> "
                     "thigh EKF; walking: the paper's Kalman framework); vqf, vqf_offline = the peer (attitude9 only); no_removal = the "
                     "thigh EKF alone (bicycle only); dead_reckoning = steps and rides only (walking only)")
    run.add_argument("--out", type=Path, help="CSV to write (default: <session>/estimate_<solver>.csv)")
    run.add_argument("--plot", type=Path, help="also write a PNG of the estimate (against the truth if known)")
    run.add_argument("--json", action="store_true", help="print the metrics as JSON")

    rep = sub.add_parser("report", help="the paper's comparison table over seeds (accuracy, time, NEES)",
                         description="head: simulate each seed, run every method, print RMS per axis (1e-2 rad), ratio to Method II, "
                         "processing time per 40 ms of data and NEES.\n"
                         "gaze: a subject 1 m from a wall fixates a mark while nodding and shaking the head, then a second mark; "
                         "the gaze point on the wall (X, Z RMS in mm) from the paper's EKF (yaw, pitch, roll, GX, GZ), fusegraph online "
                         "and batch, and speed (x real time).\n"
                         "bicycle: a cyclist's thigh and the bicycle frame, two 9-axis IMUs, downhill with hard braking at 30 s (and on an "
                         "indoor trainer): thigh pitch/roll RMS in the braking phase for the thigh alone (no_removal), the paper's pipeline "
                         "(frame EKF -> subtract -> thigh EKF), fusegraph online and batch (both bodies in one graph).",
                         epilog="examples:\n  fusegraph report head --seeds 0-9 --plot head.png\n  fusegraph report gaze --seeds 0-4 --json\n"
                         "  fusegraph report gaze --plot gaze.png\n  fusegraph report bicycle --seeds 0-2 --json --plot bicycle.png",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    rep.add_argument("system", choices=["head", "gaze", "bicycle"])
    rep.add_argument("--seeds", type=_seeds_arg, default=list(range(10)), help="seeds, e.g. 0-9 (default; gaze, bicycle: 0-2) or 0,3,7")
    rep.add_argument("--profile", choices=["ideal", "realistic"], default="realistic", help="sensor error profile (default realistic)")
    rep.add_argument("--duration", type=float, default=10.0, help="seconds per session (default 10, like the paper)")
    rep.add_argument("--latency-true", type=float, metavar="S", help="true tracker latency in seconds (default: the scenario's 0.1)")
    rep.add_argument("--latency-assumed", type=float, metavar="S",
                     help="latency the user believes; adds rows method2_wrong_d (Method II with it) and isam2_td/batch_td "
                     "(fusegraph estimating the latency from it as a prior); method2/isam2/batch get the true one")
    rep.add_argument("--json", action="store_true", help="print JSON instead of the table")
    rep.add_argument("--plot", type=Path, help="write a figure like the paper's Fig. 3/4 (first seed) to this PNG")

    vw = sub.add_parser("view", help="files to look at: 3D scene (PLY/GLB/PNG), 2D plots, TUM and CSV trajectories",
                        description="Given a session directory (the solver runs first) or an estimate CSV, write a 3D scene "
                        "(open3d: PLY, GLB and a headless PNG render), a 2D plot against the truth with 3-sigma bands, and the "
                        "trajectories as CSV and TUM files (readable by evo).")
    vw.add_argument("source", type=Path, help="session directory or estimate CSV (from fusegraph run)")
    vw.add_argument("--out", type=Path, required=True, help="directory for the files (created)")
    vw.add_argument("--solver", choices=["online", "batch", "ekf"], default="batch", help="solver for a bare session (default batch)")
    vw.add_argument("--truth", type=Path, help="truth for an estimate CSV: a TUM file or a session directory")

    abl = sub.add_parser("ablate", help="ablation study: sensors dropped x parameter grid x seeds x solvers, local or on Dask",
                         description="Run a study: the full-sensor baseline plus one variant per --drop, crossed with every --vary grid, "
                         "for every seed and solver. Results go to OUT/runs.csv (one row per run; re-running skips finished runs), "
                         "OUT/summary.csv and OUT/summary.png (mean and 95% interval per variant).",
                         epilog="example: fusegraph ablate head --drop tracker --drop gyro --vary latency=0,0.05,0.1,0.2 --seeds 0-19 --out studies/head")
    abl.add_argument("system", choices=["head"])
    abl.add_argument("--study", type=Path, help="a TOML file with a [study] table (see examples/); flags below add to it")
    abl.add_argument("--drop", action="append", default=[], metavar="SENSOR[+SENSOR]", help="a variant without these sensors (repeatable)")
    abl.add_argument("--vary", action="append", default=[], metavar="NAME=V1,V2,...", help="a parameter grid (repeatable; crossed)")
    abl.add_argument("--seeds", type=_seeds_arg, help="seeds, e.g. 0-19 (default 0-4)")
    abl.add_argument("--solver", default=None, help="comma list of ekf,online,batch (default all)")
    abl.add_argument("--duration", type=float, default=None, help="seconds per session (default 10)")
    abl.add_argument("--profile", choices=["ideal", "realistic"], default=None)
    abl.add_argument("--workers", type=int, default=None, help="parallel workers (default: all cores)")
    abl.add_argument("--scheduler", default=None, help="'local' starts a Dask LocalCluster; tcp://host:port uses an existing one")
    abl.add_argument("--out", type=Path, required=True, help="study directory (created; reused to resume)")

    ben = sub.add_parser("bench", help="head: speed on a long session; broad: every BROAD trial, every method, side by side",
                         description="head: real-time factor of the whole causal loop in the first and last minute, batch time, peak memory.\n"
                         "broad: every trial in DIR through VQF online/offline, the papers' 9-axis EKF, fusegraph online and batch, in one run: "
                         "total/heading/inclination RMSE (deg, the benchmark's metric) and speed (x real time) per trial and mean.\n"
                         "ultrasonic: simulated transmitters with unknown association (N = 3, 6, 12, several seeds), fusegraph and the paper's "
                         "combinatorial search and the true-position oracle: association accuracy, position RMSE, track loss, time per epoch; "
                         "crossings; and the recorded UWB run with and without tag labels.\n"
                         "walking: the simulated 3-floor walk through the PDR front end (activity confusion per walking cycle / ride), "
                         "dead reckoning vs EKF vs iSAM2 online vs batch with 20% wrong image fixes and with none; step counts on the "
                         "Oxford phone recordings; the Plaza range + odometry runs (odometry only, online, batch).",
                         epilog="examples:\n  fusegraph bench head --duration 600\n  fusegraph bench broad ../shared/data/broad --json > broad.json\n"
                         "  fusegraph bench broad --trials 01,32 --methods vqf,online --plot broad.png\n"
                         "  fusegraph bench ultrasonic --transmitters 3,12 --seeds 0-4 --json\n  fusegraph bench ultrasonic --plot tags.png\n"
                         "  fusegraph bench walking --plot walk.png\n  fusegraph bench walking --oxford ../shared/data/steps_oxford --json",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    ben.add_argument("system", choices=["head", "broad", "ultrasonic", "walking"])
    ben.add_argument("directory", nargs="?", type=Path, help="broad: directory of BROAD trials (*.mat; default ../shared/data/broad)")
    ben.add_argument("--duration", type=float, default=600.0, help="head: seconds of data (default 600); ultrasonic: seconds per run (default 20)")
    ben.add_argument("--repeat", type=int, default=3, help="head: repeats; the median is printed (default 3)")
    ben.add_argument("--profile", choices=["ideal", "realistic"], default="realistic", help="head: sensor error profile")
    ben.add_argument("--methods", default=None, help="broad: comma list of vqf,vqf_offline,ekf,online,batch (default all)")
    ben.add_argument("--trials", default=None, help="broad: comma list of file-name prefixes, e.g. 01,32 (default all)")
    ben.add_argument("--plot", type=Path, help="broad: also write a PNG of the errors per trial and method; walking: the trajectories; "
                     "ultrasonic: the tracks, errors and rest probability of the largest N, first seed")
    ben.add_argument("--seeds", type=_seeds_arg, default=None, help="ultrasonic: seeds per N (default 0-2); walking: the first is the walk's seed (default 0)")
    ben.add_argument("--transmitters", default="3,6,12", help="ultrasonic: comma list of N (default 3,6,12)")
    ben.add_argument("--uwb", default="default", metavar="DIR", help="ultrasonic: the recorded UWB run (default ../shared/data/uwb_lias; 'none' skips it)")
    ben.add_argument("--oxford", default="default", metavar="DIR", help="walking: Oxford step recordings (default ../shared/data/steps_oxford; 'none' skips)")
    ben.add_argument("--no-plaza", action="store_true", help="walking: skip the Plaza runs")
    ben.add_argument("--json", action="store_true", help="print JSON")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(COMMANDS[args.command](args) or 0)
    except Exception as exc:  # user-facing: one clear line, not a traceback
        from .session import SessionError

        if isinstance(exc, SessionError | FileNotFoundError | ValueError):
            print(f"fusegraph {args.command}: error: {exc}", file=sys.stderr)
            return 2
        raise


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .scenarios import SCENARIOS
    from .session import save_session

    extra: dict[str, Any] = {}
    if args.latency_true is not None:
        extra["tracker_latency_s"] = args.latency_true
    if args.latency_assumed is not None:
        extra["tracker_latency_assumed_s"] = args.latency_assumed
    if (args.scenario, args.profile) in (("head", "noise_free"), ("attitude9", "ideal")):
        raise ValueError(f"--profile {args.profile} does not apply to {args.scenario} (head: ideal, realistic; attitude9: realistic, noise_free)")
    if args.scenario != "head" and extra:
        raise ValueError("--latency-true/--latency-assumed apply to the head scenario only")
    duration = args.duration if args.duration is not None else (10.0 if args.scenario in ("head", "attitude9") else None)
    session = SCENARIOS[args.scenario](args.seed, profile=args.profile, duration_s=duration, **extra)
    path = save_session(session, args.out)
    files = ", ".join(sorted(p.name for p in path.iterdir()))
    print(f"wrote {path}/ ({files})")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .metrics import score_attitude
    from .session import load_session
    from .systems import head

    session = load_session(args.session)
    if session.system == "attitude9":
        return _run_attitude9(args, session)
    if session.system in ("gaze", "bicycle"):
        return _run_coupled(args, session)
    if session.system == "walking":
        return _run_walking(args, session)
    if session.system != "head":
        raise ValueError(f"{args.session}/session.toml: system '{session.system}' has no solver yet (available: head, attitude9, gaze, bicycle)")
    if args.solver not in ("online", "batch", "ekf"):
        raise ValueError(f"--solver {args.solver} is for attitude9 sessions; head has online, batch, ekf")
    method = {"online": "isam2", "batch": "batch", "ekf": "method2"}[args.solver]
    estimate = head.run_method(session, method)
    out = args.out or args.session / f"estimate_{args.solver}.csv"
    estimate.save_csv(out)
    print(f"wrote {out} ({len(estimate.t)} rows, {session.duration_s:.1f} s of data in {estimate.runtime_s:.2f} s)")
    if estimate.extras.get("latency_s") is not None:
        sigma = estimate.extras.get("latency_sigma_s")
        print(f"tracker latency estimated: {1000 * estimate.extras['latency_s']:.1f} ms" + (f" (sigma {1000 * sigma:.1f} ms)" if sigma else ""))
    if session.truth is not None:
        score = score_attitude(estimate, session.truth.t, session.truth.values) if _same_times(estimate, session) else None
        if score is not None:
            if args.json:
                print(json.dumps({"method": method, **score.as_dict()}, indent=2))
            else:
                rms = score.rms_rad * 100
                nees = f", NEES {score.nees:.2f}" if score.nees is not None else ""
                print(f"RMS after 1 s [1e-2 rad]: azimuth {rms[0]:.3f}, elevation {rms[1]:.3f}, roll {rms[2]:.3f}{nees}")
    if args.plot:
        print(f"wrote {_plot_estimate(args, session, estimate)}")
    return 0


def _run_attitude9(args: argparse.Namespace, session: Any) -> int:
    import numpy as np

    from .datasets.broad import broad_errors
    from .systems import attitude9

    estimate = attitude9.METHODS[args.solver](session)
    out = args.out or args.session / f"estimate_{args.solver}.csv"
    estimate.save_csv(out)
    print(f"wrote {out} ({len(estimate.t)} rows, {session.duration_s:.1f} s of data in {estimate.runtime_s:.2f} s)")
    if session.truth is not None and _same_times(estimate, session):
        movement = session.stream("movement").values[:, 0] if "movement" in session.streams else np.ones(len(estimate.t))
        errors = broad_errors(estimate.quat_wxyz, session.truth.values, movement)
        if args.json:
            print(json.dumps({"method": args.solver, "total": errors.total, "heading": errors.heading, "inclination": errors.inclination}, indent=2))
        else:
            print(f"RMSE [deg]: total {errors.total:.3f}, heading {errors.heading:.3f}, inclination {errors.inclination:.3f}")
    if args.plot:
        print(f"wrote {_plot_estimate(args, session, estimate)}")
    return 0


def _run_coupled(args: argparse.Namespace, session: Any) -> int:
    """Gaze (wall point per tracker sample) and bicycle (thigh attitude per sample) sessions."""
    import time as _time

    import numpy as np

    from .estimate import Estimate
    from .systems import bicycle, gaze

    if session.system == "gaze":
        solvers = {"online": "online", "batch": "batch", "ekf": "ekf"}
        if args.solver not in solvers:
            raise ValueError(f"--solver {args.solver}: gaze sessions have online, batch, ekf")
        data = gaze.from_session(session)
        point, seconds = gaze.RUNNERS[args.solver](data)  # type: ignore[operator]
        out = args.out or args.session / f"gaze_{args.solver}.csv"
        np.savetxt(out, np.column_stack([data.tracker_t, point]), delimiter=",", header="t,X_m,Z_m", comments="", fmt="%.10g")
        print(f"wrote {out} ({len(point)} rows: the gaze point on the wall, X = world y, Z = world z; {session.duration_s:.1f} s of data in {seconds:.2f} s)")
        if np.isfinite(data.truth_gaze_xz_m).any():
            rms = gaze.rms_mm(point, data)
            print(json.dumps({"method": args.solver, "rms": rms}, indent=2) if args.json else f"RMS after 1 s [mm]: X {rms['x_mm']:.1f}, Z {rms['z_mm']:.1f}")
        return 0
    solvers = {"online": "online", "batch": "batch", "ekf": "paper_pipeline", "no_removal": "no_removal"}
    if args.solver not in solvers:
        raise ValueError(f"--solver {args.solver}: bicycle sessions have online, batch, ekf (the paper's pipeline), no_removal")
    ride = bicycle.from_session(session)
    start = _time.perf_counter()
    quat = bicycle.RUNNERS[solvers[args.solver]](ride)  # type: ignore[operator]
    estimate = Estimate(solvers[args.solver], ride.t.copy(), quat, None, _time.perf_counter() - start)
    out = args.out or args.session / f"estimate_{args.solver}.csv"
    estimate.save_csv(out)
    print(f"wrote {out} ({len(estimate.t)} rows: the thigh attitude, {session.duration_s:.1f} s of data in {estimate.runtime_s:.2f} s)")
    if np.isfinite(ride.thigh_quat_wxyz).all() and np.isfinite(ride.config.brake_s):
        rms = bicycle.braking_rms_deg(quat, ride)
        print(json.dumps({"method": args.solver, "rms": rms}, indent=2) if args.json else
              f"braking phase ({ride.config.brake_s:.1f}-{ride.config.brake_s + 5:.1f} s) RMS [deg]: pitch {rms['pitch_deg']:.2f}, roll {rms['roll_deg']:.2f}")
    if args.plot:
        print(f"wrote {_plot_estimate(args, session, estimate)}")
    return 0


def _run_walking(args: argparse.Namespace, session: Any) -> int:
    """A walking session: the PDR front end, then dead reckoning, the EKF, iSAM2 online or batch."""
    import numpy as np

    from .systems import walking

    solvers = {"online": "online", "batch": "batch", "ekf": "ekf", "dead_reckoning": "dead_reckoning"}
    if args.solver not in solvers:
        raise ValueError(f"--solver {args.solver}: walking sessions have online, batch, ekf, dead_reckoning")
    walk, speed = walking.from_session(session)
    cycles, rides, events = walking.analyse(walk, speed)
    runs = {"online": walking.run_online, "batch": walking.run_batch, "ekf": walking.run_ekf}
    run = walking.run_dead_reckoning(walk, events) if args.solver == "dead_reckoning" else runs[args.solver](walk, events, walk.fixes.pose)
    out = args.out or args.session / f"trajectory_{args.solver}.csv"
    np.savetxt(out, np.column_stack([run.t, run.xyz]), delimiter=",", header="t,x,y,z", comments="", fmt="%.10g")
    activity = {a: sum(c.activity == a for c in cycles) for a in ("flat", "stairs_up", "stairs_down")}
    print(f"wrote {out} ({len(run.t)} states: {len(cycles)} steps {activity}, {len(rides)} elevator rides; "
          f"{session.duration_s:.0f} s of data in {run.seconds:.2f} s)")
    if np.isfinite(walk.truth_xyz_m).all():
        score = walking.score(run, walk)
        print(json.dumps({"method": args.solver, **score}, indent=2) if args.json else
              f"position RMSE {score['rmse_m']:.2f} m, final error {score['final_error_m']:.2f} m")
    return 0


def _plot_estimate(args: argparse.Namespace, session: Any, estimate: Any) -> Path:
    """The estimate's axes against the truth (or alone), as ``fusegraph run --plot`` writes them."""
    from .plots import plot_attitude_axes

    truth_t = session.truth.t if session.truth is not None else estimate.t
    truth_q = session.truth.values if session.truth is not None else estimate.quat_wxyz
    return Path(plot_attitude_axes(truth_t, truth_q, [estimate], args.plot, title=str(args.session)))


def _same_times(estimate: object, session: object) -> bool:
    import numpy as np

    truth = session.truth  # type: ignore[attr-defined]
    t = estimate.t  # type: ignore[attr-defined]
    return bool(truth is not None and t.shape == truth.t.shape and np.allclose(t, truth.t))


def _cmd_report(args: argparse.Namespace) -> int:
    if args.system in ("bicycle", "gaze"):
        from .systems import bicycle, gaze

        make, table = {"bicycle": (bicycle.bicycle_report, bicycle.format_bicycle_table), "gaze": (gaze.gaze_report, gaze.format_gaze_table)}[args.system]
        seeds = tuple(args.seeds) if args.seeds != list(range(10)) else (0, 1, 2)
        found = make(seeds, plot=str(args.plot) if args.plot else None)
        print(json.dumps(found, indent=2) if args.json else table(found))
        if args.plot:
            print(f"wrote {args.plot}", file=sys.stderr if args.json else sys.stdout)
        return 0
    from .systems import head

    report = head.head_report(args.seeds, args.profile, args.duration, latency_true_s=args.latency_true, latency_assumed_s=args.latency_assumed)
    if args.json:
        print(json.dumps(report.as_json(), indent=2))
    else:
        print(report.table())
    if args.plot:
        path = head_figure(args.seeds[0], args.profile, args.duration, args.plot)
        print(f"wrote {path}", file=sys.stderr if args.json else sys.stdout)
    return 0


def head_figure(seed: int, profile: str, duration_s: float, path: Path) -> Path:
    """The paper's Fig. 3/4 for one seed: reference, tracker, Method II and iSAM2 per axis."""
    from .plots import plot_attitude_axes
    from .scenarios import simulate_head
    from .systems import head

    session = simulate_head(seed, profile=profile, duration_s=duration_s)
    assert session.truth is not None
    estimates = [head.run_method(session, m) for m in ("tracker", "method2", "isam2")]
    title = f"head tracking, {profile} profile, seed {seed}: tracker (100 ms late), Method II, fusegraph iSAM2 (causal)"
    return plot_attitude_axes(session.truth.t, session.truth.values, estimates, path, title, head.LABELS)


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.system == "broad":
        return _bench_broad(args)
    if args.system == "walking":
        from .datasets import steps_oxford
        from .systems import walking

        oxford = None if args.oxford == "none" else (steps_oxford.DEFAULT_DIR if args.oxford == "default" else Path(args.oxford))
        if oxford is not None and not Path(oxford).is_dir():
            raise FileNotFoundError(f"Oxford recordings not found at {oxford} (use --oxford DIR or --oxford none)")
        seed = (args.seeds or (0,))[0]
        walk = walking.bench_walking(seed, oxford, plaza=not args.no_plaza, plot=args.plot)
        print(json.dumps(walk, indent=2) if args.json else walking.format_walking_table(walk))
        return 0
    if args.system == "ultrasonic":
        from .systems import ultrasonic

        counts = tuple(int(x) for x in args.transmitters.split(","))
        found = ultrasonic.bench_ultrasonic(
            counts, tuple(args.seeds or (0, 1, 2)), duration_s=20.0 if args.duration == 600.0 else args.duration,
            uwb_dir=None if args.uwb == "none" else args.uwb, plot=args.plot,
        )
        print(json.dumps(found, indent=2) if args.json else ultrasonic.format_ultrasonic_table(found))
        return 0
    if args.directory is not None:
        raise ValueError("bench head takes no directory (it simulates its session)")
    from .systems import head

    result = head.head_bench(args.duration, args.repeat, profile=args.profile)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"head bench, {args.profile} profile, {args.duration:g} s session, median of {args.repeat}:")
        print(f"  online loop, first minute : {result['x_realtime_first_minute']:8.1f} x real time")
        print(f"  online loop, last minute  : {result['x_realtime_last_minute']:8.1f} x real time")
        print(f"  batch smoother            : {result['batch_s']:8.2f} s")
        print(f"  peak memory (RSS)         : {result['peak_rss_mb']:8.0f} MB")
    return 0


def _bench_broad(args: argparse.Namespace) -> int:
    from .systems import attitude9

    methods = tuple(m.strip() for m in args.methods.split(",")) if args.methods else tuple(attitude9.METHODS)
    trials = tuple(t.strip() for t in args.trials.split(",")) if args.trials else ()
    result = attitude9.bench_broad(args.directory, methods, trials)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(attitude9.format_broad_table(result))
    if args.plot:
        print(f"wrote {attitude9.plot_broad(result, args.plot)}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from .view import view

    for path in view(args.source, args.out, args.solver, args.truth):
        print(f"wrote {path}")
    return 0


def _cmd_ablate(args: argparse.Namespace) -> int:
    import os
    from dataclasses import replace

    from . import ablation

    study = ablation.load_study(args.study) if args.study else ablation.Study(system=args.system, seeds=tuple(range(5)))
    vary = dict(study.vary)
    for item in args.vary:
        name, _, values = item.partition("=")
        if not values:
            raise ValueError(f"--vary {item!r}: use NAME=V1,V2,... (names: {', '.join(ablation.HEAD_PARAMETERS)})")
        vary[name.strip()] = tuple(float(v) for v in values.split(","))
    changes: dict[str, Any] = {"vary": tuple(vary.items()), "drops": study.drops + tuple(tuple(d.split("+")) for d in args.drop)}
    if args.seeds:
        changes["seeds"] = tuple(args.seeds)
    if args.solver:
        changes["solvers"] = tuple(s.strip() for s in args.solver.split(","))
    if args.duration:
        changes["duration_s"] = args.duration
    if args.profile:
        changes["profile"] = args.profile
    study = replace(study, **changes)
    workers = args.workers or os.cpu_count() or 1
    result = ablation.run_study(study, args.out, workers=workers, scheduler=args.scheduler)
    summary = ablation.summarize(result.rows)
    print(ablation.summary_table(summary))
    files = ablation.write_summary(summary, args.out)
    failed = sum(r["status"] != "ok" for r in result.rows)
    print(f"{len(result.rows)} runs ({result.ran} run now, {result.skipped} already done, {failed} failed); "
          f"wall {result.wall_s:.1f} s on {result.workers} worker(s); time inside the solvers: {100 * result.solver_fraction:.0f}% of the workers' time")
    print(f"wrote {args.out / 'runs.csv'}, " + ", ".join(str(f) for f in files))
    return 0


COMMANDS = {"ablate": _cmd_ablate, "simulate": _cmd_simulate, "run": _cmd_run, "report": _cmd_report, "bench": _cmd_bench, "view": _cmd_view}


if __name__ == "__main__":
    sys.exit(main())
