"""The founding papers' 9-axis attitude EKF on roll/pitch/yaw (ZYX Euler angles), a baseline.

State: (azimuth/yaw, elevation/pitch, roll) of earth_R_sensor = Rz Ry Rx, earth frame ENU (z up).
Time update with the gyro through the Euler-rate equation angles' = angles + T E^-1(angles) omega.
Observations: the accelerometer's gravity direction R^T [0, 0, g] (optionally with its noise inflated
as |a| departs from g, an addition of ours that no paper has: off by default), and the magnetometer's yaw from the tilt-compensated field
(magnetic north = +y of ENU; calibration M = G m + B applied first, identity by default). Joseph
form throughout. Euler angles are the papers' choice; they are singular at pitch +-90 deg.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from ..factors.imu import GRAVITY_M_S2
from ..geometry import FloatArray, euler_rate_matrix, matrix_from_quat, quat_from_euler_zyx, wrap_angle
from ..tuned import value
from .ekf import joseph_update


@dataclass(frozen=True)
class Ekf9Config:
    """Noise figures of the 9-axis EKF (one set for all recordings)."""

    gyro_sigma_rad_s: float = float(value("broad_ekf", "gyro_sigma_rad_s"))
    """Gyro noise driving the angles, rad/s (the papers give none; chosen as ``accel_inflation`` says)."""
    accel_sigma_m_s2: float = 0.5
    """Accelerometer noise on the gravity direction at rest, m/s^2."""
    accel_inflation: float = float(value("broad_ekf", "accel_inflation"))
    """Extra sigma per m/s^2 that |a| departs from g (translational acceleration). In no paper: an option. Chosen
    with the gyro noise by leave-one-trial-out on the thirteen BROAD trials (``fusegraph tune broad_ekf``,
    ``tuned.toml``: off, with 0.03 rad/s and 0.2 rad, 6.94 deg in-sample, 7.95 deg cross-validated; on eleven 7.93 / 12.49;
    20, the earlier default, 31.6 deg)."""
    mag_yaw_sigma_rad: float = float(value("broad_ekf", "mag_yaw_sigma_rad"))
    """Magnetometer yaw noise, rad (the papers give none; chosen with the gyro noise, ``fusegraph tune broad_ekf``)."""
    mag_gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Per-axis gain G of the calibration M = G m + B."""
    mag_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Offset B of the calibration, in the magnetometer's unit."""

    @classmethod
    def from_setting(cls, setting: Mapping[str, Any], **fixed: float) -> Ekf9Config:
        """The filter with every noise figure a study's setting holds (a grid point, or ``tuned(study)``: its other keys,
        another filter's or the provenance, are not this filter's) and ``fixed`` beside; a figure the study does not
        choose keeps its default. One path for every study, so a figure added to a study's grid reaches its filter."""
        names = {f.name for f in fields(cls)}
        return cls(**{key: float(value) for key, value in setting.items() if key in names}, **fixed)  # type: ignore[arg-type]

    def with_noise_scaled(self, factor: float) -> Ekf9Config:
        """The filter told every sensor sigma ``factor`` times its figure (gyro, accelerometer, magnetometer yaw)."""
        return replace(self, gyro_sigma_rad_s=factor * self.gyro_sigma_rad_s, accel_sigma_m_s2=factor * self.accel_sigma_m_s2,
                       mag_yaw_sigma_rad=factor * self.mag_yaw_sigma_rad)


def _tilt_compensated_yaw(angles: FloatArray, mag: FloatArray) -> float:
    """Yaw from the field levelled with the current roll and pitch (ENU: the horizontal field points +y)."""
    _, pitch, roll = angles
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    # R_y(pitch) R_x(roll) m: the field in a frame that only lacks the yaw rotation
    level_x = cp * mag[0] + sp * sr * mag[1] + sp * cr * mag[2]
    level_y = cr * mag[1] - sr * mag[2]
    return float(np.pi / 2 - np.arctan2(level_y, level_x))


def run_ekf9(t: FloatArray, gyro: FloatArray, accel: FloatArray, mag: FloatArray, config: Ekf9Config | None = None,
             linear_accel_world: FloatArray | None = None) -> FloatArray:
    """Attitude quaternions (N, 4) wxyz, earth_R_sensor in ENU, at every sample.

    ``linear_accel_world`` (N, 3), when given, is a translational acceleration known from elsewhere
    (the cyclist paper's frame IMU): it is rotated into the sensor frame with the predicted attitude
    and subtracted from the accelerometer before the gravity update.
    """
    cfg = config or Ekf9Config()
    mag_cal = np.asarray(mag, dtype=float) * np.asarray(cfg.mag_gain) + np.asarray(cfg.mag_offset)
    # initial attitude from the first accelerometer and magnetometer samples
    a0 = accel[0] / np.linalg.norm(accel[0])
    roll0, pitch0 = np.arctan2(a0[1], a0[2]), np.arctan2(-a0[0], np.hypot(a0[1], a0[2]))
    x = np.array([0.0, pitch0, roll0])
    x[0] = _tilt_compensated_yaw(x, mag_cal[0])
    P = np.diag([0.3, 0.05, 0.05]) ** 2
    out = np.empty((len(t), 3))
    out[0] = x
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        omega = 0.5 * (gyro[i] + gyro[i - 1])
        E_inv = euler_rate_matrix(x)
        x = x + dt * E_inv @ omega
        x[0] = wrap_angle(x[0])
        Q = (dt * cfg.gyro_sigma_rad_s) ** 2 * (E_inv @ E_inv.T)
        P = P + Q  # the Euler-rate Jacobian w.r.t. the angles is O(dt * omega); the papers drop it
        # gravity direction: R^T [0, 0, g] = g (-sin(pitch), sin(roll) cos(pitch), cos(roll) cos(pitch))
        sp, cp, sr, cr = np.sin(x[1]), np.cos(x[1]), np.sin(x[2]), np.cos(x[2])
        predicted = GRAVITY_M_S2 * np.array([-sp, sr * cp, cr * cp])
        H = GRAVITY_M_S2 * np.array([[0.0, -cp, 0.0], [0.0, -sr * sp, cr * cp], [0.0, -cr * sp, -sr * cp]])
        measured = accel[i]
        if linear_accel_world is not None:
            measured = measured - matrix_from_quat(quat_from_euler_zyx(x)).T @ linear_accel_world[i]
        departure = abs(np.linalg.norm(measured) - GRAVITY_M_S2)
        sigma = cfg.accel_sigma_m_s2 + cfg.accel_inflation * departure
        x, P = joseph_update(x, P, measured - predicted, H, sigma**2 * np.eye(3), angle_rows=slice(0, 1))
        # magnetometer yaw
        residual = wrap_angle(_tilt_compensated_yaw(x, mag_cal[i]) - x[0])
        x, P = joseph_update(x, P, np.array([residual]), np.array([[1.0, 0.0, 0.0]]), np.array([[cfg.mag_yaw_sigma_rad**2]]), angle_rows=slice(0, 1))
        out[i] = x
    return quat_from_euler_zyx(out)
