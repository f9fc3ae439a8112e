"""Tags on one rigid body tracked in a plane from unlabelled ranges (the UWB trolley: 3 tags, 8 anchors).

The trolley's planar pose (x, y, heading) and its rates, the tags at their fixed offsets on it (the
rigid body as part of the measurement model), and one range bias per anchor (the ranges read ~0.2 m
long; per anchor and tag is an option) as graph variables. Anchors and tags sit within 9 cm of one plane,
so height is barely observable: it is HELD at the anchors' mean height (the 9 cm it is off changes a
range by under 2 mm beyond 2 m). Per epoch, the graph is the previous marginal,
the constant-velocity law, a bias random walk and the ranges the association gave the tag
(linearised at the prediction, re-linearised once, Cauchy reweighting); gtsam eliminates it.
Unlabelled: per anchor, the sorted ranges are assigned to the tags' predicted ranges (optimal assignment, gated), and
neighbouring ranges that could have swapped are shared by the swap's probability. The start needs no prior: the
trolley's centroid from the mean range per anchor, then the tags' rigid layout (its offsets, either handedness, every
heading) that best explains the range DIFFERENCES at each anchor (no common bias affects them; a declared calibration's on the prediction).
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import block_diag

from ..frontends.association import assign_receivers, association_self_check, relative_range_misfit, share_swaps
from ..geometry import FloatArray
from ..progress import progress
from ..records import RangeEpochs
from ..results import TrackingRun
from ..solvers.sequential import MarginalStep, constant_velocity, whitening


@dataclass(frozen=True)
class UwbConfig:
    """Noise and motion of the UWB tracker."""

    range_sigma_m: float = 0.1
    """Range noise, metres (the ranges are quantised to 1 cm; multipath spreads them)."""
    accel_psd: float = 1.0
    """White-acceleration density of the trolley, (m/s^2)^2/Hz."""
    turn_psd: float = 4.0
    """White angular-acceleration density of its heading, (rad/s^2)^2/Hz."""
    bias_prior_m: float = 0.5
    """Start-up sigma of each anchor's range bias, metres (mean 0: the bias is learnt)."""
    bias_walk_m_sqrt_s: float = 0.005
    """Random walk of the range biases, m/sqrt(s)."""
    bias_per_tag: bool = False
    """True: one range bias per anchor AND tag (tag 2 reads -0.06..+0.47 m off by anchor). Measured: labelled 0.215 m
    either way, but unlabelled 0.246 m with 24 biases (they follow whatever association) against 0.217 m with one per anchor."""
    gate_chi2: float = 9.0
    """Association gate (3 sigma)."""
    cauchy_k: float = 3.0
    """Cauchy width in range sigmas."""
    assoc_sigma_m: float | None = None
    """Unlabelled: the sigma of a range against its tag's predicted range in the assignment, metres (None: twice ``range_sigma_m``)."""
    soft_pairs: bool = True
    """Unlabelled: neighbouring ranges at an anchor are shared between their two tags by the probability that they swapped
    (``frontends.association.share_swaps``; the slow LIAS run 0.0432 -> 0.0422 m, the fast 0.0426 -> 0.0430, README)."""


@functools.lru_cache(maxsize=1024)
def _state_motion(dt: float, psd: float, psd_turn: float, bias_walk: float, biases: int) -> tuple[FloatArray, FloatArray]:
    """Constant velocity in (x, y, heading) and random-walk biases: transition and whitening (read-only). Cached: a
    logger's stamps are quantised (LIAS's 13,481 epochs are 102 distinct steps), and building them was a quarter of the
    tracker's time."""
    F_cv, Q_cv = constant_velocity(dt, [psd, psd, psd_turn])
    F, W = block_diag(F_cv, np.eye(biases)), whitening(block_diag(Q_cv, np.eye(biases) * bias_walk**2 * dt))
    F.setflags(write=False)
    W.setflags(write=False)
    return F, W


@dataclass(frozen=True)
class RangeCalibration:
    """A range calibration per receiver and tag (a static calibration recording's): measured = scale x true + bias."""

    bias_m: FloatArray
    """(R, T) range bias, metres."""
    scale: FloatArray
    """(R, T) range scale (1 + slope)."""
    sigma_m: FloatArray
    """(R, T) residual sigma of the calibration fit, metres: the prior sigma of the bias the tracker refines."""


