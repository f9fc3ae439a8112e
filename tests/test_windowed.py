"""A long recording smoothed in overlapping windows: the same estimate as the whole-recording batch, every sample once."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import fusegraph.session as session_module
from fusegraph.estimate import Estimate
from fusegraph.geometry import matrix_from_quat, quat_conjugate, quat_from_rotvec, quat_multiply, rotvec_from_quat
from fusegraph.scenarios import SIMULATORS
from fusegraph.session import Session, iter_session_blocks, load_session, save_session, write_stream_csv
from fusegraph.solvers.windowed import Windows, blended, heading_offset_rad, session_blocks, smooth_in_windows, turned_about_vertical
from fusegraph.systems import attitude9


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.linalg.norm(rotvec_from_quat(quat_multiply(quat_conjugate(a), b)), axis=1))


@pytest.fixture(scope="module")
def long_session() -> Session:
    # 400 s cut into 100 s windows with 30 s margins: four windows, three seams, the simulator's disturbed stretch among them
    return SIMULATORS["attitude9"].simulate(0, 400.0)


def test_the_windowed_batch_is_the_whole_batch_across_its_seams(long_session: Session) -> None:
    whole = attitude9.run_batch(long_session, windows=None)
    windowed = attitude9.run_batch(long_session, windows=Windows(100.0, 30.0))
    assert windowed.extras["windows"] == 4
    np.testing.assert_array_equal(windowed.t, whole.t)  # every sample once, in order
    difference = _angle_deg(whole.quat_wxyz, windowed.quat_wxyz)
    # 0.03 deg RMS, 0.08 deg at worst measured: a tenth of a degree is a fifth of the batch's own error against the truth
    # here (0.16 deg RMS), and a window started from gravity and the field alone was 16 deg off in a disturbance
    assert float(np.sqrt(np.mean(difference**2))) < 0.1
    assert float(difference.max()) < 0.3


def test_without_a_magnetometer_the_windows_keep_the_whole_batch_s_inclination(long_session: Session) -> None:
    no_mag = long_session.without("mag", "mag_cal")
    whole = attitude9.run_batch(no_mag, windows=None)
    windowed = attitude9.run_batch(no_mag, windows=Windows(100.0, 30.0))
    up_whole, up_windowed = matrix_from_quat(whole.quat_wxyz)[:, 2, :], matrix_from_quat(windowed.quat_wxyz)[:, 2, :]
    tilt_deg = np.degrees(np.arccos(np.clip(np.sum(up_whole * up_windowed, axis=1), -1.0, 1.0)))
    # the heading is not observed without a magnetometer (both drift, differently); the inclination is: 0.04 deg RMS measured
    assert float(np.sqrt(np.mean(tilt_deg**2))) < 0.15


def _constant_solver(turn_rad: list[float]) -> object:
    """A stand-in batch: every window's estimate is the identity turned about the vertical by its own angle (a heading
    that differs per window, as without a magnetometer)."""

    def solve(window: Session) -> Estimate:
        t = window.stream("gyro").t
        turn_rad.append(0.3 * len(turn_rad))
        quat = np.tile(quat_from_rotvec(np.array([0.0, 0.0, turn_rad[-1]])), (len(t), 1))
        return Estimate("batch", t.copy(), quat, None, 0.01, {"window": len(turn_rad)})

    return solve


def test_windows_cover_every_sample_once_and_align_headings_without_a_field(long_session: Session) -> None:
    turns: list[float] = []
    pieces = list(smooth_in_windows(session_blocks(long_session, 37.0), _constant_solver(turns), Windows(100.0, 30.0), align_heading=True))  # type: ignore[arg-type]
    t = np.concatenate([p.t for p in pieces])
    np.testing.assert_array_equal(t, long_session.stream("gyro").t)
    quat = np.concatenate([p.quat_wxyz for p in pieces])
    # every window turned onto the first: one heading throughout, though each window's own differs by 0.3 rad
    assert len(turns) == 4
    assert float(_angle_deg(quat, np.tile(quat[:1], (len(quat), 1))).max()) < 1e-9


def test_without_alignment_the_seam_is_blended_not_stepped(long_session: Session) -> None:
    turns: list[float] = []
    pieces = list(smooth_in_windows(session_blocks(long_session, 50.0), _constant_solver(turns), Windows(100.0, 30.0), align_heading=False))  # type: ignore[arg-type]
    quat = np.concatenate([p.quat_wxyz for p in pieces])
    step = _angle_deg(quat[:-1], quat[1:])
    # 0.3 rad spread over the 30 s blend at 100 Hz: ~0.006 deg a sample, never the 17 deg step
    assert float(step.max()) < 0.05
    assert float(_angle_deg(quat[-1:], quat[:1])[0]) == pytest.approx(np.degrees(0.9), abs=1e-6)


def test_blend_ends_at_its_inputs_and_heading_offset_is_the_turn() -> None:
    t = np.linspace(0.0, 1.0, 11)
    before = Estimate("a", t, np.tile([1.0, 0.0, 0.0, 0.0], (11, 1)))
    after = turned_about_vertical(before, 0.4)
    mixed = blended(before, after)
    np.testing.assert_allclose(mixed.quat_wxyz[0], before.quat_wxyz[0], atol=1e-12)
    np.testing.assert_allclose(mixed.quat_wxyz[-1], after.quat_wxyz[-1], atol=1e-12)
    assert heading_offset_rad(after.quat_wxyz, before.quat_wxyz) == pytest.approx(0.4, abs=1e-12)
    assert not Windows(100.0, 30.0).needed(160.0) and Windows(100.0, 30.0).needed(160.5)
    with pytest.raises(ValueError, match="window_s"):
        Windows(10.0, 30.0)


def test_a_session_read_in_blocks_is_the_session_read_whole(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    session = SIMULATORS["attitude9"].simulate(1, 30.0)
    root = save_session(session, tmp_path / "s")
    toml = (root / "session.toml").read_text()
    # the gyro written in deg/s and declared so, the magnetometer with x and y swapped and declared so: both undone block by block
    gyro = session.stream("gyro")
    write_stream_csv(root / "gyro.csv", gyro.t, np.degrees(gyro.values), gyro.columns)
    mag = session.stream("mag")
    swap = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    write_stream_csv(root / "mag.csv", mag.t, mag.values @ swap, mag.columns)
    toml = toml.replace("[streams.gyro]\n", "[streams.gyro]\nunits = \"deg/s\"\n").replace(
        "[streams.mag]\n", "[streams.mag]\nframe_R_sensor = [[0, 1, 0], [1, 0, 0], [0, 0, 1]]\n")
    (root / "session.toml").write_text(toml)
    whole = load_session(root)
    monkeypatch.setattr(session_module, "CSV_BLOCK_ROWS", 777)  # several CSV blocks per time block and across them
    blocks = list(iter_session_blocks(root, block_s=4.0))
    assert len(blocks) == 8  # 30 s in blocks of 4 s
    for name, stream in whole.streams.items():
        if stream.meta.get("role") == "calibration recording":
            assert all(len(b.stream(name)) == len(stream) for b in blocks)
            continue
        np.testing.assert_array_equal(np.concatenate([b.stream(name).t for b in blocks]), stream.t)
        np.testing.assert_allclose(np.concatenate([b.stream(name).values for b in blocks]), stream.values, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(whole.stream("gyro").values, session.stream("gyro").values, atol=1e-9)
    np.testing.assert_allclose(whole.stream("mag").values, session.stream("mag").values, atol=1e-9)


def test_a_long_session_is_checked_a_window_at_a_time(tmp_path: Path) -> None:
    """``check`` reads a session longer than its window one window at a time (``runner.check_session``): on a right one every
    window passes and the frames are told; with the magnetometer's x and y swapped, ``check`` and the streamed batch (``run
    --stream``, which wrote an estimate and exited 0 on it) both stop with the frame error, naming the window."""
    from fusegraph.evaluation.runner import check_session, run_streamed
    from fusegraph.session import SessionError

    session = SIMULATORS["attitude9"].simulate(2, 60.0)
    root = save_session(session, tmp_path / "ok")
    found = check_session(root, window_s=20.0)
    frames = {f["stream"]: f for f in found["frames"]}
    assert found["windows"] == 3 and frames["accel"]["told"] and frames["mag"]["told"]
    assert frames["accel"]["turn_deg"] < 3.0 and frames["mag"]["turn_deg"] < 3.0  # deg: the simulated axes agree, a turn of noise only
    assert check_session(root)["windows"] == 1  # shorter than the default window: read whole, as before
    assert check_session(root, window_s=50.0)["windows"] == 1  # a short last window (10 s) is joined: one window, read whole
    bad = save_session(session, tmp_path / "bad")
    mag = session.stream("mag")
    write_stream_csv(bad / "mag.csv", mag.t, mag.values[:, [1, 0, 2]], mag.columns)
    with pytest.raises(SessionError, match=r"stream 'mag': .*another frame than the gyro's.* \(in the window 0-20 s\)"):
        check_session(bad, window_s=20.0)
    with pytest.raises(SessionError, match=r"stream 'mag': .*another frame than the gyro's.* \(in the window 0-60 s\)"):
        run_streamed(bad, tmp_path / "estimate.csv")
    dead = save_session(session, tmp_path / "dead")
    write_stream_csv(dead / "mag.csv", mag.t, np.zeros_like(mag.values), mag.columns)
    with pytest.warns(UserWarning, match="stream 'mag': .*solved without it"):
        said = run_streamed(dead, tmp_path / "estimate.csv")  # the dead magnetometer left out, as a session read whole
    assert f"({len(session.stream('gyro'))} rows" in said  # an attitude at every gyro sample


def test_a_long_session_s_truth_is_checked_a_window_at_a_time(tmp_path: Path) -> None:
    """The truth of a session checked window by window is checked in each window as in a whole read: written body_R_world
    (the conjugate) it is named, with its window; on another clock (no window holds a sample of it) it is the whole read's
    clock error; a right one passes, and each window's truth is the truth's samples within its streams' span."""
    from fusegraph.evaluation.runner import check_session
    from fusegraph.session import SessionError

    session = SIMULATORS["attitude9"].simulate(2, 60.0)
    truth = session.truth
    assert truth is not None
    root = save_session(session, tmp_path / "ok")
    assert check_session(root, window_s=20.0)["windows"] == 3
    blocks = list(iter_session_blocks(root, 20.0, truth=True))
    assert all(b.truth is not None for b in blocks) and sum(len(b.truth) for b in blocks if b.truth is not None) == len(truth)
    assert all(b.truth is None for b in iter_session_blocks(root, 20.0))  # not asked: not read
    conjugated = save_session(session, tmp_path / "conjugated")
    write_stream_csv(conjugated / "truth.csv", truth.t, quat_conjugate(truth.values), truth.columns)
    with pytest.raises(SessionError, match=r"truth: .*written as body_R_world.* \(in the window 0-20 s\)"):
        check_session(conjugated, window_s=20.0)
    elsewhere = save_session(session, tmp_path / "elsewhere")
    write_stream_csv(elsewhere / "truth.csv", truth.t + 1000.0, truth.values, truth.columns)
    with pytest.raises(SessionError, match=r"toml: truth \(1000.000 .. 1060.000 s\) does not overlap the streams \(0.000 .. 60.000 s\): on another clock"):
        check_session(elsewhere, window_s=20.0)
    with pytest.raises(SessionError, match=r"session.toml: truth \(1000.000 .. 1060.000 s\) does not overlap 'gyro' \(0.000 .. 60.000 s\): on another clock"):
        load_session(elsewhere).validate()  # a whole read says it of the gyro


