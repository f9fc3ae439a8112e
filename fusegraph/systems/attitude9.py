"""9-axis attitude end to end: Session (gyro, accel, mag[, attitude tracker]) -> Estimate, for fusegraph and every baseline.

An optional attitude tracker (an optical or magnetic tracker's world_R_body, kind ``attitude``, possibly
late: ``latency_s``) joins the same graph: online, each sample enters when it arrives; its room frame
is estimated (one constant rotation), so it need not be aligned with ENU. The baselines ignore it.

Methods: ``online`` (iSAM2, causal: each sample's attitude uses nothing after it), ``batch`` (the same
factors smoothed over the whole session, in two passes: the first levels the magnetometer with the
initial values' attitude (a filter in the gyro's frame) and a Gaussian heading noise, the second with
the first's attitude and the Cauchy kernel), ``ekf`` (the founding papers' 9-axis EKF on roll/pitch/yaw), ``vqf`` and ``vqf_offline`` (the peer).
"""

from __future__ import annotations

import itertools
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from ..consistency import stream_range
from ..estimate import Estimate
from ..factors.accel import declared_gravity
from ..factors.attitude import AttitudeTrack
from ..factors.gyro import GyroCalibrationPrior
from ..factors.mag import FieldReference, MagCalibration, fit_mag_calibration
from ..geometry import quat_wxyz_from_rot3, rot3_from_quat_wxyz
from ..graphs.attitude9 import MODEL_STUDIES, TRACKER_WORLD, Attitude9Builder, Attitude9Model, B, V, X, fill_samples, model_from_settings, with_rest
from ..graphs.increment import GraphIncrement
from ..progress import progress
from ..session import NotApplicableError, Session, SessionError, SessionWarning
from ..solvers.batch import chain_levenberg
from ..solvers.online import OnlineConfig, OnlineSmoother
from ..solvers.windowed import Windows, joined, recording_span, session_blocks, smooth_in_windows
from ..tuned import tuned, tuned_studies


def online_config(setting: Mapping[str, float]) -> OnlineConfig:
    """The 9-axis online solver with a ``broad_online`` setting (a grid point, or the chosen one): how many updates apart
    iSAM2 checks for variables to relinearise. The rest: 1 s of keyframes stays live, re-anchored every 2 s (20 s made
    each update 2x slower for the same accuracy); covariances are not needed per sample."""
    return OnlineConfig(window_s=1.0, reanchor_every=10, relinearize_threshold=0.05, covariance=False,
                        relinearize_skip=int(setting["relinearize_skip"]))


#: The 9-axis online solver: its relinearisation checks chosen by leave-one-trial-out on BROAD (``tune broad_online``).
ONLINE_CONFIG = online_config(tuned("broad_online"))


