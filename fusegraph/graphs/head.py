"""Head tracking graph: gyro preintegration between keyframes + late tracker attitudes at their sample times.

Variables per keyframe k (one every ``keyframe_period_s``, placed on gyro samples):
``x(k)`` world_R_head (Rot3), ``b(k)`` gyro bias (Vector3, random-walk chain); per tracker sample
at keyframe k, with the Gauss-Markov tracker model: ``e(k)`` tracker error (Vector3, AR(1) chain)
and ``t(k)`` the reading without white noise (Rot3).

Measurements are pushed in ARRIVAL order; a tracker sample attaches to the keyframe at its SAMPLE
time (nearest keyframe, corrected by the gyro rate for any offset), which the gyro created up to
``latency`` seconds earlier. The same builder feeds the online and the batch solver.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..factors.attitude import (
    AttitudeNoise,
    attitude_prior_factor,
    error_state_factor,
    gauss_markov_factor,
    markov_prior_factor,
)
from ..factors.gyro import GyroInterval, GyroNoise, bias_prior_factor, bias_walk_factor, preintegration_params
from ..geometry import FloatArray, rot3_from_quat_wxyz
from ..session import Session
from .increment import GraphIncrement


def X(k: int) -> int:
    """Key of world_R_head at keyframe k."""
    return int(gtsam.symbol("x", k))


def B(k: int) -> int:
    """Key of the gyro bias at keyframe k."""
    return int(gtsam.symbol("b", k))


def E(k: int) -> int:
    """Key of the tracker's slowly varying error at keyframe k."""
    return int(gtsam.symbol("e", k))


def T(k: int) -> int:
    """Key of the tracker reading (without white noise) at keyframe k."""
    return int(gtsam.symbol("t", k))


@dataclass(frozen=True)
class HeadModel:
    """How the head graph models its sensors (one parameter set for every session)."""

    keyframe_period_s: float = 0.02
    """Time between keyframes, seconds (the tracker's period: each tracker sample gets its state)."""
    gyro: GyroNoise = field(default_factory=GyroNoise)
    """Gyro noise and bias model."""
    tracker: AttitudeNoise = field(default_factory=AttitudeNoise)
    """Tracker error model; ``markov_sigma_deg = 0`` gives plain white-noise priors."""
    tracker_latency_s: float | None = None
    """Tracker delay, seconds; None takes the stream's ``latency_s`` from the session."""
    snap_tolerance_s: float = 5e-4
    """A tracker sample this close to a keyframe attaches to it without gyro correction, seconds."""


