"""Timing and fixations of a head-worn eye tracker, from its gaze and gyro streams alone (no method's estimate).

While the eyes fixate a still target and the head turns, the eye counter-rotates (vestibulo-ocular reflex) so that the
gaze ray IN THE WORLD stays still. The world-frame angular velocity of the gaze, in the head frame, is
``d'(t) + omega(t) x d(t)`` (``d`` the pixel's ray, ``omega`` the gyro): measured with the gyro alone, it gives

* the **time offset** between the gaze stream and the IMU (``gaze_time_offset``): the delay d for which the gaze ray
  taken at stamp - d moves least in the world over the samples where the head turns (> ``HEAD_MIN_DEG_S``); each
  sample's squared speed is truncated at the fixation threshold (saccades are not fixations) and the mean minimised over
  a grid of d; its sigma is the spread of the minimiser over a block bootstrap (2 s blocks);
* **fixations** (``fixations``): a velocity threshold (I-VT) on that speed, ``FIXATION_MAX_DEG_S`` = 30 deg/s, for at
  least ``FIXATION_MIN_S`` without a tracking gap, and "with head motion": the head turned at least
  ``FIXATION_HEAD_MIN_DEG`` during it;
* the **dispersion** of a head attitude (``dispersion_deg``): per fixation, the angles of the world-frame gaze directions
  to their mean direction; the RMS over every fixation sample, degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..geometry import FloatArray, matrix_from_quat, quat_from_rotvec, quat_multiply
from ..records import GazeSession

BoolArray = npt.NDArray[np.bool_]
HEAD_MIN_DEG_S = 10.0
"""Head rates below this carry no timing information (the eye barely moves with the head), deg/s."""
FIXATION_MAX_DEG_S = 30.0
"""I-VT threshold on the world-frame gaze speed, deg/s (the usual value for head-worn trackers)."""
FIXATION_MIN_S = 0.1
"""Shortest fixation, seconds."""
FIXATION_HEAD_MIN_DEG = 5.0
"""Head rotation during a fixation for it to test the fusion, degrees."""
OFFSET_GRID_S = np.arange(-0.3, 0.3001, 0.0025)
"""Candidate gaze-minus-IMU offsets, seconds."""
SMOOTH_SAMPLES = 9
"""Savitzky-Golay window (samples, ~90 ms at 100 Hz) for the gaze ray's rate: one-sample differences of a
0.5 deg-noisy ray would be 70 deg/s of noise."""


def _segments(t: FloatArray, max_gap_s: float) -> list[slice]:
    """Runs of samples without a gap longer than ``max_gap_s`` (blinks split the gaze stream)."""
    breaks = np.nonzero(np.diff(t) > max_gap_s)[0] + 1
    edges = [0, *breaks.tolist(), len(t)]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]


def _ray_and_rate(t: FloatArray, rays: FloatArray) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Smoothed unit rays, their time derivative (head frame, 1/s) and a mask of samples where it is defined."""
    from scipy.signal import savgol_filter

    gap = 2.5 * float(np.median(np.diff(t)))
    smooth = np.full_like(rays, np.nan)
    rate = np.full_like(rays, np.nan)
    for seg in _segments(t, gap):
        n = seg.stop - seg.start
        if n < SMOOTH_SAMPLES:
            continue
        dt = float(np.median(np.diff(t[seg])))
        smooth[seg] = savgol_filter(rays[seg], SMOOTH_SAMPLES, 2, axis=0)
        rate[seg] = savgol_filter(rays[seg], SMOOTH_SAMPLES, 2, deriv=1, delta=dt, axis=0)
    ok = np.all(np.isfinite(rate), axis=1)
    smooth[ok] /= np.linalg.norm(smooth[ok], axis=1, keepdims=True)
    return smooth, rate, ok


def _gyro_at(session: GazeSession, times: FloatArray) -> FloatArray:
    return np.stack([np.interp(times, session.t, session.gyro_rad_s[:, c]) for c in range(3)], axis=1)


