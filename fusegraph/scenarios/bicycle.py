"""Scenario ``bicycle``: a rider's thigh IMU and a frame IMU (under the saddle), 9-axis, 100 Hz.

Two rides: ``stand`` (indoor on a trainer: no translation, pedalling) and ``downhill`` (outdoor: a 4
degree descent with gentle curves, speeding up to ~8 m/s, hard braking at ``brake_s`` (~4 m/s^2 to
a stop), after which the rider holds the thigh still). The frame follows the road (heading, slope,
lean in curves, small pedalling rock); the thigh turns with the frame and pedals about the hip
(pitch +-20 deg about a 30 deg slope at the cadence, a little abduction), and its IMU sits 0.2 m
down the thigh, so it also feels the pedalling's own acceleration. Both accelerometers feel the
bicycle's translational acceleration. World ENU; body frames x forward, y left, z up.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..geometry import FloatArray, matrix_from_quat, quat_from_euler_zyx, quat_multiply
from ..records import BicycleScenarioConfig, BicycleSession
from ..session import KIND_COLUMNS, Session, Stream
from .attitude9 import _noisy_readings


def _speed(t: FloatArray, config: BicycleScenarioConfig) -> FloatArray:
    ramp = config.top_speed_m_s * np.clip((t - 2.0) / 10.0, 0.0, 1.0) ** 1.5 * (1 + 0.05 * np.sin(2 * np.pi * 0.1 * t))
    braking = np.clip(config.top_speed_m_s - config.decel_m_s2 * (t - config.brake_s), 0.0, None)
    v = np.where(t < config.brake_s, ramp, np.minimum(ramp, braking))
    return np.convolve(v, np.ones(15) / 15, mode="same") if config.ride == "downhill" else np.zeros_like(t)


def simulate_bicycle(seed: int = 0, config: BicycleScenarioConfig | None = None) -> BicycleSession:
    config = config or BicycleScenarioConfig()
    if config.ride not in ("downhill", "stand"):
        raise ValueError(f"unknown ride {config.ride!r}: use downhill or stand")
    rng = np.random.default_rng(seed)
    dt = 1.0 / config.rate_hz
    t = np.arange(0.0, config.duration_s, dt)
    n = len(t)
    v = _speed(t, config)
    moving = config.ride == "downhill"
    # road: gentle curves (heading), a descent (pitch down), lean into curves
    yaw_rate = (0.08 * np.sin(2 * np.pi * rng.uniform(0.03, 0.06) * t + rng.uniform(0, 6)) * (v / max(config.top_speed_m_s, 1e-9))) if moving else np.zeros(n)
    yaw = np.cumsum(yaw_rate) * dt + rng.uniform(-np.pi, np.pi)
    pitch_road = math.radians(config.slope_deg) if moving else 0.0
    pedal_env = np.clip((t - 1.0) / 1.0, 0, 1) * np.clip((config.brake_s - t) / 0.5, 0, 1)
    phase = 2 * np.pi * config.cadence_hz * t
    lean = np.arctan(v * yaw_rate / 9.81) + math.radians(1.5) * np.sin(phase) * pedal_env
    frame_euler = np.stack([yaw, np.full(n, pitch_road) + math.radians(0.5) * np.sin(2 * np.pi * 2.1 * t) * (v > 0.5), lean], axis=1)
    frame_q = quat_from_euler_zyx(frame_euler)
    heading = np.stack([np.cos(yaw) * math.cos(pitch_road), np.sin(yaw) * math.cos(pitch_road), -np.full(n, math.sin(pitch_road))], axis=1)
    frame_pos = np.cumsum(v[:, None] * heading, axis=0) * dt
    # thigh relative to the frame: a mean slope, pedalling swing, a little abduction; held after braking
    swing = math.radians(20.0) * np.sin(phase) * pedal_env
    held = np.where(t >= config.brake_s, 1.0, 0.0)
    rel_pitch = math.radians(30.0) + swing + math.radians(8.0) * held * np.clip((t - config.brake_s) / 1.0, 0, 1)
    rel_roll = math.radians(3.0) * np.sin(phase + 0.7) * pedal_env + math.radians(4.0)
    rel_q = quat_from_euler_zyx(np.stack([np.full(n, math.radians(5.0)), rel_pitch, rel_roll], axis=1))
    thigh_q = quat_multiply(frame_q, rel_q)
    hip = np.array([0.05, 0.1, -0.05])  # hip seen from the frame IMU (under the saddle)
    R_f = matrix_from_quat(frame_q)
    R_t = matrix_from_quat(thigh_q)
    thigh_pos = frame_pos + np.einsum("nij,j->ni", R_f, hip) + np.einsum("nij,j->ni", R_t, np.array([config.thigh_lever_m, 0.0, 0.0]))
    m_world = np.tile([0.0, math.cos(math.radians(60)), -math.sin(math.radians(60))], (n, 1))
    noise = (math.radians(config.gyro_bias_deg_s), config.gyro_sigma_rad_s, config.accel_sigma_m_s2, config.mag_sigma)
    out = {name: _noisy_readings(q, pos, t, m_world, rng, *noise)
           for name, q, pos in (("thigh", thigh_q, thigh_pos), ("frame", frame_q, frame_pos))}
    return BicycleSession(t=t, thigh_gyro=out["thigh"][0], thigh_accel=out["thigh"][1], thigh_mag=out["thigh"][2],
                          frame_gyro=out["frame"][0], frame_accel=out["frame"][1], frame_mag=out["frame"][2],
                          thigh_quat_wxyz=thigh_q, frame_quat_wxyz=frame_q, config=config)


def bicycle_session(seed: int = 0, profile: str | None = None, duration_s: float | None = None, ride: str = "downhill") -> Session:
    """The scenario as a session (``fusegraph simulate bicycle``): ``thigh_*`` and ``frame_*`` gyro,
    accel and mag streams; the ride and the braking time in the metadata; the thigh attitude as truth."""
    if profile not in (None, "realistic"):
        raise ValueError(f"--profile {profile} does not apply to bicycle (its noise is the realistic one)")
    config = BicycleScenarioConfig(ride=ride)
    if duration_s is not None:
        config = replace(config, duration_s=duration_s, brake_s=duration_s * config.brake_s / config.duration_s)
    b = simulate_bicycle(seed, config)
    streams = {}
    for body in ("thigh", "frame"):
        for kind, attr in (("gyro", "gyro"), ("accel", "accel"), ("mag", "mag")):
            name = f"{body}_{kind}"
            streams[name] = Stream(name, kind, b.t, getattr(b, f"{body}_{attr}"), KIND_COLUMNS[kind])
    truth = Stream("truth", "attitude", b.t, b.thigh_quat_wxyz, KIND_COLUMNS["attitude"])
    meta = {"session": {"description": f"bicycle scenario ({config.ride}), seed {seed}", "world_frame": "ENU",
                        "ride": config.ride, "brake_s": config.brake_s}}
    return Session("bicycle", streams, truth, meta)
