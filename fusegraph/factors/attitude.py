"""Absolute attitude (a magnetic tracker's world_R_body): white or slowly varying (Gauss-Markov) error.

White error: ``PriorFactorRot3`` on the state at the SAMPLE time.

Gauss-Markov error (reading = world_R_body * Exp(e), e a first-order Markov process): two helper
variables per sample, both C++ factors only:

* ``T`` (Rot3), the reading without its white noise: ``PriorFactorRot3(T, reading, white)``;
* ``e`` (Vector3), tied by ``T = X * Exp(e)``. No built-in factor has this form, but an
  ``AHRSFactor`` whose preintegration is the identity with d(deltaR)/d(bias) = I predicts exactly
  ``X_j = X_i * Exp(bias)``: we use it with (X, T, e) as (rot_i, rot_j, bias). Its Jacobians are
  checked against numerical derivatives in the tests.
* the AR(1) law ``e_j = phi e_i + w`` is linear in vector variables, so it enters as an exact
  ``LinearContainerFactor`` (a JacobianFactor linearised at zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ..catalogue import KeySpec, SensorKind
from ..geometry import FloatArray, rot3_from_quat_wxyz
from .linear import ar1_coefficients, isotropic, linear_factor

_EYE3 = np.eye(3)


@dataclass(frozen=True)
class AttitudeNoise:
    """Error model of an absolute attitude sensor, per axis, in the body frame."""

    white_sigma_deg: float = 0.4
    """White noise per sample, degrees."""
    markov_sigma_deg: float = 0.7
    """Stationary sigma of the slowly varying error, degrees; 0 = white noise only."""
    markov_tau_s: float = 2.0
    """Time constant of the slowly varying error, seconds."""

    @property
    def is_markov(self) -> bool:
        return self.markov_sigma_deg > 0.0

    @property
    def total_sigma_rad(self) -> float:
        return float(np.deg2rad(np.hypot(self.white_sigma_deg, self.markov_sigma_deg)))


@dataclass(frozen=True)
class AttitudeMeasurement:
    """One absolute attitude sample."""

    t: float
    """Sample time, seconds."""
    world_R_body: gtsam.Rot3
    """Measured attitude."""

    @classmethod
    def from_quat(cls, t: float, quat_wxyz: FloatArray) -> AttitudeMeasurement:
        return cls(float(t), rot3_from_quat_wxyz(quat_wxyz))


@dataclass(frozen=True)
class AttitudeTrack:
    """An attitude tracker's samples as an estimator reads them."""

    t: FloatArray
    """Sample times, seconds (increasing)."""
    latency_s: float
    """How long after its sample time each sample reaches an online estimator, seconds."""
    tracker_R_body_wxyz: FloatArray
    """Readings in the tracker's own room frame, quaternions (N, 4)."""
    sigma_rad: float
    """White noise per axis, rad."""


def attitude_prior_factor(key: int, measured: gtsam.Rot3, sigma_rad: float) -> gtsam.PriorFactorRot3:
    """White-noise attitude measurement on the state ``key``."""
    return gtsam.PriorFactorRot3(key, measured, isotropic(3, sigma_rad))


#: Sigma of the T = X * Exp(e) tie, rad: a near-hard constraint that keeps the system well conditioned.
ERROR_TIE_SIGMA_RAD = 1e-4


def _identity_preintegration() -> gtsam.PreintegratedAhrsMeasurements:
    params = gtsam.PreintegratedRotationParams()
    params.setGyroscopeCovariance(np.eye(3))
    return gtsam.PreintegratedAhrsMeasurements(params, np.zeros(3), 0.0, gtsam.Rot3(), np.eye(3), ERROR_TIE_SIGMA_RAD**2 * np.eye(3))


_IDENTITY_PIM = _identity_preintegration()  # the factor copies it; one instance serves every factor


def error_state_factor(state_key: int, reading_key: int, error_key: int) -> gtsam.AHRSFactor:
    """``reading = state * Exp(error)`` as an AHRSFactor with an identity preintegration."""
    return gtsam.AHRSFactor(state_key, reading_key, error_key, _IDENTITY_PIM)


def gauss_markov_factor(prev_key: int, next_key: int, dt_s: float, sigma: float, tau_s: float,
                        at_zero: gtsam.Values | None = None) -> gtsam.LinearContainerFactor:
    """Exact AR(1) transition e_next = phi * e_prev + w of a 3-vector first-order Markov process (``at_zero``: see
    ``linear_factor``)."""
    phi, drive_sigma = ar1_coefficients(dt_s, sigma, tau_s)
    return linear_factor([(prev_key, -phi * _EYE3), (next_key, _EYE3)], drive_sigma, at_zero=at_zero)


def markov_prior_factor(key: int, sigma: float) -> gtsam.PriorFactorVector:
    """Stationary prior N(0, sigma^2) on the first state of a Markov process."""
    return gtsam.PriorFactorVector(key, np.zeros(3), isotropic(3, sigma))

CATALOGUE = (
    SensorKind(
        kind="attitude",
        summary="attitude tracker (magnetic/optical): world_R_body as a quaternion, possibly late (latency_s)",
        columns=("qw", "qx", "qy", "qz"),
        units=("-", "-", "-", "-"),
        frame="world_R_body (scalar first)",
        factors="PriorFactorRot3 on the state at the SAMPLE time (white noise) or a Gauss-Markov error chain; with latency_sigma_s "
        "the latency is a variable",
        keys=(
            KeySpec("noise_sigma_deg", 0.4, "white noise per sample, degrees (> 0)"),
            KeySpec("markov_sigma_deg", 0.0, "stationary sigma of the slowly varying error, degrees (0: white only)"),
            KeySpec("markov_tau_s", 2.0, "correlation time of that error, s"),
            KeySpec("latency_sigma_s", None, "when set, latency_s is only assumed and the latency is estimated with this prior sigma, s"),
            KeySpec("latency_rw_s_per_sqrt_s", 0.0, "random walk of a drifting latency, s/sqrt(s)"),
            KeySpec("latency_true_s", None, "simulations only: the true latency, for scoring (estimators never read it)"),
        ),
        unit_norm=True,
    ),
)
