"""Scenario ``head``: natural head motion seen by a drifting gyro and a late magnetic tracker.

The lag-free reference (truth) is sampled at the gyro rate. Two profiles:

* ``ideal``: gyro white noise and a random-walk bias; tracker white noise; 2 % dropped samples.
* ``realistic`` (default): adds what real sensors of this kind have and nobody models by default:
  gyro scale-factor error (3 % per axis) and 1 deg axis misalignment; the tracker's white noise
  is 0.4 deg plus a first-order Gauss-Markov error (0.7 deg stationary sigma, 2 s time constant).

These numbers define the benchmark of issue "head tracking": keep them.
World frame: the tracker's transmitter frame, z up; attitude = world_R_head.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from ..catalogue import check_sensors
from ..geometry import FloatArray, body_rates_from_euler_rates, quat_from_euler_zyx, quat_from_rotvec, quat_multiply
from ..session import KIND_COLUMNS, Session, Stream

Profile = Literal["ideal", "realistic"]
PROFILES: tuple[str, ...] = ("ideal", "realistic")


@dataclass(frozen=True)
class HeadScenarioConfig:
    """Everything that defines a simulated head-tracking session."""

    duration_s: float = 10.0
    """Length of the session, seconds (the paper used 10 s)."""
    profile: Profile = "realistic"
    """``ideal`` (white noise + bias drift) or ``realistic`` (adds scale, misalignment, correlated tracker error)."""
    gyro_rate_hz: float = 100.0
    """Gyro sample rate, Hz; the truth is sampled at the same instants."""
    tracker_rate_hz: float = 50.0
    """Magnetic tracker sample rate, Hz."""
    tracker_latency_s: float = 0.1
    """TRUE tracker transport delay: a sample taken at t arrives at t + latency, seconds."""
    tracker_latency_assumed_s: float | None = None
    """If set, the latency the user believes: stamps become arrival - assumed, and the session
    declares the latency as unknown (``latency_sigma_s``) so that fusegraph estimates it."""
    tracker_latency_sigma_s: float = 0.05
    """Prior sigma the session declares for an assumed latency, seconds."""
    max_angle_deg: float = 40.0
    """Bound on azimuth, elevation and roll, degrees."""
    fast_turn_every_s: float = 2.5
    """Mean time between fast azimuth turns, seconds."""
    gyro_white_sigma_rad_s: float = 0.015
    """Gyro white noise per sample, rad/s."""
    gyro_bias_initial_min_rad_s: float = 0.02
    """Smallest initial bias magnitude per axis, rad/s (sign random)."""
    gyro_bias_initial_max_rad_s: float = 0.05
    """Largest initial bias magnitude per axis, rad/s."""
    gyro_bias_rw_sigma: float = 1e-3
    """Gyro bias random walk, rad/s/sqrt(s)."""
    gyro_scale_error: float = 0.03
    """Realistic profile: scale-factor error per axis (fraction, random sign)."""
    gyro_misalignment_deg: float = 1.0
    """Realistic profile: each sensitive axis tilted this much in a random direction, degrees."""
    tracker_white_sigma_deg: float = 0.8
    """Ideal profile: tracker white noise per axis, degrees."""
    tracker_white_sigma_realistic_deg: float = 0.4
    """Realistic profile: tracker white noise per axis, degrees."""
    tracker_gm_sigma_deg: float = 0.7
    """Realistic profile: stationary sigma of the tracker's Gauss-Markov error per axis, degrees."""
    tracker_gm_tau_s: float = 2.0
    """Realistic profile: time constant of that error, seconds."""
    tracker_drop_fraction: float = 0.02
    """Fraction of tracker samples dropped at random (dropouts)."""
    sensors: tuple[str, ...] = ("gyro", "tracker")
    """Streams to write: ``gyro`` and ``tracker`` (the paper's pair), optionally ``accel`` (the head IMU's accelerometer)."""
    tracker_gap_s: tuple[float, float] | None = None
    """A tracker dropout: no tracker sample taken in [start, end) seconds (None: none)."""
    accel_white_sigma_m_s2: float = 0.05
    """Accelerometer white noise per sample, m/s^2."""
    accel_bias_m_s2: float = 0.05
    """Largest accelerometer bias per axis, m/s^2 (constant, uniform in +-)."""
    head_accel_m_s2: float = 0.5
    """Typical translational acceleration of the head (sum of sways), m/s^2: what the accelerometer sees besides gravity."""


