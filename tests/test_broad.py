"""BROAD loader and the benchmark's metric (real-data tests skip with a reason when the data is absent)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import requires_shared_data

from fusegraph import SessionError
from fusegraph.datasets.broad import DEFAULT_DIR, load_broad, trial_paths
from fusegraph.geometry import quat_from_rotvec, quat_multiply
from fusegraph.metrics import broad_errors


def test_metric_splits_heading_and_inclination() -> None:
    rng = np.random.default_rng(0)
    truth = quat_from_rotvec(rng.normal(0, 1, (200, 3)))
    moving = np.ones(200)
    yaw = quat_multiply(quat_from_rotvec(np.tile([0, 0, np.deg2rad(10.0)], (200, 1))), truth)  # earth-frame yaw error
    errors = broad_errors(yaw, truth, moving)
    assert errors.total == pytest.approx(10.0) and errors.heading == pytest.approx(10.0)
    assert errors.inclination == pytest.approx(0.0, abs=1e-6)
    tilt = quat_multiply(quat_from_rotvec(np.tile([np.deg2rad(5.0), 0, 0], (200, 1))), truth)
    errors = broad_errors(tilt, truth, moving)
    assert errors.inclination == pytest.approx(5.0) and errors.heading == pytest.approx(0.0, abs=1e-6)


def test_metric_scores_only_movement_with_truth() -> None:
    truth = np.tile([1.0, 0, 0, 0], (4, 1))
    truth[1] = np.nan
    estimate = quat_from_rotvec(np.array([[0, 0, 0.1], [0, 0, 0.5], [0, 0, 0.9], [0, 0, 0.1]]))
    errors = broad_errors(estimate, truth, np.array([1, 1, 0, 1]))
    assert errors.samples == 2  # row 1 has no truth, row 2 no movement
    assert errors.total == pytest.approx(np.rad2deg(0.1))
    with pytest.raises(ValueError, match="no sample to score"):
        broad_errors(estimate, truth, np.zeros(4))


def test_missing_trial_is_a_clear_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(SessionError, match="BROAD trial not found"):
        load_broad(tmp_path / "01_nothing.mat")


@requires_shared_data("broad")
def test_real_trials_load_and_truth_scores_zero() -> None:
    paths = trial_paths(DEFAULT_DIR)
    assert len(paths) >= 10  # ../shared grows (trial 08 joined as a regression case)
    session = load_broad(paths[0])
    gyro = session.stream("gyro")
    assert gyro.meta["rate_hz"] == pytest.approx(285.714, abs=1e-3)
    assert len(gyro) == len(session.stream("accel")) == len(session.stream("mag"))
    assert session.truth is not None and np.isnan(session.truth.values).any()  # occlusions are kept, as NaN
    accel_norm = np.median(np.linalg.norm(session.stream("accel").values, axis=1))
    assert accel_norm == pytest.approx(9.81, abs=0.1)  # m/s^2: gravity at rest
    movement = session.stream("movement").values[:, 0]
    errors = broad_errors(session.truth.values, session.truth.values, movement)
    assert errors.total == pytest.approx(0.0, abs=1e-6) and errors.samples > 10_000


@requires_shared_data("broad")
def test_vqf_reproduces_the_reference_figures_on_the_shared_trials() -> None:
    pytest.importorskip("vqf")
    from fusegraph.baselines.peers import run_vqf

    online, offline = [], []
    for path in trial_paths(DEFAULT_DIR):
        session = load_broad(path)
        assert session.truth is not None
        movement = session.stream("movement").values[:, 0]
        online.append(broad_errors(run_vqf(session).quat_wxyz, session.truth.values, movement).total)
        offline.append(broad_errors(run_vqf(session, offline=True).quat_wxyz, session.truth.values, movement).total)
    # ../shared/data/README.md (13 trials): mean total RMSE 3.04 deg online, 2.73 deg offline (same package, defaults);
    # 0.05 deg allows for the package version
    assert np.mean(online) == pytest.approx(3.04, abs=0.05)
    assert np.mean(offline) == pytest.approx(2.73, abs=0.05)


def test_a_nan_estimate_is_scored_as_failing_not_dropped() -> None:
    truth = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    estimate = truth.copy()
    estimate[1] = np.nan
    errors = broad_errors(estimate, truth, np.ones(4))
    assert errors.samples == 4 and errors.failed == 1
    assert errors.total == pytest.approx(np.sqrt(180.0**2 / 4))  # one of four samples at 180 deg


def test_imufusion_peer_reads_our_units_and_reports_enu_scalar_first() -> None:
    """A still sensor turned 30 deg about up (world ENU, the field north and down): imufusion's estimate (deg/s, g and
    scalar-first handled by the adapter) settles on that attitude; 0.5 deg: its gain-ramped start has long settled by 20 s."""
    pytest.importorskip("imufusion")
    from fusegraph.baselines.peers import run_imufusion
    from fusegraph.geometry import quat_conjugate, quat_from_rotvec, quat_multiply, rotvec_from_quat
    from fusegraph.session import KIND_COLUMNS, Session, Stream

    t = np.arange(0.0, 20.0, 1 / 200)
    world_R_body = quat_from_rotvec(np.array([0.0, 0.0, np.deg2rad(30.0)]))
    yaw = np.deg2rad(30.0)
    body_from_world = np.array([[np.cos(yaw), np.sin(yaw), 0.0], [-np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    accel = np.tile(body_from_world @ [0.0, 0.0, 9.81], (t.size, 1))
    mag = np.tile(body_from_world @ [0.0, 20.0, -40.0], (t.size, 1))
    streams = {name: Stream(name, name, t.copy(), values, KIND_COLUMNS[name], 0.0, {"rate_hz": 200.0})
               for name, values in (("gyro", np.zeros((t.size, 3))), ("accel", accel), ("mag", mag))}
    estimate = run_imufusion(Session("attitude9", streams, None, {}))
    error = rotvec_from_quat(quat_multiply(quat_conjugate(world_R_body), estimate.quat_wxyz[-1]))
    assert np.rad2deg(np.linalg.norm(error)) < 0.5
