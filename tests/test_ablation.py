"""Ablation studies: expansion, failed runs recorded, resume after a kill, a real Dask LocalCluster."""

from __future__ import annotations

from pathlib import Path

import pytest

from fusegraph.evaluation.ablation import METRIC_COLUMNS, Study, _result_or_failure, read_rows, run_study, summarize
from fusegraph.report.ablation import summary_table

SMALL = Study(system="head", drops=(("tracker",), ("gyro",)), vary=(("latency", (0.05, 0.1)),), seeds=(0, 1), solvers=("ekf", "online"),
              duration_s=2.0, profile="ideal")


def metrics(rows: list[dict]) -> list[tuple]:
    return [(r["key"], r["status"], *[f"{float(r[c]):.12g}" if r[c] not in ("", None) else "" for c in METRIC_COLUMNS]) for r in rows]


def test_study_expands_baseline_drops_and_grid() -> None:
    variants = [v.name for v in SMALL.variants()]
    assert variants == ["full latency=0.05", "full latency=0.1", "-tracker latency=0.05", "-tracker latency=0.1", "-gyro latency=0.05", "-gyro latency=0.1"]
    runs = SMALL.runs()
    assert len(runs) == 6 * 2 * 2
    assert len({r["key"] for r in runs}) == len(runs)  # every configuration has its own key
    with pytest.raises(ValueError, match="cannot drop mag"):
        Study(drops=(("mag",),))
    with pytest.raises(ValueError, match="unknown parameter 'speed'"):
        Study(vary=(("speed", (1.0,)),))


def test_failed_runs_are_rows_and_a_killed_study_resumes_to_the_same_table(tmp_path: Path) -> None:
    full = run_study(SMALL, tmp_path / "full", workers=1)
    assert all(r["status"] == "ok" for r in full.rows)
    # a kill midway: only the first 9 finished rows made it to disk
    partial = tmp_path / "partial"
    partial.mkdir()
    lines = (tmp_path / "full" / "runs.csv").read_text().splitlines()
    (partial / "runs.csv").write_text("\n".join(lines[:10]) + "\n")
    resumed = run_study(SMALL, partial, workers=1)
    assert resumed.skipped == 9 and resumed.ran == len(SMALL.runs()) - 9
    assert metrics(resumed.rows) == metrics(full.rows)
    assert len(read_rows(partial / "runs.csv")) == len(SMALL.runs())  # nothing twice, nothing lost
    table = summary_table(summarize(resumed.rows))
    assert "-gyro latency=0.1" in table


