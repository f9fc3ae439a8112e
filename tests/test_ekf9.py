"""The papers' 9-axis EKF baseline: recovers a static attitude and follows a slow turn from noise-free data."""

from __future__ import annotations

import numpy as np

from fusegraph.baselines.ekf9 import run_ekf9
from fusegraph.factors.imu import GRAVITY_M_S2 as GRAVITY
from fusegraph.geometry import euler_zyx_from_quat, matrix_from_quat, quat_from_euler_zyx, wrap_angle

FIELD_ENU = np.array([0.0, 20.0, -40.0])  # uT: north and down, a 63 deg dip like central Europe


def sensor_data(euler: np.ndarray, rate: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R = matrix_from_quat(quat_from_euler_zyx(euler))
    accel = np.einsum("nji,j->ni", R, np.array([0.0, 0.0, GRAVITY]))
    mag = np.einsum("nji,j->ni", R, FIELD_ENU)
    return accel, mag


def test_static_attitude_is_recovered() -> None:
    t = np.arange(300) / 100.0
    euler = np.tile(np.deg2rad([30.0, -20.0, 10.0]), (300, 1))
    accel, mag = sensor_data(euler, np.zeros((300, 3)), t)
    estimate = euler_zyx_from_quat(run_ekf9(t, np.zeros((300, 3)), accel, mag))
    np.testing.assert_allclose(wrap_angle(estimate[-1] - euler[-1]), 0.0, atol=np.deg2rad(0.1))


def test_slow_turn_is_followed() -> None:
    t = np.arange(1000) / 100.0
    yaw_rate = np.deg2rad(20.0)  # about the vertical: body rate = (0, 0, r) at zero tilt
    euler = np.column_stack([yaw_rate * t, np.zeros_like(t), np.zeros_like(t)])
    gyro = np.tile([0.0, 0.0, yaw_rate], (len(t), 1))
    accel, mag = sensor_data(euler, gyro, t)
    estimate = euler_zyx_from_quat(run_ekf9(t, gyro, accel, mag))
    assert np.max(np.abs(wrap_angle(estimate - euler))) < np.deg2rad(0.5)
