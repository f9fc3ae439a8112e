"""Exact linear laws among vector variables as C++ factors (``LinearContainerFactor``)."""

from __future__ import annotations

import gtsam
import numpy as np

from ..geometry import FloatArray


def ar1_coefficients(dt_s: float, sigma: float, tau_s: float) -> tuple[float, float]:
    """(phi, drive sigma) of a first-order Gauss-Markov process with stationary ``sigma`` sampled ``dt_s`` apart."""
    phi = float(np.exp(-dt_s / tau_s))
    return phi, sigma * float(np.sqrt(max(1.0 - phi**2, 1e-12)))


def linear_factor(blocks: list[tuple[int, FloatArray]], sigma: float, rhs: FloatArray | None = None) -> gtsam.LinearContainerFactor:
    """sum_i A_i x_i - rhs ~ N(0, sigma^2 I) over vector variables, exact for any value (linearised at 0)."""
    args: list[object] = []
    at_zero = gtsam.Values()
    for key, matrix in blocks:
        args += [key, matrix]
        at_zero.insert(key, np.zeros(matrix.shape[1]))
    rows = blocks[0][1].shape[0]
    b = np.zeros(rows) if rhs is None else np.asarray(rhs, dtype=float)
    jacobian = gtsam.JacobianFactor(*args, b, gtsam.noiseModel.Isotropic.Sigma(rows, sigma))  # type: ignore[call-overload]
    return gtsam.LinearContainerFactor(jacobian, at_zero)