class HeadGraphBuilder:
    """Turns gyro and tracker samples, pushed in arrival order, into factors and initial values."""

    def __init__(self, model: HeadModel | None = None):
        self.model = model or HeadModel()
        self._params = preintegration_params(self.model.gyro)
        self._pending = GraphIncrement()
        self._gyro_buffer: list[tuple[float, FloatArray]] = []
        self._tracker_waiting: list[tuple[float, FloatArray]] = []
        self.keyframe_t: list[float] = []
        """Time of every keyframe so far, seconds."""
        self._keyframe_omega: list[FloatArray] = []
        self._interval: GyroInterval | None = None
        self._last_error_kf: int | None = None
        self._latest_rot: gtsam.Rot3 | None = None
        self._latest_bias = np.zeros(3)
        self.oldest_allowed_keyframe = 0
        """Keyframes older than this were marginalised by the online solver; samples for them are too late."""
        self.too_late: list[float] = []
        """Sample times of tracker samples that arrived after their keyframe was marginalised."""
        self.tracker_used = 0
        """Number of tracker samples turned into factors."""

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
        self._interval.add(t, omega)
        if self._interval.elapsed_s >= self.model.keyframe_period_s - 1e-9:
            self._close_keyframe()
        self._flush_waiting_tracker()

    def add_tracker(self, t: float, quat_wxyz: FloatArray) -> None:
        """A tracker attitude sample taken at time t (it may arrive much later)."""
        self._tracker_waiting.append((t, np.asarray(quat_wxyz, dtype=float)))
        if not self.started:
            self._try_start()
        else:
            self._flush_waiting_tracker()

    def set_latest(self, world_R_head: gtsam.Rot3, bias: FloatArray) -> None:
        """Feed back the solver's estimate of the newest keyframe (initial guesses, predictions)."""
        self._latest_rot = world_R_head
        self._latest_bias = np.asarray(bias, dtype=float)

    def take(self) -> GraphIncrement:
        """Factors and values built since the last call."""
        out, self._pending = self._pending, GraphIncrement()
        return out

    # ------------------------------------------------------------------ predictions

    def predict_now(self, world_R_kf: gtsam.Rot3, bias: FloatArray) -> tuple[float, gtsam.Rot3]:
        """Attitude at the newest gyro sample from the newest keyframe's estimate (time, rotation)."""
        assert self._interval is not None
        return self._interval.t_last, world_R_kf.compose(self._interval.delta(bias))

    def predict_cov(self, cov_kf: FloatArray, cov_bias: FloatArray) -> FloatArray:
        """Covariance of ``predict_now`` (right perturbation): keyframe cov carried over the gyro interval."""
        assert self._interval is not None
        delta = self._interval.delta().matrix()
        dt = self._interval.elapsed_s
        return delta.T @ cov_kf @ delta + self._interval.pim.preintMeasCov() + dt * dt * cov_bias

    @property
    def now_s(self) -> float:
        """Time of the newest gyro sample integrated."""
        return self._interval.t_last if self._interval else float("nan")

    # ------------------------------------------------------------------ internals

    def _try_start(self) -> None:
        """Anchor keyframe 0 on the gyro sample nearest the first tracker sample."""
        if not self._tracker_waiting or not self._gyro_buffer:
            return
        t_fix = self._tracker_waiting[0][0]
        times = [t for t, _ in self._gyro_buffer]
        if times[-1] < t_fix - self.model.snap_tolerance_s:
            return  # gyro has not reached the fix yet
        i0 = int(np.argmin(np.abs(np.asarray(times) - t_fix)))
        t0, omega0 = self._gyro_buffer[i0]
        later = self._gyro_buffer[i0 + 1 :]
        self._gyro_buffer = []
        first_fix = rot3_from_quat_wxyz(self._tracker_waiting[0][1])
        self.keyframe_t.append(t0)
        self._keyframe_omega.append(omega0)
        self._latest_rot = first_fix.compose(gtsam.Rot3.Expmap(-omega0 * (t_fix - t0)))
        self._pending.values.insert(X(0), self._latest_rot)
        self._pending.values.insert(B(0), np.zeros(3))
        self._pending.add(0, bias_prior_factor(B(0), self.model.gyro))
        self._interval = GyroInterval(self._params, self._latest_bias, t0, omega0)
        # tracker samples older than the anchor can never be used: say so, do not drop silently
        while self._tracker_waiting and self._tracker_waiting[0][0] < t0 - self.model.snap_tolerance_s:
            self.too_late.append(self._tracker_waiting.pop(0)[0])
        self._flush_waiting_tracker()
        for t, omega in later:
            self.add_gyro(t, omega)

    def _close_keyframe(self) -> None:
        assert self._interval is not None and self._latest_rot is not None
        k = self.latest_keyframe
        interval = self._interval
        self._pending.add(k, interval.factor(X(k), X(k + 1), B(k)))
        self._pending.add(k, bias_walk_factor(B(k), B(k + 1), interval.elapsed_s, self.model.gyro))
        self._latest_rot = self._latest_rot.compose(interval.delta(self._latest_bias))
        self._pending.values.insert(X(k + 1), self._latest_rot)
        self._pending.values.insert(B(k + 1), self._latest_bias)
        self.keyframe_t.append(interval.t_last)
        self._keyframe_omega.append(interval.omega_last)
        self._interval = GyroInterval(self._params, self._latest_bias, interval.t_last, interval.omega_last)

    def _flush_waiting_tracker(self) -> None:
        """Attach every waiting tracker sample whose keyframe exists."""
        tol = self.model.snap_tolerance_s
        while self._tracker_waiting and self._tracker_waiting[0][0] <= self.keyframe_t[-1] + tol:
            t, quat = self._tracker_waiting.pop(0)
            self._attach_tracker(t, quat)

    def _attach_tracker(self, t: float, quat_wxyz: FloatArray) -> None:
        i = bisect.bisect_left(self.keyframe_t, t)
        candidates = [j for j in (i - 1, i) if 0 <= j < len(self.keyframe_t)]
        k = min(candidates, key=lambda j: abs(self.keyframe_t[j] - t))
        if k < self.oldest_allowed_keyframe or (self._last_error_kf is not None and k <= self._last_error_kf):
            self.too_late.append(t)
            return
        measured = rot3_from_quat_wxyz(quat_wxyz)
        offset = t - self.keyframe_t[k]
        if abs(offset) > self.model.snap_tolerance_s:
            # reading at t = X(t_k) * Exp(omega * offset): move it to the keyframe to first order
            rate = self._keyframe_omega[k] - self._latest_bias
            measured = measured.compose(gtsam.Rot3.Expmap(-rate * offset))
        noise = self.model.tracker
        self.tracker_used += 1
        if not noise.is_markov:
            self._pending.add(k, attitude_prior_factor(X(k), measured, noise.total_sigma_rad))
            return
        white = float(np.deg2rad(noise.white_sigma_deg))
        markov = float(np.deg2rad(noise.markov_sigma_deg))
        self._pending.add(k, attitude_prior_factor(T(k), measured, white))
        self._pending.add(k, error_state_factor(X(k), T(k), E(k)))
        self._pending.values.insert(T(k), measured)
        self._pending.values.insert(E(k), np.zeros(3))
        if self._last_error_kf is None:
            self._pending.add(k, markov_prior_factor(E(k), markov))
        else:
            prev = self._last_error_kf
            dt = self.keyframe_t[k] - self.keyframe_t[prev]
            self._pending.add(prev, gauss_markov_factor(E(prev), E(k), dt, markov, noise.markov_tau_s))
        self._last_error_kf = k


def head_model_for(session: Session, model: HeadModel | None = None) -> HeadModel:
    """The model with gyro rate filled from the session when the stream declares it."""
    model = model or HeadModel()
    gyro = session.stream("gyro")
    rate = gyro.meta.get("rate_hz")
    if rate is None and len(gyro) > 1:
        rate = 1.0 / float(np.median(np.diff(gyro.t)))
    if rate is not None and rate != model.gyro.sample_rate_hz:
        from dataclasses import replace

        model = replace(model, gyro=replace(model.gyro, sample_rate_hz=float(rate)))
    return model
