"""Head tracking graph: gyro preintegration between keyframes + late tracker attitudes at their sample times.

Variables per keyframe k (one every ``keyframe_period_s``, placed on gyro samples):
``x(k)`` world_R_head (Rot3), ``b(k)`` the effective gyro bias of the interval from k to k+1
(Vector3; see ``factors.gyro``), one ``c`` (9) for the gyro's scale/misalignment; per tracker sample
at keyframe k, with the Gauss-Markov tracker model: ``e(k)`` tracker error (Vector3, AR(1) chain)
and ``t(k)`` the reading without white noise (Rot3).

Measurements are pushed in ARRIVAL order; a tracker sample attaches to the keyframe at its SAMPLE
time (nearest keyframe, corrected by the gyro rate for any offset), which the gyro created up to
``latency`` seconds earlier. The same builder feeds the online and the batch solver.
"""

from __future__ import annotations

import bisect
import math
import warnings
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from ..factors.accel import GravityNoise, declared_gravity, gravity_factor_rot3
from ..factors.attitude import (
    AttitudeNoise,
    attitude_prior_factor,
    error_state_factor,
    gauss_markov_factor,
    markov_prior_factor,
)
from ..factors.gyro import (
    GapInterval,
    GyroCalibrationPrior,
    GyroInterval,
    GyroNoise,
    IntegratedInterval,
    bias_prior_factor,
    bias_walk_factor,
    calibrated_bias_prior_factor,
    calibrated_bias_walk_factor,
    calibration_prior_factor,
    gap_limit_s,
    integrate_intervals,
    preintegration_params,
)
from ..factors.latency import (
    LatencyPrior,
    apparent_markov_factor,
    apparent_markov_prior_factor,
    apparent_white_factor,
    offset_prior_factor,
    offset_walk_factor,
)
from ..factors.linear import zeros
from ..geometry import FloatArray, quat_from_rotvec, quat_multiply, quat_normalize, quat_wxyz_from_rot3, rot3_from_quat_wxyz
from ..session import Session, SessionWarning
from .increment import GraphIncrement
from .ordering import SYMBOL_INDEX_BITS, SYMBOL_INDEX_MASK, nested_dissection


def X(k: int) -> int:
    """Key of world_R_head at keyframe k."""
    return int(gtsam.symbol("x", k))


def B(k: int) -> int:
    """Key of the gyro bias at keyframe k."""
    return int(gtsam.symbol("b", k))


def E(k: int) -> int:
    """Key of the tracker's slowly varying error at keyframe k."""
    return int(gtsam.symbol("e", k))


def D(j: int = 0) -> int:
    """Key of the tracker's latency error delta = true - assumed latency, seconds (one number), segment j."""
    return int(gtsam.symbol("d", j))


#: Length of one segment of a drifting latency (one variable per segment), seconds.
LATENCY_SEGMENT_S = 1.0

C = int(gtsam.symbol("c", 0))
"""Key of the gyro calibration c (K flattened row by row: scale factors and misalignment)."""


def T(k: int) -> int:
    """Key of the tracker reading (without white noise) at keyframe k."""
    return int(gtsam.symbol("t", k))


@dataclass(frozen=True)
class HeadModel:
    """How the head graph models its sensors (one parameter set for every session)."""

    keyframe_period_s: float = 0.04
    """Time between keyframes, seconds; a tracker sample between two is carried to the nearer one by the gyro samples
    between them. Chosen on seeds 100-109 (120 s, both profiles) as the longest period whose online and batch RMS stay
    within 0.5 % of 20 ms keyframes (iSAM2 at each) on every axis: 20 / 40 / 60 / 80 ms, batch azimuth RMS (ideal)
    0.0789 / 0.0791 / 0.0794 / 0.0798 deg (+0.6 % at 60 ms), realistic 0.3340 / 0.3333 / 0.3334 / 0.3329 deg; batch 36 /
    63 / 88 / 108 x real time (realistic; at 60 and 80 ms measured with every reading carried forward from the keyframe
    before it, at 40 ms the same as the nearer one's). Online at 40 ms (iSAM2 at every keyframe): realistic 0.5851 /
    0.5214 / 0.5024 deg against 0.5852 / 0.5214 / 0.5019."""
    gyro: GyroNoise = field(default_factory=GyroNoise)
    """Gyro noise and bias model."""
    tracker: AttitudeNoise = field(default_factory=AttitudeNoise)
    """Tracker error model; ``markov_sigma_deg = 0`` gives plain white-noise priors."""
    tracker_latency_s: float | None = None
    """Tracker delay, seconds; None takes the stream's ``latency_s`` from the session."""
    gyro_calibration: GyroCalibrationPrior | None = field(default_factory=GyroCalibrationPrior)
    """Estimate the gyro's scale factors and misalignment as variables (None: assume a perfect gyro)."""
    latency: LatencyPrior | None = None
    """Estimate the tracker latency as a variable around this prior (None: the stamps are exact)."""
    snap_tolerance_s: float = 5e-4
    """A tracker sample this close to a keyframe attaches to it without gyro correction, seconds."""
    gravity: GravityNoise = field(default_factory=GravityNoise)
    """Accelerometer gravity-direction noise, used when the session has an ``accel`` stream."""


