"""The head paper's EKFs (``ekf.HeadEkf``) over a whole session, compiled by numba: the same steps in the same order, ~0.3
us a gyro sample where ``HeadEkf``'s Python takes ~30 (``bench head-recorded`` runs Method II at 35 settings on every
trial). Imported by ``ekf.run_head_ekf`` when a filter first runs; numba caches the machine code on disk, so a later
process loads it (~1 s with numba's import) instead of compiling it. Written in plain loops over preallocated arrays: each
numpy function a numba function calls is compiled with it, and they made most of its compile time. ``error_model="numpy"``:
a division by zero gives inf or NaN, as in numpy, where numba's default raises (a filter that diverges near +-90 deg
elevation is scored as having left the Euler-angle domain, not stopped)."""

from __future__ import annotations

import math

import numba
import numpy as np

from ..geometry import FloatArray

METHOD1, METHOD2, KALMAN = 0, 1, 2
"""``head_ekf_loop``'s modes (``ekf.EkfMode``'s order)."""


@numba.njit(cache=True, error_model="numpy")
def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi  # ``geometry.wrap_angle``


@numba.njit(cache=True, error_model="numpy")
def _product(out: FloatArray, A: FloatArray, B: FloatArray, rows: int, inner: int, cols: int, transpose_b: bool) -> None:
    """out[:rows, :cols] = A[:rows, :inner] @ B[:inner, :cols] (``transpose_b``: @ B[:cols, :inner].T)."""
    for i in range(rows):
        for j in range(cols):
            total = 0.0
            for k in range(inner):
                total += A[i, k] * (B[j, k] if transpose_b else B[k, j])
            out[i, j] = total


@numba.njit(cache=True, error_model="numpy")
def _rate_matrix(E: FloatArray, el: float, roll: float) -> None:
    """E = E^-1 at (el, roll) (``geometry.euler_rate_matrix``)."""
    ce, se, cr, sr = math.cos(el), math.sin(el), math.cos(roll), math.sin(roll)
    E[0, 0], E[0, 1], E[0, 2] = 0.0, sr / ce, cr / ce
    E[1, 0], E[1, 1], E[1, 2] = 0.0, cr, -sr
    E[2, 0], E[2, 1], E[2, 2] = 1.0, sr * se / ce, cr * se / ce


@numba.njit(cache=True, error_model="numpy")
def _predict(x: FloatArray, P: FloatArray, Q: FloatArray, dt: float, F: FloatArray, work: FloatArray) -> None:
    """``HeadEkf.predict``, x and P in place: F = I + dt [[d(E^-1 omega)/d angles, E^-1], [0, 0]], P = F P F' + Q."""
    el, roll, p, q, r = x[1], x[2], x[3], x[4], x[5]
    ce, se, cr, sr = math.cos(el), math.sin(el), math.cos(roll), math.sin(roll)
    a, b = q * sr + r * cr, q * cr - r * sr  # ``ekf._kinematics``
    F[:, :] = 0.0
    for k in range(6):
        F[k, k] = 1.0
    F[0, 1], F[0, 2], F[1, 2], F[2, 1], F[2, 2] = dt * (a * se / ce**2), dt * (b / ce), dt * -a, dt * (a / ce**2), 1.0 + dt * (b * se / ce)
    F[0, 4], F[0, 5], F[1, 4], F[1, 5] = dt * (sr / ce), dt * (cr / ce), dt * cr, dt * -sr
    F[2, 3], F[2, 4], F[2, 5] = dt, dt * (sr * se / ce), dt * (cr * se / ce)
    x[0] = _wrap(x[0] + (F[0, 4] * q + F[0, 5] * r))
    x[1] = _wrap(x[1] + (F[1, 4] * q + F[1, 5] * r))
    x[2] = _wrap(x[2] + (dt * p + F[2, 4] * q + F[2, 5] * r))
    _product(work, F, P, 6, 6, 6, False)
    _product(P, work, F, 6, 6, 6, True)
    for i in range(6):
        for j in range(6):
            P[i, j] += Q[i, j]


