"""Systems as presets of one backend: what each system reads, which solvers it has, how it is scored.

A ``Preset`` says, for one system: the streams and session keys it reads (documented, checked:
a misspelled key is an error naming the nearest), its solvers (every one ``Session -> Estimate``
or ``PointEstimate``: ``online``, ``batch`` and its paper's baseline, plus others), how an
estimate is scored when the session has truth (one flat dict of metrics). How a session is simulated
(``scenarios.SIMULATORS``) and pictured (``report.pictures.PICTURES``) is found by system name in those
layers, so a preset imports neither. The CLI is generic over ``PRESETS``: no per-system branch.

The graph builders behind the solvers stay where a measured special case needs one (head's
ordering, attitude9's two-pass magnetometer, the cyclist's QR); what is common (catalogue, loading,
replay, scoring, files, plots, studies) is one piece.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..catalogue import CatalogueError, KeySpec, check_keys
from ..estimate import Estimate, PointEstimate, Result
from ..session import Session, SessionError
from ..solvers.pause import collector_paused

SolverFn = Callable[[Session], Result]
"""A method: a session in, an estimate out."""


@dataclass(frozen=True)
class Preset:
    """One system: its streams, keys, solvers and scoring (its simulator is in ``scenarios.SIMULATORS``, its picture in
``report.pictures.PICTURES``, both by system name)."""

    name: str
    """System name, as written in ``[session] system``."""
    summary: str
    """One line: what it estimates from which sensors."""
    streams: str
    """The streams it reads (names and kinds), as documentation."""
    session_keys: tuple[KeySpec, ...]
    """Keys of ``[session]`` (and, written ``table.key``, of other top-level tables) it reads."""
    solvers: Mapping[str, str]
    """Solver name -> one line saying what it is; ``online`` and ``batch`` always, the paper's baseline by its name."""
    run: Callable[[Session, str], Result]
    """Run a solver by name."""
    score: Callable[[Session, Result], dict[str, Any] | None]
    """Metrics of an estimate against the session's truth (None without truth)."""
    estimate_name: str = "estimate"
    """Stem of the default output file (``<stem>_<solver>.csv``)."""
    metric_keys: tuple[str, ...] = ()
    """Scalar metrics a study summarises (keys of ``score``'s result, flattened with dots)."""
    notes: tuple[str, ...] = field(default_factory=tuple)
    """Further lines of documentation (``fusegraph sensors``)."""
    truth: str = ""
    """The truth file a session may carry: kind, columns, frame, units and the times it must be on (documentation)."""
    axes: str = ""
    """The axis and sign conventions the streams need (documentation)."""

    def check_session(self, session: Session) -> None:
        """Top-level keys of session.toml against this preset's (a misspelled key names the nearest)."""
        where = session.where
        tables: dict[str, list[str]] = {"session": ["system", "description", "world_frame", "scenario", "seed", "profile", "dataset", "trial",
                                                  "time_origin_s", "subject", "device", "device_from"]}
        for spec in self.session_keys:
            table, _, key = spec.name.rpartition(".")
            tables.setdefault(table or "session", []).append(key)
        for name, table in session.meta.items():
            if name not in tables:
                raise SessionError(f"{where}: unknown table [{name}] for system '{self.name}' (known: {', '.join(f'[{t}]' for t in tables)})")
            if isinstance(table, Mapping):
                try:
                    check_keys(table, tables[name], f"{where}: [{name}]")
                except CatalogueError as err:
                    raise SessionError(str(err)) from None

    def solve(self, session: Session, solver: str) -> Result:
        """Run ``solver`` on ``session``; an unknown solver is an error listing this system's."""
        if solver not in self.solvers:
            raise SessionError(f"--solver {solver}: {self.name} sessions have {', '.join(self.solvers)}")
        session.validate()
        with collector_paused():
            return self.run(session.usable(), solver)


# ------------------------------------------------------------------------------------- head


def _head_run(session: Session, solver: str) -> Result:
    from ..graphs.head import warn_gyro_gaps
    from . import head

    warn_gyro_gaps(session, solver)
    return head.run_method(session, {"online": "isam2", "ekf": "method2"}.get(solver, solver))


