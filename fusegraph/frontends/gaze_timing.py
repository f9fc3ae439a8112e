"""Timing and fixations of a head-worn eye tracker, from its gaze and gyro streams alone (no method's estimate).

While the eyes fixate a still target and the head turns, the eye counter-rotates (vestibulo-ocular reflex) so that the
gaze ray IN THE WORLD stays still. The world-frame angular velocity of the gaze, in the head frame, is
``d'(t) + omega(t) x d(t)`` (``d`` the pixel's ray, ``omega`` the gyro): measured with the gyro alone, it gives

* the **time offset** between the gaze stream and the IMU (``gaze_time_offset``): the delay d for which the gaze ray
  taken at stamp - d moves least in the world over the samples where the head turns (> ``HEAD_MIN_DEG_S``); each
  sample's squared speed is truncated at the fixation threshold (saccades are not fixations) and the mean minimised over
  a grid of d (+-0.3 s, doubled while the best lies at its edge, up to +-2.4 s); its sigma is the spread of the
  minimiser over a block bootstrap (2 s blocks); with under a hundred samples of head turns the recording does not tell
  it (``find_time_offset``: ``told`` False, none applied);
The fixations that SCORE the methods read no IMU (the gyro is a scored method's input): the device's own detector
where the export has one (``device_fixations``), else the intervals between saccades of the eye-in-head speed
(``eye_velocity_fixations``, the saccade threshold from the data) in which the eye turned in the head (the reflex
counter-rotating a head turn). The **dispersion** of a head attitude (``dispersions_deg``): per fixation, the RMS angle
of the world-frame gaze directions to their mean direction, degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ..geometry import FloatArray, matrix_from_quat, quat_conjugate, quat_from_rotvec, quat_multiply, rotvec_from_quat
from ..records import GazeSession

BoolArray = npt.NDArray[np.bool_]
HEAD_MIN_DEG_S = 10.0
"""Head rates below this carry no timing information (the eye barely moves with the head), deg/s."""
FIXATION_MAX_DEG_S = 30.0
"""The time offset's cost truncates the world-frame gaze speed here, deg/s (the usual I-VT threshold of head-worn
trackers: faster is a saccade, which says nothing about the offset)."""
FIXATION_MIN_S = 0.1
"""Shortest fixation, seconds."""
FIXATION_HEAD_MIN_DEG = 5.0
"""Eye-in-head rotation during an eye-velocity fixation (the head's turn, counter-rotated) for it to test the fusion, degrees."""
SETTLE_S = 1.0
"""Fixations are scored from this long after the IMU's first sample (every method's start-up, as the head system scores)
to its last."""
SACCADE_START_DEG_S = 100.0
"""Where the adaptive saccade threshold starts (Nystrom & Holmqvist's initial value), deg/s."""
OFFSET_STEP_S = 0.0025
"""Step of the candidate gaze-minus-IMU offsets, seconds."""
OFFSET_SEARCH_S = 0.3
"""Half-width of the first search, seconds; doubled while the best lies within a step of its edge."""
OFFSET_WIDEST_S = 2.4
"""Widest search, seconds: beyond it the streams do not share a clock, which the import says."""
OFFSET_MIN_SAMPLES = 100
"""Gaze samples with the head turning faster than ``HEAD_MIN_DEG_S`` that the offset needs (about a second of head
turns at 100 Hz); with fewer the recording does not tell the offset and none is estimated."""
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


def _argmin_refined(costs: FloatArray, grid: FloatArray) -> float:
    i = int(np.argmin(costs))
    if 0 < i < len(costs) - 1 and np.all(np.isfinite(costs[i - 1 : i + 2])):  # parabola through the minimum and its neighbours
        a, b, c = costs[i - 1 : i + 2]
        curvature = a - 2 * b + c
        if curvature > 0:
            return float(grid[i] + 0.5 * (a - c) / curvature * (grid[1] - grid[0]))
    return float(grid[i])


@dataclass(frozen=True)
class TimeOffset:
    """The gaze stream's delay behind the IMU, as the data tell it."""

    offset_s: float
    """Seconds, positive: the gaze is stamped late. 0 when ``told`` is False."""
    sigma_s: float
    """Its block-bootstrap sigma, seconds (inf when not told)."""
    told: bool
    """False: the head turned too little (fewer than ``OFFSET_MIN_SAMPLES`` samples above ``HEAD_MIN_DEG_S``)."""
    at_edge: bool
    """The best offset lay at the widest search's edge (+-``OFFSET_WIDEST_S``): the streams may not share a clock."""
    search_s: float
    """Half-width of the search that found it, seconds."""


def find_time_offset(session: GazeSession, bootstrap: int = 100, block_s: float = 2.0, seed: int = 0) -> TimeOffset:
    """The gaze stream's delay behind the IMU: the offset whose gyro-compensated gaze moves least while the head turns,
    searched over +-``OFFSET_SEARCH_S``, the range doubled while the best lies within a step of its edge (up to
    ``OFFSET_WIDEST_S``); its sigma from a block bootstrap (``block_s`` blocks)."""
    smoothed = _ray_and_rate(session.tracker_t, session.config.camera.ray(session.gaze_px))
    t = session.tracker_t
    blocks = np.floor((t - t[0]) / block_s).astype(int)
    n_blocks = int(blocks.max()) + 1
    per_step: dict[int, tuple[FloatArray, FloatArray]] = {}  # per offset (in steps): each block's sum of truncated squared
    # speeds and count of usable samples; a widened search reuses the narrower one's

    def block_sums(step: int) -> tuple[FloatArray, FloatArray]:
        if step not in per_step:
            speed, head, ok = world_gaze_speed(session, step * OFFSET_STEP_S, smoothed)
            use = ok & (head > HEAD_MIN_DEG_S)
            per_step[step] = (np.bincount(blocks[use], np.minimum(speed[use], FIXATION_MAX_DEG_S) ** 2, n_blocks).astype(float),
                              np.bincount(blocks[use], minlength=n_blocks).astype(float))
        return per_step[step]

    search = OFFSET_SEARCH_S
    while True:
        steps = np.arange(-round(search / OFFSET_STEP_S), round(search / OFFSET_STEP_S) + 1)
        grid: FloatArray = steps.astype(float) * OFFSET_STEP_S
        sums, counts = (np.stack(part, axis=1) for part in zip(*(block_sums(int(k)) for k in steps), strict=True))
        usable = counts.sum(0) >= OFFSET_MIN_SAMPLES  # a wide offset of a short recording overlaps too little
        if search == OFFSET_SEARCH_S and not usable.all():
            return TimeOffset(0.0, float("inf"), False, False, search)
        best = _argmin_refined(np.where(usable, sums.sum(0) / np.maximum(counts.sum(0), 1), np.inf), grid)
        edge = abs(best) >= search - OFFSET_STEP_S
        if not edge or search >= OFFSET_WIDEST_S:
            break
        search = min(2 * search, OFFSET_WIDEST_S)
    rng = np.random.default_rng(seed)
    draws = []
    for _ in range(bootstrap):
        pick = rng.integers(0, n_blocks, n_blocks)
        draws.append(_argmin_refined(np.where(usable, sums[pick].sum(0) / np.maximum(counts[pick].sum(0), 1), np.inf), grid))
    return TimeOffset(best, float(np.std(draws)), True, edge, search)


def gaze_time_offset(session: GazeSession, bootstrap: int = 100, block_s: float = 2.0, seed: int = 0) -> tuple[float, float]:
    """The gaze stream's delay behind the IMU (seconds, positive: gaze stamped late) and its bootstrap sigma
    (``find_time_offset``; 0 and inf where the head turned too little to tell)."""
    found = find_time_offset(session, bootstrap, block_s, seed)
    return found.offset_s, found.sigma_s


@dataclass(frozen=True)
class Fixation:
    """One fixation scored."""

    rows: np.ndarray
    """Indices of its gaze samples."""
    eye_turn_deg: float
    """How far the eye turned in the head during it, degrees (in a fixation the eye counter-rotates the head's turn: the
    reflex makes this the head motion the fixation tests, read from the gaze alone)."""


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) of each run of True."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], flags.astype(int), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _eye_turn_deg(rays: FloatArray, rows: np.ndarray) -> float:
    """Largest angle of a fixation's head-frame rays from its first one, degrees."""
    d = rays[rows]
    return float(np.rad2deg(np.max(np.arccos(np.clip(d @ d[0], -1.0, 1.0)))))