class HeadGraphBuilder:
    """Turns gyro and tracker samples, pushed in arrival order, into factors and initial values."""

    def __init__(self, model: HeadModel | None = None, initial_bias: FloatArray | None = None):
        """``initial_bias``: the gyro bias (rad/s) to integrate with until a solver feeds back its estimate (``set_latest``):
        the batch, which has no running estimate, passes the tracker's (``frontends.head_timing.gyro_bias_from_tracker``), so that a
        reading between keyframes is carried to its keyframe without the bias's drift and the intervals are linearised there."""
        self.model = model or HeadModel()
        self._params = preintegration_params(self.model.gyro)
        self._density_sq = self.model.gyro.density**2
        # a keyframe closes on the gyro sample nearest its period: stamps jitter (a live clock's correction, a
        # logger's rounding) by microseconds, and a sample 5 us early must not push the keyframe one sample on
        self._close_after_s = self.model.keyframe_period_s - 0.5 / self.model.gyro.sample_rate_hz
        self._pending = GraphIncrement()
        self._gyro_buffer: list[tuple[float, FloatArray]] = []
        # deques: a whole session's samples may wait here (``add_gyro_block`` attaches them at its end)
        self._tracker_waiting: deque[tuple[float, FloatArray]] = deque()
        self._accel_waiting: deque[tuple[float, FloatArray]] = deque()
        self._accel_keyframe = -1
        self.accel_used = 0
        """Accelerometer samples turned into gravity factors (one per keyframe, the one nearest it)."""
        self.keyframe_t: list[float] = []
        """Time of every keyframe so far, seconds."""
        self._keyframe_omega: dict[int, FloatArray] = {}  # pruned with the marginalised keyframes
        # per keyframe, (time, rotation from the keyframe, rate) at each gyro sample inside its interval: a tuple per sample
        # pushed one by one, a ``_Samples`` per block a batch pushes
        self._partials: dict[int, list[tuple[float, gtsam.Rot3, FloatArray] | _Samples]] = {}
        # a zero for each bias and tracker-error key, shared by the linear factors on them (``linear_factor``'s at_zero);
        # (keyframe, key) in insertion order, so that online the marginalised ones can go
        self._zero_at = gtsam.Values()
        self._zero_keys: deque[tuple[int, int]] = deque()
        self._interval: GyroInterval | None = None
        self._last_error_kf: int | None = None
        self._latest_rot: gtsam.Rot3 | None = None
        self._latest_bias = np.zeros(3) if initial_bias is None else np.asarray(initial_bias, dtype=float)
        self._previous_rate = np.zeros(3)
        self._solved_keyframe = 0
        self._latency_segment = 0
        self._latency_t0 = 0.0
        self._applied: dict[int, float] = {}
        self.latency_applied_s = 0.0
        """Latency correction (true - assumed, s) applied when placing new tracker samples: the running
        estimate online, a previous pass's in batch."""
        self.oldest_allowed_keyframe = 0
        """Keyframes older than this were marginalised by the online solver; samples for them are too late."""
        self.too_late: list[float] = []
        """Sample times of tracker samples that arrived after their keyframe was marginalised."""
        self.tracker_used = 0
        """Number of tracker samples turned into factors."""
        self.gaps: list[tuple[float, float]] = []
        """Gyro dropouts bridged: (time of the last sample before, length), seconds."""
        self._gap_limit_s = gap_limit_s(self.model.gyro.sample_rate_hz)

    @property
    def linear_keys(self) -> tuple[int, ...]:
        """Variables that appear only in linear factors (the gyro calibration)."""
        keys = (C,) if self.model.gyro_calibration is not None else ()
        return keys + ((D(0),) if self.model.latency is not None else ())

    # ------------------------------------------------------------------ pushing measurements

    @property
    def started(self) -> bool:
        """True once the first tracker sample has anchored the graph."""
        return self._interval is not None

    @property
    def latest_keyframe(self) -> int:
        return len(self.keyframe_t) - 1

    def add_gyro(self, t: float, omega: FloatArray) -> None:
        """A gyro sample (sample time t, rad/s in the head frame)."""
        omega = np.asarray(omega, dtype=float)
        if not self.started:
            self._gyro_buffer.append((t, omega))
            self._try_start()
            return
        assert self._interval is not None
        if t - self._interval.t_last > self._gap_limit_s:
            self._bridge(t, omega)
        else:
            self._interval.add(t, omega)
        if self._interval.elapsed_s >= self._close_after_s:
            self._close_keyframe(self._interval)
            self._interval = GyroInterval(self._params, self._latest_bias, self._interval.t_last, self._interval.omega_last)
        else:
            self._partials.setdefault(self.latest_keyframe, []).append((t, self._interval.delta(), omega))
        self._flush_waiting_tracker()
        if self._accel_waiting:
            self._flush_waiting_accel()

    def add_tracker(self, t: float, quat_wxyz: FloatArray) -> None:
        """A tracker attitude sample taken at time t (it may arrive much later)."""
        self._tracker_waiting.append((t, np.asarray(quat_wxyz, dtype=float)))
        if not self.started:
            self._try_start()
        else:
            self._flush_waiting_tracker()

    def add_accel(self, t: float, accel_m_s2: FloatArray) -> None:
        """An accelerometer sample (sample time t, m/s^2 in the head frame): gravity holds elevation and roll.

        One gravity factor per keyframe, from the sample nearest the keyframe (within a quarter of a
        keyframe period): consecutive samples share the head's sway, so more would not add much
        information while every factor costs an update.
        """
        self._accel_waiting.append((t, np.asarray(accel_m_s2, dtype=float)))
        if self.started:
            self._flush_waiting_accel()

    def _flush_waiting_accel(self) -> None:
        window = 0.25 * self.model.keyframe_period_s
        while self._accel_waiting and self._accel_waiting[0][0] <= self.keyframe_t[-1] + window:
            t, accel = self._accel_waiting.popleft()
            i = bisect.bisect_left(self.keyframe_t, t - window)
            if i >= len(self.keyframe_t) or abs(self.keyframe_t[i] - t) > window or i <= self._accel_keyframe or i < self.oldest_allowed_keyframe:
                continue  # between keyframes (by design, see add_accel), or its keyframe is gone
            self._pending.add(i, gravity_factor_rot3(X(i), accel, self.model.gravity))
            self._accel_keyframe = i
            self.accel_used += 1

    def set_latest(self, world_R_head: gtsam.Rot3, bias: FloatArray) -> None:
        """Feed back the solver's estimate of the newest keyframe (initial guesses, predictions)."""
        self._latest_rot = world_R_head
        self._latest_bias = np.asarray(bias, dtype=float)
        self._solved_keyframe = self.latest_keyframe

    def feedback(self, vector_estimate: Callable[[int], FloatArray]) -> None:
        """After a solver update: read the estimates the builder uses to place new measurements."""
        key = self.latency_key()
        if key is not None:
            self.latency_applied_s = float(vector_estimate(key)[0])

    def take(self) -> GraphIncrement:
        """Factors and values built since the last call."""
        out, self._pending = self._pending, GraphIncrement()
        return out

    # ------------------------------------------------------------------ predictions

    def predict_now(self) -> tuple[float, gtsam.Rot3]:
        """Attitude at the newest gyro sample: the newest keyframe's estimate carried on by the gyro.

        The newest keyframe's estimate is the solver's, or (between solver updates) the solver's
        last one carried forward over the newer intervals with the estimated bias.
        """
        assert self._interval is not None and self._latest_rot is not None
        return self._interval.t_last, self._latest_rot.compose(self._interval.delta(self._latest_bias))

    def predict_cov(self, cov_kf: FloatArray, cov_bias: FloatArray) -> FloatArray:
        """Covariance of ``predict_now`` (right perturbation): the solved keyframe's, grown since then.

        The time since the solved keyframe is a few keyframe periods, over which the body turns a few
        degrees: too little to rotate the covariance noticeably; gyro noise and bias uncertainty add up.
        """
        assert self._interval is not None
        dt = self._interval.t_last - self.keyframe_t[self._solved_keyframe]
        cov = cov_kf + (dt * dt) * cov_bias
        cov.flat[::4] += dt * self._density_sq  # the diagonal: cheaper than adding a scaled identity
        return cov

    @property
    def now_s(self) -> float:
        """Time of the newest gyro sample integrated."""
        return self._interval.t_last if self._interval else float("nan")

    # ------------------------------------------------------------------ internals

    def _try_start(self) -> None:
        """Anchor keyframe 0 on the gyro sample nearest the first tracker sample."""
        tol = self.model.snap_tolerance_s
        if not self._tracker_waiting or not self._gyro_buffer:
            return
        # a fix stamped before the first gyro sample cannot be placed: counted, not hidden
        while self._tracker_waiting and self._tracker_waiting[0][0] < self._gyro_buffer[0][0] - tol:
            self.too_late.append(self._tracker_waiting.popleft()[0])
        if not self._tracker_waiting:
            return
        t_fix = self._tracker_waiting[0][0]
        if self._gyro_buffer[-1][0] < t_fix - tol:
            return  # gyro has not reached the fix yet (checked on the newest sample: this runs for every gyro sample until then)
        times = np.asarray([t for t, _ in self._gyro_buffer])
        i0 = int(np.argmax(times >= t_fix - tol))  # the first gyro sample at or after the fix
        t0, omega0 = self._gyro_buffer[i0]
        later = self._gyro_buffer[i0 + 1 :]
        self._gyro_buffer = []
        first_fix = rot3_from_quat_wxyz(self._tracker_waiting[0][1])
        self.keyframe_t.append(t0)
        self._keyframe_omega[0] = omega0
        self._latest_rot = first_fix.compose(gtsam.Rot3.Expmap(-omega0 * (t_fix - t0)))
        self._pending.insert(X(0), self._latest_rot)
        if self.model.latency is not None:
            self._pending.insert(D(0), np.zeros(1))
            self._pending.add(0, offset_prior_factor(D(0), self.model.latency))
            self._latency_segment = 0
            self._latency_t0 = t0
        if self.model.gyro_calibration is not None:
            self._pending.insert(C, np.zeros(9))
            self._zero_at.insert(C, np.zeros(9))  # session-wide: never pruned
            self._pending.add(0, calibration_prior_factor(C, self.model.gyro_calibration))
        self._interval = GyroInterval(self._params, self._latest_bias, t0, omega0)
        # tracker samples older than the anchor can never be used: say so, do not drop silently
        while self._tracker_waiting and self._tracker_waiting[0][0] < t0 - self.model.snap_tolerance_s:
            self.too_late.append(self._tracker_waiting.popleft()[0])
        self._flush_waiting_tracker()
        for t, omega in later:
            self.add_gyro(t, omega)

    def add_gyro_block(self, t: FloatArray, omega: FloatArray) -> None:
        """Many gyro samples (times increasing), with the same factors and values as ``add_gyro`` for each one.

        The whole keyframe intervals among them are integrated together (``factors.gyro.integrate_intervals``); samples
        before the graph starts, those of the interval open at the call and the last, unfinished interval go through
        ``add_gyro``. Tracker and accelerometer samples waiting for a keyframe are attached at the end: no solver
        update can come in between, so they are placed as they would have been sample by sample (the batch pushes a
        session's tracker samples first, then its gyro as one block)."""
        t = np.asarray(t, dtype=float)
        omega = np.asarray(omega, dtype=float)
        jumps = np.flatnonzero(np.diff(t) > self._gap_limit_s)
        if len(jumps):  # a dropout inside: the samples before it, the one after it (``add_gyro`` bridges), the rest
            j = int(jumps[0]) + 1
            self.add_gyro_block(t[:j], omega[:j])
            self.add_gyro(float(t[j]), omega[j])
            self.add_gyro_block(t[j + 1 :], omega[j + 1 :])
            return
        if len(t) and self._interval is not None and t[0] - self._interval.t_last > self._gap_limit_s:
            self.add_gyro(float(t[0]), omega[0])  # a dropout before the block
            t, omega = t[1:], omega[1:]
        i = 0
        while i < len(t) and (self._interval is None or self._interval.t_last > self._interval.t_start):
            self.add_gyro(float(t[i]), omega[i])  # until the graph has started and the open interval has closed
            i += 1
        if i < len(t):
            assert self._interval is not None
            opening = self._interval
            ends = self._interval_ends(t[i:].tolist(), opening.t_start)
            if ends:
                last = i + ends[-1]
                self._close_intervals(opening.t_start, opening.omega_last, t[i : last + 1], omega[i : last + 1], ends)
                i = last + 1
            for j in range(i, len(t)):
                self.add_gyro(float(t[j]), omega[j])
        self._flush_waiting_tracker()
        if self._accel_waiting and self.started:
            self._flush_waiting_accel()

    def _bridge(self, t: float, omega: FloatArray) -> None:
        """A gyro dropout before sample ``t``: the open interval closes at the last sample before it, keyframes every
        period across it are tied by random walks (``GapInterval``: the tracker alone places them), and a new interval
        opens at ``t``."""
        assert self._interval is not None
        if self._interval.elapsed_s > 0:
            self._close_keyframe(self._interval)
        t_before = self._interval.t_last
        self.gaps.append((t_before, t - t_before))
        count = max(1, round((t - t_before) / self.model.keyframe_period_s))
        times = t_before + (t - t_before) * np.arange(count + 1) / count
        times[-1] = t
        for t_start, t_end in zip(times[:-1].tolist(), times[1:].tolist(), strict=True):
            self._close_keyframe(GapInterval(t_start, t_end))
        self._interval = GyroInterval(self._params, self._latest_bias, t, omega)

    def _interval_ends(self, times: list[float], t_keyframe: float) -> list[int]:
        """Indices of the samples that close keyframes, from a keyframe at ``t_keyframe`` on (``add_gyro``'s rule)."""
        ends = []
        for j, t_j in enumerate(times):
            if t_j - t_keyframe >= self._close_after_s:
                ends.append(j)
                t_keyframe = t_j
        return ends

    def _close_intervals(self, t_before: float, omega_before: FloatArray, t: FloatArray, omega: FloatArray, ends: list[int]) -> None:
        """Close the keyframe intervals that end at samples ``ends`` of ``t`` (the first opened at ``t_before``)."""
        bias_hat = self._latest_bias
        integrals = integrate_intervals(self._params.getGyroscopeCovariance(), bias_hat, t_before, omega_before, t, omega, ends)
        after = integrals.rotation_after
        start = 0
        for m, end in enumerate(ends):
            k = self.latest_keyframe
            # the rotations as matrices: a Rot3 is made only for the few a tracker sample is carried by (``_carried``)
            self._partials.setdefault(k, []).append(_Samples(t[start:end], after[start:end], omega[start:end]))
            t_start = t_before if m == 0 else float(t[ends[m - 1]])
            t_last = float(t[end])
            elapsed = t_last - t_start
            rotation = gtsam.Rot3(after[end])
            pim = gtsam.PreintegratedAhrsMeasurements(self._params, bias_hat, float(integrals.delta_t_s[m]), rotation,
                                                      integrals.bias_jacobian[m], integrals.covariance[m])
            mean_rate = integrals.angle_sum[m] / elapsed if elapsed > 0 else omega[end]
            self._close_keyframe(IntegratedInterval(pim, bias_hat, t_start, t_last, omega[end], mean_rate, rotation))
            start = end + 1
        self._interval = GyroInterval(self._params, self._latest_bias, float(t[ends[-1]]), omega[ends[-1]])

    def _close_keyframe(self, interval: GyroInterval | IntegratedInterval | GapInterval) -> None:
        """End interval k: new keyframe k+1, the interval's effective bias b(k) and its links (the caller opens the next)."""
        assert self._latest_rot is not None
        k = self.latest_keyframe
        gyro, calibration = self.model.gyro, self.model.gyro_calibration
        self._pending.add(k, interval.factor(X(k), X(k + 1), B(k)))
        self._pending.insert(B(k), self._latest_bias)
        first: gtsam.NonlinearFactor | None
        link: gtsam.NonlinearFactor | None
        if calibration is None:
            first = bias_prior_factor(B(0), gyro) if k == 0 else None
            link = None if k == 0 else bias_walk_factor(B(k - 1), B(k), interval.elapsed_s, gyro)
        else:
            first = calibrated_bias_prior_factor(B(0), C, interval.mean_rate, gyro) if k == 0 else None
            self._zero(k, B(k))
            link = None if k == 0 else calibrated_bias_walk_factor(B(k - 1), B(k), C, self._previous_rate, interval.mean_rate, interval.elapsed_s,
                                                                   gyro, self._zero_at)
        if first is not None:
            self._pending.add(0, first)
        if link is not None:
            self._pending.add(k - 1, link)
        self._previous_rate = interval.mean_rate
        # the whole interval's rotation closes its partials: a reading just before keyframe k + 1 is carried back with it
        self._partials.setdefault(k, []).append((interval.t_last, interval.delta(), interval.omega_last))
        self._latest_rot = self._latest_rot.compose(interval.delta(self._latest_bias))
        self._pending.insert(X(k + 1), self._latest_rot)
        self.keyframe_t.append(interval.t_last)
        self._keyframe_omega[k + 1] = interval.omega_last
        while self._partials and next(iter(self._partials)) < self.oldest_allowed_keyframe:
            del self._partials[next(iter(self._partials))]  # keys are in keyframe order
        # per-keyframe memory older than the online window goes (keys are in keyframe order); batch keeps all
        for table in (self._applied, self._keyframe_omega):
            while table and next(iter(table)) < self.oldest_allowed_keyframe - 50:
                del table[next(iter(table))]
        while self._zero_keys and self._zero_keys[0][0] < self.oldest_allowed_keyframe - 50:
            self._zero_at.erase(self._zero_keys.popleft()[1])

    def _zero(self, k: int, key: int) -> None:
        """Keyframe k's 3-vector ``key`` enters the shared zeros of the linear factors."""
        self._zero_at.insert(key, zeros(3))
        self._zero_keys.append((k, key))

    def state_keys(self, k: int) -> tuple[int, int | None]:
        """Keys of keyframe k's attitude and of the newest effective gyro bias known at k."""
        return X(k), (B(k - 1) if k >= 1 else None)

    @staticmethod
    def keyframe_of(key: int) -> int | None:
        """The keyframe of a variable; None for the gyro calibration and the latency segments, which span many (the
        online solver eliminates in time order with this: ``OnlineSmoother._time_order``)."""
        return key & SYMBOL_INDEX_MASK if _RANK_OF_CHR[key >> SYMBOL_INDEX_BITS] >= 0 else None  # the split ``time_ordering`` makes

    def _flush_waiting_tracker(self) -> None:
        """Attach every waiting tracker sample whose keyframe exists."""
        tol = self.model.snap_tolerance_s
        while self._tracker_waiting and self._tracker_waiting[0][0] - self.latency_applied_s <= self.keyframe_t[-1] + tol:
            t, quat = self._tracker_waiting.popleft()
            self._attach_tracker(t, quat)

    def _attach_tracker(self, t: float, quat_wxyz: FloatArray) -> None:
        # with an estimated latency the reading is placed where the running estimate says it was taken;
        # the factors then model only the remainder (see factors.latency)
        applied = self.latency_applied_s
        t_place = t - applied
        times = self.keyframe_t
        i = bisect.bisect_left(times, t_place)
        # the nearer of the keyframes either side; the earlier one unless the later is nearer by more than the snap
        # tolerance: a reading midway (the 50 Hz tracker against 40 ms keyframes) must not change sides when a live
        # clock's correction moves its stamp by microseconds
        k = i if i == 0 or (i < len(times) and times[i] - t_place < t_place - times[i - 1] - self.model.snap_tolerance_s) else i - 1
        if k < self.oldest_allowed_keyframe or (self._last_error_kf is not None and k < self._last_error_kf):
            self.too_late.append(t)  # its state was marginalised, or it came out of order: counted, not hidden
            return
        measured = rot3_from_quat_wxyz(quat_wxyz)
        if abs(t_place - self.keyframe_t[k]) > self.model.snap_tolerance_s:
            measured = measured.compose(self._gyro_between(k, t_place).inverse())
        noise = self.model.tracker
        self.tracker_used += 1
        if not noise.is_markov and self.model.latency is None:
            self._pending.add(k, attitude_prior_factor(X(k), measured, noise.total_sigma_rad))
            return
        # reading = X(k) * Exp(e): e is the tracker's slowly varying error or, with the latency as a
        # variable, the apparent error g = e - omega * (delta - applied) (see factors.latency)
        white = math.radians(noise.white_sigma_deg)
        self._pending.add(k, attitude_prior_factor(T(k), measured, white))
        if k == self._last_error_kf:
            return  # a second sample on this keyframe: its error state exists already
        self._pending.add(k, error_state_factor(X(k), T(k), E(k)))
        self._pending.insert(T(k), measured)
        self._pending.insert(E(k), zeros(3))
        self._zero(k, E(k))
        restart = self._last_error_kf is None or self._last_error_kf < self.oldest_allowed_keyframe
        markov = math.radians(noise.markov_sigma_deg)
        self._applied[k] = applied
        if self.model.latency is None:
            if restart:
                # first sample, or the previous error state was marginalised during a long dropout:
                # restart the process from its stationary law (what is lost is < e^-(gap/tau) of it)
                self._pending.add(k, markov_prior_factor(E(k), markov))
            else:
                prev = self._last_error_kf
                assert prev is not None
                dt = self.keyframe_t[k] - self.keyframe_t[prev]
                self._pending.add(prev, gauss_markov_factor(E(prev), E(k), dt, markov, noise.markov_tau_s, self._zero_at))
        else:
            offset_key = self._offset_key(k)
            rate = self._keyframe_omega[k] - self._latest_bias
            if not noise.is_markov:
                self._pending.add(k, apparent_white_factor(E(k), offset_key, rate, applied))
            elif restart:
                self._pending.add(k, apparent_markov_prior_factor(E(k), offset_key, rate, applied, markov))
            else:
                prev = self._last_error_kf
                assert prev is not None
                dt = self.keyframe_t[k] - self.keyframe_t[prev]
                rate_prev = self._keyframe_omega[prev] - self._latest_bias
                factor = apparent_markov_factor(E(prev), E(k), offset_key, rate_prev, rate, self._applied[prev], applied, dt, markov, noise.markov_tau_s)
                self._pending.add(prev, factor)
        self._last_error_kf = k

    def latency_key(self) -> int | None:
        """Key of the newest latency variable (None when the latency is not estimated)."""
        return D(self._latency_segment) if self.model.latency is not None and self.started else None

    def _offset_key(self, k: int) -> int:
        """The latency variable of keyframe k: one for the session, or one per segment if it drifts."""
        prior = self.model.latency
        if prior is None or prior.random_walk_s_per_sqrt_s <= 0.0:
            return D(0)
        segment = int((self.keyframe_t[k] - self._latency_t0) // LATENCY_SEGMENT_S)
        while self._latency_segment < segment:
            j = self._latency_segment
            self._pending.insert(D(j + 1), np.zeros(1))
            self._pending.add(k, offset_walk_factor(D(j), D(j + 1), LATENCY_SEGMENT_S, prior))
            self._latency_segment = j + 1
        return D(min(segment, self._latency_segment))

    def _gyro_between(self, k: int, t: float) -> gtsam.Rot3:
        """Rotation of the body from keyframe k to time t, from the gyro (bias as estimated then).

        After keyframe k: the stored preintegration up to the last gyro sample at or before t (within the snap
        tolerance), the rest (less than one gyro period) at that sample's rate. Before it: the same within the
        interval before, composed with that whole interval's inverse. Extrapolating the keyframe's rate instead
        was off by ~0.5 deg over 10 ms at BROAD's fast turns (angular accelerations of ~100 rad/s^2).
        """
        if t < self.keyframe_t[k] and k - 1 in self._partials:
            last = self._partials[k - 1][-1]  # the interval's own rotation, always a tuple with a Rot3 (``_close_keyframe``)
            assert not isinstance(last, _Samples)
            whole = last[1]
            return whole.between(self._carried(k - 1, t))
        return self._carried(k, t)

    def _carried(self, k: int, t: float) -> gtsam.Rot3:
        """Rotation from keyframe k to time t: the gyro samples integrated after k, then the last one's rate."""
        t_from, delta, rate = self.keyframe_t[k], None, self._keyframe_omega[k]
        until = t + self.model.snap_tolerance_s
        for entry in self._partials.get(k, []):
            if isinstance(entry, _Samples):  # a batch's samples: the last at or before ``until``, if any
                j = int(np.searchsorted(entry.t, until, side="right")) - 1
                if j >= 0:
                    t_from, delta, rate = float(entry.t[j]), gtsam.Rot3(entry.rotation[j]), entry.omega[j]
                if j < len(entry.t) - 1:
                    break
                continue
            if entry[0] > until:
                break
            t_from, delta, rate = entry
        if abs(t - t_from) <= self.model.snap_tolerance_s and delta is not None:
            return delta
        rest = gtsam.Rot3.Expmap((rate - self._latest_bias) * (t - t_from))
        return rest if delta is None else delta.compose(rest)


@dataclass(frozen=True)
class _Samples:
    """The gyro samples of a block inside one keyframe interval (``HeadGraphBuilder._close_intervals``), as arrays: a
    tuple of Python objects per sample cost the batch's build and its teardown 4-15 % of a BROAD head trial's time
    (least CPU of 6 runs, old and new interleaved)."""

    t: FloatArray
    """Each sample's time, s (increasing)."""
    rotation: FloatArray
    """The body's rotation from the keyframe to each sample, (N, 3, 3)."""
    omega: FloatArray
    """Each sample's rate, rad/s, (N, 3)."""


#: Elimination rank of each per-keyframe variable within its keyframe (by symbol character); other keys are session-wide.
_RANK = {"t": 0, "e": 1, "b": 2, "x": 3}

_RANK_OF_CHR = np.full(256, -1)
for _tag, _rank in _RANK.items():
    _RANK_OF_CHR[ord(_tag)] = _rank


def carried_by_gyro(t: FloatArray, omega: FloatArray, starts: np.ndarray, bias: FloatArray) -> FloatArray:
    """The rotation (w, x, y, z) from the start of its segment to every sample: segments run from each of ``starts``
    (increasing sample indices) to the next, the last to the end; within one, the midpoints of consecutive rates less its
    ``bias``, each over its sample step (``GyroInterval``'s rule), composed in order. Each sample is its predecessor's
    rotation times one step, for every segment at once (step ``p``: every segment's ``p``-th sample); NaN before the first
    start."""
    q = np.full((len(t), 4), np.nan)
    q[starts] = [1.0, 0.0, 0.0, 0.0]
    lengths = np.diff(np.r_[starts, len(t)])
    for p in range(1, int(lengths.max(initial=1))):
        longer = lengths > p
        j = starts[longer] + p
        rate = 0.5 * (omega[j] + omega[j - 1]) - bias[longer]
        q[j] = quat_multiply(q[j - 1], quat_from_rotvec(rate * (t[j] - t[j - 1])[:, None]))
    return q


def interpolate_keyframes(t: FloatArray, omega: FloatArray, kf_t: FloatArray, kf_quat: FloatArray, kf_bias: FloatArray,
                          kf_cov: FloatArray | None = None) -> tuple[FloatArray, FloatArray | None]:
    """Attitude at every gyro sample: its keyframe's estimate carried forward by the bias-corrected gyro (and the keyframe's
    covariance: the <= one keyframe period of gyro adds ~1e-4 rad, negligible here)."""
    n = len(t)
    quats = np.full((n, 4), np.nan)
    covs = None if kf_cov is None else np.full((n, 3, 3), np.nan)
    kf_index = np.searchsorted(kf_t, t + 1e-9, side="right") - 1
    rows = np.nonzero(kf_index >= 0)[0]
    k = kf_index[rows]
    kf_sample = np.searchsorted(t, np.asarray(kf_t) - 1e-9)  # gyro index of each keyframe
    quats[rows] = quat_normalize(quat_multiply(kf_quat[k], carried_by_gyro(t, omega, kf_sample, kf_bias)[rows]))
    if covs is not None and kf_cov is not None:
        covs[rows] = kf_cov[k]
    return quats, covs


class OnlinePredictions:
    """The online estimate at every gyro sample of a replay, computed at its end in numpy (``fill``) from what ``note``
    records as each sample is pushed: the open interval (its first sample's time and the bias it integrates with) and the
    newest keyframe's state (attitude, bias, the solver's covariances, the solved keyframe's time), each when it changes.
    It is ``HeadGraphBuilder.predict_now`` and ``predict_cov`` at every sample (to rounding; a test holds the two together)
    without their Python per sample: with the quaternion's conversion, a sixth of the online head's time on BROAD's motion.
    A live loop, which publishes each sample's estimate as it comes, asks ``OnlineHeadTracker.latest`` instead."""

    def __init__(self) -> None:
        self._interval: GyroInterval | IntegratedInterval | GapInterval | None = None
        self._state: tuple[object, ...] = ()
        self.intervals: list[tuple[int, float, FloatArray]] = []
        """(the first sample noted in it, its start time, the bias it integrates with) per open interval."""
        self.states: list[tuple[int, FloatArray | None, FloatArray, FloatArray, FloatArray, float]] = []
        """(the first sample it served, attitude or None before an estimate, bias, covariance, bias covariance, solved
        keyframe's time) per state."""

    def note(self, i: int, builder: HeadGraphBuilder, cov: FloatArray, bias_cov: FloatArray, ready: bool) -> None:
        """Gyro sample ``i`` has been pushed (and the solver updated): record what its estimate is made of, if it changed."""
        interval = builder._interval
        if interval is not self._interval and isinstance(interval, GyroInterval):
            self._interval = interval
            self.intervals.append((i, interval.t_start, interval.bias_hat))
        rot, bias = builder._latest_rot, builder._latest_bias
        last = self._state
        # identity, not value: each update and each keyframe makes new objects (and this runs at every sample)
        if not last or rot is not last[0] or bias is not last[1] or cov is not last[2] or bias_cov is not last[3] or ready is not last[4]:
            self._state = (rot, bias, cov, bias_cov, ready)
            quat = quat_wxyz_from_rot3(rot) if ready and rot is not None and builder.started else None
            self.states.append((i, quat, bias, cov, bias_cov, builder.keyframe_t[builder._solved_keyframe] if builder.keyframe_t else math.nan))

    def fill(self, t: FloatArray, omega: FloatArray, density_sq: float) -> tuple[FloatArray, FloatArray]:
        """Attitude (w, x, y, z) and covariance at every pushed sample (``t``, ``omega``: all of them, in order); NaN before
        the first estimate."""
        n = len(t)
        quats, covs = np.full((n, 4), np.nan), np.full((n, 3, 3), np.nan)
        if not self.intervals or not self.states:
            return quats, covs
        everyone = np.arange(n)
        interval = np.searchsorted([first for first, _, _ in self.intervals], everyone, side="right") - 1
        state = np.searchsorted([first for first, *_ in self.states], everyone, side="right") - 1
        have = [quat is not None for _, quat, *_ in self.states]
        rows = everyone[(interval >= 0) & (state >= 0)]
        rows = rows[np.asarray(have)[state[rows]]]
        iv, st = interval[rows], state[rows]
        starts = np.searchsorted(t, [t_start for _, t_start, _ in self.intervals])
        biases = np.array([b for _, _, b in self.intervals])
        delta = carried_by_gyro(t, omega, starts, biases)[rows]
        start, bias_hat = starts[iv], biases[iv]
        table = [s if s[1] is not None else (s[0], np.full(4, np.nan), *s[2:]) for s in self.states]
        rot, bias, cov, bias_cov = (np.array([s[m] for s in table])[st] for m in (1, 2, 3, 4))
        # the newest bias, to first order over the interval (``GyroInterval.delta``)
        correction = quat_from_rotvec(-(bias - bias_hat) * (t[rows] - t[start])[:, None])
        quats[rows] = quat_normalize(quat_multiply(rot, quat_multiply(delta, correction)))
        dt = t[rows] - np.array([s[5] for s in table])[st]
        grown = cov + (dt * dt)[:, None, None] * bias_cov
        grown[:, [0, 1, 2], [0, 1, 2]] += (dt * density_sq)[:, None]
        covs[rows] = grown
        return quats, covs


def rates_at(gyro_t: FloatArray, rate_rad_s: FloatArray, t: FloatArray) -> FloatArray:
    """The gyro's rate at times ``t`` that are its sample times; zero at the others (keyframes inside a dropout)."""
    if len(t) == len(gyro_t):
        return rate_rad_s
    index = np.clip(np.searchsorted(gyro_t, t), 0, len(gyro_t) - 1)
    return np.where(np.isclose(gyro_t[index], t, rtol=0.0, atol=1e-9)[:, None], rate_rad_s[index], 0.0)


def with_gap_keyframes(gyro_t: FloatArray, keyframe_t: FloatArray, gaps: list[tuple[float, float]]) -> FloatArray:
    """The gyro's times and the keyframes inside its dropouts (the batch has an estimate there: the tracker's)."""
    inside = np.zeros(len(keyframe_t), dtype=bool)
    for before_s, length_s in gaps:
        inside |= (keyframe_t > before_s + 1e-9) & (keyframe_t < before_s + length_s - 1e-9)
    return np.union1d(gyro_t, keyframe_t[inside]) if inside.any() else gyro_t


def warn_gyro_gaps(session: Session, solver: str) -> None:
    """One warning per gyro dropout, with what the solver does across it (said, not hidden)."""
    limit = gap_limit_s(head_model_for(session).gyro.sample_rate_hz)
    for before, after in session.stream("gyro").gaps():
        if after - before > limit:
            inside = ("the tracker alone places the keyframes inside it" if solver == "batch" else
                      "no estimate inside it" if solver == "online" else "the paper's filter carries its rate state across it, as written")
            warnings.warn(f"{session.where}: no gyro sample for {after - before:.2f} s after t = {before:.2f} s: the gap is bridged "
                          f"(a random walk as wide as it allows; {inside})", SessionWarning, stacklevel=3)


def time_ordering(keys: Iterable[int]) -> list[int]:
    """Elimination order for a whole head graph: nested dissection over keyframes (``graphs.ordering``),
    session-wide keys last. COLAMD treats the calibration key (in every bias factor) as a dense column and
    took super-linear time here (60 s of data: 0.08 s, 240 s: 1.1 s). Keys are split into character and index
    with integer arithmetic on all of them at once (a ``gtsam.Symbol`` per key cost ~0.1 s on a 10-minute graph)."""
    key_array = np.fromiter(keys, dtype=np.uint64)
    index = (key_array & np.uint64(SYMBOL_INDEX_MASK)).astype(np.int64)
    rank = _RANK_OF_CHR[(key_array >> np.uint64(SYMBOL_INDEX_BITS)).astype(np.int64)]
    per_keyframe = rank >= 0
    order = np.lexsort((rank[per_keyframe], index[per_keyframe]))  # by keyframe, then rank within it
    step_keys, step_index = key_array[per_keyframe][order], index[per_keyframe][order]
    cuts = np.flatnonzero(np.diff(step_index)) + 1
    steps = [part.tolist() for part in np.split(step_keys, cuts)] if len(step_keys) else []
    shared = key_array[~per_keyframe][np.lexsort((key_array[~per_keyframe], index[~per_keyframe]))]
    return nested_dissection(steps, shared.tolist())


def head_model_for(session: Session, model: HeadModel | None = None) -> HeadModel:
    """The model completed from what session.toml declares about its sensors.

    Fields a stream declares (gyro: ``rate_hz``, ``noise_sigma_rad_s``, ``bias_rw_sigma``, ``calibrated``
    = true when its scale factors and axes are already calibrated, otherwise they are estimated; tracker:
    ``noise_sigma_deg``, ``markov_sigma_deg``, ``markov_tau_s``, and ``latency_sigma_s`` when its
    ``latency_s`` is only assumed and should be estimated) replace the model's defaults unless
    ``model`` is given explicitly: a sensor's data sheet belongs with its recording.
    """
    if model is not None:
        return _with_gyro_rate(session, model)
    model = HeadModel()
    gyro_meta = session.stream("gyro").meta
    # a declared zero (a noise-free simulation) is floored: a graph with infinitely stiff factors is singular
    gyro = replace(
        model.gyro,
        white_sigma_rad_s=max(float(gyro_meta.get("noise_sigma_rad_s", model.gyro.white_sigma_rad_s)), MIN_GYRO_SIGMA_RAD_S),
        bias_rw_sigma=max(float(gyro_meta.get("bias_rw_sigma", model.gyro.bias_rw_sigma)), MIN_BIAS_RW_SIGMA),
    )
    trackers = session.streams_of_kind("attitude")
    tracker = model.tracker
    if trackers:
        meta = trackers[0].meta
        tracker = AttitudeNoise(
            white_sigma_deg=max(float(meta.get("noise_sigma_deg", tracker.white_sigma_deg)), 1e-3),
            markov_sigma_deg=float(meta.get("markov_sigma_deg", 0.0)),
            markov_tau_s=float(meta.get("markov_tau_s", tracker.markov_tau_s)),
        )
    calibration = None if gyro_meta.get("calibrated", False) else model.gyro_calibration
    gravity = model.gravity
    for accel in session.streams_of_kind("accel")[:1]:
        gravity = declared_gravity(accel.meta, gravity)
    latency = None
    if trackers and "latency_sigma_s" in trackers[0].meta:
        latency = LatencyPrior(
            assumed_s=trackers[0].latency_s,
            sigma_s=float(trackers[0].meta["latency_sigma_s"]),
            random_walk_s_per_sqrt_s=float(trackers[0].meta.get("latency_rw_s_per_sqrt_s", 0.0)),
        )
    return _with_gyro_rate(session, replace(model, gyro=gyro, tracker=tracker, gyro_calibration=calibration, latency=latency, gravity=gravity))


#: Floors for declared sensor noise (rad/s per sample; rad/s/sqrt(s)); see ``head_model_for``.
MIN_GYRO_SIGMA_RAD_S = 1e-4
MIN_BIAS_RW_SIGMA = 1e-6


def _with_gyro_rate(session: Session, model: HeadModel) -> HeadModel:
    gyro = session.stream("gyro")
    rate = gyro.meta.get("rate_hz")
    if rate is None and len(gyro) > 1:
        rate = 1.0 / float(np.median(np.diff(gyro.t)))
    if rate is None or float(rate) == model.gyro.sample_rate_hz:
        return model
    return replace(model, gyro=replace(model.gyro, sample_rate_hz=float(rate)))