def simulate_head(seed: int = 0, config: HeadScenarioConfig | None = None, **overrides: object) -> Session:
    """A seeded head-tracking session with truth; ``overrides`` replace fields of the config."""
    cfg = replace(config or HeadScenarioConfig(), **overrides)  # type: ignore[arg-type]
    if cfg.profile not in PROFILES:
        raise ValueError(f"profile must be one of {PROFILES}, got {cfg.profile!r}")
    rng = np.random.default_rng(seed)
    n_gyro = int(round(cfg.duration_s * cfg.gyro_rate_hz)) + 1
    t_gyro = np.arange(n_gyro) / cfg.gyro_rate_hz
    euler, euler_rate = _head_motion(rng, t_gyro, cfg)
    quat_true = quat_from_euler_zyx(euler)
    omega_true = body_rates_from_euler_rates(euler, euler_rate)

    realistic = cfg.profile == "realistic"
    dt_gyro = 1.0 / cfg.gyro_rate_hz
    bias0 = rng.uniform(cfg.gyro_bias_initial_min_rad_s, cfg.gyro_bias_initial_max_rad_s, 3) * rng.choice([-1.0, 1.0], 3)
    bias = bias0 + np.cumsum(rng.normal(0.0, cfg.gyro_bias_rw_sigma * np.sqrt(dt_gyro), (n_gyro, 3)), axis=0)
    sensor_matrix = np.eye(3)
    if realistic:
        scale = 1.0 + cfg.gyro_scale_error * rng.choice([-1.0, 1.0], 3)
        sensor_matrix = np.diag(scale) @ _misaligned_axes(rng, np.deg2rad(cfg.gyro_misalignment_deg))
    omega_meas = omega_true @ sensor_matrix.T + bias + rng.normal(0.0, cfg.gyro_white_sigma_rad_s, (n_gyro, 3))

    step = int(round(cfg.gyro_rate_hz / cfg.tracker_rate_hz))
    tracker_idx = np.arange(0, n_gyro, step)
    n_tracker = tracker_idx.size
    error = tracker_errors(rng, n_tracker, cfg)
    quat_tracker = quat_multiply(quat_true[tracker_idx], quat_from_rotvec(error))
    keep = rng.random(n_tracker) >= cfg.tracker_drop_fraction
    keep[0] = True  # the session starts with a tracker fix, as a real tracker reports at power-up
    if cfg.tracker_gap_s is not None:
        gap_start, gap_end = cfg.tracker_gap_s
        if not 0.0 < gap_start < gap_end:
            raise ValueError(f"tracker gap {gap_start}:{gap_end} s: need 0 < start < end")
        stamps_all = t_gyro[tracker_idx]
        keep &= ~((stamps_all >= gap_start) & (stamps_all < gap_end))
    check_sensors("head", cfg.sensors, ("gyro", "tracker"), ("accel",))

    gyro = Stream(
        "gyro", "gyro", t_gyro, omega_meas, KIND_COLUMNS["gyro"], 0.0,
        {"rate_hz": cfg.gyro_rate_hz, "frame": "head", "noise_sigma_rad_s": cfg.gyro_white_sigma_rad_s,
         "bias_rw_sigma": cfg.gyro_bias_rw_sigma, "calibrated": not realistic},
    )
    # the tracker's data sheet: white noise, and for the realistic sensor its slowly varying error
    # (what a static Allan-variance test of the tracker shows); the gyro's scale and misalignment
    # are NOT declared: the graph estimates them.
    tracker_meta: dict[str, object] = {"rate_hz": cfg.tracker_rate_hz, "frame": "world_R_head"}
    if realistic:
        tracker_meta.update(noise_sigma_deg=cfg.tracker_white_sigma_realistic_deg, markov_sigma_deg=cfg.tracker_gm_sigma_deg, markov_tau_s=cfg.tracker_gm_tau_s)
    else:
        tracker_meta.update(noise_sigma_deg=cfg.tracker_white_sigma_deg)
    stamps, declared_latency = t_gyro[tracker_idx][keep], cfg.tracker_latency_s
    if cfg.tracker_latency_assumed_s is not None:
        # what a host knows: the arrival time, and a latency it assumes
        declared_latency = cfg.tracker_latency_assumed_s
        stamps = stamps + cfg.tracker_latency_s - declared_latency
        tracker_meta["latency_sigma_s"] = cfg.tracker_latency_sigma_s
        tracker_meta["latency_true_s"] = cfg.tracker_latency_s  # for scoring only; estimators never read it
    tracker = Stream("tracker", "attitude", stamps, quat_tracker[keep], KIND_COLUMNS["attitude"], declared_latency, tracker_meta)
    truth = Stream("truth", "attitude", t_gyro, quat_true, KIND_COLUMNS["attitude"], 0.0, {"frame": "world_R_head"})
    meta = {
        "session": {
            "system": "head",
            "description": f"simulated head tracking, profile {cfg.profile}, seed {seed}",
            "world_frame": "tracker transmitter frame, z up",
            "scenario": "head",
            "seed": seed,
            "profile": cfg.profile,
        }
    }
    streams = {"gyro": gyro, "tracker": tracker}
    if "accel" in cfg.sensors:
        streams = {"gyro": gyro, "accel": _accelerometer(seed, t_gyro, quat_true, cfg), "tracker": tracker}
    return Session("head", streams, truth, meta)


GRAVITY_M_S2 = 9.80665


