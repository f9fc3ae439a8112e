"""Interacting multiple models (IMM) for many point targets at once, with range rows from known anchors.

Each target's state is position (3) and velocity (3). Several motion models share it: REST (the
position a slow random walk, the velocity pulled to zero) and one or more constant-velocity models
driven by white acceleration (by default a smooth glide and an agile start or stop). Objects handled
by people alternate between resting and moving; one constant-velocity model tuned for the moves
throws away what a rest offers (averaging over many epochs), and one tuned for rests lags every move.
The IMM keeps a Gaussian per model and the models' probabilities, mixes them before each prediction,
updates each with the same ranges and weighs them by how well each predicted those ranges.

The measurement update is the exact marginal of the two-state graph [previous marginal, motion law,
range rows] (information form, Gauss-Newton: linearised at the prediction, re-linearised at the
first solution, Cauchy weights on every pass after the first; a test checks it against gtsam
eliminating the same graph). Every target and model is solved in the same
batched numpy calls: with gtsam eliminating one small graph per target the Python overhead cost
0.4 ms per target and epoch (measured), more than the whole batched step.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..geometry import FloatArray
from .sequential import constant_velocity

REST = 0


@dataclass(frozen=True)
class MotionModes:
    """The motion models (REST and one or more constant-velocity ones) and how often a target switches."""

    accel_psd: tuple[float, ...] = (0.5, 8.0)
    """White-acceleration spectral densities of the constant-velocity models, (m/s^2)^2/Hz: a smooth
    glide and an agile start or stop."""
    rest_walk_m: float = 0.002
    """REST: position random walk, m/sqrt(s) (a resting object is held, not bolted down)."""
    rest_speed_m_s: float = 0.005
    """REST: sigma of the velocity, which the model pulls to zero, m/s."""
    mean_stay_s: float = 1.0
    """Mean time a target keeps a model before it switches to one of the others (equally likely), s."""

    @property
    def count(self) -> int:
        return 1 + len(self.accel_psd)


@lru_cache(maxsize=16)  # emissions come at a fixed rate: the same dt every epoch
def _transitions(dt: float, modes: MotionModes) -> FloatArray:
    """Pi[i, j] = P(model j now | model i an epoch ago)."""
    m = modes.count
    leave = 1.0 - np.exp(-dt / modes.mean_stay_s)
    pi = np.full((m, m), leave / (m - 1))
    np.fill_diagonal(pi, 1.0 - leave)
    pi.setflags(write=False)  # cached: shared by every later call
    return pi


@lru_cache(maxsize=16)
def _models(dt: float, modes: MotionModes) -> tuple[FloatArray, FloatArray]:
    """Transition matrices (M, 6, 6) and process covariances (M, 6, 6): REST first, then each constant velocity."""
    f_rest = np.zeros((6, 6))
    f_rest[:3, :3] = np.eye(3)
    q_rest = np.diag(np.r_[[modes.rest_walk_m**2 * dt] * 3, [modes.rest_speed_m_s**2] * 3])
    moving = [constant_velocity(dt, [psd] * 3) for psd in modes.accel_psd]
    F, Q = np.stack([f_rest] + [f for f, _ in moving]), np.stack([q_rest] + [q for _, q in moving])
    F.setflags(write=False)  # cached: shared by every later call
    Q.setflags(write=False)
    return F, Q


@dataclass
class Prediction:
    """Per target and model, the mixed and predicted Gaussians, and the models' predicted probabilities."""

    x: FloatArray
    """(T, M, 6) predicted means."""
    P: FloatArray
    """(T, M, 6, 6) predicted covariances."""
    c: FloatArray
    """(T, M) predicted model probabilities."""
    info: FloatArray | None = None
    """(T, M, 6, 6) inverse of P, computed once for every update from this prediction."""

    def information(self) -> FloatArray:
        if self.info is None:
            self.info = np.asarray(np.linalg.inv(self.P), dtype=float)
        return self.info

    def combined(self) -> tuple[FloatArray, FloatArray]:
        """Moment-matched single Gaussian per target: (T, 6) mean, (T, 6, 6) covariance."""
        return combine(self.x, self.P, self.c)


