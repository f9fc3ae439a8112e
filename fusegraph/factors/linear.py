"""Exact linear laws among vector variables as C++ factors (``LinearContainerFactor``)."""

from __future__ import annotations

import functools
import math

import gtsam
import numpy as np

from ..geometry import FloatArray


def ar1_coefficients(dt_s: float, sigma: float, tau_s: float) -> tuple[float, float]:
    """(phi, drive sigma) of a first-order Gauss-Markov process with stationary ``sigma`` sampled ``dt_s`` apart."""
    phi = math.exp(-dt_s / tau_s)
    return phi, sigma * math.sqrt(max(1.0 - phi**2, 1e-12))


@functools.lru_cache(maxsize=256)
def isotropic(dim: int, sigma: float) -> gtsam.noiseModel.Isotropic:
    """One shared isotropic noise model per (dim, sigma): a factor keeps a pointer to it, so factors built at a
    steady rate (fixed intervals, fixed sigmas) need not construct one each (~2 us from Python)."""
    return gtsam.noiseModel.Isotropic.Sigma(dim, sigma)


@functools.lru_cache(maxsize=16)
def cauchy(k: float) -> gtsam.noiseModel.mEstimator.Cauchy:
    """One shared Cauchy kernel per width (stateless in gtsam; every robust factor of a session uses the same)."""
    return gtsam.noiseModel.mEstimator.Cauchy(k)


def robust(model: gtsam.noiseModel.Base, cauchy_k: float) -> gtsam.noiseModel.Base:
    """``model`` under a Cauchy kernel of width ``cauchy_k`` sigmas (the shared ``cauchy``); ``model`` itself for 0."""
    return gtsam.noiseModel.Robust.Create(cauchy(cauchy_k), model) if cauchy_k > 0 else model


_ZEROS = {n: np.zeros(n) for n in range(1, 13)}
for _zero in _ZEROS.values():
    _zero.setflags(write=False)  # shared by every factor (gtsam copies them)


def zeros(n: int) -> FloatArray:
    """A zero vector of length n, shared and read-only up to 12 (gtsam copies what it is given)."""
    return _ZEROS[n] if n in _ZEROS else np.zeros(n)


def linear_factor(blocks: list[tuple[int, FloatArray]], sigma: float, rhs: FloatArray | None = None,
                  at_zero: gtsam.Values | None = None) -> gtsam.LinearContainerFactor:
    """sum_i A_i x_i - rhs ~ N(0, sigma^2 I) over vector variables, exact for any value (linearised at 0).

    ``at_zero``: values holding a zero vector for every key of ``blocks`` (others too): a builder that makes such factors
    at a steady rate keeps one set instead of filling a new one per factor (~3 us each); the factor copies its own keys."""
    args: list[object] = []
    fill = at_zero is None
    if at_zero is None:
        at_zero = gtsam.Values()
    for key, matrix in blocks:
        args += [key, matrix]
        if fill:
            at_zero.insert(key, zeros(matrix.shape[1]))
    rows = blocks[0][1].shape[0]
    b = zeros(rows) if rhs is None else np.asarray(rhs, dtype=float)
    jacobian = gtsam.JacobianFactor(*args, b, isotropic(rows, float(sigma)))  # type: ignore[call-overload]
    return gtsam.LinearContainerFactor(jacobian, at_zero)