@dataclass(frozen=True)
class Imu9:
    """A session's synchronous gyro/accelerometer/magnetometer samples."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    mag: np.ndarray | None


def imu9(session: Session) -> Imu9:
    """The gyro, accel and (optional) mag streams, checked to share one clock."""
    names = ("gyro", "accel", "mag") if "mag" in session.streams else ("gyro", "accel")
    streams = session.synchronous(*names)
    gyro, accel = streams[0], streams[1]
    return Imu9(gyro.t, gyro.values, accel.values, streams[2].values if len(streams) == 3 else None)


def attitude_tracker(session: Session) -> AttitudeTrack | None:
    """The session's attitude tracker (its one ``attitude`` stream), if any.

    The tracker's white and slowly varying error are taken together as one white sigma here (the 9-axis
    graph does not carry the Gauss-Markov chain the head graph has).
    """
    streams = session.streams_of_kind("attitude")
    if not streams:
        return None
    if len(streams) > 1:
        raise SessionError(f"{session.system}: one attitude tracker stream at most (have: {', '.join(s.name for s in streams)})")
    tracker = streams[0]
    sigma_deg = float(np.hypot(float(tracker.meta.get("noise_sigma_deg", 0.4)), float(tracker.meta.get("markov_sigma_deg", 0.0))))
    return AttitudeTrack(tracker.t, tracker.latency_s, tracker.values, float(np.deg2rad(sigma_deg)))


DECLARED_IMU: tuple[tuple[str, str, str], ...] = (
    ("accel", "noise_m_s2_sqrt_hz", "accel_noise_m_s2_sqrt_hz"),
    ("accel", "bias_rw_m_s2_sqrt_s", "accel_bias_walk_m_s2_sqrt_s"),
    ("gyro", "bias_rw_sigma", "gyro_bias_walk_rad_s_sqrt_s"),
)
"""(stream, key it declares, ``ImuNoise`` field it replaces) for what a recording may say about its IMU (``model_for``)."""


def declared_gyro_density(session: Session, name: str = "gyro") -> float | None:
    """The gyro's declared white noise (``noise_sigma_rad_s`` per sample) as a density, rad/s/sqrt(Hz): sigma over the
    square root of its rate (declared ``rate_hz``, else the median sample spacing); None when not declared."""
    if name not in session.streams or "noise_sigma_rad_s" not in session.stream(name).meta:
        return None
    gyro = session.stream(name)
    rate = float(gyro.meta["rate_hz"]) if "rate_hz" in gyro.meta else 1.0 / float(np.median(np.diff(gyro.t)))
    return float(gyro.meta["noise_sigma_rad_s"]) / float(np.sqrt(rate))


def model_for(session: Session, model: Attitude9Model | None = None, solver: str = "online") -> Attitude9Model:
    """The model with the session's magnetometer calibration: declared in the ``mag`` stream's metadata (``calibration_gain``, ``calibration_offset``),
    or fitted to a ``mag_cal`` calibration recording.

    Without an explicit ``model``: the solver's BROAD-chosen model (``broad_model``), with what the ``accel`` stream declares replacing its motion,
    noise, bias and gravity settings (``velocity_sigma_m_s``, ``noise_m_s2_sqrt_hz``, ``bias_rw_m_s2_sqrt_s``, ``sigma_deg``,
    ``inflation_deg_per_m_s2``) and the ``gyro`` stream's ``bias_rw_sigma`` its bias walk and its ``noise_sigma_rad_s`` its white noise (a data
    sheet's figures belong with the recording), and its ``scale_sigma`` (fraction; ``misalignment_sigma_rad`` beside, the same by default) has the
    batch estimate the gyro's scale factors and misalignment (``Attitude9Model.gyro_calibration``; off on BROAD, where it was measured), its
    ``rest_rate_sigma_rad_s`` the zero-rate update's rest rate (``MotionPriors``; inf: none): BROAD is hand-held motion, and a sensor that travels (a
    walker's belt, a vehicle) needs a wider velocity prior (e.g. 2 m/s). The ``mag`` stream's ``reference_tau_s`` and ``new_field_s`` replace the
    field tracking's (``MagNoise``; BROAD's trials share one room)."""
    if model is None:
        model = broad_model(solver)
        declared = {kind: session.stream(kind).meta if kind in session.streams else {} for kind in ("accel", "gyro")}
        meta = declared["accel"]
        if "velocity_sigma_m_s" in meta:
            model = replace(model, motion=replace(model.motion, velocity_sigma_m_s=float(meta["velocity_sigma_m_s"])))
        imu = {field: float(declared[kind][key]) for kind, key, field in DECLARED_IMU if key in declared[kind]}
        density = declared_gyro_density(session)
        if density is not None:
            imu["gyro_noise_rad_s_sqrt_hz"] = density
        model = replace(model, imu=replace(model.imu, **imu)) if imu else model
        if "scale_sigma" in (gyro := declared["gyro"]):  # the batch estimates the gyro's scale factors and misalignment
            model = replace(model, gyro_calibration=GyroCalibrationPrior(gyro["scale_sigma"], gyro.get("misalignment_sigma_rad", gyro["scale_sigma"])))
        model = with_rest(model, gyro) if "rest_rate_sigma_rad_s" in gyro else model  # how still its rests are (inf: no update)
        if model.gravity is not None:
            model = replace(model, gravity=declared_gravity(meta, model.gravity))
    if "accel" in session.streams:  # a clipping accelerometer's samples at its range are bounds, not measurements
        model = replace(model, accel_range_m_s2=stream_range(session.stream("accel")))
    if "mag" not in session.streams:
        return model
    meta = session.stream("mag").meta
    if field := {key: float(meta[key]) for key in ("reference_tau_s", "new_field_s") if key in meta}:  # e.g. carried between places
        model = replace(model, mag=replace(model.mag, **field))  # type: ignore[arg-type]  # two float fields, not interval_mean
    if "calibration_gain" in meta and "calibration_offset" in meta:
        cal = MagCalibration(tuple(meta["calibration_gain"]), tuple(meta["calibration_offset"]))  # type: ignore[arg-type]
        return replace(model, mag_calibration=cal)
    if "mag_cal" in session.streams:
        return replace(model, mag_calibration=fit_mag_calibration(session.stream("mag_cal").values))
    return model


def run_online(session: Session, model: Attitude9Model | None = None, config: OnlineConfig | None = None, show_progress: bool = False) -> Estimate:
    """fusegraph online: samples pushed keyframe by keyframe, iSAM2 after each; causal attitude per sample."""
    data = imu9(session)
    builder = Attitude9Builder(model_for(session, model))
    solver = OnlineSmoother(builder, config or ONLINE_CONFIG.declared(session.meta, session.where))
    start = time.perf_counter()
    tracker = attitude_tracker(session)
    expected = int((data.t[-1] - data.t[0]) / builder.model.keyframe_period_s) + 1
    bar = progress(iter(int, 1), total=expected, desc="online keyframes", enabled=None if show_progress else False)  # a counter

    def step(now_s: float) -> None:  # at each new keyframe: the tracker samples that have arrived by then, then iSAM2
        if tracker is not None:
            builder.feed_tracker(tracker, now_s)
        solver.update()
        next(bar)

    # one push: the builder calls ``step`` as each keyframe closes, as a live feed would between its blocks
    builder.add_samples(data.t, data.gyro, data.accel, data.mag, on_keyframe=step)
    if tracker is not None:  # samples after the last keyframe: the tracker's that arrived by the end
        builder.feed_tracker(tracker, float(data.t[-1]))
        solver.update()
    quats = fill_samples(data.t, data.gyro, *builder.solved_keyframes(), False)
    runtime = time.perf_counter() - start
    say_notes(session.where, builder.notes())
    extras = {"keyframes": len(builder.keyframe_t), "reanchors": solver.reanchors, "in_place": solver.in_place_marginalisations, **builder.extras()}
    return Estimate("online", data.t.copy(), quats, None, runtime, extras)


def say_notes(where: str, notes: Iterable[str]) -> None:
    """One warning per note of a run (``Attitude9Builder.notes``: the dropouts bridged, the new fields taken)."""
    for note in notes:
        warnings.warn(f"{where}: {note}", SessionWarning, stacklevel=3)


def broad_model(solver: str = "online") -> Attitude9Model:
    """The 9-axis model each solver runs with: its settings chosen for it by leave-one-trial-out over the BROAD trials (``fusegraph tune
    broad_mag|broad_motion|broad_bias|broad_rest [--solver batch] --write``, ``tuned.toml`` [broad_mag], [broad_motion], [broad_bias], [broad_rest]
    and their ``_batch`` tables: each solver keeps its own, as the batch's best heading noise is not the causal estimate's).
    ``unmodelled_acceleration`` stays off: with it the thirteen trials scored 4.51 deg online and 2.17 batch (mean total
    RMSE, at these settings) against 1.93 and 1.67: a hand's accelerations average out over the tuned velocity prior,
    which then levels the sensor through the IMU factor."""
    return model_from_settings(broad_settings(solver))


def broad_settings(solver: str = "online") -> dict[str, dict[str, float]]:
    """Each model study's setting in ``tuned.toml`` for the solver (``broad_mag`` -> ``[broad_mag]`` or ``[broad_mag_batch]``)."""
    suffix = "" if solver == "online" else "_batch"
    return {study: tuned(study + suffix) for study in MODEL_STUDIES if study + suffix in tuned_studies()}