def tracker_errors(rng: np.random.Generator, n_tracker: int, cfg: HeadScenarioConfig) -> FloatArray:
    """The tracker's attitude errors (rotation vectors, rad) of n consecutive samples for the config's profile:
    white noise, plus the realistic profile's first-order Gauss-Markov error."""
    if cfg.profile != "realistic":
        return rng.normal(0.0, np.deg2rad(cfg.tracker_white_sigma_deg), (n_tracker, 3))
    white = np.deg2rad(cfg.tracker_white_sigma_realistic_deg)
    phi = np.exp(-1.0 / (cfg.tracker_rate_hz * cfg.tracker_gm_tau_s))
    gm_sigma = np.deg2rad(cfg.tracker_gm_sigma_deg)
    drive = rng.normal(0.0, gm_sigma * np.sqrt(1 - phi**2), (n_tracker, 3))
    gm = np.empty((n_tracker, 3))
    gm[0] = rng.normal(0.0, gm_sigma, 3)
    for k in range(1, n_tracker):
        gm[k] = phi * gm[k - 1] + drive[k]
    return gm + rng.normal(0.0, white, (n_tracker, 3))


def _accelerometer(seed: int, t: FloatArray, quat_true: FloatArray, cfg: HeadScenarioConfig) -> Stream:
    """The head IMU's accelerometer: specific force (gravity up plus the head's sway) in the head frame.

    Its own random stream (seed, 1), so that adding it leaves every other draw of the session unchanged.
    """
    from ..geometry import matrix_from_quat

    rng = np.random.default_rng([seed, 1])
    sway = np.zeros((t.size, 3))
    for axis in range(3):
        for _ in range(3):
            freq = rng.uniform(0.2, 2.0)
            sway[:, axis] += cfg.head_accel_m_s2 / np.sqrt(3) * rng.uniform(0.3, 1.0) * np.sin(2 * np.pi * freq * t + rng.uniform(0, 2 * np.pi))
    force_world = sway + np.array([0.0, 0.0, GRAVITY_M_S2])
    world_R_head = matrix_from_quat(quat_true)
    force_body = np.einsum("nji,nj->ni", world_R_head, force_world)
    bias = rng.uniform(-cfg.accel_bias_m_s2, cfg.accel_bias_m_s2, 3)
    measured = force_body + bias + rng.normal(0.0, cfg.accel_white_sigma_m_s2, force_body.shape)
    return Stream("accel", "accel", t.copy(), measured, KIND_COLUMNS["accel"], 0.0, {"rate_hz": cfg.gyro_rate_hz, "frame": "head"})


def _head_motion(rng: np.random.Generator, t: FloatArray, cfg: HeadScenarioConfig) -> tuple[FloatArray, FloatArray]:
    """ZYX angles and their rates: slow wandering + nods/shakes + minimum-jerk fast azimuth turns."""
    limit = np.deg2rad(cfg.max_angle_deg)
    raw = np.zeros((t.size, 3))
    raw_rate = np.zeros((t.size, 3))
    for axis, amplitude_deg in enumerate((22.0, 14.0, 8.0)):
        for _ in range(3):
            freq = rng.uniform(0.08, 0.9)
            amp = np.deg2rad(amplitude_deg) * rng.uniform(0.3, 1.0) / (1 + 2 * freq)
            phase = rng.uniform(0, 2 * np.pi)
            raw[:, axis] += amp * np.sin(2 * np.pi * freq * t + phase)
            raw_rate[:, axis] += amp * 2 * np.pi * freq * np.cos(2 * np.pi * freq * t + phase)
    # fast azimuth turns: minimum-jerk steps of 15-30 deg in 0.35-0.6 s (peak 50-150 deg/s)
    start = rng.uniform(0.5, cfg.fast_turn_every_s)
    while start < t[-1]:
        size = np.deg2rad(rng.uniform(15.0, 30.0)) * rng.choice([-1.0, 1.0])
        if abs(raw[np.searchsorted(t, start) - 1, 0] + size) > 0.8 * limit:
            size = -size
        length = rng.uniform(0.35, 0.6)
        s = np.clip((t - start) / length, 0.0, 1.0)
        raw[:, 0] += size * (10 * s**3 - 15 * s**4 + 6 * s**5)
        raw_rate[:, 0] += size * (30 * s**2 - 60 * s**3 + 30 * s**4) / length * ((t > start) & (t < start + length))
        start += length + rng.exponential(cfg.fast_turn_every_s)
    # soft bound: limit * tanh(raw / limit) keeps every angle inside +-limit with smooth rates
    angles = limit * np.tanh(raw / limit)
    rates = raw_rate / np.cosh(raw / limit) ** 2
    return angles, rates


def _misaligned_axes(rng: np.random.Generator, tilt_rad: float) -> FloatArray:
    """Rows are the gyro's sensitive axes, each tilted by ``tilt_rad`` in a random direction."""
    rows = []
    for axis in np.eye(3):
        direction = np.cross(axis, rng.normal(size=3))
        direction /= np.linalg.norm(direction)
        rows.append(np.cos(tilt_rad) * axis + np.sin(tilt_rad) * direction)
    return np.array(rows)
