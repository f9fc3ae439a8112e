"""The gaze paper's EKF, extended to both image axes: state (yaw, pitch, roll, GX, GZ).

Head angles are propagated by the gyro through the ZYX Euler-rate matrix and corrected by the
accelerometer's gravity direction and the magnetometer's tilt-compensated yaw, as in the 9-axis
EKF (``solvers.ekf9``); the gaze point (GX, GZ) on the wall x = D is a random walk, and each gaze
pixel is the projection of (D, GX, GZ) into the head-fixed camera at the current angles. The paper
observed GZ through the vertical pixel; the horizontal pixel observes GX the same way.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ..factors.gaze import SceneCamera
from ..factors.imu import GRAVITY_M_S2
from ..geometry import FloatArray, euler_rate_matrix, quat_wxyz_from_rot3, wrap_angle
from ..tuned import tuned, value
from .ekf import joseph_update
from .ekf9 import Ekf9Config, _tilt_compensated_yaw


@dataclass(frozen=True)
class GazeEkfConfig:
    """Noise figures of the gaze EKF."""

    head: Ekf9Config = Ekf9Config.from_setting(tuned("gaze_ekf"))
    """Head-angle part. The paper gives no noise values: the gyro sigma, the magnetometer yaw noise and the accelerometer
    inflation (an addition no paper has) are chosen with the gaze walk by ``fusegraph tune gaze_ekf`` on seeds 100-119
    (``tuned.toml``; 11.3 mm against 78 mm for the 9-axis figures used before). Until 2026-11-27 the yaw noise was the
    9-axis EKF's, chosen on BROAD (0.2 rad; 0.1 before: 11.6 mm), which moved this simulation's figure."""
    gaze_walk_m_per_sqrt_s: float = float(value("gaze_ekf", "gaze_walk_m_per_sqrt_s"))
    """Random walk of the gaze point, m/sqrt(s): small keeps a fixation steady, large follows a saccade (same study)."""
    pixel_sigma: float = 5.0
    """Gaze pixel noise, pixels (the gaze preset passes the session's declared ``pixel_sigma``, as the graph reads it; 5 px
    is the simulated camera's)."""
    use_mag: bool = True
    """Correct the yaw with the magnetometer (off for a recording whose magnetometer cannot be calibrated)."""


def _pixel(x: FloatArray, wall_m: float, camera: SceneCamera) -> FloatArray:
    R = gtsam.Rot3.Ypr(x[0], x[1], x[2]).matrix()  # ZYX: the state's (yaw, pitch, roll)
    head_point = R.T @ np.array([wall_m, x[3], x[4]])
    return camera.project(head_point)[0]


def run_gaze_ekf(t: FloatArray, gyro: FloatArray, accel: FloatArray, mag: FloatArray, tracker_t: FloatArray, gaze_px: FloatArray, wall_m: float,
                 camera: SceneCamera, config: GazeEkfConfig | None = None) -> FloatArray:
    """Gaze point (GX, GZ) on the wall at every tracker sample, causal, shape (M, 2)."""
    return run_gaze_ekf_full(t, gyro, accel, mag, tracker_t, gaze_px, wall_m, camera, config)[0]


def run_gaze_ekf_full(
    t: FloatArray,
    gyro: FloatArray,
    accel: FloatArray,
    mag: FloatArray,
    tracker_t: FloatArray,
    gaze_px: FloatArray,
    wall_m: float,
    camera: SceneCamera,
    config: GazeEkfConfig | None = None,
    wall_facing_start: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """Gaze point (GX, GZ) on the wall and head attitude world_R_head (w, x, y, z) at every tracker sample, causal.

    ``wall_facing_start``: the wall is not world x = D but faces the filter's first heading (a recording
    without a known wall): the yaw state is counted from that heading, and the attitude returned adds it back.
    The attitude at a sample is the state after its update, carried back by the gyro over the part of
    the IMU step after the sample's time.
    """
    cfg = config or GazeEkfConfig()
    a0 = accel[0] / np.linalg.norm(accel[0])
    x = np.zeros(5)
    x[1], x[2] = np.arctan2(-a0[0], np.hypot(a0[1], a0[2])), np.arctan2(a0[1], a0[2])
    x[0] = _tilt_compensated_yaw(x[:3], mag[0]) if cfg.use_mag else 0.0
    wall_yaw = 0.0
    if wall_facing_start:
        wall_yaw, x[0] = x[0], 0.0
    P = np.diag([0.3, 0.05, 0.05, 0.5, 0.5]) ** 2
    out = np.full((len(tracker_t), 2), np.nan)
    attitude = np.full((len(tracker_t), 4), np.nan)
    j = 0
    angle_rows = slice(0, 1)
    for i in range(1, len(t)):
        dt = t[i] - t[i - 1]
        omega = 0.5 * (gyro[i] + gyro[i - 1])
        E_inv = euler_rate_matrix(x[:3])
        x[:3] = x[:3] + dt * E_inv @ omega
        x[0] = wrap_angle(x[0])
        Q = np.zeros((5, 5))
        Q[:3, :3] = (dt * cfg.head.gyro_sigma_rad_s) ** 2 * (E_inv @ E_inv.T)
        Q[3:, 3:] = np.eye(2) * cfg.gaze_walk_m_per_sqrt_s**2 * dt
        P = P + Q
        sp, cp, sr, cr = np.sin(x[1]), np.cos(x[1]), np.sin(x[2]), np.cos(x[2])
        predicted = GRAVITY_M_S2 * np.array([-sp, sr * cp, cr * cp])
        H = np.zeros((3, 5))
        H[:, :3] = GRAVITY_M_S2 * np.array([[0.0, -cp, 0.0], [0.0, -sr * sp, cr * cp], [0.0, -cr * sp, -sr * cp]])
        sigma = cfg.head.accel_sigma_m_s2 + cfg.head.accel_inflation * abs(np.linalg.norm(accel[i]) - GRAVITY_M_S2)
        x, P = joseph_update(x, P, accel[i] - predicted, H, sigma**2 * np.eye(3), angle_rows=angle_rows)
        if cfg.use_mag:
            residual = wrap_angle(_tilt_compensated_yaw(x[:3], mag[i]) - wall_yaw - x[0])
            x, P = joseph_update(x, P, np.array([residual]), np.eye(5)[:1], np.array([[cfg.head.mag_yaw_sigma_rad**2]]), angle_rows=angle_rows)
        while j < len(tracker_t) and tracker_t[j] <= t[i]:
            predicted_px = _pixel(x, wall_m, camera)
            H = np.empty((2, 5))
            for c in range(5):  # numerical Jacobian of the projection (5 columns, cheap)
                d = np.zeros(5)
                d[c] = 1e-6
                H[:, c] = (_pixel(x + d, wall_m, camera) - _pixel(x - d, wall_m, camera)) / 2e-6
            x, P = joseph_update(x, P, gaze_px[j] - predicted_px, H, cfg.pixel_sigma**2 * np.eye(2), angle_rows=angle_rows)
            out[j] = x[3:]
            back = gtsam.Rot3.Expmap(-omega * (t[i] - tracker_t[j]))
            attitude[j] = quat_wxyz_from_rot3(gtsam.Rot3.Ypr(x[0] + wall_yaw, x[1], x[2]).compose(back))
            j += 1
    return out, attitude
