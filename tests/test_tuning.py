"""The tuning rule: a grid scored on tuning seeds only, best first."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import requires_shared_data

from fusegraph.evaluation.tuning import STUDIES, TEST_SEEDS, TUNING_SEEDS, Study, format_study, run_study


def test_study_ranks_the_grid_and_refuses_test_seeds() -> None:
    study = Study("toy", {"a": (1.0, 2.0, 3.0), "b": (0.0, 1.0)}, lambda s, seed: (s["a"] - 2.0) ** 2 + s["b"] + 0.001 * seed, "-")
    rows = run_study(study, (100, 101))
    assert rows[0][0] == {"a": 2.0, "b": 0.0} and len(rows) == 6
    assert rows[0][1] == pytest.approx(0.1005)
    assert "toy" in format_study(study, rows, (100, 101))
    with pytest.raises(ValueError, match="test seeds"):
        run_study(study, (9, 100))
    assert not set(TUNING_SEEDS) & set(TEST_SEEDS)


def test_the_gaze_ekf_study_scores_a_setting() -> None:
    setting = {"gyro_sigma_rad_s": 0.1, "accel_inflation": 0.0, "gaze_walk_m_per_sqrt_s": 0.05, "mag_yaw_sigma_rad": 0.05}
    score = STUDIES["gaze_ekf"].score(setting, 100)
    assert 0.0 < score < 1000.0  # mm on a 1 m wall: finite and not absurd
    # the head filter's magnetometer yaw noise is the study's own (it came from BROAD's 9-axis study before)
    assert STUDIES["gaze_ekf"].score({**setting, "mag_yaw_sigma_rad": 0.4}, 100) != score


def test_leave_one_group_out_scores_each_group_with_a_setting_chosen_without_it() -> None:
    from fusegraph.evaluation.tuning import leave_one_group_out

    # "b" is best on average only because of group 3; held out, group 3 is scored with "a"
    scores = {"a": {"1": 1.0, "2": 1.0, "3": 5.0}, "b": {"1": 2.0, "2": 2.0, "3": 0.0}}
    result = leave_one_group_out(scores)
    assert result["chosen"] == "b" and result["in_sample"] == pytest.approx(4.0 / 3.0)
    assert result["held_out"]["3"]["chosen"] == "a"
    assert result["held_out"]["1"]["chosen"] == "b"  # without group 1, b's mean 1.0 beats a's 3.0
    assert result["cross_validated"] == pytest.approx((2.0 + 2.0 + 5.0) / 3.0)


def test_tune_command_refuses_test_seeds_and_unknown_studies(capsys: pytest.CaptureFixture[str]) -> None:
    from fusegraph.cli import main

    assert main(["tune", "head_no_gyro", "--seeds", "3-4"]) == 2
    assert "are test seeds" in capsys.readouterr().err
    assert main(["tune", "nope"]) == 2
    assert "unknown study" in capsys.readouterr().err


def test_every_chosen_value_in_tuned_toml_is_a_point_of_its_study_grid() -> None:
    """The values the code reads come from the grid `fusegraph tune` prints (a grid edited without re-running
    the study, or a value typed in by hand, fails here)."""
    from fusegraph.evaluation.tuning import BROAD_GRIDS, BROAD_PER_SOLVER, broad_grid
    from fusegraph.tuned import tuned

    grids = {name: study.grid for name, study in STUDIES.items()}
    grids.update(BROAD_GRIDS)
    grids.update({f"{name}_batch": broad_grid(name, "batch") for name in BROAD_PER_SOLVER})
    for name, grid in grids.items():
        chosen = tuned(name)
        for setting, candidates in grid.items():
            assert chosen[setting] in candidates, f"[{name}] {setting} = {chosen[setting]} is not in the grid {candidates}"
        assert ("seeds" in chosen and not set(range(chosen["seeds"][0], chosen["seeds"][1] + 1)) & set(TEST_SEEDS)) or "trials" in chosen


def test_every_study_in_tuned_toml_belongs_to_a_system_whose_reports_print_it() -> None:
    from fusegraph.tuned import CHECK_STUDIES, SYSTEM_STUDIES, _table

    claimed = [study for studies in SYSTEM_STUDIES.values() for study in studies]
    checks = {study for studies in CHECK_STUDIES.values() for study in studies}
    assert sorted(claimed) == sorted(set(_table()) - checks)


def test_a_study_scored_by_two_processes_ranks_as_in_one() -> None:
    # the pool's workers look the study up by name (a lambda does not cross a process boundary)
    toy = Study("_two_workers", {"a": (1.0, 2.0, 3.0)}, lambda s, seed: (s["a"] - 2.0) ** 2 + 0.001 * seed, "-")
    STUDIES[toy.name] = toy
    try:
        assert run_study(toy, (100, 101), workers=2) == run_study(toy, (100, 101))
    finally:
        del STUDIES[toy.name]


def test_write_tuned_replaces_one_study_and_keeps_the_others(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import tomllib

    from fusegraph.tuned import write_tuned

    path = tmp_path / "tuned.toml"
    write_tuned("a", {"x": 1.0, "seeds": [100, 119], "unit": 'deg, "quoted"'}, path)
    write_tuned("b", {"y": 2, "flag": True}, path)
    write_tuned("a", {"x": 3.0}, path)
    table = tomllib.loads(path.read_text())
    assert table == {"a": {"x": 3.0}, "b": {"y": 2, "flag": True}}


def test_a_broad_study_chooses_by_leave_one_trial_out_in_one_or_two_processes(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    from conftest import SHARED_DATA

    from fusegraph.evaluation import tuning
    from fusegraph.tuned import tuned

    source = SHARED_DATA / "broad"
    stems = ("10_undisturbed_slow_translation_A", "32_disturbed_attached_magnet_1cm")
    if not all((source / f"{s}.mat").is_file() for s in stems):
        pytest.skip(f"BROAD trials {stems} not in {source}")
    for stem in stems:
        (tmp_path / f"{stem}.mat").symlink_to(source / f"{stem}.mat")
    chosen = tuned("broad_motion")
    grid = {name: (chosen[name],) for name in tuning.BROAD_MOTION_GRID}
    # the chosen prior against the old 2 m/s: 2 m/s with the chosen 0.005 accelerometer density is near-singular, so this
    # also runs the online solver through re-anchorings that gtsam refuses and the solver rebuilds (on both trials)
    grid["velocity_sigma_m_s"] = (chosen["velocity_sigma_m_s"], 2.0)
    monkeypatch.setitem(tuning.BROAD_GRIDS, "broad_motion", grid)
    one = tuning.broad_graph_logo("broad_motion", str(tmp_path))
    assert one == tuning.broad_graph_logo("broad_motion", str(tmp_path), workers=2)
    assert set(one["held_out"]) == set(stems) and len(one["all"]) == 2
    # the choice is the best mean over both trials; each fold is chosen on the other trial alone, and the cross-validated
    # figure is the mean of the held-out scores (scored against VQF on each trial, these two alone prefer 2 m/s: a slow
    # translation's tilt and a carried magnet's heading; the thirteen trials do not)
    assert one["chosen"] == min(one["all"], key=one["all"].get)
    assert one["total_in_sample"] > 0.0 and np.isfinite(one["total_cross_validated"])  # degrees, filed beside the peer-ratio score
    assert one["cross_validated"] == pytest.approx(float(np.mean([h["score"] for h in one["held_out"].values()])))
    assert one["cross_validated"] >= one["in_sample"] - 1e-9


@requires_shared_data("broad")
def test_the_motion_study_scores_a_trial_against_vqf_on_it(monkeypatch: pytest.MonkeyPatch) -> None:
    """``broad_motion`` chooses by the trial's total over VQF's plus its inclination over VQF's (``BROAD_OBJECTIVES``);
    the other studies by the total RMSE; the total is kept beside the score."""
    from fusegraph.baselines.peers import run_vqf
    from fusegraph.datasets.broad import DEFAULT_DIR, load_broad
    from fusegraph.evaluation import tuning
    from fusegraph.metrics import broad_errors
    from fusegraph.systems.attitude9 import broad_model, run_batch
    from fusegraph.tuned import tuned

    path = next(DEFAULT_DIR.glob("10_*.mat"))
    chosen = tuned("broad_motion_batch")
    monkeypatch.setitem(tuning.BROAD_GRIDS, "broad_motion", {name: (chosen[name],) for name in tuning.BROAD_MOTION_GRID})
    (figures,) = tuning._broad_trial_scores((str(path), "broad_motion", "batch")).values()
    session = load_broad(path)
    movement, truth = session.stream("movement").values[:, 0], session.truth.values  # type: ignore[union-attr]
    ours = broad_errors(run_batch(session, broad_model("batch")).quat_wxyz, truth, movement)
    peer = broad_errors(run_vqf(session, offline=True).quat_wxyz, truth, movement)  # the batch's peer: offline VQF
    assert figures["total"] == pytest.approx(ours.total, rel=1e-9)  # the same run: only float order may differ
    assert figures["score"] == pytest.approx(ours.total / peer.total + ours.inclination / peer.inclination, rel=1e-9)
    assert tuning._broad_objective("broad_mag") == "total"


def test_a_broad_bias_point_changes_the_bias_model_only() -> None:
    from fusegraph.evaluation import tuning
    from fusegraph.systems.attitude9 import broad_model

    point = {"accel_bias_prior_m_s2": 0.02, "accel_bias_walk_m_s2_sqrt_s": 1e-4, "gyro_bias_walk_rad_s_sqrt_s": 1e-4}
    model, base = tuning._broad_model("broad_bias", point, "batch"), broad_model("batch")
    imu = model.imu
    assert (imu.accel_bias_prior_m_s2, imu.accel_bias_walk_m_s2_sqrt_s, imu.gyro_bias_walk_rad_s_sqrt_s) == (0.02, 1e-4, 1e-4)
    # the other studies' choices stay as tuned
    assert model.mag == base.mag and model.motion == base.motion and model.gravity == base.gravity
    assert imu.accel_noise_m_s2_sqrt_hz == base.imu.accel_noise_m_s2_sqrt_hz


@requires_shared_data("broad")
def test_a_broad_study_on_imported_sessions_chooses_as_on_the_trial_files(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """`tune broad_online --sessions DIR` (imported trials) gives the trial files' leave-one-trial-out figures exactly."""
    from fusegraph.cli import main
    from fusegraph.datasets.broad import DEFAULT_DIR
    from fusegraph.evaluation.tuning import broad_graph_logo

    trials = [next(DEFAULT_DIR.glob(f"{prefix}_*.mat")) for prefix in ("01", "24")]
    (tmp_path / "files").mkdir()
    for trial in trials:
        (tmp_path / "files" / trial.name).symlink_to(trial)
        assert main(["import", "broad", str(trial), "--out", str(tmp_path / "sessions" / trial.stem)]) == 0
    on_files = broad_graph_logo("broad_online", str(tmp_path / "files"))
    on_sessions = broad_graph_logo("broad_online", sessions=[tmp_path / "sessions"])
    assert on_sessions["chosen"] == on_files["chosen"] and on_sessions["all"] == on_files["all"]
    assert on_sessions["cross_validated"] == on_files["cross_validated"]
    assert "total_in_sample" not in on_files  # scored by the total RMSE itself: nothing to file beside it
    assert set(on_sessions["held_out"]) == {t.stem for t in trials}


def test_jobs_on_a_dask_cluster_come_back_in_order() -> None:
    from fusegraph.evaluation.cluster import in_order

    assert in_order(abs, [-3, 1, -2, 5], 2, "local") == [3, 1, 2, 5]  # what tune --scheduler hands its studies' jobs to


def test_costliest_jobs_start_first_and_still_come_back_in_order(monkeypatch: pytest.MonkeyPatch) -> None:
    import fusegraph.evaluation.cluster as cluster

    started: list[int] = []
    run_here = cluster.completed

    def record(fn, order, workers, scheduler):  # type: ignore[no-untyped-def]
        started.extend(order)
        return run_here(fn, order, 1, None)

    monkeypatch.setattr(cluster, "completed", record)
    assert cluster.in_order(abs, [1, 5, 2, 4], 2, cost=float) == [1, 5, 2, 4]
    assert started == [5, 4, 2, 1]
