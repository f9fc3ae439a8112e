"""The user's path for a folder of sessions: ``report SYSTEM DIR`` and ``ablate SYSTEM --sessions DIR`` for every system,
through the CLI, on sessions written by ``simulate`` (hand-made sessions take the same path)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from fusegraph.cli import main
from fusegraph.systems.presets import PRESETS

# short sessions: each system's scoring needs its minimum (gaze 5 s, bicycle 10 s with braking at 3/4, walking 20 s)
DURATIONS = {"head": 4.0, "attitude9": 4.0, "gaze": 8.0, "bicycle": 12.0, "walking": 30.0, "ultrasonic": 2.0}


def _simulate(system: str, folder: Path, seeds: tuple[int, ...] = (0, 1)) -> None:
    for seed in seeds:
        assert main(["simulate", system, "--seed", str(seed), "--duration", str(DURATIONS[system]), "--out", str(folder / f"s{seed}")]) == 0


@pytest.mark.parametrize("system", list(DURATIONS))
def test_report_and_ablate_take_a_folder_of_sessions(system: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _simulate(system, tmp_path / "sessions")
    capsys.readouterr()
    solvers = "online,batch"
    assert main(["report", system, str(tmp_path / "sessions"), "--solvers", solvers, "--json", "--plot", str(tmp_path / "r.png")]) == 0
    found = json.loads(capsys.readouterr().out)
    assert set(found["sessions"]) == {"s0", "s1"} and (tmp_path / "r.png").is_file()
    headline = PRESETS[system].metric_keys[0].split(".")
    for solver in solvers.split(","):
        assert found["methods"][solver]["sessions_scored"] == 2, found["methods"][solver]
        mean = found["methods"][solver]["metrics"]
        for part in headline:
            mean = mean[part]
        per_session = []
        for name in ("s0", "s1"):
            row = found["sessions"][name][solver]["metrics"]
            for part in headline:
                row = row[part]
            per_session.append(row)
        assert mean == pytest.approx(sum(per_session) / 2)  # the mean over sessions of what run --json prints
    assert main(["ablate", system, "--sessions", str(tmp_path / "sessions"), "--solver", "online", "--workers", "1", "--out", str(tmp_path / "study")]) == 0
    with (tmp_path / "study" / "runs.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2 and all(r["status"] == "ok" and r["session"] for r in rows), rows


def test_report_without_truth_says_what_it_can(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _simulate("head", tmp_path / "sessions", seeds=(0,))
    session = tmp_path / "sessions" / "s0"
    text = (session / "session.toml").read_text()
    start = text.index("[truth]")
    end = text.find("\n[", start + 1)
    (session / "session.toml").write_text(text[:start] + (text[end + 1 :] if end > 0 else ""))
    (session / "truth.csv").unlink()
    capsys.readouterr()
    assert main(["report", "head", str(session), "--solvers", "online,ekf", "--json"]) == 0
    found = json.loads(capsys.readouterr().out)
    row = found["sessions"]["s0"]["online"]
    assert row["metrics"] == {} and row["no_truth"]["covered_frac"] > 0.9 and row["no_truth"]["sigma_deg_median"] > 0
    assert found["methods"]["online"]["sessions_scored"] == 0 and found["methods"]["online"]["sessions_failed"] == 0
    assert found["in_sample"] == {}  # test seed 0: no setting was chosen on it


def test_a_declared_gyro_noise_is_honoured_and_a_setting_nobody_reads_is_an_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _simulate("attitude9", tmp_path / "sessions", seeds=(0,))
    args = ["ablate", "attitude9", "--sessions", str(tmp_path / "sessions"), "--solver", "online,ekf", "--workers", "1"]
    assert main([*args, "--vary", "gyro.noise_sigma_rad_s=0.01,0.5", "--out", str(tmp_path / "a")]) == 0
    with (tmp_path / "a" / "runs.csv").open() as handle:
        metrics = {(r["params"], r["solver"]): r["metrics"] for r in csv.DictReader(handle)}
    for solver in ("online", "ekf"):
        assert metrics[("gyro.noise_sigma_rad_s=0.01", solver)] != metrics[("gyro.noise_sigma_rad_s=0.5", solver)]
    capsys.readouterr()
    assert main([*args, "--vary", "gyro.delay_s=0,0.05", "--out", str(tmp_path / "b")]) == 2  # no attitude9 solver reads delay_s
    assert "gyro.delay_s: every value gave the same results" in capsys.readouterr().err


def test_report_refuses_a_session_of_another_system(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _simulate("head", tmp_path / "sessions", seeds=(0,))
    assert main(["report", "attitude9", str(tmp_path / "sessions")]) == 2
    assert "a head session, not attitude9" in capsys.readouterr().err


def test_a_suspect_run_and_a_nan_figure_stay_out_of_the_means_and_say_why(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A gyro clipped on a large share of its samples marks the run suspect (in `run --json` and the report's row); the
    report's mean is then the other session's alone, and the table counts it apart. A NaN figure is not scored, with why."""
    import numpy as np

    from fusegraph.evaluation.runner import load_sessions, not_scored_reason, report_sessions
    from fusegraph.session import load_session, save_session

    for seed in (0, 1):
        assert main(["simulate", "head", "--seed", str(seed), "--duration", "5", "--out", str(tmp_path / "s" / f"seed{seed}")]) == 0
    clipped = load_session(tmp_path / "s" / "seed1")
    gyro = clipped.stream("gyro")
    level = float(np.percentile(np.abs(gyro.values), 80))  # a rail under the motion: a fifth of the samples on it
    from dataclasses import replace

    rail = replace(gyro, values=np.clip(gyro.values, -level, level))
    save_session(replace(clipped, streams={**clipped.streams, "gyro": rail}), tmp_path / "s" / "seed1")
    capsys.readouterr()
    assert main(["run", str(tmp_path / "s" / "seed1"), "--solver", "online", "--json", "--out", str(tmp_path / "e.csv")]) == 0
    assert "clipped on" in " ".join(json.loads(capsys.readouterr().out)["suspect"])
    found = report_sessions("head", load_sessions([tmp_path / "s"]), ["online"], show_progress=False)
    method = found["methods"]["online"]
    assert (method["sessions_scored"], method["sessions_suspect"]) == (1, 1)
    alone = found["sessions"]["seed0"]["online"]["metrics"]["rms_deg"]["azimuth"]
    assert method["metrics"]["rms_deg"]["azimuth"] == alone  # the mean of the one session counted
    assert "SUSPECT" in main_output(["report", "head", str(tmp_path / "s"), "--solvers", "online"], capsys)
    counted = report_sessions("head", load_sessions([tmp_path / "s"]), ["online"], show_progress=False, include_suspect=True)
    assert counted["methods"]["online"]["sessions_scored"] == 2
    why = not_scored_reason(PRESETS["head"], {"rms_deg": {"azimuth": float("nan")}, "excluded": "ekf: its elevation left the domain"}, [])
    assert why == "rms_deg.azimuth not a number: ekf: its elevation left the domain"


