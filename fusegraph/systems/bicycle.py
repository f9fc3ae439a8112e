"""Cyclist's thigh attitude with the bicycle's acceleration removed: no removal, the paper's pipeline,
and fusegraph's coupled graph (online and batch), on the ``bicycle`` scenario.

- ``no_removal``: the 9-axis EKF on the thigh alone.
- ``paper_pipeline``: the 9-axis EKF on the frame -> the frame's translational acceleration
  (its accelerometer rotated to the world, gravity removed) -> subtracted from the thigh's
  accelerometer (rotated with the thigh EKF's predicted attitude) -> the thigh EKF. Both causal.
- ``online`` / ``batch``: both bodies in one graph coupled by their velocities (``graphs.bicycle``).

The EKFs use a constant accelerometer noise, as the paper's filter does (the paper gives no figures:
each baseline's gyro and accelerometer sigmas are chosen for it on tuning seeds 100-119), rather than the
BROAD EKF's inflation with | |a| - g |, which would hide most of the braking from both baselines alike.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..baselines.ekf9 import Ekf9Config, run_ekf9
from ..factors.imu import GRAVITY_M_S2
from ..geometry import FloatArray, matrix_from_quat, quat_wxyz_from_rot3
from ..graphs.attitude9 import fill_samples
from ..graphs.bicycle import BicycleModel, CoupledBuilder
from ..metrics import euler_errors
from ..records import BicycleScenarioConfig, BicycleSession
from ..session import Session
from ..solvers.batch import solve_python_loop
from ..solvers.online import OnlineConfig, OnlineSmoother
from ..tuned import tuned

METHODS = ("no_removal", "paper_pipeline", "online", "batch")


def _ekf_tuned(study: str) -> Ekf9Config:
    """The 9-axis EKF with a constant accelerometer noise and the noise figures a study chose (``Ekf9Config.from_setting``)."""
    return Ekf9Config.from_setting(tuned(study), accel_inflation=0.0)


PAPER_EKF = _ekf_tuned("bicycle_ekf")
"""The pipeline's EKFs (frame and thigh) with a constant accelerometer noise (the paper gives no values): gyro and
accelerometer sigma chosen for the pipeline by ``fusegraph tune bicycle_ekf`` on seeds 100-119 (``tuned.toml``)."""
NO_REMOVAL_EKF = _ekf_tuned("bicycle_no_removal")
"""The thigh's EKF alone, its sigmas chosen for itself by the same rule (``fusegraph tune bicycle_no_removal``): a
baseline run with the pipeline's settings would be judged on figures chosen for another filter."""

ONLINE = OnlineConfig(window_s=1.0, reanchor_every=10, relinearize_threshold=0.05, covariance=False, factorization="QR", relinearize=False)
"""iSAM2 as the 9-axis system but with QR (Cholesky reported an indeterminate system on this well-posed
graph, with or without relinearisation) and no relinearisation between re-anchorings (every 2 s, which
relinearise the kept factors anyway): a speed setting, 31-39x -> ~98x real time with the braking RMS unchanged to
0.02 deg (checked on seeds 0-2 when it was chosen; it chooses no accuracy trade-off)."""


def from_session(session: Session) -> BicycleSession:
    """A bicycle session directory's content: ``thigh_*`` and ``frame_*`` gyro/accel/mag streams sampled
    together; ``brake_s`` in ``[session]`` (the braking phase scored); the thigh attitude as the optional truth."""
    names = [f"{body}_{kind}" for body in ("thigh", "frame") for kind in ("gyro", "accel", "mag")]
    streams = dict(zip(names, session.synchronous(*names), strict=True))
    t = streams["thigh_gyro"].t
    header = session.meta.get("session", {})
    config = BicycleScenarioConfig(ride=str(header.get("ride", "downhill")), duration_s=float(t[-1] - t[0]), brake_s=float(header.get("brake_s", np.nan)))
    truth = np.full((len(t), 4), np.nan)
    if session.truth is not None and session.truth.kind == "attitude":  # on the sensors' clock: at the times kept
        index = np.clip(np.searchsorted(session.truth.t, t), 0, len(session.truth) - 1)
        if np.allclose(session.truth.t[index], t, rtol=0.0, atol=1e-9):
            truth = session.truth.values[index].copy()
    v = {name: s.values for name, s in streams.items()}
    return BicycleSession(t=t, thigh_gyro=v["thigh_gyro"], thigh_accel=v["thigh_accel"], thigh_mag=v["thigh_mag"], frame_gyro=v["frame_gyro"],
                          frame_accel=v["frame_accel"], frame_mag=v["frame_mag"], thigh_quat_wxyz=truth, frame_quat_wxyz=np.full((len(t), 4), np.nan),
                          config=config)


def run_no_removal(s: BicycleSession, config: Ekf9Config = NO_REMOVAL_EKF) -> FloatArray:
    return run_ekf9(s.t, s.thigh_gyro, s.thigh_accel, s.thigh_mag, config)


def run_pipeline(s: BicycleSession, config: Ekf9Config = PAPER_EKF) -> FloatArray:
    frame_q = run_ekf9(s.t, s.frame_gyro, s.frame_accel, s.frame_mag, config)
    linear = np.einsum("nij,nj->ni", matrix_from_quat(frame_q), s.frame_accel) - np.array([0.0, 0.0, GRAVITY_M_S2])
    return run_ekf9(s.t, s.thigh_gyro, s.thigh_accel, s.thigh_mag, config, linear_accel_world=linear)