class UwbTracker:
    """The trolley's planar pose (tags at their fixed offsets) and a range bias per anchor (and tag)."""

    def __init__(self, anchors: FloatArray, tag_offsets: FloatArray, config: UwbConfig | None = None,
                 calibration: RangeCalibration | None = None):
        self.anchors = np.asarray(anchors, dtype=float)
        self.offsets = np.asarray(tag_offsets, dtype=float)
        self.config = config or UwbConfig()
        self.height = float(self.anchors[:, 2].mean())
        self.tags = len(self.offsets)
        self.calibration = calibration
        self._bias_tags = self.tags if self.config.bias_per_tag or calibration is not None else 1
        self._scale = np.ones((len(self.anchors), self.tags)) if calibration is None else np.asarray(calibration.scale, dtype=float)
        self.mirror = 1.0
        self.layout = self.offsets[:, :2] - self.offsets[:, :2].mean(0)
        self.x: FloatArray | None = None  # x, y, heading, their rates, biases (anchor-major: a * tags + t)
        self.sqrt_info = np.eye(1)
        self._t: float | None = None
        self.cost = 0.0
        """Sum of the Cauchy losses of the normalised range residuals so far (for model selection)."""
        self.start_cost = float("nan")
        """The misfit (m) of the start's pose: its ranges' spread against the prediction's, summed over the first epochs."""

    def tag_xy(self, x: FloatArray) -> FloatArray:
        """(T, 2) tag positions of a state."""
        c, s = np.cos(x[2]), np.sin(x[2])
        body = self.layout * [self.mirror, 1.0]
        return x[:2] + body @ np.array([[c, -s], [s, c]]).T

    def _predicted_ranges(self, xy: FloatArray) -> FloatArray:
        """(T, A) distances from tags at xy (T, 2), held at the anchors' height, to the anchors."""
        pts = np.column_stack([xy, np.full(len(xy), self.height)])
        return np.linalg.norm(pts[:, None, :] - self.anchors[None, :, :], axis=2)

    def start(self, first: FloatArray, labelled: bool, mirror: float | None = None) -> None:
        """Initial pose from the first epochs' (E, A, T) ranges (the trolley barely moves in them).

        Unlabelled, only each anchor's range DIFFERENCES are compared (no common bias affects them, and which range is which
        tag is unknown); labelled, the columns say which tag each range is. Both against what each tag would MEASURE (a
        calibration's bias and scale on the prediction: an unlabelled range's bias is unknown; 0.1 m ones swamp the layout).
        """
        ranges = np.ma.median(np.ma.masked_invalid(first), axis=0).filled(np.nan) if labelled else first[0]  # a dead anchor: NaN, quietly
        bias = np.zeros((len(self.anchors), self.tags)) if self.calibration is None else np.asarray(self.calibration.bias_m, dtype=float)
        mean = np.ma.masked_invalid(first).mean(axis=(0, 2)).filled(np.nan) - bias.mean(axis=1)
        ok = np.isfinite(mean)
        c = self.anchors[ok, :2].mean(0)
        common_bias = 0.0
        for _ in range(10):  # Gauss-Newton for the centroid and one common range bias (anchors surround the trolley)
            d = np.hypot(*(c - self.anchors[ok, :2]).T)
            jac = (c - self.anchors[ok, :2]) / d[:, None]
            step, *_ = np.linalg.lstsq(np.column_stack([jac, np.ones(ok.sum())]), mean[ok] - d - common_bias, rcond=None)
            c, common_bias = c + step[:2], common_bias + step[2]
        best = (np.inf, 0.0, 1.0)
        epochs = [ranges] if labelled else list(first)
        # each (epoch, anchor) that heard two or more: its ranges about their mean (they do not depend on the pose), in order
        groups = [(a, heard, epoch[a][heard] - epoch[a][heard].mean()) for epoch in epochs for a in range(len(self.anchors))
                  for heard in [np.isfinite(epoch[a])] if heard.sum() >= 2]
        misfit = relative_range_misfit([(a, rel_h) for a, _, rel_h in groups]) if not labelled and groups else None
        for handed in (1.0, -1.0) if mirror is None else (mirror,):  # the offsets' frame seen from above: either handedness
            self.mirror = handed
            for heading in np.deg2rad(np.arange(0, 360, 5)):
                predicted = self._scale.T * self._predicted_ranges(self.tag_xy(np.r_[c, heading])) + bias.T  # (T, A), as measured
                rel_p = predicted - predicted.mean(axis=0)
                cost = 0.0
                if labelled:
                    for a, heard, rel_h in groups:
                        cost += float(np.abs(rel_h - (rel_p[heard, a] - rel_p[heard, a].mean())).sum())
                elif misfit is not None:
                    cost = misfit(rel_p)
                if cost < best[0]:
                    best = (cost, float(heading), handed)
        self.mirror, self.start_cost = best[2], best[0]
        biases = len(self.anchors) * self._bias_tags
        if self.calibration is None:
            self.x = np.r_[c, best[1], np.zeros(3), np.full(biases, common_bias)]
            self.sqrt_info = np.diag(np.r_[[1 / 0.3] * 2, 1 / 0.3, [1 / 0.5] * 2, 1 / 1.0, [1 / self.config.bias_prior_m] * biases])
        else:  # the calibration's bias (anchor-major) with its own residual sigma as the prior
            self.x = np.r_[c, best[1], np.zeros(3), np.asarray(self.calibration.bias_m, dtype=float).reshape(-1)]
            self.sqrt_info = np.diag(np.r_[[1 / 0.3] * 2, 1 / 0.3, [1 / 0.5] * 2, 1 / 1.0, 1 / np.asarray(self.calibration.sigma_m).reshape(-1)])

    def step(self, t: float, ranges: FloatArray, labelled: bool) -> tuple[FloatArray, FloatArray]:
        """One epoch of (A, T) ranges (NaN = missing; ``labelled`` False: each row's order is meaningless).

        Returns the tags' positions (T, 2) and the tag given to each range (A, T) (-1 = none).
        """
        cfg = self.config
        if self.x is None:
            self.start(ranges[None], labelled)
            self._t = t
        assert self.x is not None
        dt = max(t - (self._t if self._t is not None else t), 1e-3)
        self._t = t
        n_anchor = len(self.anchors)
        F, W = _state_motion(dt, cfg.accel_psd, cfg.turn_psd, cfg.bias_walk_m_sqrt_s, n_anchor * self._bias_tags)
        pred = F @ self.x
        labels, sigma_assoc = np.full(ranges.shape, -1), cfg.assoc_sigma_m or 2 * cfg.range_sigma_m
        if labelled:
            labels[np.isfinite(ranges)] = np.broadcast_to(np.arange(self.tags), ranges.shape)[np.isfinite(ranges)]
        else:  # the ranges the prediction expects per tag and anchor (T, A): the assignment's and the soft pairs'
            predicted = self._scale.T * self._predicted_ranges(self.tag_xy(pred)) + pred[6:].reshape(n_anchor, self._bias_tags).T
            heard = np.isfinite(ranges)
            # every anchor's assignment at once (each its own); the range order within an anchor as heard
            labels[heard] = assign_receivers([ranges[a][heard[a]] for a in range(n_anchor)], predicted.T, np.full((n_anchor, self.tags), sigma_assoc),
                                             cfg.gate_chi2)
        a_idx, t_idx = np.nonzero(labels >= 0)
        tag_of, z, share = labels[a_idx, t_idx], ranges[a_idx, t_idx], np.ones(len(a_idx))
        if not labelled and cfg.soft_pairs:  # wrong assignments: tags whose true ranges differed by 6 cm (median, slow run)
            a_idx, tag_of, z, share = share_swaps(a_idx, tag_of, z, predicted, sigma_assoc)
        n, x_new, R = len(self.x), pred.copy(), self.sqrt_info
        step = MarginalStep(self.sqrt_info, self.x, F, W)
        for iteration in range(2):
            rows: tuple[FloatArray, FloatArray] | tuple[None, None] = (None, None)
            if len(z):
                cth, sth = np.cos(x_new[2]), np.sin(x_new[2])
                body = self.layout[tag_of] * [self.mirror, 1.0]
                turned = body @ np.array([[cth, -sth], [sth, cth]]).T
                d_turned = body @ np.array([[-sth, -cth], [cth, -sth]]).T  # d(turned)/d(heading)
                diff = np.column_stack([x_new[:2] + turned - self.anchors[a_idx, :2], self.height - self.anchors[a_idx, 2]])
                rho = np.linalg.norm(diff, axis=1)
                bias_col = 6 + (a_idx * self.tags + tag_of if self._bias_tags > 1 else a_idx)
                gain = self._scale[a_idx, tag_of]
                h = gain * rho + x_new[bias_col]
                weights = np.sqrt(share)
                if iteration == 1:
                    scaled = (z - h) / (cfg.cauchy_k * cfg.range_sigma_m)
                    weights = np.sqrt(share) / np.sqrt(1.0 + scaled**2)
                    self.cost += float(np.log1p(scaled**2).sum())
                u = gain[:, None] * diff[:, :2] / rho[:, None]
                A = np.zeros((len(z), n))
                A[:, :2] = u
                A[:, 2] = np.einsum("ij,ij->i", u, d_turned)
                A[np.arange(len(z)), bias_col] = 1.0
                b = z - h + A @ x_new
                scale = weights / cfg.range_sigma_m
                rows = (A * scale[:, None], b * scale)
            R, x_new = step.solve(*rows)
        self.x, self.sqrt_info = x_new, R
        return self.tag_xy(self.x), labels


