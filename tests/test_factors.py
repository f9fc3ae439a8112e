"""Every factor: zero error at the truth, Jacobians against numerical derivatives, exact linear laws."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from conftest import assert_jacobians_match, random_rot3

from fusegraph.factors.attitude import attitude_prior_factor, error_state_factor, gauss_markov_factor
from fusegraph.factors.gyro import (
    GyroInterval,
    GyroNoise,
    calibrated_bias_prior_factor,
    calibrated_bias_walk_factor,
    integrate_gyro,
    integrate_intervals,
    preintegration_params,
    rate_matrix,
)
from fusegraph.geometry import quat_wxyz_from_rot3, rot3_from_quat_wxyz

RNG_SEEDS = range(5)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_error_state_factor_zero_at_truth_and_jacobians(seed: int) -> None:
    rng = np.random.default_rng(seed)
    state = random_rot3(rng)
    error = rng.normal(0, 0.02, 3)
    reading = state.compose(gtsam.Rot3.Expmap(error))
    factor = error_state_factor(1, 2, 3)
    values = gtsam.Values()
    values.insert(1, state)
    values.insert(2, reading)
    values.insert(3, error)
    np.testing.assert_allclose(factor.unwhitenedError(values), 0.0, atol=1e-12)
    # away from the truth, and near a rotation of pi (a near-singular point of Log)
    values.update(3, error + rng.normal(0, 0.05, 3))
    assert_jacobians_match(factor, values)
    values.update(1, gtsam.Rot3.Expmap(np.array([0.0, 0.0, np.pi - 1e-3])))
    assert_jacobians_match(factor, values)


@pytest.mark.parametrize("seed", RNG_SEEDS)
def test_gyro_factor_zero_at_truth_and_jacobians(seed: int) -> None:
    rng = np.random.default_rng(seed)
    noise = GyroNoise()
    omega = rng.normal(0, 1.0, 3)
    bias = rng.normal(0, 0.03, 3)
    interval = GyroInterval(preintegration_params(noise), np.zeros(3), 0.0, omega + bias)
    for i in range(1, 3):
        interval.add(0.01 * i, omega + bias)
    start = random_rot3(rng)
    end = start.compose(gtsam.Rot3.Expmap(omega * 0.02))
    values = gtsam.Values()
    values.insert(1, start)
    values.insert(2, end)
    values.insert(3, bias)
    factor = interval.factor(1, 2, 3)
    # first-order bias correction: residual is second order in the bias times the interval
    assert np.linalg.norm(factor.unwhitenedError(values)) < 1e-5
    assert_jacobians_match(factor, values)


def test_gyro_interval_delta_is_kept_as_it_was() -> None:
    """A rotation read mid-interval (the builder stores them to carry tracker samples between keyframes) must not
    follow the integration on: constant 1 rad/s about x, read after 10 ms, still 10 mrad after 20 ms."""
    interval = GyroInterval(preintegration_params(GyroNoise()), np.zeros(3), 0.0, np.array([1.0, 0.0, 0.0]))
    interval.add(0.01, np.array([1.0, 0.0, 0.0]))
    partial = interval.delta()
    interval.add(0.02, np.array([1.0, 0.0, 0.0]))
    np.testing.assert_allclose(gtsam.Rot3.Logmap(partial), [0.01, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(gtsam.Rot3.Logmap(interval.delta()), [0.02, 0.0, 0.0], atol=1e-12)


def test_attitude_prior_jacobian() -> None:
    rng = np.random.default_rng(0)
    values = gtsam.Values()
    values.insert(1, random_rot3(rng))
    assert_jacobians_match(attitude_prior_factor(1, random_rot3(rng, 0.1), 0.01), values)


def test_gauss_markov_factor_is_the_exact_ar1_law() -> None:
    rng = np.random.default_rng(1)
    sigma, tau, dt = 0.012, 2.0, 0.02
    factor = gauss_markov_factor(1, 2, dt, sigma, tau)
    phi = np.exp(-dt / tau)
    drive = sigma * np.sqrt(1 - phi**2)
    for _ in range(5):
        e1, e2 = rng.normal(0, 0.02, 3), rng.normal(0, 0.02, 3)
        values = gtsam.Values()
        values.insert(1, e1)
        values.insert(2, e2)
        expected = 0.5 * np.sum(((e2 - phi * e1) / drive) ** 2)
        assert factor.error(values) == pytest.approx(expected, rel=1e-10)


def test_calibrated_bias_factors_are_exact_linear_laws() -> None:
    rng = np.random.default_rng(2)
    noise = GyroNoise()
    w1, w2 = rng.normal(0, 1, 3), rng.normal(0, 1, 3)
    K = rng.normal(0, 0.03, (3, 3))
    np.testing.assert_allclose(rate_matrix(w1) @ K.ravel(), K @ w1)
    walk = calibrated_bias_walk_factor(1, 2, 3, w1, w2, 0.02, noise)
    prior = calibrated_bias_prior_factor(1, 3, w1, noise)
    b1, b2 = rng.normal(0, 0.03, 3), rng.normal(0, 0.03, 3)
    values = gtsam.Values()
    values.insert(1, b1 + K @ w1)  # effective biases
    values.insert(2, b2 + K @ w2)
    values.insert(3, K.ravel())
    q = noise.bias_rw_sigma * np.sqrt(0.02)
    assert walk.error(values) == pytest.approx(0.5 * np.sum(((b2 - b1) / q) ** 2), rel=1e-9)
    assert prior.error(values) == pytest.approx(0.5 * np.sum((b1 / noise.bias_prior_sigma_rad_s) ** 2), rel=1e-9)


def test_integrate_gyro_matches_constant_rate_rotation() -> None:
    omega = np.array([0.3, -0.2, 1.1])
    t = np.arange(101) * 0.01
    quats = integrate_gyro(t, np.tile(omega, (101, 1)), np.array([1.0, 0, 0, 0]))
    expected = gtsam.Rot3.Expmap(omega * 1.0)
    np.testing.assert_allclose(rot3_from_quat_wxyz(quats[-1]).matrix(), expected.matrix(), atol=1e-12)
    assert quat_wxyz_from_rot3(expected)[0] >= 0


def test_insert_by_keyword_stores_what_the_positional_insert_stores() -> None:
    from fusegraph.graphs.increment import insert

    rot = gtsam.Rot3.RzRyRx(0.1, -0.2, 0.3)
    pose = gtsam.Pose3(rot, np.array([1.0, 2.0, 3.0]))
    bias = gtsam.imuBias.ConstantBias(np.array([0.1, 0.2, 0.3]), np.array([-0.01, 0.02, -0.03]))
    values = gtsam.Values()
    for key, value in enumerate((rot, pose, bias, np.array([4.0, 5.0]))):
        insert(values, key, value)
    assert values.atRot3(0).equals(rot, 0.0)
    assert values.atPose3(1).equals(pose, 0.0)
    assert values.atConstantBias(2).equals(bias, 0.0)
    np.testing.assert_array_equal(values.atVector(3), [4.0, 5.0])


def test_integrate_intervals_matches_gtsam_preintegration() -> None:
    """The numpy recursion over many intervals at once equals ``GyroInterval`` (gtsam's ``integrateMeasurement``) sample by
    sample: every partial rotation, and per interval the whole preintegration (``equals`` compares the rotation, the bias
    Jacobian and the covariance), the integrated time and the mean rate. Includes a repeated stamp (not integrated) and a
    rate equal to the bias (a zero rotation vector, gtsam's first-order branch)."""
    rng = np.random.default_rng(3)
    params = preintegration_params(GyroNoise())
    bias = np.array([0.01, -0.02, 0.005])
    t = np.cumsum(rng.uniform(0.008, 0.012, 400)) + 1.0
    t[50] = t[49]
    omega = rng.normal(scale=2.0, size=(400, 3))
    omega[100] = bias
    ends = np.r_[np.sort(rng.choice(np.arange(0, 399), 80, replace=False)), 399]
    t_before, omega_before = 1.0, np.array([0.1, 0.2, -0.3])
    integrals = integrate_intervals(params.getGyroscopeCovariance(), bias, t_before, omega_before, t, omega, ends)
    start = 0
    for m, end in enumerate(ends):
        interval = GyroInterval(params, bias, t_before, omega_before)
        for j in range(start, end + 1):
            interval.add(t[j], omega[j])
            # 3x3 products rounded in another order: a few ulp
            np.testing.assert_allclose(integrals.rotation_after[j], interval.delta().matrix(), rtol=0, atol=1e-14)
        pim = gtsam.PreintegratedAhrsMeasurements(params, bias, float(integrals.delta_t_s[m]), gtsam.Rot3(integrals.rotation_after[end]),
                                                  integrals.bias_jacobian[m], integrals.covariance[m])
        assert pim.equals(interval.pim, 1e-13)
        assert integrals.delta_t_s[m] == interval.pim.deltaTij()
        np.testing.assert_array_equal(integrals.angle_sum[m] / interval.elapsed_s if interval.elapsed_s > 0 else omega[end], interval.mean_rate)
        start, t_before, omega_before = end + 1, t[end], omega[end]
