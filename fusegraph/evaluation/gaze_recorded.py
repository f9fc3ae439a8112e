"""Gaze on a real eye tracker's recording without ground truth (``fusegraph bench gaze-recorded``).

What must hold: while the eyes fixate a still target and the head turns, the eye counter-rotates
(vestibulo-ocular reflex) so that the gaze ray IN THE WORLD stays still. The world-frame gaze
direction of a sample is ``world_R_head(t) @ ray(pixel)``: the measured pixel's ray turned by a
method's head attitude at the sample's time. Its spread during fixations with head motion measures
how well head attitude, eye-in-head gaze and their relative timing are fused.

Nothing here depends on any method's estimate (every method is scored on the same samples):

* **Time offset** between the gaze stream and the IMU (``gaze_time_offset``): the delay d for which
  the gaze ray taken at stamp - d moves least in the world over the samples where the head turns
  (> ``HEAD_MIN_DEG_S``), measured with the gyro alone: the world-frame angular velocity of the gaze
  in the head frame is ``d'(t) + omega(t) x d(t)``; each sample's squared speed is truncated at the
  fixation threshold (saccades are not fixations) and the mean minimised over a grid of d. Its sigma
  is the spread of the minimiser over a block bootstrap (2 s blocks).
* **Fixations** (``fixations``): a velocity threshold (I-VT) on that same gyro-compensated speed,
  ``FIXATION_MAX_DEG_S`` = 30 deg/s, for at least ``FIXATION_MIN_S`` without a tracking gap, and
  "with head motion": the head turned at least ``FIXATION_HEAD_MIN_DEG`` during it.
* **Dispersion** of a method: per fixation, the angles of the world-frame gaze directions to their
  mean direction; the RMS over every fixation sample, degrees. ``head_frame`` uses no head attitude
  (the gaze in the head frame: no fusion), ``gyro`` the raw gyro integrated (no bias estimate).

The magnetometer of the shipped recording reads 110-131 uT (the Earth's field is ~50): a constant
part from the glasses themselves that 65 s of turning +-70 deg about one axis cannot calibrate (a
sphere fit gives 31 uT and an 82 deg dip, its design matrix condition 1.6e4), so every method runs
WITHOUT it (gyro, accelerometer, gaze); ``--use-mag`` runs them with it as recorded.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from ..geometry import FloatArray, matrix_from_quat, quat_from_rotvec, quat_multiply
from ..scenarios.gaze import GazeSession

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


@dataclass(frozen=True)
class RecordedGaze:
    """One recording analysed: what the bench's JSON and its figure are made from."""

    session: GazeSession
    """The recording as the gaze system reads it (gaze stamps as recorded)."""
    aligned: GazeSession
    """The same with the gaze stamps corrected by the offset found (what every method ran on)."""
    offset_s: float
    """Gaze-to-IMU time offset found, seconds."""
    offset_sigma_s: float
    """Its block-bootstrap sigma, seconds."""
    fixations: list[Fixation]
    """Fixations with head motion."""
    attitudes: dict[str, FloatArray | None]
    """world_R_head at the gaze samples per row (``head_frame``: None), in the table's order."""
    runtime_s: dict[str, float]
    """Run time of each estimator, seconds."""
    untracked: int
    """Gaze lines without a measurement."""
    use_mag: bool
    """Whether the estimators used the magnetometer."""


def analyse_gaze_recording(directory: str | Path | None = None, use_mag: bool = False) -> RecordedGaze:
    """Offset, fixations and every method's head attitude on the eye-tracker recording in ``directory``."""
    from ..baselines.ekf_gaze import GazeEkfConfig
    from ..datasets.tobii import DEFAULT_DIR, load_tobii
    from ..systems import gaze

    recording = load_tobii(directory or DEFAULT_DIR)
    session = gaze.from_session(recording)
    offset, sigma = gaze_time_offset(session)
    aligned = replace(session, tracker_t=session.tracker_t - offset)
    model = gaze.GazeModel()
    model = replace(model, head=replace(model.head, use_mag=use_mag))
    estimates = {
        "ekf": gaze.run_ekf(aligned, replace(GazeEkfConfig(), use_mag=use_mag)),
        "online": gaze.run_online(aligned, model),
        "batch": gaze.run_batch(aligned, model),
    }
    attitudes: dict[str, FloatArray | None] = {"head_frame": None, "gyro": gyro_attitude(aligned)}
    attitudes.update({name: e.world_R_head for name, e in estimates.items()})
    return RecordedGaze(session, aligned, offset, sigma, fixations(session, offset), attitudes, {name: e.runtime_s for name, e in estimates.items()},
                        int(recording.meta["session"].get("gaze_untracked", 0)), use_mag)


