"""Gaze in world coordinates: head attitude and the fixated wall point in one graph.

The head's 9-axis graph (``graphs.attitude9``: IMU preintegration, gravity, magnetometer heading)
gets a fixation point ``g(k)`` per head keyframe: a Point3 on the wall plane (prior), moving slowly
from keyframe to keyframe (random walk with a Cauchy kernel, so a saccade is a jump the kernel
absorbs), and every 60 Hz gaze pixel as gtsam's ``GenericProjectionFactorCal3_S2`` of ``g(k)`` into
the head camera at keyframe k, the sample's offset from the keyframe carried by the gyro's rotation
(``factors.gaze``). The head translation is a nuisance held near the eye's rest position (5 cm).
An optional head attitude tracker (kind ``attitude``, own room frame, possibly late) joins the
head's graph as in the 9-axis system (``Attitude9Builder.add_attitude``); the EKF ignores it.
Online: iSAM2 after every keyframe, the gaze estimate of a sample is its keyframe's point right
after the update that added it (causal). Batch: the same graph, Levenberg-Marquardt, the point
of the sample's keyframe.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from ..baselines.ekf_gaze import GazeEkfConfig, run_gaze_ekf_full
from ..consistency import stream_range
from ..factors.gaze import FixationNoise, depth_prior, fixation_tuned, fixation_walk, gaze_factor, head_mag_tuned, sample_points, wall_plane_prior
from ..factors.imu import MotionPriors
from ..geometry import FloatArray, quat_wxyz_from_rot3, rotate_by_quat
from ..graphs.attitude9 import Attitude9Builder, Attitude9Model, X
from ..records import GazeData, GazeScenarioConfig, GazeSession
from ..session import Session, SessionError
from ..solvers.online import OnlineConfig, OnlineSmoother
from . import attitude9

METHODS = ("ekf", "online", "batch")


def G(k: int) -> int:
    """Key of the fixation point at head keyframe k."""
    return int(gtsam.symbol("g", k))


@dataclass(frozen=True)
class GazeModel:
    """Everything the gaze graph assumes."""

    head: Attitude9Model = field(default_factory=lambda: Attitude9Model(motion=MotionPriors(position_sigma_m=0.05, velocity_sigma_m_s=0.3),
                                                                       mag=head_mag_tuned(), unmodelled_acceleration=True))
    """The head's 9-axis graph; its position prior holds the eye within centimetres of its rest place, and what the
    accelerometer reads beyond gravity is acceleration those priors do not model (``unmodelled_acceleration``): a head
    that translates (walking, a trampoline) then keeps the gyro's rotation instead of being tilted to explain it. Without
    it the trampoline recording's batch sat 37-40 deg off the accelerometer's tilt where the wearer stood (the first and
    last seconds) and the online turned 45 deg beyond its gyro inside one 0.9 s fixation; on the simulated scenarios (no
    translation) it scores 9.02 / 6.49 mm against 9.05 / 6.66 (online / batch, seeds 100-119, the gaze studies' objective). Its
    magnetometer: ``factors.gaze.head_mag_tuned``."""
    fixation: FixationNoise = field(default_factory=FixationNoise)
    """How the fixated point moves."""
    online: OnlineConfig = field(default_factory=lambda: OnlineConfig(1.0, 10, 0.05, covariance=False, in_place=False))
    """iSAM2 settings (the 9-axis system's, re-anchored by rebuilding: in place, the fixation walk's Cauchy factors kept stale linearisations)."""


class GazeGraph:
    """Feeds head IMU samples and gaze pixels into one builder; works online (iSAM2) and batch."""

    def __init__(self, session: GazeData, model: GazeModel, deferred_mag: bool = False) -> None:
        self.session = session
        self.model = model
        self.builder = Attitude9Builder(model.head, deferred_mag=deferred_mag)
        self.camera = session.config.camera
        self.wall_m = session.config.wall_m
        self._next_gaze = 0
        self._points = 0  # keyframes that have a fixation point
        self.sample_keyframe = np.full(len(session.tracker_t), -1)
        """Keyframe each gaze sample was attached to."""
        self.keyframe_R_sample = np.tile(np.eye(3), (len(session.tracker_t), 1, 1))
        """The gyro's rotation from a gaze sample's keyframe to the sample (what its factor carries)."""
        self.gyro_bias = np.zeros(3)
        """Gyro bias used to carry a gaze sample from its keyframe (the online solver refreshes it)."""
        self._cumulative_k = -1
        self._cumulative: list[gtsam.Rot3] = []
        self.too_late = 0
        """Gaze samples that came too late for the online solver's window: no estimate (and no factor when their keyframe had
        already left it)."""

    def _grow(self) -> None:
        """Room for every gaze sample the session holds now (a live session's arrays grow as samples arrive)."""
        n = len(self.session.tracker_t)
        if n > len(self.sample_keyframe):
            extra = max(n, 2 * len(self.sample_keyframe)) - len(self.sample_keyframe)
            self.sample_keyframe = np.r_[self.sample_keyframe, np.full(extra, -1)]
            self.keyframe_R_sample = np.concatenate([self.keyframe_R_sample, np.tile(np.eye(3), (extra, 1, 1))])

    def push(self, i0: int, i1: int, final: bool = False) -> range:
        """IMU samples [i0, i1), then the gaze samples up to the newest keyframe (``final``: up to the last IMU sample); returns those added."""
        first = self._next_gaze
        s = self.session
        self.builder.add_samples(s.t[i0:i1], s.gyro_rad_s[i0:i1], s.accel_m_s2[i0:i1], s.mag[i0:i1])
        if s.head_tracker is not None and self.builder.started:  # what has arrived by the newest IMU sample
            self.builder.feed_tracker(s.head_tracker, float(s.t[min(i1, len(s.t)) - 1]))
        if not self.builder.started:
            return range(first, first)
        kf_t = self.builder.keyframe_t
        last = s.t[-1] if final else kf_t[-1]
        tt = s.tracker_t
        self._grow()
        while self._next_gaze < len(tt) and tt[self._next_gaze] <= last:
            j = self._next_gaze
            k = int(np.searchsorted(kf_t, tt[j], side="right") - 1)
            while self._points <= k:  # a point once its keyframe's gaze has come, started where that gaze looks
                self._add_point(self._points, float(kf_t[self._points + 1]) if self._points + 1 < len(kf_t) else last)
                self._points += 1
            if k >= self.builder.oldest_allowed_keyframe:
                self._add_gaze(j, k)
            elif k >= 0:
                self.too_late += 1  # live: it came after the online solver marginalised its keyframe (counted, not hidden)
            self._next_gaze += 1
        return range(first, self._next_gaze)

    def _initial_point(self, k: int, until: float) -> FloatArray:
        """Where keyframe k's own gaze rays (up to ``until``, its next keyframe) meet the wall, their median carried by the
        gyro to k and seen with k's predicted attitude (the newest keyframe's dead reckoning, carried back); without gaze
        of its own, the newest ray before k.

        Starting g(k) there matters after a saccade: linearised at the old point the random walk's Cauchy kernel would
        give the jump full weight, and iSAM2 would turn the head by part of the saccade before it followed (1.9 deg of
        yaw over a keyframe on a simulated 10 deg saccade when g(k) started at the ray before the keyframe).
        """
        s, kf_t = self.session, self.builder.keyframe_t
        lo, hi = np.searchsorted(s.tracker_t, [kf_t[k], until], side="right")
        depth = self.session.config.target_depth_m
        if hi <= lo and lo == 0:
            return np.array([depth or self.wall_m, 0.0, 0.0])
        own = range(lo, hi) if hi > lo else range(lo - 1, lo)
        rays = [self._rotation_since_keyframe(k, max(float(s.tracker_t[j]), kf_t[k])).matrix() @ self.camera.ray(s.gaze_px[j])[0] for j in own]
        world_R_head = self.builder.predicted_attitude.compose(self._rotation_since_keyframe(k, kf_t[self.builder.latest_keyframe]).inverse())
        ray = world_R_head.matrix() @ np.median(rays, axis=0)
        ray /= np.linalg.norm(ray)
        if depth is not None:
            return ray * depth
        if ray[0] <= 1e-3:
            return np.array([self.wall_m, 0.0, 0.0])
        return ray * (self.wall_m / ray[0])

    def _add_point(self, k: int, until: float) -> None:
        point = self._initial_point(k, until)
        self.builder.add_variable(G(k), point, per_keyframe=True)
        if self.session.config.target_depth_m is None:
            self.builder.add_factor(k, wall_plane_prior(G(k), self.wall_m, self.model.fixation))
        else:
            self.builder.add_factor(k, depth_prior(G(k), point, self.model.fixation))
        if k > 0:
            dt = self.builder.keyframe_t[k] - self.builder.keyframe_t[k - 1]
            self.builder.add_factor(k - 1, fixation_walk(G(k - 1), G(k), dt, self.model.fixation))

    def _rotation_since_keyframe(self, k: int, t: float) -> gtsam.Rot3:
        """The bias-corrected gyro's rotation from keyframe k to time t (cumulative per keyframe, cached)."""
        s = self.session
        i0 = self.builder.keyframe_index[k]
        if self._cumulative_k != k:
            self._cumulative_k, self._cumulative = k, [gtsam.Rot3()]
        i = int(np.searchsorted(s.t, t, side="right"))  # samples i0+1 .. i-1 lie in (t_k, t]
        while i0 + len(self._cumulative) < min(i, len(s.t)):
            n = i0 + len(self._cumulative)
            step = gtsam.Rot3.Expmap((s.gyro_rad_s[n] - self.gyro_bias) * (s.t[n] - s.t[n - 1]))
            self._cumulative.append(self._cumulative[-1].compose(step))
        last = min(i, len(s.t)) - 1
        rot = self._cumulative[max(last - i0, 0)]
        if i < len(s.t) and t > s.t[last]:  # the part of the next sample's interval up to t
            rot = rot.compose(gtsam.Rot3.Expmap((s.gyro_rad_s[i] - self.gyro_bias) * (t - s.t[last])))
        return rot

    def _add_gaze(self, j: int, k: int) -> None:
        s = self.session
        keyframe_R_sample = self._rotation_since_keyframe(k, float(s.tracker_t[j]))
        self.builder.add_factor(k, gaze_factor(X(k), G(k), s.gaze_px[j], keyframe_R_sample, self.camera))
        self.sample_keyframe[j] = k
        self.keyframe_R_sample[j] = keyframe_R_sample.matrix()

    def own_points(self, points_m: FloatArray, world_R_head: FloatArray, samples: slice | np.ndarray = slice(None)) -> FloatArray:
        """``factors.gaze.sample_points`` for the given gaze samples (rows of ``points_m`` and ``world_R_head``): each its
        keyframe's fixation point, or its own ray's point where it looks away from it by more than the model's gate."""
        return sample_points(points_m, world_R_head, self.camera.ray(self.session.gaze_px[samples]), self.camera,
                             self.session.config.target_depth_m is None, self.model.fixation.sample_gate_sigmas)

    def carry_with(self, gyro_bias: Callable[[int], FloatArray]) -> None:
        """Carry every attached gaze sample from its keyframe again, with that keyframe's gyro bias (``gyro_bias(k)``, rad/s):
        the batch knows the bias only once solved, and its samples were pushed with none (a 3 deg/s bias left a sawtooth
        of up to 0.6 deg between keyframes in every attitude it reported)."""
        current = -1
        for j in np.flatnonzero(self.sample_keyframe >= 0):
            k = int(self.sample_keyframe[j])
            if k != current:  # a new bias: the cached rotations since the keyframe were carried with the old one
                current, self.gyro_bias, self._cumulative_k = k, gyro_bias(k), -1
            self.keyframe_R_sample[j] = self._rotation_since_keyframe(k, float(self.session.tracker_t[j])).matrix()

    def sample_attitudes(self, keyframe_attitude: Callable[[int], gtsam.Rot3], samples: Iterable[int], out: FloatArray) -> None:
        """Fill ``out`` (M, 4) at the given gaze samples with world_R_head (w, x, y, z): their keyframe's attitude
        (read once per keyframe) carried by the gyro; samples without a keyframe stay as they are."""
        rotations: dict[int, gtsam.Rot3] = {}
        for j in samples:
            k = int(self.sample_keyframe[j])
            if k < 0:
                continue
            if k not in rotations:
                rotations[k] = keyframe_attitude(k)
            out[j] = self.sample_attitude(rotations[k], j)

    def sample_attitude(self, world_R_keyframe: gtsam.Rot3, j: int) -> FloatArray:
        """world_R_head (w, x, y, z) at gaze sample j from its keyframe's attitude, carried by the gyro."""
        return quat_wxyz_from_rot3(world_R_keyframe.compose(gtsam.Rot3(self.keyframe_R_sample[j])))


NEEDS_WALL = "[session] needs wall_m (distance to the wall, metres) or, without a wall, target_depth_m (depth at which each fixation point is held, metres)"


def from_session(session: Session) -> GazeSession:
    """A gaze session directory's content as the system's input: head ``gyro``/``accel``/``mag`` sampled
    together, the tracker's ``gaze`` pixels (kind ``pixel``, camera in its metadata), ``wall_m`` (or, without a
    wall, ``target_depth_m``) in ``[session]``; the truth (gaze point, world x, y, z at the tracker times) is optional."""
    where = session.where
    names = ("gyro", "accel", "mag") if "mag" in session.streams else ("gyro", "accel")  # no magnetometer: use_mag = false
    imu = dict(zip(names, session.synchronous(*names), strict=True))
    t = imu["gyro"].t
    mag = imu["mag"].values if "mag" in imu else np.full((len(t), 3), np.nan)
    gaze_stream = session.stream("gaze")
    if gaze_stream.kind != "pixel":
        raise SessionError(f"{where}: stream 'gaze' must be of kind 'pixel', not '{gaze_stream.kind}'")
    header = session.meta.get("session", {})
    if "wall_m" not in header and "target_depth_m" not in header:
        raise SessionError(f"{where}: {NEEDS_WALL}")
    config = GazeScenarioConfig.declared(header, gaze_stream.meta, float(t[-1] - t[0]))
    truth = np.full((len(gaze_stream), 2), np.nan)
    world_ray = header.get("gaze_truth") == "world_ray"  # the truth is the eye's world ray (import broad --system gaze), not a wall point
    if session.truth is not None and session.truth.kind == "position" and len(session.truth) == len(gaze_stream) and not world_ray:
        truth = session.truth.values[:, 1:3].copy()
    tracker_t = gaze_stream.t - float(gaze_stream.meta.get("time_offset_s", 0.0))  # a sample at stamp - the declared delay
    return GazeSession(t=t, gyro_rad_s=imu["gyro"].values, accel_m_s2=imu["accel"].values, mag=mag, tracker_t=tracker_t,
                       gaze_px=gaze_stream.values, truth_quat_wxyz=np.full((len(t), 4), np.nan), truth_gaze_xz_m=truth, config=config,
                       head_tracker=attitude9.attitude_tracker(session))


def wall_points(session: GazeSession, world_R_head: FloatArray) -> FloatArray:
    """Where each gaze ray, turned by a head attitude (quaternions at the gaze samples), meets the wall x = ``wall_m``
    (or the plane at ``target_depth_m``): (X, Z) = (world y, z), metres; NaN where the ray does not reach it."""
    depth = session.config.wall_m if session.config.target_depth_m is None else session.config.target_depth_m
    rays = rotate_by_quat(world_R_head, session.config.camera.ray(session.gaze_px))
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(rays[:, 0] > 1e-6, depth / rays[:, 0], np.nan)
    return rays[:, 1:] * scale[:, None]


def block_size(session: GazeData, model: GazeModel, rate_hz: float | None = None) -> int:
    """IMU samples per push (one keyframe's): from ``rate_hz`` when given, else from the samples' median spacing."""
    dt = 1.0 / rate_hz if rate_hz is not None else float(np.median(np.diff(session.t)))
    return max(1, int(round(model.head.keyframe_period_s / dt)))


@dataclass(frozen=True)
class GazeEstimate:
    """One method's output at every gaze sample."""

    points_xz_m: FloatArray
    """Gaze point on the wall (X, Z), metres, shape (M, 2) (with ``target_depth_m``: the world y, z of the point)."""
    world_R_head: FloatArray
    """Head attitude at each gaze sample's time (quaternion w, x, y, z), shape (M, 4); NaN where none."""
    runtime_s: float
    """Wall time of the run, seconds."""
    notes: tuple[str, ...] = ()
    """What the head's graph says about the run (``Attitude9Builder.notes``: the IMU dropouts bridged, new fields taken)."""


def run_online(session: GazeSession, model: GazeModel | None = None) -> GazeEstimate:
    """Causal gaze point (X, Z) on the wall and head attitude per tracker sample (right after the update that added it)."""
    model = model or GazeModel()
    start = time.perf_counter()
    graph = GazeGraph(session, model)
    solver = OnlineSmoother(graph.builder, model.online)
    out = np.full((len(session.tracker_t), 3), np.nan)
    attitude = np.full((len(session.tracker_t), 4), np.nan)
    block = block_size(session, model)
    for i in [*range(0, len(session.t), block), len(session.t)]:  # last, the gaze after the last keyframe in an update of its own
        added = graph.push(i, i + block, final=i >= len(session.t))
        if not solver.update(force=i >= len(session.t)):
            continue
        k = graph.builder.latest_keyframe
        points: dict[int, FloatArray] = {}
        graph.gyro_bias = graph.builder.posterior_gyro_bias[k] if graph.builder.posterior_gyro_bias else graph.gyro_bias
        for j in added:
            kj = int(graph.sample_keyframe[j])
            if kj >= 0:  # a sample before the first keyframe has no factor and no estimate
                if kj not in points:
                    points[kj] = solver.isam.calculateEstimatePoint3(G(kj))
                out[j] = points[kj]
        graph.sample_attitudes(lambda kj: solver.isam.calculateEstimatePose3(X(kj)).rotation(), added, attitude)
    return GazeEstimate(graph.own_points(out, attitude)[:, 1:], attitude, time.perf_counter() - start, tuple(graph.builder.notes()))


def batch_model() -> GazeModel:
    """The batch's model: its own fixation setting (``tune gaze_fixation_batch``; read when first needed, so that
    the study itself runs before its table exists). The online setting (Cauchy k 4) cost the batch a diverged
    test seed: a wider kernel lets a saccade pull the fixation point across."""
    return GazeModel(fixation=fixation_tuned("gaze_fixation_batch"))


def run_batch(session: GazeSession, model: GazeModel | None = None) -> GazeEstimate:
    """Smoothed gaze point per tracker sample (its keyframe's point) and head attitude at each sample.

    As the 9-axis batch: initial attitudes from the inertial filter (``inertial_initial``), heading factors levelled
    first with them (Gaussian), then with the first pass's attitude (Cauchy). Levelled with dead reckoning from a zero
    gyro bias instead, the tilt error grew with time, became heading error through the dip, and the Cauchy pass could
    not leave it: scene-viewing seed 101's gaze X drifted to -126 mm at 40 s (85 mm RMS; 8.8 now).
    """
    model = model or batch_model()
    start = time.perf_counter()
    graph = GazeGraph(session, model, deferred_mag=True)
    block = block_size(session, model)
    for i in range(0, len(session.t), block):
        graph.push(i, i + block, final=i + block >= len(session.t))
    increment = graph.builder.take()
    keyframes = len(graph.builder.keyframe_t)
    values = graph.builder.inertial_initial(graph.builder.tracker_seeded(increment.values))
    attitude = [values.atPose3(X(k)).rotation() for k in range(keyframes)]
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-4)
    params.setMaxIterations(30)
    params.setlambdaFactor(3.0)
    for robust in graph.builder.heading_passes():
        factors = increment.graph()
        for factor in graph.builder.heading_factors(attitude, robust):
            factors.add(factor)
        values = gtsam.LevenbergMarquardtOptimizer(factors, values, params).optimize()
        attitude = [values.atPose3(X(k)).rotation() for k in range(keyframes)]
    points = np.array([values.atPoint3(G(k)) for k in range(graph._points)])  # keyframes after the last gaze have none
    # each sample's own keyframe point (what its factor saw; interpolating across a saccade smears the jump), or its own ray
    out = np.full((len(session.tracker_t), 3), np.nan)
    attached = graph.sample_keyframe >= 0
    out[attached] = points[graph.sample_keyframe[attached]]
    graph.carry_with(lambda k: values.atConstantBias(graph.builder.B(k)).gyroscope())
    at_samples = np.full((len(session.tracker_t), 4), np.nan)
    graph.sample_attitudes(lambda k: values.atPose3(X(k)).rotation(), range(len(session.tracker_t)), at_samples)
    return GazeEstimate(graph.own_points(out, at_samples)[:, 1:], at_samples, time.perf_counter() - start, tuple(graph.builder.notes()))


