"""The walking bench: the simulated 3-floor walk, the Oxford step counts and the Plaza range + odometry runs."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from ..datasets import steps_oxford
from ..estimate import PointEstimate
from ..frontends.pdr import Cycle, Ride, front_end
from ..records import ACTIVITIES, WalkingSession
from ..report.walking import plot_gait_statistics, plot_oxford, plot_walk
from ..results import WALK_METHODS as METHODS
from ..results import WalkRun
from ..scenarios.walking import WalkingScenarioConfig, calibrated_speed, session_of_walk, simulate_walking
from ..session import Session
from ..systems.walking import WAIST, analyse
from .activity import STEP_STATISTICS
from .runner import report_sessions, solve_session


def positioning(session: Session) -> tuple[dict[str, dict[str, float]], dict[str, WalkRun]]:
    """Every positioning solver of the walking preset on the session, each through ``solve_session`` as ``fusegraph
    run`` runs it (the steps classified inside the solve, causally for all but batch): per solver its metrics and
    seconds (the whole solve, its front end included; ``solver_seconds`` the graph or filter alone), and its trajectory for
    the picture."""
    rows, runs = {}, {}
    for solver in METHODS:
        outcome = solve_session(session, solver)
        estimate = outcome.estimate
        assert isinstance(estimate, PointEstimate) and outcome.metrics is not None
        runs[solver] = WalkRun(solver, estimate.t, estimate.points[:, 0, :], estimate.runtime_s)
        rows[solver] = {**outcome.metrics, "seconds": estimate.runtime_s, "solver_seconds": float(estimate.extras["solver_s"])}
    return rows, runs


def bench_walking(seed: int = 0, oxford_dir: Path | None = steps_oxford.DEFAULT_DIR, plaza: bool = True, plot: Path | None = None,
                  hapt_dir: Path | None = None) -> dict[str, object]:
    """Everything ``fusegraph bench walking`` prints, in the issue's JSON shape (``gait_statistics``: the pendulum gait's
    per-step statistics beside UCI HAPT's real waists, ``hapt_dir`` or ../shared/data/hapt)."""
    from . import plaza as plaza_system

    # the pendulum gait (checked against real waists): the activity confusion of fusegraph's waist classifier (trained on
    # real waists, frontends.activity), which the walking graph takes (offline for batch, causal for the other methods),
    # with the paper's rules beside; the positioning runs on it (as `simulate walking --gait pendulum` writes the walk and
    # `run` solves it) are the headline, the first generator's beside them.
    pendulum = WalkingScenarioConfig(gait="pendulum")
    independent = simulate_walking(seed, pendulum)
    pendulum_speed = calibrated_speed(seed, pendulum)
    # one front end serves both classifications and the statistics
    gravity, independent_cycles = front = front_end(independent.t, independent.accel_m_s2, independent.gyro_rad_s, WAIST)
    (classified, independent_rides, _), (live, _, _) = (analyse(independent, pendulum_speed, causal=c, front=front) for c in (False, True))
    session = simulate_walking(seed)
    speed = calibrated_speed(seed)
    cycles, rides, _ = analyse(session, speed)
    out: dict[str, object] = {"confusion": confusion(independent, classified, independent_rides),
                              "confusion_causal": confusion(independent, live, independent_rides),
                              "confusion_paper_rules": confusion(independent, independent_cycles, independent_rides),
                              "confusion_signature_gait": confusion(session, cycles, rides),
                              "speed_model": {"intercept_m_s": pendulum_speed.intercept_m_s, "slope_s": pendulum_speed.slope_s}}
    for key, correct in (("walking", False), ("walking_no_wrong_fixes", True)):
        out[key], runs = positioning(session_of_walk(independent, pendulum_speed, seed, correct_fixes=correct))
        if plot is not None and key == "walking":
            plot_walk(independent, runs, plot)
    out["walking_signature_gait"], _ = positioning(session_of_walk(session, speed, seed))
    out["walking_info"] = {"duration_s": float(independent.t[-1]), "steps_true": len(independent.step_t), "cycles_detected": len(classified),
                           "rides_true": len(independent.rides), "rides_detected": len(independent_rides), "fixes": len(independent.fixes.t),
                           "wrong_fixes": int(independent.fixes.wrong.sum())}
    steps = step_rows(hapt_dir=hapt_dir, known={seed: (independent, gravity, independent_cycles)})
    out["gait_statistics"] = gait_statistics(steps)
    if plot is not None:
        plot_gait_statistics(steps, STEP_STATISTICS, plot.with_name(f"{plot.stem}_gait{plot.suffix}"))
    oxford = bench_oxford(Path(oxford_dir)) if oxford_dir is not None and Path(oxford_dir).is_dir() else {}
    out["oxford"] = oxford
    if plot is not None and oxford:
        plot_oxford(oxford, plot.with_name(f"{plot.stem}_oxford{plot.suffix}"))
    if plaza:
        out["plaza"] = plaza_system.bench_plaza()
    return out


