"""``fusegraph bench gait``: steps, stride length and walking speed from a lower-back IMU against a reference system's
walking bouts (Mobilise-D's INDIP, ``import mobgap``), for fusegraph's walking front end, the walking paper's speed
regression and the ``mobgap`` package's own Mobilise-D pipeline, all scored by the same code.

Scoring, per reference bout: the method's steps inside the bout's span (widened by the matching tolerance at both
ends, so its first and last contacts can be matched) are matched one-to-one to the bout's reference initial contacts
within ``MATCH_S`` (the assignment of least total time difference); F1 over every bout's matches, a bout with no
detection counting all its contacts as missed. Stride length and walking speed: the mean of the method's per-stride
values whose time falls inside the bout, against the bout's reference mean; mean absolute error over the bouts that
got a value (their number beside). Trials without reference bouts are listed, not scored.

Rows:

* ``fusegraph``: the walking preset's front end (``pdr.detect_cycles`` with ``systems.walking.WAIST``): a step per
  cycle; step length from the inverted pendulum (``frontends.gait.step_lengths``) with the person's sensor height
  as the leg, a stride as two consecutive steps, speed = stride length / stride time. The pendulum's drift removal
  and correction are chosen from ``frontends.gait.PENDULUM_GRID`` by leave-one-participant-out (the held-out
  participant's rows use settings chosen on the others; the in-sample choice printed beside); a folder of one
  participant is scored with the settings on main (``PendulumConfig()``).
* ``paper_speed``: the walking paper's speed regression on the vertical peak-to-peak acceleration (``pdr.SpeedModel``)
  UNCALIBRATED: its per-person fit needs a calibration walk at known speeds, and these recordings have none outside the
  reference (which never calibrates); the model's default figures serve, stride length = speed x stride time.
* ``mobgap``: ``mobgap.pipeline.MobilisedPipelineHealthy`` run on mobgap's own reading of the same files (its documented
  use): its raw initial contacts and its per-stride lengths and speeds.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..frontends.gait import PENDULUM_GRID, PendulumConfig, step_lengths
from ..session import Session, SessionError

MATCH_S = 0.25
"""A detected step matches a reference initial contact within this, seconds (the issue's rule)."""

METHODS = ("fusegraph", "paper_speed", "mobgap")
"""Rows, in order."""


@dataclass(frozen=True)
class GaitEstimate:
    """One method's steps and strides on one recording."""

    steps_s: np.ndarray
    """Time of each detected step (initial contact), s."""
    stride_t_s: np.ndarray
    """Time each stride value belongs to (its first contact), s."""
    stride_length_m: np.ndarray
    """Stride length per stride, m."""
    walking_speed_m_s: np.ndarray
    """Walking speed per stride, m/s."""


@dataclass(frozen=True)
class Reference:
    """A recording's reference bouts."""

    bouts_s: np.ndarray
    """(start, end) per bout, s."""
    stride_length_m: np.ndarray
    """Each bout's mean stride length, m."""
    walking_speed_m_s: np.ndarray
    """Each bout's mean walking speed, m/s."""
    contacts_s: np.ndarray
    """Every reference initial contact, s."""


def reference_of(session: Session) -> Reference:
    """The reference a ``import mobgap`` session carries in ``[truth_extra]``."""
    extra = session.meta.get("truth_extra", {})
    if "bouts_s" not in extra:
        raise SessionError(f"{session.where}: no [truth_extra] bouts_s (bench gait needs a reference system's bouts: fusegraph import mobgap DIR)")
    return Reference(np.array(extra["bouts_s"], dtype=float).reshape(-1, 2), np.array(extra.get("bout_stride_length_m", []), dtype=float),
                     np.array(extra.get("bout_walking_speed_m_s", []), dtype=float), np.array(extra.get("initial_contacts_s", []), dtype=float))


@dataclass(frozen=True)
class Prepared:
    """What the front end gives once per recording: the steps, the vertical acceleration and the leg."""

    t: np.ndarray
    """Sample times, s."""
    vertical_m_s2: np.ndarray
    """Vertical acceleration, gravity removed (``pdr.vertical_horizontal``)."""
    steps_s: np.ndarray
    """The walking preset's cycles' times, s."""
    leg_m: float
    """The person's sensor height, m."""
    paper: GaitEstimate
    """The paper's speed regression's strides."""


def front_end(session: Session) -> Prepared:
    """The walking preset's cycles on one session (``pdr.detect_cycles`` with ``systems.walking.WAIST``), and the paper's
    speed regression on them."""
    from ..frontends.pdr import SpeedModel, detect_cycles, gravity_filter, vertical_horizontal
    from ..systems.walking import WAIST

    accel, gyro = session.stream("accel"), session.stream("gyro")
    t = accel.t
    gravity = gravity_filter(t, accel.values, gyro.values, WAIST)
    cycles = detect_cycles(t, accel.values, gyro.values, WAIST, gravity=gravity)
    steps = np.array([c.t for c in cycles])
    leg_m = session.meta.get("person", {}).get("sensor_height_m")
    if leg_m is None:
        raise SessionError(f"{session.where}: [person] sensor_height_m missing (the inverted pendulum's leg length)")
    vertical, _ = vertical_horizontal(accel.values, gravity)
    model = SpeedModel()
    speed = np.array([model.speed(c.vertical_pp_m_s2) for c in cycles])
    period = np.array([c.period_s for c in cycles])
    return Prepared(t, vertical, steps, float(leg_m), GaitEstimate(steps, steps, speed * 2.0 * period, speed))


def pendulum(prepared: Prepared, config: PendulumConfig) -> GaitEstimate:
    """fusegraph's strides: the inverted pendulum's step lengths (``frontends.gait``), two steps a stride."""
    return _strides(prepared.steps_s, step_lengths(prepared.t, prepared.vertical_m_s2, prepared.steps_s, prepared.leg_m, config))


def _strides(steps_s: np.ndarray, step_m: np.ndarray) -> GaitEstimate:
    """Strides as two consecutive steps inside one bout (at most 2.4 s: two of the longest steps)."""
    if len(steps_s) < 3:
        return GaitEstimate(steps_s, np.zeros(0), np.zeros(0), np.zeros(0))
    duration = steps_s[2:] - steps_s[:-2]
    length = step_m[:-2] + step_m[1:-1]
    keep = (duration <= 2.4) & np.isfinite(length)
    return GaitEstimate(steps_s, steps_s[:-2][keep], length[keep], length[keep] / duration[keep])


def mobgap_estimates(directory: str | Path) -> dict[str, GaitEstimate]:
    """mobgap's healthy pipeline on every trial of the folder, through mobgap's own reader, by trial name."""
    from ..datasets.mobgap_lab import mobgap_dataset, trial_name

    out = {}
    with warnings.catch_warnings():  # mobgap warns about its pickled models and its cache
        warnings.simplefilter("ignore")
        from mobgap.pipeline import MobilisedPipelineHealthy

        for datapoint in mobgap_dataset(directory):
            fs = float(datapoint.sampling_rate_hz)
            run = MobilisedPipelineHealthy().safe_run(datapoint)
            ics = run.raw_ic_list_["ic"].to_numpy(dtype=float) / fs if len(run.raw_ic_list_) else np.zeros(0)
            strides = run.per_stride_parameters_
            if len(strides):
                out[trial_name(datapoint)] = GaitEstimate(np.sort(ics), strides["start"].to_numpy(dtype=float) / fs,
                                                          strides["stride_length_m"].to_numpy(dtype=float),
                                                          strides["walking_speed_mps"].to_numpy(dtype=float))
            else:
                out[trial_name(datapoint)] = GaitEstimate(np.sort(ics), np.zeros(0), np.zeros(0), np.zeros(0))
    return out


def score_recording(estimate: GaitEstimate, reference: Reference) -> dict[str, Any]:
    """Matches and per-bout errors of one method on one recording (see the module docstring)."""
    tp = fp = fn = 0
    length_errors, speed_errors = [], []
    for n, (start, end) in enumerate(reference.bouts_s):
        truth = reference.contacts_s[(reference.contacts_s >= start - 1e-6) & (reference.contacts_s <= end + 1e-6)]
        found = estimate.steps_s[(estimate.steps_s >= start - MATCH_S) & (estimate.steps_s <= end + MATCH_S)]
        matched = 0
        if len(truth) and len(found):
            cost = np.abs(found[:, None] - truth[None, :])
            rows, cols = linear_sum_assignment(np.where(cost <= MATCH_S, cost, 1e6))
            matched = int(np.sum(cost[rows, cols] <= MATCH_S))
        tp += matched
        fp += len(found) - matched
        fn += len(truth) - matched
        inside = (estimate.stride_t_s >= start) & (estimate.stride_t_s <= end)
        if inside.any() and n < len(reference.stride_length_m) and np.isfinite(reference.stride_length_m[n]):
            length_errors.append(abs(float(np.mean(estimate.stride_length_m[inside])) - reference.stride_length_m[n]))
        if inside.any() and n < len(reference.walking_speed_m_s) and np.isfinite(reference.walking_speed_m_s[n]):
            speed_errors.append(abs(float(np.mean(estimate.walking_speed_m_s[inside])) - reference.walking_speed_m_s[n]))
    return {"tp": tp, "fp": fp, "fn": fn, "stride_length_errors_m": length_errors, "walking_speed_errors_m_s": speed_errors,
            "bouts": len(reference.bouts_s)}


def _summary(rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    tp, fp, fn = (sum(r[k] for r in rows) for k in ("tp", "fp", "fn"))
    lengths = [e for r in rows for e in r["stride_length_errors_m"]]
    speeds = [e for r in rows for e in r["walking_speed_errors_m_s"]]
    return {"step_f1": 2 * tp / (2 * tp + fp + fn) if tp + fp + fn else None,
            "step_precision": tp / (tp + fp) if tp + fp else None, "step_recall": tp / (tp + fn) if tp + fn else None,
            "stride_length_mae_m": float(np.mean(lengths)) if lengths else None, "walking_speed_mae_m_s": float(np.mean(speeds)) if speeds else None,
            "bouts_scored": len(lengths), "bouts": sum(r["bouts"] for r in rows)}


def bench_gait(directory: str | Path | None = None, with_mobgap: bool = True, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The JSON of ``fusegraph bench gait``: ``directory`` is a Mobilise-D folder in mobgap's layout (default
    ../shared/data/mobgap; mobgap's row needs it) or a folder of sessions ``import mobgap`` wrote (no mobgap row)."""
    from ..datasets.mobgap_lab import DEFAULT_DIR, mobgap_sessions
    from .runner import load_sessions

    folder = Path(directory or DEFAULT_DIR)
    raw = bool(list(folder.rglob("data.mat")))
    sessions = mobgap_sessions(folder) if raw else load_sessions([folder])
    peer = mobgap_estimates(folder) if raw and with_mobgap else {}
    per: dict[str, dict[str, dict[str, Any]]] = {m: {} for m in METHODS}
    recordings: dict[str, Any] = {}
    prepared: dict[str, tuple[str, Prepared, Reference]] = {}
    for n, (name, session) in enumerate(sessions):
        reference = reference_of(session)
        if not len(reference.bouts_s):
            recordings[name] = {"scored": False, "reason": "no reference walking bout"}
            continue
        subject = str(session.meta.get("session", {}).get("subject", name))
        prepared[name] = (subject, front_end(session), reference)
        if progress is not None:
            progress(f"{name} ({n + 1}/{len(sessions)})")
    # the pendulum's settings: leave-one-participant-out over PENDULUM_GRID (the settings on main where one participant)
    grid = {config: {name: score_recording(pendulum(prep, config), ref) for name, (_, prep, ref) in prepared.items()} for config in PENDULUM_GRID}
    subjects = sorted({subject for subject, _, _ in prepared.values()})

    def mae(config: PendulumConfig, names: Sequence[str]) -> float:
        value = _summary([grid[config][name] for name in names])["stride_length_mae_m"]
        return float("inf") if value is None else float(value)

    chosen: dict[str, PendulumConfig] = {}
    cross_validated = len(subjects) > 1
    for subject in subjects:
        others = [name for name, (s, _, _) in prepared.items() if s != subject]
        chosen[subject] = min(PENDULUM_GRID, key=lambda c: mae(c, others)) if cross_validated else PendulumConfig()
    in_sample = min(PENDULUM_GRID, key=lambda c: mae(c, list(prepared)))
    for name, (subject, prep, reference) in prepared.items():
        estimates = {"fusegraph": pendulum(prep, chosen[subject]), "paper_speed": prep.paper, **({"mobgap": peer[name]} if name in peer else {})}
        recordings[name] = {"scored": True, "bouts": len(reference.bouts_s), "reference_contacts": len(reference.contacts_s), "methods": {}}
        for method, estimate in estimates.items():
            row = score_recording(estimate, reference)
            per[method][name] = row
            recordings[name]["methods"][method] = _summary([row])
    methods = {m: _summary(list(rows.values())) for m, rows in per.items() if rows}
    if cross_validated:
        methods["fusegraph"]["stride_length_mae_m_in_sample"] = mae(in_sample, list(prepared))
    return {"methods": methods, "recordings": recordings, "match_s": MATCH_S, "cross_validated": cross_validated,
            "pendulum": {"chosen_per_participant": {s: _config_text(c) for s, c in chosen.items()}, "in_sample": _config_text(in_sample),
                         "on_main": _config_text(PendulumConfig())},
            "notes": {"paper_speed": "uncalibrated: the default regression (no calibration walk outside the reference)",
                      "mobgap": "MobilisedPipelineHealthy on mobgap's own reading of the files" if peer else "not run (needs the raw folder)"}}


def _config_text(config: PendulumConfig) -> str:
    return (f"accel_highpass_hz={config.accel_highpass_hz:g} highpass_hz={config.highpass_hz:g} order={config.order} "
            f"correction={config.correction:g}")


def format_gait(result: dict[str, Any]) -> str:
    """The bench as a table."""
    def cell(v: float | None, fmt: str) -> str:
        return format(v, fmt) if v is not None else "-"

    lines = [f"gait against the reference system's bouts (steps matched within {result['match_s']:g} s)",
             f"{'method':<12} {'step F1':>8} {'prec.':>7} {'recall':>7} {'stride MAE m':>13} {'speed MAE m/s':>14} {'bouts':>9}"]
    for name, m in result["methods"].items():
        lines.append(f"{name:<12} {cell(m['step_f1'], '8.3f')} {cell(m['step_precision'], '7.3f')} {cell(m['step_recall'], '7.3f')} "
                     f"{cell(m['stride_length_mae_m'], '13.3f')} {cell(m['walking_speed_mae_m_s'], '14.3f')} {m['bouts_scored']:>4}/{m['bouts']:<4}")
    for name, rec in result["recordings"].items():
        if not rec["scored"]:
            lines.append(f"{name}: not scored ({rec['reason']})")
            continue
        lines.append(f"{name}: {rec['bouts']} bouts, {rec['reference_contacts']} contacts; " + "; ".join(
            f"{m} F1 {cell(r['step_f1'], '.2f')} SL {cell(r['stride_length_mae_m'], '.3f')}" for m, r in rec["methods"].items()))
    pend = result["pendulum"]
    rule = "leave-one-participant-out" if result["cross_validated"] else "the settings on main"
    lines.append(f"fusegraph's pendulum settings, {rule}: " + "; ".join(f"{s}: {c}" for s, c in pend["chosen_per_participant"].items()))
    if result["cross_validated"]:
        lines.append(f"    in-sample best {pend['in_sample']} (stride MAE {result['methods']['fusegraph']['stride_length_mae_m_in_sample']:.3f} m); "
                     f"on main {pend['on_main']}")
    lines += [f"{k}: {v}" for k, v in result["notes"].items()]
    return "\n".join(lines)
