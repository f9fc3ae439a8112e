"""Recorded UWB run: 3 tags tracked from unlabelled anchor ranges, against the labelled run and motion capture.

Each tag: position and velocity in the horizontal plane (anchors and tags sit within 9 cm of one
plane, so height is barely observable: it is HELD at the anchors' mean height; the 9 cm it is off
changes a range by under 2 mm beyond 2 m) and one range bias per anchor (the ranges read ~0.2 m long,
differently per anchor and tag) as graph variables. Per epoch, the graph is the previous marginal,
the constant-velocity law, a bias random walk and the ranges the association gave the tag
(linearised at the prediction, re-linearised once, Cauchy reweighting); gtsam eliminates it.
Unlabelled: per anchor, the sorted ranges are assigned to the tags' predicted ranges (optimal
assignment, gated). The start needs no prior: the trolley's centroid from the mean range per anchor,
then the tags' rigid layout (its offsets, either handedness, every heading) that best explains the
range DIFFERENCES at each anchor, which no common bias affects.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np

from ..datasets.uwb_lias import UwbRecording
from ..frontends.association import assign_ranges
from ..geometry import FloatArray


@dataclass(frozen=True)
class UwbConfig:
    """Noise and motion of the UWB tracker."""

    range_sigma_m: float = 0.1
    """Range noise, metres (the ranges are quantised to 1 cm; multipath spreads them)."""
    accel_psd: float = 1.0
    """White-acceleration density of the tags, (m/s^2)^2/Hz."""
    bias_prior_m: float = 0.5
    """Start-up sigma of each anchor's range bias, metres (mean 0: the bias is learnt)."""
    bias_walk_m_sqrt_s: float = 0.005
    """Random walk of the range biases, m/sqrt(s)."""
    gate_chi2: float = 9.0
    """Association gate (3 sigma)."""
    cauchy_k: float = 3.0
    """Cauchy width in range sigmas."""


def _state_motion(dt: float, psd: float, bias_walk: float, anchors: int) -> tuple[FloatArray, FloatArray]:
    n = 4 + anchors
    F = np.eye(n)
    F[0, 2] = F[1, 3] = dt
    Q = np.zeros((n, n))
    for i in range(2):
        Q[i, i] = psd * dt**3 / 3
        Q[i, i + 2] = Q[i + 2, i] = psd * dt**2 / 2
        Q[i + 2, i + 2] = psd * dt
    Q[4:, 4:] = np.eye(anchors) * bias_walk**2 * dt
    return F, np.linalg.inv(np.linalg.cholesky(Q))