def main_output(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 0
    return capsys.readouterr().out


def test_sessions_of_one_name_in_two_folders_and_below_keep_their_own_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for folder in ("A/trial", "B/trial", "C/deeper/still/other"):
        assert main(["simulate", "attitude9", "--seed", "0", "--duration", "5", "--out", str(tmp_path / "in" / folder)]) == 0
    out = main_output(["run", str(tmp_path / "in"), "--solver", "online", "--out", str(tmp_path / "out"), "--workers", "1"], capsys)
    written = sorted(p.name for p in (tmp_path / "out").glob("*.csv"))
    assert written == ["A__trial_online.csv", "B__trial_online.csv", "C__deeper__still__other_online.csv"], written
    assert out.splitlines()[-2].startswith("mean") and "3 sessions, 0 failed, 0 not scored" in out


def _report_of(names: list[str]) -> dict:
    rows = {name: {"online": {"status": "ok", "metrics": {"total_deg": 1.0 + i}, "runtime_s": 0.1, "x_realtime": 100.0, "warnings": []}}
            for i, name in enumerate(names)}
    method = {"metrics": {"total_deg": 2.0}, "x_realtime": 100.0, "sessions_scored": len(names), "sessions_failed": 0}
    return {"system": "attitude9", "solvers": ["online"], "metric_keys": ["total_deg"], "sessions": rows, "methods": {"online": method}}


def test_a_long_session_name_keeps_the_solver_column_and_many_sessions_make_a_summary_figure(tmp_path: Path) -> None:
    from PIL import Image

    from fusegraph.report.tables import format_session_report, plot_session_report

    long_name = "04_undisturbed_slow_rotation_with_breaks_A"
    lines = format_session_report(_report_of([long_name, "s2"])).splitlines()
    rows = [line for line in lines if line.startswith((long_name, "s2 "))]
    assert len(rows) == 2 and rows[0].index("online") == rows[1].index("online") > len(long_name)  # one column, after the name
    width, _ = Image.open(plot_session_report(_report_of([f"trial{i:02d}" for i in range(17)]), tmp_path / "many.png")).size
    assert width < 1200, width  # a summary per solver, not a bar per session (6,732 px over 17 sessions before)


def test_a_report_in_two_processes_is_the_report_in_one(tmp_path: Path) -> None:
    from fusegraph.evaluation.runner import load_sessions, named_session_dirs, report_sessions

    for seed in (0, 1, 2):
        assert main(["simulate", "attitude9", "--seed", str(seed), "--duration", "10", "--out", str(tmp_path / f"seed{seed}")]) == 0
    sessions = load_sessions([tmp_path])
    one = report_sessions("attitude9", sessions, ["online", "batch"], show_progress=False)
    two = report_sessions("attitude9", sessions, ["online", "batch"], show_progress=False, workers=2)
    assert list(two["sessions"]) == ["seed0", "seed1", "seed2"]  # in the order of the sessions
    for solver in ("online", "batch"):
        assert two["methods"][solver]["metrics"] == one["methods"][solver]["metrics"]
    # given as folders, the workers read them: the same report; a session that cannot be read is a row saying why
    (tmp_path / "seed1" / "gyro.csv").write_text("t,x,y,z\n0.0,1,2\n")
    folders = named_session_dirs([tmp_path])
    read_there = report_sessions("attitude9", folders, ["online", "batch"], show_progress=False, workers=2)
    assert list(read_there["sessions"]) == ["seed0", "seed1", "seed2"]
    broken = read_there["sessions"]["seed1"]
    assert {row["status"] for row in broken.values()} == {"failed"} and "gyro.csv" in broken["online"]["error"]
    for solver in ("online", "batch"):
        assert read_there["sessions"]["seed2"][solver]["metrics"] == one["sessions"]["seed2"][solver]["metrics"]
        assert read_there["methods"][solver]["sessions_failed"] == 1


def test_a_cached_report_runs_only_what_its_cache_does_not_hold(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``report --cache``: run again, nothing is solved and the report is the same; a session whose file changed, a solver
    added and a run that failed are run again; a torn last line (a kill while writing) is run again too."""
    import fusegraph.evaluation.runner as runner
    from fusegraph.evaluation.runner import named_session_dirs, report_sessions

    for seed in (0, 1):
        assert main(["simulate", "attitude9", "--seed", str(seed), "--duration", "4", "--out", str(tmp_path / "s" / f"seed{seed}")]) == 0
    folders, cache = named_session_dirs([tmp_path / "s"]), tmp_path / "cache"
    first = report_sessions("attitude9", folders, ["online", "vqf"], show_progress=False, cache=cache)
    solved: list[str] = []
    real = runner.solve_session

    def counted(session, solver):  # type: ignore[no-untyped-def]
        solved.append(f"{session.path.name}/{solver}")
        return real(session, solver)

    monkeypatch.setattr(runner, "solve_session", counted)
    assert report_sessions("attitude9", folders, ["online", "vqf"], show_progress=False, cache=cache) == first and solved == []
    with (tmp_path / "s" / "seed1" / "session.toml").open("a") as toml:
        toml.write("# edited\n")  # the same data, another file: its runs are not known to be of this session
    again = report_sessions("attitude9", folders, ["online", "vqf", "batch"], show_progress=False, cache=cache)
    assert sorted(solved) == ["seed0/batch", "seed1/batch", "seed1/online", "seed1/vqf"]
    assert again["sessions"]["seed0"]["online"] == first["sessions"]["seed0"]["online"]  # held, runtime and all
    assert again["sessions"]["seed1"]["vqf"]["metrics"] == first["sessions"]["seed1"]["vqf"]["metrics"]  # made again, the same

    def failing(session, solver):  # type: ignore[no-untyped-def]
        raise RuntimeError("a node went down")

    monkeypatch.setattr(runner, "solve_session", failing)
    (tmp_path / "s" / "seed0" / "session.toml").write_text((tmp_path / "s" / "seed0" / "session.toml").read_text() + "# edited\n")
    failed = report_sessions("attitude9", folders, ["online"], show_progress=False, cache=cache)
    assert failed["sessions"]["seed0"]["online"]["status"] == "failed" and failed["sessions"]["seed1"]["online"]["status"] == "ok"
    log = cache / "report.jsonl"
    log.write_bytes(log.read_bytes() + b'{"key": "torn')
    monkeypatch.setattr(runner, "solve_session", counted)
    solved.clear()
    assert report_sessions("attitude9", folders, ["online"], show_progress=False, cache=cache)["sessions"]["seed0"]["online"]["status"] == "ok"
    assert solved == ["seed0/online"] and all(json.loads(line) for line in log.read_text().splitlines() if not line.startswith('{"key": "torn'))
    # the traces a page draws are kept beside the rows: a page made again from the cache draws the same curves
    drawn: dict[str, list[object]] = {}
    report_sessions("attitude9", folders, ["online"], show_progress=False, cache=cache, traces=drawn)
    monkeypatch.setattr(runner, "solve_session", failing)
    kept: dict[str, list[object]] = {}
    report_sessions("attitude9", folders, ["online"], show_progress=False, cache=cache, traces=kept)
    assert [t.solver for t in kept["seed0"]] == ["online"]  # type: ignore[attr-defined]
    assert np.array_equal(kept["seed0"][0].values, drawn["seed0"][0].values, equal_nan=True)  # type: ignore[attr-defined]