@numba.njit(cache=True, error_model="numpy")
def _tracker_rows(residual: FloatArray, H: FloatArray, x: FloatArray, angles: FloatArray, d: float, E: FloatArray) -> None:
    """``HeadEkf._tracker_model`` into the first three rows: the residual of a tracker reading of ``angles`` against the angles
    carried back by the delay d, and H = (I, -d E^-1)."""
    _rate_matrix(E, x[1], x[2])
    for k in range(3):
        predicted = x[k] - d * (E[k, 0] * x[3] + E[k, 1] * x[4] + E[k, 2] * x[5])
        residual[k] = _wrap(angles[k] - predicted)
        for c in range(6):
            H[k, c] = 0.0
        H[k, k] = 1.0
        for c in range(3):
            H[k, 3 + c] = -d * E[k, c]


@numba.njit(cache=True, error_model="numpy")
def _joseph(x: FloatArray, P: FloatArray, residual: FloatArray, H: FloatArray, R: FloatArray, m: int) -> None:
    """``ekf.joseph_update`` of m measurement rows (residual[:m], H[:m], R[:m, :m]), x and P in place; the angles (x[:3])
    wrapped. K = (S^-1 H P)' with S = H P H' + R."""
    rhs = np.zeros((m, 6))  # H P, then eliminated in place
    LU = np.zeros((m, m))  # S, then its LU factors
    _product(rhs, H, P, m, 6, 6, False)
    _product(LU, rhs, H, m, 6, m, True)
    for i in range(m):
        for j in range(m):
            LU[i, j] += R[i, j]
    # K' = S^-1 (H P) by LU with partial pivoting, as numpy's solve (LAPACK's gesv) does it
    K = np.zeros((6, m))
    for col in range(m):
        pivot = col
        for i in range(col + 1, m):
            if abs(LU[i, col]) > abs(LU[pivot, col]):
                pivot = i
        if pivot != col:
            for c in range(m):
                LU[col, c], LU[pivot, c] = LU[pivot, c], LU[col, c]
            for c in range(6):
                rhs[col, c], rhs[pivot, c] = rhs[pivot, c], rhs[col, c]
        for i in range(col + 1, m):
            factor = LU[i, col] / LU[col, col]
            for c in range(col, m):
                LU[i, c] -= factor * LU[col, c]
            for c in range(6):
                rhs[i, c] -= factor * rhs[col, c]
    for c in range(6):
        for i in range(m - 1, -1, -1):
            total = rhs[i, c]
            for k in range(i + 1, m):
                total -= LU[i, k] * K[c, k]
            K[c, i] = total / LU[i, i]
    for c in range(6):
        total = 0.0
        for i in range(m):
            total += K[c, i] * residual[i]
        x[c] += total
    for k in range(3):
        x[k] = _wrap(x[k])
    I_KH = np.zeros((6, 6))
    _product(I_KH, K, H, 6, m, 6, False)
    for i in range(6):
        for j in range(6):
            I_KH[i, j] = (1.0 if i == j else 0.0) - I_KH[i, j]
    work = np.zeros((6, 6))
    KR = np.zeros((6, m))
    _product(work, I_KH, P, 6, 6, 6, False)
    _product(P, work, I_KH, 6, 6, 6, True)
    _product(KR, K, R, 6, m, m, False)
    _product(work, KR, K, 6, m, 6, True)
    for i in range(6):
        for j in range(6):
            P[i, j] += work[i, j]


