"""Scenario ``attitude9``: a body-worn 9-axis IMU (limb or head motion with translation) and a disturbed field.

Truth: smooth rotations up to ~+-60 deg yaw and +-35 deg tilt with rests, and translations of
~10 cm at up to ~1.5 Hz (several m/s^2: the accelerometer is NOT gravity alone). Sensors at
``rate_hz``; sample i describes the interval (t_{i-1}, t_i] (the gyro sample is the mean rate over
it). The magnetometer reads the Earth field (``field_uT``, ``dip_deg``; magnetic north = +y of
ENU) through an uncalibrated sensor, raw = (M - B) / G with per-axis gain G and offset B, plus an
indoor disturbance (a world-fixed extra field from steel nearby) over a stretch of the session. A
separate calibration recording ``mag_cal`` (the sensor turned through many orientations, same
sensor, no disturbance) lets the pipeline fit G and B. With ``tracker`` among the sensors, an
optical/magnetic attitude tracker reads the attitude in its own room frame, 100 ms late.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..catalogue import check_sensors
from ..factors.imu import GRAVITY_M_S2
from ..geometry import FloatArray, matrix_from_quat, quat_conjugate, quat_from_euler_zyx, quat_from_rotvec, quat_multiply, rotvec_from_quat
from ..session import CALIBRATION_ROLE, KIND_COLUMNS, Session, Stream


@dataclass(frozen=True)
class Attitude9ScenarioConfig:
    """Everything that defines a simulated 9-axis session."""

    duration_s: float = 60.0
    """Length of the session, seconds."""
    rate_hz: float = 100.0
    """Sample rate of gyro, accelerometer and magnetometer, Hz."""
    noise: bool = True
    """False: noise-free sensors (biases, calibration errors and the disturbance stay)."""
    gyro_white_rad_s: float = 0.01
    """Gyro white noise per sample, rad/s."""
    gyro_bias_max_rad_s: float = 0.01
    """Constant gyro bias per axis, uniform in +-this, rad/s."""
    gyro_scale_error: float = 0.0
    """Scale-factor error of each gyro axis (the reading is (1 + s) times the rate), s uniform in +-this (fraction; drawn
    from its own generator, so 0 leaves every other draw as it was)."""
    accel_white_m_s2: float = 0.05
    """Accelerometer white noise per sample, m/s^2."""
    mag_white_uT: float = 0.3
    """Magnetometer white noise per sample, uT."""
    field_uT: float = 50.0
    """Earth field norm, uT."""
    dip_deg: float = 65.0
    """Earth field dip (positive down), degrees."""
    mag_gain_error: float = 0.1
    """Per-axis gain error of the raw magnetometer, uniform in +-this (fraction)."""
    mag_offset_uT: float = 15.0
    """Per-axis offset of the raw magnetometer, uniform in +-this, uT."""
    disturbance_uT: float = 30.0
    """Strength of the indoor disturbance (world-fixed extra field), uT; 0 = none."""
    disturbance_window: tuple[float, float] = (0.55, 0.75)
    """Where the disturbance is, as fractions of the duration (ramped in and out over 1 s)."""
    translation_m: float = 0.1
    """Amplitude of the translational motion, metres."""
    calibration_s: float = 30.0
    """Length of the magnetometer calibration recording, seconds."""
    sensors: tuple[str, ...] = ("gyro", "accel", "mag")
    """Streams to write: gyro and accel always; mag and tracker (an optical/magnetic attitude tracker) optional."""
    tracker_rate_hz: float = 50.0
    """Attitude tracker sample rate, Hz (when ``tracker`` is among the sensors)."""
    tracker_latency_s: float = 0.1
    """How late each tracker sample arrives, seconds."""
    tracker_sigma_deg: float = 0.4
    """Tracker white noise per axis, degrees."""


def _smooth_angles(rng: np.random.Generator, t: FloatArray, amplitudes_rad: FloatArray, freq_hz: tuple[float, float]) -> FloatArray:
    out = np.zeros((len(t), len(amplitudes_rad)))
    for axis, amp in enumerate(amplitudes_rad):
        for _ in range(3):
            f = rng.uniform(*freq_hz)
            out[:, axis] += amp / 3 * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))
    return out


def _envelope(t: FloatArray, duration: float) -> FloatArray:
    """Rests at the start, in the middle and at the end (smooth), motion elsewhere."""
    env = np.ones_like(t)
    for start, stop in ((0.0, 2.0), (0.4 * duration, 0.4 * duration + 3.0), (duration - 2.0, duration + 1.0)):
        inside = (t > start) & (t < stop)
        env[inside] = 0.0
    # smooth the edges over 1 s with a raised cosine
    kernel = np.hanning(max(3, int(1.0 / max(t[1] - t[0], 1e-9))))
    return np.convolve(env, kernel / kernel.sum(), mode="same")


def _readings(q_wxyz: FloatArray, position_m: FloatArray, t: FloatArray, m_world: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Noise-free gyro (mean over each interval), specific force and field in the body frame."""
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0]))
    steps = rotvec_from_quat(quat_multiply(quat_conjugate(np.vstack([q_wxyz[:1], q_wxyz[:-1]])), q_wxyz))
    gyro = steps / dt[:, None]
    gyro[0] = gyro[1]
    velocity = np.gradient(position_m, t, axis=0)
    accel_world = np.gradient(velocity, t, axis=0)
    R = matrix_from_quat(q_wxyz)
    specific = np.einsum("nji,nj->ni", R, accel_world + np.array([0.0, 0.0, GRAVITY_M_S2]))
    field = np.einsum("nji,nj->ni", R, m_world)
    return gyro, specific, field


