"""Head tracking end to end: a Session in, one Estimate per method out, every method at the gyro times.

Methods (the rows of the paper's Table 1 plus ours): ``tracker`` (the latest ARRIVED tracker
sample), ``gyro`` (dead reckoning from the first fix), ``kalman``, ``method1``, ``method2`` (the
paper's EKFs), ``isam2`` (fusegraph online: causal estimate after every gyro sample) and ``batch``
(fusegraph smoother over the whole session).
"""

from __future__ import annotations

import contextlib
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Concatenate, ParamSpec

import gtsam
import numpy as np

from ..baselines.ekf import HeadEkfConfig, declared_ekf, ekf_config_from, load_compiled, run_head_ekf
from ..estimate import Estimate
from ..factors.gyro import RecentGyro, integrate_gyro
from ..frontends.head_timing import gyro_bias_from_tracker
from ..geometry import (
    FloatArray,
    quat_conjugate,
    quat_from_rotvec,
    quat_multiply,
    quat_normalize,
    quat_wxyz_from_rot3,
    rot3_from_quat_wxyz,
)
from ..graphs.head import HeadGraphBuilder, HeadModel, OnlinePredictions, X, head_model_for, interpolate_keyframes, rates_at, time_ordering, with_gap_keyframes
from ..progress import progress as progress_bar
from ..session import Session, replay_in_arrival_order
from ..solvers.batch import BatchConfig, solve_batch
from ..solvers.online import OnlineConfig, OnlineSmoother
from ..tuned import tuned

P = ParamSpec("P")

METHODS = ("tracker", "gyro", "kalman", "method1", "method2", "isam2", "batch")
"""Method names in the order of the report's rows."""


USED_KINDS = ("gyro", "attitude", "accel")
"""The streams the head graph reads (a truth stream beside them is not replayed)."""


def feed(builder: HeadGraphBuilder, session: Session, on_gyro: Callable[[float], None] | None = None) -> None:
    """Push every sample of the session into the builder in arrival order.

    ``on_gyro(t)`` runs after each gyro sample (the online solver updates and reads out there).
    """
    events = replay_in_arrival_order(session, last_streams=("gyro",), kinds=USED_KINDS)
    if session.duration_s > 60.0:  # long sessions show progress on a terminal
        events = progress_bar(events, sum(len(s) for s in session.streams.values() if s.kind in USED_KINDS), "building the graph")
    for event in events:
        if event.stream.kind == "gyro":
            builder.add_gyro(event.t, event.values)
            if on_gyro is not None:
                on_gyro(event.t)
        elif event.stream.kind == "attitude":
            builder.add_tracker(event.t, event.values)
        elif event.stream.kind == "accel":
            builder.add_accel(event.t, event.values)


def feed_recorded(builder: HeadGraphBuilder, session: Session) -> None:
    """Push a whole recorded session into the builder: every other sample in arrival order (tracker samples wait for
    their keyframes), then the gyro as one block (``HeadGraphBuilder.add_gyro_block``). The graph is ``feed``'s: no solver
    runs in between to change where a sample is placed; only the factors' order differs. ~1 s less Python per 10
    minutes of 100 Hz gyro than a call per sample."""
    others = tuple(kind for kind in USED_KINDS if kind != "gyro")  # not the truth either: ~5 % of the batch's time
    for event in replay_in_arrival_order(session, kinds=others):
        if event.stream.kind == "attitude":
            builder.add_tracker(event.t, event.values)
        elif event.stream.kind == "accel":
            builder.add_accel(event.t, event.values)
    gyro = session.stream("gyro")
    builder.add_gyro_block(gyro.t, gyro.values)


def _with_latency(session: Session, model: HeadModel) -> Session:
    """Apply the model's assumed tracker latency (if set) to the replay."""
    if model.tracker_latency_s is None:
        return session
    streams = dict(session.streams)
    for name, stream in streams.items():
        if stream.kind == "attitude":
            streams[name] = replace(stream, latency_s=model.tracker_latency_s)
    return replace(session, streams=streams)


@dataclass(frozen=True)
class AttitudeNow:
    """The online estimate at one instant."""

    t: float
    """Time of the newest gyro sample, seconds."""
    world_R_head: gtsam.Rot3
    """Attitude at that instant (tracker latency cancelled by the gyro)."""
    cov: FloatArray
    """Covariance of the attitude (right perturbation, rad^2)."""

    @property
    def quat_wxyz(self) -> FloatArray:
        return quat_wxyz_from_rot3(self.world_R_head)


