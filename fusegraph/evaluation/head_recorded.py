"""Head tracking on recorded motion (``fusegraph bench head-recorded``): BROAD trials imported as head sessions
(``import broad --system head``, see ``datasets.broad_head``) through the head preset, as ``report head`` runs them.

The bench is a report over those sessions whose open settings are chosen by leave-one-trial-out: each grid point is the
same session DECLARING the setting (the paper's EKF figures in ``[ekf]``, the graph's gyro noise and bias walk on the
gyro stream), run by ``runner.solve_session`` (what ``fusegraph run`` calls) and scored by the head preset (movement
flag, Euler-angle domain, first second skipped). A held-out trial's row is exactly ``report head`` on that trial's
session declaring the setting chosen without it.

The paper's Method II is an Euler-angle filter: near +-90 deg elevation its rate matrix (1/cos(elevation)) is singular,
and BROAD's rotation trials pass within a degree of it. Where the filter's own elevation estimate leaves the domain the
preset gives it no figure (``metrics.excluded``) and the trial is not averaged: it is listed with the reason, so no mean
hides a singular filter.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..baselines.ekf import HeadEkfConfig
from ..geometry import FloatArray
from ..metrics import AXES, EULER_DOMAIN_DEG
from ..session import Session, SessionError
from .runner import solve_session

METHODS = ("tracker", "method2", "method2_paper_values", "isam2", "batch")
"""Rows of the table and keys of the JSON, in order (the targets use ``tracker, method2, isam2, batch``)."""

SOLVER_OF = {"tracker": "tracker", "method2": "ekf", "method2_paper_values": "method2_paper_values", "isam2": "online", "batch": "batch"}
"""The head preset's solver behind each row."""

#: Method II's open settings, chosen by leave-one-trial-out (``_choose``) over the trials of the run (the paper's values
#: fit its own hardware and rate): process noise (x the paper's w1, w2) and gyro sigma; the tracker sigma
#: stays the paper's 0.0268 rad (the same tracker error model as the simulated head report's). Once the gyro's delay was
#: declared, Method II chose the grid's lowest gyro sigma (0.00185 rad/s, then 0.0006 in the next run: leave-one-trial-out
#: 0.626 -> 0.620 deg); a run with 0.0002 chose that edge too but scored 0.620 deg again: its score has levelled off there.
EKF_GRID: tuple[tuple[float, float], ...] = tuple((p, g) for p in (1 / 256, 1 / 64, 1 / 16, 1 / 4, 1.0)
                                                  for g in (0.0002, 0.0006, 0.00185, 0.0056, 0.0167, 0.05, 0.15))


def ekf_setting_name(setting: tuple[float, float]) -> str:
    """A grid point as text (``process_scale=0.25 gyro_sigma_rad_s=0.45``)."""
    return f"process_scale={setting[0]:g} gyro_sigma_rad_s={setting[1]:g}"


GRAPH_GYRO_GRID: tuple[tuple[float, float], ...] = tuple((w, q) for w in (0.0005, 0.0015) for q in (1e-3, 3e-4, 1e-4, 3e-5, 1e-5))
"""What fusegraph's graph is told about the gyro (its free settings here), chosen by the same leave-one-trial-out rule as
Method II's: the white noise per sample (rad/s) and the bias random walk (rad/s/sqrt(s)); BROAD's IMU has no data sheet in
the dataset. The head model's default walk (1e-3) suits a consumer gyro; a lower one lets the smoother carry the tracker's
slowly varying error over seconds of gyro. A first grid (white 0.0005 / 0.0015 / 0.005 x walk 1e-3 / 1e-4 / 1e-5) chose
0.0005 and 1e-4 on every fold; this one refines the walk around it. 0.005 and 0.015 rad/s were chosen on no fold, and a walk of 1e-6
made gtsam refuse the batch system (trials 15, 32). With the gyro's delay declared (``RecordedHeadConfig.estimate_gyro_delay``)
the choice moved inside the grid: white 0.0015 and walk 1e-4 (leave-one-trial-out 0.853 -> 0.414 deg): the lowest white noise
had partly stood in for the 4 ms the gyro and the tracker disagreed by."""

TUNED_METHODS = ("method2", "isam2", "batch")
"""Methods whose free settings are chosen per held-out trial."""


def graph_setting_name(setting: tuple[float, float]) -> str:
    """A graph grid point as text."""
    return f"gyro_noise_sigma_rad_s={setting[0]:g} bias_rw_sigma={setting[1]:g}"


