"""Gaze on a real eye tracker's recording without ground truth (``fusegraph bench gaze-recorded``), through the
session path: the export imported as ``import tobii`` writes it (the gaze-to-IMU delay and the magnetometer's fitness
declared from the data, ``datasets.importers.tobii_session``) and every gaze solver run by ``solve_session`` and scored
by the gaze preset's scorer: the dispersion of the world gaze ray in fixations that read no IMU (the device's own
detector where the export has one, else eye-in-head velocity: ``frontends.gaze_timing.scoring_fixations``), the median
over fixations of each one's RMS angle to its mean direction.

Rows: ``head_frame`` (no head attitude: the gaze in the head frame), ``gyro`` (the raw gyro integrated, no bias
estimate), ``device`` (the device's own head attitude, the session's scoring-only ``device_attitude`` stream at the gaze
samples: a Neon export's; null, with the reason in ``device_attitude``, when the export has no whole one: the Tobii
export has none, the Pupil Invisible's has roll and pitch without a heading), the paper's
``ekf``, fusegraph ``online`` and ``batch``. Beside them ``fixation_turn_beyond_gyro_deg`` (``ekf``, ``online``,
``batch``): per fixation the largest angle by which the method turned the head beyond its raw gyro, the median over
fixations (``frontends.gaze_timing.turn_beyond_gyro_deg``; it says why a method disperses more than the raw gyro).
``accel_beyond_gravity``: how much the head translated, from the accelerometer alone (``rms_m_s2`` of |f| - g and
``free_fall_fraction``; ``accel_beyond_gravity``).
``dispersion_ratio_ci95`` (``online`` and ``batch`` against ``ekf``, ``gyro`` and ``head_frame``): the ratio of the two
medians with its 95 % interval over the fixations resampled together for both rows (``median_ratio_ci``): an interval
that holds 1 says that these fixations do not tell the two rows apart.

Either export is read, told apart by its files (``export_kind``): a Tobii Pro Glasses 3 folder (``imudata.gz``:
``import tobii``) or a Pupil Labs Pupil Invisible or Neon one (``imu.csv`` + ``gaze.csv``: ``import pupil``, the
device's own fixations and no magnetometer).

The magnetometer of the shipped recording reads 110-131 uT (the Earth's field is ~50): a constant part from the
glasses themselves that 65 s of turning +-70 deg about one axis cannot calibrate (a sphere fit gives 31 uT and an
82 deg dip, its design matrix condition 1.6e4); the import declares ``use_mag = false``, so every method runs WITHOUT
it (gyro, accelerometer, gaze); ``--use-mag`` runs them with it as recorded.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..estimate import PointEstimate
from ..frontends.gaze_timing import (
    Fixation,
    _ray_and_rate,
    counter_rotation_gain,
    counter_rotation_gain_by_axis,
    dispersions_deg,
    fixation_angles,
    saccade_threshold_deg_s,
    scoring_fixations,
    turn_beyond_gyro_deg,
)
from ..records import GazeSession
from ..session import Session
from .runner import solve_session

ROWS = ("head_frame", "gyro", "ekf", "online", "batch")
"""The table's rows: the gaze preset's solvers, no fusion first."""
RATIO_DRAWS = 2000
"""Bootstrap draws of ``median_ratio_ci`` (its interval's ends move by ~0.01 between seeds at 2000 on ../shared's recordings)."""
DEVICE_ATTITUDE = {"tobii": "the export has no head attitude", "pupil": "the export's roll and pitch (the cloud's Madgwick filter) have no heading"}
"""Why the ``device`` row is null, per export (a Pupil export with its quaternions, a Neon's, has the row)."""


def export_kind(directory: Path) -> str:
    """``tobii`` or ``pupil``, from the export's files; an error names the folder and what each export holds."""
    from ..session import SessionError

    if (directory / "imudata.gz").is_file():
        return "tobii"
    if (directory / "imu.csv").is_file() and (directory / "gaze.csv").is_file():
        return "pupil"
    raise SessionError(f"{directory}: not an eye-tracker export fusegraph reads (a Tobii Pro Glasses 3 folder has imudata.gz and "
                       "gazedata.gz; a Pupil Invisible or Neon export has imu.csv and gaze.csv)")


@dataclass(frozen=True)
class RecordedGaze:
    """One recording run: what the bench's JSON and its figure are made from."""

    session: Session
    """The imported session (its gaze stream declares the time offset)."""
    data: GazeSession
    """The session as the gaze system reads it (gaze stamps moved by the declared offset)."""
    estimates: dict[str, PointEstimate]
    """Each row's estimate (``extras['world_R_head']``: the head attitude at the gaze samples)."""
    metrics: dict[str, dict[str, Any]]
    """Each row's metrics, as ``run --json`` prints them."""
    fixations: list[Fixation]
    """The fixations scored."""
    fixation_source: str
    """``device`` or ``eye_velocity``."""
    export: str
    """``tobii`` or ``pupil`` (``export_kind``)."""
    device_R_head: np.ndarray | None
    """The device's own head attitude at the gaze samples (``device_attitude_at_gaze``), or None: the export has none."""


def analyse_gaze_recording(directory: str | Path | None = None, use_mag: bool = False, device: str | None = None) -> RecordedGaze:
    """The eye-tracker export in ``directory`` imported and run by every row's solver; ``device``: a Pupil export's
    device (``invisible``/``neon``), as ``import pupil --device``."""
    from ..datasets.importers import pupil_session, tobii_session
    from ..datasets.tobii import DEFAULT_DIR
    from ..session import SessionError
    from ..systems.gaze import from_session

    directory = Path(directory or DEFAULT_DIR)
    export = export_kind(directory)
    if device is not None and export != "pupil":
        raise SessionError(f"--device {device}: {directory} is a {export} export, not a Pupil Labs one")
    session = tobii_session(directory) if export == "tobii" else pupil_session(directory, device)
    if use_mag:
        session = session.with_meta(session={**session.meta["session"], "use_mag": True})
    estimates, metrics = {}, {}
    for row in ROWS:
        outcome = solve_session(session, row)
        assert isinstance(outcome.estimate, PointEstimate) and outcome.metrics is not None
        estimates[row], metrics[row] = outcome.estimate, outcome.metrics
    data = from_session(session)
    found, source = scoring_fixations(data, session.stream("fixation").values[:, 0] if "fixation" in session.streams else None)
    return RecordedGaze(session, data, estimates, metrics, found, source, export, device_attitude_at_gaze(session, data.tracker_t))


def gaze_recorded_json(run: RecordedGaze) -> dict[str, Any]:
    """The JSON of ``fusegraph bench gaze-recorded``."""
    found, data = run.fixations, run.data
    duration = float(data.t[-1] - data.t[0])
    turns = [f.eye_turn_deg for f in found]
    gaze = run.session.stream("gaze").meta
    header = run.session.meta["session"]
    gyro = run.estimates["gyro"].extras["world_R_head"]  # the gyro row's attitude: the raw gyro integrated
    device = run.device_R_head
    spread = dispersions_deg(device, data, found) if device is not None and found else None
    return {
        "dispersion_deg": {"device": None if spread is None else float(np.median(spread)),
                           **{name: m["dispersion_deg"] for name, m in run.metrics.items()}},
        "dispersion_mean_deg": {"device": None if spread is None else float(np.mean(spread)),
                                **{name: m["dispersion_mean_deg"] for name, m in run.metrics.items()}},
        "device_attitude": "the export's own attitude (device_attitude)" if device is not None else DEVICE_ATTITUDE[run.export],
        "export": run.export,
        "device": header.get("dataset", run.export),
        "fixation_source": run.fixation_source,
        "fixation_fraction": float(sum(len(f.rows) for f in found) / max(len(data.tracker_t), 1)),
        "time_offset_s": float(gaze["time_offset_s"]),
        # null: the recording did not tell the delay (the head turned too little), none applied
        "time_offset_sigma_s": float(gaze["time_offset_sigma_s"]) if np.isfinite(float(gaze["time_offset_sigma_s"])) else None,
        "fixations": len(found),
        "fixation_samples": int(sum(len(f.rows) for f in found)),
        "fixation_eye_turn_deg": {"median": float(np.median(turns)) if turns else None, "max": float(np.max(turns)) if turns else None},
        # the key earlier versions printed: the head's turn, now read as the eye's counter-rotation (no gyro)
        "fixation_head_turn_deg": {"median": float(np.median(turns)) if turns else None, "max": float(np.max(turns)) if turns else None},
        "fixation_counter_rotation_gain": counter_rotation_gain(data, found),
        "fixation_counter_rotation_gain_by_axis": counter_rotation_gain_by_axis(data, found),
        "accel_beyond_gravity": accel_beyond_gravity(data),
        "dispersion_ratio_ci95": _ratio_cis(run),
        "fixation_turn_beyond_gyro_deg": {name: _median_or_none(turn_beyond_gyro_deg(e.extras["world_R_head"], gyro, found))
                                          for name, e in run.estimates.items() if name in ("ekf", "online", "batch")},
        "gaze_samples": len(data.tracker_t),
        "gaze_untracked": int(header.get("gaze_untracked", 0)),
        "duration_s": duration,
        "use_mag": bool(header.get("use_mag", True)),
        "x_realtime": {name: duration / max(e.runtime_s, 1e-9) for name, e in run.estimates.items() if name in ("ekf", "online", "batch")},
        "camera": {"focal_px": data.config.camera.focal_px, "pixel_sigma": data.config.camera.pixel_sigma},
    }


FREE_FALL_G = 0.3
"""A reading under this many g is free fall (a flight), as the README's trampoline figure counts it."""


def accel_beyond_gravity(session: GazeSession) -> dict[str, float]:
    """How much the head translated, read from the accelerometer alone: the RMS of |f| - g over the recording (m/s^2) and
    the fraction of readings in free fall (under ``FREE_FALL_G``): the Tobii recording's head 0.3 m/s^2 and none, the
    Pupil trampoline 8.9 m/s^2 and 37 %. A translating head moves a fixated near point's direction in the world whatever
    the attitude, which the dispersion does not separate from a wrong attitude. A description: it selects and scores
    nothing."""
    from ..factors.imu import GRAVITY_M_S2

    norm = np.linalg.norm(session.accel_m_s2, axis=1)
    return {"rms_m_s2": float(np.sqrt(np.mean((norm - GRAVITY_M_S2) ** 2))),
            "free_fall_fraction": float(np.mean(norm < FREE_FALL_G * GRAVITY_M_S2))}


def median_ratio_ci(of: np.ndarray, to: np.ndarray, draws: int = RATIO_DRAWS, seed: int = 0) -> tuple[float, float] | None:
    """95 % interval of median(``of``) / median(``to``), two rows' per-fixation dispersions, by a paired bootstrap: the
    fixations are resampled with replacement, the same draw for both rows (a fixation hard for one is hard for the other).
    None with fewer than two fixations or a NaN (a row without an attitude somewhere)."""
    of, to = np.asarray(of, float), np.asarray(to, float)
    if len(of) < 2 or not (np.all(np.isfinite(of)) and np.all(np.isfinite(to))):
        return None
    pick = np.random.default_rng(seed).integers(0, len(of), size=(draws, len(of)))
    ratio = np.median(of[pick], axis=1) / np.median(to[pick], axis=1)
    low, high = np.percentile(ratio, [2.5, 97.5])
    return float(low), float(high)


def _ratio_cis(run: RecordedGaze) -> dict[str, dict[str, list[float] | None]]:
    """``dispersion_ratio_ci95``: online and batch against the EKF, the raw gyro and the head frame."""
    per = {name: dispersions_deg(e.extras.get("world_R_head"), run.data, run.fixations) for name, e in run.estimates.items()}
    out: dict[str, dict[str, list[float] | None]] = {}
    for name in ("online", "batch"):
        out[name] = {}
        for other in ("ekf", "gyro", "head_frame"):
            ci = median_ratio_ci(per[name], per[other])
            out[name][other] = None if ci is None else list(ci)
    return out


def device_attitude_at_gaze(session: Session, at_t: np.ndarray) -> np.ndarray | None:
    """The session's ``device_attitude`` (the export's own head attitude) at the gaze samples' IMU times ``at_t``
    (``metrics.on_truth_times``: slerped, NaN outside its span and in its dropouts). None without the stream."""
    from ..estimate import Estimate
    from ..metrics import on_truth_times

    if "device_attitude" not in session.streams:
        return None
    stream = session.stream("device_attitude")
    return on_truth_times(Estimate("device", stream.t, stream.values), at_t).quat_wxyz


def bench_gaze_recorded(directory: str | Path | None = None, use_mag: bool = False, device: str | None = None) -> dict[str, Any]:
    """``fusegraph bench gaze-recorded``: the JSON (see the module docstring)."""
    return gaze_recorded_json(analyse_gaze_recording(directory, use_mag, device))


def format_gaze_recorded(result: dict[str, Any]) -> str:
    """The bench as text."""
    d = result["dispersion_deg"]
    labels = {
        "head_frame": "gaze in the head frame (no fusion)",
        "gyro": "raw gyro integrated",
        "device": "the device's own attitude",
        "ekf": "the paper's EKF",
        "online": "fusegraph online",
        "batch": "fusegraph batch",
    }
    lines = [
        f"gaze on a recorded head-worn eye tracker ({result.get('device', result['export'])}; {result['duration_s']:.0f} s; "
        f"{result['gaze_samples']} gaze samples, "
        f"{result['gaze_untracked']} untracked; magnetometer "
        f"{'used' if result['use_mag'] else 'not used' + (' (uncalibratable)' if result['export'] == 'tobii' else ' (none)')})",
        f"gaze-to-IMU time offset: {1000 * result['time_offset_s']:.1f} ms (sigma {1000 * result['time_offset_sigma_s']:.1f} ms, "
        "block bootstrap); gaze stamps corrected by it for every method" if result["time_offset_sigma_s"] is not None else
        "gaze-to-IMU time offset: not told by this recording (the head turned too little); none applied",
        f"{result['fixations']} fixations from {'the device' if result['fixation_source'] == 'device' else 'eye-in-head velocity (no IMU)'} "
        f"({result['fixation_samples']} samples, {100 * result['fixation_fraction']:.0f} % of the gaze; eye turn in the head median "
        f"{result['fixation_eye_turn_deg']['median'] or float('nan'):.1f} deg, max {result['fixation_eye_turn_deg']['max'] or float('nan'):.1f} deg)",
        _counter_rotation_text(result.get("fixation_counter_rotation_gain"), result.get("fixation_counter_rotation_gain_by_axis")),
        *_translation_text(result.get("accel_beyond_gravity")),
        f"{'method':<36} {'dispersion [deg]: median':>26} {'mean':>8} {'x real time':>12}",
    ]
    for name, value in d.items():
        if value is None:
            lines.append(f"{labels['device']:<36} none: {result['device_attitude']}")
            continue
        speed = result["x_realtime"].get(name)
        lines.append(f"{labels.get(name, name):<36} {value:26.3f} {result['dispersion_mean_deg'][name]:8.3f} {'' if speed is None else f'{speed:12.0f}'}")
    cis = result.get("dispersion_ratio_ci95", {})
    for name in ("online", "batch"):
        parts = [f"x{d[name] / d[other]:.2f}{_interval(cis.get(name, {}).get(other))} {what}"
                 for other, what in (("ekf", "the EKF's dispersion"), ("gyro", "the integrated gyro's"), ("head_frame", "the head-frame gaze's"))]
        lines.append(f"{name}: " + ", ".join(parts))
    if any(ci is not None for row in cis.values() for ci in row.values()):
        lines.append("(in brackets the ratio's 95 % interval over the fixations resampled, both rows alike; one that holds 1: these "
                     "fixations do not tell the two apart)")
    beyond = result.get("fixation_turn_beyond_gyro_deg")
    if beyond:
        lines.append("inside a fixation each method turned the head beyond its raw gyro by (median over fixations of the largest angle; "
                     "a bias correction is tenths of a degree, more is an update's correction or a saturated gyro's recovery): "
                     + ", ".join(f"{name} {value:.2f} deg" for name, value in beyond.items() if value is not None))
    return "\n".join(lines)


def _interval(ci: list[float] | None) -> str:
    return "" if ci is None else f" ({ci[0]:.2f}-{ci[1]:.2f})"


def _median_or_none(values: np.ndarray) -> float | None:
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if len(finite) else None


def _translation_text(beyond: dict[str, float] | None) -> list[str]:
    if not beyond:
        return []
    return [f"head translation: the accelerometer departs from g by {beyond['rms_m_s2']:.1f} m/s^2 RMS, in free fall (under "
            f"{FREE_FALL_G:g} g) {100 * beyond['free_fall_fraction']:.0f} % of the time (a seated or standing head: tenths of a m/s^2, "
            "none); a translating head moves a near target's direction in the world whatever the attitude"]


def _counter_rotation_text(gain: float | None, by_axis: dict[str, float | None] | None = None) -> str:
    if gain is None:
        return "the head did not turn in the fixations: their dispersion does not test a head attitude"
    axes = ", ".join(f"{axis} {100 * value:.0f} %" for axis, value in (by_axis or {}).items() if value is not None)
    return (f"in the fixations the eye counter-rotated {100 * gain:.0f} % of the head's rotation ({axes + '; ' if axes else ''}gyro; 100 % = "
            "the gaze held still in the world)" + ("" if gain > 0.7 else "; well below: the gaze moved with the head (pursuit, or the head "
                                     "translating towards a near target, which moves it in pitch), and the head frame can be the "
                                     "stiller gaze whatever the attitude"))


def plot_gaze_recorded(run: RecordedGaze, path: str | Path) -> Path:
    """Eye-in-head speed with the saccade threshold and the scored fixations shaded; per method, each fixation sample's
    world gaze angle from its fixation's mean direction. PNG."""
    import matplotlib.pyplot as plt

    from ..report.plots import save_figure

    found = run.fixations
    _, rate, ok = _ray_and_rate(run.data.tracker_t, run.data.config.camera.ray(run.data.gaze_px))
    speed = np.where(ok, np.rad2deg(np.linalg.norm(rate, axis=1)), np.nan)
    fig, axes = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    t = run.data.tracker_t
    axes[0].plot(t, speed, lw=0.7, label="eye-in-head speed (gaze only)")
    axes[0].axhline(saccade_threshold_deg_s(speed), color="k", lw=0.5, ls="--", label="saccade threshold (from the data)")
    for f in found:
        for ax in axes:
            ax.axvspan(t[f.rows[0]], t[f.rows[-1]], color="g", alpha=0.15)
    axes[0].set(ylabel="deg/s", ylim=(0, 300), title=f"fixations scored ({run.fixation_source}, shaded: {len(found)})")
    axes[0].legend(fontsize=8, loc="upper right")
    rays = run.data.config.camera.ray(run.data.gaze_px)
    attitudes = {name: estimate.extras["world_R_head"] for name, estimate in run.estimates.items()}
    if run.device_R_head is not None:
        attitudes["device"] = run.device_R_head
    for name, quat in attitudes.items():
        if found:
            angles = np.rad2deg(np.concatenate([fixation_angles(quat, rays, f) for f in found]))
            label = f"{name} (median {np.median(dispersions_deg(quat, run.data, found)):.2f} deg)"
            axes[1].plot(np.concatenate([t[f.rows] for f in found]), angles, ".", ms=2, label=label)
    axes[1].set(xlabel="time (s)", ylabel="angle from the fixation's mean (deg)", title="world gaze ray during fixations")
    axes[1].legend(fontsize=8, loc="upper right", markerscale=4)
    return save_figure(fig, path)