class RejectedSampleError(ValueError):
    """A live sample the tracker refused (not finite, implausible, out of time order); its state is unchanged."""


#: Largest plausible angular rate, rad/s (a 2000 deg/s full scale; the gyro catalogue entry's bound).
MAX_RATE_RAD_S = 35.0
#: Largest departure of a tracker quaternion's norm from 1 that is taken as rounding (then normalised).
QUAT_NORM_TOLERANCE = 0.01
#: How far (s) a tracker sample's time may lie after the newest gyro sample. Streams interleave unevenly (a
#: tracker sample may overtake a few gyro samples in transit) but a second ahead is another clock.
FUTURE_TOLERANCE_S = 1.0
#: Chi-square (3 dof) above which a tracker sample's difference from the estimate carried back to its time is an outlier:
#: the 99.99 % point, so a sample of the declared noise is refused once in 10,000.
GATE_CHI2 = 21.1
#: After this many refused tracker samples in a row the next one is taken whatever it says (the estimate, not the
#: tracker, may be what went wrong: the gate must not lock the tracker out for good).
GATE_MAX_RUN = 25
#: ...and only a sample at least this far from the estimate is refused, degrees: the estimate's own covariance is
#: optimistic while the graph settles (a live start refused a sample 2.2 deg off at chi-square 26); 10 deg is over 5x a
#: realistic tracker's error (white 0.4 plus a 0.7 deg Gauss-Markov term per axis) and far below a glitch's.
GATE_MIN_DEG = 10.0


def gyro_delay_s(session: Session) -> float:
    """The delay the session's gyro declares (``delay_s``, 0 when it declares none), seconds."""
    return float(session.stream("gyro").meta.get("delay_s", 0.0))


def honours_gyro_delay(run: Callable[Concatenate[Session, P], Estimate]) -> Callable[Concatenate[Session, P], Estimate]:
    """A head method that runs on the gyro's true timeline when the gyro declares a delay d.

    The samples are re-stamped to t - d (they still arrive at t: the stream's latency grows by d), so every
    sensor meets on one clock; the attitude the method gives for each sample's true time is carried forward over
    d by that sample's rate and reported at the sample's stamp. Online that is a prediction d ahead from the
    newest sample, so the estimate stays causal.
    """

    @functools.wraps(run)
    def on_true_time(session: Session, *args: P.args, **kwargs: P.kwargs) -> Estimate:
        delay = gyro_delay_s(session)
        if delay == 0.0:
            return run(session, *args, **kwargs)
        gyro = session.stream("gyro")
        retimed = replace(gyro, t=gyro.t - delay, latency_s=gyro.latency_s + delay, meta={**gyro.meta, "delay_s": 0.0})
        estimate = run(replace(session, streams={**session.streams, "gyro": retimed}), *args, **kwargs)
        quats = carried_over_delay(estimate.quat_wxyz, rates_at(retimed.t, gyro.values, estimate.t), delay)
        out_t = gyro.t.copy() if len(estimate.t) == len(gyro.t) else estimate.t + delay  # keyframes inside a dropout too
        return replace(estimate, t=out_t, quat_wxyz=quats, extras={**estimate.extras, "gyro_delay_s": delay})

    return on_true_time


def carried_over_delay(quat_wxyz: FloatArray, rate_rad_s: FloatArray, delay_s: float) -> FloatArray:
    """Attitudes at a sample's true time carried to its stamp, ``delay_s`` later, by its body rate (one or (N, 4))."""
    return quat_normalize(quat_multiply(quat_wxyz, quat_from_rotvec(np.asarray(rate_rad_s, dtype=float) * delay_s)))