@dataclass(frozen=True)
class MethodResult:
    """One row's run on one trial (one grid point), from the head preset's metrics."""

    rms_deg: FloatArray
    """RMS of the azimuth, elevation and roll errors over the scored samples, degrees (NaN: no valid figure)."""
    invalid: str | None
    """Why there is no figure (the preset's ``excluded``, scored samples without an estimate, a failed run), or None."""
    runtime_s: float
    """Wall time of the run, seconds."""


def result_from(outcome_metrics: dict[str, Any], runtime_s: float, label: str) -> MethodResult:
    """A row from the head preset's metrics of one run."""
    rms = np.array([np.nan if (v := outcome_metrics["rms_deg"][a]) is None else v for a in AXES], dtype=float)
    invalid = outcome_metrics.get("excluded")
    if invalid is None and outcome_metrics.get("truth_samples_missing", 0):
        invalid = f"{label}: estimate not finite on {outcome_metrics['truth_samples_missing']} scored samples"
    return MethodResult(np.full(3, np.nan) if invalid else rms, invalid, runtime_s)


def declare_ekf(session: Session, setting: tuple[float, float]) -> Session:
    """The session declaring Method II's figures at a grid point (``[ekf]``)."""
    return session.with_meta(ekf={"process_scale": setting[0], "gyro_sigma_rad_s": setting[1]})


def declare_gyro(session: Session, setting: tuple[float, float]) -> Session:
    """The session whose gyro declares a graph grid point (``noise_sigma_rad_s``, ``bias_rw_sigma``)."""
    gyro = session.stream("gyro")
    meta = {**gyro.meta, "noise_sigma_rad_s": setting[0], "bias_rw_sigma": setting[1]}
    return replace(session, streams={**session.streams, "gyro": replace(gyro, meta=meta)})


def _run(session: Session, row: str) -> MethodResult:
    """One row on one (declared) session through ``solve_session``; a failed run is a row with its reason."""
    try:
        outcome = solve_session(session, SOLVER_OF[row])
    except RuntimeError as exc:  # gtsam's indeterminate system: this declaration fails here, reported as such
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        return MethodResult(np.full(3, np.nan), f"{row}: gtsam: {first_line}", 0.0)
    if not outcome.metrics:
        raise SessionError(f"{session.where}: no truth to score (bench head-recorded needs the optical reference)")
    return result_from(outcome.metrics, float(outcome.estimate.runtime_s), row)


@dataclass(frozen=True)
class TrialRuns:
    """Everything measured on one trial (what a worker returns)."""

    stem: str
    """Trial (session) name."""
    methods: dict[str, MethodResult]
    """Results of the rows without a free setting (``tracker``, ``method2_paper_values``)."""
    grids: dict[str, dict[str, MethodResult]]
    """Per tuned row (``TUNED_METHODS``), its result at every grid point, for the leave-one-trial-out choice."""
    scored_fraction: float
    """Scored samples over the samples in movement."""
    duration_s: float
    """Length of the trial, seconds."""
    gyro_delay_s: tuple[float, float] | None = None
    """The gyro delay the session declares and its sigma, seconds (None: not declared)."""


@dataclass(frozen=True)
class TrialJob:
    """One trial for a worker: a BROAD file to import, or an imported session directory, and the grids."""

    source: Path
    """A BROAD trial (.mat) or a head session directory."""
    ekf_grid: tuple[tuple[float, float], ...]
    """Method II's grid."""
    graph_grid: tuple[tuple[float, float], ...]
    """The graph's gyro grid."""


def trial_session(source: Path) -> tuple[str, Session]:
    """A trial's head session: imported from a BROAD file as ``import broad --system head`` does, or loaded."""
    from ..datasets.importers import broad_sessions
    from ..session import load_session

    if source.suffix == ".mat":
        return broad_sessions(source, system="head")[0]
    session = load_session(source)
    if session.system != "head":
        raise SessionError(f"{source}: a {session.system} session, not head (import BROAD trials with `import broad DIR --system head`)")
    return source.name, session


