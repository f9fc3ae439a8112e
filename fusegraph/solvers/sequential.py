"""One step of an exactly marginalising smoother on a small vector state (fixed lag 0), and the
constant-velocity law it usually carries.

Factors: the previous marginal as a prior on the old state, the motion law x_new = F x_old + w
(whitened by W, W^T W = Q^-1), and measurement rows already whitened and linearised; gtsam
eliminates the old state (QR) and the last conditional is the new marginal, its square-root
information R and mean. Used by trackers that solve many small independent states per epoch.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from ..geometry import FloatArray

_ORDER = gtsam.Ordering()  # old state, then the new one: the new one's marginal is the last conditional
_ORDER.push_back(0)
_ORDER.push_back(1)


def constant_velocity(dt: float, psd: Sequence[float]) -> tuple[FloatArray, FloatArray]:
    """Transition F and covariance Q over dt for a state [positions (k), rates (k)] driven by white
    acceleration of density ``psd[i]`` on axis i."""
    k = len(psd)
    F = np.eye(2 * k)
    F[:k, k:] = dt * np.eye(k)
    q = np.diag(np.asarray(psd, dtype=float))
    Q = np.block([[dt**3 / 3 * q, dt**2 / 2 * q], [dt**2 / 2 * q, dt * q]])
    return F, Q


def whitening(Q: FloatArray) -> FloatArray:
    """W with W^T W = Q^-1."""
    return np.asarray(np.linalg.inv(np.linalg.cholesky(Q)), dtype=float)


def covariance(sqrt_info: FloatArray) -> FloatArray:
    """Covariance of a marginal given its upper-triangular square-root information."""
    r_inv = np.linalg.inv(sqrt_info)  # triangular: better conditioned than inverting R^T R
    return np.asarray(r_inv @ r_inv.T, dtype=float)


class MarginalStep:
    """Prior and motion factors of one step, built once; ``solve`` adds measurement rows (any number of times)."""

    def __init__(self, sqrt_info: FloatArray, x_old: FloatArray, F: FloatArray, W: FloatArray):
        n = len(x_old)
        unit = gtsam.noiseModel.Unit.Create(n)
        self._prior = gtsam.JacobianFactor(0, sqrt_info, sqrt_info @ x_old, unit)
        self._motion = gtsam.JacobianFactor(0, -W @ F, 1, W, np.zeros(n), unit)

    def solve(self, A: FloatArray | None = None, b: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
        """New marginal (R, mean) with whitened rows A x_new ~ b (None: prediction only)."""
        graph = gtsam.GaussianFactorGraph()
        graph.add(self._prior)
        graph.add(self._motion)
        if A is not None and b is not None and len(b):
            graph.add(gtsam.JacobianFactor(1, A, b, gtsam.noiseModel.Unit.Create(len(b))))
        conditional = graph.eliminateSequential(_ORDER).at(1)
        R = np.array(conditional.R(), copy=True)  # R() and d() view the conditional's memory: copy before it goes
        return R, np.asarray(np.linalg.solve(R, np.array(conditional.d(), copy=True)), dtype=float)
