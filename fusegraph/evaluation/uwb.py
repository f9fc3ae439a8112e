"""The recorded UWB run scored: labelled and unlabelled tracks against the motion capture, the clocks aligned on the
raw ranges, and a geometry-only self-check of the association."""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from ..datasets.uwb_lias import UwbRecording
from ..geometry import FloatArray
from ..systems.uwb import UwbConfig, UwbTracker


@dataclass(frozen=True)
class UwbResult:
    labelled_rmse_m: float
    unlabelled_rmse_m: float
    assoc_acc: float
    """Unlabelled run: ranges given to the right tag (after matching tags to the truth once)."""
    clock_offset_s: float
    """Motion capture time = UWB time + this (found from the raw ranges against the motion capture)."""
    ms_per_epoch: float
    assoc_expected: float = float("nan")
    """The self-check's association accuracy from the geometry alone (no labels, no truth): a lower bound,
    the tracker's continuity does better (fast run: 0.48 here, 0.80 measured). Near chance: a warning."""


def _track(rec: UwbRecording, labelled: bool, config: UwbConfig | None, select_s: float = 20.0) -> tuple[FloatArray, FloatArray, float]:
    """Track the whole run. The offsets' handedness seen from above (the motion-capture body frame is
    upside down here) is not decidable from one epoch: both are tracked for ``select_s`` seconds and the
    one whose ranges fit better (Cauchy cost) is kept; the run then restarts with it."""
    window = int(np.searchsorted(rec.t, rec.t[0] + select_s))
    costs = {}
    for handed in (1.0, -1.0):
        trial = UwbTracker(rec.anchors, rec.tag_offsets, config)
        trial.start(rec.ranges[:100], labelled, mirror=handed)
        for k in range(window):
            trial.step(float(rec.t[k]), rec.ranges[k], labelled)
        costs[handed] = trial.cost
    tracker = UwbTracker(rec.anchors, rec.tag_offsets, config)
    tracker.start(rec.ranges[:100], labelled, mirror=min(costs, key=costs.__getitem__))  # the first second, buffered
    xy, labels = np.zeros((len(rec.t), 3, 2)), np.zeros(rec.ranges.shape, dtype=int)
    start = time.perf_counter()
    for k, t in enumerate(rec.t):
        xy[k], labels[k] = tracker.step(float(t), rec.ranges[k], labelled)
    return xy, labels, 1e3 * (time.perf_counter() - start) / len(rec.t)


def _rmse(rec: UwbRecording, xy: FloatArray, offset_s: float, mapping: np.ndarray | None = None) -> float:
    truth = rec.tags_truth(rec.t + offset_s)[:, :, :2]
    ordered = xy if mapping is None else xy[:, np.argsort(mapping)]
    inside = (rec.t + offset_s >= rec.mocap_t[0]) & (rec.t + offset_s <= rec.mocap_t[-1])
    return float(np.sqrt(np.mean(np.sum((ordered[inside] - truth[inside]) ** 2, axis=2))))


def clock_offset_from_ranges(rec: UwbRecording, search_s: float = 0.3, step_s: float = 0.005) -> float:
    """Motion-capture time minus UWB time, from the raw data alone: the offset at which the measured ranges
    best match the ranges the motion capture's tag positions give (a constant bias per anchor and tag
    removed; median absolute residual). No estimate enters, so the offset cannot favour any method."""
    anchors = rec.anchors[None, :, None, :]
    best_cost, best = np.inf, 0.0
    for offset in np.arange(-search_s, search_s + 0.5 * step_s, step_s):
        t = rec.t + offset
        inside = (t >= rec.mocap_t[0]) & (t <= rec.mocap_t[-1])
        if inside.sum() < 100:
            continue
        tags = rec.tags_truth(t[inside])[:, None, :, :]  # (K, 1, T, 3)
        residual = rec.ranges[inside] - np.linalg.norm(tags - anchors, axis=3)
        residual = residual - np.nanmedian(residual, axis=0, keepdims=True)
        cost = float(np.nanmedian(np.abs(residual)))
        if cost < best_cost:
            best_cost, best = cost, float(offset)
    return best


def association_self_check(rec: UwbRecording, xy: FloatArray) -> float:
    """Association accuracy to expect from the geometry alone, no labels, no truth.

    Per epoch (every tenth) and anchor, every assignment of the measured ranges to the tracked tags is
    costed; the range noise is the robust spread of the best assignments' residuals. A range set is told
    apart when the best assignment beats the second best by more than 4 (chi-square: 2 sigma); otherwise
    it is a guess (right 1 time in T). Returns told + (1 - told) / T.
    """
    import itertools

    tags = xy.shape[1]
    height = float(rec.anchors[:, 2].mean())
    perms = np.array(list(itertools.permutations(range(tags))))
    best, second, residuals = [], [], []
    for k in range(0, len(rec.t), 10):  # every tenth epoch: the figure is a mean
        pos = np.column_stack([xy[k], np.full(tags, height)])
        predicted = np.linalg.norm(rec.anchors[:, None, :] - pos[None, :, :], axis=2)  # (A, T)
        for a in range(len(rec.anchors)):
            measured = rec.ranges[k, a]
            if not np.all(np.isfinite(measured)) or not np.all(np.isfinite(predicted[a])):
                continue
            costs = ((measured[None, :] - predicted[a][perms]) ** 2).sum(axis=1)
            order = np.argsort(costs)
            best.append(costs[order[0]])
            second.append(costs[order[1]])
            residuals.append(measured - predicted[a][perms[order[0]]])
    if not best:
        return float("nan")
    spread = np.concatenate(residuals)
    sigma = 1.4826 * float(np.median(np.abs(spread - np.median(spread))))  # robust sigma of the residuals
    told = float(np.mean((np.array(second) - np.array(best)) / max(sigma, 1e-3) ** 2 > 4.0))
    return told + (1.0 - told) / tags


def run_uwb(rec: UwbRecording, config: UwbConfig | None = None) -> UwbResult:
    """Labelled and unlabelled runs, scored against the motion capture after aligning the two clocks on the
    raw ranges (``clock_offset_from_ranges``; formerly the offset that minimised our own labelled error)."""
    from ..systems.ultrasonic import identity_map

    labelled_xy, _, _ = _track(rec, True, config)
    offset = clock_offset_from_ranges(rec)
    xy, labels, ms = _track(rec, False, config)
    k = min(50, len(xy) - 1)  # tags matched to the truth once, half a second in
    mapping = identity_map(xy[k], rec.tags_truth(rec.t[k : k + 1] + offset)[0, :, :2])
    finite = np.isfinite(rec.ranges)
    truth_labels = np.broadcast_to(np.arange(rec.ranges.shape[2]), rec.ranges.shape)
    guessed = np.where(labels >= 0, mapping[np.clip(labels, 0, None)], -1)
    assoc = float(np.mean(guessed[finite] == truth_labels[finite]))
    expected = association_self_check(rec, xy)
    chance = 1.0 / rec.ranges.shape[2]
    if expected < chance + 0.1:  # the geometry tells (almost) no range set apart: the tracker's continuity is all it has
        warnings.warn(f"UWB self-check: from the geometry alone the association is {expected:.0%} (chance {chance:.0%}): the unlabelled "
                      "association is no better than guessing", RuntimeWarning, stacklevel=2)
    return UwbResult(_rmse(rec, labelled_xy, offset), _rmse(rec, xy, offset, mapping), assoc, offset, ms, expected)
