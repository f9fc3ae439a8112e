"""Ultrasonic 3D tags with unknown data association: fusegraph's tracker, the paper's search, scoring, bench.

fusegraph: every transmitter's state (position, velocity) is a variable of a small graph per epoch:
the previous marginal (a prior), the motion law, and the ranges from known receivers that the
association gave it. Objects handled by people rest and move, so the motion law is one of several
models (REST, a smooth and an agile constant velocity) and the estimate an interacting
multiple-model mixture of them (``solvers.multiple_model``, all transmitters and models in the same
batched solve). The association comes from the prediction: per receiver, an optimal assignment of the
sorted distances to the predicted ones, gated by the predicted range uncertainty; neighbouring
distances are shared between their two tracks by the probability that they swapped; a Cauchy kernel
takes what slips through; then the whole is associated and solved once more from the solution. A
track that loses its ranges, or duplicates another, is re-initialised from the distances nobody
explains (``frontends.association.locate``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..factors.linear import robust
from ..frontends.association import assign_receivers, locate, swap_probability
from ..geometry import FloatArray
from ..records import RangeEpochs
from ..results import TrackingRun
from ..solvers.multiple_model import REST, MotionModes, PointBank, Prediction


@dataclass(frozen=True)
class TrackerConfig:
    """Motion models, gating and track maintenance of the fusegraph tracker."""

    modes: MotionModes = field(default_factory=MotionModes)
    """The REST and MOVE motion models and their switching (an IMM per transmitter)."""
    gate_chi2: float = 16.0
    """Association gate on the squared normalised range innovation (4 sigma)."""
    gate_floor_m: float = 0.01
    """Smallest predicted-range sigma used in the gate, metres (model error of the motion law)."""
    cauchy_k: float = 3.0
    """Cauchy kernel width in range sigmas (reweighting on the second iteration)."""
    outlier_sigmas: float = 6.0
    """An assigned range further than this from the solution is dropped (label -1)."""
    lost_after: int = 8
    """A track with fewer than ``min_ranges`` inliers for this many epochs is lost."""
    min_ranges: int = 4
    """Inlier ranges a track needs per epoch to count as seen."""
    duplicate_m: float = 0.008
    """Two tracks closer than this: the one with fewer inliers is lost (it latched onto the other's ranges).
    Real transmitters rest 3 cm apart in the scenario: 3 cm here made tracks flap between lost and found."""
    recover_every: int = 5
    """Look for untracked transmitters in the unassigned ranges every this many epochs (always when a track is lost)."""
    recover_support: int = 8
    """Receivers that must agree on an untracked transmitter before a track moves there."""
    reassociate: bool = True
    """Associate a second time with the solved positions and solve again."""
    settle_s: float = 0.5
    """A new track is carried by the moving models only for this long: its start comes from one epoch's
    prior-free location, possibly on a neighbour's distances, and REST would average that in place
    (measured: two resting tracks held 4-5 cm off for 1.5 s at start-up, seed 5 at N = 12)."""
    soft_pairs: bool = True
    """Neighbouring distances at a receiver are shared between their two tracks by the probability of a swap."""


Predicted = tuple[FloatArray, FloatArray]
"""Predicted range and its sigma (receivers x tracks) that an association used, metres."""


@dataclass
class StepResult:
    positions: FloatArray
    """(N, 3) every track's position, metres; NaN while a track is lost."""
    labels: list[np.ndarray]
    """Per receiver: the track of each sorted distance, or -1 (echo / unexplained)."""


class UltrasonicTracker:
    """Online tracker of N transmitters from unlabelled ranges."""

    def __init__(self, receivers: FloatArray, transmitters: int, range_sigma_m: float = 0.005, config: TrackerConfig | None = None):
        self.receivers = np.asarray(receivers, dtype=float)
        self.n = transmitters
        self.sigma = range_sigma_m
        self.config = config or TrackerConfig()
        self.bank = PointBank(transmitters, self.config.modes)
        self.lost = np.ones(transmitters, dtype=bool)
        self.missed = np.zeros(transmitters, dtype=int)
        self.inliers = np.zeros(transmitters, dtype=int)
        self.started_s = np.zeros(transmitters)
        self._t: float | None = None
        self._epoch = 0
        self.reinitialisations = 0

    def _start(self, i: int, position_m: FloatArray, t: float) -> None:
        self.bank.reset(i, position_m)
        self.lost[i], self.missed[i] = False, 0
        self.started_s[i] = t

    def step(self, t: float, ranges: list[FloatArray]) -> StepResult:
        cfg = self.config
        if self._t is None:
            for i, f in enumerate(locate(self.receivers, ranges, self.n)):
                self._start(i, f.position_m, t)
        dt = max(t - self._t, 1e-3) if self._t is not None else 0.025  # the first epoch: a nominal step from a static start
        self._t = t
        lost = self.lost.copy()
        frozen = (self.bank.x[lost], self.bank.P[lost], self.bank.mu[lost])  # a lost track keeps its last state
        young = ~self.lost & (t - self.started_s < cfg.settle_s)
        if young.any():
            self.bank.forbid(young, REST)
        prediction = self.bank.predict(dt)
        active = np.nonzero(~self.lost)[0]
        counts = [len(m) for m in ranges]
        label_of, predicted = self._associate(ranges, *prediction.combined(), active)
        again = cfg.reassociate and len(active) > 0
        self._update(prediction, ranges, label_of, predicted, final=not again)
        if again:
            # associate again with the solved positions (mm, not the prediction's cm) and solve again,
            # one Gauss-Newton pass from that solution
            label_of, predicted = self._associate(ranges, *self.bank.combined(), active)
            self._update(prediction, ranges, label_of, predicted, final=True, linearise_at=self.bank.x)
        # (its prediction would only grow)
        for store, old in zip((self.bank.x, self.bank.P, self.bank.mu), frozen, strict=True):
            store[lost] = old
        labels = np.split(label_of, np.cumsum(counts)[:-1])
        self._maintain()
        if self.lost.any() or self._epoch % cfg.recover_every == 0:
            self._recover(ranges, labels, t)
        self._epoch += 1
        positions = self.bank.combined()[0][:, :3].copy()
        positions[self.lost] = np.nan  # a lost track has no estimate (its last one is kept inside, for recovery)
        return StepResult(positions, labels)

    def _associate(self, ranges: list[FloatArray], mean: FloatArray, cov: FloatArray, active: np.ndarray) -> tuple[np.ndarray, Predicted]:
        """Hard labels of every distance (flat, receiver-major) and the predicted ranges and sigmas they came from."""
        diff = mean[None, :, :3] - self.receivers[:, None, :]  # (R, T, 3)
        rho = np.linalg.norm(diff, axis=2)
        u = diff / rho[:, :, None]
        sigma = np.sqrt(np.einsum("rai,aij,raj->ra", u, cov[:, :3, :3], u) + self.sigma**2)
        gate_sigma = np.maximum(sigma, self.config.gate_floor_m)
        index = np.r_[active, -1]
        return index[assign_receivers(ranges, rho[:, active], gate_sigma[:, active], self.config.gate_chi2)], (rho, sigma)

    def _update(
        self, prediction: Prediction, ranges: list[FloatArray], label_of: np.ndarray, predicted: Predicted, final: bool,
        linearise_at: FloatArray | None = None,
    ) -> None:
        """Every track's ranges as (tracks x receivers) tables (the assignment gives a track at most one
        distance per receiver), one batched update; assigned distances far from the solution become -1.

        Soft pairs: at a receiver, two neighbouring distances (in arrival order) assigned to tracks i and j
        could be the other way round; with probability q (from the same predicted ranges and sigmas)
        they are. Each track then weighs its own distance by 1 - q and the neighbour's by q (the EM
        weights of the two-way mixture). Hard labels alone pull two close resting transmitters to a
        self-consistent wrong pair of positions (measured: 13 mm off at 2.7 cm apart)."""
        receiver_of = np.repeat(np.arange(len(ranges)), [len(m) for m in ranges])
        z_all = np.concatenate(ranges) if ranges else np.zeros(0)
        mine = np.nonzero(label_of >= 0)[0]
        own_weight = np.ones(len(mine))
        # every (track, receiver, distance, weight) row: its own distances, then the shared neighbours
        rows = [(label_of[mine], receiver_of[mine], z_all[mine])]
        shared = []
        if self.config.soft_pairs and len(mine) > 1:
            rho, sigma = predicted
            a, b = mine[:-1], mine[1:]
            pair = receiver_of[a] == receiver_of[b]
            a, b, first = a[pair], b[pair], np.nonzero(pair)[0]
            r, i, j = receiver_of[a], label_of[a], label_of[b]
            q = swap_probability(z_all[a], z_all[b], rho[r, i], rho[r, j], sigma[r, i], sigma[r, j])
            own_weight[first] -= q
            own_weight[first + 1] -= q
            real = q > 1e-4  # the rest carry no information: left out of the tables
            rows += [(i[real], r[real], z_all[b][real]), (j[real], r[real], z_all[a][real])]
            shared = [q[real], q[real]]
        track = np.concatenate([x[0] for x in rows])
        anchor = np.concatenate([x[1] for x in rows])
        z = np.concatenate([x[2] for x in rows])
        w = np.concatenate([np.clip(own_weight, 0.0, 1.0), *shared])
        # packed per track: column c of track t is its c-th row (a track has at most a few per receiver)
        order = np.argsort(track, kind="stable")
        track, anchor, z, w = track[order], anchor[order], z[order], w[order]
        counts = np.bincount(track, minlength=self.n)
        column = np.arange(len(track)) - np.repeat(np.cumsum(counts) - counts, counts)
        width = max(int(counts.max(initial=0)), 1)
        table = np.full((self.n, width), np.nan)
        weights = np.zeros((self.n, width))
        anchors = np.tile(self.receivers[0], (self.n, width, 1))  # unused cells: any receiver (no weight)
        table[track, column], weights[track, column], anchors[track, column] = z, w, self.receivers[anchor]
        self.bank.update(
            prediction, anchors, table, self.sigma, self.config.cauchy_k, weights,
            linearise_at=linearise_at, iterations=1 if linearise_at is not None else 2, probabilities=final,
        )
        solved = self.bank.combined()[0][:, :3]
        residual = np.abs(z_all[mine] - np.linalg.norm(solved[label_of[mine]] - self.receivers[receiver_of[mine]], axis=1))
        outlier = np.zeros(len(label_of), dtype=bool)
        outlier[mine] = residual > self.config.outlier_sigmas * self.sigma
        inliers = np.bincount(label_of[(label_of >= 0) & ~outlier], minlength=self.n)
        label_of[outlier] = -1
        self.inliers = inliers
        self.missed = np.where(inliers < self.config.min_ranges, self.missed + 1, 0)

    def _maintain(self) -> None:
        cfg = self.config
        self.lost |= self.missed >= cfg.lost_after
        live = np.nonzero(~self.lost)[0]
        if len(live) < 2:
            return
        points = self.bank.combined()[0][live, :3]
        close = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2) < cfg.duplicate_m
        for a, b in zip(*np.nonzero(np.triu(close, 1)), strict=True):
            ia, ib = live[a], live[b]
            if not self.lost[ia] and not self.lost[ib]:
                self.lost[ia if self.inliers[ia] < self.inliers[ib] else ib] = True

    def _recover(self, ranges: list[FloatArray], labels: list[np.ndarray], t: float) -> None:
        free = [rng[lab < 0] for rng, lab in zip(ranges, labels, strict=True)]
        if sum(len(f) >= 1 for f in free) < self.config.recover_support:
            return
        lost = [int(i) for i in np.nonzero(self.lost)[0]]
        positions = self.bank.combined()[0][:, :3]
        live = positions[~self.lost]
        found = locate(self.receivers, free, max(len(lost), 1), min_support=self.config.recover_support, exclude_near=live, max_triples=2)
        for f in found:
            if lost:  # the lost track that was last nearest takes it (keeps identities through short losses)
                i = min(lost, key=lambda j: float(np.linalg.norm(positions[j] - f.position_m)))
                lost.remove(i)
            else:
                # an untracked transmitter while every track is live: one track wandered; move the weakest
                i = int(np.argmin(self.inliers))
            self._start(i, f.position_m, t)
            self.reinitialisations += 1
            # its distances now belong to it
            for r, j in f.used:
                idx = np.nonzero(labels[r] < 0)[0]
                if j < len(idx):
                    labels[r][idx[j]] = i


