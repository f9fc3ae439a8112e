"""Scenario ``ultrasonic``: N transmitters emitting at once, ceiling receivers that hear ranges in arrival order.

Receivers: a 3 x 6 grid at 30 cm pitch, 2.5 m above the floor (the fourth founding paper's board).
Transmitters on objects handled by people: rests and moves (up to 1 m/s) in a 2 x 1.5 m area at
0.5-1.3 m height. Every ``1 / rate_hz`` all transmitters emit; each receiver records the distances it
heard SORTED (arrival order), so which distance belongs to which transmitter is unknown. A reception
is missed with ``miss_prob``; an echo (a distance 0.1-1 m too long) is added with ``echo_prob``.
The truth keeps the label of every distance: transmitter index, or ``-1 - n`` for an echo of n.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import FloatArray
from ..records import RangeEpochs


def ceiling_board(nx: int = 3, ny: int = 6, pitch_m: float = 0.3, height_m: float = 2.5, centre_xy: tuple[float, float] = (1.0, 0.75)) -> FloatArray:
    """Receiver positions (R, 3): an nx x ny grid centred above the work area."""
    xs = centre_xy[0] + pitch_m * (np.arange(nx) - (nx - 1) / 2)
    ys = centre_xy[1] + pitch_m * (np.arange(ny) - (ny - 1) / 2)
    return np.array([[x, y, height_m] for x in xs for y in ys])


@dataclass(frozen=True)
class UltrasonicScenarioConfig:
    """Everything that defines a simulated ultrasonic session."""

    transmitters: int = 3
    """Number of transmitters N emitting simultaneously (1..16)."""
    duration_s: float = 20.0
    """Length of the session, seconds."""
    rate_hz: float = 40.0
    """Emission rate, Hz."""
    range_sigma_m: float = 0.005
    """Range noise, metres."""
    miss_prob: float = 0.05
    """Probability that a receiver misses a transmitter's emission."""
    echo_prob: float = 0.02
    """Probability of an echo per receiver and transmitter (an extra, longer distance)."""
    echo_extra_m: tuple[float, float] = (0.1, 1.0)
    """How much longer than the direct path an echo is, metres."""
    area_min_m: tuple[float, float, float] = (0.0, 0.0, 0.5)
    """Lower corner of the transmitters' region (x, y, z), metres."""
    area_max_m: tuple[float, float, float] = (2.0, 1.5, 1.3)
    """Upper corner, metres."""
    max_speed_m_s: float = 1.0
    """Fastest move, m/s."""
    rest_s: tuple[float, float] = (0.3, 2.5)
    """Range of rest durations between moves, seconds."""
    min_start_separation_m: float = 0.5
    """Transmitters start at least this far apart (the paper's setting: about 50 cm)."""
    receivers: FloatArray = field(default_factory=ceiling_board)
    """Receiver positions (R, 3), metres."""
    rigid_tag_offsets_m: tuple[tuple[float, float, float], ...] | None = None
    """The transmitters ride ONE body with these offsets (its frame, metres; one per transmitter), its centre moving in
    the plane at the area's mid height and turning about z (a trolley, as the UWB recordings): the session declares
    ``tag_offsets_m`` and ``planar``. None: independent transmitters."""
    range_bias_sigma_m: float = 0.0
    """A constant bias per receiver and transmitter, drawn once per seed with this sigma, metres (the UWB recordings
    carry 0-0.23 m); 0: none. Drawn from its own generator: the other draws of a seed do not change."""
    declare_calibration: bool = True
    """Declare the true biases as the session's range calibration (``range_bias_m``; scale 1, sigma ``range_sigma_m``)."""


def _trajectory(rng: np.random.Generator, t: FloatArray, start: FloatArray, cfg: UltrasonicScenarioConfig) -> FloatArray:
    """Rest, then move to a random waypoint with a smooth (raised-cosine) speed profile, repeat."""
    lo, hi = np.array(cfg.area_min_m), np.array(cfg.area_max_m)
    out = np.empty((len(t), 3))
    here, clock, i = start.copy(), 0.0, 0
    while i < len(t):
        rest_end = clock + rng.uniform(*cfg.rest_s)
        while i < len(t) and t[i] < rest_end:
            out[i] = here
            i += 1
        target = rng.uniform(lo, hi)
        distance = float(np.linalg.norm(target - here))
        peak = rng.uniform(0.3, 1.0) * cfg.max_speed_m_s
        duration = max(2.0 * distance / peak, 0.2)  # raised cosine: mean speed = peak / 2
        move_start = rest_end
        while i < len(t) and t[i] < move_start + duration:
            s = (t[i] - move_start) / duration
            out[i] = here + (target - here) * (s - np.sin(2 * np.pi * s) / (2 * np.pi))
            i += 1
        here, clock = target, move_start + duration
    return out