def _head_score(session: Session, estimate: Result) -> dict[str, Any] | None:
    from ..metrics import AXES, EULER_DOMAIN_DEG, gap_scores, in_euler_domain, nearest_samples, on_truth_times, score_attitude, why_missing
    from .head import EULER_FILTERS

    truth = session.truth
    if truth is None or not isinstance(estimate, Estimate):
        return None
    estimate_t = estimate.t
    # an Euler-angle filter whose own elevation left the domain gives the singularity's figures, not its own: none
    left = estimate.method in EULER_FILTERS and not in_euler_domain(estimate.quat_wxyz[np.isfinite(estimate.quat_wxyz).all(axis=1)]).all()
    estimate = on_truth_times(estimate, truth.t)  # the truth on any grid
    mask = in_euler_domain(truth.values)  # the errors are per Euler angle: scored where those are three angles
    if "movement" in session.streams:  # BROAD's flag at each truth time (its nearest sample)
        mask &= session.stream("movement").values[nearest_samples(session.stream("movement").t, truth.t), 0] > 0
    score = score_attitude(estimate, truth.t, truth.values, mask=mask)
    rms_rad = np.full(3, np.nan) if left else score.rms_rad
    out: dict[str, Any] = {
        "rms_deg": dict(zip(AXES, (float(v) for v in np.rad2deg(rms_rad)), strict=True)),
        "rms_rad": dict(zip(AXES, (float(v) for v in rms_rad), strict=True)),
        "nees": None if left else score.nees,
        "truth_samples_scored": score.samples,
        "truth_samples_missing": score.missing,
    }
    if score.missing:
        out["truth_samples_missing_why"] = why_missing(estimate_t, score.missing_t)
    if left:
        out["excluded"] = f"{estimate.method}: its elevation estimate left the Euler-angle domain |elevation| < {EULER_DOMAIN_DEG:g} deg"
    trackers = session.streams_of_kind("attitude")
    gaps = trackers[0].gaps() if trackers else []
    if gaps:
        out.update(gap_scores(estimate, truth.t, truth.values, gaps, estimate_t))
    return out


# --------------------------------------------------------------------------------- attitude9


def _attitude9_run(session: Session, solver: str) -> Result:
    from . import attitude9

    return attitude9.METHODS[solver](session)


def _attitude9_score(session: Session, estimate: Result) -> dict[str, Any] | None:
    from ..metrics import broad_errors, estimate_gaps, inside_gaps, nearest_samples, on_truth_times, why_missing

    truth = session.truth
    if truth is None or not isinstance(estimate, Estimate):
        return None
    estimate_t = estimate.t
    estimate = on_truth_times(estimate, truth.t)  # the truth on any grid
    movement = np.ones(len(truth.t))
    if "movement" in session.streams:  # the flag at each truth time (its nearest sample)
        flag = session.stream("movement")
        movement = flag.values[nearest_samples(flag.t, truth.t), 0]
    # inside a dropout an online estimate has nothing (not a failure of the method: the sensor was silent), said
    dropped = inside_gaps(estimate_gaps(estimate_t), truth.t) & (movement > 0)
    errors = broad_errors(estimate.quat_wxyz, truth.values, np.where(dropped, 0.0, movement))
    out: dict[str, Any] = {"total_deg": errors.total, "heading_deg": errors.heading, "inclination_deg": errors.inclination,
                           "truth_samples_scored": errors.samples}
    if dropped.any() and not np.isfinite(estimate.quat_wxyz[dropped]).all():
        out["truth_samples_missing"] = int(dropped.sum())
        out["truth_samples_missing_why"] = why_missing(estimate_t, truth.t[dropped])
    return out


# -------------------------------------------------------------------------------------- gaze


def _gaze_run(session: Session, solver: str) -> Result:
    from ..baselines.ekf_gaze import GazeEkfConfig
    from ..frontends.gaze_timing import gyro_attitude
    from ..metrics import on_truth_times
    from . import attitude9, gaze

    data = gaze.from_session(session)
    use_mag = bool(session.meta.get("session", {}).get("use_mag", True))
    if use_mag and "mag" not in session.streams:
        raise SessionError(f"{session.where}: no stream 'mag': declare use_mag = false in [session] to run without a magnetometer")
    start = time.perf_counter()
    if solver in ("gyro", "head_frame", "imu_only"):
        attitude = gyro_attitude(data) if solver == "gyro" else np.tile([1.0, 0.0, 0.0, 0.0], (len(data.tracker_t), 1))
        if solver == "imu_only":  # the 9-axis online attitude alone (the gaze read by no estimator), at the gaze samples
            nine = session.without(*(n for n in session.streams if n not in ("gyro", "accel", "mag")))
            attitude = on_truth_times(attitude9.run_online(nine, replace(attitude9.model_for(nine), use_mag=use_mag)), data.tracker_t).quat_wxyz
        points = gaze.wall_points(data, attitude)
        return PointEstimate(solver, data.tracker_t.copy(), points[:, None, :], ("X_m", "Z_m"), time.perf_counter() - start,
                             {"world_R_head": None if solver == "head_frame" else attitude})
    if solver == "ekf":
        result = gaze.run_ekf(data, replace(GazeEkfConfig(), use_mag=use_mag, pixel_sigma=data.config.camera.pixel_sigma))  # the declared noise, as ours
    else:
        result = gaze.RUNNERS[solver](data, gaze.model_for(session, solver))  # type: ignore[operator]
        attitude9.say_notes(session.where, result.notes)
    return PointEstimate(solver, data.tracker_t.copy(), np.asarray(result.points_xz_m)[:, None, :], ("X_m", "Z_m"), float(result.runtime_s),
                         {"world_R_head": result.world_R_head})


