"""import csv and import xdf on files the tests write: a vendor-style CSV export and a LabRecorder-style XDF file of a
simulated session give back the session's streams (converted to SI), and the same figures when run."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest

from fusegraph.cli import main
from fusegraph.scenarios import SIMULATORS
from fusegraph.session import SessionError, load_session, save_session


def _run_json(path: Path, solver: str, capsys: pytest.CaptureFixture[str]) -> dict[str, float]:
    capsys.readouterr()
    assert main(["run", str(path), "--solver", solver, "--json"]) == 0
    return json.loads(capsys.readouterr().out)["metrics"]


def test_import_csv_maps_a_vendor_export_onto_the_catalogue(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    session = SIMULATORS["attitude9"].simulate(3, 6.0).without("mag_cal")  # no calibration recording on either side
    save_session(session, tmp_path / "original")
    gyro, accel, mag = (session.stream(n) for n in ("gyro", "accel", "mag"))
    # a vendor's export: milliseconds, deg/s, g, its own column names, semicolons
    rows = np.column_stack([1000.0 * gyro.t, np.degrees(gyro.values), accel.values / 9.80665, mag.values])
    header = "Timestamp;GyrX;GyrY;GyrZ;AccX;AccY;AccZ;MagX;MagY;MagZ"
    np.savetxt(tmp_path / "export.csv", rows, delimiter=";", header=header, comments="", fmt="%.17g")
    truth = session.truth
    assert truth is not None
    np.savetxt(tmp_path / "optical.csv", np.column_stack([1000.0 * truth.t, truth.values]), delimiter=",", header="time,w,x,y,z", comments="", fmt="%.17g")
    out = tmp_path / "mine"
    common = ["--time-units", "ms", "--out", str(out)]
    assert main(["import", "csv", str(tmp_path / "export.csv"), "--system", "attitude9", "--kind", "gyro", "--units", "deg/s",
                 "--columns", "t=Timestamp,wx=GyrX,wy=GyrY,wz=GyrZ", *common]) == 0
    accel_columns = "t=Timestamp,ax=AccX,ay=AccY,az=AccZ"
    assert main(["import", "csv", str(tmp_path / "export.csv"), "--kind", "accel", "--units", "g", "--columns", accel_columns, *common]) == 0
    assert main(["import", "csv", str(tmp_path / "export.csv"), "--kind", "mag", "--columns", "t=Timestamp,mx=MagX,my=MagY,mz=MagZ", *common]) == 0
    assert main(["import", "csv", str(tmp_path / "optical.csv"), "--kind", "attitude", "--truth", "--columns", "t=time,qw=w,qx=x,qy=y,qz=z", *common]) == 0
    imported = load_session(out)
    np.testing.assert_allclose(imported.stream("gyro").values, gyro.values, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(imported.stream("accel").t + imported.meta["session"]["time_origin_s"], accel.t, atol=1e-9)
    ours, theirs = _run_json(out, "online", capsys), _run_json(tmp_path / "original", "online", capsys)
    assert ours["total_deg"] == pytest.approx(theirs["total_deg"], abs=1e-6)  # deg: only the unit conversions' rounding differs
    # mistakes a user makes, each one clear line
    assert main(["import", "csv", str(tmp_path / "export.csv"), "--kind", "gyro", "--columns", "t=Timestamp,wx=GyrX,wy=GyrY", *common]) == 2
    assert "name the file's column for wz too" in capsys.readouterr().err
    assert main(["import", "csv", str(tmp_path / "export.csv"), "--kind", "gyro", "--columns", "t=Timestamp,wx=GX,wy=GyrY,wz=GyrZ",
                 "--out", str(tmp_path / "x"), "--system", "attitude9"]) == 2
    assert "'GX' not in the header" in capsys.readouterr().err
    assert main(["import", "csv", str(tmp_path / "export.csv"), "--kind", "gyro", "--columns", "t=Timestamp,wx=GyrX,wy=GyrY,wz=GyrZ", *common]) == 2
    assert "already has stream 'gyro'" in capsys.readouterr().err


# ---------------------------------------------------------------------------------- a minimal XDF writer


def _chunk(tag: int, content: bytes) -> bytes:
    return struct.pack("<BQH", 8, len(content) + 2, tag) + content


def _xdf(path: Path, streams: list[tuple[str, np.ndarray, np.ndarray]]) -> None:
    """XDF 1.0 as LabRecorder writes it: file header, a header, samples and a footer per stream (float32 channels)."""
    data = b"XDF:" + _chunk(1, b"<?xml version='1.0'?><info><version>1.0</version></info>")
    for sid, (name, t, values) in enumerate(streams, start=1):
        info = (f"<?xml version='1.0'?><info><name>{name}</name><type>IMU</type><channel_count>{values.shape[1]}</channel_count>"
                f"<nominal_srate>0</nominal_srate><channel_format>double64</channel_format><created_at>0</created_at></info>")
        data += _chunk(2, struct.pack("<I", sid) + info.encode())
        samples = b"".join(struct.pack("<Bd", 8, float(ti)) + struct.pack(f"<{values.shape[1]}d", *row) for ti, row in zip(t, values, strict=True))
        data += _chunk(3, struct.pack("<I", sid) + struct.pack("<BI", 4, len(t)) + samples)
        footer = (f"<?xml version='1.0'?><info><first_timestamp>{t[0]}</first_timestamp><last_timestamp>{t[-1]}</last_timestamp>"
                  f"<sample_count>{len(t)}</sample_count></info>")
        data += _chunk(6, struct.pack("<I", sid) + footer.encode())
    path.write_bytes(data)


def test_import_xdf_reads_a_lab_streaming_layer_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("pyxdf")
    session = SIMULATORS["head"].simulate(2, 4.0)
    gyro, tracker = session.stream("gyro"), session.stream("tracker")
    offset = 5000.0  # LSL's clock: seconds since the machine started
    extra = np.zeros((10, 3))
    _xdf(tmp_path / "run.xdf", [("HMD_gyro", gyro.t + offset, gyro.values), ("Polhemus", tracker.t + offset, tracker.values),
                                ("Markers", np.arange(10.0) + offset, extra)])
    capsys.readouterr()
    assert main(["import", "xdf", str(tmp_path / "run.xdf"), "--system", "head", "--map", "HMD_gyro=gyro", "--map", "Polhemus=tracker:attitude",
                 "--out", str(tmp_path / "s")]) == 0
    assert "'Markers' not imported" in capsys.readouterr().err  # nothing silently dropped
    imported = load_session(tmp_path / "s")
    assert imported.stream("tracker").kind == "attitude"
    np.testing.assert_allclose(imported.stream("gyro").values, gyro.values)
    np.testing.assert_allclose(imported.stream("tracker").t - imported.stream("gyro").t[0], tracker.t - gyro.t[0], atol=1e-9)
    assert main(["import", "xdf", str(tmp_path / "run.xdf"), "--system", "head", "--map", "Nope=gyro", "--out", str(tmp_path / "t")]) == 2
    assert "no LSL stream 'Nope' (the file has: HMD_gyro, Polhemus, Markers)" in capsys.readouterr().err
    assert main(["import", "xdf", str(tmp_path / "run.xdf"), "--system", "head", "--map", "Markers=tracker:attitude", "--out", str(tmp_path / "u")]) == 2
    assert "has 3 channels; kind attitude needs 4" in capsys.readouterr().err


def test_import_xdf_reads_only_the_mapped_streams(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The streams of an XDF file are named from their header chunks alone, and pyxdf is asked for the mapped ones only: an
    EEG or a video stream beside the IMU's never reaches memory (a 300 MB file with a 64-channel 1 kHz stream beside a 100 Hz
    gyro: 705 MB and 3.4 s before, 151 MB and 0.9 s, the same session)."""
    pyxdf = pytest.importorskip("pyxdf")
    from fusegraph.datasets.generic import xdf_stream_names, xdf_streams

    t = np.arange(50) * 0.01
    _xdf(tmp_path / "run.xdf", [("EEG", t, np.ones((50, 8))), ("HMD_gyro", t, np.full((50, 3), 0.1)), ("Markers", t[:5], np.zeros((5, 1)))])
    assert xdf_stream_names(tmp_path / "run.xdf") == {1: "EEG", 2: "HMD_gyro", 3: "Markers"}
    asked: list[object] = []
    load = pyxdf.load_xdf

    def spy(path: str, select_streams: object = None, **kwargs: object) -> object:
        asked.append(select_streams)
        return load(path, select_streams=select_streams, **kwargs)

    monkeypatch.setattr(pyxdf, "load_xdf", spy)
    streams, unused = xdf_streams(tmp_path / "run.xdf", {"HMD_gyro": ("gyro", "gyro")})
    assert asked == [[2]] and unused == ["EEG", "Markers"]
    np.testing.assert_array_equal(streams["gyro"].values, np.full((50, 3), 0.1))
    (tmp_path / "torn.xdf").write_bytes((tmp_path / "run.xdf").read_bytes()[:4] + b"\x03")
    with pytest.raises(SessionError, match=r"torn.xdf: not a readable XDF file .*1, 4 or 8 in XDF"):
        xdf_streams(tmp_path / "torn.xdf", {"HMD_gyro": ("gyro", "gyro")})