#: The head tracker's online solver: iSAM2 once per 40 ms keyframe (``HeadModel.keyframe_period_s``; a tracker sample that
#: arrives between keyframes waits for the next, at most 20 ms), old keyframes marginalised in place every 10 keyframes.
#: On seeds 100-109 (120 s) the 40 ms keyframes gave the RMS of 20 ms ones (realistic 0.5851 / 0.5214 / 0.5024 against
#: 0.5852 / 0.5214 / 0.5019 deg; ideal 0.1373 / 0.1337 / 0.1401 against 0.1373 / 0.1337 / 0.1400). Seeds 100-119 (60 s,
#: mean RMS deg, speed): an update at every tracker sample, rebuilt every 50 keyframes, realistic 0.5845 / 0.5615 /
#: 0.5746 at 36.6x real time, ideal 0.1363 / 0.1385 / 0.1416 at 62.8x; once per keyframe 0.5858 / 0.5629 / 0.5756 at
#: 47.8x, ideal 0.1372 / 0.1395 / 0.1425 at 80.2x (+0.2 % realistic, +0.6 % ideal, the largest seed +0.7 % / +1.1 %); in
#: place every 2 / 5 / 10 / 25 keyframes 53.0 / 54.4 / 55.1 / 50.7x at 0.5872 / 0.5634 / 0.5760 (every 10; the others
#: within 0.0007 deg), ideal 84.1x, RMS unchanged to 0.0001 deg. Every second keyframe: +0.7-1.3 % (seeds 100-102).
HEAD_ONLINE = OnlineConfig(reanchor_every=10, update_every=1)


def _chi_square3(cov: FloatArray, added_variance: float, error: FloatArray) -> float:
    """e^T (cov + added_variance I)^-1 e for a 3x3 symmetric ``cov``, by the adjugate in Python floats (numpy's solve of
    a 3x3 costs ~10 us, 4 % of the online head's time at every tracker sample)."""
    (a, b, c), (_, d, e), (_, _, f) = cov.tolist()
    a, d, f = a + added_variance, d + added_variance, f + added_variance
    x, y, z = error.tolist()
    # the adjugate of [[a b c] [b d e] [c e f]]
    A, B, C = d * f - e * e, c * e - b * f, b * e - c * d
    D, E, F = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * A + b * B + c * C
    return (x * (A * x + B * y + C * z) + y * (B * x + D * y + E * z) + z * (C * x + E * y + F * z)) / det