def test_a_walk_streamed_window_by_window_is_the_whole_run_s(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--solver gait`` window by window (``runner.gait_in_windows``) finds the whole run's steps, each once, and its strides
    to 5e-4 m (measured 1.6e-4: 400 s of simulated walking in windows of 100 s with 60 s either side, where the pelvis's
    rise's 0.1 Hz high-pass is cut); ``run --stream --solver gait`` writes the files ``run --solver gait`` writes (a session
    that one window holds: the same bytes), and a solver it does not stream is an error naming what it streams."""
    from fusegraph.cli import main
    from fusegraph.evaluation.runner import gait_in_windows
    from fusegraph.systems.presets import PRESETS

    session = SIMULATORS["walking"].simulate(0, 400.0)
    whole = PRESETS["walking"].solve(session, "gait")
    pieces = list(gait_in_windows(session_blocks(session, 60.0), Windows(100.0, 60.0)))
    assert len(pieces) == 3  # kept 0-100, 100-200 and the rest: under 100 s plus both margins is left after 200 s
    np.testing.assert_array_equal(np.concatenate([p.extras["steps_s"] for p in pieces]), whole.extras["steps_s"])
    np.testing.assert_array_equal(np.concatenate([p.extras["steps_inferred"] for p in pieces]), whole.extras["steps_inferred"])
    np.testing.assert_array_equal(np.concatenate([p.t for p in pieces]), whole.t)
    np.testing.assert_allclose(np.concatenate([p.points for p in pieces]), whole.points, atol=5e-4)
    root = save_session(session, tmp_path / "walk")
    assert main(["run", str(root), "--solver", "gait", "--out", str(tmp_path / "whole.csv")]) == 0
    assert main(["run", str(root), "--solver", "gait", "--stream", "--out", str(tmp_path / "streamed.csv")]) == 0
    for name in ("", "_steps"):
        assert (tmp_path / f"streamed{name}.csv").read_bytes() == (tmp_path / f"whole{name}.csv").read_bytes()
    capsys.readouterr()
    assert main(["run", str(root), "--solver", "batch", "--stream", "--out", str(tmp_path / "x.csv")]) == 2
    assert "--stream runs the attitude9 batch, the walking gait; this is a 'walking' session and --solver batch" in capsys.readouterr().err