def run_fusegraph(epochs: RangeEpochs, transmitters: int, config: TrackerConfig | None = None) -> TrackingRun:
    tracker = UltrasonicTracker(epochs.receivers, transmitters, epochs.range_sigma_m, config)
    positions, labels, times, rest = [], [], [], []
    for k, t in enumerate(epochs.t):
        start = time.perf_counter()
        out = tracker.step(float(t), epochs.ranges[k])
        times.append(1e3 * (time.perf_counter() - start))
        positions.append(out.positions)
        labels.append(out.labels)
        rest.append(tracker.bank.mu[:, REST].copy())
    extras = {"reinitialisations": float(tracker.reinitialisations)}
    return TrackingRun(np.array(positions), labels, np.array(times), extras, np.array(rest))


def run_combinatorial(epochs: RangeEpochs, transmitters: int, config: object | None = None) -> TrackingRun:
    """The paper's search at every epoch (no tracking: each epoch stands alone)."""
    from ..baselines.combinatorial import CombinatorialConfig, combinatorial_epoch

    cfg = config if isinstance(config, CombinatorialConfig) else CombinatorialConfig()
    positions, labels, times = [], [], []
    capped = 0
    for k in range(len(epochs.t)):
        start = time.perf_counter()
        p, lab, exhaustive = combinatorial_epoch(epochs.receivers, epochs.ranges[k], transmitters, epochs.range_sigma_m, cfg, seed=k)
        times.append(1e3 * (time.perf_counter() - start))
        capped += int(not exhaustive)
        positions.append(p)
        labels.append(lab)
    return TrackingRun(np.array(positions), labels, np.array(times), {"capped_epochs": capped})