def bench_oxford(directory: Path) -> dict[str, dict[str, Any]]:
    """Every Oxford recording imported (as ``import oxford`` writes it) and counted by the walking preset's ``steps``
    solver (``report walking DIR --solvers steps``), its peak threshold chosen by leave-one-recording-out: each
    recording is counted with the threshold of ``pdr.PHONE_PEAK_THRESHOLDS_M_S2`` whose mean absolute count error on the
    OTHER recordings is least (declared as ``[steps] peak_threshold_m_s2``): ``counted`` and ``peak_threshold_m_s2``.
    ``counted_in_sample``: with the threshold chosen on every recording; ``counted_by_peak``: at every threshold. Beside
    them the true count, the insoles' count and where the phone was carried. ``phone``: the phone's own step counter,
    which these recordings do not hold (stepcounter.csv is the foot switches, see datasets.steps_oxford); null rather
    than a guess."""
    from ..datasets.importers import oxford_sessions
    from ..frontends.pdr import PHONE_PEAK_THRESHOLDS_M_S2

    recorded = oxford_sessions(directory)
    true = {name: int(phone.meta["truth_extra"]["steps"]) for name, phone in recorded}
    counted: dict[float, dict[str, int]] = {}
    for peak in PHONE_PEAK_THRESHOLDS_M_S2:
        report = report_sessions("walking", [(name, phone.with_meta(steps={"peak_threshold_m_s2": peak})) for name, phone in recorded], ["steps"],
                                 show_progress=False)
        counted[peak] = {name: int(report["sessions"][name]["steps"]["metrics"]["steps"]) for name, _ in recorded}

    def chosen(names: list[str]) -> float:
        return min(PHONE_PEAK_THRESHOLDS_M_S2, key=lambda peak: float(np.mean([abs(counted[peak][n] - true[n]) / true[n] for n in names])))

    everyone = [name for name, _ in recorded]
    in_sample = chosen(everyone)
    out: dict[str, dict[str, Any]] = {}
    for name, phone in recorded:
        peak = chosen([n for n in everyone if n != name]) if len(everyone) > 1 else in_sample
        extra = phone.meta.get("truth_extra", {})
        out[name] = {"true": true[name], "counted": counted[peak][name], "peak_threshold_m_s2": peak, "counted_in_sample": counted[in_sample][name],
                     "peak_threshold_in_sample_m_s2": in_sample, "counted_by_peak": {str(p): counted[p][name] for p in PHONE_PEAK_THRESHOLDS_M_S2},
                     "phone": None, "foot_switches": extra.get("foot_switch_steps"), "position": str(phone.meta["session"]["placement"])}
    return out


def confusion(session: WalkingSession, cycles: list[Cycle], rides: list[Ride]) -> dict[str, dict[str, int]]:
    """Per true step: the activity of the detected cycle within a quarter second (else none); per true ride: elevator or none."""
    table: dict[str, Counter[str]] = {a: Counter() for a in ACTIVITIES}
    ct = np.array([c.t for c in cycles])
    for ts, activity in zip(session.step_t, session.step_activity, strict=True):
        j = int(np.argmin(np.abs(ct - ts))) if len(ct) else -1
        table[activity][cycles[j].activity if j >= 0 and abs(ct[j] - ts) < 0.25 else "none"] += 1
    for start, end, _ in session.rides:
        hit = any(r.start_s < end and r.end_s > start for r in rides)
        table["elevator"]["elevator" if hit else "none"] += 1
    return {a: dict(c) for a, c in table.items()}


def simulated_step_statistics(walk: WalkingSession, analysed: tuple[np.ndarray, list[Cycle]] | None = None) -> dict[str, np.ndarray]:
    """``evaluation.activity.step_statistics`` of a simulated walk (``analysed``: its gravity and cycles, when known): a
    step's class is that of the true step within a quarter second of its first cycle."""
    from .activity import step_statistics

    return step_statistics(walk.t, walk.accel_m_s2, walk.gyro_rad_s, lambda start, end: walk.activity_at(start), analysed)


def step_rows(seeds: tuple[int, ...] = (0, 1, 2), hapt_dir: Path | None = None,
              known: dict[int, tuple[WalkingSession, np.ndarray, list[Cycle]]] | None = None) -> dict[str, dict[str, np.ndarray]]:
    """Every step's ``evaluation.activity.STEP_STATISTICS`` per class, pooled: ``pendulum_gait`` over ``seeds`` (``known``:
    a seed's pendulum walk, gravity and cycles the caller already has) and ``hapt``, the real waists of UCI HAPT
    (``hapt_dir``, default ../shared/data/hapt, when it is there)."""
    from ..datasets.hapt import DEFAULT_DIR, hapt_sessions
    from .activity import labelled_step_statistics

    def pooled(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        return {a: np.concatenate([p[a] for p in parts]) for a in ("flat", "stairs_up", "stairs_down")}

    known = known or {}
    walks = [simulated_step_statistics(known[s][0], known[s][1:]) if s in known else
             simulated_step_statistics(simulate_walking(s, WalkingScenarioConfig(gait="pendulum"))) for s in seeds]
    result = {"pendulum_gait": pooled(walks)}
    folder = Path(hapt_dir or DEFAULT_DIR)
    if folder.is_dir():
        result["hapt"] = pooled([labelled_step_statistics(session) for _, session in hapt_sessions(folder)])
    return result


def gait_statistics(rows: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, dict[str, float]]]:
    """The medians of ``step_rows`` per source and class (and the number of steps): the check that the simulated gait
    moves like the real one."""
    from .activity import STEP_STATISTICS

    return {source: {a: {"steps": float(len(r)), **{k: float(np.median(r[:, i])) for i, k in enumerate(STEP_STATISTICS)}}
                     for a, r in per_class.items()} for source, per_class in rows.items()}
