"""``fusegraph`` command line: a thin layer over the library (every command calls one library function)."""

from __future__ import annotations

import argparse
import json
import math
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


def _seeds_arg(text: str) -> list[int]:
    from .evaluation.runner import parse_seeds

    try:
        return parse_seeds(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad seed list {text!r} (use e.g. 0-9 or 0,2,5)") from None


def build_parser() -> argparse.ArgumentParser:
    from .evaluation.tuning import BROAD_GRIDS, BROAD_OBJECTIVES, BROAD_PER_SOLVER, STUDIES
    from .systems.presets import PRESETS

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
    sim.add_argument("scenario", choices=["head", "attitude9", "gaze", "bicycle", "walking", "ultrasonic"], help="which system to simulate")
    sim.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    sim.add_argument("--out", type=Path, required=True, help="directory to write (created)")
    sim.add_argument("--profile", choices=["ideal", "realistic", "noise_free"], default=None,
                     help="sensor error profile (default realistic); head: ideal or realistic; attitude9: realistic or noise_free")
    sim.add_argument("--duration", type=float, default=None,
                     help="seconds of data (default: head, attitude9, ultrasonic 10; gaze, bicycle 40; walking: its whole tour, or its first seconds)")
    sim.add_argument("--sensors", metavar="LIST", help="streams to write: head gyro,tracker[,accel] (default gyro,tracker); "
                     "attitude9 gyro,accel[,mag][,tracker] "
                     "(default gyro,accel,mag); gaze gyro,accel,mag,gaze[,tracker] (tracker = a head attitude tracker); "
                     "walking gyro,accel[,fixes][,beacons] (default gyro,accel,fixes; beacons = UWB ranges to known beacons)")
    sim.add_argument("--gait", choices=["signature", "pendulum"], help="walking: the gait model (default signature; pendulum: the "
                     "inverted-pendulum walker checked against real waists, the one bench walking scores)")
    sim.add_argument("--tracker-gap", metavar="START:END", help="head: no tracker samples from START to END seconds, e.g. 30:90")
    sim.add_argument("--transmitters", type=int, metavar="N", help="ultrasonic: transmitters emitting at once (default 3)")
    sim.add_argument("--latency-true", type=float, metavar="S", help="true tracker latency, seconds (default 0.1)")
    sim.add_argument("--gyro-scale-error", type=float, metavar="S", help="attitude9: each gyro axis reads (1 + s) times the rate, "
                     "s uniform in +-S (default 0; declare scale_sigma on the gyro in session.toml to have the batch estimate it)")
    sim.add_argument("--latency-assumed", type=float, metavar="S",
                     help="write stamps made with this assumed latency and declare it unknown (latency_sigma_s), so solvers estimate it")

    run = sub.add_parser("run", help="estimate a session with one solver; metrics when it has truth",
                         description="Run one solver over a session directory and write the estimate as CSV "
                         "(t, quaternion, azimuth/elevation/roll in degrees, covariance; gaze sessions: t, wall point X, Z). "
                         "The session's system (session.toml) picks the graph: head, attitude9, gaze, bicycle, walking.",
                         epilog="examples:\n  fusegraph simulate gaze --out sessions/gaze0 && fusegraph run sessions/gaze0 --solver batch\n"
                         "  fusegraph simulate bicycle --seed 1 --out sessions/bike1 && fusegraph run sessions/bike1 --solver ekf --plot bike.png",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    run.add_argument("session", type=Path, nargs="+", help="session directory (with session.toml); several, or a folder of sessions, for a study")
    run.add_argument("--solver", choices=list(dict.fromkeys(name for preset in PRESETS.values() for name in preset.solvers)), default="online",
                     help="online = iSAM2 causal estimate at every gyro sample; batch = smoother over the whole session; ekf = the paper's "
                     "EKF (head: Method II; attitude9: the 9-axis EKF; gaze: (yaw, pitch, roll, GX, GZ); bicycle: frame EKF -> subtract -> "
                     "thigh EKF; walking: the paper's Kalman framework); vqf, vqf_offline = the peer (attitude9 only); no_removal = the "
                     "thigh EKF alone (bicycle only); dead_reckoning = steps and rides only, steps = the step count of an accelerometer-only "
                     "recording (walking only); combinatorial = the paper's search "
                     "(ultrasonic only); method1, kalman, tracker, gyro = the head paper's other rows. `fusegraph sensors SYSTEM` lists a system's solvers")
    run.add_argument("--out", type=Path, help="CSV to write (default: ./<session>_<estimate>_<solver>.csv in the current folder: never into the "
                     "recording); with several sessions, a folder")
    run.add_argument("--plot", type=Path, help="also write a PNG of the estimate (against the truth if known)")
    run.add_argument("--json", action="store_true", help='print one JSON object and nothing else: {"system", "solver", "metrics"}')
    run.add_argument("--stream", action="store_true", help="read the session a minute at a time and write the estimate as each 10-minute "
                     "window is solved, a recording of any length in memory that does not grow with it; nothing is scored. attitude9 "
                     "--solver batch (overlapping windows blended at their seams: a day at 285 Hz) or walking --solver gait (steps and "
                     "strides found with two minutes either side of each window: a week of a Mobilise-D waist sensor)")
    run.add_argument("--workers", type=int, default=None, help="several sessions: parallel processes (default: all cores)")
    run.add_argument("--scheduler", default=None, help="several sessions: 'local' starts a Dask LocalCluster; tcp://host:port uses an existing one")

    rep = sub.add_parser("report", help="every solver of a system on your sessions (or on simulated seeds): one table, one JSON, one figure",
                         description="With session folders: every solver of SYSTEM (ours, the paper's baseline, the peers) on each session, "
                         "each run exactly as `fusegraph run` runs it; a table of the means over the sessions and a row per session "
                         "(a session without truth: the estimate's own sigma, the samples it covers, speed, warnings). JSON: "
                         "methods.<solver>.metrics (the keys `run --json` prints) and sessions.<name>.<solver>.\n"
                         "Without folders, the system's simulated report over --seeds:\n"
                         "head: simulate each seed, run every method, print RMS per axis (1e-2 rad), ratio to Method II, "
                         "processing time per 40 ms of data and NEES.\n"
                         "gaze: a subject 1 m from a wall fixates a mark while nodding and shaking the head, then a second mark; "
                         "the gaze point on the wall (X, Z RMS in mm) from the paper's EKF (yaw, pitch, roll, GX, GZ), fusegraph online "
                         "and batch, and speed (x real time).\n"
                         "bicycle: a cyclist's thigh and the bicycle frame, two 9-axis IMUs, downhill with hard braking at 30 s (and on an "
                         "indoor trainer): thigh pitch/roll RMS in the braking phase for the thigh alone (no_removal), the paper's pipeline "
                         "(frame EKF -> subtract -> thigh EKF), fusegraph online and batch (both bodies in one graph).\n"
                         "attitude9, walking, ultrasonic: every solver on each simulated seed, means over seeds.",
                         epilog="examples:\n  fusegraph import broad ../shared/data/broad --out sessions/broad\n"
                         "  fusegraph import broad ../shared/data/broad --system head --out sessions/broad_head\n"
                         "  fusegraph report attitude9 sessions/broad --json > broad.json\n"
                         "  fusegraph report head sessions/broad_head --solvers online,batch,ekf\n"
                         "  fusegraph report attitude9 sessions/cohort --workers 8 --scheduler tcp://10.0.0.5:8786 --cache out/cohort_cache\n"
                         "  fusegraph report ultrasonic sessions/uwb --solvers online,batch --plot uwb.png\n"
                         "  fusegraph report head --seeds 0-9 --plot head.png\n  fusegraph report gaze --seeds 0-4 --json\n"
                         "  fusegraph report bicycle --seeds 0-2 --json --plot bicycle.png",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    rep.add_argument("system", choices=["head", "attitude9", "gaze", "bicycle", "walking", "ultrasonic"])
    rep.add_argument("sessions", nargs="*", type=Path, metavar="SESSION_DIR",
                     help="session directories, or folders of them (from `fusegraph import`, `simulate` or your own); none: simulate --seeds")
    rep.add_argument("--seeds", type=_seeds_arg, default=None, help="seeds, e.g. 0-9 (default: test seeds; settings are chosen on 100-119) or 0,3,7")
    rep.add_argument("--solvers", default=None, metavar="LIST", help="comma list of the system's solvers (default: all; `fusegraph sensors SYSTEM` lists them)")
    rep.add_argument("--profile", choices=["ideal", "realistic"], default="realistic", help="sensor error profile (default realistic)")
    rep.add_argument("--duration", type=float, default=None, help="seconds per session (default: head 10, like the paper; others their simulate default)")
    rep.add_argument("--latency-true", type=float, metavar="S", help="true tracker latency in seconds (default: the scenario's 0.1)")
    rep.add_argument("--latency-assumed", type=float, metavar="S",
                     help="latency the user believes; adds rows method2_wrong_d (Method II with it) and isam2_td/batch_td "
                     "(fusegraph estimating the latency from it as a prior); method2/isam2/batch get the true one")
    rep.add_argument("--viewing", action="store_true", help="gaze: the scene-viewing scenario (the same head motion, a new mark "
                     "every 0.33 s, the mean fixation in scene perception) instead of the paper's two marks")
    rep.add_argument("--gait", choices=["signature", "pendulum"], default=None,
                     help="walking seeds: the gait model simulated (default signature; pendulum: the one bench walking scores)")
    rep.add_argument("--json", action="store_true", help="print JSON instead of the table")
    rep.add_argument("--plot", type=Path, help="write a figure to this PNG (sessions: the headline metric per session and solver; "
                     "seeds: like the paper's Fig. 3/4, first seed)")
    rep.add_argument("--html", type=Path, metavar="OUT.html", help="sessions: also write a page to look at in a browser (one file, works "
                     "offline): the table, and per session each solver's estimate against the truth, its error and 3-sigma band, the warnings")
    rep.add_argument("--workers", type=int, default=None, help="sessions: how many in parallel (default: every core)")
    rep.add_argument("--scheduler", default=None, help="sessions: a Dask scheduler: local, or tcp://host:port of a running cluster")
    rep.add_argument("--cache", type=Path, metavar="DIR", help="sessions: keep each session's rows in DIR by its files, the solver and the "
                     "settings, and run again only what DIR does not hold (a report that was killed, a folder that grew, a session "
                     "changed, a solver added, a run that failed)")
    rep.add_argument("--include-suspect", action="store_true", help="sessions: count runs marked suspect (a heavily clipped gyro, a long "
                     "dropout) in the means; by default they are left out and counted apart")

    vw = sub.add_parser("view", help="files to look at: 3D scene (PLY/GLB/PNG), 2D plots, TUM and CSV trajectories",
                        description="Given a session directory (the solver runs first) or an estimate CSV, write a 3D scene "
                        "(open3d: PLY, GLB and a headless PNG render), a 2D plot against the truth with 3-sigma bands, and the "
                        "trajectories as CSV and TUM files (readable by evo).")
    vw.add_argument("source", type=Path, help="session directory or estimate CSV (from fusegraph run)")
    vw.add_argument("--out", type=Path, required=True, help="directory for the files (created)")
    vw.add_argument("--solver", default="batch", help="solver for a bare session (default batch; any of the system's solvers)")
    vw.add_argument("--truth", type=Path, help="truth for an estimate CSV: a TUM file or a session directory")
    vw.add_argument("--html", type=Path, metavar="OUT.html", help="a session: also write the page `report --html` writes, for this "
                    "session and --solver (a comma list: several solvers side by side)")

    abl = sub.add_parser("ablate", help="ablation study: sensors dropped x parameter grid x seeds x solvers, local or on Dask",
                         description="Run a study: the full-sensor baseline plus one variant per --drop, crossed with every --vary grid, "
                         "for every seed and solver. Results go to OUT/runs.csv (one row per run; re-running skips finished runs), "
                         "OUT/summary.csv and OUT/summary.png (mean and 95% interval per variant).",
                         epilog="example: fusegraph ablate head --drop tracker --drop gyro --vary latency=0,0.05,0.1,0.2 --seeds 0-19 --out studies/head")
    abl.add_argument("system", choices=["head", "attitude9", "gaze", "bicycle", "walking", "ultrasonic"])
    abl.add_argument("--study", type=Path, help="a TOML file with a [study] table (see examples/); flags below add to it")
    abl.add_argument("--drop", action="append", default=[], metavar="SENSOR[+SENSOR]", help="a variant without these sensors (repeatable)")
    abl.add_argument("--vary", action="append", default=[], metavar="NAME=V1,V2,...",
                     help="a parameter grid (repeatable; crossed): head scenario names (latency, gyro_noise, ...) or any catalogued key STREAM.KEY, "
                     "e.g. tracker.noise_sigma_deg=0.2,0.4,0.8")
    abl.add_argument("--seeds", type=_seeds_arg, help="seeds, e.g. 0-19 (default 0-4)")
    abl.add_argument("--sessions", nargs="+", type=Path, metavar="DIR", help="study these session directories (or folders of them: "
                     "imported, recorded, your own) instead of simulating seeds; --vary then takes STREAM.KEY settings")
    abl.add_argument("--solver", default=None, help="comma list of solvers (default: online, batch and the system's baseline)")
    abl.add_argument("--duration", type=float, default=None, help="seconds per session (default 10)")
    abl.add_argument("--profile", choices=["ideal", "realistic"], default=None)
    abl.add_argument("--workers", type=int, default=None, help="parallel workers (default: all cores)")
    abl.add_argument("--scheduler", default=None, help="'local' starts a Dask LocalCluster; tcp://host:port uses an existing one")
    abl.add_argument("--out", type=Path, required=True, help="study directory (created; reused to resume)")
    abl.add_argument("--retry-failed", action="store_true", help="on resume, run the runs that failed before again (default: keep them as failed)")
    abl.add_argument("--force", action="store_true", help="--out holds a study with other settings: start this one there anyway "
                     "(its rows are kept aside as runs.replaced.csv)")

    chk = sub.add_parser("check", help="every check of a session without solving: units, clocks, sensor frames (with the rotation "
                         "between them where the motion tells), dead streams, truth",
                         description="Load each session and run every check a solver would run first, without solving: the format, "
                         "units (a gyro in deg/s, an accelerometer in g), clocks, quaternion conventions, dead or stuck streams, repeated "
                         "range rows, truth in another convention or clock. Then, for each accelerometer and magnetometer, how far its "
                         "axes as written are from the gyro's frame and the rotation between them fitted from the data (with its "
                         "1-sigma per axis) where the motion tells it. A session of 15 minutes or more is read and checked 10 minutes at a time "
                         "(a week-long recording in the memory of one window, its truth checked in each; an error names its window). Exit 2 "
                         "with the first error; warnings are printed.",
                         epilog="examples:\n  fusegraph check sessions/broad/01_undisturbed_slow_rotation_A\n  fusegraph check sessions/broad --json",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    chk.add_argument("sessions", nargs="+", type=Path, metavar="SESSION_DIR", help="session directories, or folders of them")
    chk.add_argument("--json", action="store_true", help="print JSON instead of text")

    dst = sub.add_parser("datasets", help="the public datasets the importers read: source, licence, layout, import command; "
                         "`datasets check DIR` says what a folder holds",
                         description="Every public dataset an importer reads: where to get it (URL or DOI), its licence, the folder "
                         "layout the importer expects (as the source publishes it) and the import command. `datasets check DIR` says "
                         "which dataset a folder holds, what of it is there and what is missing. Nothing is downloaded.",
                         epilog="examples:\n  fusegraph datasets\n  fusegraph datasets check ~/Downloads/broad/data_mat",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    dst.add_argument("action", nargs="?", choices=["list", "check"], default="list", help="list (default) or check a folder")
    dst.add_argument("folder", nargs="?", type=Path, help="check: the folder to look at")
    dst.add_argument("--json", action="store_true", help="print JSON instead of text")

    sen = sub.add_parser("sensors", help="the sensor catalogue: every stream kind's columns, units, keys, factors and checks",
                         description="Print the sensor catalogue (docs/sensors.md is this output), one kind's entry, "
                         "or one system's streams, keys and solvers.",
                         epilog="examples:\n  fusegraph sensors\n  fusegraph sensors gyro\n  fusegraph sensors walking",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    sen.add_argument("kind", nargs="?", help="a stream kind (gyro, accel, ...) or a system (head, walking, ...)")

    imp = sub.add_parser("import", help="turn a real recording into a session directory (then run/view/ablate it)",
                         description="broad: a BROAD trial (.mat) or a folder of them -> attitude9 sessions (one per trial). "
                         "uwb: one UWB run's folder (UWB_<run>.csv + motion_capture_<run>.csv + SOURCE_README.md) -> an ultrasonic session "
                         "(anchors as receivers, tags unlabelled on one rigid planar body, motion capture on the UWB clock as truth; a folder "
                         "without the motion capture gives a session without truth: run tracks it, report and bench need the truth). "
                         "oxford: an Oxford step recording folder or the dataset folder -> walking "
                         "sessions with the phone accelerometer and the hand-counted steps (run --solver steps). hapt: UCI HAPT's raw folder -> "
                         "walking sessions, one per experiment (waist accel + gyro, hand labels as the scoring-only activity stream). "
                         "mobgap: Mobilise-D lab recordings in mobgap's layout -> walking sessions per test and trial (lower-back IMU; "
                         "the INDIP reference's bouts, steps, stride lengths in [truth_extra]). plaza: Plaza1|Plaza2 (shipped with gtsam) "
                         "-> a walking session driven by wheel odometry with beacon ranges (start found from the ranges). tobii: a Tobii Pro Glasses 3 "
                         "export folder (imudata.gz, gazedata.gz) -> a gaze session (no wall: target_depth_m; no truth). pupil: a Pupil Labs Pupil Invisible "
                         "or Neon export folder (imu.csv, gaze.csv; which device from its info.json or its quaternion columns, or --device) -> "
                         "a gaze session without a magnetometer, the device's fixations (and a Neon's own attitude) for scoring. csv: one stream of a "
                         "vendor's CSV export mapped onto a kind (--kind, --columns, --units, --time-units, --decimal), into a new session "
                         "(--system) or added to one, read and written a block at a time (an export of any length in ~150 MB, "
                         "--onto too). xdf: a Lab Streaming Layer recording (LabRecorder), its streams mapped "
                         "with --map onto session streams.",
                         epilog="examples:\n  fusegraph import broad ../shared/data/broad --out sessions/broad\n"
                         "  fusegraph import broad ../shared/data/broad --system head --out sessions/broad_head\n"
                         "  fusegraph import uwb ../shared/data/uwb_lias --out sessions/uwb\n"
                         "  fusegraph import oxford ../shared/data/steps_oxford --out sessions/oxford\n"
                         "  fusegraph run sessions/oxford --solver steps --out studies/oxford\n"
                         "  fusegraph import plaza Plaza2 --out sessions/plaza2 && fusegraph run sessions/plaza2 --solver batch --json\n"
                         "  fusegraph import tobii ../shared/data/gaze_tobii --out sessions/tobii && fusegraph run sessions/tobii --solver batch\n"
                         "  fusegraph import pupil ../shared/data/gaze_pupil_invisible --out sessions/pupil && fusegraph report gaze sessions/pupil\n"
                         "  fusegraph import csv imu.csv --system attitude9 --kind gyro --columns t=Timestamp,wx=GyrX,wy=GyrY,wz=GyrZ "
                         "--units deg/s --time-units ms --out sessions/mine\n"
                         "  fusegraph import csv imu.csv --kind accel --columns t=Timestamp,ax=AccX,ay=AccY,az=AccZ --units g --time-units ms "
                         "--out sessions/mine   # adds a stream\n"
                         "  fusegraph import xdf run1.xdf --system head --map HMD_gyro=gyro --map Polhemus=tracker:attitude --out sessions/run1",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    imp.add_argument("format", choices=["broad", "hapt", "mobgap", "oxford", "plaza", "pupil", "tobii", "uwb", "csv", "xdf"])
    imp.add_argument("source", type=Path, help="the recording (file or folder)")
    imp.add_argument("--out", type=Path, required=True, help="session directory to write (a folder of sessions for several trials)")
    imp.add_argument("--system", choices=["head", "attitude9", "gaze", "bicycle", "walking", "ultrasonic"],
                     help="csv, xdf: whose session a new --out folder is (an existing session keeps its own); broad: head writes head "
                     "sessions (recorded gyro, optical attitude as a 50 Hz tracker 100 ms late) instead of attitude9 ones; gaze writes gaze "
                     "sessions: the recorded IMU as the head's, a SIMULATED eye looking at world-fixed targets (scenarios.eye), the eye's "
                     "true world ray as the truth (report gaze scores gaze_error_deg)")
    imp.add_argument("--kind", help="csv: the stream's kind (`fusegraph sensors` lists them)")
    imp.add_argument("--name", help="csv: the stream's name in the session (default: the kind; e.g. tracker for an attitude stream)")
    imp.add_argument("--columns", metavar="t=COL,wx=COL,...", help="csv: the file's column for t and for each column of the kind")
    imp.add_argument("--units", metavar="UNIT", help="csv: the values' unit when not SI (the kind's accepted units, e.g. deg/s, g); "
                     "xdf: STREAM=UNIT, repeatable")
    imp.add_argument("--time-units", default="s", choices=["s", "ms", "us", "ns", "iso"], help="csv: the time column's unit (default s); "
                     "iso: date-times such as 2024-05-01 12:00:00.010 (a T and a zone offset allowed; without a zone taken as UTC; "
                     "held to 0.24 us)")
    imp.add_argument("--decimal", default=".", choices=[".", ","], help="csv: the numbers' decimal mark (default .; many European exports "
                     "write 1,5 with ; between columns)")
    imp.add_argument("--onto", metavar="STREAM", help="csv, into an existing session: put the stream on the times of this stream of the "
                     "session (e.g. an accelerometer exported on its own clock onto the gyro's), interpolated linearly; what was "
                     "bridged is said")
    imp.add_argument("--map", action="append", default=[], metavar="LSL_NAME=STREAM[:KIND]",
                     help="xdf: an LSL stream of the file as a session stream (KIND defaults to STREAM, e.g. HMD_gyro=gyro, "
                     "Polhemus=tracker:attitude); repeatable")
    imp.add_argument("--truth", action="store_true", help="csv: the stream is the session's truth (kind attitude, position, ...)")
    imp.add_argument("--calibration", type=Path, metavar="FILE", help="uwb: a range calibration per anchor and tag "
                     "(anchor,tag,bias_m,slope,sigma_m; default: the folder's calibration.csv when there is one)")
    imp.add_argument("--device", choices=["invisible", "neon"], help="pupil: which Pupil Labs device made the export (IMU axes, "
                     "camera; default: the export's info.json, else a Neon when imu.csv's quaternion columns hold numbers)")
    imp.add_argument("--labelled", action="store_true", help="uwb: keep each range's tag as the ranging system reports it (a tag column); "
                     "default: unlabelled, each receiver's distances in arrival order")

    tun = sub.add_parser("tune", help="choose free settings by one rule: a grid on tuning seeds 100-119, or leave-one-trial-out on BROAD",
                         description="Every setting a paper leaves open (a baseline's noise) and every free setting of ours is chosen by "
                         "the same rule: the grid printed here, scored on TUNING seeds 100-119 (reports score 0-9), or on real data by "
                         "leave-one-trial-out with the cross-validated figure beside the in-sample one. With --write the chosen values go "
                         "to fusegraph/tuned.toml (with the seeds or trials and the score), which the reports and benches read. "
                         f"Studies: {', '.join(STUDIES)} (simulated); {', '.join(BROAD_GRIDS)} (BROAD trials; {', '.join(BROAD_PER_SOLVER)} "
                         "per --solver, written as broad_mag / broad_mag_batch ...; broad_online: the online solver's relinearisation "
                         f"checks; each trial scored by its total RMSE, except {' and '.join(BROAD_OBJECTIVES)}, whose settings level the "
                         "sensor: its total over VQF's plus its inclination over VQF's, the offline VQF for the batch); "
                         "broad_nested (not a choice but a check: every BROAD study of --solver re-chosen in its order without each "
                         "held-out trial, from the code's defaults, and the trial scored with what its fold chose; printed beside the "
                         "same procedure on all trials and beside tuned.toml's settings; --write files the figure for bench broad); "
                         "uwb_calibrated (the UWB tracker's range noise, leave-one-run-out over the LIAS "
                         "runs or --sessions); activity (the waist activity classifier on "
                         "../shared/data/hapt or --sessions: feature set, boosting stages and context by grouped cross-validation over the "
                         "subjects, checked on the pendulum gait's simulated walks of seeds 100-119 (a pace change must not pass for "
                         "stairs); --write makes it the model on main, fusegraph/models/activity_waist.json).",
                         epilog="examples:\n  fusegraph tune gaze_ekf\n  fusegraph tune head_ekf --write --workers 2\n"
                         "  fusegraph tune broad_mag --solver batch --write\n  fusegraph tune broad_motion --workers 2\n"
                         "  fusegraph tune broad_nested --solver batch --workers 2 --write\n"
                         "  fusegraph tune broad_nested --workers 2 --cache out/nested_online\n"
                         "  fusegraph tune broad_nested --rule one_se --cache out/nested_online   # runs only what the first did not\n"
                         "  fusegraph tune activity --write",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    tun.add_argument("study", help="the study's name (see above)")
    tun.add_argument("--seeds", type=_seeds_arg, help="tuning seeds (default 100-119; test seeds 0-9 are refused)")
    tun.add_argument("--solver", default="online", choices=["online", "batch"],
                     help=f"{', '.join(BROAD_PER_SOLVER)}: which estimate they tune")
    tun.add_argument("--write", action="store_true", help="write the chosen values to fusegraph/tuned.toml, which the reports and benches read")
    tun.add_argument("--sessions", nargs="+", type=Path, default=[], metavar="DIR",
                     help="BROAD studies: choose on these sessions (or folders of them, e.g. imported trials) by leave-one-recording-out")
    tun.add_argument("--workers", type=int, default=1, help="processes: a simulated study's settings, BROAD's trials or the UWB runs (default 1)")
    tun.add_argument("--scheduler", default=None, help="a Dask scheduler for the same jobs: local, or tcp://host:port of a running cluster")
    tun.add_argument("--cache", type=Path, metavar="DIR", help="broad_nested: keep every trial's run in DIR by the trial's content, the code "
                     "and the settings; run again (killed halfway, another --rule, more --passes) it runs only the settings not run yet")
    tun.add_argument("--passes", type=int, default=2, help="broad_nested: passes over the studies in their order at most (default 2; it "
                     "stops when no choice moves)")
    tun.add_argument("--rule", default="best", choices=["best", "one_se"],
                     help="broad_nested: how each study's setting is chosen on a fold's trials: best (default) takes the lowest mean; "
                     "one_se keeps the setting as it stands (the code's default, or the last pass's) unless the best grid point beats "
                     "it by more than one standard error of their per-trial differences (on the online: 2.192 deg cross-validated, "
                     "+12.2 %% over its in-sample, against best's 2.120, +9.7 %%)")

    liv = sub.add_parser("live", help="live over the Lab Streaming Layer: streams in, the causal estimate out, the session recorded",
                         description="Read each declared input from an LSL stream (sample times from LSL's clock, moved onto this machine's "
                         "with one smoothed offset per sending host), feed the online solver as replay does, publish the estimate as an "
                         "LSL stream. head: --in gyro= (3 ch, rad/s), --in tracker= (4 ch, quaternion wxyz; "
                         "stamped with the sample's capture time, so its latency is real), optional --in accel= (3 ch, m/s^2); "
                         "publishes qw qx qy qz and the 9 attitude covariance entries per gyro sample. "
                         "attitude9: --in imu= (9 ch: gyro, accel, mag sampled together), optional --in tracker=; the same channels per "
                         "keyframe. gaze: --in imu=, --in gaze= (2 ch: pixel u right, v up from the image centre), optional --in tracker=; "
                         "--session-toml gives the wall (wall_m) or fixation depth (target_depth_m) and the scene camera; publishes the "
                         "fixated point gaze_x_m gaze_y_m gaze_z_m and the head's qw qx qy qz per gaze sample. Ctrl-C stops.",
                         epilog="examples:\n  fusegraph live head --in gyro=lsl:HMD_gyro --in tracker=lsl:Polhemus --out lsl:head_estimate "
                         "--session-toml sessions/head0/session.toml --record sessions/live1\n"
                         "  fusegraph run sessions/live1 --solver batch        # smooth the live run afterwards\n"
                         "  fusegraph live gaze --in imu=lsl:HeadIMU --in gaze=lsl:EyeTracker --out lsl:gaze_estimate "
                         "--session-toml sessions/gaze0/session.toml",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    liv.add_argument("system", choices=["head", "attitude9", "gaze"])
    liv.add_argument("--in", dest="inputs", action="append", default=[], metavar="NAME=lsl:STREAM", help="an input stream (repeatable)")
    liv.add_argument("--out", required=True, metavar="lsl:STREAM", help="name of the LSL stream the estimate is published on")
    liv.add_argument("--session-toml", type=Path, help="a session.toml declaring the sensors (noise, rates, latency); defaults otherwise")
    liv.add_argument("--record", type=Path, metavar="DIR", help="write what was received as a session directory when the run ends")
    liv.add_argument("--duration", type=float, help="stop after this many seconds (default: until Ctrl-C)")
    liv.add_argument("--estimate-first", action="store_true",
                     help="head: publish each gyro sample's estimate before the iSAM2 update it makes due (the update runs before the "
                     "next sample is read): no sample waits for an update, for an HMD. Cost measured on seeds 100-109: RMS +0.3 %% "
                     "(realistic), +0.8 %% (ideal)")

    ben = sub.add_parser("bench", help="each system against its peers in one run: head, broad, ultrasonic, walking, live, soak, "
                         "head-recorded, gaze-recorded, activity, gait; speed: every system's x real time, memory, throughput",
                         description="head: real-time factor of the whole causal loop in the first and last minute, batch time, peak memory.\n"
                         "broad: every trial in DIR through VQF online/offline, the papers' 9-axis EKF, fusegraph online and batch, in one run: "
                         "total/heading/inclination RMSE (deg, the benchmark's metric) and speed (x real time) per trial and mean.\n"
                         "ultrasonic: simulated transmitters with unknown association (N = 3, 6, 12, several seeds), fusegraph and the paper's "
                         "combinatorial search and the true-position oracle: association accuracy, position RMSE, track loss, time per epoch; "
                         "crossings; and the recorded UWB run with and without tag labels.\n"
                         "walking: the simulated 3-floor walk through the PDR front end (activity confusion per walking cycle / ride, "
                         "the pendulum gait's per-step statistics beside UCI HAPT's real waists when ../shared/data/hapt is there), "
                         "dead reckoning vs EKF vs iSAM2 online vs batch with 20% wrong image fixes and with none; step counts on the "
                         "Oxford phone recordings; the Plaza range + odometry runs (odometry only, online, batch).\n"
                         "live: a simulated head session replayed in real time over the LSL loopback into `fusegraph live head` (its own "
                         "process): latency from a gyro sample's push to its estimate's arrival (p50, p99, max), samples lost, RMS beside "
                         "the replay's (--duration, default 60 s here).\n"
                         "head-recorded: every BROAD trial in DIR as a head session (its recorded gyro; its optical attitude as a 50 Hz "
                         "tracker 100 ms late with the realistic profile's errors; the optical attitude at the gyro rate as the reference): "
                         "tracker, Method II (noise chosen leaving the trial out), the paper's values, iSAM2 online, batch; RMS per axis in "
                         "movement, Euler-angle domain exits listed.\n"
                         "gaze-recorded: the head-worn eye tracker's export in DIR (default ../shared/data/gaze_tobii; a Tobii Pro Glasses 3 "
                         "folder with imudata.gz or a Pupil Labs Pupil Invisible or Neon one with imu.csv, told apart by their files): the gaze-to-IMU "
                         "time offset found from the data, fixations that read no IMU (the device's own, else eye-in-head velocity), and "
                         "the dispersion of the world gaze ray in them (median over fixations) for the head-frame gaze, the raw gyro, the "
                         "paper's EKF, fusegraph online and batch, and the device's own attitude where the export has a whole one (a Neon's).\n"
                         "soak: the online head tracker over an hour of data (--duration, default 3600 s here): speed per 10 minutes and peak memory.\n"
                         "activity: every walking cycle the waist front end detects in DIR (UCI HAPT's raw folder, default ../shared/data/hapt, "
                         "or sessions from `import hapt`) against the hand label of its segment: fusegraph's classifier (leave-one-user-out "
                         "on the users that fitted the model on main, else that model unchanged) and the walking paper's rules; fraction "
                         "correct per class, confusion, cycles per labelled second, cycles per minute while static.\n"
                         "gait: a lower-back IMU against a reference system's walking bouts (DIR: Mobilise-D data in mobgap's layout, default "
                         "../shared/data/mobgap, or sessions from `import mobgap`): step F1 (matched within 0.25 s), stride-length and "
                         "walking-speed MAE per bout, for fusegraph's front end (step length from the pelvis's vertical excursion by the inverted "
                         "pendulum with Mobilise-D's published settings; the step thresholds chosen leave-one-participant-out), the walking paper's "
                         "speed regression "
                         "and mobgap's own Mobilise-D pipeline.\n"
                         "speed: in one run, every system's solvers in x real time against the peer run beside them (9-axis online and "
                         "batch against VQF and offline VQF on the BROAD trials in DIR, and the online with iSAM2 every second keyframe, "
                         "[online] update_every = 2, with its error beside; the head tracker's iSAM2 and batch on BROAD's motion and "
                         "online on simulations against Method II), the live head tracker's time per gyro sample (median, p99, worst), the "
                         "9-axis windowed batch's peak memory on a 1 h and a 24 h recording, and a cohort's recordings per hour per core; "
                         "without DIR (default ../shared/data/broad) the BROAD rows run on simulations and say so. Timings, never asserted.",
                         epilog="examples:\n  fusegraph bench head --duration 600\n  fusegraph bench broad ../shared/data/broad --json > broad.json\n"
                         "  fusegraph bench broad --trials 01,32 --methods vqf,online --plot broad.png\n"
                         "  fusegraph bench ultrasonic --transmitters 3,12 --seeds 0-4 --json\n  fusegraph bench ultrasonic --plot tags.png\n"
                         "  fusegraph bench walking --plot walk.png\n  fusegraph bench walking --oxford ../shared/data/steps_oxford --json\n"
                         "  fusegraph bench head-recorded --plot head_recorded.png\n  fusegraph bench gaze-recorded --plot gaze_recorded.png\n"
                         "  fusegraph import hapt ../shared/data/hapt --out sessions/hapt && fusegraph bench activity sessions/hapt --json\n"
                         "  fusegraph bench gait ../shared/data/mobgap\n  fusegraph bench speed ../shared/data/broad --workers 2 --json > speed.json",
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    ben.add_argument("system", choices=["head", "broad", "ultrasonic", "walking", "live", "soak", "head-recorded", "gaze-recorded", "activity", "gait",
                                               "speed"])
    ben.add_argument("directory", nargs="?", type=Path, help="broad, head-recorded, speed: directory of BROAD trials (*.mat; default ../shared/data/broad) "
                     "or, head-recorded, of the head sessions `import broad --system head` wrote; "
                     "gaze-recorded: the eye-tracker export (Tobii, Pupil Invisible or Neon; default ../shared/data/gaze_tobii); "
                     "activity: HAPT's raw folder or imported sessions")
    ben.add_argument("--duration", type=float, default=600.0, help="head: seconds of data (default 600); ultrasonic: seconds per run (default 20)")
    ben.add_argument("--repeat", type=int, default=3, help="head: repeats; the median is printed (default 3)")
    ben.add_argument("--profile", choices=["ideal", "realistic"], default="realistic", help="head: sensor error profile")
    ben.add_argument("--methods", default=None, help="broad: comma list of vqf,vqf_offline,ekf,online,batch (default all)")
    ben.add_argument("--trials", default=None, help="broad, head-recorded: comma list of file-name prefixes, e.g. 01,32 (default all)")
    ben.add_argument("--plot", type=Path, help="broad: also write a PNG of the errors per trial and method; walking: the trajectories; "
                     "ultrasonic: the tracks, errors and rest probability of the largest N, first seed; gait: each method's stride length and speed "
                     "per bout against the reference's; activity: each method's confusion")
    ben.add_argument("--seeds", type=_seeds_arg, default=None, help="ultrasonic: seeds per N (default 0-2); walking: the first is the walk's seed (default 0)")
    ben.add_argument("--transmitters", default="3,6,12", help="ultrasonic: comma list of N (default 3,6,12)")
    ben.add_argument("--estimate-first", action="store_true", help="live: the live process and the replay publish before the update "
                     "(fusegraph live --estimate-first)")
    ben.add_argument("--uwb", default="default", metavar="DIR", help="ultrasonic: the recorded UWB run (default ../shared/data/uwb_lias; 'none' skips it)")
    ben.add_argument("--oxford", default="default", metavar="DIR", help="walking: Oxford step recordings (default ../shared/data/steps_oxford; 'none' skips)")
    ben.add_argument("--no-plaza", action="store_true", help="walking: skip the Plaza runs")
    ben.add_argument("--use-mag", action="store_true", help="gaze-recorded: use the magnetometer as recorded (default: not; it cannot be calibrated)")
    ben.add_argument("--device", choices=["invisible", "neon"], help="gaze-recorded: which Pupil Labs device made a Pupil export (default: what "
                     "the export says, as import pupil)")
    ben.add_argument("--workers", type=int, default=2,
                     help="head-recorded: trials run side by side in processes; activity: leave-one-user-out folds; speed: sessions (default 2)")
    ben.add_argument("--scheduler", default=None, help="head-recorded, activity, speed: the same jobs on a Dask scheduler: local, or "
                     "tcp://host:port of a running cluster")
    ben.add_argument("--json", action="store_true", help="print JSON")
    return parser


def _show_warning(message: Warning | str, category: type[Warning], filename: str, lineno: int, file: Any = None, line: str | None = None) -> None:
    """Every warning as one stderr line starting with ``warning:`` (a session's own say what and where; others name
    their kind and source)."""
    from .session import SessionWarning

    text = " ".join(str(message).split())
    if not issubclass(category, SessionWarning):
        text = f"{category.__name__}: {text} ({Path(filename).name}:{lineno})"
    print(f"warning: {text}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    import warnings

    args = build_parser().parse_args(argv)
    with warnings.catch_warnings():  # restored on return (tests call main in one process)
        warnings.showwarning = _show_warning
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    try:
        return int(COMMANDS[args.command](args) or 0)
    except BrokenPipeError:  # `fusegraph sensors | head`: the reader has gone; nothing to say to it
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    except Exception as exc:  # user-facing: one clear line, not a traceback (FUSEGRAPH_DEBUG=1 shows it)
        import os

        from .session import SessionError

        if os.environ.get("FUSEGRAPH_DEBUG"):
            raise
        if isinstance(exc, SessionError | FileNotFoundError | ValueError):
            print(f"fusegraph {args.command}: error: {exc}", file=sys.stderr)
            return 2
        if isinstance(exc, RuntimeError) and "Indeterminant" in str(exc):  # gtsam: the linear system has no unique solution
            print(f"fusegraph {args.command}: error: the graph has no unique solution ({str(exc).splitlines()[0].strip()}): a variable no "
                  "measurement reaches (a stream that does not overlap the others, a gap longer than the model bridges) or a "
                  "declared noise of zero", file=sys.stderr)
            return 2
        print(f"fusegraph {args.command}: internal error: {type(exc).__name__}: {exc} (a bug: please report it with the command "
              "line; FUSEGRAPH_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .scenarios import SIMULATORS
    from .session import save_session
    from .systems.presets import PRESETS

    preset, simulator = PRESETS[args.scenario], SIMULATORS[args.scenario]
    options: dict[str, Any] = {}
    given = {
        "tracker_latency_s": args.latency_true, "tracker_latency_assumed_s": args.latency_assumed,
        "sensors": tuple(x.strip() for x in args.sensors.split(",")) if args.sensors else None,
        "tracker_gap_s": _gap_arg(args.tracker_gap) if args.tracker_gap else None, "transmitters": args.transmitters, "gait": args.gait,
        "gyro_scale_error": args.gyro_scale_error,
    }
    flags = {"tracker_latency_s": "--latency-true", "tracker_latency_assumed_s": "--latency-assumed", "sensors": "--sensors",
             "tracker_gap_s": "--tracker-gap", "transmitters": "--transmitters", "gait": "--gait", "gyro_scale_error": "--gyro-scale-error"}
    for name, value in given.items():
        if value is None:
            continue
        if name not in simulator.options:
            raise ValueError(f"{flags[name]} does not apply to {args.scenario} (it applies to: "
                             f"{', '.join(system for system, s in SIMULATORS.items() if name in s.options)})")
        options[name] = value
    if args.profile is not None:
        profiles = simulator.profiles
        if args.profile not in profiles:
            raise ValueError(f"--profile {args.profile} does not apply to {args.scenario} (it has: {', '.join(sorted(profiles))})")
        if "profile" in simulator.options:
            options["profile"] = args.profile
    if args.duration is not None and not args.duration >= simulator.min_duration_s:
        raise ValueError(f"--duration {args.duration:g}: {args.scenario} needs at least {simulator.min_duration_s:g} s"
                         + (f" ({preset.notes[0]})" if preset.notes else ""))
    session = simulator.simulate(args.seed, args.duration, **options)
    if args.out.exists() and any(args.out.iterdir()) and not (args.out / "session.toml").is_file():
        raise ValueError(f"--out {args.out}: a folder with other files in it; give a new or empty folder (or an old session to replace)")
    if (args.out / "session.toml").is_file():
        for old in args.out.glob("*.csv"):
            old.unlink()  # a session written before: no stale stream files stay beside the new ones
        (args.out / "session.toml").unlink()
    path = save_session(session, args.out)
    files = ", ".join(sorted(p.name for p in path.iterdir()))
    print(f"wrote {path}/ ({files})")
    return 0


def _gap_arg(text: str) -> tuple[float, float]:
    start, _, end = text.partition(":")
    try:
        return float(start), float(end)
    except ValueError:
        raise ValueError(f"--tracker-gap {text!r}: use START:END in seconds, e.g. 30:90") from None


def _cmd_sensors(args: argparse.Namespace) -> int:
    from .catalogue import kind_markdown, suggest
    from .sensors import catalogue_markdown, sensor_catalogue
    from .systems.presets import PRESETS

    catalogue = sensor_catalogue()
    if args.kind:
        if args.kind in PRESETS:
            p = PRESETS[args.kind]
            print(f"system {p.name}: {p.summary}\nstreams: {p.streams}\ntruth: {p.truth}\naxes: {p.axes}\nsolvers:")
            for name, text in p.solvers.items():
                print(f"  {name:<16} {text}")
            for key in p.session_keys:
                print(f"  key {key.name} (default {key.default}): {key.meaning}")
            return 0
        if args.kind not in catalogue:
            raise ValueError(f"no sensor kind or system {args.kind!r}{suggest(args.kind, [*catalogue, *PRESETS])}; kinds: {', '.join(catalogue)}")
        print(kind_markdown(catalogue[args.kind]))
        return 0
    print(catalogue_markdown(system_docs()))
    return 0


def system_docs() -> list[tuple[str, str, tuple[Any, ...], tuple[str, ...], str, str]]:
    """Each preset's documentation rows for the catalogue page."""
    from .systems.presets import PRESETS

    return [(p.name, p.streams, p.session_keys, tuple(p.solvers), p.truth, p.axes) for p in PRESETS.values()]


def _cmd_datasets(args: argparse.Namespace) -> int:
    from dataclasses import asdict

    from .datasets.catalogue import DATASETS, check_folder

    if args.action == "check":
        if args.folder is None:
            raise ValueError("datasets check: give the folder to look at (fusegraph datasets check DIR)")
        if not args.folder.is_dir():
            raise FileNotFoundError(f"{args.folder}: not a folder")
        found = check_folder(args.folder)
        if args.json:
            print(_dump(found))
            return 0 if any(row["complete"] for row in found) else 2
        if not found:
            print(f"{args.folder}: holds none of the datasets the importers read (`fusegraph datasets` lists their layouts)")
            return 2
        for row in found:
            parts = ", ".join(f"{pattern}: {count}" for pattern, count in row["parts"].items())  # type: ignore[attr-defined]
            state = "complete" if row["complete"] else "missing " + ", ".join(row["missing"])  # type: ignore[arg-type]
            print(f"{args.folder}: {row['dataset']} ({state}; files {parts})\n  import: {row['import']}")
        return 0 if any(row["complete"] for row in found) else 2
    if args.json:
        print(_dump([asdict(d) for d in DATASETS]))
        return 0
    for d in DATASETS:
        print(f"{d.name}: {d.title}\n  source:  {d.source}\n  licence: {d.licence}\n  cite:    {d.citation}\n  system:  {d.system}")
        for part in d.layout:
            print(f"  {'needs' if part.required else 'reads'}:   {part.pattern}  ({part.meaning})")
        print(f"  layout:  {d.notes}\n  import:  {d.example}\n")
    return 0


def _cmd_check(args: argparse.Namespace) -> int:
    from .evaluation.runner import CHECK_WINDOW_S, check_session, named_session_dirs

    found: list[dict[str, Any]] = []
    for name, path in named_session_dirs(args.sessions):
        checked = check_session(path)  # an error is the command's exit 2, naming the stream (and a long session's window)
        found.append({"session": name, "frames": checked["frames"], "suspect": checked["suspect"]}
                     | ({"windows": checked["windows"]} if checked["windows"] > 1 else {}))
    if args.json:
        print(_dump(found))
        return 0
    for entry in found:
        windows = f" (in {entry['windows']} windows of {CHECK_WINDOW_S:.0f} s)" if "windows" in entry else ""
        print(f"{entry['session']}: every check passed{windows}" + (f"; suspect: {'; '.join(entry['suspect'])}" if entry["suspect"] else ""))
        for frame in entry["frames"]:
            if not frame["told"]:
                print(f"  {frame['stream']} against {frame['gyro']}: the motion turns too little to tell its frame")
                continue
            sigma = ", ".join(f"{s:.2f}" for s in frame["turn_sigma_deg"])
            print(f"  {frame['stream']} against {frame['gyro']}: axes as written off by {frame['misfit_as_written_deg']:.2f} deg (median); "
                  f"fitted turn {frame['turn_deg']:.2f} deg (1-sigma per axis {sigma} deg) leaves {frame['fitted_misfit_deg']:.2f} deg; "
                  f"frame_R_sensor = {json.dumps([[round(v, 4) for v in row] for row in frame['frame_R_sensor']])}")
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .evaluation.runner import describe, format_many, run_many, run_session, run_streamed, session_dirs

    paths = session_dirs(args.session)
    if args.stream:
        if len(paths) != 1 or args.solver not in ("batch", "gait") or args.plot or args.json:
            raise ValueError("--stream: one session, --solver batch (attitude9) or gait (walking), no --plot or --json (the estimate is "
                             "written as it is solved)")
        print(run_streamed(paths[0], args.out, progress=_on_terminal, solver=args.solver))
        return 0
    if len(paths) == 1 and (Path(args.session[0]) / "session.toml").is_file():
        outcome = run_session(paths[0], args.solver, args.out, args.plot)
        if args.json:
            print(_dump(outcome.as_json()))
        else:
            print(describe(outcome))
            for extra in outcome.files[1:]:
                print(f"wrote {extra}")
        return 0
    if args.out is None:
        raise ValueError("several sessions: --out names the folder for their estimates and results.jsonl")
    if args.plot:
        raise ValueError("--plot is for one session; run `fusegraph view` on the one you want to see")
    import os

    rows = run_many(paths, args.solver, args.out, workers=args.workers or os.cpu_count() or 1, scheduler=args.scheduler)
    if args.json:
        print(_dump(rows))
    else:
        print(format_many(rows))
    return 1 if any(r.get("status") != "ok" for r in rows) else 0


def _cmd_import(args: argparse.Namespace) -> int:
    from .datasets.importers import import_recording

    if args.labelled and args.format != "uwb":
        raise ValueError("--labelled applies to import uwb only")
    if args.format in ("csv", "xdf"):
        return _import_generic(args)
    given = [flag for flag, value in (("--kind", args.kind), ("--columns", args.columns), ("--map", args.map), ("--decimal", args.decimal != ".")) if value]
    if given:
        raise ValueError(f"{', '.join(given)}: for import csv / xdf")
    if args.calibration and args.format != "uwb":
        raise ValueError("--calibration applies to import uwb only")
    for path in import_recording(args.format, args.source, args.out, labelled=args.labelled, calibration=args.calibration, system=args.system,
                                 device=args.device):
        print(f"wrote {path}/")
    return 0


def _import_generic(args: argparse.Namespace) -> int:
    from .datasets.generic import add_to_session, import_csv, parse_columns, xdf_streams

    if args.format == "csv":
        if not args.kind or not args.columns:
            raise ValueError("import csv needs --kind and --columns (e.g. --kind gyro --columns t=Timestamp,wx=GyrX,wy=GyrY,wz=GyrZ)")
        path, rows = import_csv(args.out, args.source, args.kind, parse_columns(args.columns, args.kind), args.name, args.units, args.time_units,
                                args.system, truth=args.truth, onto=args.onto, decimal=args.decimal)
        print(f"wrote {path}/ (stream '{'truth' if args.truth else args.name or args.kind}': {rows} samples of {args.kind})")
        return 0
    if not args.map:
        raise ValueError("import xdf needs --map LSL_NAME=STREAM[:KIND] for each stream to use (e.g. --map HMD_gyro=gyro)")
    mapping: dict[str, tuple[str, str]] = {}
    for item in args.map:
        lsl, _, ours = item.partition("=")
        name, _, kind = ours.partition(":")
        if not lsl or not name:
            raise ValueError(f"--map {item!r}: write LSL_NAME=STREAM or LSL_NAME=STREAM:KIND")
        mapping[lsl] = (name, kind or name)
    units = dict(u.split("=", 1) for u in (args.units.split(",") if args.units else []) if "=" in u)
    streams, skipped = xdf_streams(args.source, mapping, units)
    path = add_to_session(args.out, streams, args.system)
    print(f"wrote {path}/ (" + ", ".join(f"'{n}': {len(s.t)} samples of {s.kind}" for n, s in streams.items()) + ")")
    if skipped:
        print(f"warning: {args.source}: LSL stream{'s' if len(skipped) > 1 else ''} {', '.join(repr(n) for n in skipped)} not imported "
              "(no --map names it)", file=sys.stderr)
    return 0


def _seeds_block(seeds: Any, system: str) -> dict[str, Any]:
    """The seeds a report scores, the tuning seeds no setting was chosen outside of (a warning when they meet) and the
    settings every method of the system runs with (``tuned.toml``: values, the seeds they were chosen on, the score)."""
    from .evaluation.tuning import TUNING_SEEDS
    from .tuned import settings_of

    chosen = [int(x) for x in seeds]
    if set(chosen) & set(TUNING_SEEDS):
        print(f"warning: seeds {sorted(set(chosen) & set(TUNING_SEEDS))} are tuning seeds: settings were chosen on them", file=sys.stderr)
    return {"seeds": chosen, "tuning_seeds": list(TUNING_SEEDS), "settings": settings_of(system)}


def _seeds_label(seeds: Any) -> str:
    """``evaluation.tuning.seeds_label`` (imported when a report prints)."""
    from .evaluation.tuning import seeds_label as label

    return label(seeds)


def _cmd_report(args: argparse.Namespace) -> int:
    solvers = [x.strip() for x in args.solvers.split(",") if x.strip()] if args.solvers else None
    if args.viewing and (args.system != "gaze" or args.sessions):
        raise ValueError("--viewing chooses the scenario of simulated gaze seeds (report gaze --seeds ...)")
    if args.gait is not None and (args.system != "walking" or args.sessions):
        raise ValueError("--gait chooses the gait of simulated walking seeds (report walking --seeds ...); recorded sessions have their own")
    if args.sessions:
        return _report_sessions(args, solvers)
    if args.html or args.include_suspect or args.workers or args.scheduler or args.cache:
        raise ValueError("--html, --include-suspect, --workers, --scheduler, --cache: for session folders "
                         "(write simulated ones with `fusegraph simulate SYSTEM --seed N --out DIR`)")
    if args.seeds is None:
        args.seeds = list(range(10))
    if solvers is not None and args.system in ("head", "bicycle", "gaze"):
        raise ValueError(f"report {args.system} over seeds: the paper's table has fixed rows; --solvers applies to session folders and to "
                         "attitude9, walking, ultrasonic")
    if args.system in ("bicycle", "gaze"):
        from .evaluation import bicycle, gaze
        from .report.bicycle import format_bicycle_table
        from .report.gaze import format_gaze_table

        if args.duration is not None or args.profile != "realistic":
            raise ValueError(f"report {args.system}: its scenario is fixed (40 s, the realistic profile); --duration and --profile do not apply")
        make, table = {"bicycle": (bicycle.bicycle_report, format_bicycle_table), "gaze": (gaze.gaze_report, format_gaze_table)}[args.system]
        seeds = tuple(args.seeds)
        found = make(seeds, plot=str(args.plot) if args.plot else None, **({"viewing": True} if args.viewing else {}))
        found.update(_seeds_block(seeds, args.system))
        print(_dump(found) if args.json else table(found) + "\n" + _seeds_label(seeds))
        if args.plot:
            print(f"wrote {args.plot}", file=sys.stderr if args.json else sys.stdout)
        return 0
    if args.system != "head":
        from .evaluation.runner import format_generic_report, generic_report

        if args.latency_true is not None or args.latency_assumed is not None or args.profile != "realistic":
            raise ValueError(f"report {args.system}: --latency-true/--latency-assumed/--profile apply to head only")
        chosen = args.seeds
        options = {} if args.gait is None else {"gait": args.gait}
        found = generic_report(args.system, chosen, args.duration, solvers, **options)
        found.pop("per_seed")
        found.update(_seeds_block(chosen, args.system))
        print(_dump(found) if args.json else format_generic_report(found) + "\n" + _seeds_label(chosen))
        if args.plot:
            from .evaluation.runner import solve_session
            from .report.pictures import PICTURES
            from .scenarios import SIMULATORS

            session = SIMULATORS[args.system].simulate(chosen[0], args.duration, **options)
            estimates = [solve_session(session, m).estimate for m in ("online", "batch")]
            written = PICTURES[args.system](session, estimates, args.plot.parent)
            written[0].replace(args.plot)
            print(f"wrote {args.plot}", file=sys.stderr if args.json else sys.stdout)
        return 0
    from .evaluation import head

    duration = 10.0 if args.duration is None else args.duration
    report = head.head_report(args.seeds, args.profile, duration, latency_true_s=args.latency_true, latency_assumed_s=args.latency_assumed)
    if args.json:
        print(_dump({**report.as_json(), **_seeds_block(args.seeds, "head")}))
    else:
        print(report.table() + "\n" + _seeds_label(args.seeds))
    if args.plot:
        path = head_figure(args.seeds[0], args.profile, duration, args.plot)
        print(f"wrote {path}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _report_sessions(args: argparse.Namespace, solvers: list[str] | None) -> int:
    """``report SYSTEM DIR ...``: every solver on the user's sessions."""
    from .evaluation.runner import named_session_dirs, report_sessions
    from .report.tables import format_session_report, plot_session_report

    fixed = {"--seeds": args.seeds is not None, "--duration": args.duration is not None, "--latency-true": args.latency_true is not None,
             "--latency-assumed": args.latency_assumed is not None, "--profile": args.profile != "realistic"}
    given = [flag for flag, used in fixed.items() if used]
    if given:
        raise ValueError(f"{', '.join(given)}: for simulated reports; session folders are reported as recorded")
    traces: dict[str, list[Any]] | None = {} if args.html else None
    import os

    found = report_sessions(args.system, named_session_dirs(args.sessions), solvers, include_suspect=args.include_suspect, traces=traces,
                            workers=args.workers or os.cpu_count() or 1, scheduler=args.scheduler, cache=args.cache)
    table = format_session_report(found)
    print(_dump(found) if args.json else table)
    if args.html and traces is not None:
        from .report.html import write_html

        print(f"wrote {write_html(found, table, traces, args.html)}", file=sys.stderr if args.json else sys.stdout)
    if args.plot:
        print(f"wrote {plot_session_report(found, args.plot)}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _on_terminal(line: str) -> None:
    """A bench's progress line, on stderr when a person watches it (a terminal); a log stays quiet."""
    if sys.stderr.isatty():
        print(f"\r\033[K{line}", end="", file=sys.stderr, flush=True)


def _dump(value: Any) -> str:
    """JSON as every command prints it: NaN and infinities as null (JSON has no NaN; a reader's parser would fail)."""
    return json.dumps(_json_safe(value), indent=2)


def _json_safe(value: Any) -> Any:
    """NaN and infinities as null (JSON has no NaN)."""
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def head_figure(seed: int, profile: str, duration_s: float, path: Path) -> Path:
    """The paper's Fig. 3/4 for one seed: reference, tracker, Method II and iSAM2 per axis."""
    from .evaluation.head import LABELS
    from .report.plots import plot_attitude_axes
    from .scenarios import simulate_head
    from .systems import head

    session = simulate_head(seed, profile=profile, duration_s=duration_s)
    assert session.truth is not None
    estimates = [head.run_method(session, m) for m in ("tracker", "method2", "isam2")]
    title = f"head tracking, {profile} profile, seed {seed}: tracker (100 ms late), Method II, fusegraph iSAM2 (causal)"
    return plot_attitude_axes(session.truth.t, session.truth.values, estimates, path, title, LABELS)


def _cmd_bench(args: argparse.Namespace) -> int:
    if args.system == "broad":
        return _bench_broad(args)
    if args.system == "soak":
        from .evaluation.head import head_soak

        soak = head_soak(3600.0 if args.duration == 600.0 else args.duration)
        if args.json:
            print(_dump(soak))
        else:
            print(f"online head tracker over {soak['duration_s']:g} s of data: x real time per {soak['block_s']:g} s: "
                  + ", ".join(f"{x:.1f}" for x in soak["x_realtime_per_block"])
                  + f"; last/first {soak['last_over_first']:.2f}; peak RSS {soak['peak_rss_mb']:.0f} MB; every estimate finite: {soak['finite']}")
        return 0
    if args.system == "speed":
        from .evaluation.speed import bench_speed, format_speed

        broad = args.directory or Path(__file__).resolve().parents[1].parent / "shared" / "data" / "broad"
        found = bench_speed(broad if broad.is_dir() else None, workers=args.workers or 1, scheduler=args.scheduler, progress=_on_terminal)
        print(_dump(found) if args.json else format_speed(found))
        return 0
    if args.system == "live":
        from .live import bench_live, format_bench_live

        found = bench_live(60.0 if args.duration == 600.0 else args.duration, seed=(args.seeds or (0,))[0], estimate_first=args.estimate_first)
        print(_dump(found) if args.json else format_bench_live(found))
        return 0
    if args.system == "head-recorded":
        from .evaluation import head_recorded

        trials = tuple(t.strip() for t in args.trials.split(",")) if args.trials else ()
        found = head_recorded.bench_head_recorded(args.directory, workers=args.workers, trials=trials,
                                                  progress=_on_terminal, scheduler=args.scheduler)
        print(_dump(found) if args.json else head_recorded.format_head_recorded(found))
        if args.plot:
            print(f"wrote {head_recorded.plot_head_recorded(found, args.plot)}", file=sys.stderr if args.json else sys.stdout)
        return 0
    if args.system == "gait":
        from .evaluation.gait import bench_gait, format_gait

        found = bench_gait(args.directory, progress=_on_terminal)
        print(_dump(found) if args.json else format_gait(found))
        if args.plot:
            from .evaluation.gait import plot_gait

            print(f"wrote {plot_gait(found, args.plot)}", file=sys.stderr if args.json else sys.stdout)
        return 0
    if args.system == "activity":
        from .evaluation.activity import bench_activity, format_activity

        found = bench_activity(args.directory, progress=_on_terminal, workers=args.workers, scheduler=args.scheduler)
        print(_dump(found) if args.json else format_activity(found))
        if args.plot:
            from .report.gait import plot_confusions

            rule = "fusegraph leave-one-user-out (nested)" if found["cross_validated"] else "fusegraph's model on main, unchanged"
            title = f"activity per detected cycle, {len(found['users'])} users: {rule}"
            print(f"wrote {plot_confusions(found['methods'], args.plot, title)}", file=sys.stderr if args.json else sys.stdout)
        return 0
    if args.system == "gaze-recorded":
        from .evaluation import gaze_recorded

        recorded = gaze_recorded.analyse_gaze_recording(args.directory, use_mag=args.use_mag, device=args.device)
        found = gaze_recorded.gaze_recorded_json(recorded)
        print(_dump(found) if args.json else gaze_recorded.format_gaze_recorded(found))
        if args.plot:
            print(f"wrote {gaze_recorded.plot_gaze_recorded(recorded, args.plot)}", file=sys.stderr if args.json else sys.stdout)
        return 0
    if args.system == "walking":
        from .datasets import steps_oxford
        from .evaluation import walking
        from .report.walking import format_walking_table

        oxford = None if args.oxford == "none" else (steps_oxford.DEFAULT_DIR if args.oxford == "default" else Path(args.oxford))
        if oxford is not None and not Path(oxford).is_dir():
            raise FileNotFoundError(f"Oxford recordings not found at {oxford} (use --oxford DIR or --oxford none)")
        seed = (args.seeds or (0,))[0]
        walk = walking.bench_walking(seed, oxford, plaza=not args.no_plaza, plot=args.plot)
        print(_dump(walk) if args.json else format_walking_table(walk) + "\n" + _seeds_label([seed]) + " (the simulated walks; the recordings: as labelled)")
        return 0
    if args.system == "ultrasonic":
        from .evaluation import ultrasonic
        from .report.ultrasonic import format_ultrasonic_table

        counts = tuple(int(x) for x in args.transmitters.split(","))
        seeds = tuple(args.seeds or (0, 1, 2))
        found = ultrasonic.bench_ultrasonic(
            counts, seeds, duration_s=20.0 if args.duration == 600.0 else args.duration, uwb_dir=None if args.uwb == "none" else args.uwb, plot=args.plot,
        )
        print(_dump(found) if args.json else format_ultrasonic_table(found) + "\n" + _seeds_label(seeds) + " (the simulated rows; the LIAS runs: as labelled)")
        return 0
    if args.directory is not None:
        raise ValueError("bench head takes no directory (it simulates its session)")
    from .evaluation import head

    result = head.head_bench(args.duration, args.repeat, profile=args.profile)
    if args.json:
        print(_dump(result))
    else:
        print(f"head bench, {args.profile} profile, {args.duration:g} s session, median of {args.repeat}:")
        print(f"  online loop, first minute : {result['x_realtime_first_minute']:8.1f} x real time")
        print(f"  online loop, last minute  : {result['x_realtime_last_minute']:8.1f} x real time")
        print(f"  batch smoother            : {result['batch_s']:8.2f} s")
        print(f"  peak memory (RSS)         : {result['peak_rss_mb']:8.0f} MB")
    return 0


def _bench_broad(args: argparse.Namespace) -> int:
    from .evaluation.broad import bench_broad
    from .report.broad import format_broad_table, plot_broad

    methods = tuple(m.strip() for m in args.methods.split(",")) if args.methods else ()
    trials = tuple(t.strip() for t in args.trials.split(",")) if args.trials else ()
    result = bench_broad(args.directory, methods, trials)
    if args.json:
        print(_dump(result))
    else:
        print(format_broad_table(result))
    if args.plot:
        print(f"wrote {plot_broad(result, args.plot)}", file=sys.stderr if args.json else sys.stdout)
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    from .evaluation.view import view

    solvers = [s.strip() for s in args.solver.split(",") if s.strip()]
    for path in view(args.source, args.out, solvers[0], args.truth):
        print(f"wrote {path}")
    if args.html:
        from .evaluation.runner import load_sessions, report_sessions
        from .report.html import write_html
        from .report.tables import format_session_report

        if not (args.source / "session.toml").is_file():
            raise ValueError("--html: for a session directory (an estimate CSV alone has no report)")
        sessions = load_sessions([args.source])
        traces: dict[str, list[Any]] = {}
        found = report_sessions(sessions[0][1].system, sessions, solvers, show_progress=False, traces=traces)
        print(f"wrote {write_html(found, format_session_report(found), traces, args.html)}")
    return 0


def _cmd_tune(args: argparse.Namespace) -> int:
    from .evaluation.tuning import main as tune_main

    if args.study == "broad_nested":
        from .evaluation.nested import main_nested

        return main_nested(args.solver, args.sessions, args.passes, args.workers, args.scheduler, args.write, args.rule, args.cache)
    if args.cache is not None:
        raise ValueError("--cache: for broad_nested (the other studies run each grid point once)")

    argv = [args.study, "--solver", args.solver, "--workers", str(args.workers)] + (["--write"] if args.write else [])
    argv += ["--scheduler", args.scheduler] if args.scheduler else []
    if args.sessions:
        argv += ["--sessions", *(str(p) for p in args.sessions)]
    if args.seeds:
        argv += ["--seeds", str(min(args.seeds)), str(max(args.seeds))]
    return tune_main(argv)


def _cmd_live(args: argparse.Namespace) -> int:
    from .live import declared_session, parse_inputs, run_live
    from .session import SessionError

    if not args.out.startswith("lsl:") or len(args.out) <= 4:
        raise SessionError(f"--out {args.out!r}: write lsl:STREAM")
    inputs = parse_inputs(args.system, args.inputs)
    stats = run_live(args.system, inputs, args.out[4:], declared_session(args.system, args.session_toml), duration_s=args.duration, record=args.record,
                     estimate_first=args.estimate_first,
                     on_ready=lambda: print(f"live {args.system}: reading {', '.join(f'{k}={v}' for k, v in inputs.items())}; publishing {args.out} "
                                            "(Ctrl-C stops)", flush=True))
    print(f"received {stats.received}, refused {stats.rejected}, published {stats.published} estimates in {stats.seconds:.1f} s "
          f"({100 * stats.solve_s / max(stats.seconds, 1e-9):.0f}% in the solver); {stats.behind} arrived behind a sample due after them; "
          f"{stats.too_late} came after the solver's window had passed their time (no estimate)")
    if args.record:
        print(f"wrote {args.record}/ (fusegraph run {args.record} --solver batch smooths it)")
    return 0


def _cmd_ablate(args: argparse.Namespace) -> int:
    import os
    from dataclasses import replace

    from .evaluation import ablation

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
    if args.sessions:
        from .evaluation.runner import session_dirs

        if args.seeds or args.duration or args.profile:
            raise ValueError("--seeds, --duration and --profile are for simulated studies; --sessions are studied as recorded")
        changes["sessions"] = tuple(str(p) for p in session_dirs(args.sessions))
    if args.solver:
        changes["solvers"] = tuple(s.strip() for s in args.solver.split(","))
    if args.duration:
        changes["duration_s"] = args.duration
    if args.profile:
        changes["profile"] = args.profile
    study = replace(study, **changes)
    workers = args.workers or os.cpu_count() or 1
    result = ablation.run_study(study, args.out, workers=workers, scheduler=args.scheduler, retry_failed=args.retry_failed, force=args.force)
    summary = ablation.summarize(result.rows)
    from .report.ablation import summary_table, write_summary

    print(summary_table(summary))
    files = write_summary(summary, args.out)
    failed = sum(r["status"] == "failed" for r in result.rows)
    idle = ablation.settings_without_effect(result.rows, study)
    if idle:
        raise ValueError(f"--vary {', '.join(idle)}: every value gave the same results in every run: no solver of {study.system} "
                         f"reads {'it' if len(idle) == 1 else 'them'} (the rows are in {args.out / 'runs.csv'})")
    print(f"{len(result.rows)} runs ({result.ran} run now, {result.skipped} already done, {failed} failed); "
          f"wall {result.wall_s:.1f} s on {result.workers} worker(s); time inside the solvers: {100 * result.solver_fraction:.0f}% of the workers' time")
    print(f"wrote {args.out / 'runs.csv'}, " + ", ".join(str(f) for f in files))
    if failed:
        print(f"fusegraph ablate: {failed} of {len(result.rows)} runs failed (see the error column of runs.csv; running the same "
              "command again retries them)", file=sys.stderr)
        return 1
    return 0


COMMANDS = {"tune": _cmd_tune, "live": _cmd_live,
            "ablate": _cmd_ablate, "simulate": _cmd_simulate, "run": _cmd_run, "report": _cmd_report, "bench": _cmd_bench, "view": _cmd_view,
            "sensors": _cmd_sensors, "import": _cmd_import, "check": _cmd_check,
            "datasets": _cmd_datasets}


if __name__ == "__main__":
    sys.exit(main())
