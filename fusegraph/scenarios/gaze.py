"""Scenario ``gaze``: a subject 1 m from a wall fixates a mark while nodding and shaking the head,
then looks at a second mark.

World ENU; the subject sits at the origin facing east (+x); the wall is the plane x = ``wall_m``.
Wall coordinates: X = world y (north, to the subject's left), Z = world z (up). The head turns about
the eye (the camera and the IMU sit there), so the IMU feels no translational acceleration. The eye
keeps the mark on the fovea (the vestibulo-ocular reflex), so the tracker's gaze pixel is the mark's
projection into the head-fixed scene camera, plus fixational jitter on the wall and pixel noise.
Head IMU at 100 Hz (gyro with bias, accelerometer, calibrated magnetometer), tracker at 60 Hz.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..catalogue import check_sensors
from ..geometry import FloatArray, matrix_from_quat, quat_from_euler_zyx
from ..records import GazeScenarioConfig, GazeSession
from ..session import KIND_COLUMNS, Session, Stream
from .attitude9 import _noisy_readings, attitude_tracker_stream

VIEWING_SACCADE_EVERY_S = 0.33
"""Scene viewing's fixation length, seconds: the mean fixation in scene perception is ~330 ms (Rayner 1998, Psychol.
Bull. 124(3), Table 1)."""


def viewing_config() -> GazeScenarioConfig:
    """The scenario while the subject views a scene: the head moves as in the two-mark scenario, the eyes fixate a new
    mark every ``VIEWING_SACCADE_EVERY_S`` (``report gaze --viewing``, ``tune gaze_points``)."""
    return replace(GazeScenarioConfig(), saccade_every_s=VIEWING_SACCADE_EVERY_S)


def head_motion(t: FloatArray, config: GazeScenarioConfig, rng: np.random.Generator) -> FloatArray:
    """Yaw, pitch, roll (rad): nodding, then shaking, then both, at varying rates, calm at the switch."""
    f_nod, f_shake = rng.uniform(0.4, 0.9), rng.uniform(0.3, 0.7)
    ramp = np.clip(t / 2.0, 0, 1) * np.clip((config.duration_s - t) / 2.0, 0, 1)
    nod_on = np.clip((t - 2) / 2, 0, 1) * np.clip((14 - t) / 2, 0, 1) + np.clip((t - 18) / 2, 0, 1)
    shake_on = np.clip((t - 10) / 2, 0, 1)
    calm = 1.0 - 0.8 * np.exp(-(((t - config.switch_s) / 1.5) ** 2))
    yaw = math.radians(config.shake_deg) * np.sin(2 * np.pi * f_shake * t) * shake_on * ramp * calm
    pitch = math.radians(config.nod_deg) * np.sin(2 * np.pi * f_nod * t + 0.3) * nod_on * ramp * calm
    roll = math.radians(3.0) * np.sin(2 * np.pi * 0.23 * t) * ramp
    return np.stack([yaw, pitch, roll], axis=1)


def simulate_gaze(seed: int = 0, config: GazeScenarioConfig | None = None) -> GazeSession:
    config = config or GazeScenarioConfig()
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, config.duration_s, 1.0 / config.imu_rate_hz)
    angles = head_motion(t, config, rng)
    quat = quat_from_euler_zyx(angles)
    m_world = np.array([0.0, math.cos(math.radians(60)), -math.sin(math.radians(60))])  # northern field, 60 deg dip
    gyro, accel, mag = _noisy_readings(quat, np.zeros((len(t), 3)), t, np.tile(m_world, (len(t), 1)), rng,
                                       math.radians(config.gyro_bias_deg_s), config.gyro_sigma_rad_s, config.accel_sigma_m_s2, config.mag_sigma)
    tt = np.arange(0.0, config.duration_s - 1.0 / config.imu_rate_hz, 1.0 / config.tracker_rate_hz)
    marks = np.where((tt < config.switch_s)[:, None], np.array(config.first_mark_xz_m), np.array(config.second_mark_xz_m))
    if config.saccade_every_s is not None:  # scene viewing: a new mark per fixation, from a stream of its own
        drawn = np.random.default_rng([seed, 3]).uniform(-config.viewing_half_m, config.viewing_half_m, (int(tt[-1] // config.saccade_every_s) + 1, 2))
        marks = drawn[(tt // config.saccade_every_s).astype(int)]
    # a fixation wanders slowly (a random walk of a few mm), the saccade is instantaneous
    jitter = np.cumsum(rng.normal(0.0, config.jitter_m / np.sqrt(config.tracker_rate_hz), (len(tt), 2)), axis=0)
    gaze_xz = marks + np.clip(jitter, -3 * config.jitter_m, 3 * config.jitter_m)
    world_point = np.stack([np.full(len(tt), config.wall_m), gaze_xz[:, 0], gaze_xz[:, 1]], axis=1)
    q_tracker = np.stack([np.interp(tt, t, quat[:, j]) for j in range(4)], axis=1)
    q_tracker /= np.linalg.norm(q_tracker, axis=1, keepdims=True)
    head_point = np.einsum("nji,nj->ni", matrix_from_quat(q_tracker), world_point)
    px = config.camera.project(head_point) + rng.normal(0.0, config.camera.pixel_sigma, (len(tt), 2))
    return GazeSession(t=t, gyro_rad_s=gyro, accel_m_s2=accel, mag=mag, tracker_t=tt, gaze_px=px, truth_quat_wxyz=quat,
                       truth_gaze_xz_m=gaze_xz, config=config)


def gaze_session(seed: int = 0, profile: str | None = None, duration_s: float | None = None, sensors: tuple[str, ...] | None = None) -> Session:
    """The scenario as a session directory's content (``fusegraph simulate gaze``): head IMU streams,
    the tracker's ``gaze`` pixels (kind ``pixel``: u right, v up, origin at the image centre), the wall
    and camera in the metadata, and the true gaze point (world x, y, z) as the truth. With ``tracker``
    among ``sensors``, a head attitude tracker (``head_tracker``, kind attitude: 50 Hz, 100 ms late, 0.4 deg,
    in its own room frame) is written too."""
    sensors = check_sensors("gaze", sensors or ("gyro", "accel", "mag", "gaze"), ("gyro", "accel", "mag", "gaze"), ("tracker",))
    if profile not in (None, "realistic"):
        raise ValueError(f"--profile {profile} does not apply to gaze (its noise is the realistic one)")
    config = GazeScenarioConfig()
    if duration_s is not None:
        config = replace(config, duration_s=duration_s, switch_s=duration_s * config.switch_s / config.duration_s)
    g = simulate_gaze(seed, config)
    cam = config.camera
    imu = {"gyro": (g.gyro_rad_s, KIND_COLUMNS["gyro"]), "accel": (g.accel_m_s2, KIND_COLUMNS["accel"]), "mag": (g.mag, KIND_COLUMNS["mag"])}
    streams = {name: Stream(name, name, g.t, values, cols) for name, (values, cols) in imu.items()}
    streams["gaze"] = Stream("gaze", "pixel", g.tracker_t, g.gaze_px, KIND_COLUMNS["pixel"],
                             meta={"focal_px": cam.focal_px, "width_px": cam.width_px, "height_px": cam.height_px, "pixel_sigma": cam.pixel_sigma})
    if "tracker" in sensors:
        streams["head_tracker"] = attitude_tracker_stream(g.t, g.truth_quat_wxyz, np.random.default_rng([seed, 2]), 50.0, 0.1, 0.4, name="head_tracker")
    point = np.column_stack([np.full(len(g.tracker_t), config.wall_m), g.truth_gaze_xz_m])
    truth = Stream("truth", "position", g.tracker_t, point, KIND_COLUMNS["position"])
    meta = {"session": {"description": f"gaze scenario, seed {seed}: a wall {config.wall_m} m ahead (+x), marks, nodding and shaking",
                        "world_frame": "ENU; wall plane x = wall_m; wall X = world y, Z = world z", "wall_m": config.wall_m,
                        "switch_s": config.switch_s}}
    return Session("gaze", streams, truth, meta)