def _imu(s: BicycleSession, i: int, j: int) -> tuple[tuple[FloatArray, FloatArray, FloatArray], tuple[FloatArray, FloatArray, FloatArray]]:
    return (s.thigh_gyro[i:j], s.thigh_accel[i:j], s.thigh_mag[i:j]), (s.frame_gyro[i:j], s.frame_accel[i:j], s.frame_mag[i:j])


def run_online(s: BicycleSession, model: BicycleModel | None = None) -> FloatArray:
    """Causal thigh attitude per sample."""
    builder = CoupledBuilder(model or BicycleModel())
    solver = OnlineSmoother(builder, ONLINE)  # type: ignore[arg-type]
    block = max(1, int(round(builder.thigh.model.keyframe_period_s / float(np.median(np.diff(s.t))))))
    for i in range(0, len(s.t), block):
        thigh, frame = _imu(s, i, i + block)
        builder.add_samples(s.t[i : i + block], thigh, frame)
        solver.update()
    th = builder.thigh
    return fill_samples(s.t, s.thigh_gyro, *th.solved_keyframes(), False)


def run_batch(s: BicycleSession, model: BicycleModel | None = None) -> FloatArray:
    """Smoothed thigh attitude per sample (two passes, as the 9-axis batch)."""
    builder = CoupledBuilder(model or BicycleModel(), deferred_mag=True)
    thigh, frame = _imu(s, 0, len(s.t))
    builder.add_samples(s.t, thigh, frame)
    increment = builder.take()
    n = len(builder.keyframe_t)
    values = increment.values
    bodies = (builder.frame, builder.thigh)
    attitude = {b.prefix: [values.atPose3(b.X(k)).rotation() for k in range(n)] for b in bodies}
    for robust in (False, True):
        graph = increment.graph()
        for b in bodies:
            for factor in b.heading_factors(attitude[b.prefix], robust):
                graph.add(factor)
        # Gauss-Newton driven from Python: the non-holonomic CustomFactors would each get a copy of
        # every variable from gtsam's C++ optimisers (measured: LM 6x real time, this loop ~40x)
        values = solve_python_loop(graph, values, max_iterations=20, relative_error_tol=1e-4).values
        attitude = {b.prefix: [values.atPose3(b.X(k)).rotation() for k in range(n)] for b in bodies}
    th = builder.thigh
    kq = np.array([quat_wxyz_from_rot3(r) for r in attitude["t"]])
    kb = np.array([values.atConstantBias(th.B(k)).gyroscope() for k in range(n)])
    return fill_samples(s.t, s.thigh_gyro, np.array(th.keyframe_index), kq, kb, True)


def braking_rms_deg(quat: FloatArray, s: BicycleSession) -> dict[str, float]:
    """Thigh pitch and roll error RMS over the braking phase, degrees."""
    err = np.degrees(euler_errors(quat[s.braking], s.thigh_quat_wxyz[s.braking]))
    return {"pitch_deg": float(np.sqrt(np.mean(err[:, 1] ** 2))), "roll_deg": float(np.sqrt(np.mean(err[:, 2] ** 2)))}


RUNNERS = {"no_removal": run_no_removal, "paper_pipeline": run_pipeline, "online": run_online, "batch": run_batch}




def declared(session: Session) -> tuple[BicycleModel, Ekf9Config, Ekf9Config]:
    """The graph model and the two EKF settings with what the session's gyro streams declare (``noise_sigma_rad_s`` per
    sample: the graph's white-noise density per body, sigma over the square root of the rate; the EKFs' gyro sigma,
    the thigh's where the two bodies differ, as the paper's pipeline runs one setting on both)."""
    from .attitude9 import declared_gyro_density

    model = BicycleModel()
    bodies = {}
    for body in ("thigh", "frame"):
        density = declared_gyro_density(session, f"{body}_gyro")
        chain = getattr(model, body)
        bodies[body] = chain if density is None else replace(chain, imu=replace(chain.imu, gyro_noise_rad_s_sqrt_hz=density))
    model = replace(model, **bodies)
    paper, alone = PAPER_EKF, NO_REMOVAL_EKF
    for name in ("thigh_gyro", "frame_gyro"):
        if name in session.streams and "noise_sigma_rad_s" in session.stream(name).meta:
            sigma = float(session.stream(name).meta["noise_sigma_rad_s"])
            paper, alone = replace(paper, gyro_sigma_rad_s=sigma), replace(alone, gyro_sigma_rad_s=sigma)
            break
    return model, paper, alone


def run_declared(session: Session, solver: str) -> tuple[FloatArray, FloatArray]:
    """A bicycle session's solver (``no_removal``, ``paper_pipeline``, ``online``, ``batch``) with its declared settings:
    the sample times (those every stream has) and the thigh attitude there."""
    ride = from_session(session)
    model, paper, alone = declared(session)
    if solver == "no_removal":
        return ride.t, run_no_removal(ride, alone)
    if solver == "paper_pipeline":
        return ride.t, run_pipeline(ride, paper)
    return ride.t, {"online": run_online, "batch": run_batch}[solver](ride, model)