def run_trial(job: TrialJob) -> TrialRuns:
    """Every row at every grid point on one trial's head session."""
    from ..metrics import in_euler_domain, nearest_samples

    stem, session = trial_session(job.source)
    methods = {row: _run(session, row) for row in ("tracker", "method2_paper_values")}
    grids: dict[str, dict[str, MethodResult]] = {m: {} for m in TUNED_METHODS}
    for setting in job.ekf_grid:
        grids["method2"][ekf_setting_name(setting)] = _run(declare_ekf(session, setting), "method2")
    for setting in job.graph_grid:
        declared = declare_gyro(session, setting)
        for row in ("isam2", "batch"):
            grids[row][graph_setting_name(setting)] = _run(declared, row)
    assert session.truth is not None
    truth = session.truth
    flag = session.stream("movement")
    moving = flag.values[nearest_samples(flag.t, truth.t), 0] > 0
    scored = moving & in_euler_domain(truth.values) & (truth.t >= truth.t[0] + 1.0)
    gyro_meta = session.stream("gyro").meta
    delay = (float(gyro_meta["delay_s"]), float(gyro_meta["delay_sigma_s"])) if "delay_sigma_s" in gyro_meta else None
    return TrialRuns(stem, methods, grids, float(scored.sum() / max(moving.sum(), 1)), session.duration_s, delay)


# ------------------------------------------------------------------------------------ bench

def _rms_json(rms_deg: FloatArray) -> dict[str, float | None]:
    return {axis: (float(v) if np.isfinite(v) else None) for axis, v in zip(AXES, rms_deg, strict=True)}


def _point(name: str) -> tuple[float, ...]:
    """A grid point's values from its text (``a=1 b=2``)."""
    return tuple(float(part.split("=")[1]) for part in name.split())


def _choose(runs: dict[str, TrialRuns], method: str, stems: list[str], scored_with: tuple[str, ...] = ()) -> tuple[dict[str, str], dict[str, Any]]:
    """One method's setting per trial by leave-one-trial-out. Method II: over the trials where every grid point stayed
    inside its Euler domain (outside it the figures are the singularity's: choosing by them once picked settings 2x
    worse on the trials inside it); trials outside that set get the best over all of it. Any row: a grid point without a
    figure on a trial (not finite, outside the domain, or gtsam refused the system) scores as far off there.
    ``scored_with``: the methods whose mean RMS scores a grid point (the graph's gyro declaration is one property of
    the sensor that online and batch share: chosen once for both)."""
    from .tuning import leave_one_group_out

    inside = [stem for stem in stems if method != "method2" or all(r.invalid is None for r in runs[stem].grids[method].values())]
    tuning_trials = inside if len(inside) >= 2 else stems
    settings = list(runs[stems[0]].grids[method])
    # a setting that returned nothing finite on a trial scores as far off (it must not win by failing)
    together = scored_with or (method,)
    scores = {s: {stem: float(np.mean([np.nan_to_num(np.mean(runs[stem].grids[m][s].rms_deg), nan=1e3) for m in together])) for stem in tuning_trials}
              for s in settings}
    logo = leave_one_group_out(scores)
    chosen = {stem: logo["held_out"][stem]["chosen"] if stem in logo["held_out"] else logo["chosen"] for stem in stems}
    info = {"tuning_trials": tuning_trials, "grid": settings, "chosen_per_trial": chosen, "in_sample_best": logo["chosen"],
            "in_sample_deg": logo["in_sample"], "cross_validated_deg": logo["cross_validated"]}
    return chosen, info