#: Median heading residual (angle between the levelled field and north) above which a batch solution is
#: taken as diverged, degrees: a converged batch on BROAD stays within a few degrees, a slid one near 180.
DIVERGED_HEADING_DEG = 30.0


#: How a long recording is cut for the batch (``solvers.windowed``): BROAD's trials (at most 3.6 min) are solved whole.
BATCH_WINDOWS = Windows()
#: How far a window's first attitude may move from the window before's estimate there: the batch's error on the simulations'
#: test seeds (0.2-0.4 deg RMS) with room for a disturbed stretch.
CARRIED_ATTITUDE_SIGMA_RAD = float(np.deg2rad(1.0))


def run_batch(session: Session, model: Attitude9Model | None = None, max_iterations: int = 30, windows: Windows | None = BATCH_WINDOWS) -> Estimate:
    """fusegraph batch: every factor at once, two Levenberg-Marquardt passes; smoothed attitude per sample.

    Checked, never silently wrong: when the median heading residual of the solution exceeds
    ``DIVERGED_HEADING_DEG`` the batch is solved again from the causal (online) estimate; if that too
    fails the check, a warning says so and ``extras["check"]`` is ``"suspect"``.

    A recording longer than ``windows`` allows is smoothed window by window (``windowed_batch``; its worst window's check
    is said); None: whole.
    """
    start_s, end_s = recording_span(session)
    if windows is not None and windows.needed(end_s - start_s):
        pieces = windowed_batch(session_blocks(session, windows.window_s), model, max_iterations, windows)
        return joined(pieces, ranked={"check": ("ok", "repaired", "suspect")})
    return _run_batch_whole(session, model, max_iterations)[0]


