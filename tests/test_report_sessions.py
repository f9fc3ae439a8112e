"""The user's path for a folder of sessions: ``report SYSTEM DIR`` and ``ablate SYSTEM --sessions DIR`` for every system,
through the CLI, on sessions written by ``simulate`` (hand-made sessions take the same path)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

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