def _gaze_score(session: Session, estimate: Result) -> dict[str, Any] | None:
    """With a true gaze point: RMS on the wall (mm). Without (a recording): the dispersion of the world gaze ray in
    fixations that no scored method's input picked (``frontends.gaze_timing.scoring_fixations``: the device's own where
    the session has a ``fixation`` stream, else eye-in-head velocity), degrees: the median over fixations (and the mean)."""
    from ..frontends.gaze_timing import dispersions_deg, scoring_fixations
    from ..metrics import gaze_ray_errors, gaze_rms_mm
    from . import gaze

    data = gaze.from_session(session)
    if not isinstance(estimate, PointEstimate):
        return None
    if np.isfinite(data.truth_gaze_xz_m).any():
        return {"rms": gaze_rms_mm(estimate.points[:, 0, :], data)}
    if "world_R_head" not in estimate.extras:
        return None
    ids = session.stream("fixation").values[:, 0] if "fixation" in session.streams else None
    found, source = scoring_fixations(data, ids)  # the stamps are already moved by the declared time_offset_s
    if session.meta.get("session", {}).get("gaze_truth") == "world_ray" and session.truth is not None:  # the simulator's fixations
        return gaze_ray_errors(estimate.extras["world_R_head"], data, session.truth.values, [f.rows for f in found])
    per = dispersions_deg(estimate.extras["world_R_head"], data, found)
    samples = int(sum(len(f.rows) for f in found))
    return {"dispersion_deg": float(np.median(per)) if len(per) else float("nan"), "dispersion_mean_deg": float(np.mean(per)) if len(per) else float("nan"),
            "fixations": len(found), "fixation_samples": samples, "fixation_fraction": samples / max(len(data.tracker_t), 1), "fixation_source": source}


# ----------------------------------------------------------------------------------- bicycle

_BICYCLE_SOLVERS = {"online": "online", "batch": "batch", "ekf": "paper_pipeline", "paper_pipeline": "paper_pipeline", "no_removal": "no_removal"}


def _bicycle_run(session: Session, solver: str) -> Result:
    from . import bicycle

    start = time.perf_counter()
    t, quat = bicycle.run_declared(session, _BICYCLE_SOLVERS[solver])
    return Estimate(solver, t.copy(), quat, None, time.perf_counter() - start)


def _bicycle_score(session: Session, estimate: Result) -> dict[str, Any] | None:
    from . import bicycle

    ride = bicycle.from_session(session)
    if not isinstance(estimate, Estimate) or not np.isfinite(ride.thigh_quat_wxyz).all() or not np.isfinite(ride.config.brake_s):
        return None
    return {"rms": bicycle.braking_rms_deg(estimate.quat_wxyz, ride)}


# ----------------------------------------------------------------------------------- walking


def _walking_run(session: Session, solver: str) -> Result:
    from . import walking

    if solver == "steps":
        return _count_steps(session)
    if solver in ("activity", "gait"):
        return _waist_analysis(session, solver)
    start = time.perf_counter()  # the solve's time includes its front end (steps, their activities, rides): what `run` takes
    if session.streams_of_kind("wheel_odometry") and "gyro" not in session.streams:
        walk, events = walking.vehicle_from_session(session)  # a vehicle: wheel odometry instead of steps
        cycles: list[Any] = []
        rides: list[Any] = []
    elif "gyro" not in session.streams:
        raise SessionError(f"{session.path or 'walking session'}: no gyro stream: an accelerometer-only recording (a phone's step "
                           "recording) is counted with --solver steps; the trajectory solvers need the waist gyro (or wheel_odometry)")
    else:
        walk, speed = walking.from_session(session)
        cycles, rides, events = walking.analyse(walk, speed, causal=solver != "batch")  # the causal solvers classify causally
    if solver == "dead_reckoning":
        run = walking.run_dead_reckoning(walk, events)
    else:
        vehicle = bool(session.streams_of_kind("wheel_odometry")) and "gyro" not in session.streams
        if solver == "online":
            run = walking.run_online(walk, events, walk.fixes.pose, walking.VEHICLE_ONLINE if vehicle else walking.ONLINE)
        elif solver == "batch":
            run = walking.run_batch(walk, events, walk.fixes.pose)
        else:
            run = walking.run_ekf(walk, events, walk.fixes.pose)
    activity = {a: sum(c.activity == a for c in cycles) for a in ("flat", "stairs_up", "stairs_down", "not_walking")}
    return PointEstimate(solver, run.t, run.xyz[:, None, :], ("x", "y", "z"), time.perf_counter() - start,
                         {"steps": len(cycles), "activity": activity, "rides": len(rides), "solver_s": run.seconds})