def combine(x: FloatArray, P: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean and covariance of the mixture sum_j w_j N(x_j, P_j), per target."""
    mean = np.einsum("tj,tji->ti", w, x)
    d = x - mean[:, None, :]
    cov = np.einsum("tj,tjab->tab", w, P + d[..., :, None] * d[..., None, :])
    return mean, cov


class PointBank:
    """T point targets, each with one Gaussian per motion model and the models' probabilities."""

    def __init__(self, count: int, modes: MotionModes | None = None):
        self.modes = modes or MotionModes()
        m = self.modes.count
        self.x = np.zeros((count, m, 6))
        self.P = np.tile(np.eye(6), (count, m, 1, 1))
        self.mu = np.full((count, m), 1.0 / m)

    def reset(self, i: int, position_m: FloatArray, position_sigma_m: float = 0.02, speed_sigma_m_s: float = 1.0) -> None:
        """Target i starts again at a position (every model equally likely; velocity unknown)."""
        self.x[i] = np.r_[position_m, np.zeros(3)]
        self.P[i] = np.diag(np.r_[[position_sigma_m**2] * 3, [speed_sigma_m_s**2] * 3])
        self.mu[i] = 1.0 / self.modes.count

    def forbid(self, targets: np.ndarray, model: int) -> None:
        """Give ``model`` no probability for the selected targets (the others share it)."""
        mu = self.mu[targets]
        mu[:, model] = 0.0
        empty = mu.sum(axis=1) <= 0.0  # it had it all: the others start equal
        mu[empty] = 1.0
        mu[:, model] = 0.0
        self.mu[targets] = mu / mu.sum(axis=1, keepdims=True)

    def combined(self) -> tuple[FloatArray, FloatArray]:
        """Each target's moment-matched mean (T, 6) and covariance (T, 6, 6)."""
        return combine(self.x, self.P, self.mu)

    def predict(self, dt: float) -> Prediction:
        """IMM mixing, then each model's prediction over dt (the bank itself is unchanged)."""
        pi = _transitions(dt, self.modes)
        c = self.mu @ pi  # (T, M)
        mix = self.mu[:, :, None] * pi[None, :, :] / np.maximum(c[:, None, :], 1e-300)  # (T, i, j)
        x0 = np.einsum("tij,tia->tja", mix, self.x)
        d = self.x[:, :, None, :] - x0[:, None, :, :]  # (T, i, j, 6)
        P0 = np.einsum("tij,tijab->tjab", mix, self.P[:, :, None] + d[..., :, None] * d[..., None, :])
        F, Q = _models(dt, self.modes)
        x = (F @ x0[..., None])[..., 0]
        P = F @ P0 @ F.transpose(0, 2, 1) + Q  # batched matmul: einsum with three operands is 10x slower here
        return Prediction(x, P, c)

    def update(
        self, prediction: Prediction, anchors_m: FloatArray, ranges_m: FloatArray, sigma_m: float, cauchy_k: float,
        row_weight: FloatArray | None = None, linearise_at: FloatArray | None = None, iterations: int = 2,
        probabilities: bool = True,
    ) -> None:
        """Fold in ranges: ``ranges_m`` (T, K) is target t's distance to its anchor k (``anchors_m`` (K, 3)
        shared by every target, or (T, K, 3) each target its own; an anchor may appear in several
        columns), NaN where it has none; ``row_weight`` (T, K) scales each row's information (an
        association's probability), 1 by default.

        Gauss-Newton from the prediction (or from ``linearise_at``, (T, M, 6), e.g. an earlier solution
        of the same epoch), ``iterations`` times; every pass not linearised at the prediction weighs the
        rows by the Cauchy kernel. ``probabilities`` False keeps the models' predicted probabilities
        (a pass that another will follow)."""
        xp, Pp, c = prediction.x, prediction.P, prediction.c
        anchors_m = anchors_m if anchors_m.ndim == 3 else np.broadcast_to(anchors_m, (len(xp), *anchors_m.shape))
        have = np.isfinite(ranges_m)
        if row_weight is not None:
            have = have * row_weight
        have = have[:, None, :]  # (T, 1, K)
        z = np.nan_to_num(ranges_m)[:, None, :]
        info_prior = prediction.information()
        weight = have / sigma_m**2  # information of each row
        x_lin = xp if linearise_at is None else linearise_at
        for iteration in range(iterations):
            if iteration > 0 or linearise_at is not None:
                # Cauchy weights from the models' combined solution, shared by every model so that their
                # likelihoods below are comparable
                mean = np.einsum("tj,tji->ti", c, x_lin[..., :3])
                residual = z[:, 0, :] - np.linalg.norm(mean[:, None, :] - anchors_m, axis=2)
                weight = have / sigma_m**2 / (1.0 + (residual / (cauchy_k * sigma_m))[:, None, :] ** 2)
            diff = x_lin[:, :, None, :3] - anchors_m[:, None]
            rho = np.linalg.norm(diff, axis=3)
            u = diff / rho[..., None]  # (T, M, K, 3): d range / d position
            info = info_prior.copy()
            info[..., :3, :3] += (u.swapaxes(-1, -2) * weight[..., None, :]) @ u
            innovation = z - rho + (u @ (x_lin[..., :3] - xp[..., :3])[..., None])[..., 0]
            rhs = np.zeros_like(xp)
            rhs[..., :3] = (u.swapaxes(-1, -2) @ (weight * innovation)[..., None])[..., 0]
            x_lin = xp + np.linalg.solve(info, rhs[..., None])[..., 0]
        self.x = x_lin
        self.P = np.asarray(np.linalg.inv(info), dtype=float)
        self.mu = self._probabilities(xp, Pp, c, anchors_m, z, weight) if probabilities else c.copy()

    @staticmethod
    def _probabilities(xp: FloatArray, Pp: FloatArray, c: FloatArray, anchors_m: FloatArray, z: FloatArray, weight: FloatArray) -> FloatArray:
        """Posterior model probabilities: c_j N(z; h(x_j), H P_j H^T + W^-1), in 3 x 3 form (determinant
        lemma and Woodbury; the det(W^-1) both models share cancels)."""
        diff = xp[:, :, None, :3] - anchors_m[:, None]
        rho = np.linalg.norm(diff, axis=3)
        u = diff / rho[..., None]
        r = z - rho
        cov_p = Pp[..., :3, :3]
        inner = np.linalg.inv(cov_p) + (u.swapaxes(-1, -2) * weight[..., None, :]) @ u
        g = (u.swapaxes(-1, -2) @ (weight * r)[..., None])[..., 0]
        quad = np.einsum("tja,tja->tj", weight, r**2) - np.einsum("tji,tji->tj", g, np.linalg.solve(inner, g[..., None])[..., 0])
        logdet = np.linalg.slogdet(cov_p)[1] + np.linalg.slogdet(inner)[1]
        log_lik = -0.5 * (quad + logdet) + np.log(np.maximum(c, 1e-300))
        log_lik -= log_lik.max(axis=1, keepdims=True)
        mu = np.exp(log_lik)
        return np.asarray(mu / mu.sum(axis=1, keepdims=True), dtype=float)