def bench_head_recorded(
    directory: str | Path | None = None, workers: int = 2, progress: Callable[[str], None] | None = None, trials: Sequence[str] = (),
    scheduler: str | None = None,
    ekf_grid: Sequence[tuple[float, float]] = EKF_GRID, graph_grid: Sequence[tuple[float, float]] = GRAPH_GYRO_GRID,
) -> dict[str, Any]:
    """Every trial in ``directory`` (BROAD's ``*.mat``, imported here as ``import broad --system head`` would, or a folder
    of head sessions that command wrote) through every row; the JSON of ``fusegraph bench head-recorded`` (see the module
    docstring). ``trials``: name prefixes to keep."""
    from ..datasets.broad import DEFAULT_DIR, trial_paths
    from .cluster import completed, costliest_first, path_bytes
    from .runner import session_dirs

    folder = Path(directory or DEFAULT_DIR)
    found = trial_paths(folder) if list(folder.glob("*.mat")) else session_dirs([folder])
    paths = [p for p in found if not trials or any(p.name.startswith(t) for t in trials)]
    if len(paths) < 2:
        raise ValueError(f"{folder}: need at least two trials (BROAD .mat files or head sessions; settings are chosen leaving one out), "
                         f"found {len(paths)}")
    jobs = [TrialJob(p, tuple(ekf_grid), tuple(graph_grid)) for p in paths]
    runs: dict[str, TrialRuns] = {}
    started = costliest_first(jobs, lambda job: path_bytes(job.source), workers, scheduler)  # results are keyed by trial
    for n, (_job, future) in enumerate(completed(run_trial, started, workers, scheduler)):
        run = future.result()
        runs[run.stem] = run
        if progress is not None:
            progress(f"{run.stem} done ({n + 1}/{len(jobs)})")
    stems = sorted(runs, key=lambda stem: [p.stem if p.suffix == ".mat" else p.name for p in paths].index(stem))
    graph = _choose(runs, "isam2", stems, scored_with=("isam2", "batch"))
    choices = {"method2": _choose(runs, "method2", stems), "isam2": graph, "batch": graph}
    result: dict[str, Any] = {"trials": {}, "excluded": {}, "scored_fraction": {}, "runtime_s": {m: 0.0 for m in METHODS}}
    valid_rms: dict[str, list[FloatArray]] = {m: [] for m in METHODS}
    total_s = 0.0
    for stem in stems:
        run = runs[stem]
        per = {**run.methods, **{m: run.grids[m][choices[m][0][stem]] for m in TUNED_METHODS}}
        result["trials"][stem] = {m: {"rms_deg": _rms_json(per[m].rms_deg)} for m in METHODS}
        result["scored_fraction"][stem] = run.scored_fraction
        total_s += run.duration_s
        for m in METHODS:
            result["runtime_s"][m] += per[m].runtime_s
        reasons = [per[m].invalid for m in METHODS if per[m].invalid]
        if reasons:
            result["excluded"][stem] = "; ".join(str(r) for r in reasons)
            continue
        for m in METHODS:
            valid_rms[m].append(per[m].rms_deg)
    result["mean"] = {m: {"rms_deg": _rms_json(np.mean(valid_rms[m], axis=0) if valid_rms[m] else np.full(3, np.nan))} for m in METHODS}
    result["mean_trials"] = [s for s in stems if s not in result["excluded"]]
    # the methods that are valid everywhere, over every trial (what the exclusions leave out of the mean)
    everywhere = [m for m in METHODS if all(result["trials"][s][m]["rms_deg"]["azimuth"] is not None for s in stems)]
    result["mean_all_trials"] = {
        m: {"rms_deg": _rms_json(np.mean([list(result["trials"][s][m]["rms_deg"].values()) for s in stems], axis=0))} for m in everywhere
    }
    result["x_realtime"] = {m: total_s / max(result["runtime_s"][m], 1e-9) for m in METHODS}
    result["gyro_delay_ms"] = {stem: {"delay": 1e3 * d[0], "sigma": 1e3 * d[1]} for stem in stems if (d := runs[stem].gyro_delay_s) is not None}
    result["tuning"] = {m: {"rule": "leave-one-trial-out: for each trial, the grid point with the lowest mean of the azimuth/elevation/"
                                "roll RMS (deg) on the other ones (Method II: over the trials where every grid point stayed inside the "
                                "Euler domain, the rest get the best on all of those; the graph's one gyro declaration: the mean of "
                                "iSAM2's and batch's, a failed run counting as 1000 deg)", **choices[m][1]} for m in TUNED_METHODS}
    failed = {stem: [r.invalid for m in ("isam2", "batch") for r in runs[stem].grids[m].values() if r.invalid] for stem in stems}
    result["tuning"]["failed_grid_points"] = {stem: reasons for stem, reasons in failed.items() if reasons}
    result["tuning"]["method2"]["tracker_sigma_rad"] = HeadEkfConfig().tracker_sigma_rad
    result["paper_values"] = ekf_setting_name((1.0, HeadEkfConfig().gyro_sigma_rad_s))
    result["chosen_setting"] = {stem: {"ekf": dict(zip(("process_scale", "gyro_sigma_rad_s"), _point(choices["method2"][0][stem]), strict=True)),
                                       "gyro": dict(zip(("noise_sigma_rad_s", "bias_rw_sigma"), _point(choices["isam2"][0][stem]), strict=True))}
                                for stem in stems}
    result["scoring"] = (
        f"RMS of ZYX Euler-angle errors against the optical attitude at the gyro rate, over samples in movement with "
        f"|reference elevation| < {EULER_DOMAIN_DEG:g} deg, after the first second"
    )
    return result


LABELS = {"tracker": "tracker", "method2": "Method II", "method2_paper_values": "Method II, paper's noise", "isam2": "iSAM2", "batch": "batch"}