def gaze_recorded_json(run: RecordedGaze) -> dict[str, Any]:
    """The JSON of ``fusegraph bench gaze-recorded`` (see the module docstring)."""
    found, session = run.fixations, run.session
    duration = float(session.t[-1] - session.t[0])
    turns = [f.head_turn_deg for f in found]
    return {
        "dispersion_deg": {name: dispersion_deg(quat, run.aligned, found) for name, quat in run.attitudes.items()},
        "time_offset_s": run.offset_s,
        "time_offset_sigma_s": run.offset_sigma_s,
        "fixations": len(found),
        "fixation_samples": int(sum(len(f.rows) for f in found)),
        "fixation_head_turn_deg": {"median": float(np.median(turns)) if turns else None, "max": float(np.max(turns)) if turns else None},
        "gaze_samples": len(session.tracker_t),
        "gaze_untracked": run.untracked,
        "duration_s": duration,
        "use_mag": run.use_mag,
        "x_realtime": {name: duration / max(seconds, 1e-9) for name, seconds in run.runtime_s.items()},
        "camera": {"focal_px": session.config.camera.focal_px, "pixel_sigma": session.config.camera.pixel_sigma},
    }


def bench_gaze_recorded(directory: str | Path | None = None, use_mag: bool = False) -> dict[str, Any]:
    """``fusegraph bench gaze-recorded``: the JSON (see the module docstring)."""
    return gaze_recorded_json(analyse_gaze_recording(directory, use_mag))


def format_gaze_recorded(result: dict[str, Any]) -> str:
    """The bench as text."""
    d = result["dispersion_deg"]
    labels = {
        "head_frame": "gaze in the head frame (no fusion)",
        "gyro": "raw gyro integrated",
        "ekf": "the paper's EKF",
        "online": "fusegraph online",
        "batch": "fusegraph batch",
    }
    lines = [
        f"gaze on a recorded head-worn eye tracker ({result['duration_s']:.0f} s; {result['gaze_samples']} gaze samples, "
        f"{result['gaze_untracked']} untracked; magnetometer {'used' if result['use_mag'] else 'not used (uncalibratable)'})",
        f"gaze-to-IMU time offset: {1000 * result['time_offset_s']:.1f} ms (sigma {1000 * result['time_offset_sigma_s']:.1f} ms, "
        "block bootstrap); gaze stamps corrected by it for every method",
        f"{result['fixations']} fixations with head motion ({result['fixation_samples']} samples; head turn median "
        f"{result['fixation_head_turn_deg']['median'] or float('nan'):.1f} deg, max {result['fixation_head_turn_deg']['max'] or float('nan'):.1f} deg)",
        f"{'method':<36} {'dispersion of the world gaze ray [deg]':>40} {'x real time':>12}",
    ]
    for name, value in d.items():
        speed = result["x_realtime"].get(name)
        lines.append(f"{labels[name]:<36} {value:40.3f} {'' if speed is None else f'{speed:12.0f}'}")
    for name in ("online", "batch"):
        lines.append(f"{name}: x{d[name] / d['ekf']:.2f} the EKF's dispersion, x{d[name] / d['head_frame']:.2f} the head-frame gaze's")
    return "\n".join(lines)


def plot_gaze_recorded(run: RecordedGaze, path: str | Path) -> Path:
    """Head speed and gyro-compensated gaze speed with the fixations shaded; per method, each fixation sample's
    world gaze angle from its fixation's mean direction. PNG."""
    import matplotlib.pyplot as plt

    from ..report.plots import save_figure

    speed, head, ok = world_gaze_speed(run.session, run.offset_s)
    found = run.fixations
    fig, axes = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    t = run.aligned.tracker_t
    axes[0].plot(t[ok], head[ok], lw=0.7, label="head speed (gyro)")
    axes[0].plot(t[ok], speed[ok], lw=0.7, label="world gaze speed (gyro-compensated)")
    axes[0].axhline(FIXATION_MAX_DEG_S, color="k", lw=0.5, ls="--", label="fixation threshold")
    for f in found:
        for ax in axes:
            ax.axvspan(t[f.rows[0]], t[f.rows[-1]], color="g", alpha=0.15)
    axes[0].set(ylabel="deg/s", ylim=(0, 150), title=f"fixations with head motion (shaded, {len(found)}); gaze taken {1000 * run.offset_s:.0f} ms late")
    axes[0].legend(fontsize=8, loc="upper right")
    rays = run.session.config.camera.ray(run.session.gaze_px)
    for name, quat in run.attitudes.items():
        if found:
            angles = np.rad2deg(np.concatenate([fixation_angles(quat, rays, f) for f in found]))
            label = f"{name} ({dispersion_deg(quat, run.aligned, found):.2f} deg RMS)"
            axes[1].plot(np.concatenate([t[f.rows] for f in found]), angles, ".", ms=2, label=label)
    axes[1].set(xlabel="time (s)", ylabel="angle from the fixation's mean (deg)", title="world gaze ray during fixations")
    axes[1].legend(fontsize=8, loc="upper right", markerscale=4)
    return save_figure(fig, path)
