"""Activity of each walking cycle from a waist IMU (flat, stairs up, stairs down, or not walking): features of the pelvis's motion over a few
steps and a small boosted-tree classifier trained on real waist recordings.

What tells the activities apart on a real waist (UCI HAPT, users 1-10, medians per step flat / up / down): the vertical
acceleration's strength (RMS 2.0 / 2.4 / 3.4 m/s^2 in 3 s around the step) and its ratio to the horizontal (1.1 / 1.7 /
2.3), the pelvis's vertical excursion (4.7 / 8.6 / 8.9 cm peak to peak, double-integrated), the impacts of stepping down
(skewness 0.38 / 0.38 / 0.71), the forward lean of climbing (gravity's tilt along the travel direction against the
recording's own median), the step time (0.54 / 0.60 / 0.54 s), and the phase of the sagittal rotation against the
vertical acceleration; and what tells walking from not walking beyond those: how far the trunk tilts within the window
(a postural transition turns gravity in the sensor by tens of degrees, walking by a few; ``_tilts``). Differences between
people dominate: each feature also enters as its difference from the recording's median over its cycles (a per-person
reference), which makes the classifier OFFLINE: it needs the whole recording (a live caller would use the median of the
cycles so far). The fit chooses which of them the model reads
(``evaluation.activity.FEATURE_SETS``): HAPT's users each walk at one pace, so an acceleration amplitude above the person's
median there means stairs, but on level ground it also means a faster pace; the model on main reads the amplitudes
absolutely only (``ActivityModel.features``; its provenance says what chose that).

The classifier is a gradient-boosted tree ensemble (scikit-learn's ``GradientBoostingClassifier`` when fitted, in
``evaluation.activity``), exported to plain arrays (``ActivityModel``) and evaluated here in numpy, so the front end
needs no scikit-learn at run time and the model file does not depend on its version. Each cycle's class is the mean of
the log-probabilities over ``context_cycles`` cycles either side within its bout (a bout: cycles less than
``BOUT_GAP_S`` apart), the context of several steps.
"""

from __future__ import annotations

import bisect
import functools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.signal import butter, filtfilt

from ..geometry import FloatArray
from .gait import pelvis_excursion
from .pdr import Cycle, PdrConfig, front_end, vertical_horizontal

GATE_CLASSES = ("walking", "not_walking")
"""The gate's classes (``ActivityModel.gate``)."""

ACTIVITIES = ("flat", "stairs_up", "stairs_down", "not_walking")
"""The classes, in the model's order. Not walking: a cycle the front end found in standing, sitting, lying or getting up or
down (HAPT's labels 4-12): a postural transition moves the pelvis like a step or two, and an elevator or a sway like one."""

BOUT_GAP_S = 1.5
"""Cycles further apart than this are in different bouts (a step takes at most 1.2 s: ``PdrConfig.max_period_s``)."""

WINDOW_S = 3.0
"""Span of signal around each cycle its features are taken over, seconds (about five steps)."""

BASE_FEATURES = (
    "period_s", "vertical_rms", "forward_rms", "lateral_rms", "vertical_over_horizontal", "excursion_pp_m", "excursion_std_m",
    "roll_rate_rms", "pitch_rate_rms", "yaw_rate_rms", "vertical_skew", "vertical_peak_ratio", "vertical_pp", "forward_pp",
    "corr_vertical_forward", "corr_vertical_pitch_rate", "corr_vertical_roll_rate", "vertical_max", "vertical_min",
    "vertical_above_3hz_rms", "vertical_kurtosis", "lean_forward", "lean_lateral", "tilt_change_deg", "tilt_spread_deg",
)
"""One value per cycle each (see ``cycle_features``); the model reads these and their differences from the recording's median."""

FEATURES = BASE_FEATURES + tuple(f"{name}_vs_median" for name in BASE_FEATURES)
"""The model's inputs, in order."""


def feature_columns(names: Sequence[str]) -> list[int]:
    """The columns of rows of ``FEATURES`` that hold ``names`` (a model's features, in its order)."""
    return [FEATURES.index(name) for name in names]