def smooth_tracks(epochs: RangeEpochs, run: TrackingRun, speed_sigma_m_s: float = 0.02, cauchy_k: float = 3.0) -> TrackingRun:
    """The batch: every transmitter's track smoothed over the whole session with the association the
    online pass made (its labels), in one gtsam graph solved by Levenberg-Marquardt.

    Per transmitter and epoch where the online pass tracked it, a Point3; consecutive ones are tied
    by a position random walk (``speed_sigma_m_s`` x sqrt(dt): objects handled by people, see the
    scenario; 0.02 m/sqrt(s) chosen from 0.02, 0.05, 0.1, 0.5 on TUNING seeds 100-101, 6 s, N = 3: position
    RMSE 5.5/3.8 mm against 10.6/9.3 mm at 0.5, the online pass 6.2/5.5 mm); each assigned distance is a ``RangeFactor3`` to its receiver (a Point3 pinned by a
    ``NonlinearEqualityPoint3``) with a Cauchy kernel. Epochs where a track was lost stay NaN.
    """
    start = time.perf_counter()
    k_count, n = run.positions.shape[:2]
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    receiver_keys = [int(gtsam.symbol("r", r)) for r in range(len(epochs.receivers))]
    for key, position in zip(receiver_keys, epochs.receivers, strict=True):
        values.insert(key, position)
        graph.add(gtsam.NonlinearEqualityPoint3(key, position))
    noise = robust(gtsam.noiseModel.Isotropic.Sigma(1, epochs.range_sigma_m), cauchy_k)
    have = np.all(np.isfinite(run.positions), axis=2)
    keys = np.array([[int(gtsam.symbol(chr(ord("A") + j), k)) for j in range(n)] for k in range(k_count)]) if n <= 26 else None
    if keys is None:
        raise ValueError(f"smooth_tracks: at most 26 transmitters (got {n})")
    for k in range(k_count):
        for j in np.nonzero(have[k])[0]:
            values.insert(int(keys[k, j]), run.positions[k, j])
            if k > 0 and have[k - 1, j]:
                dt = float(epochs.t[k] - epochs.t[k - 1])
                walk = gtsam.noiseModel.Isotropic.Sigma(3, speed_sigma_m_s * np.sqrt(dt))
                graph.add(gtsam.BetweenFactorPoint3(int(keys[k - 1, j]), int(keys[k, j]), np.zeros(3), walk))
        for r, labels in enumerate(run.labels[k]):
            for distance, j in zip(epochs.ranges[k][r], labels, strict=True):
                if j >= 0 and have[k, j]:
                    graph.add(gtsam.RangeFactor3(int(keys[k, j]), receiver_keys[r], float(distance), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(20)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    positions = np.full_like(run.positions, np.nan)
    for k, j in zip(*np.nonzero(have), strict=True):
        positions[k, j] = result.atPoint3(int(keys[k, j]))
    seconds = time.perf_counter() - start
    times = np.full(k_count, 1e3 * seconds / max(k_count, 1))
    return TrackingRun(positions, run.labels, times, {**run.extras, "batch_s": seconds})
