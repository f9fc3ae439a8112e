"""The CLI wraps the library: simulate -> run -> report round trip, --help that teaches, clear errors."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from fusegraph.cli import main
from fusegraph.estimate import Estimate
from fusegraph.evaluation.runner import parse_seeds


def test_simulate_run_and_read_back(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    session = tmp_path / "head0"
    assert main(["simulate", "head", "--seed", "0", "--out", str(session), "--duration", "3"]) == 0
    assert (session / "session.toml").is_file()
    capsys.readouterr()
    out_csv = tmp_path / "est.csv"
    assert main(["run", str(session), "--solver", "batch", "--out", str(out_csv), "--json"]) == 0
    found = json.loads(capsys.readouterr().out)  # --json prints one JSON object and nothing else
    assert found["system"] == "head" and found["solver"] == "batch"
    assert set(found["metrics"]["rms_rad"]) == {"azimuth", "elevation", "roll"}
    assert set(found["metrics"]["rms_deg"]) == {"azimuth", "elevation", "roll"}
    estimate = Estimate.load_csv(out_csv)
    assert estimate.cov is not None and len(estimate.t) == 301


def test_report_json_has_the_issue_shape(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", "head", "--seeds", "0", "--duration", "3", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    paper_and_ours = {"tracker", "gyro", "kalman", "method1", "method2", "isam2", "batch"}
    wrong_noise = {f"{m}_noise_x{k}" for m in ("method2", "isam2", "batch") for k in ("0.5", "2")}
    assert set(report["methods"]) == paper_and_ours | wrong_noise | {"method1_paper_values", "method2_paper_values"}  # method1/2 are tuned
    assert report["tuning_seeds"] == list(range(100, 120)) and report["seeds"] == [0]
    # every baseline's (and graph's) chosen settings with where they were chosen
    assert report["settings"]["head_ekf"]["seeds"] == [100, 119] and "process_scale" in report["settings"]["head_ekf"]
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


def test_gaze_and_bicycle_sessions_simulate_and_run(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """A simulated session written to disk and run back gives the same figures as the in-memory system; the estimate
    goes into the current folder, not into the session."""
    monkeypatch.chdir(tmp_path)
    from fusegraph.scenarios.bicycle import BicycleScenarioConfig, simulate_bicycle
    from fusegraph.systems import bicycle

    assert main(["simulate", "gaze", "--out", str(tmp_path / "g")]) == 0
    capsys.readouterr()
    assert main(["run", str(tmp_path / "g"), "--solver", "batch", "--json"]) == 0
    rms = json.loads(capsys.readouterr().out)["metrics"]["rms"]
    assert rms["x_mm"] < 8 and rms["z_mm"] < 8  # mm: the batch measured 3.6 and 2.2 on this seed
    assert (tmp_path / "g_gaze_batch.csv").read_text().startswith("t,X_m,Z_m")
    assert not list((tmp_path / "g").glob("gaze_*.csv"))
    assert main(["simulate", "bicycle", "--duration", "36", "--out", str(tmp_path / "b")]) == 0
    capsys.readouterr()
    assert main(["run", str(tmp_path / "b"), "--solver", "no_removal", "--json"]) == 0
    from_disk = json.loads(capsys.readouterr().out)["metrics"]["rms"]
    direct = simulate_bicycle(0, BicycleScenarioConfig(duration_s=36.0, brake_s=27.0))  # simulate scales the braking time with the length
    in_memory = bicycle.braking_rms_deg(bicycle.run_no_removal(direct), direct)
    # the CSVs keep 17 digits: the same figures to rounding
    assert abs(from_disk["pitch_deg"] - in_memory["pitch_deg"]) < 1e-6
    assert main(["run", str(tmp_path / "b"), "--solver", "vqf"]) == 2
    assert "bicycle sessions have" in capsys.readouterr().err


def test_walking_session_simulate_and_run(tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "walking", "--out", str(tmp_path / "w")]) == 0
    capsys.readouterr()
    assert main(["run", str(tmp_path / "w"), "--solver", "dead_reckoning", "--json"]) == 0
    dr = json.loads(capsys.readouterr().out)["metrics"]
    assert main(["run", str(tmp_path / "w"), "--solver", "batch", "--json"]) == 0
    batch = json.loads(capsys.readouterr().out)["metrics"]
    assert batch["rmse_m"] < 0.5 * dr["rmse_m"]  # the fixes and the map pull the drift back (measured 0.91 vs 6.8 m)
    assert (tmp_path / "w_trajectory_batch.csv").read_text().startswith("t,x,y,z")
    assert main(["simulate", "walking", "--duration", "5", "--out", str(tmp_path / "x")]) == 2  # shorter than a scorable walk


def test_damaged_copies_of_a_head_session_are_one_clear_line_each(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's damaged copies: gyro in deg/s, stamps in ms, quaternions x3, a misspelled key, a zero sigma:
    exit 2 with one line naming the file and the likely cause, for online, batch and ekf alike."""
    import shutil

    good = tmp_path / "ok"
    assert main(["simulate", "head", "--seed", "0", "--duration", "3", "--out", str(good)]) == 0

    def damaged(name: str, edit) -> Path:  # type: ignore[no-untyped-def]
        path = tmp_path / name
        shutil.copytree(good, path)
        edit(path)
        return path

    def scale(path: Path, column_from: int, factor: float) -> None:
        lines = path.read_text().splitlines()
        rows = [",".join(v if i < column_from or (column_from == 0 and i > 0) else repr(float(v) * factor) for i, v in enumerate(line.split(",")))
                for line in lines[1:]]
        path.write_text("\n".join([lines[0], *rows]) + "\n")

    cases = {
        "deg/s": damaged("degs", lambda p: scale(p / "gyro.csv", 1, 57.3)),
        "milliseconds": damaged("ms", lambda p: [scale(p / f, 0, 1000.0) for f in ("gyro.csv", "tracker.csv", "truth.csv")]),
        "quaternion norm 3": damaged("quat3", lambda p: scale(p / "tracker.csv", 1, 3.0)),
        "did you mean 'noise_sigma_deg'": damaged("typo", lambda p: (p / "session.toml").write_text(
            (p / "session.toml").read_text().replace("noise_sigma_deg", "noise_sigma_degs"))),
        "must be a number > 0": damaged("zero", lambda p: (p / "session.toml").write_text(
            (p / "session.toml").read_text().replace("noise_sigma_rad_s = 0.015", "noise_sigma_rad_s = 0"))),
    }
    capsys.readouterr()
    for cause, path in cases.items():
        for solver in ("online", "batch", "ekf"):
            assert main(["run", str(path), "--solver", solver, "--json"]) == 2, (cause, solver)
            err = capsys.readouterr().err
            assert cause in err and err.count("\n") == 1 and "Traceback" not in err, err