def world_gaze_speed(session: GazeSession, offset_s: float,
                     smoothed: tuple[FloatArray, FloatArray, BoolArray] | None = None) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Per gaze sample: world-frame gaze speed (deg/s, from the gyro alone), head speed (deg/s), defined mask;
    the gaze taken ``offset_s`` late (its sample at stamp - offset). ``smoothed``: ``_ray_and_rate`` of the session's
    gaze when the caller already has it (it does not depend on the offset)."""
    ray, rate, ok = smoothed or _ray_and_rate(session.tracker_t, session.config.camera.ray(session.gaze_px))
    omega = _gyro_at(session, session.tracker_t - offset_s)
    world = rate + np.cross(omega, ray)
    speed = np.rad2deg(np.linalg.norm(world, axis=1))
    head = np.rad2deg(np.linalg.norm(omega, axis=1))
    return speed, head, ok & (session.tracker_t - offset_s >= session.t[0]) & (session.tracker_t - offset_s <= session.t[-1])


def _argmin_refined(costs: FloatArray) -> float:
    i = int(np.argmin(costs))
    if 0 < i < len(costs) - 1:  # parabola through the minimum and its neighbours
        a, b, c = costs[i - 1 : i + 2]
        curvature = a - 2 * b + c
        if curvature > 0:
            return float(OFFSET_GRID_S[i] + 0.5 * (a - c) / curvature * (OFFSET_GRID_S[1] - OFFSET_GRID_S[0]))
    return float(OFFSET_GRID_S[i])


def gaze_time_offset(session: GazeSession, bootstrap: int = 100, block_s: float = 2.0, seed: int = 0) -> tuple[float, float]:
    """The gaze stream's delay behind the IMU (seconds, positive: gaze stamped late) and its bootstrap sigma."""
    smoothed = _ray_and_rate(session.tracker_t, session.config.camera.ray(session.gaze_px))
    per_offset = [world_gaze_speed(session, float(o), smoothed) for o in OFFSET_GRID_S]
    t = session.tracker_t
    blocks = np.floor((t - t[0]) / block_s).astype(int)
    n_blocks = int(blocks.max()) + 1
    # per block and offset: sum of truncated squared speeds and count of usable samples
    sums = np.zeros((n_blocks, len(OFFSET_GRID_S)))
    counts = np.zeros((n_blocks, len(OFFSET_GRID_S)))
    for j, (speed, head, ok) in enumerate(per_offset):
        use = ok & (head > HEAD_MIN_DEG_S)
        np.add.at(sums[:, j], blocks[use], np.minimum(speed[use], FIXATION_MAX_DEG_S) ** 2)
        np.add.at(counts[:, j], blocks[use], 1.0)
    best = _argmin_refined(sums.sum(0) / np.maximum(counts.sum(0), 1))
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(bootstrap):
        pick = rng.integers(0, n_blocks, n_blocks)
        draws.append(_argmin_refined(sums[pick].sum(0) / np.maximum(counts[pick].sum(0), 1)))
    return best, float(np.std(draws))


@dataclass(frozen=True)
class Fixation:
    """One fixation with head motion."""

    rows: FloatArray
    """Indices of its gaze samples."""
    head_turn_deg: float
    """How far the head turned during it, degrees."""


def fixations(session: GazeSession, offset_s: float) -> list[Fixation]:
    """Fixations with head motion (see the module docstring), the gaze taken ``offset_s`` late."""
    speed, _, ok = world_gaze_speed(session, offset_s)
    still = ok & (speed < FIXATION_MAX_DEG_S)
    t = session.tracker_t - offset_s
    gap = 2.5 * float(np.median(np.diff(t)))
    out = []
    for seg in _segments(t, gap):
        flags = still[seg]
        edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(int), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            rows = np.arange(seg.start + a, seg.start + b)
            if t[rows[-1]] - t[rows[0]] < FIXATION_MIN_S:
                continue
            inside = (session.t >= t[rows[0]]) & (session.t <= t[rows[-1]])
            turn = float(np.linalg.norm(np.sum(session.gyro_rad_s[inside] * np.gradient(session.t)[inside, None], axis=0)))
            if np.rad2deg(turn) >= FIXATION_HEAD_MIN_DEG:
                out.append(Fixation(rows, float(np.rad2deg(turn))))
    return out


def fixation_angles(world_R_head: FloatArray | None, rays: FloatArray, fixation: Fixation) -> FloatArray:
    """Angles (rad) of a fixation's world-frame gaze directions to their mean direction; NaN where the method has no
    attitude. ``world_R_head`` (quaternions at the gaze samples) None: the head frame (no attitude at all)."""
    d = rays[fixation.rows]
    if world_R_head is not None:
        q = world_R_head[fixation.rows]
        if not np.all(np.isfinite(q)):
            return np.full(len(d), np.nan)
        d = np.einsum("nij,nj->ni", matrix_from_quat(q), d)
    mean = d.sum(0) / np.linalg.norm(d.sum(0))
    return np.arccos(np.clip(d @ mean, -1.0, 1.0))


def dispersion_deg(world_R_head: FloatArray | None, session: GazeSession, found: list[Fixation]) -> float:
    """RMS angle of the world-frame gaze directions to their fixation's mean direction, over every fixation sample, degrees.
    ``world_R_head`` (quaternions at the gaze samples) None: the head frame. A method without an attitude on a fixation
    sample fails (NaN): it does not escape its hard samples."""
    rays = session.config.camera.ray(session.gaze_px)
    angles = [fixation_angles(world_R_head, rays, fixation) for fixation in found]
    return float(np.rad2deg(np.sqrt(np.mean(np.concatenate(angles) ** 2)))) if angles else float("nan")


def gyro_attitude(session: GazeSession) -> FloatArray:
    """The raw gyro integrated from identity (no bias estimate) at the gaze samples' times."""
    from ..factors.gyro import integrate_gyro

    quat = integrate_gyro(session.t, session.gyro_rad_s, np.array([1.0, 0.0, 0.0, 0.0]))
    i = np.clip(np.searchsorted(session.t, session.tracker_t, side="right") - 1, 0, len(session.t) - 1)
    step = session.gyro_rad_s[np.minimum(i + 1, len(session.t) - 1)] * (session.tracker_t - session.t[i])[:, None]
    return quat_multiply(quat[i], quat_from_rotvec(step))
