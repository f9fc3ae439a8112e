"""``pdr.gravity_filter``'s per-sample loop compiled by numba (imported when the filter first runs; numba caches the
machine code on disk, so later processes load it instead of compiling it): the same float operations in the same order
as the scalar Python it replaced, so the same gravity to the bit, at ~0.05 us a sample where that Python took ~5 (a week
of a waist IMU at 100 Hz: 3 s where it took 5 minutes)."""

from __future__ import annotations

import math

import numba
import numpy as np

from ..geometry import FloatArray


@numba.njit(cache=True, error_model="numpy")
def gravity_loop(t: FloatArray, accel: FloatArray, gyro: FloatArray, has_gyro: bool, g0: FloatArray, q: float, sigma0: float, gate: float,
                 G: float) -> FloatArray:  # noqa: N803 (G: the gravity's magnitude, as in pdr)
    """Gravity in the body frame per sample (N, 3), starting from ``g0`` with a unit covariance: see ``pdr.gravity_filter``
    (``gyro`` is read only with ``has_gyro``; q: the process sigma; sigma0, gate: the accelerometer's sigma and its growth
    per m/s^2 of the reading's distance from G). The symmetric covariance is kept as six floats."""
    n = len(t)
    out = np.empty((n, 3))
    gx, gy, gz = g0[0], g0[1], g0[2]
    p00, p01, p02, p11, p12, p22 = 1.0, 0.0, 0.0, 1.0, 0.0, 1.0
    previous = t[0]
    for i in range(n):
        dt = max(t[i] - previous, 0.0)
        previous = t[i]
        if has_gyro and dt > 0:
            wx, wy, wz = gyro[i, 0], gyro[i, 1], gyro[i, 2]
            # g_{t+1} = F g_t, F = I - dt [omega]x: the world's gravity seen from a turning body; P <- F P F^T
            f01, f02, f10, f12, f20, f21 = dt * wz, -dt * wy, -dt * wz, dt * wx, dt * wy, -dt * wx
            gx, gy, gz = gx + f01 * gy + f02 * gz, f10 * gx + gy + f12 * gz, f20 * gx + f21 * gy + gz
            a00, a01, a02 = p00 + f01 * p01 + f02 * p02, p01 + f01 * p11 + f02 * p12, p02 + f01 * p12 + f02 * p22
            a10, a11, a12 = f10 * p00 + p01 + f12 * p02, f10 * p01 + p11 + f12 * p12, f10 * p02 + p12 + f12 * p22
            a20, a21, a22 = f20 * p00 + f21 * p01 + p02, f20 * p01 + f21 * p11 + p12, f20 * p02 + f21 * p12 + p22
            p00, p01, p02 = a00 + a01 * f01 + a02 * f02, a00 * f10 + a01 + a02 * f12, a00 * f20 + a01 * f21 + a02
            p11, p12, p22 = a10 * f10 + a11 + a12 * f12, a10 * f20 + a11 * f21 + a12, a20 * f20 + a21 * f21 + a22
        qq = q * q * dt
        p00, p11, p22 = p00 + qq, p11 + qq, p22 + qq
        ax, ay, az = accel[i, 0], accel[i, 1], accel[i, 2]
        sigma = sigma0 + gate * abs(math.sqrt(ax * ax + ay * ay + az * az) - G)
        r = sigma * sigma
        s00, s11, s22 = p00 + r, p11 + r, p22 + r
        # S^-1 by its cofactors (S symmetric)
        c00, c01, c02 = s11 * s22 - p12 * p12, p02 * p12 - p01 * s22, p01 * p12 - p02 * s11
        c11, c12, c22 = s00 * s22 - p02 * p02, p01 * p02 - s00 * p12, s00 * s11 - p01 * p01
        det = s00 * c00 + p01 * c01 + p02 * c02
        i00, i01, i02, i11, i12, i22 = c00 / det, c01 / det, c02 / det, c11 / det, c12 / det, c22 / det
        # K = P S^-1; g <- g + K (a - g); P <- (I - K) P
        k00, k01, k02 = p00 * i00 + p01 * i01 + p02 * i02, p00 * i01 + p01 * i11 + p02 * i12, p00 * i02 + p01 * i12 + p02 * i22
        k10, k11, k12 = p01 * i00 + p11 * i01 + p12 * i02, p01 * i01 + p11 * i11 + p12 * i12, p01 * i02 + p11 * i12 + p12 * i22
        k20, k21, k22 = p02 * i00 + p12 * i01 + p22 * i02, p02 * i01 + p12 * i11 + p22 * i12, p02 * i02 + p12 * i12 + p22 * i22
        ex, ey, ez = ax - gx, ay - gy, az - gz
        gx, gy, gz = gx + k00 * ex + k01 * ey + k02 * ez, gy + k10 * ex + k11 * ey + k12 * ez, gz + k20 * ex + k21 * ey + k22 * ez
        p00, p01, p02, p11, p12, p22 = (p00 - (k00 * p00 + k01 * p01 + k02 * p02), p01 - (k00 * p01 + k01 * p11 + k02 * p12),
                                        p02 - (k00 * p02 + k01 * p12 + k02 * p22), p11 - (k10 * p01 + k11 * p11 + k12 * p12),
                                        p12 - (k10 * p02 + k11 * p12 + k12 * p22), p22 - (k20 * p02 + k21 * p12 + k22 * p22))
        scale = G / math.sqrt(gx * gx + gy * gy + gz * gz)
        gx, gy, gz = gx * scale, gy * scale, gz * scale
        out[i, 0], out[i, 1], out[i, 2] = gx, gy, gz
    return out