class OnlineHeadTracker:
    """Live use: push samples as they arrive, read the causal estimate after each gyro sample.

    >>> tracker = OnlineHeadTracker(HeadModel())
    >>> tracker.add_tracker(t_sample, quat_wxyz)   # whenever a (late) tracker sample arrives
    >>> now = tracker.add_gyro(t, omega)          # AttitudeNow, or None before the first fix

    Every sample is checked before it touches the graph: a non-finite value, a rate above 35 rad/s, a
    quaternion whose norm is not 1 (within 1 %), a gyro time that does not increase or a tracker
    sample from after the newest gyro sample raises ``RejectedSampleError`` naming the problem, and the
    tracker carries on as if the sample had not come (``rejected`` counts them). One bad sample can
    no longer break every later update. With ``gate`` (default) a tracker sample from before the data or older than
    the online window, or one more than ``GATE_MIN_DEG`` and chi-square ``GATE_CHI2`` from the estimate carried back to
    its time by the gyro, is refused too (``gated``); after ``GATE_MAX_RUN`` refusals in a row the next is taken.

    ``estimate_first``: ``add_gyro`` returns the gyro's prediction from the last solved keyframe and the iSAM2
    update that sample makes due runs in ``maintain()`` (after the caller published it), so no sample waits for an
    update; the update's result counts from the next sample on. What that costs, measured on seeds 100-109 (30 s):
    RMS +0.3 % per axis (realistic profile), +0.7-0.8 % (ideal).
    """

    def __init__(self, model: HeadModel | None = None, config: OnlineConfig | None = None, estimate_first: bool = False,
                 gate: bool = True):
        self.estimate_first = estimate_first
        self.gate = gate
        """Refuse a tracker sample whose difference from the estimate carried back to its time exceeds ``GATE_CHI2``
        (the estimate's covariance plus the tracker's declared noise), or that is older than the online window."""
        self.gated = 0
        """Tracker samples refused by the gate so far (also counted in ``rejected``)."""
        self._gated_run = 0
        self._recent = RecentGyro()
        self._first_gyro_t = math.nan
        """Run a due iSAM2 update in ``maintain()``, after the estimate is out (see above)."""
        self._update_due = False
        self.model = model or HeadModel()
        cfg = config or HEAD_ONLINE
        if self.model.tracker_latency_s is not None and cfg.window_s <= self.model.tracker_latency_s + self.model.keyframe_period_s:
            raise ValueError(f"online window_s = {cfg.window_s} s must exceed the tracker latency ({self.model.tracker_latency_s} s) plus one keyframe")
        self.builder = HeadGraphBuilder(self.model)
        self.solver = OnlineSmoother(self.builder, cfg)
        self.solver.defer_reanchor = True  # see maintain()
        self.rejected = 0
        """Samples refused so far."""
        self._last_gyro_t = -np.inf

    def _reject(self, message: str) -> RejectedSampleError:
        self.rejected += 1
        return RejectedSampleError(message)

    def _vector(self, what: str, t: float, values: FloatArray, size: int) -> FloatArray:
        v = np.asarray(values, dtype=float).reshape(-1)
        # math.isfinite on the sum: any NaN or inf makes it non-finite (np.all(np.isfinite) cost 5 % of the loop, and
        # numpy's own sum of three numbers is slower than Python's of the list)
        if v.shape != (size,) or not math.isfinite(sum(v.tolist())) or not math.isfinite(t):
            raise self._reject(f"{what} at t = {t!r}: need {size} finite values, got {np.asarray(values).tolist()!r}")
        return v

    def add_tracker(self, t_sample: float, quat_wxyz: FloatArray) -> None:
        """A tracker sample taken at ``t_sample`` has arrived (now, possibly much later)."""
        q = self._vector("tracker sample", t_sample, quat_wxyz, 4)
        norm = math.sqrt(float(q.dot(q)))  # np.linalg.norm costs ~8 us on a 4-vector
        if abs(norm - 1.0) > QUAT_NORM_TOLERANCE:
            raise self._reject(f"tracker sample at t = {t_sample:.6f} s: quaternion norm {norm:.4g} is not 1 (scaled or not a quaternion?)")
        if t_sample > self._last_gyro_t + FUTURE_TOLERANCE_S and np.isfinite(self._last_gyro_t):
            raise self._reject(f"tracker sample at t = {t_sample:.6f} s is after the newest gyro sample ({self._last_gyro_t:.6f} s): "
                               "its clock is not the gyro's (offset or units?)")
        if self.gate:
            self._gate(float(t_sample), q / norm)
        self.builder.add_tracker(float(t_sample), q / norm)

    def _gate(self, t_sample: float, quat_wxyz: FloatArray) -> None:
        """Raise (counted in ``gated``) for a sample from before the data or the online window, or one whose difference
        from the estimate carried back to its time by the recent gyro exceeds ``GATE_CHI2``."""
        window = self.solver.config.window_s
        if math.isfinite(self._first_gyro_t) and (t_sample < self._first_gyro_t - FUTURE_TOLERANCE_S or t_sample < self._last_gyro_t - window):
            self.gated += 1
            raise self._reject(f"tracker sample at t = {t_sample:.6f} s: older than the online window (newest gyro "
                               f"{self._last_gyro_t:.6f} s, window {window:g} s): its clock is not the gyro's?")
        back = self._recent.since(t_sample)  # the body's rotation from t_sample to now, by the gyro samples in between
        if self.solver.latest_rot is None or not self.builder.started or back is None:
            return  # no estimate yet (``latest``), or nothing to carry it back by
        error = gtsam.Rot3.Logmap(self.builder.predict_now()[1].compose(back.inverse()).between(rot3_from_quat_wxyz(quat_wxyz)))
        # the covariance and chi-square only for a sample far enough to be refused (``GATE_MIN_DEG``): ~3 % of the online
        # head's time on BROAD's motion went to them at every tracker sample
        far = float(error.dot(error)) > math.radians(GATE_MIN_DEG) ** 2 and self._gated_run < GATE_MAX_RUN
        if far and (chi2 := _chi_square3(self.builder.predict_cov(self.solver.latest_cov, self.solver.latest_bias_cov),
                                         self.model.tracker.total_sigma_rad**2, error)) > GATE_CHI2:
            self._gated_run += 1
            self.gated += 1
            raise self._reject(f"tracker sample at t = {t_sample:.6f} s: {np.rad2deg(np.linalg.norm(error)):.1f} deg from the estimate "
                               f"(chi-square {chi2:.0f} > {GATE_CHI2:g}): an outlier, not used")
        self._gated_run = 0

    def add_accel(self, t_sample: float, accel_m_s2: FloatArray) -> None:
        """An accelerometer sample (m/s^2, head frame): gravity holds elevation and roll, e.g. while the tracker is out."""
        a = self._vector("accelerometer sample", t_sample, accel_m_s2, 3)
        self.builder.add_accel(float(t_sample), a)

    def add_gyro(self, t: float, omega: FloatArray, estimate: bool = True) -> AttitudeNow | None:
        """A gyro sample at ``t`` (rad/s): update and return the estimate at ``t`` (None without ``estimate``: a replay's
        ``OnlinePredictions`` computes them all at its end)."""
        w = self._vector("gyro sample", t, omega, 3)
        if float(w.dot(w)) > MAX_RATE_RAD_S**2:
            raise self._reject(f"gyro sample at t = {t:.6f} s: |omega| = {np.linalg.norm(w):.4g} rad/s is above {MAX_RATE_RAD_S:g} (deg/s?)")
        if t <= self._last_gyro_t:
            raise self._reject(f"gyro sample at t = {t:.6f} s does not follow the previous one ({self._last_gyro_t:.6f} s)")
        return self._checked_gyro(float(t), w, estimate)

    def _checked_gyro(self, t: float, w: FloatArray, estimate: bool) -> AttitudeNow | None:
        """``add_gyro`` after its checks (a replay whose whole stream passed them, ``gyro_stream_passes``, comes here)."""
        self.builder.add_gyro(t, w)
        self._last_gyro_t = t
        if self.gate:  # the last second of gyro, to carry the estimate back to a late tracker sample's time
            if not math.isfinite(self._first_gyro_t):
                self._first_gyro_t = t
            self._recent.append(t, w)
        if self.estimate_first:
            if self._update_due:  # maintain() was not called after the previous sample: run its update now, not never
                self.solver.update()
            self._update_due = True
        else:
            self.solver.update()
        return self.latest() if estimate else None

    def maintain(self) -> None:
        """Housekeeping once the estimate is out: a due re-anchoring of the online solver (~7 ms every 2 s of
        head data), so that it is not part of any sample's latency, and with ``estimate_first`` the update itself.
        Without this call the next update runs the re-anchoring."""
        if self._update_due:
            self._update_due = False
            self.solver.update()
        self.solver.maintain()

    def latency(self) -> tuple[float, float] | None:
        """Current estimate of the tracker latency and its sigma, seconds (None when it is not estimated)."""
        key, prior = self.builder.latency_key(), self.model.latency
        if key is None or prior is None:
            return None
        delta = float(self.solver.isam.calculateEstimateVector(key)[0])
        sigma = float(np.sqrt(self.solver.isam.marginalCovariance(key)[0, 0]))
        return prior.assumed_s + delta, sigma

    def latest(self) -> AttitudeNow | None:
        """The causal estimate at the newest gyro sample, None before the first tracker fix."""
        if self.solver.latest_rot is None or not self.builder.started:
            return None
        t, rot = self.builder.predict_now()
        return AttitudeNow(t, rot, self.builder.predict_cov(self.solver.latest_cov, self.solver.latest_bias_cov))


