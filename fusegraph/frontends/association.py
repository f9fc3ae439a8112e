"""Unknown data association of ranges: per-receiver optimal assignment, and locating transmitters without a prior.

``assign_ranges``: one receiver's sorted distances against predicted distances of the tracks: an
optimal assignment (Hungarian, ``scipy.optimize.linear_sum_assignment``) with a chi-square gate and
one "leave it unassigned" option per distance (echoes, transmitters nobody tracks).

``locate``: positions supported by the most receivers, without any prior: trilaterate every
combination of the distances heard by three well-spread receivers, count the other receivers that
heard a distance within ``tolerance_m`` of the candidate's, keep the best, refine by Gauss-Newton,
remove its distances and repeat. It (re)initialises tracks from unassigned distances.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..geometry import FloatArray
from ..records import RangeEpochs


def _assign(chi2: FloatArray, gate_chi2: float) -> np.ndarray:
    """Optimal assignment of rows (distances) to columns (tracks) with a "leave it out" option of cost
    ``gate_chi2`` per row. Clipping every cost at the gate is the same problem as one dummy column
    per row: a row parked on an out-of-gate track pays what the dummy would, and with more rows than
    tracks the rows left over would all pay the gate anyway (a constant). The matrix stays m x n.
    A NaN cost (no prediction) is outside the gate (``fmin`` takes the gate, the comparison fails)."""
    m, n = chi2.shape
    out = np.full(m, -1)
    if m == 0 or n == 0:
        return out
    rows, cols = linear_sum_assignment(np.fmin(chi2, gate_chi2))
    inside = chi2[rows, cols] <= gate_chi2
    out[rows[inside]] = cols[inside]
    return out


def assign_ranges(measured_m: FloatArray, predicted_m: FloatArray, sigma_m: FloatArray, gate_chi2: float = 16.0) -> np.ndarray:
    """Index of the track each measured distance belongs to, or -1 (unassigned)."""
    chi2 = ((np.asarray(measured_m)[:, None] - np.asarray(predicted_m)[None, :]) / np.asarray(sigma_m)[None, :]) ** 2
    return _assign(chi2.reshape(len(measured_m), len(predicted_m)), gate_chi2)


def assign_receivers(ranges: list[FloatArray], predicted_m: FloatArray, sigma_m: FloatArray, gate_chi2: float = 16.0) -> np.ndarray:
    """``assign_ranges`` for every receiver at once: ``predicted_m`` and ``sigma_m`` are (receivers x
    tracks); returns the track of every distance, flat in receiver order (-1: unassigned)."""
    counts = [len(m) for m in ranges]
    if not sum(counts):
        return np.zeros(0, dtype=int)
    receiver_of = np.repeat(np.arange(len(ranges)), counts)
    chi2 = ((np.concatenate(ranges)[:, None] - predicted_m[receiver_of]) / sigma_m[receiver_of]) ** 2  # one pass for all
    ends = np.cumsum(counts)
    return np.concatenate([_assign(chi2[end - m:end], gate_chi2) for m, end in zip(counts, ends, strict=True)])


def swap_probability(z_a: FloatArray, z_b: FloatArray, predicted_i: FloatArray, predicted_j: FloatArray, sigma_i: FloatArray | float,
                     sigma_j: FloatArray | float) -> FloatArray:
    """Probability that two distances at one receiver, assigned a -> track i and b -> track j, belong the other way round
    (the two-way mixture of Gaussian range errors, equal priors)."""
    keep = ((z_a - predicted_i) / sigma_i) ** 2 + ((z_b - predicted_j) / sigma_j) ** 2
    swap = ((z_a - predicted_j) / sigma_j) ** 2 + ((z_b - predicted_i) / sigma_i) ** 2
    return np.asarray(1.0 / (1.0 + np.exp(np.clip(0.5 * (swap - keep), -50.0, 50.0))))


def share_swaps(receiver_of: np.ndarray, track_of: np.ndarray, z_m: FloatArray, predicted_m: FloatArray,
                sigma_m: float) -> tuple[np.ndarray, np.ndarray, FloatArray, FloatArray]:
    """Assigned distances with the swaps they may hide: neighbouring distances at a receiver (in distance order) given to
    tracks i and j could be the other way round; with the probability q of the swap (``swap_probability`` against
    ``predicted_m``, (tracks, receivers)) each track weighs its own distance by 1 - q and the neighbour's by q (the EM
    weights of the two-way mixture). Returns (receiver, track, distance, weight) per row: the given rows first (sorted),
    then the shared ones with q above 1e-4."""
    order = np.lexsort((z_m, receiver_of))
    receiver_of, track_of, z_m = receiver_of[order], track_of[order], z_m[order]
    first = np.nonzero(receiver_of[:-1] == receiver_of[1:])[0]
    r, i, j = receiver_of[first], track_of[first], track_of[first + 1]
    z_a, z_b = z_m[first], z_m[first + 1]
    q = swap_probability(z_a, z_b, predicted_m[i, r], predicted_m[j, r], sigma_m, sigma_m)
    own = np.ones(len(z_m))
    np.subtract.at(own, first, q)
    np.subtract.at(own, first + 1, q)
    real = q > 1e-4  # the rest carry no information
    return (np.concatenate([receiver_of, r[real], r[real]]), np.concatenate([track_of, i[real], j[real]]),  # np.r_: 5x the time
            np.concatenate([z_m, z_b[real], z_a[real]]), np.concatenate([np.clip(own, 0.0, 1.0), q[real], q[real]]))


def relative_range_misfit(groups: list[tuple[int, FloatArray]]) -> Callable[[FloatArray], float]:
    """For groups of ranges heard together at one receiver, each about its mean ((receiver, values), in order): the function
    of predicted ranges about their mean (tracks x receivers) that sums each range's distance to the nearest prediction at
    its receiver, group by group in order and each group left to right (the float a loop adding each group's own sum()
    gives, computed for every group at once)."""
    values = np.concatenate([v for _, v in groups])
    receiver_of = np.concatenate([np.full(len(v), r) for r, v in groups])
    group_of = np.concatenate([np.full(len(v), g) for g, (_, v) in enumerate(groups)])
    place = np.concatenate([np.arange(len(v)) for _, v in groups])
    padded = np.zeros((len(groups), int(place.max()) + 1))  # a group's values in a row, zeros after them (+ 0 is exact)

    def misfit(predicted_rel: FloatArray) -> float:
        padded[group_of, place] = np.min(np.abs(values[:, None] - predicted_rel[:, receiver_of].T), axis=1)
        sums = padded[:, 0]
        for column in range(1, padded.shape[1]):  # left to right, as sum() adds (numpy's reduceat adds otherwise)
            sums = sums + padded[:, column]
        cost = 0.0
        for value in sums.tolist():
            cost += value
        return cost

    return misfit


def trilaterate(centres: FloatArray, radii: FloatArray, below: bool = True) -> tuple[FloatArray, np.ndarray]:
    """Points at distances ``radii`` (K, 3) from three ``centres`` (3, 3); the solution below their plane.

    Returns (K, 3) points and a validity mask (the spheres meet, up to 2 cm of noise).
    """
    c1, c2, c3 = centres
    ex = (c2 - c1) / np.linalg.norm(c2 - c1)
    i = ex @ (c3 - c1)
    ey = c3 - c1 - i * ex
    ey /= np.linalg.norm(ey)
    ez = np.cross(ex, ey)
    d = np.linalg.norm(c2 - c1)
    j = ey @ (c3 - c1)
    r1, r2, r3 = radii[:, 0], radii[:, 1], radii[:, 2]
    x = (r1**2 - r2**2 + d**2) / (2 * d)
    y = (r1**2 - r3**2 + i**2 + j**2) / (2 * j) - i * x / j
    z2 = r1**2 - x**2 - y**2
    valid = z2 > -(0.02**2) * 50  # noisy spheres that nearly touch still locate a point
    z = np.sqrt(np.clip(z2, 0.0, None))
    sign = -1.0 if (ez[2] > 0) == below else 1.0
    points = c1 + x[:, None] * ex + y[:, None] * ey + sign * z[:, None] * ez
    return points, valid


@dataclass(frozen=True)
class Located:
    """A transmitter found without a prior."""

    position_m: FloatArray
    support: int
    """Receivers whose distances agree with it."""
    used: list[tuple[int, int]]
    """(receiver, index in its sorted distances) of the distances it explains."""


def refine(position_m: FloatArray, receivers: FloatArray, distances: FloatArray, iterations: int = 3) -> FloatArray:
    """Gauss-Newton on the distances to known receivers."""
    p = np.asarray(position_m, dtype=float).copy()
    for _ in range(iterations):
        diff = p - receivers
        predicted = np.linalg.norm(diff, axis=1)
        jac = diff / predicted[:, None]
        step, *_ = np.linalg.lstsq(jac, distances - predicted, rcond=None)
        p += step
    return p


def _triples(receivers: FloatArray) -> list[tuple[int, int, int]]:
    """A few well-spread receiver triples (largest triangles first)."""
    r = len(receivers)
    hull = [int(np.argmin(receivers[:, 0] + receivers[:, 1])), int(np.argmax(receivers[:, 0] + receivers[:, 1])),
            int(np.argmin(receivers[:, 0] - receivers[:, 1])), int(np.argmax(receivers[:, 0] - receivers[:, 1]))]
    centre = int(np.argmin(np.linalg.norm(receivers[:, :2] - receivers[:, :2].mean(0), axis=1)))
    cands = {tuple(sorted(t)) for t in ((hull[0], hull[1], hull[2]), (hull[0], hull[1], hull[3]), (hull[2], hull[3], hull[0]),
                                        (hull[2], hull[3], hull[1]), (hull[0], hull[3], centre), (hull[1], hull[2], centre))}
    good = [t for t in cands if len(set(t)) == 3 and r >= 3]

    def area(t: tuple[int, ...]) -> float:
        a, b, c = receivers[list(t)]
        return float(np.linalg.norm(np.cross(b - a, c - a)))

    return sorted(good, key=area, reverse=True)  # type: ignore[arg-type]


def locate(
    receivers: FloatArray,
    ranges: list[FloatArray],
    count: int,
    tolerance_m: float = 0.02,
    min_support: int = 6,
    exclude_near: FloatArray | None = None,
    exclude_radius_m: float = 0.05,
    max_triples: int = 3,
) -> list[Located]:
    """Up to ``count`` transmitters located from unlabelled distances alone (greedy, best-supported first)."""
    available = [np.asarray(r, dtype=float).copy() for r in ranges]
    taken = [np.zeros(len(r), dtype=bool) for r in available]
    found: list[Located] = []
    triples = _triples(receivers)[:max_triples]
    for _ in range(count):
        best: Located | None = None
        for triple in triples:
            lists = [np.nonzero(~taken[r])[0] for r in triple]
            if any(len(x) == 0 for x in lists):
                continue
            grid = np.array(np.meshgrid(*lists, indexing="ij")).reshape(3, -1).T  # index combos
            radii = np.column_stack([available[r][grid[:, c]] for c, r in enumerate(triple)])
            points, valid = trilaterate(receivers[list(triple)], radii)
            points, grid = points[valid], grid[valid]
            if len(points) == 0:
                continue
            support = np.zeros(len(points), dtype=int)
            for r in range(len(receivers)):
                free = available[r][~taken[r]]
                if len(free) == 0:
                    continue
                predicted = np.linalg.norm(points - receivers[r], axis=1)
                support += (np.abs(predicted[:, None] - free[None, :]).min(axis=1) < tolerance_m).astype(int)
            if exclude_near is not None and len(exclude_near):
                near = np.linalg.norm(points[:, None, :] - exclude_near[None, :, :], axis=2).min(axis=1) < exclude_radius_m
                support[near] = 0
            i = int(np.argmax(support))
            if support[i] >= min_support and (best is None or support[i] > best.support):
                best = _explain(points[i], receivers, available, taken, tolerance_m)
        if best is None:
            break
        for r, j in best.used:
            taken[r][j] = True
        found.append(best)
    return found


def _explain(point: FloatArray, receivers: FloatArray, available: list[FloatArray], taken: list[np.ndarray], tolerance_m: float) -> Located:
    """The distances a candidate explains (the closest free one per receiver), and the refined point."""
    used: list[tuple[int, int]] = []
    for _ in range(2):  # refine, then re-collect with the refined point
        used = []
        for r in range(len(receivers)):
            free = np.nonzero(~taken[r])[0]
            if len(free) == 0:
                continue
            gap = np.abs(np.linalg.norm(point - receivers[r]) - available[r][free])
            j = int(np.argmin(gap))
            if gap[j] < tolerance_m:
                used.append((r, int(free[j])))
        if len(used) >= 3:
            point = refine(point, receivers[[r for r, _ in used]], np.array([available[r][j] for r, j in used]))
    return Located(point, len(used), used)


def association_self_check(epochs: RangeEpochs, positions: FloatArray) -> float:
    """Association accuracy to expect from the geometry alone, no labels, no truth.

    Per epoch (every tenth) and receiver that heard every tag, every assignment of the measured ranges to the
    tracked tags (``positions`` (K, T, 3)) is costed; the range noise is the robust spread of the best
    assignments' residuals. A range set is told apart when the best assignment beats the second best by more
    than 4 (chi-square: 2 sigma); otherwise it is a guess (right 1 time in T). Returns told + (1 - told) / T.
    """
    import itertools

    tags = positions.shape[1]
    perms = np.array(list(itertools.permutations(range(tags))))
    best, second, residuals = [], [], []
    for k in range(0, len(epochs.t), 10):  # every tenth epoch: the figure is a mean
        predicted = np.linalg.norm(epochs.receivers[:, None, :] - positions[k][None, :, :], axis=2)  # (R, T)
        for a in range(len(epochs.receivers)):
            measured = np.sort(epochs.ranges[k][a][np.isfinite(epochs.ranges[k][a])])
            if len(measured) != tags or not np.all(np.isfinite(predicted[a])):
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