MODEL_PATH = Path(__file__).resolve().parent.parent / "models" / "activity_waist.json"
"""The model on main (``fusegraph tune activity --sessions DIR --write`` fits and writes it)."""


def _band(x: FloatArray, fs: float, lo_hz: float, hi_hz: float) -> FloatArray:
    b, a = butter(2, [lo_hz / (fs / 2), hi_hz / (fs / 2)], btype="band")
    return np.asarray(filtfilt(b, a, x, axis=0))


def _highpass(x: FloatArray, fs: float, hz: float) -> FloatArray:
    b, a = butter(2, hz / (fs / 2), btype="high")
    return np.asarray(filtfilt(b, a, x, axis=0))


def cycle_features(t: FloatArray, accel_m_s2: FloatArray, gyro_rad_s: FloatArray, gravity: FloatArray, cycles: Sequence[Cycle]) -> FloatArray:
    """``BASE_FEATURES`` of each cycle, shape (len(cycles), len(BASE_FEATURES)), from the waist's accelerometer and gyro and
    ``pdr.gravity_filter``'s gravity (the sensor's axes and its orientation on the belt never enter: every signal is
    taken in the levelled frame of gravity and the cycle's direction of travel)."""
    fs = 1.0 / float(np.median(np.diff(t)))
    vertical, horizontal = vertical_horizontal(accel_m_s2, gravity)
    up = gravity / np.linalg.norm(gravity, axis=1, keepdims=True)
    e1 = np.array([1.0, 0.0, 0.0]) - up[:, 0:1] * up  # the levelled frame of ``vertical_horizontal``
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(up, e1)
    v = _band(vertical, fs, 0.3, 6.0)
    h = _band(horizontal, fs, 0.3, 6.0)
    excursion = pelvis_excursion(v, fs)
    rates = np.stack([_band(np.einsum("ni,ni->n", gyro_rad_s, axis), fs, 0.3, 6.0) for axis in (e1, e2, up)], axis=1)
    above_3hz = _highpass(vertical, fs, 3.0)
    half = int(round(WINDOW_S * fs / 2))
    rows = np.full((len(cycles), len(BASE_FEATURES)), np.nan)
    means = np.full((len(cycles), 3), np.nan)
    axes = np.full((len(cycles), 2, 3), np.nan)
    for n, cycle in enumerate(cycles):
        p = int(np.clip(np.searchsorted(t, cycle.t), 0, len(t) - 1))
        lo, hi = max(0, p - half), min(len(t), p + half)
        if hi - lo < 10:
            continue
        c, s = math.cos(cycle.travel_rad), math.sin(cycle.travel_rad)
        forward, lateral = h[lo:hi, 0] * c + h[lo:hi, 1] * s, -h[lo:hi, 0] * s + h[lo:hi, 1] * c
        roll_rate = rates[lo:hi, 0] * c + rates[lo:hi, 1] * s  # about the travel direction
        pitch_rate = -rates[lo:hi, 0] * s + rates[lo:hi, 1] * c  # about the lateral axis: the sagittal rotation
        vv, raw = v[lo:hi], vertical[lo:hi]
        rows[n, :21] = [
            cycle.period_s, vv.std(), forward.std(), lateral.std(), vv.std() / max(math.hypot(forward.std(), lateral.std()), 1e-9),
            np.ptp(excursion[lo:hi]), excursion[lo:hi].std(), roll_rate.std(), pitch_rate.std(), rates[lo:hi, 2].std(),
            _skewness(vv), vv.max() / max(-vv.min(), 1e-9), cycle.vertical_pp_m_s2, cycle.forward_pp_m_s2,
            _corr(vv, forward), _corr(vv, pitch_rate), _corr(vv, roll_rate), raw.max(), raw.min(), above_3hz[lo:hi].std(),
            float(np.mean(vv**4)) / max(float(np.mean(vv**2)) ** 2, 1e-12),
        ]
        means[n] = up[lo:hi].mean(axis=0)
        rows[n, 23:25] = _tilts(up[lo:hi], means[n])
        axes[n, 0] = c * e1[p] + s * e2[p]
        axes[n, 1] = np.cross(up[p], axes[n, 0])
    if len(cycles):  # the lean: gravity's mean direction near the cycle against the recording's median, along travel and across
        have = np.all(np.isfinite(means), axis=1)
        if have.any():
            median = np.median(means[have], axis=0)
            median /= np.linalg.norm(median)
            rows[:, 21] = np.einsum("ni,ni->n", means - median, axes[:, 0])
            rows[:, 22] = np.einsum("ni,ni->n", means - median, axes[:, 1])
    return rows