def gyro_stream_passes(t: FloatArray, omega: FloatArray) -> bool:
    """Whether every gyro sample (float64, in the order given) passes ``OnlineHeadTracker.add_gyro``'s checks: a replay of
    such a stream skips them per sample (5 % of the online head's time on BROAD's motion); another meets them sample by
    sample, its first refused one raising as it would live."""
    return (omega.dtype == np.float64 and omega.ndim == 2 and omega.shape[1] == 3 and bool(np.isfinite(t).all() and np.isfinite(omega).all())
            and bool((np.einsum("ij,ij->i", omega, omega) <= MAX_RATE_RAD_S**2).all() and (np.diff(t) > 0).all()))


@honours_gyro_delay
def run_isam2(session: Session, model: HeadModel | None = None, config: OnlineConfig | None = None, estimate_first: bool = False) -> Estimate:
    """fusegraph online: replay in arrival order through ``OnlineHeadTracker``; causal estimate per gyro sample
    (``estimate_first``: see ``OnlineHeadTracker``), the live one at each, computed at the end (``OnlinePredictions``:
    ``extras["wall_s"]`` leaves that out)."""
    model = head_model_for(session, model)
    gyro = session.stream("gyro")
    max_latency = max((s.latency_s for s in session.streams_of_kind("attitude")), default=0.0)
    if model.latency is not None:
        max_latency += 3.0 * model.latency.sigma_s  # the true latency may be this much longer
    cfg = config or HEAD_ONLINE
    if cfg.window_s <= max_latency + model.keyframe_period_s:
        raise ValueError(f"online window_s = {cfg.window_s} s must exceed the largest tracker latency ({max_latency:.3f} s) plus one keyframe")
    wall = np.zeros(len(gyro))
    live = OnlineHeadTracker(model, cfg, estimate_first)
    predictions = OnlinePredictions()
    # the gyro in the order the replay pushes it (by arrival, then index): checked at once when it all passes; what was pushed
    order = np.argsort(np.round(gyro.arrival_t * 1e6).astype(np.int64), kind="stable")
    pushed_t, pushed = gyro.t[order], gyro.values[order]
    push = live._checked_gyro if gyro_stream_passes(pushed_t, pushed) else live.add_gyro
    i = 0
    start = time.perf_counter()
    for event in replay_in_arrival_order(_with_latency(session, model), last_streams=("gyro",), kinds=USED_KINDS):
        kind = event.stream.kind
        if kind == "attitude":
            with contextlib.suppress(RejectedSampleError):  # the gate's outliers (counted in extras); the session was checked already
                live.add_tracker(event.t, event.values)
        elif kind == "accel":
            live.add_accel(event.t, event.values)
        elif kind == "gyro":
            push(event.t, event.values, False)
            predictions.note(i, live.builder, live.solver.latest_cov, live.solver.latest_bias_cov, live.solver.latest_rot is not None)
            wall[i] = time.perf_counter()
            live.maintain()  # as the live loop does after publishing (its time is in the next sample's wall)
            i += 1
    quats, covs = predictions.fill(pushed_t, pushed, live.builder.model.gyro.density**2)
    runtime = time.perf_counter() - start
    latency_estimate = live.latency()
    extras = {
        "latency_s": None if latency_estimate is None else latency_estimate[0],
        "latency_sigma_s": None if latency_estimate is None else latency_estimate[1],
        "reanchors": live.solver.reanchors,
        "in_place": live.solver.in_place_marginalisations,
        "too_late": len(live.builder.too_late),
        "tracker_used": live.builder.tracker_used,
        "tracker_gated": live.gated,
        "bias_final": live.solver.latest_bias.tolist(),
        "wall_s": wall - start,
    }
    return Estimate("isam2", gyro.t.copy(), quats, covs, runtime, extras)