def _ratio_text(result: dict[str, Any], method: str, key: str = "mean") -> str:
    ref = result[key].get("method2", {}).get("rms_deg")
    own = result[key].get(method, {}).get("rms_deg")
    if not ref or not own or any(v is None for v in (*ref.values(), *own.values())):
        return "-"
    return "/".join(f"{own[a] / ref[a]:.2f}" for a in AXES)


def format_head_recorded(result: dict[str, Any]) -> str:
    """The bench as text: per trial and method the RMS per axis, the means, the ratios to Method II, exclusions."""

    def cells(rms: dict[str, float | None]) -> str:
        return " ".join(f"{v:8.3f}" if v is not None else f"{'-':>8}" for v in rms.values())

    width = max(len(v) for v in LABELS.values())
    lines = [
        "head tracking on recorded motion (BROAD trials: recorded gyro, optical attitude as a 50 Hz tracker 100 ms late)",
        result["scoring"],
        f"{'trial / method':<{width + 4}} {'azimuth':>8} {'elev.':>8} {'roll':>8}  [deg]   ratio to Method II (az/el/roll)",
    ]
    for stem, methods in result["trials"].items():
        lines.append(f"{stem}  (scored {100 * result['scored_fraction'][stem]:.0f} % of the movement)")
        for m, row in methods.items():
            lines.append(f"    {LABELS[m]:<{width}} {cells(row['rms_deg'])}")
    kept = ", ".join(s.split("_")[0] for s in result["mean_trials"])
    lines.append(f"mean over the {len(result['mean_trials'])} trials where every method is valid ({kept}):")
    for m, row in result["mean"].items():
        lines.append(f"    {LABELS[m]:<{width}} {cells(row['rms_deg'])}   {_ratio_text(result, m)}")
    lines.append(f"mean over all {len(result['trials'])} trials, methods valid on every trial:")
    for m, row in result["mean_all_trials"].items():
        lines.append(f"    {LABELS[m]:<{width}} {cells(row['rms_deg'])}")
    if result["excluded"]:
        lines.append("excluded from the mean:")
        lines += [f"    {stem}: {reason}" for stem, reason in result["excluded"].items()]
    lines.append(f"settings chosen by leave-one-trial-out ({result['tuning']['method2']['rule']}):")
    for m in TUNED_METHODS:
        tuning = result["tuning"][m]
        trials = ", ".join(t.split("_")[0] for t in tuning["tuning_trials"])
        lines.append(f"    {LABELS[m]:<{width}} on trials {trials}: in-sample best {tuning['in_sample_best']} ({tuning['in_sample_deg']:.3f} deg), "
                     f"leave-one-trial-out {tuning['cross_validated_deg']:.3f} deg")
    lines.append(f"    Method II, paper's noise: {result['paper_values']}")
    for stem, failures in result["tuning"]["failed_grid_points"].items():
        lines.append(f"    grid points that failed on {stem}: " + "; ".join(failures))
    if result.get("gyro_delay_ms"):
        lines.append("gyro delay found from the gyro and the tracker (declared to every method), ms: "
                     + ", ".join(f"{s.split('_')[0]} {d['delay']:.2f} +- {d['sigma']:.2f}" for s, d in result["gyro_delay_ms"].items()))
    lines.append("speed, x real time: " + ", ".join(f"{LABELS[m]} {x:.0f}" for m, x in result["x_realtime"].items()))
    return "\n".join(lines)


def plot_head_recorded(result: dict[str, Any], path: str | Path) -> Path:
    """Bars of the RMS per axis, trial and method (log scale), excluded figures left out, as a PNG."""
    import matplotlib.pyplot as plt

    from ..report.plots import grouped_bars, save_figure

    trials = list(result["trials"])
    labels = [t.split("_", 1)[0] for t in trials] + ["mean"]
    fig, axes = plt.subplots(3, 1, figsize=(max(8, 0.9 * len(trials) + 2), 8), sharex=True)
    for ax, axis in zip(axes, AXES, strict=True):
        series = {LABELS[m]: [result["trials"][t][m]["rms_deg"][axis] for t in trials] + [result["mean"][m]["rms_deg"][axis]] for m in METHODS}
        grouped_bars(ax, labels, series)
        ax.set_ylabel(f"{axis} RMS (deg)")
        ax.set_yscale("log")
    axes[0].legend(ncol=len(METHODS), fontsize=7)
    fig.suptitle("head tracking on recorded BROAD motion: error per trial (missing bar: excluded)")
    return save_figure(fig, path)