def _tilts(up: FloatArray, mean: FloatArray) -> tuple[float, float]:
    """How far the trunk tilts within a window (``up``: gravity's direction per sample, ``mean`` its mean), degrees: the
    angle between gravity's mean direction over its first and its last third (lying down, sitting, standing up), and the
    largest angle of gravity from its mean over the window (a transition that leans forward and back: sit to stand).
    Walking keeps both a few degrees. HAPT users 1-10, each
    held out: the walking-or-not gate alone at fixed settings (100 stages, context 0-2) called 92.5 % of the not-walking
    cycles right without them, 96.8-97.8 % with them; ``bench activity``'s whole procedure 82.3 % -> 97.3 %."""
    third = len(up) // 3  # the caller's windows hold at least 10 samples
    first, last = up[:third].mean(axis=0), up[-third:].mean(axis=0)
    cos_change = float(first @ last) / max(float(np.linalg.norm(first) * np.linalg.norm(last)), 1e-12)
    unit_mean = mean / max(float(np.linalg.norm(mean)), 1e-12)
    return math.degrees(math.acos(min(1.0, max(-1.0, cos_change)))), math.degrees(math.acos(min(1.0, max(-1.0, float((up @ unit_mean).min())))))


def _skewness(x: FloatArray) -> float:
    """The sample skewness m3 / m2^1.5 (``scipy.stats.skew``'s default, NaN for a constant signal as there), without its
    per-call argument handling: half of the features' time went there."""
    d = x - x.mean()
    m2 = float(np.mean(d * d))
    if m2 <= (np.finfo(float).resolution * float(x.mean())) ** 2:
        return math.nan
    return float(np.mean(d * d * d)) / m2**1.5


def _corr(a: FloatArray, b: FloatArray) -> float:
    sa, sb = a.std(), b.std()
    return float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb)) if sa > 0 and sb > 0 else 0.0


def with_reference(base: FloatArray, causal: bool = False) -> FloatArray:
    """``FEATURES`` from ``BASE_FEATURES`` of ONE recording's cycles: each also as its difference from the recording's
    median (the person's own reference; offline: it needs the whole recording). ``causal``: from the median of the
    cycles so far instead (what a live estimate can know)."""
    base = np.nan_to_num(np.asarray(base, dtype=float))
    median: FloatArray = expanding_median(base) if causal else (np.median(base, axis=0) if len(base) else np.zeros(base.shape[1]))
    return np.hstack([base, base - median])


def expanding_median(x: FloatArray) -> FloatArray:
    """Row k: the column-wise median of rows 0..k (each column kept sorted as rows arrive: O(n) per row, not a sort)."""
    out = np.empty_like(x, dtype=float)
    columns: list[list[float]] = [[] for _ in range(x.shape[1])]
    for k, row in enumerate(np.asarray(x, dtype=float)):
        half = k // 2
        for j, value in enumerate(row):
            bisect.insort(columns[j], float(value))
            column = columns[j]
            out[k, j] = column[half] if k % 2 == 0 else 0.5 * (column[half] + column[half + 1])
    return out


def bouts(cycle_t: FloatArray) -> np.ndarray:
    """Bout index of each cycle (a new bout after a gap longer than ``BOUT_GAP_S``)."""
    cycle_t = np.asarray(cycle_t, dtype=float)
    return np.concatenate([[0], np.cumsum(np.diff(cycle_t) > BOUT_GAP_S)]).astype(int) if len(cycle_t) else np.zeros(0, dtype=int)


