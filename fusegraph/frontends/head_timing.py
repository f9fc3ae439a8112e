"""A head gyro's bias and delay against an attitude tracker, from those two streams alone (no reference attitude):
initial values for the graph (``gyro_bias_from_tracker``) and the gyro's delay a session declares
(``gyro_delay_from_tracker``), as ``gaze_timing`` does for an eye tracker."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..factors.gyro import integrate_gyro
from ..geometry import FloatArray, matrix_from_quat, quat_conjugate, quat_from_rotvec, quat_multiply, rotvec_from_quat
from ..session import Session


def _pairs_span_apart(stamps: FloatArray, span_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices (i, j) of sample pairs: j the first stamp at least ``span_s`` after i, kept when under 1.5 spans apart (a gap)."""
    i = np.arange(len(stamps))
    j = np.searchsorted(stamps, stamps + span_s)
    ok = (j < len(stamps)) & (stamps[np.minimum(j, len(stamps) - 1)] - stamps < 1.5 * span_s)
    return i[ok], j[ok]


def gyro_bias_from_tracker(session: Session, span_s: float = 1.0) -> FloatArray:
    """A constant gyro bias (rad/s, body frame) that makes the gyro agree with the tracker: the median over
    tracker sample pairs ``span_s`` apart of the rotation the gyro adds beyond the tracker's, per second.

    For initial values only (the graph estimates the bias properly): robust to dropouts and to the
    tracker's own error, which ``span_s`` of gyro drift outweighs for a bias above ~0.01 rad/s."""
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    raw = integrate_gyro(gyro.t, gyro.values, np.array([1.0, 0.0, 0.0, 0.0]))
    i, j = _pairs_span_apart(tracker.t, span_s)
    if not len(i):
        return np.zeros(3)
    gi, gj = (np.clip(np.searchsorted(gyro.t, tracker.t[k] - 1e-9), 0, len(gyro) - 1) for k in (i, j))
    spanned = gyro.t[gj] - gyro.t[gi] > 0.5 * span_s  # not across a gyro dropout
    if not spanned.any():
        return np.zeros(3)
    i, j, gi, gj = i[spanned], j[spanned], gi[spanned], gj[spanned]
    by_gyro = quat_multiply(quat_conjugate(raw[gi]), raw[gj])
    by_tracker = quat_multiply(quat_conjugate(tracker.values[i]), tracker.values[j])
    excess = rotvec_from_quat(quat_multiply(quat_conjugate(by_tracker), by_gyro))
    return np.median(excess / (gyro.t[gj] - gyro.t[gi])[:, None], axis=0)


@dataclass(frozen=True)
class GyroDelay:
    """How late a gyro's samples are on the tracker's clock, estimated from the two streams alone."""

    delay_s: float
    """The gyro sample stamped t measured the rate at t - delay_s, seconds (a filter's group delay, a clock offset)."""
    sigma_s: float
    """Its standard error, seconds (least squares over the pairs kept)."""
    pairs: int
    """Tracker sample pairs used (after the outliers were set aside)."""


def gyro_delay_from_tracker(session: Session, span_s: float = 0.1) -> GyroDelay:
    """The gyro's delay relative to the tracker from their agreement: no reference attitude is read.

    A gyro that lags by d integrates, between tracker stamps a and b, the rotation of [a - d, b - d]:
    G = Exp(w_a d) T Exp(-w_b d) for the tracker's rotation T, so Log(T^-1 G) = d (G^T w_a - w_b) + bias (b - a)
    to first order (w the body rates at a and b, G^T carrying w_a into the frame at b). Least squares for (d, bias)
    over tracker pairs ``span_s`` apart; pairs whose residual exceeds 4 robust sigmas (tracker glitches) are set
    aside and the fit repeated. The tracker's own error is what makes the residual: over thousands of pairs it
    averages to a fraction of a millisecond when the head moves (at rest d is not observable and sigma says so).
    """
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    t_g = gyro.t
    raw = integrate_gyro(t_g, gyro.values, np.array([1.0, 0.0, 0.0, 0.0]))

    def at(times: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Integrated gyro attitude and gyro rate at arbitrary times (the next sample's rate carries the last one)."""
        i = np.clip(np.searchsorted(t_g, times, side="right") - 1, 0, len(t_g) - 2)
        rate = gyro.values[i + 1]
        quat = quat_multiply(raw[i], quat_from_rotvec(rate * (times - t_g[i])[:, None]))
        return quat, np.stack([np.interp(times, t_g, gyro.values[:, axis]) for axis in range(3)], axis=1)

    stamps = tracker.t
    a, b = _pairs_span_apart(stamps, span_s)
    inside = (stamps > t_g[0]) & (stamps < t_g[-1])
    ok = inside[a] & inside[b]  # both ends inside the gyro's span
    a, b = a[ok], b[ok]
    if len(a) < 10:
        return GyroDelay(0.0, float("inf"), 0)
    q_a, w_a = at(stamps[a])
    q_b, w_b = at(stamps[b])
    by_gyro = quat_multiply(quat_conjugate(q_a), q_b)
    by_tracker = quat_multiply(quat_conjugate(tracker.values[a]), tracker.values[b])
    excess = rotvec_from_quat(quat_multiply(quat_conjugate(by_tracker), by_gyro))  # (n, 3)
    column = np.einsum("nji,nj->ni", matrix_from_quat(by_gyro), w_a) - w_b  # G^T w_a - w_b
    finite = np.all(np.isfinite(excess), axis=1) & np.all(np.isfinite(column), axis=1)
    excess, column, a, b = excess[finite], column[finite], a[finite], b[finite]
    n = len(a)
    if n < 10:  # a gap in the gyro (NaN samples) everywhere: nothing to fit
        return GyroDelay(0.0, float("inf"), 0)
    design = np.zeros((3 * n, 4))
    design[:, 0] = column.ravel()
    dt = stamps[b] - stamps[a]
    for axis in range(3):
        design[axis::3, 1 + axis] = dt
    target = excess.ravel()
    use = np.ones(n, dtype=bool)
    for refit in range(3):  # all pairs, then twice without the outliers of the fit before
        rows = np.repeat(use, 3)
        solution, *_ = np.linalg.lstsq(design[rows], target[rows], rcond=None)
        if refit < 2:
            residual = np.linalg.norm((target - design @ solution).reshape(n, 3), axis=1)
            use = residual <= 4.0 * 1.4826 * np.median(residual[use])
    dof = max(int(rows.sum()) - 4, 1)
    variance = float(np.sum((target[rows] - design[rows] @ solution) ** 2)) / dof
    info = design[rows].T @ design[rows]
    sigma = float(np.sqrt(variance * np.linalg.inv(info)[0, 0])) if np.linalg.cond(info) < 1e12 else float("inf")
    return GyroDelay(float(solution[0]), sigma, int(use.sum()))


__all__ = ["GyroDelay", "gyro_bias_from_tracker", "gyro_delay_from_tracker"]
