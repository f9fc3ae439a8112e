"""9-axis attitude end to end: Session (gyro, accel, mag) -> Estimate, for fusegraph and every baseline.

Methods: ``online`` (iSAM2, causal: each sample's attitude uses nothing after it), ``batch`` (the same
factors smoothed over the whole session, in two passes: the first levels the magnetometer with dead
reckoning and a Gaussian heading noise, the second with the first's attitude and the Cauchy kernel),
``ekf`` (the founding papers' 9-axis EKF on roll/pitch/yaw), ``vqf`` and ``vqf_offline`` (the peer).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import gtsam
import numpy as np

from ..estimate import Estimate
from ..geometry import quat_wxyz_from_rot3
from ..graphs.attitude9 import Attitude9Builder, Attitude9Model, B, V, X, fill_samples
from ..progress import progress
from ..session import Session
from ..solvers.online import OnlineConfig, OnlineSmoother

#: Online solver settings for this graph: 1 s of keyframes stays live; covariances are not needed per sample.
ONLINE_CONFIG = OnlineConfig(window_s=1.0, reanchor_every=100, relinearize_threshold=0.05, covariance=False)


@dataclass(frozen=True)
class Imu9:
    """A session's synchronous gyro/accelerometer/magnetometer samples."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    mag: np.ndarray | None


def imu9(session: Session) -> Imu9:
    """The gyro, accel and (optional) mag streams, checked to share one clock."""
    gyro, accel = session.stream("gyro"), session.stream("accel")
    if len(gyro) != len(accel) or not np.allclose(gyro.t, accel.t):
        raise ValueError(f"{session.path or session.system}: gyro and accel must be sampled together (same times)")
    mag = None
    if "mag" in session.streams:
        m = session.stream("mag")
        if len(m) != len(gyro) or not np.allclose(m.t, gyro.t):
            raise ValueError(f"{session.path or session.system}: mag must be sampled with the gyro (same times)")
        mag = m.values
    return Imu9(gyro.t, gyro.values, accel.values, mag)


def model_for(session: Session, model: Attitude9Model | None = None) -> Attitude9Model:
    """The model, with the session's magnetometer calibration when it declares one (``mag`` meta gain/offset)."""
    model = model or Attitude9Model()
    if "mag" in session.streams:
        meta = session.stream("mag").meta
        if "calibration_gain" in meta and "calibration_offset" in meta:
            from dataclasses import replace

            from ..factors.mag import MagCalibration

            cal = MagCalibration(tuple(meta["calibration_gain"]), tuple(meta["calibration_offset"]))  # type: ignore[arg-type]
            model = replace(model, mag_calibration=cal)
    return model


def run_online(session: Session, model: Attitude9Model | None = None, config: OnlineConfig | None = None, show_progress: bool = False) -> Estimate:
    """fusegraph online: samples pushed keyframe by keyframe, iSAM2 after each; causal attitude per sample."""
    data = imu9(session)
    builder = Attitude9Builder(model_for(session, model))
    solver = OnlineSmoother(builder, config or ONLINE_CONFIG)
    start = time.perf_counter()
    period = builder.model.keyframe_period_s
    dt = float(np.median(np.diff(data.t)))
    block = max(1, int(round(period / dt)))  # any block size gives the same graph; one keyframe's worth is cheapest
    bar = progress(range(0, len(data.t), block), desc="online", enabled=None if show_progress else False)
    for i in bar:
        j = i + block
        builder.add_samples(data.t[i:j], data.gyro[i:j], data.accel[i:j], None if data.mag is None else data.mag[i:j])
        solver.update()
    quats = fill_samples(data.t, data.gyro, np.array(builder.keyframe_index), np.array(builder.posterior_quat), np.array(builder.posterior_gyro_bias), False)
    runtime = time.perf_counter() - start
    return Estimate("online", data.t.copy(), quats, None, runtime, {"keyframes": len(builder.keyframe_t), "reanchors": solver.reanchors})


def _levenberg(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, order: gtsam.Ordering, max_iterations: int) -> gtsam.Values:
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-5)
    params.setOrdering(order)  # the chain's time order: COLAMD would spend longer than the solve
    return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()


def run_batch(session: Session, model: Attitude9Model | None = None, max_iterations: int = 30) -> Estimate:
    """fusegraph batch: every factor at once, two Levenberg-Marquardt passes; smoothed attitude per sample."""
    data = imu9(session)
    start = time.perf_counter()
    builder = Attitude9Builder(model_for(session, model), deferred_mag=True)
    builder.add_samples(data.t, data.gyro, data.accel, data.mag)
    increment = builder.take()
    keyframes = len(builder.keyframe_t)
    order = gtsam.Ordering()
    for k in range(keyframes):
        for key in (X(k), V(k), B(k)):
            order.push_back(key)
    base = increment.graph()
    initial = increment.values
    values = initial
    attitude = [initial.atPose3(X(k)).rotation() for k in range(keyframes)]
    for robust in (False, True) if builder.mag_readings else (True,):
        graph = gtsam.NonlinearFactorGraph(base)
        for factor in builder.heading_factors(attitude, robust):
            graph.add(factor)
        values = _levenberg(graph, values, order, max_iterations)
        attitude = [values.atPose3(X(k)).rotation() for k in range(keyframes)]
    kq = np.array([quat_wxyz_from_rot3(r) for r in attitude])
    kb = np.array([values.atConstantBias(B(k)).gyroscope() for k in range(keyframes)])
    quats = fill_samples(data.t, data.gyro, np.array(builder.keyframe_index), kq, kb, True)
    runtime = time.perf_counter() - start
    return Estimate("batch", data.t.copy(), quats, None, runtime, {"keyframes": keyframes})


def run_ekf(session: Session, model: Attitude9Model | None = None) -> Estimate:
    """The founding papers' 9-axis EKF on roll/pitch/yaw (the same magnetometer calibration)."""
    from ..solvers.ekf9 import Ekf9Config, run_ekf9

    data = imu9(session)
    if data.mag is None:
        raise ValueError("the 9-axis EKF needs a magnetometer stream")
    cal = model_for(session, model).mag_calibration
    start = time.perf_counter()
    quats = run_ekf9(data.t, data.gyro, data.accel, data.mag, Ekf9Config(mag_gain=cal.gain, mag_offset=cal.offset))
    return Estimate("ekf", data.t.copy(), quats, None, time.perf_counter() - start)


def run_vqf(session: Session, offline: bool = False) -> Estimate:
    from ..solvers.peers import run_vqf as peer

    return peer(session, offline=offline)


METHODS: dict[str, Callable[[Session], Estimate]] = {
    "vqf": run_vqf,
    "vqf_offline": lambda s: run_vqf(s, offline=True),
    "ekf": run_ekf,
    "online": run_online,
    "batch": run_batch,
}
"""Every method of the 9-axis comparison, in the bench's column order."""