def in_context(log_proba: FloatArray, cycle_t: FloatArray, context_cycles: int, causal: bool = False) -> FloatArray:
    """Each cycle's mean log-probability over ``context_cycles`` cycles either side inside its bout (``causal``: the
    cycle and the ``context_cycles`` before it)."""
    if context_cycles <= 0 or not len(log_proba):
        return log_proba
    out = np.empty_like(log_proba)
    labels = bouts(cycle_t)
    for bout in np.unique(labels):
        idx = np.flatnonzero(labels == bout)
        cumulative = np.vstack([np.zeros(log_proba.shape[1]), np.cumsum(log_proba[idx], axis=0)])
        lo = np.clip(np.arange(len(idx)) - context_cycles, 0, len(idx))
        hi = np.clip(np.arange(len(idx)) + (1 if causal else context_cycles + 1), 0, len(idx))
        out[idx] = (cumulative[hi] - cumulative[lo]) / (hi - lo)[:, None]
    return out


@dataclass(frozen=True)
class Tree:
    """One regression tree as arrays (scikit-learn's ``tree_`` layout: a leaf has ``left == -1``)."""

    left: np.ndarray
    """Index of each node's left child (taken when ``x[feature] <= threshold``), -1 at a leaf."""
    right: np.ndarray
    """Index of each node's right child, -1 at a leaf."""
    feature: np.ndarray
    """Feature each split reads."""
    threshold: FloatArray
    """Split threshold of each node."""
    value: FloatArray
    """Output of each node (read at the leaves)."""

    def predict(self, x: FloatArray) -> FloatArray:
        node = np.zeros(len(x), dtype=int)
        active = self.left[node] >= 0
        while active.any():
            rows = np.flatnonzero(active)
            at = node[rows]
            go_left = x[rows, self.feature[at]] <= self.threshold[at]
            node[rows] = np.where(go_left, self.left[at], self.right[at])
            active = self.left[node] >= 0
        return self.value[node]


@dataclass(frozen=True)
class ActivityModel:
    """The activity classifier: boosted trees over ``FEATURES``, and how much context it takes."""

    classes: tuple[str, ...]
    """The classes in output order (``ACTIVITIES``)."""
    features: tuple[str, ...]
    """The inputs in order: ``FEATURES`` or the subset of them the fit chose (``evaluation.activity.FEATURE_SETS``)."""
    init_raw: FloatArray
    """The ensemble's starting score per class."""
    learning_rate: float
    """Weight of each tree."""
    trees: tuple[tuple[Tree, ...], ...]
    """Per boosting stage, one tree per class."""
    context_cycles: int
    """Cycles either side (in the bout) whose log-probabilities are averaged."""
    provenance: dict[str, Any]
    """What it was fitted on and how its settings were chosen (dataset, subjects, rule, scores)."""
    gate: ActivityModel | None = None
    """Walking or not (classes ``GATE_CLASSES``, its own context: a postural transition lasts a cycle or two), asked first;
    None: every cycle is one of ``classes``."""

    def log_proba(self, x: FloatArray) -> FloatArray:
        """Log-probability of each class per row of ``x`` (rows of ``FEATURES``; the model reads its ``features``)."""
        if self.features != FEATURES:
            x = x[:, feature_columns(self.features)]
        raw = np.tile(self.init_raw, (len(x), 1))
        for stage in self.trees:
            for k, tree in enumerate(stage):
                raw[:, k] += self.learning_rate * tree.predict(x)
        if raw.shape[1] == 1:  # two classes: the score is the second's log-odds
            raw = np.hstack([np.zeros_like(raw), raw])
        raw -= raw.max(axis=1, keepdims=True)
        return raw - np.log(np.exp(raw).sum(axis=1, keepdims=True))

    def classify(self, base: FloatArray, cycle_t: FloatArray, causal: bool = False) -> list[str]:
        """The activity of each cycle of ONE recording from its ``cycle_features`` and times (``causal``: from the cycles
        up to each one only: the reference and the context of a live estimate)."""
        if not len(base):
            return []
        x = with_reference(base, causal)
        calls = [self.classes[k] for k in in_context(self.log_proba(x), cycle_t, self.context_cycles, causal).argmax(axis=1)]
        if self.gate is None:
            return calls
        gate = in_context(self.gate.log_proba(x), cycle_t, self.gate.context_cycles, causal).argmax(axis=1)
        return ["not_walking" if self.gate.classes[g] == "not_walking" else call for g, call in zip(gate, calls, strict=True)]

    def as_json(self) -> dict[str, Any]:
        return {"classes": list(self.classes), "features": list(self.features), "init_raw": self.init_raw.tolist(),
                "learning_rate": self.learning_rate, "context_cycles": self.context_cycles, "provenance": self.provenance,
                "gate": None if self.gate is None else self.gate.as_json(),
                "trees": [[{"left": t.left.tolist(), "right": t.right.tolist(), "feature": t.feature.tolist(),
                            "threshold": [round(float(v), 9) for v in t.threshold], "value": [round(float(v), 9) for v in t.value]}
                           for t in stage] for stage in self.trees]}

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.as_json(), separators=(",", ":")) + "\n")
        return path


