"""Session loading: every bad input fails with a message naming file, line and problem; round trips are exact."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fusegraph import Session, SessionError, Stream, load_session, replay_in_arrival_order, save_session
from fusegraph.scenarios import simulate_head
from fusegraph.session import KIND_COLUMNS

TOML = """[session]
system = "head"

[streams.gyro]
kind = "gyro"
file = "gyro.csv"

[streams.tracker]
kind = "attitude"
file = "tracker.csv"
latency_s = 0.1
"""


def write_session(root: Path, gyro: str, tracker: str = "t,qw,qx,qy,qz\n0,1,0,0,0\n0.02,1,0,0,0\n", toml: str = TOML) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    (root / "session.toml").write_text(toml)
    (root / "gyro.csv").write_text(gyro)
    (root / "tracker.csv").write_text(tracker)
    return root


GOOD_GYRO = "t,wx,wy,wz\n0,0,0,0\n0.01,0.1,0,0\n0.02,0.1,0,0\n"


def test_good_session_loads(tmp_path: Path) -> None:
    session = load_session(write_session(tmp_path, GOOD_GYRO))
    assert session.system == "head"
    assert session.stream("tracker").latency_s == 0.1
    assert len(session.stream("gyro")) == 3


@pytest.mark.parametrize(
    ("gyro", "message"),
    [
        ("t,wx,wy\n0,0,0\n", r"gyro.csv \(stream 'gyro'\): column 'wz' missing \(have: t, wx, wy\)"),
        ("t,wx,wy,wz\n0,0,0,0\n0.01,nan,0,0\n", r"gyro.csv \(stream 'gyro'\): line 3: column 'wx' is nan"),
        ("t,wx,wy,wz\n0,0,0,0\n0.01,0,inf,0\n", r"line 3: column 'wy' is inf"),
        ("t,wx,wy,wz\n0,0,0,0\n0.02,0,0,0\n0.01,0,0,0\n", r"line 4: time goes backwards \(t = 0.01 after 0.02\)"),
        ("t,wx,wy,wz\n0,0,0,0\n0,0,0,0\n", r"line 3: duplicate time t = 0.0"),
        ("t,wx,wy,wz\n", r"no samples \(the stream is empty\)"),
        ("", r"empty file"),
        ("t,wx,wy,wz\n0,0,x,0\n", r"line 2: column 'wy' is not a number \('x'\)"),
        ("t,wx,wy,wz\n0,0,0\n", r"line 2: 3 fields, header has 4"),
        ("wx,t,wy,wz\n0,0,0,0\n", r"first column must be 't'"),
    ],
)
def test_bad_stream_names_file_line_and_problem(tmp_path: Path, gyro: str, message: str) -> None:
    with pytest.raises(SessionError, match=message):
        load_session(write_session(tmp_path, gyro))


def test_missing_file_and_bad_kind(tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="session.toml: not found"):
        load_session(tmp_path)
    root = write_session(tmp_path / "a", GOOD_GYRO, toml=TOML.replace('kind = "gyro"', 'kind = "gyroscope"'))
    with pytest.raises(SessionError, match=r"stream 'gyro': kind = 'gyroscope' is not one of"):
        load_session(root)
    root = write_session(tmp_path / "b", GOOD_GYRO, toml=TOML.replace('file = "tracker.csv"', 'file = "nope.csv"'))
    with pytest.raises(SessionError, match=r"nope.csv \(stream 'tracker'\): file not found"):
        load_session(root)
    root = write_session(tmp_path / "c", GOOD_GYRO, toml=TOML.replace("latency_s = 0.1", "latency_s = -1"))
    with pytest.raises(SessionError, match="latency_s must be a finite number >= 0"):
        load_session(root)


def test_unknown_stream_lists_the_known_ones(tmp_path: Path) -> None:
    session = load_session(write_session(tmp_path, GOOD_GYRO))
    with pytest.raises(SessionError, match=r"no stream 'mag' \(have: gyro, tracker\)"):
        session.stream("mag")


def test_simulated_session_round_trips_exactly(tmp_path: Path) -> None:
    session = simulate_head(4, duration_s=2.0)
    loaded = load_session(save_session(session, tmp_path / "s"))
    for name, stream in session.streams.items():
        np.testing.assert_array_equal(loaded.stream(name).t, stream.t)
        np.testing.assert_array_equal(loaded.stream(name).values, stream.values)
        assert loaded.stream(name).latency_s == stream.latency_s
        assert dict(loaded.stream(name).meta) == dict(stream.meta)
    assert loaded.truth is not None and session.truth is not None
    np.testing.assert_array_equal(loaded.truth.values, session.truth.values)


def test_gaps_are_reported_not_errors() -> None:
    t = np.array([0.0, 0.02, 0.04, 0.5, 0.52])
    stream = Stream("tracker", "attitude", t, np.tile([1.0, 0, 0, 0], (5, 1)), KIND_COLUMNS["attitude"])
    assert stream.gaps() == [(0.04, 0.5)]


def test_replay_orders_by_arrival_and_puts_gyro_last_on_ties() -> None:
    gyro = Stream("gyro", "gyro", np.array([0.0, 0.1, 0.2]), np.zeros((3, 3)), KIND_COLUMNS["gyro"])
    tracker = Stream("tracker", "attitude", np.array([0.0, 0.1]), np.tile([1.0, 0, 0, 0], (2, 1)), KIND_COLUMNS["attitude"], latency_s=0.1)
    session = Session("head", {"gyro": gyro, "tracker": tracker})
    order = [(e.stream.name, e.t) for e in replay_in_arrival_order(session, last_streams=("gyro",))]
    assert order == [("gyro", 0.0), ("tracker", 0.0), ("gyro", 0.1), ("tracker", 0.1), ("gyro", 0.2)]


# within a gyro's plausible range (|omega| <= 35 rad/s, the catalogue's check; beyond it loading refuses)
finite = st.floats(min_value=-20.0, max_value=20.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=30), st.floats(min_value=1e-3, max_value=10.0))
def test_any_valid_stream_round_trips(tmp_path_factory: pytest.TempPathFactory, rows: list[tuple[float, float, float]], dt: float) -> None:
    t = np.arange(len(rows)) * dt
    stream = Stream("gyro", "gyro", t, np.array(rows, dtype=float), KIND_COLUMNS["gyro"])
    root = tmp_path_factory.mktemp("s")
    loaded = load_session(save_session(Session("head", {"gyro": stream}), root))
    np.testing.assert_array_equal(loaded.stream("gyro").values, stream.values)
    np.testing.assert_array_equal(loaded.stream("gyro").t, t)


def test_truth_may_have_nan_gaps_but_sensors_may_not(tmp_path: Path) -> None:
    session = simulate_head(1, duration_s=1.0)
    assert session.truth is not None
    values = session.truth.values.copy()
    values[5] = np.nan  # an occluded marker
    gappy = Session(session.system, session.streams, Stream("truth", "attitude", session.truth.t, values, KIND_COLUMNS["attitude"]), session.meta)
    loaded = load_session(save_session(gappy, tmp_path / "s"))
    assert loaded.truth is not None and np.isnan(loaded.truth.values[5]).all()


def test_a_stream_on_another_clock_is_named(tmp_path: Path) -> None:
    """Tracker stamps in milliseconds against a gyro in seconds: the streams do not overlap in time."""
    tracker_ms = "t,qw,qx,qy,qz\n1000,1,0,0,0\n1020,1,0,0,0\n"
    with pytest.raises(SessionError, match=r"stream 'gyro' \(0.000 .. 0.020 s\) does not overlap 'tracker' \(1000.000 .. 1020.000 s\).*\(ms\? ns\?\)"):
        load_session(write_session(tmp_path, GOOD_GYRO, tracker_ms))


def test_a_session_built_in_memory_is_validated_by_every_solver() -> None:
    """NaN, time going back or an unknown key in a Session made in Python: the same clear errors as a loaded one, before
    any solver runs (not gtsam's 'Indeterminant linear system')."""
    from dataclasses import replace

    from fusegraph.systems.presets import PRESETS

    session = simulate_head(0, duration_s=2.0)
    gyro = session.stream("gyro")
    broken = gyro.values.copy()
    broken[10, 1] = np.nan
    for damaged, message in (
        (replace(gyro, values=broken), "stream 'gyro': sample 10: a value is NaN"),
        (replace(gyro, t=gyro.t[::-1].copy()), "stream 'gyro': sample 1: time goes backwards"),
        (replace(gyro, meta={**gyro.meta, "noise_sigma_rad": 0.01}), "unknown key 'noise_sigma_rad'"),
    ):
        for solver in ("online", "ekf"):
            with pytest.raises(SessionError, match=message):
                PRESETS["head"].solve(replace(session, streams={**session.streams, "gyro": damaged}), solver)


def test_the_fast_csv_reader_reads_the_floats_python_reads_and_falls_back_where_it_cannot(tmp_path: Path) -> None:
    """pandas' C reader gives the bits Python's float() gives (exponents from 1e-8 to 1e8, 17 digits), block by block; a
    file it cannot vouch for (a row of empty cells, a row with an extra field) is read row by row to the same samples."""
    from fusegraph.session import _iter_fast, _iter_rows, read_stream_csv

    rng = np.random.default_rng(0)
    table = rng.normal(size=(3000, 4)) * 10.0 ** rng.integers(-8, 8, size=(3000, 4))
    table[:, 0] = np.arange(3000) * 0.0035 + rng.uniform(0.0, 1e-4, 3000)
    path = tmp_path / "x.csv"
    path.write_text("t,a,b,c\n" + "".join(",".join(repr(float(v)) for v in row) + "\n" for row in table))
    fast = np.vstack([np.c_[t, v] for t, v in _iter_fast(path, ("a", "b", "c"), False, False, 700)])
    slow = np.vstack([np.c_[t, v] for t, v in _iter_rows(path, ("a", "b", "c"), "", False, False, 700)])
    np.testing.assert_array_equal(fast, table)
    np.testing.assert_array_equal(slow, table)
    lines = path.read_text().splitlines(keepends=True)
    odd = tmp_path / "odd.csv"
    odd.write_text("".join(lines[:1500]) + ",,,\n" + lines[1500].rstrip("\n") + ",9\n" + "".join(lines[1501:]))
    t, values = read_stream_csv(odd, ("a", "b", "c"))
    np.testing.assert_array_equal(np.c_[t, values], table)
    late = tmp_path / "late.csv"  # a fault past the first blocks: the row reader names its line
    late.write_text("".join(lines[:2500]) + lines[2499] + "".join(lines[2500:]))
    with pytest.raises(SessionError, match="line 2501: duplicate time"):
        read_stream_csv(late, ("a", "b", "c"))