def _noisy_readings(
    q_wxyz: FloatArray, position_m: FloatArray, t: FloatArray, m_world: FloatArray, rng: np.random.Generator,
    gyro_bias_sigma_rad_s: float, gyro_sigma_rad_s: float, accel_sigma_m_s2: float, mag_sigma: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``_readings`` with a constant gyro bias (drawn per axis) and white noise on every sensor."""
    gyro, accel, mag = _readings(q_wxyz, position_m, t, m_world)
    bias = rng.normal(0.0, gyro_bias_sigma_rad_s, 3)
    gyro = gyro + bias + rng.normal(0.0, gyro_sigma_rad_s, gyro.shape)
    return gyro, accel + rng.normal(0.0, accel_sigma_m_s2, accel.shape), mag + rng.normal(0.0, mag_sigma, mag.shape)


def attitude_tracker_stream(
    t: FloatArray, q_wxyz: FloatArray, rng: np.random.Generator, rate_hz: float, latency_s: float, sigma_deg: float, noise: bool = True, name: str = "tracker",
) -> Stream:
    """An optical/magnetic attitude tracker sampling the truth ``q_wxyz`` (at times ``t``) at ``rate_hz``, in its
    own room frame (a random fixed rotation from ENU: yaw anywhere, tilt within 6 deg), white noise, late."""
    step = max(1, int(round(1.0 / (float(np.median(np.diff(t))) * rate_hz))))
    rows = np.arange(0, len(t), step)
    tracker_R_world = quat_from_euler_zyx(np.array([[rng.uniform(-np.pi, np.pi), rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1)]]))[0]
    white = quat_from_rotvec(rng.normal(0.0, np.deg2rad(sigma_deg), (len(rows), 3)) * (1.0 if noise else 0.0))
    reading = quat_multiply(quat_multiply(np.broadcast_to(tracker_R_world, (len(rows), 4)), q_wxyz[rows]), white)
    meta = {"rate_hz": rate_hz, "frame": "tracker_R_body (the tracker's room frame, not ENU)", "noise_sigma_deg": sigma_deg}
    return Stream(name, "attitude", t[rows], reading, KIND_COLUMNS["attitude"], latency_s, meta)


def simulate_attitude9(seed: int = 0, config: Attitude9ScenarioConfig | None = None, **overrides: object) -> Session:
    """A seeded 9-axis session with truth and a magnetometer calibration recording."""
    cfg = replace(config or Attitude9ScenarioConfig(), **{k: v for k, v in overrides.items() if k not in ("profile",) and v is not None})  # type: ignore[arg-type]
    check_sensors("attitude9", cfg.sensors, ("gyro", "accel"), ("mag", "tracker"))
    if overrides.get("profile") == "noise_free":
        cfg = replace(cfg, noise=False)
    rng = np.random.default_rng(seed)
    dt = 1.0 / cfg.rate_hz
    t = np.arange(0.0, cfg.duration_s + 0.5 * dt, dt)
    env = _envelope(t, cfg.duration_s)[:, None]
    yaw0 = rng.uniform(-np.pi, np.pi)
    angles = env * _smooth_angles(rng, t, np.deg2rad([60.0, 35.0, 35.0]), (0.1, 0.6))
    angles[:, 0] += yaw0
    q = quat_from_euler_zyx(angles)
    position = env * _smooth_angles(rng, t, np.full(3, cfg.translation_m), (0.3, 1.5))
    dip = np.deg2rad(cfg.dip_deg)
    earth = cfg.field_uT * np.array([0.0, np.cos(dip), -np.sin(dip)])
    # indoor disturbance: a world-fixed field from steel, ramped in and out
    start, stop = (f * cfg.duration_s for f in cfg.disturbance_window)
    ramp = np.clip(np.minimum(t - start, stop - t), 0.0, 1.0)[:, None]
    direction = np.array([0.8, -0.3, 0.5]) / np.linalg.norm([0.8, -0.3, 0.5])
    m_world = earth + ramp * cfg.disturbance_uT * direction
    gyro, accel, mag_true = _readings(q, position, t, m_world)
    gain = 1.0 + rng.uniform(-cfg.mag_gain_error, cfg.mag_gain_error, 3)
    offset = rng.uniform(-cfg.mag_offset_uT, cfg.mag_offset_uT, 3)
    bias = rng.uniform(-cfg.gyro_bias_max_rad_s, cfg.gyro_bias_max_rad_s, 3)
    noise = 1.0 if cfg.noise else 0.0
    scale = np.random.default_rng([seed, 3]).uniform(-cfg.gyro_scale_error, cfg.gyro_scale_error, 3) if cfg.gyro_scale_error else np.zeros(3)
    gyro = gyro * (1.0 + scale) + bias + noise * rng.normal(0, cfg.gyro_white_rad_s, gyro.shape)
    accel = accel + noise * rng.normal(0, cfg.accel_white_m_s2, accel.shape)
    mag_raw = (mag_true + noise * rng.normal(0, cfg.mag_white_uT, mag_true.shape) - offset) / gain
    # calibration recording: slow tumbling through all orientations, no disturbance
    t_cal = np.arange(0.0, cfg.calibration_s, dt)
    tumble = quat_from_euler_zyx(np.column_stack([0.7 * t_cal, 1.3 * np.sin(0.23 * t_cal), 1.1 * t_cal]))  # covers the sphere
    cal_true = np.einsum("nji,j->ni", matrix_from_quat(tumble), earth)
    cal_raw = (cal_true + noise * rng.normal(0, cfg.mag_white_uT, cal_true.shape) - offset) / gain
    meta = {"rate_hz": cfg.rate_hz, "frame": "sensor"}
    streams = {
        "gyro": Stream("gyro", "gyro", t, gyro, KIND_COLUMNS["gyro"], 0.0, dict(meta)),
        "accel": Stream("accel", "accel", t, accel, KIND_COLUMNS["accel"], 0.0, dict(meta)),
    }
    if "mag" in cfg.sensors:
        streams["mag"] = Stream("mag", "mag", t, mag_raw, KIND_COLUMNS["mag"], 0.0, {**meta, "unit": "uT"})
        streams["mag_cal"] = Stream("mag_cal", "mag", t_cal, cal_raw, KIND_COLUMNS["mag"], 0.0, {**meta, "unit": "uT", "role": CALIBRATION_ROLE})
    if "tracker" in cfg.sensors:
        streams["tracker"] = attitude_tracker_stream(t, q, np.random.default_rng([seed, 2]), cfg.tracker_rate_hz, cfg.tracker_latency_s,
                                                     cfg.tracker_sigma_deg, cfg.noise)
    truth = Stream("truth", "attitude", t, q, KIND_COLUMNS["attitude"], 0.0, {"frame": "world_R_body", "world_frame": "ENU"})
    session_meta = {
        "session": {"system": "attitude9", "scenario": "attitude9", "seed": seed, "world_frame": "ENU"},
        "truth_extra": {
            "disturbance_s": [start, stop],
            "gyro_bias_rad_s": bias.tolist(),
            "gyro_scale_error": scale.tolist(),
            "mag_gain": gain.tolist(),
            "mag_offset_uT": offset.tolist(),
        },
    }
    return Session("attitude9", streams, truth, session_meta)
