"""The head paper's EKFs as the paper writes them: noise-free convergence, the delayed-tracker model
H = (I, -d F'), and what Method II does differently from Method I (prediction only between tracker samples)."""

from __future__ import annotations

import numpy as np

from fusegraph.baselines.ekf import HeadEkf, HeadEkfConfig, run_head_ekf
from fusegraph.geometry import euler_rate_matrix, euler_zyx_from_quat, quat_conjugate, quat_from_euler_zyx, quat_multiply, rotvec_from_quat


def _constant_rotation(duration_s: float = 10.0, rate_hz: float = 100.0, tracker_hz: float = 50.0):
    """Euler rates held constant (a slow turn while nodding up): exact gyro and exact tracker readings."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    euler_rates = np.array([0.3, 0.1, -0.05])
    angles = np.array([0.2, -0.1, 0.05]) + t[:, None] * euler_rates
    omega = np.array([np.linalg.solve(euler_rate_matrix(a), euler_rates) for a in angles])  # body rates
    quat = quat_from_euler_zyx(angles)
    rows = np.arange(0, len(t), int(rate_hz / tracker_hz))
    return t, omega, t[rows], quat[rows], quat


def test_noise_free_both_methods_converge_to_the_truth() -> None:
    t, omega, tt, tq, truth = _constant_rotation()
    for mode in ("method1", "method2"):
        quats, _ = run_head_ekf(mode, t, omega, tt, tq, HeadEkfConfig(tracker_latency_s=0.1), latency_s=0.1)  # type: ignore[arg-type]
        late = t > 5.0
        err = np.degrees(np.linalg.norm(rotvec_from_quat(quat_multiply(quat_conjugate(truth[late]), quats[late])), axis=1))
        # the paper's first-order delay model (angles - d E^-1 omega) is exact only for constant Euler-rate
        # mappings; at ~0.3 rad/s its error is ~0.01 deg, the filter's lag adds little more
        assert err.max() < 0.1, (mode, err.max())


def test_tracker_model_is_the_papers_h() -> None:
    ekf = HeadEkf("method1", HeadEkfConfig(tracker_latency_s=0.1))
    ekf.start(0.0, np.array([0.4, 0.2, -0.3]), np.array([0.5, -0.2, 0.1]))
    residual, H, R = ekf._tracker_model(np.array([0.4, 0.2, -0.3]))
    assert np.allclose(H[:, :3], np.eye(3))
    assert np.allclose(H[:, 3:], -0.1 * euler_rate_matrix(ekf.x[:3]))  # (I, -d F'), F' = E^-1
    assert np.allclose(residual, 0.1 * euler_rate_matrix(ekf.x[:3]) @ ekf.x[3:])  # z - (angles - d F' omega)
    assert np.allclose(R, HeadEkfConfig().tracker_sigma_rad**2 * np.eye(3))


def test_method2_only_predicts_between_tracker_samples() -> None:
    """Method II, between tracker samples: the rates are the mean of the 3 preceding gyro samples and there
    is no measurement update (P only grows); Method I updates with every gyro sample (P shrinks)."""
    rng = np.random.default_rng(0)
    samples = rng.normal(0.0, 0.5, (5, 3))
    filters = {mode: HeadEkf(mode) for mode in ("method1", "method2")}  # type: ignore[arg-type]
    for f in filters.values():
        f.start(0.0, np.zeros(3), samples[0])
    for i, omega in enumerate(samples[1:], start=1):
        before = {m: f.P.copy() for m, f in filters.items()}
        for f in filters.values():
            f.gyro(0.01 * i, omega)
        assert np.trace(filters["method2"].P) > np.trace(before["method2"]) - 1e-15  # prediction only
        if i >= 3:
            assert np.allclose(filters["method2"].x[3:], samples[i - 3:i].mean(axis=0))
        assert not np.allclose(filters["method1"].x[3:], filters["method2"].x[3:])
    # at a tracker arrival Method II makes its joint update: the covariance shrinks
    before_p = filters["method2"].P.copy()
    filters["method2"].tracker(np.zeros(3))
    filters["method2"].gyro(0.06, samples[-1])
    assert np.trace(filters["method2"].P) < np.trace(before_p)


def test_euler_angles_round_trip_in_the_helpers() -> None:
    angles = np.array([[0.3, -0.2, 0.1]])
    assert np.allclose(euler_zyx_from_quat(quat_from_euler_zyx(angles)), angles)


def _rate_jacobian(angles: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """The Jacobian of E^-1(angles) @ omega with respect to the angles as ``HeadEkf.predict`` takes it (``_kinematics``)."""
    from fusegraph.baselines.ekf import _kinematics

    _, (j01, j02, j12, j21, j22) = _kinematics(float(angles[1]), float(angles[2]), float(omega[1]), float(omega[2]))
    return np.array([[0.0, j01, j02], [0.0, 0.0, j12], [0.0, j21, j22]])


def test_rate_jacobian_matches_central_differences() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        angles = rng.uniform([-3, -1.3, -3], [3, 1.3, 3])  # inside the Euler domain (|el| < 75 deg)
        omega = rng.normal(0, 2, 3)
        numeric = np.empty((3, 3))
        for j in range(3):
            step = np.zeros(3)
            step[j] = 1e-6
            numeric[:, j] = (euler_rate_matrix(angles + step) @ omega - euler_rate_matrix(angles - step) @ omega) / 2e-6
        # central differences are exact to ~1e-9 here; 1e-6 leaves room for 1/cos(el)^2 up to ~15
        np.testing.assert_allclose(_rate_jacobian(angles, omega), numeric, atol=1e-6)


def test_the_time_update_is_the_state_equation_and_its_jacobian() -> None:
    """``HeadEkf.predict`` (written in Python floats for speed) against the module docstring's state equation written with
    numpy: angles + T E^-1(angles) omega wrapped, P = F P F' + Q with F = I + T [[d(E^-1 omega)/d angles, E^-1], [0, 0]].
    1e-13: the same operations, some summed in another order."""
    from fusegraph.geometry import wrap_angle

    rng = np.random.default_rng(5)
    for _ in range(20):
        ekf = HeadEkf("method2")
        ekf.start(0.0, rng.uniform([-3, -1.3, -3], [3, 1.3, 3]), rng.normal(0, 2, 3))
        ekf.P = np.cov(rng.normal(size=(6, 12)))  # a full covariance: every block of F P F' matters
        x, P, dt = ekf.x.copy(), ekf.P.copy(), 0.0035
        F = np.eye(6)
        F[:3, 3:] = dt * euler_rate_matrix(x[:3])
        F[:3, :3] += dt * _rate_jacobian(x[:3], x[3:])
        ekf.predict(dt)
        np.testing.assert_allclose(ekf.x[:3], wrap_angle(x[:3] + dt * euler_rate_matrix(x[:3]) @ x[3:]), rtol=0, atol=1e-13)
        np.testing.assert_allclose(ekf.P, F @ P @ F.T + ekf._Q, rtol=1e-13, atol=1e-15)


def test_the_compiled_loop_is_head_ekf_sample_by_sample() -> None:
    """``run_head_ekf``'s numba loop against ``HeadEkf`` fed sample by sample (``compiled=False``), every mode, on a noisy
    60 s of turning and nodding (elevation within +-0.7 rad: near +-90 deg the paper's Euler angles are singular and any
    rounding grows without bound) whose tracker stream has a dropout, two samples arriving within one gyro step (the later
    one is used) and one before the first gyro sample. 1e-9 rad: the loop sums the matrix products in another order (~1e-16
    a step), which the filter carries over 6,000 steps; a wrong entry of F or H moves it by 1e-4 or more."""
    t = np.arange(0.0, 60.0, 0.01)
    angles = np.stack([0.3 * t, 0.7 * np.sin(0.5 * t), 0.4 * np.sin(0.7 * t)], axis=1)
    rates = np.stack([np.full_like(t, 0.3), 0.35 * np.cos(0.5 * t), 0.28 * np.cos(0.7 * t)], axis=1)
    rng = np.random.default_rng(11)
    omega = np.array([np.linalg.solve(euler_rate_matrix(a), r) for a, r in zip(angles, rates, strict=True)]) + rng.normal(0.0, 0.05, (len(t), 3))
    rows = np.flatnonzero((np.arange(len(t)) % 2 == 0) & ((t < 20.0) | (t > 23.0)))
    tt = np.concatenate([[-0.05], t[rows], [40.0005]])
    tq = quat_from_euler_zyx(np.concatenate([angles[:1], angles[rows], angles[4000:4001]]))
    order = np.argsort(tt, kind="stable")
    tt, tq = tt[order], tq[order]
    cfg = HeadEkfConfig(process_angle_sigma_rad=0.003, process_rate_sigma_rad_s=0.05, gyro_sigma_rad_s=0.02, tracker_latency_s=0.1)
    for mode in ("method1", "method2", "kalman"):
        compiled = run_head_ekf(mode, t, omega, tt, tq, cfg, latency_s=0.1)  # type: ignore[arg-type]
        reference = run_head_ekf(mode, t, omega, tt, tq, cfg, latency_s=0.1, compiled=False)  # type: ignore[arg-type]
        np.testing.assert_array_equal(np.isnan(compiled[0]), np.isnan(reference[0]))
        err = rotvec_from_quat(quat_multiply(quat_conjugate(reference[0][10:]), compiled[0][10:]))
        assert np.nanmax(np.linalg.norm(err, axis=1)) < 1e-9, mode
        np.testing.assert_allclose(compiled[1], reference[1], rtol=1e-7, atol=1e-15)
