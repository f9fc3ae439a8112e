"""EKF baselines of the head-tracking paper, on ZYX Euler angles + body rates (the paper's state).

State x = (azimuth, elevation, roll, p, q, r). Time update at the gyro rate T:

    angles' = angles + T * E^-1(angles) @ omega,   omega' = omega          (state equation)

with process noise w1 on the angles and w2 on the rates. Gyro: z = omega + v, H = (0, I).
Tracker, sampled d seconds before it arrives: z = angles(t - d) ~ angles - d * E^-1 omega, so the
paper's H = (I, -d F') with F' = E^-1 (the first-order extrapolation of the delay).

* Method I: every measurement its own sequential update (gyro at each sample, tracker on arrival).
* Method II: between tracker samples ONLY the time update r(n+1|n+1) = F r(n|n), with the rates set to
  the mean of the 3 preceding gyro samples (no measurement update: why the paper times it at half of
  Method I); at a tracker arrival one joint update with the stacked H = [(I, -d F'); (0, I)] of the
  tracker and the current gyro sample.
* Kalman (tracker only): the same model without the gyro updates.

What the paper leaves open and is chosen here: the noise figures (``HeadEkfConfig``, the paper's values
where it gives them), "preceding" read as the last three samples before the current one, and the
covariance propagated (P = F P F' + Q) through Method II's prediction-only steps.

Updates use the Joseph form, which keeps P symmetric and positive definite in long runs.

``HeadEkf`` is the filter sample by sample; ``run_head_ekf`` runs it over a session as a loop compiled by numba
(``_ekf_compiled``: the same steps, ~30x faster, held to ``HeadEkf`` by a test).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from ..geometry import FloatArray, euler_rate_matrix, euler_zyx_from_quat, quat_from_euler_zyx, wrap_angle
from ..session import Session, SessionError

EkfMode = Literal["method1", "method2", "kalman"]


@dataclass(frozen=True)
class HeadEkfConfig:
    """Noise figures of the paper (defaults) and the delay the filter assumes."""

    process_angle_sigma_rad: float = 0.01
    """w1: process noise on the angles per step, rad."""
    process_rate_sigma_rad_s: float = 0.15
    """w2: process noise on the body rates per step, rad/s."""
    gyro_sigma_rad_s: float = 0.15
    """Gyro measurement noise, rad/s."""
    tracker_sigma_rad: float = 0.0268
    """Tracker measurement noise, rad (the paper folds the latency error into it)."""
    tracker_latency_s: float = 0.1
    """Delay d the filter assumes for the tracker, seconds."""


_EYE6 = np.eye(6)


class HeadEkf:
    """One of the paper's filters; feed it samples in arrival order and read ``x``, ``P``."""

    def __init__(self, mode: EkfMode, config: HeadEkfConfig | None = None):
        if mode not in ("method1", "method2", "kalman"):
            raise ValueError(f"unknown EKF mode {mode!r}")
        self.mode = mode
        self.cfg = config or HeadEkfConfig()
        self.x = np.zeros(6)
        self.P = np.eye(6)
        self.started = False
        self._t = float("nan")
        self._pending_tracker: FloatArray | None = None
        self._preceding: list[list[float]] = []  # Method II: the last gyro samples (at most 3)
        self._Q = np.diag([self.cfg.process_angle_sigma_rad**2] * 3 + [self.cfg.process_rate_sigma_rad_s**2] * 3)

    def start(self, t: float, angles: FloatArray, omega: FloatArray | None = None) -> None:
        """Initialise from a first tracker fix (and a gyro sample when there is one)."""
        self.x = np.concatenate([angles, np.zeros(3) if omega is None else omega])
        self.P = np.diag([self.cfg.tracker_sigma_rad**2] * 3 + [self.cfg.gyro_sigma_rad_s**2 if omega is not None else 1.0] * 3)
        self._t = t
        self._preceding = [] if omega is None else [np.asarray(omega, dtype=float).tolist()]
        self.started = True

    def predict(self, t: float) -> None:
        """Time update from the last step to ``t``: F = I + dt [[d(E^-1 omega)/d angles, E^-1], [0, 0]], in Python floats
        but for P's products (numpy's per-scalar calls on 3-vectors were most of the filter's time)."""
        dt = t - self._t
        if dt <= 0:
            return
        az, el, roll, p, q, r = self.x.tolist()
        (e01, e02, e11, e12, e21, e22), (j01, j02, j12, j21, j22) = _kinematics(el, roll, q, r)
        f01, f02, f11, f12, f21, f22 = dt * e01, dt * e02, dt * e11, dt * e12, dt * e21, dt * e22  # dt E^-1 (its first column 0, 0, 1)
        F = np.array([[1.0, dt * j01, dt * j02, 0.0, f01, f02], [0.0, 1.0, dt * j12, 0.0, f11, f12], [0.0, dt * j21, 1.0 + dt * j22, dt, f21, f22],
                      [0.0, 0.0, 0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0, 1.0]])
        moved = (az + (f01 * q + f02 * r), el + (f11 * q + f12 * r), roll + (dt * p + f21 * q + f22 * r))
        self.x[:3] = [(angle + math.pi) % (2 * math.pi) - math.pi for angle in moved]  # ``wrap_angle``
        self.P = F @ self.P @ F.T + self._Q
        self._t = t

    def gyro(self, t: float, omega: FloatArray) -> None:
        """A gyro sample at t: time update, then (unless tracker-only) the update(s) of this step."""
        tracker, self._pending_tracker = self._pending_tracker, None
        if self.mode == "method2":
            self._method2(t, np.asarray(omega, dtype=float), tracker)
            return
        self.predict(t)
        if self.mode == "kalman":
            if tracker is not None:
                self._update(*self._tracker_model(tracker))
            return
        H_g = np.hstack([np.zeros((3, 3)), np.eye(3)])
        residual_g = np.asarray(omega) - self.x[3:]
        R_g = self.cfg.gyro_sigma_rad_s**2 * np.eye(3)
        self._update(residual_g, H_g, R_g)
        if tracker is not None:  # method1: the tracker's own sequential update after the gyro's
            self._update(*self._tracker_model(tracker))

    def _method2(self, t: float, omega: FloatArray, tracker: FloatArray | None) -> None:
        """Method II's step: rates from the mean of the 3 preceding gyro samples, the time update, and only
        at a tracker arrival the joint update of tracker and gyro."""
        if self._preceding:  # their mean, per axis in Python floats (the same sums as numpy's)
            self.x[3:] = [sum(axis) / len(self._preceding) for axis in zip(*self._preceding, strict=True)]
        self.predict(t)
        self._preceding = [*self._preceding[-2:], omega.tolist()]
        if tracker is None:
            return
        residual_t, H_t, R_t = self._tracker_model(tracker)
        H_g = np.hstack([np.zeros((3, 3)), np.eye(3)])
        R = np.zeros((6, 6))
        R[:3, :3], R[3:, 3:] = R_t, self.cfg.gyro_sigma_rad_s**2 * np.eye(3)
        self._update(np.concatenate([residual_t, omega - self.x[3:]]), np.vstack([H_t, H_g]), R)

    def tracker(self, angles: FloatArray) -> None:
        """A tracker sample ARRIVED; it is used with the next gyro step (same instant in the paper)."""
        self._pending_tracker = np.asarray(angles, dtype=float)

    def _tracker_model(self, angles: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        d = self.cfg.tracker_latency_s
        rate_matrix = euler_rate_matrix(self.x[:3])
        predicted = self.x[:3] - d * rate_matrix @ self.x[3:]
        H = np.hstack([np.eye(3), -d * rate_matrix])
        return wrap_angle(angles - predicted), H, self.cfg.tracker_sigma_rad**2 * np.eye(3)

    def _update(self, residual: FloatArray, H: FloatArray, R: FloatArray) -> None:
        self.x, self.P = joseph_update(self.x, self.P, residual, H, R, angle_rows=slice(0, 3))

    def attitude_cov_body(self) -> FloatArray:
        """Covariance of the attitude as a body-frame rotation vector (for NEES against gtsam's)."""
        return attitude_cov_body(self.x[:3], self.P[:3, :3])


def attitude_cov_body(angles: FloatArray, angle_cov: FloatArray) -> FloatArray:
    """Covariance of ZYX angles (..., 3) with covariance (..., 3, 3) as a body-frame rotation vector."""
    el, roll = angles[..., 1], angles[..., 2]
    # body rates = M @ euler rates, so a small angle change maps to Exp(M @ d_angles) on the right
    M = np.zeros((*np.shape(el), 3, 3))
    M[..., 0, 0], M[..., 0, 2] = -np.sin(el), 1.0
    M[..., 1, 0], M[..., 1, 1] = np.cos(el) * np.sin(roll), np.cos(roll)
    M[..., 2, 0], M[..., 2, 1] = np.cos(el) * np.cos(roll), -np.sin(roll)
    return M @ angle_cov @ np.swapaxes(M, -1, -2)


def joseph_update(
    x: FloatArray, P: FloatArray, residual: FloatArray, H: FloatArray, R: FloatArray, angle_rows: slice = slice(0, 3)
) -> tuple[FloatArray, FloatArray]:
    """Kalman update in Joseph form (P stays symmetric positive definite); angles wrapped to [-pi, pi)."""
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    x = x + K @ residual
    x[angle_rows] = wrap_angle(x[angle_rows])
    I_KH = np.eye(len(x)) - K @ H
    return x, I_KH @ P @ I_KH.T + K @ R @ K.T


def _kinematics(el: float, roll: float, q: float, r: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The entries of E^-1 at (el, roll) other than its first column (0, 0, 1) (``geometry.euler_rate_matrix``), and the
    non-zero ones of the Jacobian of E^-1 @ omega with respect to the angles, from one evaluation of the sines and cosines.

    With a = q sin(roll) + r cos(roll) and b = q cos(roll) - r sin(roll): d(az)/dt = a / cos(el),
    d(el)/dt = b, d(roll)/dt = p + a tan(el); da/droll = b, db/droll = -a; nothing depends on az.
    """
    ce, se, cr, sr = math.cos(el), math.sin(el), math.cos(roll), math.sin(roll)
    a, b = q * sr + r * cr, q * cr - r * sr
    return (sr / ce, cr / ce, cr, -sr, sr * se / ce, cr * se / ce), (a * se / ce**2, b / ce, -a, a / ce**2, b * se / ce)


def run_head_ekf(
    mode: EkfMode,
    t_gyro: FloatArray,
    omega: FloatArray,
    t_tracker: FloatArray,
    quat_tracker: FloatArray,
    config: HeadEkfConfig | None = None,
    latency_s: float = 0.1,
    compiled: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Run a filter over a session; attitude quaternions (N, 4) and covariances (N, 3, 3) at gyro times.

    Rows before the first tracker sample has arrived are NaN (no estimate yet). ``compiled``: the loop compiled by numba
    (``_ekf_compiled.head_ekf_loop``, the same steps as ``HeadEkf``'s; ~1 us a sample where ``HeadEkf`` takes ~30); False runs
    ``HeadEkf`` sample by sample (the reference a test holds the compiled loop to).
    """
    if mode not in ("method1", "method2", "kalman"):
        raise ValueError(f"unknown EKF mode {mode!r}")
    cfg = config or HeadEkfConfig()
    arrival = np.ascontiguousarray(t_tracker, dtype=float) + latency_s
    angles_tracker = np.ascontiguousarray(euler_zyx_from_quat(quat_tracker), dtype=float)
    t_gyro = np.ascontiguousarray(t_gyro, dtype=float)
    omega = np.ascontiguousarray(omega, dtype=float)
    if compiled:
        from ._ekf_compiled import head_ekf_loop  # numba: imported when a filter first runs (``load_compiled``)

        angles, angle_covs = head_ekf_loop(("method1", "method2", "kalman").index(mode), t_gyro, omega, arrival, angles_tracker,
                                           cfg.process_angle_sigma_rad, cfg.process_rate_sigma_rad_s, cfg.gyro_sigma_rad_s,
                                           cfg.tracker_sigma_rad, cfg.tracker_latency_s)
        return quat_from_euler_zyx(angles), attitude_cov_body(angles, angle_covs)
    ekf = HeadEkf(mode, cfg)
    angles = np.full((len(t_gyro), 3), np.nan)
    angle_covs = np.full((len(t_gyro), 3, 3), np.nan)
    j = 0
    for i, t in enumerate(t_gyro):
        while j < len(arrival) and arrival[j] <= t + 1e-9:
            if not ekf.started:
                ekf.start(t, angles_tracker[j], None if mode == "kalman" else omega[i])
            else:
                ekf.tracker(angles_tracker[j])
            j += 1
        if not ekf.started:
            continue
        ekf.gyro(t, omega[i])
        angles[i] = ekf.x[:3]
        angle_covs[i] = ekf.P[:3, :3]
    return quat_from_euler_zyx(angles), attitude_cov_body(angles, angle_covs)


@functools.cache
def load_compiled() -> None:
    """Import the compiled loop, once per process: numba's import and its machine code (compiled on a machine's first run,
    ~5 s, then loaded from numba's cache, ~1 s). A caller that times a run calls this first, so that the time is the filter's."""
    from ._ekf_compiled import head_ekf_loop

    two = np.zeros(2)
    head_ekf_loop(0, two, np.zeros((2, 3)), two, np.zeros((2, 3)), 0.01, 0.15, 0.15, 0.0268, 0.1)  # compiles or loads it


def ekf_config_from(setting: Mapping[str, Any]) -> HeadEkfConfig:
    """The paper's EKF figures at a tuning setting: ``process_scale`` x the paper's process noise (w1, w2),
    ``gyro_sigma_rad_s``, and ``tracker_sigma_rad`` when given (else the paper's)."""
    base = HeadEkfConfig()
    return replace(base, process_angle_sigma_rad=float(setting["process_scale"]) * base.process_angle_sigma_rad,
                   process_rate_sigma_rad_s=float(setting["process_scale"]) * base.process_rate_sigma_rad_s,
                   gyro_sigma_rad_s=float(setting["gyro_sigma_rad_s"]), tracker_sigma_rad=float(setting.get("tracker_sigma_rad", base.tracker_sigma_rad)))


def declared_ekf(session: Session) -> HeadEkfConfig | None:  # the head preset's [ekf] table
    """The paper's EKF figures a session declares in ``[ekf]`` (``process_scale``, ``gyro_sigma_rad_s``, optional
    ``tracker_sigma_rad``), or None."""
    table = session.meta.get("ekf")
    if not table:
        return None
    missing = [key for key in ("process_scale", "gyro_sigma_rad_s") if key not in table]
    if missing:
        raise SessionError(f"{session.where}: [ekf] needs {' and '.join(missing)} too (the paper's EKF figures are declared together)")
    return ekf_config_from(table)
