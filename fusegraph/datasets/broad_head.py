"""Head sessions from BROAD trials (``fusegraph import broad DIR --system head``): recorded motion as a head rig sees it.

Each BROAD trial gives what a head-tracking rig records, minus the tracker's own errors:

* gyro: the trial's recorded gyro as it is (its real bias, scale factors and misalignment; ~286 Hz);
* tracker: the optical attitude decimated to 50 Hz (the gyro sample nearest each 20 ms instant),
  100 ms late, with the realistic head profile's tracker errors added (white 0.4 deg plus a
  0.7 deg, 2 s Gauss-Markov error; ``scenarios.head.tracker_errors``, fixed seed), 2 % dropped,
  and no sample where the optical markers were occluded;
* movement: the trial's own flag (the head preset scores where it is set);
* truth: the optical attitude at the gyro rate (lag-free).

The gyro's delay against the tracker is found from those two streams (``head_timing.gyro_delay_from_tracker``; never
from the reference) and declared on the gyro stream, where every solver reads it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..frontends import head_timing
from ..geometry import quat_from_rotvec, quat_multiply, quat_normalize
from ..scenarios.head import HeadScenarioConfig, tracker_errors
from ..session import KIND_COLUMNS, Session, Stream
from .broad import load_broad

TRACKER_SEED = 0
"""Seed of the added tracker errors and drops (fixed: every import of a trial gives the same tracker)."""


@dataclass(frozen=True)
class RecordedHeadConfig:
    """How a BROAD trial becomes a head session."""

    tracker_rate_hz: float = 50.0
    """Rate of the simulated tracker, Hz (the optical attitude is decimated to it)."""
    tracker_latency_s: float = 0.1
    """Transport delay of every tracker sample, seconds (declared in the session: known)."""
    drop_fraction: float = 0.02
    """Fraction of tracker samples dropped at random."""
    errors: HeadScenarioConfig = HeadScenarioConfig(profile="realistic", tracker_rate_hz=50.0)
    """Source of the tracker error model (the realistic head profile's)."""
    gyro_noise_sigma_rad_s: float = 0.015
    """Gyro white noise per sample the session declares, rad/s (the head model's default: BROAD's IMU
    data sheet is not given; the graph estimates scale and misalignment because ``calibrated`` is false)."""
    estimate_gyro_delay: bool = True
    """Declare the gyro's delay on the session's gyro stream as found from the gyro and the tracker alone
    (``head_timing.gyro_delay_from_tracker``), so every method, Method II as well, runs on one clock. BROAD's gyro lags its
    optical attitude by ~4 ms (1.0-1.2 samples on all eleven trials): at 100-300 deg/s that is 0.4-1.2 deg."""


def head_session_from_broad(path: str | Path, config: RecordedHeadConfig | None = None, seed: int = TRACKER_SEED) -> Session:
    """A head session from one BROAD trial (streams ``gyro``, ``tracker``, ``movement``; truth at the gyro rate)."""
    cfg = config or RecordedHeadConfig()
    trial = load_broad(path)
    gyro_in = trial.stream("gyro")
    assert trial.truth is not None
    optical = trial.truth.values
    rate = float(gyro_in.meta["rate_hz"])
    instants = np.arange(0.0, gyro_in.t[-1], 1.0 / cfg.tracker_rate_hz)
    idx = np.unique(np.clip(np.round(instants * rate).astype(int), 0, len(gyro_in) - 1))
    rng = np.random.default_rng(seed)
    error = tracker_errors(rng, idx.size, replace(cfg.errors, tracker_rate_hz=cfg.tracker_rate_hz))
    keep = rng.random(idx.size) >= cfg.drop_fraction
    keep &= np.all(np.isfinite(optical[idx]), axis=1)  # occluded markers: the tracker reports nothing
    quat = quat_multiply(quat_normalize(np.where(np.isfinite(optical[idx]), optical[idx], [1.0, 0, 0, 0])), quat_from_rotvec(error))
    gyro = Stream(
        "gyro",
        "gyro",
        gyro_in.t.copy(),
        gyro_in.values.copy(),
        KIND_COLUMNS["gyro"],
        0.0,
        {"rate_hz": rate, "frame": "head", "noise_sigma_rad_s": cfg.gyro_noise_sigma_rad_s, "calibrated": False},
    )
    e = cfg.errors
    tracker = Stream(
        "tracker",
        "attitude",
        gyro_in.t[idx][keep],
        quat[keep],
        KIND_COLUMNS["attitude"],
        cfg.tracker_latency_s,
        {
            "rate_hz": cfg.tracker_rate_hz,
            "frame": "world_R_head",
            "noise_sigma_deg": e.tracker_white_sigma_realistic_deg,
            "markov_sigma_deg": e.tracker_gm_sigma_deg,
            "markov_tau_s": e.tracker_gm_tau_s,
        },
    )
    if cfg.estimate_gyro_delay:  # from the two streams the estimators get; the reference is not read
        delay = head_timing.gyro_delay_from_tracker(Session("head", {"gyro": gyro, "tracker": tracker}, None, {}, trial.path))
        gyro = replace(gyro, meta={**gyro.meta, "delay_s": delay.delay_s, "delay_sigma_s": delay.sigma_s})
    truth = replace(trial.truth, meta={**trial.truth.meta, "frame": "world_R_head"})
    meta = {
        "session": {
            "system": "head",
            "dataset": "BROAD",
            "trial": Path(path).stem,
            "world_frame": "ENU (optical)",
            "description": f"head session from BROAD trial {Path(path).stem}: recorded gyro, optical attitude as a late tracker",
        }
    }
    return Session("head", {"gyro": gyro, "tracker": tracker, "movement": trial.stream("movement")}, truth, meta, trial.path)
