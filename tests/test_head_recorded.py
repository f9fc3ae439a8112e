"""Head sessions from recorded BROAD motion (``bench head-recorded``): how the session is built and scored."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import requires_shared_data

from fusegraph.estimate import Estimate
from fusegraph.evaluation.head_recorded import EULER_DOMAIN_DEG, _score, scored_samples
from fusegraph.geometry import quat_conjugate, quat_from_euler_zyx, quat_multiply, rotvec_from_quat
from fusegraph.session import KIND_COLUMNS, Session, Stream


def _session(elevation_deg: np.ndarray) -> Session:
    t = np.arange(elevation_deg.size) / 100.0
    angles = np.stack([0.1 * t, np.deg2rad(elevation_deg), np.zeros_like(t)], axis=1)
    truth = Stream("truth", "attitude", t, quat_from_euler_zyx(angles), KIND_COLUMNS["attitude"])
    movement = Stream("movement", "flag", t, np.ones((t.size, 1)), KIND_COLUMNS["flag"])
    return Session("head", {"movement": movement}, truth)


def test_scoring_keeps_to_the_euler_domain_and_flags_a_filter_that_leaves_it() -> None:
    elevation = np.concatenate([np.full(300, 10.0), np.full(100, 85.0), np.full(300, 10.0)])
    session = _session(elevation)
    scored = scored_samples(session)
    assert not scored[:100].any()  # the first second
    assert scored[100:300].all() and not scored[300:400].any() and scored[400:].all()
    assert session.truth is not None
    offset = quat_from_euler_zyx(np.array([np.deg2rad(1.0), 0.0, 0.0]))
    estimate = Estimate("method2", session.truth.t, quat_multiply(offset, session.truth.values), None, 0.0)
    plain = _score(estimate, session, scored)
    assert plain.invalid is None
    np.testing.assert_allclose(plain.rms_deg, [1.0, 0.0, 0.0], atol=1e-6)  # a pure azimuth offset, exactly
    # the same estimate from an Euler-angle filter: its own elevation passed the bound, so no figure
    flagged = _score(estimate, session, scored, euler_filter=True)
    assert flagged.invalid is not None and f"{EULER_DOMAIN_DEG:g} deg" in flagged.invalid and np.isnan(flagged.rms_deg).all()
    broken = estimate.quat_wxyz.copy()
    broken[500] = np.nan
    failed = _score(Estimate("isam2", session.truth.t, broken, None, 0.0), session, scored)
    assert failed.invalid is not None and "not finite on 1 scored" in failed.invalid


@requires_shared_data("broad")
def test_broad_trial_becomes_a_late_50_hz_tracker_with_the_declared_errors() -> None:
    from fusegraph.datasets.broad import DEFAULT_DIR, trial_paths
    from fusegraph.evaluation.head_recorded import head_session_from_broad

    path = trial_paths(DEFAULT_DIR)[-1]  # an attached-magnet trial: occlusions as well as motion
    session = head_session_from_broad(path)
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    assert session.truth is not None
    assert tracker.latency_s == pytest.approx(0.1) and gyro.meta["calibrated"] is False
    # about 50 Hz: the nearest gyro sample (3.5 ms apart) to each 20 ms instant, 2 % dropped, none while occluded
    period = np.median(np.diff(tracker.t))
    assert period == pytest.approx(0.02, abs=0.004)
    expected = gyro.t[-1] * 50.0
    assert 0.85 * expected < len(tracker) < 0.99 * expected
    rows = np.searchsorted(gyro.t, tracker.t)
    optical = session.truth.values[rows]
    assert np.all(np.isfinite(optical))
    error_deg = np.rad2deg(np.linalg.norm(rotvec_from_quat(quat_multiply(quat_conjugate(optical), tracker.values)), axis=1))
    # white 0.4 deg + Gauss-Markov 0.7 deg per axis: RMS of the norm sqrt(3 (0.16 + 0.49)) = 1.4 deg
    assert 1.0 < np.sqrt(np.mean(error_deg**2)) < 1.8
    again = head_session_from_broad(path)
    np.testing.assert_array_equal(again.stream("tracker").values, tracker.values)  # a fixed seed: every run the same


@requires_shared_data("broad")
def test_online_head_survives_a_covariance_that_cholesky_calls_indeterminate() -> None:
    """BROAD trial 06's first seconds: iSAM2's update passes at the fifth keyframe but the covariance's own elimination
    does not (the gyro's scale and axes not yet observable); the solver is rebuilt and the covariance read again."""
    from dataclasses import replace

    from fusegraph.datasets.broad import DEFAULT_DIR
    from fusegraph.evaluation.head_recorded import head_session_from_broad
    from fusegraph.systems import head

    session = head_session_from_broad(DEFAULT_DIR / "06_undisturbed_fast_rotation_A.mat")
    first = {name: replace(s, t=s.t[s.t < 3.0], values=s.values[s.t < 3.0]) for name, s in session.streams.items()}
    estimate = head.run_isam2(replace(session, streams=first))
    fixed = np.isfinite(estimate.quat_wxyz).all(axis=1)
    assert fixed[-1] and fixed.sum() > 0.9 * len(fixed)
    assert estimate.cov is not None and np.isfinite(estimate.cov[fixed]).all()
