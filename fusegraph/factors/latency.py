"""Time offset of a late stream as a variable: the measurement is of the state at (stamp - offset).

A stream stamped with its NOMINAL sample time (arrival minus the assumed latency) really sampled
``delta`` seconds earlier, delta = true latency - assumed latency. For an attitude reading taken on
a body turning at ``omega`` (body frame), to first order

    reading = X(stamp - delta) * Exp(noise) = X(stamp) * Exp(-omega * delta) * Exp(noise).

The offset enters through an *apparent error* g = e - omega * (delta - delta_hat) per sample (e the
sensor's own error; delta_hat the offset already applied when the reading was placed on the
timeline, the running estimate online, so that only the small remainder is first order), tied to
the attitude by the same C++ ``reading = X * Exp(g)`` factor as the tracker error
(``factors.attitude.error_state_factor``). Every law on g is linear in (g, delta), so it is an exact
``LinearContainerFactor``: the offset's Jacobian is the body rate, and the offset variable (one
number, key ``d``) appears in linear factors only. A stationary stretch (omega = 0) leaves delta
to its prior.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from ..geometry import FloatArray
from .attitude import ERROR_TIE_SIGMA_RAD
from .linear import ar1_coefficients, linear_factor


@dataclass(frozen=True)
class LatencyPrior:
    """What is known of a stream's latency before the session: an assumed value and its uncertainty."""

    assumed_s: float
    """Latency the stamps were made with (arrival - assumed = nominal sample time), seconds."""
    sigma_s: float = 0.05
    """Prior sigma of the true latency around the assumed one, seconds."""
    random_walk_s_per_sqrt_s: float = 0.0
    """Drift of the latency, s/sqrt(s); 0 = constant for the session."""


def offset_column(rate: FloatArray) -> FloatArray:
    """d(apparent error)/d(delta) = -omega as a 3x1 block."""
    return -np.asarray(rate, dtype=float).reshape(3, 1)


def offset_prior_factor(offset_key: int, prior: LatencyPrior) -> gtsam.PriorFactorVector:
    """delta ~ N(0, sigma^2): the true latency is the assumed one give or take sigma."""
    return gtsam.PriorFactorVector(offset_key, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, prior.sigma_s))


def offset_walk_factor(prev_key: int, next_key: int, dt_s: float, prior: LatencyPrior) -> gtsam.BetweenFactorVector:
    """A drifting latency: delta_next - delta_prev ~ N(0, q dt)."""
    sigma = max(prior.random_walk_s_per_sqrt_s * np.sqrt(max(dt_s, 1e-9)), 1e-9)
    return gtsam.BetweenFactorVector(prev_key, next_key, np.zeros(1), gtsam.noiseModel.Isotropic.Sigma(1, sigma))


def apparent_white_factor(apparent_key: int, offset_key: int, rate: FloatArray, applied_s: float) -> gtsam.LinearContainerFactor:
    """A sensor with white error only: g + omega * delta = omega * delta_hat (its white noise sits on the reading)."""
    rate = np.asarray(rate, dtype=float)
    return linear_factor([(apparent_key, np.eye(3)), (offset_key, -offset_column(rate))], ERROR_TIE_SIGMA_RAD, rate * applied_s)


def apparent_markov_prior_factor(apparent_key: int, offset_key: int, rate: FloatArray, applied_s: float, sigma: float) -> gtsam.LinearContainerFactor:
    """First sample of a Gauss-Markov sensor error: e = g + omega * (delta - delta_hat) ~ N(0, sigma^2)."""
    rate = np.asarray(rate, dtype=float)
    return linear_factor([(apparent_key, np.eye(3)), (offset_key, -offset_column(rate))], sigma, rate * applied_s)


def apparent_markov_factor(
    prev_key: int,
    next_key: int,
    offset_key: int,
    rate_prev: FloatArray,
    rate_next: FloatArray,
    applied_prev_s: float,
    applied_next_s: float,
    dt_s: float,
    sigma: float,
    tau_s: float,
) -> gtsam.LinearContainerFactor:
    """AR(1) law of the sensor error seen through apparent errors: e_next - phi e_prev ~ N(0, q)."""
    phi, drive_sigma = ar1_coefficients(dt_s, sigma, tau_s)
    rate_prev, rate_next = np.asarray(rate_prev, dtype=float), np.asarray(rate_next, dtype=float)
    offset_block = -offset_column(rate_next) + phi * offset_column(rate_prev)
    rhs = rate_next * applied_next_s - phi * rate_prev * applied_prev_s
    return linear_factor([(prev_key, -phi * np.eye(3)), (next_key, np.eye(3)), (offset_key, offset_block)], drive_sigma, rhs)