def saccade_threshold_deg_s(eye_speed_deg_s: FloatArray, start_deg_s: float = SACCADE_START_DEG_S) -> float:
    """The data's own saccade threshold, after Nystrom & Holmqvist (Behav Res Methods 42:188-204, 2010): starting from
    ``start_deg_s``, the centre plus 6 spreads of the eye-in-head speeds below the current threshold, until it moves
    less than 1 deg/s. Deviation, and why: their centre and spread are the mean and standard deviation, for a head held
    still; with the head free the reflex's speeds give a heavy tail that drove mean + 6 SD to 477 deg/s on the Tobii
    recording (every saccade below it), so the median and the MAD (x 1.4826, the SD of a normal sample) serve here."""
    speed = eye_speed_deg_s[np.isfinite(eye_speed_deg_s)]
    threshold = start_deg_s
    for _ in range(100):
        below = speed[speed < threshold]
        if len(below) < 10:
            break
        centre = float(np.median(below))
        new = centre + 6.0 * 1.4826 * float(np.median(np.abs(below - centre)))
        if abs(new - threshold) < 1.0:
            return new
        threshold = new
    return threshold


def eye_velocity_fixations(session: GazeSession) -> tuple[list[Fixation], float]:
    """Fixations from the gaze alone (no IMU): the intervals between saccades of the eye-in-head speed (its threshold
    from the data, ``saccade_threshold_deg_s``) lasting ``FIXATION_MIN_S`` without a tracking gap, in which the eye
    turned at least ``FIXATION_HEAD_MIN_DEG`` in the head (the reflex's counter-rotation: a fixation with head motion).
    Returns them and the threshold."""
    rays, rate, ok = _ray_and_rate(session.tracker_t, session.config.camera.ray(session.gaze_px))
    speed = np.where(ok, np.rad2deg(np.linalg.norm(rate, axis=1)), np.nan)
    threshold = saccade_threshold_deg_s(speed)
    t = session.tracker_t
    out = []
    settled = _scored_span(session)
    for seg in _segments(t, 2.5 * float(np.median(np.diff(t)))):
        for a, b in _runs(ok[seg] & (speed[seg] < threshold) & settled[seg]):
            rows = np.arange(seg.start + a, seg.start + b)
            if t[rows[-1]] - t[rows[0]] >= FIXATION_MIN_S and (turn := _eye_turn_deg(rays, rows)) >= FIXATION_HEAD_MIN_DEG:
                out.append(Fixation(rows, turn))
    return out, threshold


