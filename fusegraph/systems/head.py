"""Head tracking end to end: a Session in, one Estimate per method out, every method at the gyro times.

Methods (the rows of the paper's Table 1 plus ours): ``tracker`` (the latest ARRIVED tracker
sample), ``gyro`` (dead reckoning from the first fix), ``kalman``, ``method1``, ``method2`` (the
paper's EKFs), ``isam2`` (fusegraph online: causal estimate after every gyro sample) and ``batch``
(fusegraph smoother over the whole session).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import gtsam
import numpy as np

from ..estimate import Estimate
from ..factors.gyro import integrate_gyro
from ..geometry import quat_from_rotvec, quat_multiply, quat_normalize, quat_wxyz_from_rot3
from ..graphs.head import B, HeadGraphBuilder, HeadModel, X, head_model_for
from ..session import Session, replay_in_arrival_order
from ..solvers.batch import BatchConfig, solve_batch
from ..solvers.ekf import HeadEkfConfig, run_head_ekf
from ..solvers.online import OnlineConfig, OnlineSmoother

METHODS = ("tracker", "gyro", "kalman", "method1", "method2", "isam2", "batch")
"""Method names in the order of the report's rows."""


class HeadBuilder(HeadGraphBuilder):
    """The head graph builder with the keys the online solver asks for."""

    def state_keys(self, k: int) -> tuple[int, int]:
        return X(k), B(k)


def feed(builder: HeadGraphBuilder, session: Session, on_gyro: Callable[[float], None] | None = None) -> None:
    """Push every sample of the session into the builder in arrival order.

    ``on_gyro(t)`` runs after each gyro sample (the online solver updates and reads out there).
    """
    for event in replay_in_arrival_order(session, last_streams=("gyro",)):
        if event.stream.kind == "gyro":
            builder.add_gyro(event.t, event.values)
            if on_gyro is not None:
                on_gyro(event.t)
        elif event.stream.kind == "attitude":
            builder.add_tracker(event.t, event.values)


def _with_latency(session: Session, model: HeadModel) -> Session:
    """Apply the model's assumed tracker latency (if set) to the replay."""
    if model.tracker_latency_s is None:
        return session
    from dataclasses import replace

    streams = dict(session.streams)
    for name, stream in streams.items():
        if stream.kind == "attitude":
            streams[name] = replace(stream, latency_s=model.tracker_latency_s)
    return replace(session, streams=streams)


def run_isam2(session: Session, model: HeadModel | None = None, config: OnlineConfig | None = None) -> Estimate:
    """fusegraph online: replay in arrival order, iSAM2 update per keyframe, causal estimate per gyro sample."""
    model = head_model_for(session, model)
    gyro = session.stream("gyro")
    quats = np.full((len(gyro), 4), np.nan)
    covs = np.full((len(gyro), 3, 3), np.nan)
    builder = HeadBuilder(model)
    solver = OnlineSmoother(builder, config)
    index = {"i": 0}

    def on_gyro(t: float) -> None:
        i = index["i"]
        index["i"] += 1
        solver.update()
        if solver.latest_rot is None or not builder.started:
            return
        kf_rot = solver.latest_rot
        _, now_rot = builder.predict_now(kf_rot, solver.latest_bias)
        quats[i] = quat_wxyz_from_rot3(now_rot)
        covs[i] = builder.predict_cov(solver.latest_cov, solver.latest_bias_cov)

    start = time.perf_counter()
    feed(builder, _with_latency(session, model), on_gyro)
    runtime = time.perf_counter() - start
    extras = {"reanchors": solver.reanchors, "too_late": len(builder.too_late), "tracker_used": builder.tracker_used, "bias_final": solver.latest_bias.tolist()}
    return Estimate("isam2", gyro.t.copy(), quats, covs, runtime, extras)


def run_batch(session: Session, model: HeadModel | None = None, config: BatchConfig | None = None) -> Estimate:
    """fusegraph batch: the same factors as online, optimised together; smoothed attitude per gyro sample."""
    model = head_model_for(session, model)
    gyro = session.stream("gyro")
    start = time.perf_counter()
    builder = HeadBuilder(model)
    feed(builder, _with_latency(session, model))
    increment = builder.take()
    n_kf = len(builder.keyframe_t)
    result = solve_batch(increment.graph(), increment.values, [X(k) for k in range(n_kf)], config)
    kf_t = np.asarray(builder.keyframe_t)
    kf_quat = np.array([quat_wxyz_from_rot3(result.values.atRot3(X(k))) for k in range(n_kf)])
    kf_bias = np.array([result.values.atVector(B(k)) for k in range(n_kf)])
    kf_cov = np.array([result.covariances[X(k)] for k in range(n_kf)]) if result.covariances else None
    quats, covs = interpolate_keyframes(gyro.t, gyro.values, kf_t, kf_quat, kf_bias, kf_cov)
    runtime = time.perf_counter() - start
    extras = {"iterations": result.iterations, "final_error": result.final_error, "too_late": len(builder.too_late), "bias_final": kf_bias[-1].tolist()}
    return Estimate("batch", gyro.t.copy(), quats, covs, runtime, extras)


