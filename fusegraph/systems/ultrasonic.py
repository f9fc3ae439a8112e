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
from pathlib import Path

import gtsam
import numpy as np

from ..factors.linear import robust
from ..frontends.association import assign_ranges, assign_receivers, locate
from ..geometry import FloatArray
from ..scenarios.ultrasonic import RangeEpochs
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
            keep = ((z_all[a] - rho[r, i]) / sigma[r, i]) ** 2 + ((z_all[b] - rho[r, j]) / sigma[r, j]) ** 2
            swap = ((z_all[a] - rho[r, j]) / sigma[r, j]) ** 2 + ((z_all[b] - rho[r, i]) / sigma[r, i]) ** 2
            q = 1.0 / (1.0 + np.exp(np.clip(0.5 * (swap - keep), -50.0, 50.0)))
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


@dataclass
class TrackingRun:
    """A method's output over a session."""

    positions: FloatArray
    """(K, N, 3) estimated positions, in the method's own transmitter order."""
    labels: list[list[np.ndarray]]
    """Per epoch and receiver: the method's transmitter of each distance, or -1."""
    ms_per_epoch: FloatArray
    """Processing time of every epoch, ms."""
    extras: dict[str, float] = field(default_factory=dict)
    rest_probability: FloatArray | None = None
    """(K, N) probability of the REST motion model per transmitter (fusegraph only)."""


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


def oracle_labels(epochs: RangeEpochs, gate_chi2: float = 16.0) -> list[list[np.ndarray]]:
    """The limit: each receiver's distances assigned against the TRUE positions (same assignment and gate)."""
    assert epochs.positions is not None
    out = []
    sigma = np.full(epochs.transmitters, epochs.range_sigma_m)
    for k in range(len(epochs.t)):
        predicted = np.linalg.norm(epochs.positions[k][None, :, :] - epochs.receivers[:, None, :], axis=2)
        out.append([assign_ranges(epochs.ranges[k][r], predicted[r], sigma, gate_chi2) for r in range(len(epochs.receivers))])
    return out