def scoring_fixations(session: GazeSession, fixation_id: FloatArray | None) -> tuple[list[Fixation], str]:
    """The fixations that score a recording and where they come from: ``"device"`` (the export's own detector, ids per
    gaze sample) or ``"eye_velocity"`` (``eye_velocity_fixations``)."""
    if fixation_id is not None:
        return device_fixations(session, fixation_id), "device"
    return eye_velocity_fixations(session)[0], "eye_velocity"


def _scored_span(session: GazeSession) -> np.ndarray:
    """Gaze samples inside the IMU's span, after its first ``SETTLE_S`` (no head attitude exists outside it)."""
    return (session.tracker_t >= session.t[0] + SETTLE_S) & (session.tracker_t <= session.t[-1])


def device_fixations(session: GazeSession, fixation_id: FloatArray) -> list[Fixation]:
    """The eye tracker's own fixations (its detector's id per gaze sample, 0 or NaN outside one) lasting
    ``FIXATION_MIN_S`` after the first ``SETTLE_S``; every one is scored (the device's detector decides what a fixation is)."""
    rays = session.config.camera.ray(session.gaze_px)
    ids = np.nan_to_num(np.asarray(fixation_id, dtype=float))
    out = []
    for value in np.unique(ids[ids > 0]):
        rows = np.flatnonzero(ids == value)
        rows = rows[_scored_span(session)[rows]]
        if len(rows) and session.tracker_t[rows[-1]] - session.tracker_t[rows[0]] >= FIXATION_MIN_S:
            out.append(Fixation(rows, _eye_turn_deg(rays, rows)))
    return out


def _reflex_samples(session: GazeSession, found: list[Fixation]) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """The scored fixations' samples with the head turning faster than ``HEAD_MIN_DEG_S``: the gaze ray's rate in the
    head (1/s), the ray, the gyro's rate (rad/s); None without such samples."""
    if not found:
        return None
    rays, rate, ok = _ray_and_rate(session.tracker_t, session.config.camera.ray(session.gaze_px))
    rows = np.concatenate([f.rows for f in found])
    omega = _gyro_at(session, session.tracker_t[rows])
    use = ok[rows] & (np.rad2deg(np.linalg.norm(omega, axis=1)) > HEAD_MIN_DEG_S)
    if not use.any() or not np.any(np.cross(rays[rows][use], omega[use])):
        return None
    return rate[rows][use], rays[rows][use], omega[use]