@honours_gyro_delay
def run_batch(session: Session, model: HeadModel | None = None, config: BatchConfig | None = None) -> Estimate:
    """fusegraph batch: the same factors as online, optimised together; smoothed attitude per gyro sample."""
    model = head_model_for(session, model)
    gyro = session.stream("gyro")
    start = time.perf_counter()
    # with an estimated latency: a first pass finds it, a second places the readings with it so that
    # the first-order offset model only covers the remainder (as online, where it is the running estimate)
    applied = 0.0
    bias = gyro_bias_from_tracker(session)
    dead_reckoned = corrected_dead_reckoning(session, bias)  # shared by both passes
    for _ in range(2 if model.latency is not None else 1):
        builder = HeadGraphBuilder(model, initial_bias=bias)
        builder.latency_applied_s = applied
        feed_recorded(builder, _with_latency(session, model))
        increment = builder.take()
        n_kf = len(builder.keyframe_t)
        kf_t = np.asarray(builder.keyframe_t)
        for k, quat in enumerate(tracker_seeded_initial(session, kf_t, applied, dead_reckoned)):
            increment.values.update(j=X(k), rot3=rot3_from_quat_wxyz(quat))  # by keyword: no search of the ~46 overloads
        latency_key = builder.latency_key()
        marginal_keys = [X(k) for k in range(n_kf)] + ([latency_key] if latency_key is not None else [])
        result = solve_batch(increment.graph(), increment.values, marginal_keys, config, ordering=time_ordering(increment.values.keys()))
        if latency_key is not None:
            applied = float(result.values.atVector(latency_key)[0])
    kf_quat = np.array([quat_wxyz_from_rot3(result.values.atRot3(X(k))) for k in range(n_kf)])
    biases = gtsam.utilities.extractVectors(result.values, "b")  # b(0) .. b(n_kf - 2) in key order, in one call
    kf_bias = np.vstack([biases, biases[-1:]])  # the last keyframe keeps the last interval's
    kf_cov = _hold_covariances(result.covariances, n_kf) if result.covariances else None
    out_t = with_gap_keyframes(gyro.t, kf_t, builder.gaps)
    quats, covs = interpolate_keyframes(out_t, rates_at(gyro.t, gyro.values, out_t), kf_t, kf_quat, kf_bias, kf_cov)
    runtime = time.perf_counter() - start
    extras: dict[str, Any] = {
        "iterations": result.iterations,
        "max_iterations": (config or BatchConfig()).max_iterations,
        "final_error": result.final_error,
        "too_late": len(builder.too_late),
        "bias_final": kf_bias[-1].tolist(),
    }
    if latency_key is not None and model.latency is not None:
        extras["latency_s"] = model.latency.assumed_s + float(result.values.atVector(latency_key)[0])
        cov = result.covariances.get(latency_key)
        extras["latency_sigma_s"] = float(np.sqrt(cov[0, 0])) if cov is not None else None
    return Estimate("batch", out_t.copy(), quats, covs, runtime, extras)