@numba.njit(cache=True, error_model="numpy")
def head_ekf_loop(mode: int, t_gyro: FloatArray, omega: FloatArray, arrival: FloatArray, angles_tracker: FloatArray, w1: float, w2: float,
                  gyro_sigma: float, tracker_sigma: float, d: float) -> tuple[FloatArray, FloatArray]:
    """``ekf.run_head_ekf``'s loop: angles (N, 3) and their covariance (N, 3, 3) at the gyro samples (NaN before the first
    tracker sample arrives). ``arrival``: the tracker samples' arrival times; w1, w2: the process noise on the angles and
    the rates per step; ``d``: the delay the filter assumes (``ekf.HeadEkfConfig``)."""
    n = len(t_gyro)
    angles = np.full((n, 3), np.nan)
    angle_covs = np.full((n, 3, 3), np.nan)
    x = np.zeros(6)
    P = np.zeros((6, 6))
    Q = np.zeros((6, 6))
    F = np.zeros((6, 6))
    E = np.zeros((3, 3))
    work = np.zeros((6, 6))
    residual = np.zeros(6)
    H = np.zeros((6, 6))
    R = np.zeros((6, 6))  # the tracker's rows first; Method II's joint update adds the gyro's below them
    for k in range(3):
        Q[k, k], Q[3 + k, 3 + k] = w1 * w1, w2 * w2
    preceding = np.zeros((3, 3))  # Method II: the last (at most 3) gyro samples, oldest first
    n_preceding = 0
    pending = np.zeros(3)
    has_pending = False
    started = False
    t_last = np.nan
    j = 0
    for i in range(n):
        t = t_gyro[i]
        while j < len(arrival) and arrival[j] <= t + 1e-9:
            if not started:  # ``HeadEkf.start``
                P[:, :] = 0.0
                for k in range(3):
                    x[k] = angles_tracker[j, k]
                    x[3 + k] = 0.0 if mode == KALMAN else omega[i, k]
                    P[k, k] = tracker_sigma * tracker_sigma
                    P[3 + k, 3 + k] = 1.0 if mode == KALMAN else gyro_sigma * gyro_sigma
                    preceding[0, k] = omega[i, k]
                t_last = t
                n_preceding = 0 if mode == KALMAN else 1
                started = True
            else:  # ``HeadEkf.tracker``: used with the next gyro step; a later arrival before it replaces it
                for k in range(3):
                    pending[k] = angles_tracker[j, k]
                has_pending = True
            j += 1
        if not started:
            continue
        tracker_now, has_pending = has_pending, False
        if mode == METHOD2 and n_preceding > 0:  # the rates: the mean of the preceding samples
            for k in range(3):
                total = 0.0
                for m in range(n_preceding):
                    total += preceding[m, k]
                x[3 + k] = total / n_preceding
        if t - t_last > 0:
            _predict(x, P, Q, t - t_last, F, work)
            t_last = t
        if mode == METHOD2:
            if n_preceding == 3:
                for k in range(3):
                    preceding[0, k], preceding[1, k] = preceding[1, k], preceding[2, k]
                n_preceding = 2
            for k in range(3):
                preceding[n_preceding, k] = omega[i, k]
            n_preceding += 1
            if tracker_now:  # one joint update: the tracker's rows, then the current gyro sample's
                _tracker_rows(residual, H, x, pending, d, E)
                R[:, :] = 0.0
                for k in range(3):
                    residual[3 + k] = omega[i, k] - x[3 + k]
                    for c in range(6):
                        H[3 + k, c] = 0.0
                    H[3 + k, 3 + k] = 1.0
                    R[k, k], R[3 + k, 3 + k] = tracker_sigma * tracker_sigma, gyro_sigma * gyro_sigma
                _joseph(x, P, residual, H, R, 6)
        else:
            if mode == METHOD1:  # the gyro's own update, then the tracker's
                R[:, :] = 0.0
                for k in range(3):
                    residual[k] = omega[i, k] - x[3 + k]
                    for c in range(6):
                        H[k, c] = 0.0
                    H[k, 3 + k] = 1.0
                    R[k, k] = gyro_sigma * gyro_sigma
                _joseph(x, P, residual, H, R, 3)
            if tracker_now:
                _tracker_rows(residual, H, x, pending, d, E)
                R[:, :] = 0.0
                for k in range(3):
                    R[k, k] = tracker_sigma * tracker_sigma
                _joseph(x, P, residual, H, R, 3)
        for k in range(3):
            angles[i, k] = x[k]
            for c in range(3):
                angle_covs[i, k, c] = P[k, c]
    return angles, angle_covs