def calibrated_config(setting: dict[str, float] | None = None) -> UwbConfig:
    """The tracker when the session declares a range calibration: the biases constant (the calibration's, refined by
    the data: a walk of 1e-6 m/sqrt(s) is numerically constant over hours), the range noise of a moving tag and the
    assignment's sigma as ``tune uwb_calibrated`` chose them by leave-one-run-out (``tuned.toml``)."""
    from ..tuned import tuned

    chosen = setting if setting is not None else tuned("uwb_calibrated")
    return UwbConfig(range_sigma_m=float(chosen["range_sigma_m"]), bias_walk_m_sqrt_s=1e-6, assoc_sigma_m=chosen.get("assoc_sigma_m"))


def ranges_by_receiver(epochs: RangeEpochs, tags: int) -> FloatArray:
    """(K, R, tags) distances per epoch and receiver in the order heard (NaN where fewer were heard; an epoch that
    heard more than ``tags`` at a receiver keeps its shortest ``tags``: the others are echoes)."""
    out = np.full((len(epochs.t), len(epochs.receivers), tags), np.nan)
    for k, per_receiver in enumerate(epochs.ranges):
        for r, heard in enumerate(per_receiver):
            n = min(len(heard), tags)
            out[k, r, :n] = heard[:n]
    return out


