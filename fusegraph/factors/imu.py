"""Full IMU (gyro + accelerometer) between keyframes, and the bounded-motion priors of a worn sensor.

The accelerometer measures specific force, gravity included. Its gravity direction becomes
information on the tilt only through a motion model: a body-worn sensor stays within a few metres
of where it started and moves at a few m/s at most, so weak zero-mean priors on position and
velocity (and a tight zero velocity when the sensor rests) make the accelerometer's integral
pin the tilt, while translational accelerations are explained by velocity instead of tilt.
Everything is a C++ factor: ``ImuFactor`` (preintegrated), ``BetweenFactorConstantBias``,
``GPSFactor`` (position only), ``PriorFactorVector`` (velocity).

Sample convention: a sample at t_i describes the interval (t_{i-1}, t_i] (rate-integrating
sensors output the mean over the last period); the state at t_i includes sample i.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np

from ..geometry import FloatArray
from .linear import isotropic, zeros

#: Standard gravity, m/s^2.
GRAVITY_M_S2 = 9.81


@dataclass(frozen=True)
class ImuNoise:
    """Noise of a MEMS IMU (continuous-time densities)."""

    gyro_noise_rad_s_sqrt_hz: float = 3.5e-3
    """Gyro white noise density, rad/s/sqrt(Hz): ~20x a datasheet's, lumping what is not modelled
    (scale, misalignment, vibration); lower trusts the gyro's heading more but corrects the tilt slower."""
    accel_noise_m_s2_sqrt_hz: float = 2e-2
    """Accelerometer white noise density, m/s^2/sqrt(Hz)."""
    gyro_scale_sigma: float = 0.0
    """Gyro scale/misalignment uncertainty (fraction of the rate): adds (sigma |omega|)^2 T to the
    interval's gyro covariance, so fast rotation trusts the gyro less."""
    gyro_bias_walk_rad_s_sqrt_s: float = 1e-5
    """Gyro bias random walk, rad/s per sqrt(s)."""
    accel_bias_walk_m_s2_sqrt_s: float = 1e-3
    """Accelerometer bias random walk, m/s^2 per sqrt(s)."""
    gyro_bias_prior_rad_s: float = 0.01
    """Start-up sigma of the gyro bias, rad/s."""
    accel_bias_prior_m_s2: float = 0.2
    """Start-up sigma of the accelerometer bias, m/s^2."""
    gravity_m_s2: float = GRAVITY_M_S2
    """Local gravity magnitude, m/s^2 (the world frame is ENU: gravity along -z)."""


@dataclass(frozen=True)
class MotionPriors:
    """What a body-worn sensor's translation does on average (pseudo-measurements, per keyframe)."""

    position_sigma_m: float = 5.0
    """Zero-mean position prior: the sensor stays within metres of the start."""
    velocity_sigma_m_s: float = 2.0
    """Zero-mean velocity prior: hand, head and limb speeds of a few m/s."""
    rest_velocity_sigma_m_s: float = 0.02
    """Velocity sigma while the sensor rests (zero-velocity update)."""
    rest_gyro_rad_s: float = 0.05
    """At rest: every gyro sample's norm below this, rad/s ..."""
    rest_accel_m_s2: float = 0.3
    """... and every accelerometer norm within this of gravity, m/s^2 ..."""
    rest_window_s: float = 0.14
    """... over this long a trailing window."""
    rest_rate_sigma_rad_s: float = math.inf
    """A zero-rate update where the whole interval between two keyframes and the rest window before it are still and its
    readings agree with the interval's before (``steady_rest``): the gyro then reads its bias, up to this true rate (how
    still a detected rest is: the detector passes rates below ``rest_gyro_rad_s``) or the readings' own standard error
    where that is larger (``zero_rate_factor``); inf: none."""


def preintegration_params(noise: ImuNoise, rate_rad_s: float = 0.0, interval_s: float = 1.0) -> gtsam.PreintegrationParams:
    """Preintegration noise; ``rate_rad_s`` (RMS rotation rate of the interval) adds the scale-error term."""
    params = gtsam.PreintegrationParams.MakeSharedU(noise.gravity_m_s2)
    density_sq = noise.gyro_noise_rad_s_sqrt_hz**2 + (noise.gyro_scale_sigma * rate_rad_s) ** 2 * interval_s
    params.setGyroscopeCovariance(density_sq * np.eye(3))
    params.setAccelerometerCovariance(noise.accel_noise_m_s2_sqrt_hz**2 * np.eye(3))
    params.setIntegrationCovariance(1e-8 * np.eye(3))  # position from velocity: numerically exact
    return params


_ZERO_BIAS = gtsam.imuBias.ConstantBias()


FREE_GYRO_BIAS_RAD_S = 1e3
"""Sigma of a bias factor's gyro part when another factor holds it (the gyro calibration's linear factors), rad/s."""


