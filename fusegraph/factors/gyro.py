"""Gyro: rate samples -> preintegrated rotation between keyframes (gtsam ``AHRSFactor``) + bias walk.

Sensor model: ``omega_measured = (I + K) omega + b + noise``, K the scale-factor and misalignment
error (9 numbers, small), b a random-walk bias. Over one keyframe interval K acts as an extra bias
``K @ mean(omega_measured)``, so each interval's AHRSFactor takes an *effective* bias
``beta_k = b_k + W(omega_k) @ c`` (c = K row by row, W the 3x9 rate matrix). The bias walk
b_{k+1} - b_k ~ N(0, q dt) is then linear in (beta_k, beta_{k+1}, c): an exact
``LinearContainerFactor``, C++ like everything else here. Without calibration it is a plain
``BetweenFactorVector`` chain (one Vector3 per keyframe: a single shared bias key made iSAM2
3-6x slower here). ``AHRSFactor`` carries its own covariance, so it takes no noise model.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..catalogue import KeySpec, Magnitude, SensorKind
from ..geometry import FloatArray
from .linear import linear_factor


@dataclass(frozen=True)
class GyroNoise:
    """Gyro error model used by the graph (not necessarily the simulator's truth)."""

    white_sigma_rad_s: float = 0.015
    """White noise of one sample, rad/s (discrete, at the sample rate)."""
    sample_rate_hz: float = 100.0
    """Sample rate the white sigma refers to, Hz."""
    bias_rw_sigma: float = 1e-3
    """Bias random walk, rad/s/sqrt(s)."""
    bias_prior_sigma_rad_s: float = 0.05
    """Prior on the bias at start-up, rad/s per axis (zero mean)."""

    @property
    def density(self) -> float:
        """Continuous white-noise density, rad/s/sqrt(Hz), as gtsam's preintegration expects."""
        return self.white_sigma_rad_s / np.sqrt(self.sample_rate_hz)


def preintegration_params(noise: GyroNoise) -> gtsam.PreintegratedRotationParams:
    """gtsam parameters for rotation-only preintegration with this noise."""
    params = gtsam.PreintegratedRotationParams()
    params.setGyroscopeCovariance(noise.density**2 * np.eye(3))
    return params


@dataclass(frozen=True)
class GyroCalibrationPrior:
    """Prior on the gyro's scale-factor and misalignment errors (the matrix K), estimated as variables."""

    scale_sigma: float = 0.05
    """Sigma of each scale-factor error (diagonal of K), as a fraction."""
    misalignment_sigma: float = 0.03
    """Sigma of each cross-axis term (off-diagonal of K), rad."""

    @property
    def sigmas(self) -> FloatArray:
        """Per-entry sigmas of c = K flattened row by row."""
        return np.where(np.eye(3, dtype=bool).ravel(), self.scale_sigma, self.misalignment_sigma)


_EYE3 = np.eye(3)
_IDENTITY_ROT = gtsam.Rot3()
_MINUS_EYE3 = -_EYE3


def rate_matrix(omega: FloatArray) -> FloatArray:
    """W(omega), 3x9, with W @ c = K @ omega for c = K flattened row by row."""
    out = np.zeros((3, 9))
    out[0, 0:3] = out[1, 3:6] = out[2, 6:9] = omega
    return out


def scale_rate_map(gyro_rad_s: FloatArray, dt_s: FloatArray, bias_rad_s: FloatArray) -> FloatArray:
    """M (3 x 9) with M c the constant bias that turns an interval's preintegrated rotation as a gyro error K w does
    (c = K row by row; first order in both): the interval's rotation moves by sum_s A_s K w_s for the samples'
    sensitivities A_s = (R_{s+1} ... R_n)^T Jr(phi_s) dt_s, and by (sum_s A_s) b for a bias b, so M = (sum A)^-1 sum A_s W(w_s).
    About W(mean rate) when the axis holds still over the interval; at 500 deg/s the axis turns within a 0.2 s keyframe
    and the two differ."""
    omega = np.asarray(gyro_rad_s, dtype=float)
    phi = (omega - np.asarray(bias_rad_s, dtype=float)) * np.asarray(dt_s, dtype=float)[:, None]
    theta = np.linalg.norm(phi, axis=1)
    small = theta < 1e-6
    t = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1.0 - np.cos(t)) / t**2)  # Jr = I - a [phi]x + b [phi]x^2
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t**3)
    c = np.where(small, 1.0, np.sin(t) / t)  # Exp = I + c [phi]x + a [phi]x^2
    hat = np.zeros((len(phi), 3, 3))
    hat[:, 0, 1], hat[:, 0, 2], hat[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    hat[:, 1, 0], hat[:, 2, 0], hat[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    hat2 = hat @ hat
    jr = np.eye(3) - a[:, None, None] * hat + b[:, None, None] * hat2
    rot = np.eye(3) + c[:, None, None] * hat + a[:, None, None] * hat2
    sens = np.empty_like(jr)
    after = np.eye(3)  # (R_{s+1} ... R_n)^T
    for s in range(len(phi) - 1, -1, -1):
        sens[s] = after @ jr[s] * dt_s[s]
        after = after @ rot[s].T
    weighted = np.zeros((3, 9))
    for row in range(3):  # A_s W(w_s): W's row r holds w_s in columns 3r..3r+2
        weighted[:, 3 * row : 3 * row + 3] = (sens[:, :, row : row + 1] * omega[:, None, :]).sum(0)
    return np.asarray(np.linalg.solve(sens.sum(0), weighted))


def calibration_prior_factor(cal_key: int, prior: GyroCalibrationPrior) -> gtsam.PriorFactorVector:
    """Zero-mean prior on c (9 numbers)."""
    return gtsam.PriorFactorVector(cal_key, np.zeros(9), gtsam.noiseModel.Diagonal.Sigmas(prior.sigmas))


def calibrated_bias_walk_factor(
    beta_i: int, beta_j: int, cal_key: int, rate_i: FloatArray, rate_j: FloatArray, dt_s: float, noise: GyroNoise,
    at_zero: gtsam.Values | None = None,
) -> gtsam.LinearContainerFactor:
    """(beta_j - W_j c) - (beta_i - W_i c) ~ N(0, q dt): the bias walk seen through effective biases (``at_zero``: see
    ``linear_factor``)."""
    sigma = noise.bias_rw_sigma * math.sqrt(max(dt_s, 1e-9))
    blocks = [(beta_i, _MINUS_EYE3), (beta_j, _EYE3), (cal_key, rate_matrix(np.subtract(rate_i, rate_j)))]  # W is linear in omega
    return linear_factor(blocks, sigma, at_zero=at_zero)


def calibrated_bias_prior_factor(beta_key: int, cal_key: int, rate: FloatArray, noise: GyroNoise) -> gtsam.LinearContainerFactor:
    """beta_0 - W_0 c ~ N(0, sigma_b0^2): the start-up bias prior seen through the effective bias."""
    return linear_factor([(beta_key, _EYE3), (cal_key, -rate_matrix(rate))], noise.bias_prior_sigma_rad_s)


class GyroInterval:
    """Gyro samples between two keyframes, integrated with the bias estimate known at its start.

    Samples are integrated with the midpoint of consecutive rates (second-order accurate), so a
    noise-free gyro reproduces the rotation to ~1e-6 rad per keyframe at head-motion rates.
    """

    def __init__(self, params: gtsam.PreintegratedRotationParams, bias_hat: FloatArray, t_start: float, omega_start: FloatArray):
        self.pim = gtsam.PreintegratedAhrsMeasurements(params, np.asarray(bias_hat, dtype=float))
        self.bias_hat = np.asarray(bias_hat, dtype=float)
        self.t_start = t_start
        self.t_last = t_start
        self.omega_last = np.asarray(omega_start, dtype=float)
        self._angle_sum = np.zeros(3)

    def add(self, t: float, omega: FloatArray) -> None:
        """Integrate up to sample time ``t`` whose measured rate is ``omega`` (rad/s)."""
        dt = t - self.t_last
        omega = np.asarray(omega, dtype=float)
        if dt > 0:
            midpoint = 0.5 * (self.omega_last + omega)
            self.pim.integrateMeasurement(midpoint, dt)
            self._angle_sum += midpoint * dt
        self.t_last = t
        self.omega_last = omega

    @property
    def elapsed_s(self) -> float:
        return self.t_last - self.t_start

    @property
    def mean_rate(self) -> FloatArray:
        """Mean measured rate over the interval, rad/s (the W of the calibrated bias)."""
        return self._angle_sum / self.elapsed_s if self.elapsed_s > 0 else self.omega_last

    def delta(self, bias: FloatArray | None = None) -> gtsam.Rot3:
        """Rotation from the interval start to the last sample, corrected to ``bias`` to first order."""
        # a copy: deltaRij() is a view of the preintegration, which the next sample moves on (a stored partial
        # rotation that aliased it became the whole interval's by the time a tracker sample used it)
        return _bias_corrected(self.pim.deltaRij(), bias, self.bias_hat, self.elapsed_s, copy=True)

    def factor(self, key_i: int, key_j: int, bias_key: int) -> gtsam.AHRSFactor:
        """world_R_body(i) -> world_R_body(j) constraint with gyro bias ``bias_key``."""
        return gtsam.AHRSFactor(key_i, key_j, bias_key, self.pim)


GAP_PERIODS = 10.0
"""A step of more than this many sample periods between gyro samples is a dropout (bridged, not integrated)."""
GAP_MIN_S = 0.05
"""...and of at least this long, seconds (a jittery clock's late sample is not one)."""
GAP_RATE_RAD_S = 2.0 * math.pi
"""How fast the body may have turned in a dropout, rad/s (a head or a hand turns at most a few hundred deg/s; a bridge's
attitude sigma is this times its length, at most pi)."""


def gap_limit_s(sample_rate_hz: float) -> float:
    """The longest step between gyro samples that is not a dropout, seconds."""
    return max(GAP_PERIODS / sample_rate_hz, GAP_MIN_S)


@dataclass(frozen=True)
class GapInterval:
    """A keyframe interval inside a gyro dropout: nothing measured the rotation, so the keyframes are tied by a random
    walk as wide as the interval allows (``GAP_RATE_RAD_S`` x its length, at most pi); same interface as ``GyroInterval``."""

    t_start: float
    """Time of the keyframe that opens the interval, s."""
    t_last: float
    """Time of the next keyframe, s."""

    omega_last = np.zeros(3)
    """No rate is known inside a gap (a tracker sample there is placed on its keyframe as it is)."""
    mean_rate = np.zeros(3)

    @property
    def elapsed_s(self) -> float:
        return self.t_last - self.t_start

    def delta(self, bias: FloatArray | None = None) -> gtsam.Rot3:
        """No rotation known: the identity."""
        return gtsam.Rot3()

    def factor(self, key_i: int, key_j: int, bias_key: int) -> gtsam.BetweenFactorRot3:
        """The random walk between the interval's keyframes (the bias is left to its own walk)."""
        sigma = min(math.pi, GAP_RATE_RAD_S * self.elapsed_s)
        return gtsam.BetweenFactorRot3(key_i, key_j, gtsam.Rot3(), gtsam.noiseModel.Isotropic.Sigma(3, sigma))


def _bias_corrected(delta: gtsam.Rot3, bias: FloatArray | None, bias_hat: FloatArray, elapsed_s: float, copy: bool) -> gtsam.Rot3:
    """``delta`` integrated with ``bias_hat``, corrected to ``bias`` to first order (d(deltaR)/d(bias) ~ -dt for the short
    intervals used here, a few samples); ``copy`` returns a new rotation where no correction is made."""
    if bias is None or bias is bias_hat or elapsed_s == 0.0:  # the same array: Exp(0) would be exactly the identity
        return delta.compose(_IDENTITY_ROT) if copy else delta  # exact: products with 1 and 0
    return delta.compose(gtsam.Rot3.Expmap(-(np.asarray(bias) - bias_hat) * elapsed_s))


@dataclass(frozen=True)
class IntegratedInterval:
    """A keyframe interval integrated in one go (``integrate_intervals``): what a ``GyroInterval`` holds when its
    keyframe closes, with the same ``delta``, ``factor`` and ``elapsed_s``."""

    pim: gtsam.PreintegratedAhrsMeasurements
    """The interval's preintegration (gtsam's, built from the integrated rotation, bias Jacobian and covariance)."""
    bias_hat: FloatArray
    """Bias it was integrated with, rad/s."""
    t_start: float
    """Time of the keyframe that opens the interval, s."""
    t_last: float
    """Time of its last sample (the next keyframe), s."""
    omega_last: FloatArray
    """Measured rate of the last sample, rad/s."""
    mean_rate: FloatArray
    """Mean measured rate over the interval, rad/s (the W of the calibrated bias)."""
    rotation: gtsam.Rot3
    """Rotation from the interval start to its last sample (with ``bias_hat``)."""

    @property
    def elapsed_s(self) -> float:
        return self.t_last - self.t_start

    def delta(self, bias: FloatArray | None = None) -> gtsam.Rot3:
        """As ``GyroInterval.delta`` (the rotation is this object's own: no copy needed)."""
        return _bias_corrected(self.rotation, bias, self.bias_hat, self.elapsed_s, copy=False)

    def factor(self, key_i: int, key_j: int, bias_key: int) -> gtsam.AHRSFactor:
        """As ``GyroInterval.factor``."""
        return gtsam.AHRSFactor(key_i, key_j, bias_key, self.pim)


@dataclass(frozen=True)
class IntervalIntegrals:
    """Many keyframe intervals integrated at once by gtsam's recursion (``PreintegratedAhrsMeasurements``), in numpy."""

    rotation_after: FloatArray
    """(N, 3, 3): each sample's rotation from its interval's start, itself included."""
    bias_jacobian: FloatArray
    """(M, 3, 3): per interval, d(rotation)/d(bias) as gtsam keeps it (delRdelBiasOmega)."""
    covariance: FloatArray
    """(M, 3, 3): per interval, the preintegrated rotation's covariance (preintMeasCov)."""
    delta_t_s: FloatArray
    """(M,): per interval, the integrated time (deltaTij), s."""
    angle_sum: FloatArray
    """(M, 3): per interval, the sum of midpoint rate x dt (mean rate x elapsed time), rad."""


def integrate_intervals(gyro_covariance: FloatArray, bias_hat: FloatArray, t_before: float, omega_before: FloatArray,
                        t: FloatArray, omega: FloatArray, ends: Sequence[int]) -> IntervalIntegrals:
    """What ``GyroInterval.add`` does sample by sample, for consecutive intervals at once.

    Samples ``t``/``omega`` follow the sample (``t_before``, ``omega_before``) that opens the first interval; interval m
    ends with sample ``ends[m]`` and the next starts after it (the last sample of ``t`` must be ``ends[-1]``). Each sample
    integrates the midpoint of its rate and the previous one over the time since it (none when that is not positive),
    by the recursion of gtsam's ``PreintegratedRotation::integrateGyroMeasurement`` and
    ``PreintegratedAhrsMeasurements::integrateMeasurement`` (SO(3) exponential, its right Jacobian for the bias, the
    covariance propagated through the increment): one vectorised step per sample position within the intervals,
    instead of a Python call per sample (~20 us each with the bookkeeping around it).
    """
    t = np.asarray(t, dtype=float)
    omega = np.asarray(omega, dtype=float)
    last = np.asarray(ends, dtype=int)
    starts = np.r_[0, last[:-1] + 1]
    lengths = last - starts + 1
    dt = np.diff(t, prepend=t_before)
    midpoint = 0.5 * (np.vstack([omega_before, omega[:-1]]) + omega)
    m, steps = len(last), int(lengths.max(initial=0))
    rotation = np.broadcast_to(_EYE3, (m, 3, 3)).copy()
    jacobian = np.zeros((m, 3, 3))
    covariance = np.zeros((m, 3, 3))
    delta_t = np.zeros(m)
    angle_sum = np.zeros((m, 3))
    after = np.empty((len(t), 3, 3))
    for step in range(steps):
        rows = np.flatnonzero(lengths > step)
        j = starts[rows] + step
        moving = dt[j] > 0
        live, j_live = rows[moving], j[moving]
        h = dt[j_live]
        increment, dexp = _exp_and_right_jacobian((midpoint[j_live] - bias_hat) * h[:, None])
        transposed = np.transpose(increment, (0, 2, 1))  # compose's Jacobian in the first argument, inverse(increment)
        rotation[live] = rotation[live] @ increment
        jacobian[live] = transposed @ jacobian[live] - dexp * h[:, None, None]
        covariance[live] = transposed @ covariance[live] @ increment + gyro_covariance * h[:, None, None]
        delta_t[live] += h
        angle_sum[live] += midpoint[j_live] * h[:, None]
        after[j] = rotation[rows]
    return IntervalIntegrals(after, jacobian, covariance, delta_t, angle_sum)


def _exp_and_right_jacobian(phi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(N, 3) rotation vectors -> their rotations and right Jacobians (N, 3, 3), as gtsam's SO3 ``ExpmapFunctor`` and
    ``DexpFunctor`` compute them (Rodrigues with 1 - cos as 2 sin^2(theta / 2); first order below theta^2 = eps)."""
    theta2 = np.einsum("ij,ij->i", phi, phi)
    theta = np.sqrt(theta2)
    w = np.zeros((len(phi), 3, 3))
    w[:, 0, 1], w[:, 0, 2], w[:, 1, 2] = -phi[:, 2], phi[:, 1], -phi[:, 0]
    w[:, 1, 0], w[:, 2, 0], w[:, 2, 1] = phi[:, 2], -phi[:, 1], phi[:, 0]
    near = theta2 <= np.finfo(float).eps
    safe = np.where(near, 1.0, theta)
    k = w / safe[:, None, None]
    kk = k @ k
    sin_theta = np.sin(theta)[:, None, None]
    s2 = np.sin(theta / 2.0)
    one_minus_cos = (2.0 * s2 * s2)[:, None, None]
    rotation = _EYE3 + sin_theta * k + one_minus_cos * kk
    a = one_minus_cos / safe[:, None, None]
    b = 1.0 - sin_theta / safe[:, None, None]
    dexp = _EYE3 - a * k + b * kk
    if near.any():
        rotation[near] = _EYE3 + w[near]
        dexp[near] = _EYE3 - 0.5 * w[near]
    return rotation, dexp


def bias_walk_factor(bias_i: int, bias_j: int, dt_s: float, noise: GyroNoise) -> gtsam.BetweenFactorVector:
    """Random-walk link between consecutive bias states dt_s apart."""
    sigma = noise.bias_rw_sigma * np.sqrt(max(dt_s, 1e-9))
    return gtsam.BetweenFactorVector(bias_i, bias_j, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, sigma))


def bias_prior_factor(bias_key: int, noise: GyroNoise, mean: FloatArray | None = None) -> gtsam.PriorFactorVector:
    """Start-up prior on the bias (zero unless told)."""
    mean_vec = np.zeros(3) if mean is None else np.asarray(mean, dtype=float)
    return gtsam.PriorFactorVector(bias_key, mean_vec, gtsam.noiseModel.Isotropic.Sigma(3, noise.bias_prior_sigma_rad_s))


def integrate_gyro(t: FloatArray, omega: FloatArray, start_quat_wxyz: FloatArray, bias: FloatArray | None = None) -> FloatArray:
    """Dead reckoning: attitude quaternions at every sample from a start attitude at t[0].

    Same midpoint rule as ``GyroInterval``; ``bias`` (3,) or (N, 3) is subtracted first. The
    increments are computed vectorised, their running product blockwise (``geometry.quat_running_product``).
    """
    from ..geometry import quat_from_rotvec, quat_normalize, quat_running_product

    rates = np.asarray(omega, dtype=float) - (0.0 if bias is None else np.asarray(bias, dtype=float))
    steps = 0.5 * (rates[1:] + rates[:-1]) * np.diff(t)[:, None]
    return quat_normalize(quat_running_product(quat_normalize(start_quat_wxyz), quat_from_rotvec(steps)))

CATALOGUE = (
    SensorKind(
        kind="gyro",
        summary="rate gyroscope: angular velocity of the body; sample i covers (t[i-1], t[i]]",
        columns=("wx", "wy", "wz"),
        units=("rad/s", "rad/s", "rad/s"),
        frame="body (sensor) axes",
        factors="AHRSFactor per keyframe interval (PreintegratedAhrsMeasurements) with a bias random walk; "
        "head: gyro scale/misalignment as a calibration variable unless calibrated = true; attitude9 batch: the same when scale_sigma "
        "is declared",
        keys=(
            KeySpec("noise_sigma_rad_s", 0.015, "white noise per sample, rad/s (head, > 0)"),
            KeySpec("bias_rw_sigma", 0.001, "bias random walk, rad/s/sqrt(s) (head, > 0; attitude9: default chosen on BROAD, 1e-6)"),
            KeySpec("calibrated", False, "true when scale factors and axes are already calibrated (head: else estimated)"),
            KeySpec("scale_sigma", None, "attitude9 batch: estimate the scale factors and misalignment with this prior sigma on each "
                    "scale error (fraction; absent: a perfect gyro, as chosen on BROAD); the estimate is in the run's extras gyro_calibration"),
            KeySpec("misalignment_sigma_rad", None, "attitude9 batch, with scale_sigma: prior sigma of each cross-axis term, rad (default scale_sigma)"),
            KeySpec("rest_rate_sigma_rad_s", None, "attitude9: how still a detected rest is, rad/s: the zero-rate update's sigma where larger "
                    "than the readings' standard error (default: chosen on BROAD, whose rests lie on a table; a worn sensor whose "
                    "wearer stands still sways: declare a wider rate, or inf for no update)"),
            KeySpec("delay_s", 0.0, "the output lags the motion by this much (the sensor's filter delay), s; head: every method re-times "
                    "the samples and reports at their stamps (estimate it with the tracker: frontends.head_timing.gyro_delay_from_tracker)"),
            KeySpec("delay_sigma_s", None, "how well delay_s is known, s (documentation: what the estimate of the delay said)"),
        ),
        magnitude=(Magnitude("max", 0.0, 35.0, "above a 2000 deg/s full scale: degrees per second? set units = 'deg/s' or convert"),),
        unit_conversions={"rad/s": 1.0, "deg/s": math.pi / 180.0},
    ),
)


class RecentGyro:
    """The last second or more of gyro samples with their running product, so that the rotation since any time in it is
    two compositions (``since``), not one per sample in between (the online head tracker's gate asks at every tracker
    sample: the loop over the samples since took a fifth of the online head's time on BROAD's motion)."""

    KEEP_S = 1.0
    """Samples at least this old are dropped (in batches: a list is trimmed when it has doubled)."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.omega: list[FloatArray] = []
        self.running: list[gtsam.Rot3] = []
        """The product of every kept sample's rotation (omega times the time since the previous sample) up to each one."""

    def append(self, t: float, omega: FloatArray) -> None:
        if self.t:
            self.running.append(self.running[-1].compose(gtsam.Rot3.Expmap(omega * (t - self.t[-1]))))
        else:
            self.running.append(gtsam.Rot3())
        self.t.append(t)
        self.omega.append(omega)
        if self.t[0] < t - 2.0 * self.KEEP_S:
            first = bisect.bisect_left(self.t, t - self.KEEP_S)
            del self.t[:first], self.omega[:first], self.running[:first]

    def since(self, t: float) -> gtsam.Rot3 | None:
        """The rotation from ``t`` to the newest sample (each sample after ``t`` turning by its rate over the time since
        the one before, the first since ``t``); None when ``t`` is before the last ``KEEP_S`` of samples."""
        if not self.t or self.t[bisect.bisect_left(self.t, self.t[-1] - self.KEEP_S)] > t:
            return None
        j = bisect.bisect_right(self.t, t)
        if j == len(self.t):
            return gtsam.Rot3()
        first = gtsam.Rot3.Expmap(self.omega[j] * (self.t[j] - t))
        return first.compose(self.running[j].between(self.running[-1]))