def _count_steps(session: Session) -> PointEstimate:
    """Steps of the accelerometer (waist or phone) as their times; ``points`` hold the running count."""
    from ..frontends.pdr import phone_config, step_times

    accel = session.stream("accel")
    start = time.perf_counter()
    step_t = step_times(accel.t, accel.values, phone_config(session.meta))
    count = np.arange(1, len(step_t) + 1, dtype=float)
    return PointEstimate("steps", step_t, count[:, None, None], ("steps",), time.perf_counter() - start, {"steps": len(step_t)})


def _waist_analysis(session: Session, solver: str) -> PointEstimate:
    """``activity``: each walking cycle's class by the waist classifier (``frontends.activity``; points: its index in
    flat, stairs_up, stairs_down, not_walking); ``gait``: strides from the pelvis's vertical excursion (``frontends.gait``; points: length m,
    speed m/s; the steps in ``extras``). Both on the waist gyro and accelerometer with the walking front end's cycles."""
    from ..frontends.activity import ACTIVITIES, classify_waist
    from ..frontends.gait import declared_settings, waist_gait
    from .walking import WAIST

    accel, gyro = session.synchronous("accel", "gyro")
    start = time.perf_counter()
    if solver == "activity":
        cycles, calls, base = classify_waist(accel.t, accel.values, gyro.values, WAIST)
        index = np.array([ACTIVITIES.index(c) for c in calls], dtype=float)
        return PointEstimate("activity", np.array([c.t for c in cycles]), index.reshape(-1, 1, 1), ("activity",), time.perf_counter() - start,
                             {"activity": calls, "features": base, "rules_activity": [c.activity for c in cycles]})
    leg = session.meta.get("person", {}).get("sensor_height_m")
    if leg is None:
        raise SessionError(f"{session.where}: --solver gait needs [person] sensor_height_m (the waist sensor's height: the pendulum's leg)")
    steps, inferred, stride_t, stride_m, speed = waist_gait(accel.t, accel.values, gyro.values, float(leg), *declared_settings(session.meta, WAIST))
    return PointEstimate("gait", stride_t, np.stack([stride_m, speed], axis=1)[:, None, :], ("stride_length_m", "walking_speed_m_s"),
                         time.perf_counter() - start, {"steps_s": steps, "steps_inferred": inferred})


def _waist_score(session: Session, estimate: PointEstimate) -> dict[str, Any] | None:
    """Activity against the session's ``activity`` labels; gait against ``[truth_extra]``'s reference bouts."""
    from ..metrics import GaitReference, activity_counts, activity_scores, gait_counts, gait_scores, nearest_samples

    if estimate.method == "activity":
        if "activity" not in session.streams:
            return None
        labels = session.stream("activity")
        at = labels.values[nearest_samples(labels.t, estimate.t), 0] if len(estimate.t) else np.zeros(0)
        counts = activity_counts(at, estimate.extras["activity"], labels.values[:, 0], float(np.median(np.diff(labels.t))))
        return {**activity_scores([counts]), "counts": counts}
    reference = GaitReference.from_truth_extra(session.meta.get("truth_extra", {}))
    if reference is None:
        return None
    counts = gait_counts(estimate.extras["steps_s"], estimate.t, estimate.points[:, 0, 0], estimate.points[:, 0, 1], reference)
    return {**gait_scores([counts]), "counts": counts}


