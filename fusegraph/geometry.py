"""Rotation conversions at the edges: quaternions (w, x, y, z), ZYX Euler angles, gtsam.Rot3.

Inside the graph every attitude is a ``gtsam.Rot3``; Euler angles appear only in reports and in the
EKF baselines that the papers define on them. Vectorised numpy versions are used for scoring
long sessions without a Python call per sample.
"""

from __future__ import annotations

from typing import Any

import gtsam
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def skew(v: FloatArray) -> FloatArray:
    """The cross-product matrix [v]x (skew(a) @ b == a x b)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rot3_from_quat_wxyz(quat_wxyz: FloatArray) -> gtsam.Rot3:
    """One unit quaternion (w, x, y, z) as a gtsam rotation."""
    w, x, y, z = np.asarray(quat_wxyz, dtype=float).tolist()
    return gtsam.Rot3.Quaternion(w, x, y, z)


def quat_wxyz_from_rot3(rotation: gtsam.Rot3) -> FloatArray:
    """A gtsam rotation as a unit quaternion (w, x, y, z) with w >= 0."""
    q: Any = rotation.toQuaternion()  # gtsam's stubs do not type the quaternion accessors
    out = np.array([q.w(), q.x(), q.y(), q.z()])
    return out if out[0] >= 0 else -out


def quat_normalize(quat_wxyz: FloatArray) -> FloatArray:
    """Unit quaternions with a non-negative scalar part (rows of an (N, 4) array or one (4,))."""
    q = np.asarray(quat_wxyz, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(a_wxyz: FloatArray, b_wxyz: FloatArray) -> FloatArray:
    """Hamilton product a * b, broadcasting over leading axes."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a_wxyz, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b_wxyz, dtype=float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_running_product(start_wxyz: FloatArray, increments_wxyz: FloatArray, block: int = 64) -> FloatArray:
    """start, start * q0, start * q0 * q1, ... (N + 1, 4) for increments (N, 4).

    A running product is sequential; here it runs within blocks of ``block`` increments for all blocks at once (numpy),
    then carries each block's start over the blocks (the same, on the N / block block ends): ~10x faster than a scalar
    loop over every increment (10 minutes of 100 Hz gyro: ~15 ms against ~150 ms on this machine). The rounding differs
    from the scalar loop's by a few ulp (products associated in another order)."""
    q = np.asarray(increments_wxyz, dtype=float)
    n = len(q)
    start = np.asarray(start_wxyz, dtype=float)
    blocks_n = -(-n // block)
    padded = np.zeros((blocks_n * block, 4))
    padded[:, 0] = 1.0  # identity quaternions after the last increment
    padded[:n] = q
    blocks = padded.reshape(blocks_n, block, 4)
    for step in range(1, block):
        blocks[:, step] = quat_multiply(blocks[:, step - 1], blocks[:, step])
    # each block's start: the running product of the blocks' ends, by the same method (recursion over N / block ends)
    prefix = start[None, :] if blocks_n <= 1 else quat_running_product(start, blocks[:-1, -1], block)
    out = quat_multiply(prefix[:, None, :], blocks).reshape(-1, 4)[:n]
    return np.vstack([start[None, :], out])


def quat_conjugate(q_wxyz: FloatArray) -> FloatArray:
    """Inverse of unit quaternions."""
    q = np.array(q_wxyz, dtype=float)
    q[..., 1:] *= -1.0
    return q


def quat_from_rotvec(rotvec: FloatArray) -> FloatArray:
    """Exp map: rotation vectors (..., 3) in rad to unit quaternions (..., 4)."""
    v = np.asarray(rotvec, dtype=float)
    angle = np.linalg.norm(v, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(x/2)/x -> 1/2 as x -> 0; the series keeps small angles exact to double precision
    scale = np.where(angle > 1e-8, np.sin(half) / np.maximum(angle, 1e-300), 0.5 - angle**2 / 48.0)
    return np.concatenate([np.cos(half), v * scale], axis=-1)


def rotvec_from_quat(q_wxyz: FloatArray) -> FloatArray:
    """Log map: unit quaternions (..., 4) to rotation vectors (..., 3) in rad, angle in [0, pi]."""
    q = quat_normalize(q_wxyz)
    vec = q[..., 1:]
    sin_half = np.linalg.norm(vec, axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, q[..., :1])
    scale = np.where(sin_half > 1e-12, angle / np.maximum(sin_half, 1e-300), 2.0)
    return vec * scale


def matrix_from_quat(q_wxyz: FloatArray) -> FloatArray:
    """Rotation matrices (..., 3, 3) from unit quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(quat_normalize(q_wxyz), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def rotate_by_quat(q_wxyz: FloatArray, vectors: FloatArray) -> FloatArray:
    """Vectors (N, 3) turned by unit quaternions (N, 4) row by row: ``R(q_i) v_i`` (NaN where a quaternion is)."""
    return np.einsum("nij,nj->ni", matrix_from_quat(q_wxyz), vectors)


def euler_zyx_from_quat(q_wxyz: FloatArray) -> FloatArray:
    """ZYX Euler angles (azimuth, elevation, roll) in rad of R = Rz(az) Ry(el) Rx(roll).

    Elevation is the rotation about the intermediate y axis (gtsam's ``pitch``), in [-pi/2, pi/2].
    """
    m = matrix_from_quat(q_wxyz)
    azimuth = np.arctan2(m[..., 1, 0], m[..., 0, 0])
    elevation = np.arcsin(np.clip(-m[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(m[..., 2, 1], m[..., 2, 2])
    return np.stack([azimuth, elevation, roll], axis=-1)


def quat_from_euler_zyx(euler_zyx: FloatArray) -> FloatArray:
    """Unit quaternions of R = Rz(az) Ry(el) Rx(roll) from (..., 3) angles in rad."""
    e = np.asarray(euler_zyx, dtype=float)
    cz, sz = np.cos(e[..., 0] / 2), np.sin(e[..., 0] / 2)
    cy, sy = np.cos(e[..., 1] / 2), np.sin(e[..., 1] / 2)
    cx, sx = np.cos(e[..., 2] / 2), np.sin(e[..., 2] / 2)
    q = np.stack(
        [
            cz * cy * cx + sz * sy * sx,
            cz * cy * sx - sz * sy * cx,
            cz * sy * cx + sz * cy * sx,
            sz * cy * cx - cz * sy * sx,
        ],
        axis=-1,
    )
    return quat_normalize(q)


def body_rates_from_euler_rates(euler_zyx: FloatArray, euler_rates: FloatArray) -> FloatArray:
    """Body angular velocity (p, q, r) from ZYX angles and their time derivatives (rad, rad/s)."""
    _, el, roll = np.moveaxis(np.asarray(euler_zyx, dtype=float), -1, 0)
    d_az, d_el, d_roll = np.moveaxis(np.asarray(euler_rates, dtype=float), -1, 0)
    p = d_roll - d_az * np.sin(el)
    q = d_el * np.cos(roll) + d_az * np.cos(el) * np.sin(roll)
    r = -d_el * np.sin(roll) + d_az * np.cos(el) * np.cos(roll)
    return np.stack([p, q, r], axis=-1)


def euler_rate_matrix(euler_zyx: FloatArray) -> FloatArray:
    """Matrix E^-1 with d(az, el, roll)/dt = E^-1 @ body_omega (singular at elevation +-90 deg)."""
    _, el, roll = (float(v) for v in euler_zyx)
    ce, se = np.cos(el), np.sin(el)
    cr, sr = np.cos(roll), np.sin(roll)
    return np.array(
        [
            [0.0, sr / ce, cr / ce],
            [0.0, cr, -sr],
            [1.0, sr * se / ce, cr * se / ce],
        ]
    )


def wrap_angle(angle_rad: FloatArray) -> FloatArray:
    """Angles wrapped to [-pi, pi)."""
    return (np.asarray(angle_rad) + np.pi) % (2 * np.pi) - np.pi