class UwbTracker:
    """Tags in the plane with per-anchor range biases, from labelled or unlabelled ranges."""

    def __init__(self, anchors: FloatArray, tag_offsets: FloatArray, config: UwbConfig | None = None):
        self.anchors = np.asarray(anchors, dtype=float)
        self.offsets = np.asarray(tag_offsets, dtype=float)
        self.config = config or UwbConfig()
        self.height = float(self.anchors[:, 2].mean())
        self.x: FloatArray | None = None  # (T, 4 + A)
        self.sqrt_info: list[FloatArray] = []
        self._t: float | None = None

    def _predicted_ranges(self, xy: FloatArray) -> FloatArray:
        """(T, A) distances from tags at xy (T, 2), held at the anchors' height, to the anchors."""
        pts = np.column_stack([xy, np.full(len(xy), self.height)])
        return np.linalg.norm(pts[:, None, :] - self.anchors[None, :, :], axis=2)

    def start(self, ranges: FloatArray) -> None:
        """Initial tags from one epoch's (A, T) ranges, labelled or not (the columns' order is not used)."""
        mean = np.nanmean(ranges, axis=1)
        ok = np.isfinite(mean)
        c = self.anchors[ok, :2].mean(0)
        common_bias = 0.0
        for _ in range(10):  # Gauss-Newton for the centroid and one common range bias (anchors surround the trolley)
            d = np.hypot(*(c - self.anchors[ok, :2]).T)
            jac = (c - self.anchors[ok, :2]) / d[:, None]
            step, *_ = np.linalg.lstsq(np.column_stack([jac, np.ones(ok.sum())]), mean[ok] - d - common_bias, rcond=None)
            c, common_bias = c + step[:2], common_bias + step[2]
        layout = self.offsets[:, :2] - self.offsets[:, :2].mean(0)
        best: tuple[float, FloatArray] = (np.inf, np.zeros((len(layout), 2)))
        for mirror in (1.0, -1.0):
            for heading in np.deg2rad(np.arange(0, 360, 5)):
                rot = np.array([[np.cos(heading), -np.sin(heading)], [np.sin(heading), np.cos(heading)]])
                xy = c + (layout * [mirror, 1.0]) @ rot.T
                predicted = self._predicted_ranges(xy)  # (T, A)
                cost = 0.0
                for a in range(len(self.anchors)):
                    heard = np.sort(ranges[a][np.isfinite(ranges[a])])
                    if len(heard) < 2:
                        continue
                    rel_p = predicted[:, a] - predicted[:, a].mean()
                    rel_h = heard - heard.mean()
                    cost += float(np.min(np.abs(rel_h[:, None] - rel_p[None, :]), axis=1).sum())
                if cost < best[0]:
                    best = (cost, xy)
        self.x = np.zeros((len(layout), 4 + len(self.anchors)))
        self.x[:, :2] = best[1]
        self.x[:, 4:] = common_bias  # learnt per anchor and tag from here on
        cfg = self.config
        info = np.diag(np.r_[[1 / 0.3] * 2, [1 / 0.5] * 2, [1 / cfg.bias_prior_m] * len(self.anchors)])
        self.sqrt_info = [info.copy() for _ in range(len(layout))]

    def step(self, t: float, ranges: FloatArray, labelled: bool) -> tuple[FloatArray, FloatArray]:
        """One epoch of (A, T) ranges (NaN = missing; ``labelled`` False: each row's order is meaningless).

        Returns the tags' positions (T, 2) and the tag given to each range (A, T) (-1 = rejected).
        """
        cfg = self.config
        if self.x is None:
            self.start(ranges)
            self._t = t
        assert self.x is not None
        dt = max(t - (self._t if self._t is not None else t), 1e-3)
        self._t = t
        F, W = _state_motion(dt, cfg.accel_psd, cfg.bias_walk_m_sqrt_s, len(self.anchors))
        pred = self.x @ F.T
        tags = len(self.x)
        labels = np.full(ranges.shape, -1)
        if labelled:
            labels[np.isfinite(ranges)] = np.broadcast_to(np.arange(tags), ranges.shape)[np.isfinite(ranges)]
        else:
            predicted = self._predicted_ranges(pred[:, :2]) + pred[:, 4:]  # (T, A) with each tag's bias
            for a in range(len(self.anchors)):
                heard = np.isfinite(ranges[a])
                found = assign_ranges(ranges[a][heard], predicted[:, a], np.full(tags, 2 * cfg.range_sigma_m), cfg.gate_chi2)
                labels[a, np.nonzero(heard)[0]] = found
        order = gtsam.Ordering()
        order.push_back(0)
        order.push_back(1)
        n = self.x.shape[1]
        unit = gtsam.noiseModel.Unit.Create(n)
        for i in range(tags):
            a_idx, c_idx = np.nonzero(labels == i)
            z = ranges[a_idx, c_idx]
            x_new = pred[i].copy()
            weights = np.ones(len(z))
            for iteration in range(2):
                graph = gtsam.GaussianFactorGraph()
                graph.add(gtsam.JacobianFactor(0, self.sqrt_info[i], self.sqrt_info[i] @ self.x[i], unit))
                graph.add(gtsam.JacobianFactor(0, -W @ F, 1, W, np.zeros(n), unit))
                if len(z):
                    diff = np.column_stack([x_new[:2] - self.anchors[a_idx, :2], self.height - self.anchors[a_idx, 2]])
                    rho = np.linalg.norm(diff, axis=1)
                    h = rho + x_new[4 + a_idx]
                    if iteration == 1:
                        weights = 1.0 / np.sqrt(1.0 + ((z - h) / (cfg.cauchy_k * cfg.range_sigma_m)) ** 2)
                    A = np.zeros((len(z), n))
                    A[:, :2] = diff[:, :2] / rho[:, None]
                    A[np.arange(len(z)), 4 + a_idx] = 1.0
                    b = z - h + A @ x_new
                    graph.add(gtsam.JacobianFactor(1, A * (weights / cfg.range_sigma_m)[:, None], b * weights / cfg.range_sigma_m,
                                                   gtsam.noiseModel.Unit.Create(len(z))))
                conditional = graph.eliminateSequential(order).at(1)
                R = np.array(conditional.R(), copy=True)
                x_new = np.linalg.solve(R, np.array(conditional.d(), copy=True))
            self.x[i], self.sqrt_info[i] = x_new, R
        return self.x[:, :2].copy(), labels


@dataclass(frozen=True)
class UwbResult:
    labelled_rmse_m: float
    unlabelled_rmse_m: float
    assoc_acc: float
    """Unlabelled run: ranges given to the right tag (after matching tags to the truth once)."""
    clock_offset_s: float
    """Motion capture time = UWB time + this (found on the labelled run)."""
    ms_per_epoch: float


def _track(rec: UwbRecording, labelled: bool, config: UwbConfig | None) -> tuple[FloatArray, FloatArray, float]:
    tracker = UwbTracker(rec.anchors, rec.tag_offsets, config)
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


def run_uwb(rec: UwbRecording, config: UwbConfig | None = None) -> UwbResult:
    """Labelled and unlabelled runs, scored against the motion capture after finding the clock offset."""
    from .ultrasonic import identity_map

    labelled_xy, _, _ = _track(rec, True, config)
    offsets = np.arange(-0.2, 0.2001, 0.005)
    errors = [_rmse(rec, labelled_xy, float(o)) for o in offsets]
    offset = float(offsets[int(np.argmin(errors))])
    xy, labels, ms = _track(rec, False, config)
    k = min(50, len(xy) - 1)  # tags matched to the truth once, half a second in
    mapping = identity_map(xy[k], rec.tags_truth(rec.t[k : k + 1] + offset)[0, :, :2])
    finite = np.isfinite(rec.ranges)
    truth_labels = np.broadcast_to(np.arange(rec.ranges.shape[2]), rec.ranges.shape)
    guessed = np.where(labels >= 0, mapping[np.clip(labels, 0, None)], -1)
    assoc = float(np.mean(guessed[finite] == truth_labels[finite]))
    return UwbResult(min(errors), _rmse(rec, xy, offset, mapping), assoc, offset, ms)