def windowed_batch(blocks: Iterable[Session], model: Attitude9Model | None = None, max_iterations: int = 30, windows: Windows = BATCH_WINDOWS,
                   progress: Callable[[float], None] | None = None, check: Callable[[Session], Session] | None = None) -> Iterator[Estimate]:
    """The batch over a recording given in blocks (Sessions in time order: ``session_blocks``, or read from disk) in overlapping windows, its
    pieces in time order as each is solved: memory bounded by one window. Each window starts from the one before's attitude and field there;
    without a magnetometer it is turned onto its heading. ``check(window)`` gives the window to solve (``runner.checked_window``)."""
    if (first := next(iterator := iter(blocks), None)) is None:
        raise SessionError("attitude9 batch: no samples")
    align = "mag" not in first.streams or (model is not None and not model.use_mag)
    before: list[tuple[Estimate, Attitude9Builder]] = []  # the window before: its estimate and field at this one's start

    def solve(window: Session) -> Estimate:
        window = check(window) if check is not None else window
        start_s = float(window.stream("gyro").t[0])
        reference, attitude = None, None
        if before:
            estimate, builder = before[-1]
            reference = builder.reference_at(start_s)
            n = min(int(np.searchsorted(estimate.t, start_s)), len(estimate.t) - 1)
            if np.isfinite(estimate.quat_wxyz[n]).all():
                attitude = (rot3_from_quat_wxyz(estimate.quat_wxyz[n]), CARRIED_ATTITUDE_SIGMA_RAD)
        estimate, builder = _run_batch_whole(window, model, max_iterations, reference, attitude)
        before[:] = [(estimate, builder)]
        return estimate

    yield from smooth_in_windows(itertools.chain([first], iterator), solve, windows, align, progress)


def _run_batch_whole(session: Session, model: Attitude9Model | None, max_iterations: int,
                     start_reference: FieldReference | None = None,
                     start_attitude: tuple[gtsam.Rot3, float] | None = None) -> tuple[Estimate, Attitude9Builder]:
    data = imu9(session)
    start = time.perf_counter()
    model = model_for(session, model, "batch")
    builder, increment = _build_batch(session, data, model, start_reference, start_attitude)
    kq, kb, residual = _solve_batch(builder, increment, max_iterations, None)
    check = "ok"
    if np.isfinite(residual) and residual > DIVERGED_HEADING_DEG:
        online = run_online(session, model)
        seed = online.quat_wxyz[np.array(builder.keyframe_index)]
        kq, kb, again = _solve_batch(builder, increment, max_iterations, seed)
        check = "repaired" if again <= DIVERGED_HEADING_DEG else "suspect"
        if check == "suspect":
            trial = session.meta.get("session", {}).get("trial")  # a dataset folder holds many trials: name the one
            where = f"{session.path}, trial {trial}" if session.path and trial else (session.path or trial or "session")
            warnings.warn(f"{where}: the 9-axis batch did not converge (median heading residual {again:.0f} deg, also from the online "
                          "estimate): its result is suspect", SessionWarning, stacklevel=2)
        residual = again
    quats = fill_samples(data.t, data.gyro, np.array(builder.keyframe_index), kq, kb, True)
    runtime = time.perf_counter() - start
    say_notes(session.where, builder.notes())
    extras = {"keyframes": len(builder.keyframe_t), "check": check, "heading_residual_median_deg": residual, **builder.extras()}
    return Estimate("batch", data.t.copy(), quats, None, runtime, extras), builder


def _build_batch(session: Session, data: Imu9, model: Attitude9Model | None,
                 start_reference: FieldReference | None = None,
                 start_attitude: tuple[gtsam.Rot3, float] | None = None) -> tuple[Attitude9Builder, GraphIncrement]:
    """The whole session's graph, heading factors deferred (``_solve_batch`` levels them)."""
    builder = Attitude9Builder(model_for(session, model), deferred_mag=True, start_reference=start_reference, start_attitude=start_attitude)
    builder.add_samples(data.t, data.gyro, data.accel, data.mag)
    tracker = attitude_tracker(session)
    if tracker is not None:
        builder.feed_tracker(tracker)
    return builder, builder.take()