#: What ``[session] head_motion`` may declare (``model_for``).
HEAD_MOTIONS = ("seated", "free")


def model_for(session: Session, solver: str) -> GazeModel:
    """The solver's model for a session. ``[session] head_motion``: ``seated`` (default), a viewer's head held within centimetres of its place
    (``GazeModel.head``, chosen on the simulated gaze scenarios); ``free``, a sensor carried and moved by hand (BROAD's), whose head is the 9-axis
    online model ``attitude9.model_for`` gives this session's IMU, for both solvers as ``GazeModel`` has one head (``docs/systems/gaze.md``)."""
    header = session.meta.get("session", {})
    if (motion := header.get("head_motion", "seated")) not in HEAD_MOTIONS:
        raise SessionError(f"{session.where}: [session] head_motion = {motion!r}: one of {', '.join(HEAD_MOTIONS)}")
    model = GazeModel() if solver == "online" else batch_model()
    head = model.head
    if motion == "free":  # the 9-axis model as that system reads the streams (the accelerometer's range with it)
        head = attitude9.model_for(session, solver="online")
    elif "accel" in session.streams:  # live declarations may name none
        head = replace(head, accel_range_m_s2=stream_range(session.stream("accel")))
    return replace(model, head=replace(head, use_mag=bool(header.get("use_mag", True))))


def run_ekf(session: GazeSession, config: GazeEkfConfig | None = None) -> GazeEstimate:
    """The gaze paper's EKF; without a wall (``target_depth_m``) its wall faces its own first heading at that distance."""
    start = time.perf_counter()
    s = session
    wall_m = s.config.wall_m if s.config.target_depth_m is None else s.config.target_depth_m
    out, attitude = run_gaze_ekf_full(
        s.t, s.gyro_rad_s, s.accel_m_s2, s.mag, s.tracker_t, s.gaze_px, wall_m, s.config.camera, config, wall_facing_start=s.config.target_depth_m is not None
    )
    return GazeEstimate(out, attitude, time.perf_counter() - start)


RUNNERS = {"ekf": run_ekf, "online": run_online, "batch": run_batch}

__all__ = ["RUNNERS", "GazeGraph", "GazeModel", "from_session", "model_for", "run_batch", "run_ekf", "run_online"]