def load_model(path: str | Path = MODEL_PATH) -> ActivityModel:
    """The activity model written by ``ActivityModel.save`` (default: the one on main); read once per file version
    (every ``run --solver activity`` asks for it)."""
    path = Path(path)
    return _read_model(path, path.stat().st_mtime_ns)


@functools.lru_cache(maxsize=4)
def _read_model(path: Path, mtime_ns: int) -> ActivityModel:
    return _model_from(json.loads(path.read_text()), path)


def _model_from(data: dict[str, Any], path: Path) -> ActivityModel:
    unknown = [name for name in data["features"] if name not in FEATURES]
    if unknown:
        raise ValueError(f"{path}: fitted on features this version does not compute ({', '.join(unknown)}): refit it (fusegraph tune activity --write)")
    trees = tuple(tuple(Tree(np.array(t["left"], dtype=int), np.array(t["right"], dtype=int), np.array(t["feature"], dtype=int),
                             np.array(t["threshold"], dtype=float), np.array(t["value"], dtype=float)) for t in stage)
                  for stage in data["trees"])
    return ActivityModel(tuple(data["classes"]), tuple(data["features"]), np.array(data["init_raw"], dtype=float), float(data["learning_rate"]),
                         trees, int(data["context_cycles"]), dict(data["provenance"]),
                         None if data.get("gate") is None else _model_from(data["gate"], path))


def with_activity(t: FloatArray, accel_m_s2: FloatArray, gyro_rad_s: FloatArray, gravity: FloatArray, cycles: Sequence[Cycle],
                  model: ActivityModel | None = None, causal: bool = False) -> list[Cycle]:
    """The cycles with each one's activity by ``model`` (default: the model on main) instead of the paper's rules
    (``Cycle.activity`` as ``pdr.detect_cycles`` gives it); ``gravity`` the gravity filter's output the cycles came from;
    ``causal``: each cycle classified from the cycles up to it (``ActivityModel.classify``)."""
    from dataclasses import replace

    calls, _ = _classified(t, accel_m_s2, gyro_rad_s, gravity, cycles, model, causal)
    return [replace(c, activity=call) for c, call in zip(cycles, calls, strict=True)]


def _classified(t: FloatArray, accel_m_s2: FloatArray, gyro_rad_s: FloatArray, gravity: FloatArray, cycles: Sequence[Cycle],
                model: ActivityModel | None, causal: bool = False) -> tuple[list[str], FloatArray]:
    """Each cycle's activity by ``model`` (default: the model on main) and the cycles' ``BASE_FEATURES``."""
    base = cycle_features(t, accel_m_s2, gyro_rad_s, gravity, cycles)
    return (model or load_model()).classify(base, np.array([c.t for c in cycles]), causal), base


def classify_waist(t: FloatArray, accel_m_s2: FloatArray, gyro_rad_s: FloatArray, config: PdrConfig,
                   model: ActivityModel | None = None) -> tuple[list[Cycle], list[str], FloatArray]:
    """The walking cycles of one waist recording (``pdr.detect_cycles`` with ``config``), each one's activity by
    ``model`` (default: the model on main), and their ``BASE_FEATURES`` (what a model is fitted on)."""
    gravity, cycles = front_end(t, accel_m_s2, gyro_rad_s, config)
    return cycles, *_classified(t, accel_m_s2, gyro_rad_s, gravity, cycles, model)
