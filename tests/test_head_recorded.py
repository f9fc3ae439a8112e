"""Head sessions from recorded BROAD motion (``bench head-recorded``): how the session is built and scored."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import requires_shared_data

from fusegraph.estimate import Estimate
from fusegraph.geometry import quat_conjugate, quat_from_euler_zyx, quat_multiply, rotvec_from_quat
from fusegraph.metrics import EULER_DOMAIN_DEG
from fusegraph.session import KIND_COLUMNS, Session, Stream
from fusegraph.systems.presets import PRESETS


def _session(elevation_deg: np.ndarray) -> Session:
    t = np.arange(elevation_deg.size) / 100.0
    angles = np.stack([0.1 * t, np.deg2rad(elevation_deg), np.zeros_like(t)], axis=1)
    truth = Stream("truth", "attitude", t, quat_from_euler_zyx(angles), KIND_COLUMNS["attitude"])
    movement = Stream("movement", "flag", t, np.ones((t.size, 1)), KIND_COLUMNS["flag"])
    return Session("head", {"movement": movement}, truth)


def test_scoring_keeps_to_the_euler_domain_and_flags_a_filter_that_leaves_it() -> None:
    score = PRESETS["head"].score
    elevation = np.concatenate([np.full(300, 10.0), np.full(100, 85.0), np.full(300, 10.0)])
    session = _session(elevation)
    assert session.truth is not None
    offset = quat_from_euler_zyx(np.array([np.deg2rad(1.0), 0.0, 0.0]))
    estimate = Estimate("isam2", session.truth.t, quat_multiply(offset, session.truth.values), None, 0.0)
    plain = score(session, estimate)
    assert plain is not None and "excluded" not in plain
    # the first second and the 100 samples past 80 deg are not scored; a pure azimuth offset, exactly
    assert plain["truth_samples_scored"] == 500 and plain["truth_samples_missing"] == 0
    np.testing.assert_allclose(list(plain["rms_deg"].values()), [1.0, 0.0, 0.0], atol=1e-6)
    # the same estimate from an Euler-angle filter: its own elevation passed the bound, so no figure
    flagged = score(session, replace(estimate, method="method2"))
    assert flagged is not None and f"{EULER_DOMAIN_DEG:g} deg" in flagged["excluded"] and np.isnan(list(flagged["rms_deg"].values())).all()
    broken = estimate.quat_wxyz.copy()
    broken[500] = np.nan
    failed = score(session, Estimate("isam2", session.truth.t, broken, None, 0.0))
    assert failed is not None and failed["truth_samples_missing"] == 1
    # the movement flag: scored only where it is set
    still = replace(session, streams={"movement": replace(session.stream("movement"), values=(session.truth.t[:, None] < 5.0).astype(float))})
    moving = score(still, estimate)
    assert moving is not None and moving["truth_samples_scored"] == 300  # 1-5 s less the 3-4 s past 80 deg


@requires_shared_data("broad")
def test_bench_rows_are_report_head_on_the_imported_sessions_declaring_the_chosen_setting(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The bench is a report over imported sessions: each held-out trial's row equals ``report head`` on that trial's
    session declaring the setting chosen without it (two trials cut to 30-60 s, one grid point each: a fast test)."""
    from fusegraph.cli import main
    from fusegraph.datasets.broad import DEFAULT_DIR
    from fusegraph.evaluation.head_recorded import METHODS, SOLVER_OF, bench_head_recorded, declare_ekf, declare_gyro
    from fusegraph.session import load_session, save_session

    for trial in ("10", "26"):
        assert main(["import", "broad", str(next(DEFAULT_DIR.glob(f"{trial}_*.mat"))), "--system", "head", "--out", str(tmp_path / "full" / trial)]) == 0
        session = load_session(tmp_path / "full" / trial)
        assert session.system == "head" and set(session.streams) == {"gyro", "tracker", "movement"}
        window = {name: (s.t >= 30.0) & (s.t < 60.0) for name, s in session.streams.items()}  # movement starts at 37 s, 45 s
        cut = {name: replace(s, t=s.t[window[name]], values=s.values[window[name]]) for name, s in session.streams.items()}
        assert session.truth is not None
        keep = (session.truth.t >= 30.0) & (session.truth.t < 60.0)
        save_session(replace(session, streams=cut, truth=replace(session.truth, t=session.truth.t[keep], values=session.truth.values[keep])),
                     tmp_path / "cut" / trial)
    capsys.readouterr()
    found = bench_head_recorded(tmp_path / "cut", workers=1, ekf_grid=[(1 / 16, 0.0006)], graph_grid=[(0.0015, 1e-4)])
    for trial in ("10", "26"):
        chosen = found["chosen_setting"][trial]
        assert chosen == {"ekf": {"process_scale": 1 / 16, "gyro_sigma_rad_s": 0.0006}, "gyro": {"noise_sigma_rad_s": 0.0015, "bias_rw_sigma": 1e-4}}
        declared = declare_gyro(declare_ekf(load_session(tmp_path / "cut" / trial), (1 / 16, 0.0006)), (0.0015, 1e-4))
        save_session(declared, tmp_path / "declared" / trial)
        assert main(["report", "head", str(tmp_path / "declared" / trial), "--solvers", ",".join(SOLVER_OF[m] for m in METHODS), "--json"]) == 0
        report = json.loads(capsys.readouterr().out)["sessions"][trial]
        for method in METHODS:
            assert found["trials"][trial][method]["rms_deg"] == report[SOLVER_OF[method]]["metrics"]["rms_deg"], (trial, method)
    assert all(v is not None for trial in ("10", "26") for v in found["trials"][trial]["batch"]["rms_deg"].values())  # not None == None
    assert found["mean_all_trials"]["batch"]["rms_deg"]["azimuth"] < found["mean_all_trials"]["tracker"]["rms_deg"]["azimuth"]


@requires_shared_data("broad")
def test_broad_trial_becomes_a_late_50_hz_tracker_with_the_declared_errors() -> None:
    from fusegraph.datasets.broad import DEFAULT_DIR, trial_paths
    from fusegraph.datasets.broad_head import head_session_from_broad

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
    from fusegraph.datasets.broad import DEFAULT_DIR
    from fusegraph.datasets.broad_head import head_session_from_broad
    from fusegraph.systems import head

    session = head_session_from_broad(DEFAULT_DIR / "06_undisturbed_fast_rotation_A.mat")
    first = {name: replace(s, t=s.t[s.t < 3.0], values=s.values[s.t < 3.0]) for name, s in session.streams.items()}
    estimate = head.run_isam2(replace(session, streams=first))
    fixed = np.isfinite(estimate.quat_wxyz).all(axis=1)
    assert fixed[-1] and fixed.sum() > 0.9 * len(fixed)
    assert estimate.cov is not None and np.isfinite(estimate.cov[fixed]).all()