def bias_walk_factor(bias_i: int, bias_j: int, dt_s: float, noise: ImuNoise, gyro: bool = True) -> gtsam.BetweenFactorConstantBias:
    """Random walk of both biases between keyframes dt_s apart (accelerometer first, as gtsam orders them); ``gyro``
    False: the accelerometer's alone (the gyro's part free)."""
    a, g = noise.accel_bias_walk_m_s2_sqrt_s, noise.gyro_bias_walk_rad_s_sqrt_s
    if not gyro:
        g = FREE_GYRO_BIAS_RAD_S / math.sqrt(max(dt_s, 1e-9))
    sigmas = np.sqrt(max(dt_s, 1e-9)) * np.array([a, a, a, g, g, g])
    return gtsam.BetweenFactorConstantBias(bias_i, bias_j, _ZERO_BIAS, gtsam.noiseModel.Diagonal.Sigmas(sigmas))


def bias_prior_factor(bias_key: int, noise: ImuNoise, gyro: bool = True) -> gtsam.PriorFactorConstantBias:
    """Zero-mean start-up prior on both biases; ``gyro`` False: the accelerometer's alone (the gyro's part free)."""
    sigmas = np.r_[[noise.accel_bias_prior_m_s2] * 3, [noise.gyro_bias_prior_rad_s if gyro else FREE_GYRO_BIAS_RAD_S] * 3]
    return gtsam.PriorFactorConstantBias(bias_key, gtsam.imuBias.ConstantBias(), gtsam.noiseModel.Diagonal.Sigmas(sigmas))


ZERO_RATE_SCATTER_FLOOR_RAD_S = 1e-4
"""Least per-sample scatter a zero-rate update assumes, rad/s: a quantised gyro can read one value through a rest (a
scatter of 0), and its noise is then about its step over sqrt(12), not 0."""


def rest_reading(gyro_rad_s: FloatArray, dt_s: FloatArray) -> tuple[FloatArray, float]:
    """An interval's mean gyro reading and its standard error (the readings' own scatter over sqrt(n), at least
    ``ZERO_RATE_SCATTER_FLOOR_RAD_S`` over sqrt(n)), rad/s."""
    # one memory layout and numpy's reductions (no BLAS product): the same readings give the same bits whether they came
    # row- or column-major (an imported session and the one in memory agree to the last digit)
    gyro = np.ascontiguousarray(gyro_rad_s, dtype=float)
    dt = np.ascontiguousarray(dt_s, dtype=float)
    mean = (gyro * dt[:, None]).sum(axis=0) / dt.sum()
    return mean, max(float(np.std(gyro, axis=0).mean()), ZERO_RATE_SCATTER_FLOOR_RAD_S) / math.sqrt(len(gyro))


STEADY_SIGMAS = 3.0
"""Two rest intervals read the same rate when their means differ by at most this many of their combined standard errors
on every axis (a 3-sigma test: a rest edge that turns slowly changes the mean from one interval to the next)."""


def steady_rest(previous: tuple[FloatArray, float], current: tuple[FloatArray, float]) -> bool:
    """Whether two consecutive rest intervals' readings (``rest_reading``) agree: the body turned at neither, or at the
    same rate (which a rest of several intervals does not)."""
    bound = STEADY_SIGMAS * math.sqrt(previous[1] ** 2 + current[1] ** 2)
    return bool(np.all(np.abs(current[0] - previous[0]) <= bound))


def zero_rate_factor(bias_key: int, reading: tuple[FloatArray, float], rest_rate_sigma_rad_s: float = 0.0) -> gtsam.PriorFactorConstantBias:
    """At rest the gyro reads its bias: the gyro part of the interval's bias at the readings' mean (``rest_reading``), its
    sigma their standard error or the rest's own rate (``rest_rate_sigma_rad_s``) where that is larger; the accelerometer's
    part free."""
    mean, standard_error = reading
    sigma = max(standard_error, rest_rate_sigma_rad_s)
    return gtsam.PriorFactorConstantBias(bias_key, gtsam.imuBias.ConstantBias(zeros(3), mean),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.array([FREE_GYRO_BIAS_RAD_S] * 3 + [sigma] * 3)))  # np.r_: ~10 us


def position_prior_factor(pose_key: int, sigma_m: float) -> gtsam.GPSFactor:
    """Zero-mean position pseudo-measurement on a Pose3 (touches only its translation)."""
    return gtsam.GPSFactor(pose_key, zeros(3), isotropic(3, float(sigma_m)))


def velocity_prior_factor(velocity_key: int, sigma_m_s: float) -> gtsam.PriorFactorVector:
    """Zero-mean velocity pseudo-measurement (or a zero-velocity update with a tight sigma)."""
    return gtsam.PriorFactorVector(velocity_key, zeros(3), isotropic(3, float(sigma_m_s)))


def still_samples(gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray, priors: MotionPriors, gravity_m_s2: float = GRAVITY_M_S2) -> np.ndarray:
    """Per sample: is it still (gyro norm small, |a| close to g)? A rest is a long enough run of these."""
    return np.asarray(
        (np.einsum("ij,ij->i", gyro_rad_s, gyro_rad_s) < priors.rest_gyro_rad_s**2)
        & (np.abs(np.sqrt(np.einsum("ij,ij->i", accel_m_s2, accel_m_s2)) - gravity_m_s2) < priors.rest_accel_m_s2)
    )