def _walking_score(session: Session, estimate: Result) -> dict[str, Any] | None:
    from ..metrics import track_errors
    from . import walking

    if isinstance(estimate, PointEstimate) and estimate.method in ("activity", "gait"):
        return _waist_score(session, estimate)
    if session.streams_of_kind("wheel_odometry") and "gyro" not in session.streams and isinstance(estimate, PointEstimate):
        if session.truth is None:
            return None
        return track_errors(estimate.t, estimate.points[:, 0, :], session.truth.t, session.truth.values)
    if estimate.method == "steps":
        true = session.meta.get("truth_extra", {}).get("steps")
        if not isinstance(estimate, PointEstimate) or true is None:
            return None
        counted = len(estimate.t)
        return {"steps": counted, "steps_true": int(true), "step_error_frac": abs(counted - int(true)) / max(int(true), 1)}

    if session.truth is None or session.truth.kind != "position" or not isinstance(estimate, PointEstimate):
        return None  # nothing to score (and the session's warnings were said by the solve)
    walk, _ = walking.from_session(session)
    if not np.isfinite(walk.truth_xyz_m).all():
        return None
    return walking.score(walking.WalkRun(estimate.method, estimate.t, estimate.points[:, 0, :], estimate.runtime_s), walk)


# -------------------------------------------------------------------------------- ultrasonic


def _ultrasonic_run(session: Session, solver: str) -> Result:
    from ..records import epochs_from_session
    from . import ultrasonic, uwb

    epochs = epochs_from_session(session)
    n = int(session.streams_of_kind("ranges")[0].meta["transmitters"])
    start = time.perf_counter()
    if solver == "combinatorial":
        run = ultrasonic.run_combinatorial(epochs, n)
    elif epochs.tag_offsets_m is not None:  # the tags of one rigid body: its pose, not N free points
        calibration = None if epochs.calibration is None else uwb.RangeCalibration(*epochs.calibration)
        config = None if calibration is None else uwb.calibrated_config()
        run = uwb.track_rigid(epochs, epochs.tag_offsets_m, config, labelled=epochs.labelled, calibration=calibration)
    else:
        run = ultrasonic.run_fusegraph(epochs, n)
    if solver == "batch":
        run = ultrasonic.smooth_tracks(epochs, run)
    seconds = time.perf_counter() - start
    extras = {"labels": run.labels, "ms_per_epoch": run.ms_per_epoch, "epochs": epochs, **run.extras}  # epochs: scoring reuses them, not re-reading the file
    return PointEstimate(solver, epochs.t.copy(), run.positions, ("x", "y", "z"), seconds, extras)


def _ultrasonic_score(session: Session, estimate: Result) -> dict[str, Any] | None:
    from dataclasses import asdict

    from ..metrics import score_run
    from ..records import epochs_from_session

    if not isinstance(estimate, PointEstimate):
        return None
    epochs = estimate.extras.get("epochs") or epochs_from_session(session)
    if epochs.labels is None or epochs.positions is None:
        return None
    score = score_run(epochs, estimate.extras["labels"], estimate.points)
    out: dict[str, Any] = asdict(score)
    out["ms_per_epoch"] = float(np.mean(estimate.extras["ms_per_epoch"]))
    if "assoc_expected_geometry" in estimate.extras:
        out["assoc_expected_geometry"] = float(estimate.extras["assoc_expected_geometry"])
    return out


# ------------------------------------------------------------------------------------ shared


