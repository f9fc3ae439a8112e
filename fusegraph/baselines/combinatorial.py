"""The fourth founding paper's association by combinatorial search (the baseline), epoch by epoch.

Choose three receivers that heard exactly N distances (all transmitters, no echo); keep the first
one's order, permute the other two rows of the distance matrix; for each hypothesis trilaterate
every column and score it by how well the other receivers' distances agree; repeat with other
triples; keep the best. Then every receiver's distances are assigned to the located points and each
point is refined on its distances. Hypotheses grow as (N!)^2: with full enumeration up to
``max_enumerated`` hypotheses, beyond that random hypotheses until ``time_cap_s`` (say so).
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass

import numpy as np

from ..frontends.association import assign_ranges, refine, trilaterate
from ..geometry import FloatArray


@dataclass(frozen=True)
class CombinatorialConfig:
    """Search limits of the baseline."""

    tolerance_m: float = 0.03
    """A distance further than this from a column's prediction scores as a miss."""
    triples: int = 3
    """Receiver triples tried per epoch ("repeat"), well spread first."""
    max_enumerated: int = 1_000_000
    """Enumerate every hypothesis up to this many ((N!)^2: N <= 6)."""
    time_cap_s: float = 0.05
    """Beyond, random hypotheses until this time per triple."""


def _column_costs(
    receivers: FloatArray, ranges: list[FloatArray], triple: tuple[int, int, int], others: list[int], tol: float
) -> tuple[FloatArray, FloatArray]:
    """Points and costs of every (i, j, k) choice of one distance per receiver of the triple."""
    a, b, c = (ranges[r] for r in triple)
    n = len(a)
    grid = np.array(np.meshgrid(np.arange(n), np.arange(n), np.arange(n), indexing="ij")).reshape(3, -1).T
    points, valid = trilaterate(receivers[list(triple)], np.column_stack([a[grid[:, 0]], b[grid[:, 1]], c[grid[:, 2]]]))
    cost = np.zeros(len(points))
    for r in others:
        if len(ranges[r]) == 0:
            continue
        predicted = np.linalg.norm(points - receivers[r], axis=1)
        cost += np.minimum(np.abs(predicted[:, None] - ranges[r][None, :]).min(axis=1), tol)
    cost[~valid] = 1e6
    return points.reshape(n, n, n, 3), cost.reshape(n, n, n)


def _search(costs: FloatArray, config: CombinatorialConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float, bool]:
    """Best (perm2, perm3) for sum_c cost[c, perm2[c], perm3[c]]; True when every hypothesis was tried."""
    n = costs.shape[0]
    columns = np.arange(n)
    if math.factorial(n) ** 2 <= config.max_enumerated:
        perms = np.array(list(itertools.permutations(range(n))))
        # total[p2, p3] = sum_c costs[c, perms[p2, c], perms[p3, c]]
        total = np.zeros((len(perms), len(perms)))
        for c in columns:
            total += costs[c][perms[:, c]][:, perms[:, c]]
        i2, i3 = np.unravel_index(int(np.argmin(total)), total.shape)
        return perms[i2], perms[i3], float(total[i2, i3]), True
    best = (columns, columns, np.inf)
    deadline = time.perf_counter() + config.time_cap_s
    while time.perf_counter() < deadline:
        p2 = np.argsort(rng.random((2048, n)), axis=1)
        p3 = np.argsort(rng.random((2048, n)), axis=1)
        total = costs[columns[None, :], p2, p3].sum(axis=1)
        i = int(np.argmin(total))
        if total[i] < best[2]:
            best = (p2[i], p3[i], float(total[i]))
    return best[0], best[1], best[2], False


def combinatorial_epoch(
    receivers: FloatArray, ranges: list[FloatArray], transmitters: int, range_sigma_m: float, config: CombinatorialConfig | None = None, seed: int = 0
) -> tuple[FloatArray, list[np.ndarray], bool]:
    """Positions (N, 3) (NaN when no three receivers heard all N), labels per receiver, and whether the search was exhaustive."""
    cfg = config or CombinatorialConfig()
    n = transmitters
    complete = [r for r in range(len(receivers)) if len(ranges[r]) == n]
    positions = np.full((n, 3), np.nan)
    labels = [np.full(len(x), -1) for x in ranges]
    if len(complete) < 3:
        return positions, labels, True
    # well-spread triples among the receivers that heard everything
    def area(t: tuple[int, ...]) -> float:
        return float(np.linalg.norm(np.cross(receivers[t[1]] - receivers[t[0]], receivers[t[2]] - receivers[t[0]])))

    # collinear triples (a grid has many) cannot trilaterate: left out; none left, no estimate this epoch
    triples = sorted((t for t in itertools.combinations(complete, 3) if area(t) > 1e-6), key=area, reverse=True)[: cfg.triples]
    if not triples:
        return positions, labels, True
    rng = np.random.default_rng(seed)
    best_cost, exhaustive = np.inf, True
    for triple in triples:
        others = [r for r in range(len(receivers)) if r not in triple]
        points, costs = _column_costs(receivers, ranges, triple, others, cfg.tolerance_m)
        p2, p3, cost, full = _search(costs, cfg, rng)
        exhaustive &= full
        if cost < best_cost:
            best_cost = cost
            positions = points[np.arange(n), p2, p3]
    # every receiver's distances to the located points, then each point refined on its distances
    for r in range(len(receivers)):
        predicted = np.linalg.norm(positions - receivers[r], axis=1)
        labels[r] = assign_ranges(ranges[r], predicted, np.full(n, max(3 * range_sigma_m, 0.01)))
    for i in range(n):
        rows = [(r, j) for r in range(len(receivers)) for j in np.nonzero(labels[r] == i)[0]]
        if len(rows) >= 4:
            positions[i] = refine(positions[i], receivers[[r for r, _ in rows]], np.array([ranges[r][j] for r, j in rows]))
    return positions, labels, exhaustive