def test_a_closed_pipe_a_one_sample_stream_and_nan_are_user_facing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`fusegraph sensors | head` exits quietly; a one-sample gyro is a clear error naming it (not 'a bug'); JSON holds
    null where a figure is NaN."""
    import subprocess
    import sys

    from fusegraph.cli import _dump

    done = subprocess.run(f"{sys.executable} -m fusegraph.cli sensors | head -1", shell=True, capture_output=True, text=True, check=False)
    assert done.stdout.strip() == "# Sensor catalogue" and "Error" not in done.stderr and "bug" not in done.stderr, done.stderr
    assert main(["simulate", "head", "--duration", "2", "--out", str(tmp_path / "h")]) == 0
    gyro = (tmp_path / "h" / "gyro.csv").read_text().splitlines()
    (tmp_path / "h" / "gyro.csv").write_text("\n".join(gyro[:2]) + "\n")
    capsys.readouterr()
    assert main(["run", str(tmp_path / "h"), "--solver", "online"]) == 2
    err = capsys.readouterr().err
    assert "stream 'gyro': one sample" in err and "bug" not in err
    assert json.loads(_dump({"rmse_m": float("nan"), "x": [float("inf"), 1.0]})) == {"rmse_m": None, "x": [None, 1.0]}


def test_stamps_in_milliseconds_are_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A head session written with every stamp in milliseconds and no rate_hz: exit 2 naming the stream and the unit
    (it ran to 77 deg RMS before)."""
    from fusegraph.scenarios import simulate_head
    from fusegraph.session import save_session

    session = simulate_head(0, duration_s=3.0)
    in_ms = {name: replace(s, t=1000.0 * s.t, meta={k: v for k, v in s.meta.items() if k != "rate_hz"}) for name, s in session.streams.items()}
    save_session(replace(session, streams=in_ms, truth=None), tmp_path / "ms")
    capsys.readouterr()
    assert main(["run", str(tmp_path / "ms"), "--solver", "online"]) == 2
    err = capsys.readouterr().err
    assert "stream 'gyro'" in err and "milliseconds" in err, err


def test_a_declared_gyro_scale_is_estimated_and_printed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np

    session = tmp_path / "a9"
    assert main(["simulate", "attitude9", "--gyro-scale-error", "0.02", "--duration", "20", "--out", str(session)]) == 0
    toml = session / "session.toml"
    toml.write_text(toml.read_text().replace("[streams.gyro]\n", "[streams.gyro]\nscale_sigma = 0.05\n"))
    capsys.readouterr()
    assert main(["run", str(session), "--solver", "batch", "--out", str(tmp_path / "e.csv"), "--json"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert np.shape(printed["gyro_calibration"]) == (3, 3)
    assert main(["run", str(session), "--solver", "batch", "--out", str(tmp_path / "e.csv")]) == 0
    assert "gyro calibration estimated" in capsys.readouterr().out
    assert main(["run", str(session), "--solver", "online", "--out", str(tmp_path / "o.csv"), "--json"]) == 0
    assert "gyro_calibration" not in json.loads(capsys.readouterr().out)  # the online estimate keeps a perfect gyro
    assert main(["simulate", "head", "--gyro-scale-error", "0.01", "--out", str(tmp_path / "h")]) == 2  # attitude9 only


def test_check_runs_every_check_without_solving_and_prints_the_frames(tmp_path, capsys) -> None:
    """`fusegraph check`: exit 0 with the fitted turn between the accelerometer's and the gyro's axes where the motion tells
    (near zero on a right session); a session with its accelerometer axes swapped: exit 2 naming the stream."""
    import json

    import numpy as np

    from fusegraph.session import load_session, save_session

    assert main(["simulate", "attitude9", "--seed", "0", "--duration", "30", "--out", str(tmp_path / "ok")]) == 0
    capsys.readouterr()
    assert main(["check", str(tmp_path / "ok"), "--json"]) == 0
    frames = {f["stream"]: f for f in json.loads(capsys.readouterr().out)[0]["frames"]}
    assert frames["accel"]["told"] and frames["accel"]["turn_deg"] < 3.0  # the simulated axes agree: a turn of noise only
    session = load_session(tmp_path / "ok")
    from dataclasses import replace

    accel = session.stream("accel")
    save_session(replace(session, streams={**session.streams, "accel": replace(accel, values=accel.values[:, [1, 0, 2]])}), tmp_path / "bad")
    assert main(["check", str(tmp_path / "bad")]) == 2
    assert "stream 'accel'" in capsys.readouterr().err and np.isfinite(frames["accel"]["misfit_as_written_deg"])
