"""Cyclist: the non-holonomic factor, two bodies in one graph, the coupled graph against the paper's pipeline."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from conftest import assert_jacobians_match

from fusegraph.factors.vehicle import NonholonomicNoise, nonholonomic_factor
from fusegraph.scenarios.bicycle import BicycleScenarioConfig, simulate_bicycle
from fusegraph.systems import bicycle


def test_nonholonomic_factor_jacobians_and_zero_along_the_axis() -> None:
    rng = np.random.default_rng(2)
    for _ in range(5):
        pose = gtsam.Pose3(gtsam.Rot3.Ypr(*rng.uniform(-1, 1, 3)), rng.uniform(-3, 3, 3))
        values = gtsam.Values()
        values.insert(1, pose)
        values.insert(2, rng.uniform(-5, 5, 3))
        factor = nonholonomic_factor(1, 2, NonholonomicNoise())
        assert_jacobians_match(factor, values)
        values.update(2, pose.rotation().matrix() @ np.array([7.0, 0.0, 0.0]))  # moving along its own x
        assert np.abs(factor.unwhitenedError(values)).max() < 1e-12


@pytest.fixture(scope="module")
def ride() -> bicycle.BicycleSession:
    return simulate_bicycle(1)


def test_coupled_graph_beats_the_pipeline_in_the_braking_phase(ride: bicycle.BicycleSession) -> None:
    r = {name: bicycle.braking_rms_deg(run(ride), ride) for name, run in bicycle.RUNNERS.items()}  # type: ignore[operator]
    tilt = {name: float(np.hypot(v["pitch_deg"], v["roll_deg"])) for name, v in r.items()}
    # the figures `fusegraph report bicycle` prints. Per seed the EKF baselines swing widely in one angle
    # or the other (seed 1: pipeline pitch 0.49 but roll 4.5 deg), so the tilt (both angles) is compared;
    # the 0.7 x target itself is on the report's RMS over seeds
    assert tilt["online"] < 0.7 * tilt["paper_pipeline"], r
    assert tilt["online"] < tilt["no_removal"], r
    assert tilt["batch"] < tilt["online"], r
    assert tilt["batch"] < 0.5, r  # degrees: measured 0.22 on this seed


def test_stand_ride_has_no_translation() -> None:
    s = simulate_bicycle(0, BicycleScenarioConfig(ride="stand", duration_s=5.0, brake_s=3.0))
    # on a trainer the frame IMU feels gravity only: |a| = g to the noise
    assert abs(np.linalg.norm(s.frame_accel, axis=1).mean() - 9.80665) < 0.05
    with pytest.raises(ValueError, match="unknown ride"):
        simulate_bicycle(0, BicycleScenarioConfig(ride="track"))


def test_report_rows_tell_every_method_its_sigmas_halved_and_doubled() -> None:
    from fusegraph.evaluation.bicycle import _report_runners

    runners = _report_runners(noise_rows=True)
    methods = ("no_removal", "paper_pipeline", "online", "batch")
    assert set(runners) == set(methods) | {f"{m}_noise_x{k:g}" for m in methods for k in (0.5, 2.0)}
    doubled = bicycle.PAPER_EKF.with_noise_scaled(2.0)
    assert doubled.gyro_sigma_rad_s == 2.0 * bicycle.PAPER_EKF.gyro_sigma_rad_s
    assert doubled.accel_sigma_m_s2 == 2.0 * bicycle.PAPER_EKF.accel_sigma_m_s2
    model = bicycle.BicycleModel().thigh
    halved = model.with_noise_scaled(0.5)
    assert halved.imu.accel_noise_m_s2_sqrt_hz == 0.5 * model.imu.accel_noise_m_s2_sqrt_hz
    assert halved.gravity is not None and model.gravity is not None and halved.gravity.sigma_deg == 0.5 * model.gravity.sigma_deg