PRESETS: dict[str, Preset] = {
    "head": Preset(
        name="head",
        summary="HMD head attitude at the gyro rate from a gyro and a ~100 ms late magnetic tracker (optionally the IMU's accelerometer)",
        streams="gyro (kind gyro), tracker (kind attitude, latency_s), optional accel (kind accel)",
        session_keys=(KeySpec("ekf.process_scale", None, "the paper's EKFs (ekf, method1, kalman): x the paper's process noise (w1, w2); "
                              "with ekf.gyro_sigma_rad_s (absent: each filter's figures tuned on seeds 100-119)"),
                      KeySpec("ekf.gyro_sigma_rad_s", None, "the paper's EKFs: gyro noise, rad/s"),
                      KeySpec("ekf.tracker_sigma_rad", None, "the paper's EKFs: tracker noise, rad (absent: the paper's 0.0268)")),
        solvers={"online": "iSAM2, causal estimate at every gyro sample", "batch": "smoother over the whole session",
                 "ekf": "the paper's Method II (joint update)", "method1": "the paper's Method I (sequential updates)",
                 "kalman": "the paper's tracker-only Kalman filter", "tracker": "the latest arrived tracker sample", "gyro": "dead reckoning",
                 "method2_paper_values": "Method II with the paper's own noise figures (ekf/method1/method2/kalman are tuned on seeds 100-119)"},
        truth="truth.csv, kind attitude: t, qw, qx, qy, qz (scalar first), world_R_head (a head-frame vector to the world), a lag-free "
        "reference on any grid (NaN rows: occluded); scored per axis (azimuth, elevation, roll) after the first second, where the "
        "reference's elevation is inside +-80 deg and the optional movement stream (kind flag) is 1; an Euler-angle filter that "
        "leaves that domain gets no figure (metrics.excluded says why)",
        axes="gyro: the head's angular rate in the head frame, rad/s (any right-handed head frame: simulations use x forward, y left, "
        "z up); tracker: world_R_head of the SAME head frame in the tracker's world, scalar first, stamped with its sample time "
        "(latency_s: how much later it arrives); accel (optional): specific force in the head frame, +9.81 m/s^2 up at rest",
        run=_head_run,
        score=_head_score,
        metric_keys=("rms_deg.azimuth", "rms_deg.elevation", "rms_deg.roll", "nees"),
    ),
    "attitude9": Preset(
        name="attitude9",
        summary="9-axis attitude from gyro, accelerometer (gravity) and magnetometer (heading, calibrated, disturbances rejected)",
        streams="gyro, accel, mag sampled together (kinds gyro, accel, mag); optional mag_cal (a calibration recording), movement (kind flag), "
        "an attitude tracker (kind attitude, its own room frame, latency_s: a factor in the same graph)",
        session_keys=(KeySpec("truth_extra.disturbance_s", None, "simulations: when the field is disturbed (documentation)"),
                      KeySpec("truth_extra.gyro_bias_rad_s", None, "simulations: the true gyro bias (documentation)"),
                      KeySpec("truth_extra.mag_gain", None, "simulations: the true magnetometer gain (documentation)"),
                      KeySpec("truth_extra.mag_offset_uT", None, "simulations: the true magnetometer offset (documentation)"),
                      KeySpec("truth_extra.gyro_scale_error", None, "simulations: the gyro's true scale-factor errors (documentation)"),
                      KeySpec("online.update_every", 0, "online: iSAM2 every this many keyframes (0: each): faster, older solves (see Scale)")),
        solvers={"online": "iSAM2 causal", "batch": "smoother (two passes: the field model from the first)", "ekf": "the papers' 9-axis EKF on roll-pitch-yaw",
                 "vqf": "VQF online (the peer)", "vqf_offline": "VQF offline (the peer)",
                 "imufusion": "x-io Fusion (imufusion, its example's settings; the peer)"},
        truth="truth.csv, kind attitude: t, qw, qx, qy, qz, world_R_sensor with the world ENU (east, north, up), at the IMU's sample "
        "times; NaN rows where the reference lost the sensor (occluded markers); scored where the optional movement flag is 1 (BROAD's "
        "metric: total, heading, inclination RMSE, no alignment of any kind)",
        axes="gyro, accel, mag: one right-handed sensor frame, sampled together; accel is specific force (reads +9.81 m/s^2 along "
        "the sensor's up at rest); mag in any unit (say which in unit), calibrated by calibration_gain/offset or a mag_cal recording; "
        "heading is to magnetic north (world ENU with y = magnetic north)",
        run=_attitude9_run,
        score=_attitude9_score,
        metric_keys=("total_deg", "heading_deg", "inclination_deg"),
    ),
    "gaze": Preset(
        name="gaze",
        summary="the gaze point on a wall in world coordinates from a head 9-axis IMU and an eye tracker's scene-image gaze pixels",
        streams="gyro, accel, mag sampled together (no mag: use_mag = false); gaze (kind pixel; the camera's focal_px, width_px, height_px, pixel_sigma); "
        "optional head attitude tracker (kind attitude, own room frame, latency_s)",
        session_keys=(KeySpec("wall_m", None, "distance from the head to the wall along world +x, m (this or target_depth_m is required)"),
                      KeySpec("target_depth_m", None, "no wall known (a recording in a room): each fixation point held at this depth "
                              "along its first ray, m; the EKF's wall faces its first heading at this distance"),
                      KeySpec("switch_s", None, "simulations: when the subject switches to the second mark, s (documentation)"),
                      KeySpec("gaze_untracked", None, "imports: gaze lines without a measurement (blinks), count (documentation)"),
                      KeySpec("use_mag", True, "false: no method reads the magnetometer (one that cannot be calibrated: the imports say why)"),
                      KeySpec("gaze_truth", None, "world_ray: the truth is the eye's world ray per gaze sample (import broad --system gaze): gaze_error_deg"),
                      KeySpec("head_motion", "seated", "seated: a viewer's head held within centimetres (the gaze model's head); free: a sensor moved by hand "
                              "(import broad --system gaze): the head is the 9-axis system's model for the IMU"),
                      KeySpec("mag_rate_hz", None, "imports: the magnetometer's own rate before it was interpolated onto the IMU times, Hz "
                              "(documentation)")),
        solvers={"online": "iSAM2 causal", "batch": "smoother", "ekf": "the paper's EKF on (yaw, pitch, roll, GX, GZ)",
                 "gyro": "the raw gyro integrated from identity (no fusion, no bias estimate)",
                 "head_frame": "no head attitude at all: the gaze in the head frame",
                 "imu_only": "the 9-axis online attitude alone (attitude9's, as BROAD chose it) turning the tracker's rays: no gaze fused"},
        truth="truth.csv, kind position: t, x, y, z, the true gaze point in the world (ENU; the wall is x = wall_m) at the gaze samples' "
        "times (one row per gaze sample); scored as RMS of X = world y and Z = world z in mm. Without truth (a recording): the "
        "dispersion of the world gaze ray in the fixations with head motion that the gaze and gyro find, degrees",
        axes="head IMU (gyro, accel, mag sampled together) in the head frame: x forward (the scene camera's optical axis), y left, "
        "z up; gaze pixels (u, v) from the image centre, u to the RIGHT and v UP, in the head-fixed scene camera (focal_px, width_px, "
        "height_px); a tracker's v pointing down or pixels from the top-left corner must be converted; time_offset_s: the gaze stamps' "
        "delay behind the IMU",
        run=_gaze_run,
        score=_gaze_score,
        estimate_name="gaze",
        metric_keys=("rms.x_mm", "rms.z_mm", "dispersion_deg"),
    ),
    "bicycle": Preset(
        name="bicycle",
        summary="a cyclist's thigh attitude from 9-axis IMUs on the thigh and the bicycle frame (the frame's acceleration removed)",
        streams="thigh_gyro, thigh_accel, thigh_mag, frame_gyro, frame_accel, frame_mag, all sampled together",
        session_keys=(KeySpec("ride", "downhill", "downhill or indoor (documentation)"),
                      KeySpec("brake_s", None, "start of the braking phase that the report scores, s")),
        solvers={"online": "iSAM2 causal, both bodies in one graph", "batch": "smoother", "ekf": "the paper's pipeline (frame EKF -> subtract -> thigh EKF)",
                 "paper_pipeline": "same as ekf", "no_removal": "the thigh EKF alone"},
        truth="truth.csv, kind attitude: t, qw, qx, qy, qz, world_R_thigh (ENU) at the IMU sample times (one row per sample); scored "
        "as thigh pitch and roll RMS in the braking phase brake_s .. brake_s + 5 s",
        axes="thigh_* and frame_* gyro, accel, mag: each IMU in its own right-handed frame, all six streams sampled together; the "
        "frame IMU's x along the bicycle's direction of travel (the non-holonomic factor assumes it); accel is specific force",
        run=_bicycle_run,
        score=_bicycle_score,
        metric_keys=("rms.pitch_deg", "rms.roll_deg"),
        notes=("the braking phase brake_s .. brake_s + 5 s is scored; a shorter simulation brakes at 3/4 of its length",),
    ),
    "walking": Preset(
        name="walking",
        summary="a walker's 3D trajectory over floors from a waist IMU (PDR steps, stairs, elevator) and image-match fixes (some wrong)",
        streams="gyro, accel sampled together (waist IMU); optional fixes (kind pose); optional ranges to known UWB beacons (kind beacon_ranges)",
        session_keys=(KeySpec("start_pose", None, "[x, y, z, yaw] of the known start (required with fixes or beacons; else 0: relative to the start)"),
                      KeySpec("building.floor_height_m", 3.5, "m"), KeySpec("building.floors", 3, "count"),
                      KeySpec("building.elevator_xy_m", None, "[x, y] of the elevator, m"), KeySpec("building.stairs_foot_xy_m", None, "[x, y], m"),
                      KeySpec("building.riser_m", 0.175, "stair riser, m"), KeySpec("building.tread_m", 0.28, "stair tread, m"),
                      KeySpec("truth_extra.steps", None, "steps counted by hand (scores --solver steps)"),
                      KeySpec("truth_extra.foot_switch_steps", None, "steps of a reference's foot switches (documentation)"),
                      KeySpec("steps.peak_threshold_m_s2", None, "--solver steps: a step's least vertical peak, m/s^2 (default frontends.pdr.PHONE's)"),
                      KeySpec("placement", None, "where the sensor was carried, e.g. pocket, hand (documentation)"),
                      KeySpec("speed_model.intercept_m_s", None, "walking speed = intercept + slope x peak-to-peak acceleration (required: a person's own)"),
                      KeySpec("speed_model.slope_s", None, "see intercept_m_s (required)"),
                      KeySpec("person.height_m", None, "the walker's height, m (may calibrate a gait model)"),
                      KeySpec("person.sensor_height_m", None, "height of the waist sensor above the ground standing, m (the inverted pendulum's leg)"),
                      KeySpec("truth_extra.bouts_s", None, "a reference system's walking bouts, [[start, end], ...] s (bench gait)"),
                      KeySpec("truth_extra.bout_stride_length_m", None, "each reference bout's mean stride length, m"),
                      KeySpec("truth_extra.bout_walking_speed_m_s", None, "each reference bout's mean walking speed, m/s"),
                      KeySpec("truth_extra.initial_contacts_s", None, "the reference's initial contacts (steps), s"),
                      KeySpec("gait.model", None, "--solver gait: 'pendulum' (default) or 'excursion' (step = correction x the pelvis's rise; frontends.gait)"),
                      KeySpec("gait.highpass_hz", None, "--solver gait: the pelvis's rise's drift removal, Hz (frontends.gait.StepLengthConfig)"),
                      KeySpec("gait.correction", None, "--solver gait: the step length's scale (the pendulum's correction, or step per excursion)"),
                      KeySpec("gait.peak_threshold_m_s2", None, "--solver gait: a step's vertical peak at least, m/s^2 (frontends.gait.StepDetection)"),
                      KeySpec("gait.forward_slope_m_s3", None, "--solver gait: a step's forward rise at least, m/s^3 (frontends.gait.StepDetection)")),
        solvers={"online": "iSAM2 causal", "batch": "smoother (fixes beyond the tuned threshold, tuned.toml [walking_fixes], rejected, solved again)",
                 "ekf": "the paper's Kalman framework",
                 "dead_reckoning": "steps and rides only", "steps": "step count of the accelerometer alone (a phone's step recording; no trajectory)",
                 "activity": "each walking cycle's activity by the waist classifier (scored against an activity label stream)",
                 "gait": "strides from the pelvis's vertical excursion, needs [person] sensor_height_m (scored against [truth_extra] reference bouts)"},
        truth="truth.csv, kind position: t, x, y, z of the waist in the building frame (ENU, z up from the ground floor), one row per "
        "IMU sample (a vehicle: per odometry row); scored as RMSE and final error, m. An accelerometer-only recording: the hand "
        "count as [truth_extra] steps",
        axes="waist gyro and accel sampled together in the sensor's own frame (its orientation on the belt is found from gravity and "
        "the walking direction); accel specific force; fixes (kind pose): x, y, z, yaw in the building frame, yaw from east "
        "counter-clockwise; wheel_odometry: per-row distance and heading change",
        run=_walking_run,
        score=_walking_score,
        estimate_name="trajectory",
        metric_keys=("rmse_m", "final_error_m"),
    ),
    "ultrasonic": Preset(
        name="ultrasonic",
        summary="every ultrasonic/UWB tag's 3D position at the full rate from unlabelled distances heard by known receivers",
        streams="ranges (kind ranges: t, receiver, range_m per distance heard; receivers_m, transmitters, sigma_m)",
        session_keys=(KeySpec("truth_clock_offset_s", None, "imports: the reference clock minus the ranges' clock, found from the raw data "
                              "and applied to the truth, s (documentation)"),),
        solvers={"online": "association + multiple-model tracks per epoch", "batch": "the tracks smoothed over the session with the online association",
                 "combinatorial": "the paper's combinatorial search per epoch"},
        truth="truth.csv, kind tag_position: t, tag, x, y, z, one row per tag at each range epoch's time (the same t as ranges.csv), "
        "room frame (receivers_m's); scored by matching tags to the truth each epoch: association accuracy, RMSE, track loss (in x, y "
        "when planar); the optional truth_label column of ranges.csv (scoring only)",
        axes="receivers_m in a room frame (z up, ceiling receivers above the tags); one row per distance heard, the rows of an epoch "
        "sharing t; ranges in metres (a UWB export in mm must be converted); tag_offsets_m in the rigid body's frame",
        run=_ultrasonic_run,
        score=_ultrasonic_score,
        estimate_name="tags",
        metric_keys=("assoc_acc", "assoc_acc_unambiguous", "rmse_m", "lost_frac"),
    ),
}
"""Every system by name."""


def preset_for(session: Session) -> Preset:
    """The preset of a session's system (an error lists the systems)."""
    try:
        preset = PRESETS[session.system]
    except KeyError:
        where = f"{session.path / 'session.toml'}: " if session.path else ""
        raise SessionError(f"{where}[session] system = '{session.system}' is not one of {', '.join(PRESETS)}") from None
    preset.check_session(session)
    return preset