def interpolate_keyframes(t, omega, kf_t, kf_quat, kf_bias, kf_cov=None):  # type: ignore[no-untyped-def]
    """Attitude at every gyro sample: its keyframe's estimate carried forward by the bias-corrected gyro.

    Vectorised over samples: a sample ``p`` steps after its keyframe composes ``p`` midpoint increments.
    """
    n = len(t)
    quats = np.full((n, 4), np.nan)
    covs = None if kf_cov is None else np.full((n, 3, 3), np.nan)
    kf_index = np.searchsorted(kf_t, t + 1e-9, side="right") - 1
    valid = kf_index >= 0
    kf_sample = np.searchsorted(t, np.asarray(kf_t) - 1e-9)  # gyro index of each keyframe
    idx = np.nonzero(valid)[0]
    k = kf_index[idx]
    steps_after = idx - kf_sample[k]
    q = kf_quat[k].copy()
    rot_total = np.zeros((len(idx), 3))
    for p in range(1, int(steps_after.max(initial=0)) + 1):
        moving = steps_after >= p
        j = kf_sample[k[moving]] + p  # sample at the end of this step
        rate = 0.5 * (omega[j] + omega[j - 1]) - kf_bias[k[moving]]
        step = rate * (t[j] - t[j - 1])[:, None]
        q[moving] = quat_multiply(q[moving], quat_from_rotvec(step))
        rot_total[moving] += step
    quats[idx] = quat_normalize(q)
    if covs is not None and kf_cov is not None:
        covs[idx] = kf_cov[k]  # the <= one keyframe period of gyro adds ~1e-4 rad: negligible here
    return quats, covs


def run_tracker_only(session: Session) -> Estimate:
    """What the tracker alone gives at each gyro instant: its latest ARRIVED sample (latency included)."""
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    start = time.perf_counter()
    last = np.searchsorted(tracker.arrival_t, gyro.t + 1e-9, side="right") - 1
    quats = np.full((len(gyro), 4), np.nan)
    quats[last >= 0] = tracker.values[last[last >= 0]]
    return Estimate("tracker", gyro.t.copy(), quat_normalize(np.where(np.isnan(quats), 1.0, quats)) * np.where(np.isnan(quats), np.nan, 1.0), None, time.perf_counter() - start)


def run_gyro_only(session: Session) -> Estimate:
    """Dead reckoning: integrate the raw gyro from the first tracker fix, from when that fix arrived."""
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    start = time.perf_counter()
    i0 = int(np.argmin(np.abs(gyro.t - tracker.t[0])))
    quats = np.full((len(gyro), 4), np.nan)
    quats[i0:] = integrate_gyro(gyro.t[i0:], gyro.values[i0:], tracker.values[0])
    quats[gyro.t < tracker.arrival_t[0] - 1e-9] = np.nan  # nothing to start from before the fix arrives
    return Estimate("gyro", gyro.t.copy(), quats, None, time.perf_counter() - start)


def run_ekf(session: Session, mode: str, config: HeadEkfConfig | None = None) -> Estimate:
    """One of the paper's EKFs (``kalman``, ``method1``, ``method2``) over the session."""
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    cfg = config or HeadEkfConfig()
    start = time.perf_counter()
    quats, covs = run_head_ekf(mode, gyro.t, gyro.values, tracker.t, tracker.values, cfg, latency_s=tracker.latency_s)  # type: ignore[arg-type]
    return Estimate(mode, gyro.t.copy(), quats, covs, time.perf_counter() - start)


def run_method(session: Session, method: str, model: HeadModel | None = None) -> Estimate:
    """Any method of ``METHODS`` by name."""
    if method == "tracker":
        return run_tracker_only(session)
    if method == "gyro":
        return run_gyro_only(session)
    if method in ("kalman", "method1", "method2"):
        return run_ekf(session, method)
    if method == "isam2":
        return run_isam2(session, model)
    if method == "batch":
        return run_batch(session, model)
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")


def final_values(estimate: Estimate) -> gtsam.Values:  # pragma: no cover - convenience for notebooks
    values = gtsam.Values()
    for i, q in enumerate(estimate.quat_wxyz):
        if np.all(np.isfinite(q)):
            values.insert(X(i), gtsam.Rot3.Quaternion(*q))
    return values