def test_write_xdf_round_trips_through_import_xdf(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """What `live --record` writes beside the session (write_xdf) reads back through `import xdf` to the same samples."""
    pytest.importorskip("pyxdf")
    from fusegraph.datasets.generic import write_xdf

    session = SIMULATORS["attitude9"].simulate(1, 3.0).without("mag_cal")
    write_xdf(session, tmp_path / "rec.xdf")
    maps = [arg for name in ("gyro", "accel", "mag") for arg in ("--map", f"{name}={name}")]
    assert main(["import", "xdf", str(tmp_path / "rec.xdf"), "--system", "attitude9", *maps, "--out", str(tmp_path / "s")]) == 0
    back = load_session(tmp_path / "s")
    for name in ("gyro", "accel", "mag"):
        np.testing.assert_array_equal(back.stream(name).values, session.stream(name).values)
        np.testing.assert_allclose(back.stream(name).t + back.meta["session"]["time_origin_s"], session.stream(name).t, atol=1e-12)


def _vendor_csv(path: Path, t_ms: np.ndarray, values: np.ndarray, names: tuple[str, str, str]) -> Path:
    np.savetxt(path, np.column_stack([t_ms, values]), delimiter=",", header=",".join(("Timestamp", *names)), comments="")
    return path


def test_import_csv_takes_a_magnetometer_unit_and_puts_a_stream_on_another_s_clock(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """One unit key for every stream (`--units uT` / `gauss` for a magnetometer, as docs/sensors.md says); `--onto gyro` puts an
    accelerometer sampled on its own clock onto the gyro's times, interpolated, saying what it bridged."""
    rng = np.random.default_rng(0)
    t_gyro = np.arange(0.0, 20.0, 0.01) * 1000.0
    t_own = np.arange(0.003, 20.0, 0.0125) * 1000.0  # 80 Hz on another clock
    _vendor_csv(tmp_path / "gyr.csv", t_gyro, rng.normal(0.0, 0.01, (len(t_gyro), 3)), ("GyrX", "GyrY", "GyrZ"))
    ramp = np.column_stack([np.linspace(0.1, 0.2, len(t_own)), np.zeros(len(t_own)), np.full(len(t_own), 0.98)])
    _vendor_csv(tmp_path / "acc.csv", t_own, ramp, ("AccX", "AccY", "AccZ"))
    _vendor_csv(tmp_path / "mag.csv", t_own, np.tile([0.2, 0.0, -0.4], (len(t_own), 1)), ("MagX", "MagY", "MagZ"))
    out = tmp_path / "mine"
    assert main(["import", "csv", str(tmp_path / "gyr.csv"), "--system", "attitude9", "--kind", "gyro", "--columns",
                 "t=Timestamp,wx=GyrX,wy=GyrY,wz=GyrZ", "--time-units", "ms", "--out", str(out)]) == 0
    assert main(["import", "csv", str(tmp_path / "acc.csv"), "--kind", "accel", "--columns", "t=Timestamp,ax=AccX,ay=AccY,az=AccZ", "--units", "g",
                 "--time-units", "ms", "--out", str(out), "--onto", "gyro"]) == 0
    assert "interpolated linearly onto the" in capsys.readouterr().err
    for unit, factor in (("uT", 1.0), ("gauss", 100.0)):
        name = f"mag_{unit}"
        assert main(["import", "csv", str(tmp_path / "mag.csv"), "--kind", "mag", "--name", name, "--units", unit, "--columns",
                     "t=Timestamp,mx=MagX,my=MagY,mz=MagZ", "--time-units", "ms", "--out", str(out), "--onto", "gyro"]) == 0
        np.testing.assert_allclose(load_session(out).stream(name).values[0], np.array([0.2, 0.0, -0.4]) * factor)
    session = load_session(out)
    gyro, accel = session.stream("gyro"), session.stream("accel")
    assert np.all(np.isin(accel.t, gyro.t))  # on the gyro's times
    expected = np.interp(accel.t + float(session.meta["session"]["time_origin_s"]), t_own / 1000.0, ramp[:, 0]) * 9.80665
    np.testing.assert_allclose(accel.values[:, 0], expected, rtol=1e-6)  # a linear ramp is interpolated exactly


def test_import_csv_says_repeated_stamps_at_import(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    t = np.arange(0.0, 5.0, 0.01) * 1000.0
    values = np.random.default_rng(1).normal(0.0, 0.01, (len(t), 3))
    twice = np.insert(np.column_stack([t, values]), 50, np.column_stack([t, values])[49], axis=0)
    np.savetxt(tmp_path / "g.csv", twice, delimiter=",", header="T,X,Y,Z", comments="")
    argv = ["import", "csv", str(tmp_path / "g.csv"), "--system", "attitude9", "--kind", "gyro", "--columns", "t=T,wx=X,wy=Y,wz=Z", "--time-units", "ms"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    assert "1 row repeat the row before exactly (first: line 52)" in capsys.readouterr().err
    assert len(load_session(tmp_path / "a").stream("gyro")) == len(t)
    twice[50, 1] += 1.0  # the same time with another value: no sample can be kept
    np.savetxt(tmp_path / "g.csv", twice, delimiter=",", header="T,X,Y,Z", comments="")
    assert main([*argv, "--out", str(tmp_path / "b")]) == 2
    assert "line 52: time 490.0 repeats line 51 with other values" in capsys.readouterr().err


def test_dataset_importers_take_the_published_folders(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """LIAS UWB as published (its README.md at the top, runs in folders below) and a folder of Pupil exports."""
    import shutil

    from conftest import SHARED_DATA

    if not (SHARED_DATA / "uwb_lias").is_dir() or not (SHARED_DATA / "gaze_pupil_invisible").is_dir():
        pytest.skip(f"real recordings not found at {SHARED_DATA} (CI has them beside the repo)")
    published = tmp_path / "Planar_Dataset"
    (published / "fast").mkdir(parents=True)
    shutil.copy(SHARED_DATA / "uwb_lias" / "SOURCE_README.md", published / "README.md")
    for csv_file in (SHARED_DATA / "uwb_lias").glob("*_exp_fast.csv"):
        shutil.copy(csv_file, published / "fast")
    assert main(["import", "uwb", str(published), "--out", str(tmp_path / "uwb")]) == 0
    assert (tmp_path / "uwb" / "fast" / "session.toml").is_file()
    for name in ("rec1", "rec2"):
        shutil.copytree(SHARED_DATA / "gaze_pupil_invisible", tmp_path / "exports" / name)
    assert main(["import", "pupil", str(tmp_path / "exports"), "--out", str(tmp_path / "pupil")]) == 0
    assert sorted(p.parent.name for p in (tmp_path / "pupil").glob("*/session.toml")) == ["rec1", "rec2"]
    capsys.readouterr()
    assert main(["datasets", "check", str(published / "fast")]) == 2  # a run alone lacks the README: said
    assert "missing README.md|SOURCE_README.md" in capsys.readouterr().out
    assert main(["datasets", "check", str(SHARED_DATA / "uwb_lias")]) == 0
    assert "uwb (complete" in capsys.readouterr().out


def test_every_dataset_importer_takes_one_recording_too(tmp_path: Path) -> None:
    from conftest import SHARED_DATA

    if not (SHARED_DATA / "hapt").is_dir() or not (SHARED_DATA / "mobgap").is_dir():
        pytest.skip(f"real recordings not found at {SHARED_DATA} (CI has them beside the repo)")
    assert main(["import", "hapt", str(SHARED_DATA / "hapt" / "acc_exp01_user01.txt"), "--out", str(tmp_path / "hapt")]) == 0
    assert [p.parent.name for p in (tmp_path / "hapt").glob("*/session.toml")] == ["exp01_user01"]
    participant = next((SHARED_DATA / "mobgap" / "lab").glob("*/*"))
    assert main(["import", "mobgap", str(participant), "--out", str(tmp_path / "mobgap")]) == 0
    assert list((tmp_path / "mobgap").glob("*/session.toml"))


def test_import_csv_reads_and_writes_a_block_at_a_time(tmp_path: Path) -> None:
    """A long export is never held whole (``iter_csv_stream``, ``import_csv``): read in blocks of 64 rows, the checks hold
    across the blocks' edges (a double write and a time going back straddling one are found at their lines), and the
    session written block by block is the one the whole-file path writes. A decimal comma is read with ``decimal=","``
    and named when it is not declared."""
    import warnings

    from fusegraph.datasets.generic import add_to_session, csv_stream, import_csv, iter_csv_stream
    from fusegraph.session import SessionError

    t = np.arange(300) * 10.0  # ms
    values = np.random.default_rng(2).normal(0.0, 0.5, (300, 3)).round(6)
    rows = np.insert(np.column_stack([t, values]), 64, np.column_stack([t, values])[63], axis=0)  # rows 64 and 65 the same, blocks of 64
    lines = ["Time;GX;GY;GZ;Temp"] + [f"{r[0]:.0f};{r[1]:.6f};{r[2]:.6f};{r[3]:.6f};25.0" for r in rows]
    (tmp_path / "dot.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "comma.csv").write_text("\n".join(line.replace(".", ",") for line in lines) + "\n")
    columns = {"t": "Time", "wx": "GX", "wy": "GY", "wz": "GZ"}
    with pytest.warns(UserWarning, match=r"1 row repeat the row before exactly \(first: line 66\)"):
        blocks = list(iter_csv_stream(tmp_path / "dot.csv", "gyro", columns, "deg/s", "ms", block_rows=64))
    assert [len(b[0]) for b in blocks] == [64, 63, 64, 64, 45]  # 301 rows; the repeat, the second block's first row, left out
    np.testing.assert_array_equal(np.concatenate([b[0] for b in blocks]), t * 1e-3)  # ms times 1e-3, as --time-units ms
    np.testing.assert_allclose(np.concatenate([b[1] for b in blocks]), np.radians(values), rtol=1e-15)
    (tmp_path / "spaces.txt").write_text("\n".join(line.replace(";", "  ") for line in lines) + "\n")  # columns between spaces
    with pytest.warns(UserWarning, match="1 row repeat"):
        spaced = list(iter_csv_stream(tmp_path / "spaces.txt", "gyro", columns, "deg/s", "ms", block_rows=64))
    for ours, theirs in zip(spaced, blocks, strict=True):
        np.testing.assert_array_equal(ours[0], theirs[0])
        np.testing.assert_array_equal(ours[1], theirs[1])
    (tmp_path / "one.csv").write_text("TimeGX\n1\n")
    with pytest.raises(SessionError, match="line 1: no delimiter between the column names"):
        list(iter_csv_stream(tmp_path / "one.csv", "gyro", columns))
    with pytest.raises(SessionError, match=r"line 2: column 'GX' is not a number \('-?\d+,\d+'\) \(a decimal comma\? pass --decimal ,\)"):
        list(iter_csv_stream(tmp_path / "comma.csv", "gyro", columns, block_rows=64))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the double write, said above
        whole = csv_stream(tmp_path / "dot.csv", "gyro", columns, units="deg/s", time_units="ms")
        path, written = import_csv(tmp_path / "blocks", tmp_path / "comma.csv", "gyro", columns, units="deg/s", time_units="ms", system="attitude9",
                                   decimal=",", block_rows=64)
    add_to_session(tmp_path / "whole", {"gyro": whole}, "attitude9")
    assert written == 300
    by_blocks, at_once = load_session(path), load_session(tmp_path / "whole")
    np.testing.assert_array_equal(by_blocks.stream("gyro").t, at_once.stream("gyro").t)
    np.testing.assert_array_equal(by_blocks.stream("gyro").values, at_once.stream("gyro").values)
    assert by_blocks.meta["session"] == at_once.meta["session"]
    # a time going back across a block's edge: data row 128 (line 130), the third block's first, against the second's last
    broken = lines.copy()
    broken[129] = broken[129].replace(f"{rows[128, 0]:.0f};", "5;", 1)
    (tmp_path / "back.csv").write_text("\n".join(broken) + "\n")
    with pytest.raises(SessionError, match=r"line 130: time 5.0 goes back from 1260.0 on line 129"):
        list(iter_csv_stream(tmp_path / "back.csv", "gyro", columns, block_rows=64))
    with pytest.raises(SessionError, match="line 130: time 5.0 goes back"):
        import_csv(tmp_path / "failed", tmp_path / "back.csv", "gyro", columns, system="attitude9", block_rows=64)
    assert not (tmp_path / "failed").exists()  # nothing half written is left
    broken = lines.copy()
    broken[200] = f"{rows[199, 0]:.0f};{rows[199, 1]:.6f};;{rows[199, 3]:.6f};25.0"  # data row 199 (line 201): GY empty
    (tmp_path / "hole.csv").write_text("\n".join(broken) + "\n")
    with pytest.raises(SessionError, match="line 201: column 'GY' is empty"):
        list(iter_csv_stream(tmp_path / "hole.csv", "gyro", columns, block_rows=64))
    nan_row = f"{rows[149, 0]:.0f};nan;{rows[149, 2]:.6f};{rows[149, 3]:.6f};25.0"  # data row 149 (line 151): a logger's NaN
    (tmp_path / "nan.csv").write_text("\n".join([*lines[:150], nan_row, *lines[151:]]) + "\n")
    with pytest.raises(SessionError, match=r"line 151: column 'GX' is nan \(leave the row out for a dropout\)"):
        list(iter_csv_stream(tmp_path / "nan.csv", "gyro", columns, block_rows=64))


def test_a_stream_put_on_another_s_times_block_by_block_is_the_one_put_on_them_whole(tmp_path: Path) -> None:
    """``--onto`` reads both streams a block at a time (``onto_times``): an accelerometer on its own clock (80 Hz, starting
    before the gyro and ending after it, one sample missing for 0.5 s) put on the gyro's times in blocks of 64 rows of
    either is the one made in one block of each, to the byte, and says the same; a stream that does not overlap is an error
    that leaves nothing behind."""
    import warnings

    from fusegraph.datasets.generic import import_csv
    from fusegraph.session import SessionError

    rng = np.random.default_rng(3)
    t_gyro = np.arange(1.0, 9.0, 0.01) * 1000.0
    t_own = np.delete(np.arange(0.003, 10.0, 0.0125), np.arange(300, 340)) * 1000.0
    _vendor_csv(tmp_path / "gyr.csv", t_gyro, rng.normal(0.0, 0.01, (len(t_gyro), 3)), ("GyrX", "GyrY", "GyrZ"))
    _vendor_csv(tmp_path / "acc.csv", t_own, rng.normal(0.0, 0.1, (len(t_own), 3)) + [0.0, 0.0, 1.0], ("AccX", "AccY", "AccZ"))
    gyro_columns = {"t": "Timestamp", "wx": "GyrX", "wy": "GyrY", "wz": "GyrZ"}
    accel_columns = {"t": "Timestamp", "ax": "AccX", "ay": "AccY", "az": "AccZ"}
    said = {}
    for rows in (64, 100_000):
        out = tmp_path / f"blocks_{rows}"
        import_csv(out, tmp_path / "gyr.csv", "gyro", gyro_columns, time_units="ms", system="attitude9", block_rows=rows)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            import_csv(out, tmp_path / "acc.csv", "accel", accel_columns, units="g", time_units="ms", onto="gyro", block_rows=rows)
        said[rows] = [str(w.message).split(": ", 1)[1] for w in caught if "interpolated linearly" in str(w.message)]
    assert said[64] == said[100_000] and "largest interval bridged 0.5125 s" in said[64][0], said  # the 0.5 s without a sample
    assert (tmp_path / "blocks_64" / "accel.csv").read_bytes() == (tmp_path / "blocks_100000" / "accel.csv").read_bytes()
    assert (tmp_path / "blocks_64" / "session.toml").read_text() == (tmp_path / "blocks_100000" / "session.toml").read_text()
    accel = load_session(tmp_path / "blocks_64").stream("accel")
    assert len(accel) == len(t_gyro)  # the gyro's every time lies inside the accelerometer's span
    _vendor_csv(tmp_path / "late.csv", t_own + 60_000.0, rng.normal(0.0, 0.1, (len(t_own), 3)), ("AccX", "AccY", "AccZ"))
    with pytest.raises(SessionError, match="does not overlap 'gyro'"):
        import_csv(tmp_path / "blocks_64", tmp_path / "late.csv", "accel", accel_columns, name="late", time_units="ms", onto="gyro", block_rows=64)
    assert not (tmp_path / "blocks_64" / "late.csv").exists() and not (tmp_path / "blocks_64" / "late.csv.partial").exists()


def test_import_csv_reads_iso_date_times(tmp_path: Path) -> None:
    """``--time-units iso``: a date-time column (a space or a T, a zone offset or none) read as seconds since 1970 UTC;
    without it the error says what the column looks like. 1e-6 s: seconds near 1.7e9 are held to 0.24 us."""
    from fusegraph.datasets.generic import import_csv, iter_csv_stream
    from fusegraph.session import SessionError

    stamps = ["2024-05-01 12:00:00.000", "2024-05-01 12:00:00.010", "2024-05-01T12:00:00.020", "2024-05-01T14:00:00.030+02:00"]
    (tmp_path / "iso.csv").write_text("When,GX,GY,GZ\n" + "".join(f"{s},0.1,0.2,0.3\n" for s in stamps))
    columns = {"t": "When", "wx": "GX", "wy": "GY", "wz": "GZ"}
    ((t, values),) = list(iter_csv_stream(tmp_path / "iso.csv", "gyro", columns, time_units="iso"))
    np.testing.assert_allclose(t - 1714564800.0, [0.0, 0.01, 0.02, 0.03], atol=1e-6)  # 12:00 UTC on 2024-05-01; 14:00+02:00 is 12:00 UTC
    path, rows = import_csv(tmp_path / "s", tmp_path / "iso.csv", "gyro", columns, time_units="iso", system="attitude9")
    assert rows == 4 and load_session(path).meta["session"]["time_origin_s"] == 1714564800.0
    with pytest.raises(SessionError, match=r"line 2: column 'When' is not a number \('2024-05-01 12:00:00.000'\) \(a date-time\? pass --time-units iso\)"):
        list(iter_csv_stream(tmp_path / "iso.csv", "gyro", columns))
    (tmp_path / "bad.csv").write_text("When,GX,GY,GZ\n2024-05-01 12:00:00.000,0.1,0.2,0.3\nnoon,0.1,0.2,0.3\n")
    with pytest.raises(SessionError, match=r"line 3: column 'When' is not an ISO 8601 date-time \('noon'\)"):
        list(iter_csv_stream(tmp_path / "bad.csv", "gyro", columns, time_units="iso"))