def _hold_covariances(covariances: dict[int, FloatArray], n_kf: int) -> FloatArray:
    """Keyframe covariances where computed, linearly interpolated entry-wise in between.

    The smoother's covariance changes slowly along the trajectory (it follows the sensor
    schedule), so a stride of a few keyframes loses nothing a 3-sigma band can show.
    """
    known = sorted(k for k in range(n_kf) if X(k) in covariances)
    table = np.array([covariances[X(k)] for k in known]).reshape(len(known), 9)
    out = np.empty((n_kf, 9))
    for j in range(9):
        out[:, j] = np.interp(np.arange(n_kf), known, table[:, j])
    return out.reshape(n_kf, 3, 3)


def tracker_seeded_initial(session: Session, times: FloatArray, tracker_shift_s: float = 0.0, dead_reckoned: FloatArray | None = None) -> FloatArray:
    """Initial attitudes for the batch: the nearest tracker sample, carried to each time by the gyro.

    Dead reckoning from the start alone drifts by bias x duration (radians after minutes), which
    cost Levenberg-Marquardt ~100 iterations on 2-minute sessions; re-seeding at the tracker samples
    keeps the initial guess within the tracker's error plus the gyro drift over half a gap. The gyro
    is carried from both ends of a gap (from the sample before in the first half, backwards from the
    one after in the second), with its bias removed as the tracker shows it (``gyro_bias_from_tracker``):
    a 60 s dropout with a raw 0.05 rad/s bias carried across put the guess radians off and LM into a
    wrong minimum (batch 95 deg mid-gap, the online estimate 2 deg).
    ``tracker_shift_s`` is subtracted from the tracker stamps (a latency correction); ``dead_reckoned``
    (the bias-corrected gyro integrated from identity at every sample) may be passed in when it is known.
    """
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    if dead_reckoned is None:
        dead_reckoned = corrected_dead_reckoning(session)
    stamps = tracker.t - tracker_shift_s
    before = np.clip(np.searchsorted(stamps, times + 1e-9, side="right") - 1, 0, len(tracker) - 1)
    after = np.clip(before + 1, 0, len(tracker) - 1)
    use_after = (stamps[after] - times) < (times - stamps[before])
    j = np.where(use_after, after, before)
    at_fix = np.clip(np.searchsorted(gyro.t, stamps[j] - 1e-9), 0, len(gyro) - 1)
    at_time = np.clip(np.searchsorted(gyro.t, times - 1e-9), 0, len(gyro) - 1)
    since_fix = quat_multiply(quat_conjugate(dead_reckoned[at_fix]), dead_reckoned[at_time])
    return quat_normalize(quat_multiply(tracker.values[j], since_fix))