def counter_rotation_gain(session: GazeSession, found: list[Fixation]) -> float | None:
    """How much of the head's rotation the eye counter-rotated in the scored fixations: the least-squares slope of the
    gaze ray's rate in the head on ``d x omega`` (the rate that holds the gaze still in the world while the head turns at
    the gyro's ``omega``), over fixation samples with the head turning faster than ``HEAD_MIN_DEG_S``. About 1: the gaze
    stood still in the world, and a fixation's dispersion tests the head attitude; well below 1: the gaze moved with the
    head (pursuit, or a head translating towards a near target), and the gaze in the head frame can be the stiller one
    whatever the attitude. A description of the recording that reads the gyro: it selects and scores nothing. None
    without such samples."""
    samples = _reflex_samples(session, found)
    if samples is None:
        return None
    rate, rays, omega = samples
    holding = np.cross(rays, omega)
    return float(np.sum(rate * holding) / np.sum(holding * holding))


def counter_rotation_gain_by_axis(session: GazeSession, found: list[Fixation]) -> dict[str, float | None] | None:
    """``counter_rotation_gain`` per head axis: one least-squares fit of the gaze ray's rate on ``d x (omega_k e_k)`` for
    roll, pitch and yaw together (the head's axes: x forward, y left, z up), pitch and yaw returned where the head turned
    about that axis at ``HEAD_MIN_DEG_S`` / 2 RMS or more (else None; a turn about the line of sight hardly moves the ray:
    roll's gain is not determined). A head bouncing towards a near target moves the target in pitch; a gaze that falls
    short in yaw as well turned with the head. A description, as the overall gain."""
    samples = _reflex_samples(session, found)
    if samples is None:
        return None
    rate, rays, omega = samples
    columns = np.stack([np.cross(rays, omega * (np.arange(3) == k)).ravel() for k in range(3)], axis=1)
    gains = np.linalg.lstsq(columns, rate.ravel(), rcond=None)[0]
    turned = np.rad2deg(np.sqrt(np.mean(omega**2, axis=0))) >= HEAD_MIN_DEG_S / 2
    return {axis: float(gains[k]) if turned[k] else None for k, axis in ((1, "pitch"), (2, "yaw"))}


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


def dispersions_deg(world_R_head: FloatArray | None, session: GazeSession, found: list[Fixation]) -> FloatArray:
    """Each fixation's dispersion: the RMS angle of its world-frame gaze directions to their mean direction, degrees.
    ``world_R_head`` (quaternions at the gaze samples) None: the head frame. A method without an attitude on a fixation
    sample gets NaN there: it does not escape its hard samples."""
    rays = session.config.camera.ray(session.gaze_px)
    return np.array([float(np.rad2deg(np.sqrt(np.mean(fixation_angles(world_R_head, rays, f) ** 2)))) for f in found])


def turn_beyond_gyro_deg(world_R_head: FloatArray, gyro_R_head: FloatArray, found: list[Fixation]) -> FloatArray:
    """Per fixation, the largest angle between a method's head rotation since the fixation's first sample and the raw
    gyro's (``gyro_attitude``), degrees: what the method turned the head beyond its gyro inside the fixation. A bias
    correction over a fraction of a second is a few tenths of a degree; more is a filter's update or a saturated gyro's
    recovery. A description of an estimate: it selects and scores nothing."""
    out = []
    for fixation in found:
        q, g = world_R_head[fixation.rows], gyro_R_head[fixation.rows]
        if not np.all(np.isfinite(q)):
            out.append(np.nan)
            continue
        since_q = quat_multiply(quat_conjugate(q[:1]), q)
        since_g = quat_multiply(quat_conjugate(g[:1]), g)
        out.append(float(np.rad2deg(np.max(np.linalg.norm(rotvec_from_quat(quat_multiply(quat_conjugate(since_g), since_q)), axis=1)))))
    return np.array(out)


def gyro_attitude(session: GazeSession) -> FloatArray:
    """The raw gyro integrated from identity (no bias estimate) at the gaze samples' times."""
    from ..factors.gyro import integrate_gyro

    quat = integrate_gyro(session.t, session.gyro_rad_s, np.array([1.0, 0.0, 0.0, 0.0]))
    i = np.clip(np.searchsorted(session.t, session.tracker_t, side="right") - 1, 0, len(session.t) - 1)
    step = session.gyro_rad_s[np.minimum(i + 1, len(session.t) - 1)] * (session.tracker_t - session.t[i])[:, None]
    return quat_multiply(quat[i], quat_from_rotvec(step))