def test_a_row_torn_by_a_kill_a_failed_run_and_other_settings_in_the_same_folder(tmp_path: Path) -> None:
    """Killed while writing a row: the torn row is dropped and its run done again (no crash in the summary);
    a failed run is kept as failed on resume, and run again with retry_failed; the same folder with other
    settings is refused, not mixed, and with force starts afresh with the old rows kept aside."""
    study = Study(system="head", seeds=(0, 1), solvers=("ekf",), duration_s=2.0, profile="ideal")
    first = run_study(study, tmp_path, workers=1)
    lines = (tmp_path / "runs.csv").read_text().splitlines()
    broken = lines[1].replace(",ok,", ",failed,", 1)
    (tmp_path / "runs.csv").write_text("\n".join([lines[0], broken, lines[2][: len(lines[2]) // 2]]))  # one failed, one torn
    kept = run_study(study, tmp_path, workers=1)
    assert kept.ran == 1 and kept.skipped == 1 and [r["status"] for r in kept.rows] == ["failed", "ok"]
    again = run_study(study, tmp_path, workers=1, retry_failed=True)
    assert again.ran == 1 and again.skipped == 1
    assert metrics(again.rows) == metrics(first.rows)
    assert len(read_rows(tmp_path / "runs.csv")) == 2
    summary_table(summarize(again.rows))
    with pytest.raises(ValueError, match="other settings"):
        run_study(Study(system="head", seeds=(0, 1, 2), solvers=("ekf",), duration_s=2.0, profile="ideal"), tmp_path, workers=1)
    other = run_study(Study(system="head", seeds=(0,), solvers=("ekf",), duration_s=2.0, profile="ideal"), tmp_path, workers=1, force=True)
    assert other.ran == 1 and len(read_rows(tmp_path / "runs.csv")) == 1 and len(read_rows(tmp_path / "runs.replaced.csv")) == 2


def test_dask_local_cluster_with_two_workers_gives_the_same_results(tmp_path: Path) -> None:
    pytest.importorskip("dask.distributed")
    study = Study(system="head", drops=(("tracker",),), seeds=(0, 1), solvers=("ekf", "online"), duration_s=2.0, profile="ideal")
    local = run_study(study, tmp_path / "local", workers=1)
    on_dask = run_study(study, tmp_path / "dask", workers=2, scheduler="local")
    assert metrics(on_dask.rows) == metrics(local.rows)


def test_a_dead_worker_becomes_a_failed_row() -> None:
    class DeadFuture:
        def result(self) -> dict:
            raise RuntimeError("KilledWorker: the process died")

    spec = SMALL.runs()[0]
    row = _result_or_failure(DeadFuture(), spec)
    assert row["status"] == "failed" and "KilledWorker" in row["error"] and row["key"] == spec["key"]


@pytest.mark.parametrize("path", sorted(Path(__file__).resolve().parents[1].joinpath("examples").glob("*.toml")))
def test_example_studies_parse(path: Path) -> None:
    from fusegraph.evaluation.ablation import load_study

    study = load_study(path)
    assert study.runs(), path


def test_a_failing_run_is_a_row_with_its_error_and_the_study_goes_on(tmp_path: Path) -> None:
    study = Study(system="head", vary=(("tracker_rate", (50.0, 0.0)),), seeds=(0,), solvers=("ekf",), duration_s=2.0, profile="ideal")
    result = run_study(study, tmp_path, workers=1)
    by_rate = {r["params"]: r for r in result.rows}
    assert by_rate["tracker_rate=50"]["status"] == "ok"
    assert by_rate["tracker_rate=0"]["status"] == "failed" and "ZeroDivisionError" in by_rate["tracker_rate=0"]["error"]


def test_without_gyro_the_graph_tracks_with_a_constant_velocity_model() -> None:
    import numpy as np

    from fusegraph.evaluation.ablation import without_gyro
    from fusegraph.metrics import score_attitude
    from fusegraph.scenarios import simulate_head
    from fusegraph.systems.head import run_batch

    session = simulate_head(3, profile="ideal", duration_s=4.0)
    clock_only, model = without_gyro(session)
    assert not np.any(clock_only.stream("gyro").values)
    assert session.truth is not None
    rms = score_attitude(run_batch(clock_only, model), session.truth.t, session.truth.values).rms_rad
    # the tracker alone (0.8 deg noise at 50 Hz) smoothed by the motion model: well under 2 deg per axis
    assert np.all(rms < np.deg2rad(2.0)), rms


def test_a_variant_a_solver_cannot_take_is_not_applicable_not_a_failure(tmp_path, capsys) -> None:
    """Dropping the magnetometer leaves the papers' 9-axis EKF nothing to run on: its row says 'not applicable' and why, the
    study exits 0 and the other solvers' rows are figures."""
    from fusegraph.cli import main

    assert main(["simulate", "attitude9", "--seed", "0", "--duration", "10", "--out", str(tmp_path / "s")]) == 0
    capsys.readouterr()
    assert main(["ablate", "attitude9", "--sessions", str(tmp_path / "s"), "--drop", "mag", "--solver", "ekf,online",
                 "--workers", "1", "--out", str(tmp_path / "study")]) == 0
    table = capsys.readouterr().out
    assert "-mag    ekf                1      0  not applicable: the 9-axis EKF needs a magnetometer" in table
    assert "0 failed" in table


def test_bench_progress_stays_off_a_log(capsys) -> None:
    from fusegraph.cli import _on_terminal

    _on_terminal("step-length grid point 1/64")  # stderr is captured here, as in a log: nothing is written
    assert capsys.readouterr().err == ""