def corrected_dead_reckoning(session: Session, bias: FloatArray | None = None) -> FloatArray:
    """The gyro integrated from identity at every sample, less the bias the tracker shows (``bias`` when it is known)."""
    gyro = session.stream("gyro")
    bias = gyro_bias_from_tracker(session) if bias is None else bias
    return integrate_gyro(gyro.t, gyro.values, np.array([1.0, 0.0, 0.0, 0.0]), bias=bias)


def run_tracker_only(session: Session) -> Estimate:
    """What the tracker alone gives at each gyro instant: its latest ARRIVED sample (latency included)."""
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    start = time.perf_counter()
    last = np.searchsorted(tracker.arrival_t, gyro.t + 1e-9, side="right") - 1
    quats = np.full((len(gyro), 4), np.nan)
    quats[last >= 0] = tracker.values[last[last >= 0]]
    have = np.all(np.isfinite(quats), axis=1)
    quats[have] = quat_normalize(quats[have])
    return Estimate("tracker", gyro.t.copy(), quats, None, time.perf_counter() - start)


@honours_gyro_delay
def run_gyro_only(session: Session) -> Estimate:
    """Dead reckoning: integrate the raw gyro from the first tracker fix, from when that fix arrived."""
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    start = time.perf_counter()
    i0 = int(np.argmin(np.abs(gyro.t - tracker.t[0])))
    quats = np.full((len(gyro), 4), np.nan)
    quats[i0:] = integrate_gyro(gyro.t[i0:], gyro.values[i0:], tracker.values[0])
    quats[gyro.t < tracker.arrival_t[0] - 1e-9] = np.nan  # nothing to start from before the fix arrives
    return Estimate("gyro", gyro.t.copy(), quats, None, time.perf_counter() - start)


#: The paper's EKFs, each with its noise figures chosen by its own study on seeds 100-119 (``fusegraph tune head_ekf``,
#: ``head_ekf_method1``, ``head_ekf_kalman``; the values and scores are in ``fusegraph/tuned.toml``). The paper fitted its
#: figures to its hardware; they stay as the ``*_paper_values`` rows.
TUNED_EKF = ekf_config_from(tuned("head_ekf"))
TUNED_EKF_METHOD1 = ekf_config_from(tuned("head_ekf_method1"))
TUNED_EKF_KALMAN = ekf_config_from(tuned("head_ekf_kalman"))


@honours_gyro_delay
def run_ekf(session: Session, mode: str, config: HeadEkfConfig | None = None) -> Estimate:
    """One of the paper's EKFs (``kalman``, ``method1``, ``method2``) over the session, each with its own noise
    figures chosen on the tuning seeds unless ``config`` is given (the paper's: ``HeadEkfConfig()``)."""
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    # the filter's H = (I, -d F') uses the latency the session declares (true, or only assumed)
    default = {"method2": TUNED_EKF, "method1": TUNED_EKF_METHOD1, "kalman": TUNED_EKF_KALMAN}.get(mode, HeadEkfConfig())
    cfg = replace(config or default, tracker_latency_s=tracker.latency_s)
    load_compiled()  # outside the timed run: numba's import and the loading of its machine code are not the filter's time
    start = time.perf_counter()
    quats, covs = run_head_ekf(mode, gyro.t, gyro.values, tracker.t, tracker.values, cfg, latency_s=tracker.latency_s)  # type: ignore[arg-type]
    return Estimate(mode, gyro.t.copy(), quats, covs, time.perf_counter() - start)


EULER_FILTERS = ("kalman", "method1", "method2", "method1_paper_values", "method2_paper_values")
"""The paper's filters, whose state is ZYX Euler angles (singular at +-90 deg elevation)."""


def run_method(session: Session, method: str, model: HeadModel | None = None) -> Estimate:
    """Any method of ``METHODS`` by name (the paper's EKFs with the figures the session declares in ``[ekf]``)."""
    if method == "tracker":
        return run_tracker_only(session)
    if method == "gyro":
        return run_gyro_only(session)
    if method in ("kalman", "method1", "method2"):
        return run_ekf(session, method, declared_ekf(session))
    if method in ("method1_paper_values", "method2_paper_values"):
        return replace(run_ekf(session, method.removesuffix("_paper_values"), HeadEkfConfig()), method=method)
    if method == "isam2":
        return run_isam2(session, model)
    if method == "batch":
        return run_batch(session, model)
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")


# ------------------------------------------------------------------------------ without a gyro


