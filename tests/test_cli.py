"""The CLI wraps the library: simulate -> run -> report round trip, --help that teaches, clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fusegraph.cli import main, parse_seeds
from fusegraph.estimate import Estimate


def test_simulate_run_and_read_back(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    session = tmp_path / "head0"
    assert main(["simulate", "head", "--seed", "0", "--out", str(session), "--duration", "3"]) == 0
    assert (session / "session.toml").is_file()
    out_csv = tmp_path / "est.csv"
    assert main(["run", str(session), "--solver", "batch", "--out", str(out_csv), "--json"]) == 0
    printed = capsys.readouterr().out
    metrics = json.loads(printed[printed.index("{") :])
    assert set(metrics["rms_rad"]) == {"azimuth", "elevation", "roll"}
    estimate = Estimate.load_csv(out_csv)
    assert estimate.cov is not None and len(estimate.t) == 301


def test_report_json_has_the_issue_shape(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", "head", "--seeds", "0", "--duration", "3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["methods"]) == {"tracker", "gyro", "kalman", "method1", "method2", "isam2", "batch"}
    for name, row in report["methods"].items():
        assert set(row) == {"rms_rad", "ms_per_40ms", "nees"}
        assert (row["nees"] is None) == (name in ("tracker", "gyro"))


def test_bad_session_is_one_clear_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["run", str(tmp_path)]) == 2
    assert "session.toml: not found" in capsys.readouterr().err


def test_help_teaches(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "examples:" in capsys.readouterr().out


def test_seed_lists() -> None:
    assert parse_seeds("0-3,7") == [0, 1, 2, 3, 7]
    assert parse_seeds("5") == [5]


def test_report_with_an_assumed_latency_adds_rows_and_the_latency_block(capsys: pytest.CaptureFixture[str]) -> None:
    args = ["report", "head", "--seeds", "0", "--duration", "3", "--profile", "ideal", "--latency-true", "0.13", "--latency-assumed", "0.1", "--json"]
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert {"method2", "isam2", "method2_wrong_d", "isam2_td"} <= set(report["methods"])
    assert set(report["latency"]) == {"true", "assumed", "estimated", "sigma"}
    assert report["latency"]["true"] == 0.13 and report["latency"]["assumed"] == 0.1
    assert abs(report["latency"]["estimated"] - 0.13) < 0.01  # 3 s of motion: within 10 ms
