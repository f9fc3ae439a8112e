"""``fusegraph bench gait``: steps, stride length and walking speed from a lower-back IMU against a reference system's
walking bouts (Mobilise-D's INDIP, ``import mobgap``), for fusegraph's walking front end, the walking paper's speed
regression and the ``mobgap`` package's own Mobilise-D pipeline, all scored by the same code.

Scoring, per reference bout: the method's steps inside the bout's span (widened by the matching tolerance at both
ends, so its first and last contacts can be matched) are matched one-to-one to the bout's reference initial contacts
within ``metrics.GAIT_MATCH_S`` (the assignment of least total time difference); F1 over every bout's matches, a bout with no
detection counting all its contacts as missed. Stride length and walking speed: the mean of the method's per-stride
values whose time falls inside the bout, against the bout's reference mean; mean absolute error over the bouts that
got a value (their number beside). Trials without reference bouts are listed, not scored.

Rows:

* ``fusegraph``: ``run --solver gait`` (the walking preset: a step per walking cycle of ``pdr.detect_cycles``, the
  contacts it missed inside a bout inferred, ``frontends.gait.with_missed_steps``; step length from the pelvis's
  vertical excursion by the inverted pendulum, ``frontends.gait``; a stride as two consecutive steps, speed = stride
  length / stride time) on each session. Every setting of it chosen on data is chosen by leave-one-participant-out: the
  step thresholds from ``frontends.gait.STEP_DETECTION_GRID`` by step F1. The step length is chosen on none: it is the
  cited configuration (``frontends.gait.CITED``: Mobilise-D's published settings of Zijlstra & Hof's pendulum). The held-out
  participant's rows are its sessions DECLARING the settings chosen on the others (``[gait]``); the in-sample choice is
  printed beside, and so are the step thresholds as first set by hand with the cited step length. A
  folder of one participant is scored with the settings on main (``Setting()``).
* ``paper_speed``: the walking paper's speed regression on the vertical peak-to-peak acceleration (``pdr.SpeedModel``)
  UNCALIBRATED: its per-person fit needs a calibration walk at known speeds, and these recordings have none outside the
  reference (which never calibrates); the model's default figures serve, stride length = speed x stride time.
* ``mobgap``: ``mobgap.pipeline.MobilisedPipelineUniversal`` run on mobgap's own reading of the same files (its documented
  use): the package's own choice of its healthy pipeline (cohorts HA, COPD, CHF) or its impaired one (PD, MS, PFF) from the
  participant's cohort; its raw initial contacts and its per-stride lengths and speeds. The pipeline used per trial is
  printed (JSON ``mobgap_pipeline``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..frontends.gait import CITED, HAND_SET_DETECTION, STEP_DETECTION_GRID, StepDetection, StepLengthConfig
from ..metrics import GAIT_MATCH_S, GaitReference, gait_counts, gait_scores
from ..session import Session, SessionError
from .runner import solve_session

METHODS = ("fusegraph", "paper_speed", "mobgap")
"""Rows, in order."""

SLOW_GAIT_M_S = 0.8
"""A reference bout slower than this, m/s, is slow walking in ``by_speed``: the cut-off for low gait speed of the European
consensus on sarcopenia (EWGSOP2: Cruz-Jentoft et al., Age and Ageing 48(1):16-31, 2019), the pace of the cohorts other
than healthy adults in Mobilise-D."""


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


def reference_of(session: Session) -> GaitReference:
    """The reference a ``import mobgap`` session carries in ``[truth_extra]``."""
    reference = GaitReference.from_truth_extra(session.meta.get("truth_extra", {}))
    if reference is None:
        raise SessionError(f"{session.where}: no [truth_extra] bouts_s (bench gait needs a reference system's bouts: fusegraph import mobgap DIR)")
    return reference


def paper_speed(session: Session) -> GaitEstimate:
    """The walking paper's speed regression (``pdr.SpeedModel``, uncalibrated) on the walking preset's cycles
    (``pdr.detect_cycles`` with ``systems.walking.WAIST``, its step thresholds as set by hand, ``HAND_SET_DETECTION``: the
    walking front end's are chosen on these participants): a step per cycle, speed x two cycle times a stride."""
    from ..frontends.pdr import SpeedModel, detect_cycles
    from ..systems.walking import WAIST

    accel, gyro = session.synchronous("accel", "gyro")
    cycles = detect_cycles(accel.t, accel.values, gyro.values, HAND_SET_DETECTION.front_end(WAIST))
    steps = np.array([c.t for c in cycles])
    speed = np.array([SpeedModel().speed(c.vertical_pp_m_s2) for c in cycles])
    return GaitEstimate(steps, steps, speed * 2.0 * np.array([c.period_s for c in cycles]), speed)


@dataclass(frozen=True)
class Setting:
    """What ``bench gait`` chooses for ``--solver gait`` by leave-one-participant-out."""

    detection: StepDetection = StepDetection()
    """The step thresholds (chosen first, by step F1)."""
    length: StepLengthConfig = CITED
    """The step-length model and its scale (``CITED``, chosen on no recording; a session may declare another)."""

    def text(self) -> str:
        """As the JSON and the table print it (``setting_of_text`` reads it back)."""
        d, c = self.detection, self.length
        return (f"peak_threshold_m_s2={d.peak_threshold_m_s2:g} forward_slope_m_s3={d.forward_slope_m_s3:g} model={c.model} "
                f"accel_highpass_hz={c.accel_highpass_hz:g} highpass_hz={c.highpass_hz:g} order={c.order} correction={c.correction:g}")


def declare(session: Session, config: StepLengthConfig, detection: StepDetection | None = None) -> Session:
    """The session declaring the settings ``--solver gait`` reads: the step length's (``[gait] model, highpass_hz,
    correction``) and the step thresholds (``[gait] peak_threshold_m_s2, forward_slope_m_s3``; default ``StepDetection()``)."""
    detection = detection or StepDetection()
    return session.with_meta(gait={"model": config.model, "highpass_hz": config.highpass_hz, "correction": config.correction,
                                   "peak_threshold_m_s2": detection.peak_threshold_m_s2, "forward_slope_m_s3": detection.forward_slope_m_s3})


def fusegraph_counts(session: Session) -> dict[str, Any]:
    """``run --solver gait`` on the session (``runner.solve_session``), its raw counts (``metrics.gait_counts``)."""
    outcome = solve_session(session, "gait")
    if not outcome.metrics:
        raise SessionError(f"{session.where}: no reference bouts to score ([truth_extra] bouts_s)")
    return dict(outcome.metrics["counts"])


@dataclass(frozen=True)
class _Searched:
    """One recording as the settings' search reads it: ``--solver gait``'s computation with the gravity filter run once
    (it reads none of the settings searched); the rows a table prints are ``fusegraph_counts``, the solver's own run
    (a test holds the two equal)."""

    t: np.ndarray
    accel_m_s2: np.ndarray
    gyro_rad_s: np.ndarray
    leg_m: float
    gravity: np.ndarray

    @classmethod
    def of(cls, session: Session) -> _Searched:
        from ..frontends.pdr import gravity_filter
        from ..systems.walking import WAIST

        leg = session.meta.get("person", {}).get("sensor_height_m")
        if leg is None:
            fusegraph_counts(session)  # the solver's own error: it needs the sensor's height
        accel, gyro = session.synchronous("accel", "gyro")
        return cls(accel.t, accel.values, gyro.values, float(leg), gravity_filter(accel.t, accel.values, gyro.values, WAIST))

    def counts(self, setting: Setting, reference: GaitReference) -> dict[str, Any]:
        """``fusegraph_counts`` of the session declaring ``setting``."""
        from ..frontends.gait import waist_gait
        from ..systems.walking import WAIST

        steps, _, stride_t, length, speed = waist_gait(self.t, self.accel_m_s2, self.gyro_rad_s, self.leg_m, setting.detection.front_end(WAIST),
                                                       setting.length, self.gravity)
        return score_recording(GaitEstimate(steps, stride_t, length, speed), reference)


def mobgap_estimates(directory: str | Path) -> tuple[dict[str, GaitEstimate], dict[str, str]]:
    """mobgap's universal pipeline (its healthy or impaired one by the participant's cohort) on every trial of the folder,
    through mobgap's own reader: the estimates and the pipeline used, by trial name. A trial the pipeline fails on has
    no estimate (its row leaves the trial out) and ``failed: <the error>`` as its pipeline, which the bench prints."""
    from ..datasets.mobgap_lab import mobgap_dataset, trial_name

    out, used = {}, {}
    with warnings.catch_warnings():  # mobgap warns about its pickled models and its cache
        warnings.simplefilter("ignore")
        from mobgap.pipeline import MobilisedPipelineUniversal

        for datapoint in mobgap_dataset(directory):
            fs = float(datapoint.sampling_rate_hz)
            try:
                universal = MobilisedPipelineUniversal().safe_run(datapoint)
            except Exception as error:  # the peer's own failure on one trial: said, not fatal to the bench
                used[trial_name(datapoint)] = f"failed: {type(error).__name__}: {error}"
                continue
            run, used[trial_name(datapoint)] = universal.pipeline_, str(universal.pipeline_name_)
            ics = run.raw_ic_list_["ic"].to_numpy(dtype=float) / fs if len(run.raw_ic_list_) else np.zeros(0)
            ics = ics[np.isfinite(ics)]  # a contact without a time is none (the matching's costs must be finite)
            strides = run.per_stride_parameters_
            if len(strides):
                out[trial_name(datapoint)] = GaitEstimate(np.sort(ics), strides["start"].to_numpy(dtype=float) / fs,
                                                          strides["stride_length_m"].to_numpy(dtype=float),
                                                          strides["walking_speed_mps"].to_numpy(dtype=float))
            else:
                out[trial_name(datapoint)] = GaitEstimate(np.sort(ics), np.zeros(0), np.zeros(0), np.zeros(0))
    return out, used


def score_recording(estimate: GaitEstimate, reference: GaitReference) -> dict[str, Any]:
    """A method's raw counts on one recording (``metrics.gait_counts``)."""
    return gait_counts(estimate.steps_s, estimate.stride_t_s, estimate.stride_length_m, estimate.walking_speed_m_s, reference)


def bench_gait(directory: str | Path | None = None, with_mobgap: bool = True, progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The JSON of ``fusegraph bench gait``: ``directory`` is a Mobilise-D folder in mobgap's layout (default
    ../shared/data/mobgap; mobgap's row needs it) or a folder of sessions ``import mobgap`` wrote (no mobgap row)."""
    from ..datasets.mobgap_lab import DEFAULT_DIR, data_files, mobgap_sessions
    from .runner import load_sessions

    folder = Path(directory or DEFAULT_DIR)
    raw = bool(data_files(folder))
    sessions = mobgap_sessions(folder) if raw else load_sessions([folder])
    peer, pipelines = mobgap_estimates(folder) if raw and with_mobgap else ({}, {})
    per: dict[str, dict[str, dict[str, Any]]] = {m: {} for m in METHODS}
    recordings: dict[str, Any] = {}
    scored: dict[str, tuple[str, Session, GaitReference]] = {}
    for name, session in sessions:
        reference = reference_of(session)
        if not len(reference.bouts_s):
            recordings[name] = {"scored": False, "reason": "no reference walking bout"}
            continue
        scored[name] = (str(session.meta.get("session", {}).get("subject", name)), session, reference)
    subjects = sorted({subject for subject, _, _ in scored.values()})
    cross_validated = len(subjects) > 1
    folds = {subject: [name for name, (s, _, _) in scored.items() if s != subject] for subject in subjects}
    everyone = list(scored)
    # the step thresholds, leave-one-participant-out by step F1, each grid point the sessions declaring it; the step length cited
    counted: dict[Setting, dict[str, dict[str, Any]]] = {}
    searched = {name: _Searched.of(session) for name, (_, session, _) in scored.items()}

    def counts(setting: Setting) -> dict[str, dict[str, Any]]:
        if setting not in counted:
            counted[setting] = {name: searched[name].counts(setting, reference) for name, (_, _, reference) in scored.items()}
        return counted[setting]

    def f1(detection: StepDetection, names: Sequence[str]) -> float:
        value = gait_scores([counts(Setting(detection))[name] for name in names])["step_f1"]
        return -1.0 if value is None else float(value)

    def mae(setting: Setting, names: Sequence[str]) -> float:
        value = gait_scores([counts(setting)[name] for name in names])["stride_length_mae_m"]
        return float("inf") if value is None else float(value)

    def choose(names: Sequence[str], what: str, detection: StepDetection | None = None) -> Setting:
        """The setting chosen on ``names``: the thresholds by step F1 (or ``detection`` as given), the cited step length."""
        if progress is not None:
            progress(f"{what}: step thresholds {'chosen' if detection is None else 'given'}")
        return Setting(detection or max(STEP_DETECTION_GRID, key=lambda d: f1(d, names)))  # the step length: Setting's default, CITED

    if progress is not None:
        progress(f"step-threshold grid ({len(STEP_DETECTION_GRID)} points) on {len(scored)} recordings")
    chosen = {subject: choose(others, f"without {subject}") if cross_validated else Setting() for subject, others in folds.items()}
    in_sample = choose(everyone, "in-sample") if cross_validated else Setting()
    # beside it, the thresholds as the walking front end sets them by hand (no rule chose them), the step length cited
    hand_set = {subject: choose(others, f"hand-set thresholds, without {subject}", HAND_SET_DETECTION) if cross_validated
                else Setting(HAND_SET_DETECTION) for subject, others in folds.items()}
    for name, (subject, session, reference) in scored.items():
        # fusegraph: run --solver gait on the session declaring the setting chosen without its participant
        rows = {"fusegraph": fusegraph_counts(declare(session, chosen[subject].length, chosen[subject].detection)),
                "paper_speed": score_recording(paper_speed(session), reference),
                **({"mobgap": score_recording(peer[name], reference)} if name in peer else {})}
        recordings[name] = {"scored": True, "bouts": len(reference.bouts_s), "reference_contacts": len(reference.contacts_s),
                            "methods": {m: gait_scores([row]) for m, row in rows.items()},
                            "per_bout": _per_bout(reference, rows)}
        for method, row in rows.items():
            per[method][name] = row
    methods = {m: gait_scores(list(rows.values())) for m, rows in per.items() if rows}
    # each method's stride-length MAE over the bouts EVERY method scored: a method that leaves a hard bout without
    # strides is not scored on it, so the headline MAEs can be over different bouts
    errors = {m: {(name, b): e for name, row in rows.items() for b, e in zip(row["stride_length_bouts"], row["stride_length_errors_m"], strict=True)}
              for m, rows in per.items() if rows}
    common = set.intersection(*(set(e) for e in errors.values())) if errors else set()
    for m, e in errors.items():
        methods[m]["stride_length_mae_common_m"] = float(np.mean([e[k] for k in common])) if common else None
        methods[m]["bouts_common"] = len(common)
    hand_rows = [counts(hand_set[subject])[name] for name, (subject, _, _) in scored.items()]
    methods["fusegraph"]["hand_set_thresholds"] = {k: gait_scores(hand_rows)[k] for k in ("step_f1", "stride_length_mae_m", "walking_speed_mae_m_s")}
    if cross_validated:
        methods["fusegraph"]["stride_length_mae_m_in_sample"] = mae(in_sample, everyone)
        methods["fusegraph"]["step_f1_in_sample"] = f1(in_sample.detection, everyone)
    by_speed = {m: steps_by_speed([(scored[name][2], row) for name, row in rows.items()]) for m, rows in per.items() if rows}
    return {"methods": methods, "by_speed": by_speed, "recordings": recordings, "match_s": GAIT_MATCH_S, "cross_validated": cross_validated,
            "step_length": {"chosen_per_participant": {s: c.text() for s, c in chosen.items()}, "in_sample": in_sample.text(),
                            "on_main": Setting().text(), "hand_set_thresholds": {s: c.text() for s, c in hand_set.items()}},
            "notes": {"paper_speed": "uncalibrated: the default regression (no calibration walk outside the reference)",
                      "mobgap": (f"MobilisedPipelineUniversal on mobgap's own reading of the files ({_pipelines_text(pipelines)})"
                                 if peer else "not run (needs the raw folder)")},
            "mobgap_pipeline": pipelines}


def _pipelines_text(used: dict[str, str]) -> str:
    """Which of mobgap's pipelines ran on how many trials, e.g. ``healthy on 6 trials``."""
    from collections import Counter

    ran = Counter(v for v in used.values() if not v.startswith("failed"))
    failed = [f"{trial} {why}" for trial, why in used.items() if why.startswith("failed")]
    return ", ".join([f"{name} on {n} trial{'s' if n != 1 else ''}" for name, n in sorted(ran.items())] + failed)


def _per_bout(reference: GaitReference, rows: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Each reference bout's mean stride length and speed beside each method's (None where it gave no stride)."""
    out = []
    for n in range(len(reference.bouts_s)):
        bout: dict[str, Any] = {"reference": {"stride_length_m": float(reference.stride_length_m[n]) if n < len(reference.stride_length_m) else None,
                                              "walking_speed_m_s": float(reference.walking_speed_m_s[n]) if n < len(reference.walking_speed_m_s) else None}}
        for m, row in rows.items():
            lengths = dict(zip(row["stride_length_bouts"], row["stride_length_m"], strict=True))
            speeds = dict(zip(row["walking_speed_bouts"], row["walking_speed_m_s"], strict=True))
            bout[m] = {"stride_length_m": lengths.get(n), "walking_speed_m_s": speeds.get(n)}
        out.append(bout)
    return out


def steps_by_speed(recordings: Sequence[tuple[GaitReference, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """One method's steps pooled over the reference bouts slower than ``SLOW_GAIT_M_S`` (``slow``) and the others
    (``not_slow``), each band by the reference's own mean speed of the bout (a bout without one is in neither): step F1,
    precision, recall, the bouts and the reference contacts in the band."""
    # each band as one recording's counts (no stride errors), which gait_scores turns into F1, precision and recall
    pooled: dict[str, dict[str, Any]] = {band: {"tp": 0, "fp": 0, "fn": 0, "bouts": 0, "stride_length_errors_m": [], "walking_speed_errors_m_s": []}
                                         for band in ("slow", "not_slow")}
    for reference, row in recordings:
        for n, (matched, extra, missed) in enumerate(row["bout_steps"]):
            speed = float(reference.walking_speed_m_s[n]) if n < len(reference.walking_speed_m_s) else float("nan")
            if not np.isfinite(speed):
                continue
            counts = pooled["slow" if speed < SLOW_GAIT_M_S else "not_slow"]
            counts["tp"] += matched
            counts["fp"] += extra
            counts["fn"] += missed
            counts["bouts"] += 1
    out = {}
    for band, counts in pooled.items():
        scores = gait_scores([counts])
        out[band] = {k: scores[k] for k in ("step_f1", "step_precision", "step_recall")} | {"bouts": counts["bouts"], "contacts": counts["tp"] + counts["fn"]}
    return out


def plot_gait(result: dict[str, Any], path: str | Path) -> Path:
    """``bench gait --plot``: per reference bout, each method's mean stride length and walking speed against the
    reference's (the diagonal: agreement), the methods' MAE in the legend; each method's step F1 on slow and faster bouts
    (``by_speed``). PNG."""
    from ..report.gait import plot_per_bout

    bouts = [b for rec in result["recordings"].values() if rec["scored"] for b in rec["per_bout"]]
    return plot_per_bout(bouts, {m: (v["stride_length_mae_m"], v["walking_speed_mae_m_s"]) for m, v in result["methods"].items()}, path,
                         result.get("by_speed"), SLOW_GAIT_M_S)


def setting_of_text(text: str) -> Setting:
    """The setting a bench's JSON prints (``step_length``: ``peak_threshold_m_s2=... model=... correction=...``)."""
    values = dict(part.split("=", 1) for part in text.split())
    return Setting(StepDetection(float(values["peak_threshold_m_s2"]), float(values["forward_slope_m_s3"])),
                   StepLengthConfig(float(values["accel_highpass_hz"]), float(values["highpass_hz"]), int(values["order"]), float(values["correction"]),
                                    values["model"]))


def format_gait(result: dict[str, Any]) -> str:
    """The bench as a table."""
    def cell(v: float | None, fmt: str) -> str:
        return format(v, fmt) if v is not None else "-"

    lines = [f"gait against the reference system's bouts (steps matched within {result['match_s']:g} s)",
             f"{'method':<12} {'step F1':>8} {'prec.':>7} {'recall':>7} {'stride MAE m':>13} {'speed MAE m/s':>14} {'bouts':>9}"]
    for name, m in result["methods"].items():
        lines.append(f"{name:<12} {cell(m['step_f1'], '8.3f')} {cell(m['step_precision'], '7.3f')} {cell(m['step_recall'], '7.3f')} "
                     f"{cell(m['stride_length_mae_m'], '13.3f')} {cell(m['walking_speed_mae_m_s'], '14.3f')} {m['bouts_scored']:>4}/{m['bouts']:<4}")
    common = {name: m.get("stride_length_mae_common_m") for name, m in result["methods"].items()}
    if all(v is not None for v in common.values()):
        lines.append(f"stride MAE over the {next(iter(result['methods'].values()))['bouts_common']} bouts every method scored: "
                     + ", ".join(f"{name} {v:.3f} m" for name, v in common.items()))
    by_speed = result.get("by_speed", {})
    if by_speed:
        parts = []
        for band, name in (("slow", f"under {SLOW_GAIT_M_S:g} m/s"), ("not_slow", f"{SLOW_GAIT_M_S:g} m/s and faster")):
            first = next(iter(by_speed.values()))[band]  # a row that scored fewer bouts (a peer failed on a trial) says so
            parts.append(f"{name} ({first['bouts']} bouts, {first['contacts']} contacts) " + ", ".join(
                f"{m} {cell(v[band]['step_f1'], '.3f')}" + (f" (over {v[band]['bouts']} bouts)" if v[band]["bouts"] != first["bouts"] else "")
                for m, v in by_speed.items()))
        lines.append("step F1 by the reference bout's speed: " + "; ".join(parts))
    for name, rec in result["recordings"].items():
        if not rec["scored"]:
            lines.append(f"{name}: not scored ({rec['reason']})")
            continue
        lines.append(f"{name}: {rec['bouts']} bouts, {rec['reference_contacts']} contacts; " + "; ".join(
            f"{m} F1 {cell(r['step_f1'], '.2f')} SL {cell(r['stride_length_mae_m'], '.3f')}" for m, r in rec["methods"].items()))
    step_length, ours = result["step_length"], result["methods"]["fusegraph"]
    rule = "leave-one-participant-out (the step thresholds by step F1; the step length cited)" if result["cross_validated"] else "the settings on main"
    lines.append(f"fusegraph's settings, {rule}: " + "; ".join(f"{s}: {c}" for s, c in step_length["chosen_per_participant"].items()))
    if result["cross_validated"]:
        lines.append(f"    in-sample best {step_length['in_sample']} (step F1 {ours['step_f1_in_sample']:.3f}, "
                     f"stride MAE {ours['stride_length_mae_m_in_sample']:.3f} m); on main {step_length['on_main']}")
    hand = ours.get("hand_set_thresholds")
    if hand:
        lines.append(f"    with the step thresholds as first set by hand ({HAND_SET_DETECTION.peak_threshold_m_s2:g} m/s^2, "
                     f"{HAND_SET_DETECTION.forward_slope_m_s3:g} m/s^3; no rule chose them) and the step length cited: "
                     f"step F1 {cell(hand['step_f1'], '.3f')}, stride MAE {cell(hand['stride_length_mae_m'], '.3f')} m, "
                     f"speed MAE {cell(hand['walking_speed_mae_m_s'], '.3f')} m/s")
    lines += [f"{k}: {v}" for k, v in result["notes"].items()]
    return "\n".join(lines)