def _solve_batch(
    builder: Attitude9Builder, increment: GraphIncrement, max_iterations: int, seed_quat_wxyz: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, float]:
    """One batch solve of a built graph (left as it is, so a repair can solve it again): (keyframe quats, keyframe gyro
    biases, median heading residual deg). ``seed_quat_wxyz`` (one per keyframe) replaces the initial
    attitudes (the repair from the online estimate)."""
    keyframes = len(builder.keyframe_t)
    order = gtsam.Ordering()
    for k in range(keyframes):
        for key in (X(k), V(k), B(k)):
            order.push_back(key)
    if builder.tracker_factors:
        order.push_back(TRACKER_WORLD)  # one variable tied to every keyframe: eliminated last
    base = increment.graph()
    values = builder.with_calibration(base, order, builder.inertial_initial(builder.tracker_seeded(gtsam.Values(increment.values))))
    if seed_quat_wxyz is not None:
        for k, quat in enumerate(seed_quat_wxyz):
            if np.all(np.isfinite(quat)):
                values.update(X(k), gtsam.Pose3(rot3_from_quat_wxyz(quat), values.atPose3(X(k)).translation()))
    attitude = [values.atPose3(X(k)).rotation() for k in range(keyframes)]
    for robust in builder.heading_passes():
        graph = gtsam.NonlinearFactorGraph(base)
        for factor in builder.heading_factors(attitude, robust):
            graph.add(factor)
        # the first pass must converge: capping it at 4 iterations left trial 24 levelled badly enough for
        # the Cauchy pass to settle 2.5 deg off in heading
        values = chain_levenberg(graph, values, order, max_iterations)
        attitude = [values.atPose3(X(k)).rotation() for k in range(keyframes)]
    kq = np.array([quat_wxyz_from_rot3(r) for r in attitude])
    kb = np.array([values.atConstantBias(B(k)).gyroscope() for k in range(keyframes)])
    builder.read_calibration(values)
    residuals = builder.heading_residuals_deg(attitude)
    return kq, kb, float(np.median(residuals)) if len(residuals) else float("nan")


def run_ekf(session: Session, model: Attitude9Model | None = None) -> Estimate:
    """The founding papers' 9-axis EKF on roll/pitch/yaw (the same magnetometer calibration)."""
    from ..baselines.ekf9 import Ekf9Config, run_ekf9

    data = imu9(session)
    if data.mag is None:
        raise NotApplicableError(f"{session.where}: the 9-axis EKF needs a magnetometer stream (the papers' filter has no mode without one)")
    cal = model_for(session, model).mag_calibration
    start = time.perf_counter()
    config = Ekf9Config(mag_gain=cal.gain, mag_offset=cal.offset)
    if "noise_sigma_rad_s" in session.stream("gyro").meta:  # the declared per-sample sigma is the EKF's gyro noise
        config = replace(config, gyro_sigma_rad_s=float(session.stream("gyro").meta["noise_sigma_rad_s"]))
    quats = run_ekf9(data.t, data.gyro, data.accel, data.mag, config)
    return Estimate("ekf", data.t.copy(), quats, None, time.perf_counter() - start)


def _calibrated_mag(session: Session) -> Session:
    """The session with its magnetometer calibrated as ours is (what the peers get too)."""
    if "mag" in session.streams:
        cal = model_for(session).mag_calibration
        if cal != MagCalibration():
            mag = session.stream("mag")
            session = replace(session, streams={**session.streams, "mag": replace(mag, values=cal.apply(mag.values))})
    return session


def run_vqf(session: Session, offline: bool = False) -> Estimate:
    """The peer VQF (default parameters) on the same calibrated magnetometer as ours."""
    from ..baselines.peers import run_vqf as peer

    return peer(_calibrated_mag(session), offline=offline)


def run_imufusion(session: Session) -> Estimate:
    """The peer imufusion (x-io Fusion, its example's settings) on the same calibrated magnetometer as ours."""
    from ..baselines.peers import run_imufusion as peer

    return peer(_calibrated_mag(session))


METHODS: dict[str, Callable[[Session], Estimate]] = {
    "vqf": run_vqf,
    "vqf_offline": lambda s: run_vqf(s, offline=True),
    "imufusion": run_imufusion,
    "ekf": run_ekf,
    "online": run_online,
    "batch": run_batch,
}
"""Every method of the 9-axis comparison, in the bench's column order."""