def identity_map(estimate: FloatArray, truth: FloatArray) -> np.ndarray:
    """Method's transmitter index -> truth index by an optimal matching of positions (one epoch)."""
    from scipy.optimize import linear_sum_assignment

    cost = np.linalg.norm(estimate[:, None, :] - truth[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.nan_to_num(cost, nan=1e6))
    mapping = np.full(len(estimate), -1)
    mapping[rows] = cols
    return mapping


@dataclass(frozen=True)
class AssociationScore:
    """Association accuracy (fractions) and position accuracy of one run."""

    assoc_acc: float
    """Over all distances: direct ones given their transmitter, echoes left out."""
    assoc_acc_unambiguous: float
    """Over echoes and the direct distances more than 2 cm from every other transmitter's at that receiver."""
    rmse_m: float
    """Position RMSE over the transmitter-epochs that are tracked (within 5 cm), metres."""
    rmse_all_m: float
    """Position RMSE over every transmitter-epoch with an estimate, lost ones included, metres."""
    lost_frac: float
    """Transmitter-epochs with no estimate within 5 cm (track loss)."""
    identity_swaps: int
    """Times the matching of the method's transmitters to the truth changed from one epoch to the next."""


def score_run(epochs: RangeEpochs, labels: list[list[np.ndarray]], positions: FloatArray | None) -> AssociationScore:
    """Score a run. Each epoch, the method's transmitters are matched to the truth by position (the
    association question is which distance belongs to which transmitter; keeping identities over time
    is counted apart, as swaps). ``positions`` None: the labels are truth indices already (oracle)."""
    assert epochs.labels is not None and epochs.positions is not None
    correct = total = correct_u = total_u = 0
    errors, swaps, previous = [], 0, None
    for k in range(len(epochs.t)):
        truth_k = epochs.positions[k]
        mapping = None
        if positions is not None:
            mapping = identity_map(positions[k], truth_k)
            if previous is not None:
                swaps += int(np.sum(mapping != previous)) // 2
            previous = mapping
            matched = np.full((epochs.transmitters, 3), np.nan)
            matched[mapping[mapping >= 0]] = positions[k][mapping >= 0]
            errors.append(np.linalg.norm(matched - truth_k, axis=1))
        direct = np.linalg.norm(truth_k[None, :, :] - epochs.receivers[:, None, :], axis=2)
        for r in range(len(epochs.receivers)):
            truth = epochs.labels[k][r]
            guess = labels[k][r]
            if mapping is not None:
                guess = np.where(guess >= 0, mapping[np.clip(guess, 0, None)], -1)
            want = np.where(truth >= 0, truth, -1)
            hit = guess == want
            correct += int(hit.sum())
            total += len(truth)
            # unambiguous: echoes, and direct distances > 2 cm from every OTHER transmitter's direct distance
            own = np.clip(truth, 0, None)
            others = np.abs(direct[r][None, :] - direct[r][own][:, None])
            others[np.arange(len(truth)), own] = np.inf
            clear = (truth < 0) | (others.min(axis=1, initial=np.inf) > 0.02)
            correct_u += int(hit[clear].sum())
            total_u += int(clear.sum())
    rmse = rmse_all = lost = float("nan")
    if errors:
        err = np.nan_to_num(np.array(errors), nan=np.inf)
        finite = np.isfinite(err)
        tracked = err <= 0.05
        rmse = float(np.sqrt(np.mean(err[tracked] ** 2))) if tracked.any() else float("nan")
        rmse_all = float(np.sqrt(np.mean(err[finite] ** 2))) if finite.any() else float("nan")
        lost = float(np.mean(~tracked))
    return AssociationScore(correct / max(total, 1), correct_u / max(total_u, 1), rmse, rmse_all, lost, swaps)


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


def crossing_epochs(closest_m: float, speed_m_s: float, head_on: bool, seed: int = 0, rate_hz: float = 40.0) -> RangeEpochs:
    """Two transmitters passing each other: head-on (opposite directions) or side by side (one overtakes)."""
    from ..scenarios.ultrasonic import UltrasonicScenarioConfig, hear

    cfg = UltrasonicScenarioConfig(transmitters=2, rate_hz=rate_hz)
    t = np.arange(0.0, 3.0, 1.0 / rate_hz)
    centre = np.array([1.0, 0.75, 0.9])
    s = np.clip((t - 0.5) / 2.0, 0.0, 1.0)  # both move for 2 s, passing at the middle
    a = centre + np.outer(speed_m_s * 2.0 * (s - 0.5), [1.0, 0.0, 0.0]) + [0.0, -closest_m / 2, 0.0]
    if head_on:
        b = centre + np.outer(-speed_m_s * 2.0 * (s - 0.5), [1.0, 0.0, 0.0]) + [0.0, closest_m / 2, 0.0]
    else:  # side by side: b starts ahead at half the speed, a overtakes it at the middle
        b = centre + np.outer(0.5 * speed_m_s * 2.0 * (s - 0.5), [1.0, 0.0, 0.0]) + [0.0, closest_m / 2, 0.0]
    positions = np.stack([a, b], axis=1)
    rng = np.random.default_rng(seed)
    ranges, labels = hear(positions, cfg.receivers, rng, cfg)
    return RangeEpochs(t, cfg.receivers.copy(), ranges, labels, positions, cfg.range_sigma_m)


def bench_ultrasonic(
    transmitter_counts: tuple[int, ...] = (3, 6, 12),
    seeds: tuple[int, ...] = (0, 1, 2),
    duration_s: float = 20.0,
    baseline_s: float = 5.0,
    show_progress: bool = True,
    uwb_dir: str | None = "default",
    plot: str | Path | None = None,
    peer_s: float = 2.0,
    peers: tuple[str, ...] = ("gnn", "jpda"),
) -> dict[str, object]:
    """Simulation (both methods and the oracle per N), crossings; the JSON of ``fusegraph bench ultrasonic``.
    ``plot``: a PNG of fusegraph's run at the largest N and the first seed (``plot_ultrasonic``).
    ``peers``: Stone Soup's trackers (``stonesoup_gnn``, ``stonesoup_jpda``, with their tuned settings) on the first
    ``peer_s`` seconds (Stone Soup needs ~1 s per epoch at N = 12), beside ``fusegraph_peer_window``: fusegraph's causal
    run scored on the same epochs."""
    from ..baselines.stonesoup_peer import run_stonesoup, tuned_config
    from ..progress import progress
    from ..scenarios.ultrasonic import simulate_ultrasonic

    sim: dict[str, dict[str, dict[str, float]]] = {}
    jobs = [(n, seed) for n in transmitter_counts for seed in seeds]
    rows: dict[tuple[int, str], list[dict[str, float]]] = {}
    for n, seed in progress(jobs, desc="bench ultrasonic", enabled=None if show_progress else False):
        epochs = simulate_ultrasonic(seed, transmitters=n, duration_s=duration_s)
        oracle = score_run(epochs, oracle_labels(epochs), None)
        short = _head(epochs, baseline_s)
        ours = run_fusegraph(epochs, n)
        if plot is not None and n == max(transmitter_counts) and seed == seeds[0]:
            plot_ultrasonic(epochs, ours, plot)
        window = _head(epochs, peer_s)
        compared: list[tuple[str, TrackingRun, RangeEpochs]] = [("fusegraph", ours, epochs), ("combinatorial", run_combinatorial(short, n), short)]
        if peers:
            compared.append(("fusegraph_peer_window", _first_epochs(ours, len(window.t)), window))
            compared += [(f"stonesoup_{p}", run_stonesoup(window, n, p, tuned_config(p)), window) for p in peers]
        for method, run, scored in compared:
            score = score_run(scored, run.labels, run.positions)
            oracle_here = oracle if scored is epochs else score_run(scored, oracle_labels(scored), None)
            rows.setdefault((n, method), []).append({
                "assoc_acc": score.assoc_acc,
                "assoc_acc_unambiguous": score.assoc_acc_unambiguous,
                "oracle_acc": oracle_here.assoc_acc,
                "oracle_acc_unambiguous": oracle_here.assoc_acc_unambiguous,
                "rmse_m": score.rmse_m,
                "rmse_all_m": score.rmse_all_m,
                "lost_frac": score.lost_frac,
                "identity_swaps": float(score.identity_swaps),
                "ms_per_epoch": float(np.mean(run.ms_per_epoch)),
                "ms_p99": float(np.percentile(run.ms_per_epoch, 99)),
                "seconds_scored": float(scored.t[-1] - scored.t[0] + 1 / 40),
                "capped_epochs": float(run.extras.get("capped_epochs", 0)),
            })
    for (n, method), runs in rows.items():
        sim.setdefault(str(n), {})[method] = {key: float(np.mean([r[key] for r in runs])) for key in runs[0]}
        sim[str(n)][method]["ms_p99"] = float(np.max([r["ms_p99"] for r in runs]))  # the worst seed's p99
    swaps = runs_done = 0
    for closest in (0.05, 0.07, 0.10):
        for speed in (0.3, 0.6, 1.0):
            for head_on in (True, False):
                epochs = crossing_epochs(closest, speed, head_on, seed=runs_done)
                run = run_fusegraph(epochs, 2)
                assert epochs.positions is not None
                start = identity_map(run.positions[0], epochs.positions[0])
                end = identity_map(run.positions[-1], epochs.positions[-1])
                swaps += int(np.any(start != end))
                runs_done += 1
    uwb: dict[str, float] | None = None
    uwb_status = "skipped"
    if uwb_dir is not None:
        from ..datasets.uwb_lias import DEFAULT_DIR, load_uwb_lias
        from .uwb import run_uwb

        directory = DEFAULT_DIR if uwb_dir == "default" else Path(uwb_dir)
        uwb_status = f"recording not found at {directory}"
        if directory.is_dir():
            uwb_status = "ran"
            found = run_uwb(load_uwb_lias(directory))
            uwb = {
                "labelled_rmse_m": found.labelled_rmse_m,
                "unlabelled_rmse_m": found.unlabelled_rmse_m,
                "assoc_acc": found.assoc_acc,
                "clock_offset_s": found.clock_offset_s,
                "ms_per_epoch": found.ms_per_epoch,
                "assoc_expected_geometry": found.assoc_expected,
            }
    return {"sim": sim, "crossing": {"runs": runs_done, "swaps": swaps}, "uwb": uwb, "uwb_status": uwb_status}


def _first_epochs(run: TrackingRun, count: int) -> TrackingRun:
    """A causal run's output over its first epochs (what it gave there, whatever came later)."""
    return TrackingRun(run.positions[:count], run.labels[:count], run.ms_per_epoch[:count], dict(run.extras))


def _head(epochs: RangeEpochs, seconds: float) -> RangeEpochs:
    keep = int(np.searchsorted(epochs.t, epochs.t[0] + seconds))
    return RangeEpochs(
        epochs.t[:keep], epochs.receivers, epochs.ranges[:keep], None if epochs.labels is None else epochs.labels[:keep],
        None if epochs.positions is None else epochs.positions[:keep], epochs.range_sigma_m,
    )


def plot_ultrasonic(epochs: RangeEpochs, run: TrackingRun, path: str | Path) -> None:
    """Top view of every transmitter (truth and estimate), each one's error over time, and the REST
    model's probability beside the truth's rests."""
    from ..report.plots import plt, save_figure  # headless pyplot

    assert epochs.positions is not None
    truth = epochs.positions
    n = truth.shape[1]
    mapping = np.array([identity_map(run.positions[k], truth[k]) for k in range(len(epochs.t))])  # (K, N): track -> truth
    matched = np.full_like(truth, np.nan)
    rest = np.full(truth.shape[:2], np.nan)
    for k in range(len(epochs.t)):
        ok = mapping[k] >= 0
        matched[k, mapping[k][ok]] = run.positions[k][ok]
        if run.rest_probability is not None:
            rest[k, mapping[k][ok]] = run.rest_probability[k][ok]
    error_mm = 1e3 * np.linalg.norm(matched - truth, axis=2)
    speed = np.linalg.norm(np.gradient(truth, epochs.t, axis=0), axis=2)
    fig = plt.figure(figsize=(15, 8))
    grid = fig.add_gridspec(2, 2, width_ratios=[1, 1.4])
    top, err, modes = fig.add_subplot(grid[:, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])
    colours = plt.get_cmap("tab20")(np.arange(n) % 20)
    top.plot(epochs.receivers[:, 0], epochs.receivers[:, 1], "ks", ms=5, label="receiver (2.5 m up)")
    for i in range(n):
        top.plot(truth[:, i, 0], truth[:, i, 1], "-", color=colours[i], lw=3, alpha=0.3)
        top.plot(matched[:, i, 0], matched[:, i, 1], "-", color=colours[i], lw=0.8)
        err.plot(epochs.t, error_mm[:, i], color=colours[i], lw=0.6)
    top.plot([], [], "k-", lw=3, alpha=0.3, label="truth")
    top.plot([], [], "k-", lw=0.8, label="fusegraph")
    top.set(xlabel="x (m)", ylabel="y (m)", title=f"{n} transmitters, top view", aspect="equal")
    top.legend(fontsize=8, loc="lower right")
    err.axhline(50.0, color="r", ls=":", lw=1)
    err.set(yscale="log", ylim=(0.1, 500), ylabel="position error (mm)", title="error per transmitter (red: 5 cm, track lost)")
    picture = np.where(speed < 0.01, 1.0, 0.0) * 0.5 + np.nan_to_num(rest) * 0.5  # both at rest: 1, neither: 0
    modes.imshow(picture.T, aspect="auto", cmap="viridis", vmin=0, vmax=1, interpolation="nearest",
                 extent=(epochs.t[0], epochs.t[-1], n - 0.5, -0.5))
    modes.set(xlabel="time (s)", ylabel="transmitter",
              title="REST: truth at rest and model probability (yellow both, teal one of them, purple neither)")
    save_figure(fig, path)


def format_ultrasonic_table(result: dict[str, object]) -> str:
    sim = result["sim"]
    assert isinstance(sim, dict)
    header = f"{'N':>3} {'method':<22}{'assoc':>8}{'unamb.':>8}{'oracle':>8}{'or.unamb':>9}{'rmse mm':>9}{'all mm':>8}{'lost %':>8}{'swaps':>7}"
    lines = [header + f"{'ms/ep':>8}{'p99 ms':>8}{'s':>6}{'capped':>8}"]
    for n, methods in sim.items():
        for method, r in methods.items():
            lines.append(
                f"{n:>3} {method:<22}{r['assoc_acc']:>8.4f}{r['assoc_acc_unambiguous']:>8.4f}{r['oracle_acc']:>8.4f}{r['oracle_acc_unambiguous']:>9.4f}"
                f"{1e3 * r['rmse_m']:>9.1f}{1e3 * r['rmse_all_m']:>8.0f}{100 * r['lost_frac']:>8.2f}{r['identity_swaps']:>7.1f}"
                f"{r['ms_per_epoch']:>8.2f}{r['ms_p99']:>8.2f}{r['seconds_scored']:>6.0f}{r['capped_epochs']:>8.0f}"
            )
    crossing = result["crossing"]
    assert isinstance(crossing, dict)
    lines.append(f"crossings (closest approach 5, 7, 10 cm; 0.3-1 m/s; head-on and side by side): {crossing['swaps']} identity swaps "
                 f"in {crossing['runs']} runs")
    lines.append("means over seeds (p99: the worst seed); accuracies as fractions; rmse over tracked transmitter-epochs (within 5 cm), "
                 "all = every epoch with an estimate;")
    lines.append("the combinatorial search runs on the first s seconds (capped = epochs where its time cap stopped the search); "
                 "Stone Soup's GNN and JPDA (tuned settings) on the first s seconds too, beside fusegraph's run scored there (peer window)")
    uwb = result.get("uwb")
    if isinstance(uwb, dict):
        lines.append(
            f"uwb (3 tags, 8 anchors, height held): labelled RMSE {uwb['labelled_rmse_m']:.3f} m, unlabelled {uwb['unlabelled_rmse_m']:.3f} m "
            f"(ratio {uwb['unlabelled_rmse_m'] / uwb['labelled_rmse_m']:.2f}), association {uwb['assoc_acc']:.3f}, "
            f"clock offset {uwb['clock_offset_s'] * 1e3:.0f} ms (raw ranges vs motion capture), {uwb['ms_per_epoch']:.2f} ms/epoch; "
            f"self-check: association from geometry alone {uwb.get('assoc_expected_geometry', float('nan')):.2f} (a lower bound, no truth)"
        )
    else:
        lines.append(f"uwb: {result.get('uwb_status', 'not run')} (--uwb DIR)")
    return "\n".join(lines)


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