def track_rigid(epochs: RangeEpochs, tag_offsets_m: FloatArray, config: UwbConfig | None = None, labelled: bool = False,
                select_s: float = 20.0, calibration: RangeCalibration | None = None) -> TrackingRun:
    """Every tag of one rigid body from its ranges (unlabelled: each receiver's distances in arrival order).

    The offsets' handedness seen from above is not decidable from one epoch (a motion-capture body frame may be
    upside down): both are tracked for ``select_s`` seconds and the one whose ranges fit better (Cauchy cost) is
    kept; the run then restarts with it. The start uses the first second of ranges, buffered.
    ``labelled``: the ranges of each receiver are in tag order (a ranging system that knows its tags).
    """
    offsets = np.asarray(tag_offsets_m, dtype=float)
    tags = len(offsets)
    ranges = ranges_by_receiver(epochs, tags)
    first = ranges[: max(1, int(np.searchsorted(epochs.t, epochs.t[0] + 1.0)))]
    window = int(np.searchsorted(epochs.t, epochs.t[0] + select_s))
    costs = {}
    for handed in (1.0, -1.0):
        trial = UwbTracker(epochs.receivers, offsets, config, calibration)
        trial.start(first, labelled, mirror=handed)
        for k in range(window):
            trial.step(float(epochs.t[k]), ranges[k], labelled)
        costs[handed] = trial.cost
    tracker = UwbTracker(epochs.receivers, offsets, config, calibration)
    tracker.start(first, labelled, mirror=min(costs, key=costs.__getitem__))
    positions, times = np.zeros((len(epochs.t), tags, 3)), np.zeros(len(epochs.t))
    labels: list[list[np.ndarray]] = []
    for k, t in progress(enumerate(epochs.t), len(epochs.t), "rigid-body tracks (epochs)"):
        start = time.perf_counter()
        xy, given = tracker.step(float(t), ranges[k], labelled)
        times[k] = 1e3 * (time.perf_counter() - start)
        positions[k, :, :2] = xy
        positions[k, :, 2] = tracker.height
        labels.append([given[r, : len(heard)] if len(heard) <= tags else np.r_[given[r], np.full(len(heard) - tags, -1)]
                       for r, heard in enumerate(epochs.ranges[k])])
    extras = {"mirror": float(tracker.mirror), "assoc_expected_geometry": association_self_check(epochs, positions)}
    return TrackingRun(positions, labels, times, extras)