def hear(
    positions: FloatArray, receivers: FloatArray, rng: np.random.Generator, cfg: UltrasonicScenarioConfig, bias_m: FloatArray | None = None
) -> tuple[list[list[FloatArray]], list[list[np.ndarray]]]:
    """Sorted distances per epoch and receiver (with misses and echoes, ``bias_m`` (R, N) added), and their truth labels."""
    ranges: list[list[FloatArray]] = []
    labels: list[list[np.ndarray]] = []
    n = positions.shape[1]
    for k in range(positions.shape[0]):
        direct = np.linalg.norm(positions[k][None, :, :] - receivers[:, None, :], axis=2)  # (R, N)
        noisy = direct + rng.normal(0.0, cfg.range_sigma_m, direct.shape) + (0.0 if bias_m is None else bias_m)
        heard = rng.random(direct.shape) >= cfg.miss_prob
        echo = rng.random(direct.shape) < cfg.echo_prob
        extra = rng.uniform(*cfg.echo_extra_m, direct.shape)
        row_r, row_l = [], []
        for r in range(len(receivers)):
            d = np.concatenate([noisy[r, heard[r]], noisy[r, echo[r]] + extra[r, echo[r]]])
            lab = np.concatenate([np.arange(n)[heard[r]], -1 - np.arange(n)[echo[r]]])
            order = np.argsort(d)
            row_r.append(d[order])
            row_l.append(lab[order])
        ranges.append(row_r)
        labels.append(row_l)
    return ranges, labels


def simulate_ultrasonic(seed: int = 0, config: UltrasonicScenarioConfig | None = None, **overrides: object) -> RangeEpochs:
    """A seeded session: transmitters' truth, and what every receiver heard at every epoch."""
    from dataclasses import replace

    cfg = replace(config or UltrasonicScenarioConfig(), **overrides)  # type: ignore[arg-type]
    if not 1 <= cfg.transmitters <= 16:
        raise ValueError(f"transmitters must be 1..16, got {cfg.transmitters}")
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, cfg.duration_s, 1.0 / cfg.rate_hz)
    lo, hi = np.array(cfg.area_min_m), np.array(cfg.area_max_m)
    starts: list[FloatArray] = []
    while len(starts) < cfg.transmitters:
        candidate = rng.uniform(lo, hi)
        separation = cfg.min_start_separation_m if len(starts) < 6 else cfg.min_start_separation_m / 2  # 16 fit in 2 x 1.5 m
        if all(np.linalg.norm(candidate - s) >= separation for s in starts):
            starts.append(candidate)
    if cfg.rigid_tag_offsets_m is None:
        positions = np.stack([_trajectory(rng, t, s, cfg) for s in starts], axis=1)
    else:
        offsets = np.asarray(cfg.rigid_tag_offsets_m, dtype=float)
        if offsets.shape != (cfg.transmitters, 3):
            raise ValueError(f"rigid_tag_offsets_m: one [x, y, z] per transmitter ({cfg.transmitters}), got shape {offsets.shape}")
        centre = _trajectory(rng, t, starts[0], cfg)
        centre[:, 2] = 0.5 * (lo[2] + hi[2])
        yaw = 0.6 * np.sin(2 * np.pi * 0.07 * t + rng.uniform(0, 2 * np.pi))  # a slow turn back and forth
        c, s_ = np.cos(yaw), np.sin(yaw)
        positions = centre[:, None, :] + np.stack([c[:, None] * offsets[:, 0] - s_[:, None] * offsets[:, 1],
                                                   s_[:, None] * offsets[:, 0] + c[:, None] * offsets[:, 1],
                                                   np.broadcast_to(offsets[:, 2], (len(t), len(offsets)))], axis=2)
    bias = None
    if cfg.range_bias_sigma_m > 0:
        bias = np.random.default_rng([seed, 7]).normal(0.0, cfg.range_bias_sigma_m, (len(cfg.receivers), cfg.transmitters))
    ranges, labels = hear(positions, cfg.receivers, rng, cfg, bias)
    calibration = None
    if bias is not None and cfg.declare_calibration:
        calibration = (bias, np.ones_like(bias), np.full_like(bias, cfg.range_sigma_m))
    rigid = None if cfg.rigid_tag_offsets_m is None else np.asarray(cfg.rigid_tag_offsets_m, dtype=float)
    return RangeEpochs(t, cfg.receivers.copy(), ranges, labels, positions, cfg.range_sigma_m, rigid, rigid is not None, cfg.transmitters,
                       False, calibration)
