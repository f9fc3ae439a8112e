"""Damaged sessions, generated: a clear error (exit 2) or a valid estimate (exit 0), never a traceback or an
internal error (exit 1), never a silently wrong one for the faults the loader can see."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fusegraph.cli import main

FAULTS = ("gyro_deg_s", "stamps_ms", "quat_x3", "nan_value", "time_backwards", "key_typo", "sigma_zero", "drop_column", "tracker_shifted", "truncated")


def _damage(root: Path, fault: str, rng: np.random.Generator) -> None:
    def rows(name: str) -> tuple[str, list[list[str]]]:
        lines = (root / name).read_text().splitlines()
        return lines[0], [line.split(",") for line in lines[1:]]

    def write(name: str, header: str, table: list[list[str]]) -> None:
        (root / name).write_text("\n".join([header, *(",".join(r) for r in table)]) + "\n")

    toml = root / "session.toml"
    if fault == "gyro_deg_s":
        header, table = rows("gyro.csv")
        write("gyro.csv", header, [[r[0], *(repr(float(v) * 57.3) for v in r[1:])] for r in table])
    elif fault == "stamps_ms":
        for name in ("gyro.csv", "tracker.csv"):
            header, table = rows(name)
            write(name, header, [[repr(float(r[0]) * 1000.0), *r[1:]] for r in table])
    elif fault == "quat_x3":
        header, table = rows("tracker.csv")
        write("tracker.csv", header, [[r[0], *(repr(float(v) * 3.0) for v in r[1:])] for r in table])
    elif fault == "nan_value":
        header, table = rows("gyro.csv")
        table[int(rng.integers(len(table)))][1] = "nan"
        write("gyro.csv", header, table)
    elif fault == "time_backwards":
        header, table = rows("gyro.csv")
        i = int(rng.integers(1, len(table)))
        table[i][0] = repr(float(table[i - 1][0]) - 0.5)
        write("gyro.csv", header, table)
    elif fault == "key_typo":
        toml.write_text(toml.read_text().replace("noise_sigma_deg", "noise_sigma_degs"))
    elif fault == "sigma_zero":
        toml.write_text(toml.read_text().replace("noise_sigma_rad_s = 0.015", "noise_sigma_rad_s = 0"))
    elif fault == "drop_column":
        header, table = rows("tracker.csv")
        write("tracker.csv", ",".join(header.split(",")[:-1]), [r[:-1] for r in table])
    elif fault == "tracker_shifted":
        header, table = rows("tracker.csv")
        write("tracker.csv", header, [[repr(float(r[0]) + 1000.0), *r[1:]] for r in table])
    elif fault == "truncated":
        text = (root / "gyro.csv").read_text()
        (root / "gyro.csv").write_text(text[: int(len(text) * 0.7)])


@pytest.fixture(scope="module")
def pristine(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fuzz") / "ok"
    assert main(["simulate", "head", "--seed", "1", "--duration", "2", "--out", str(root)]) == 0
    return root


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(faults=st.lists(st.sampled_from(FAULTS), min_size=1, max_size=3, unique=True), seed=st.integers(0, 1000),
       solver=st.sampled_from(["online", "batch", "ekf"]))
def test_damaged_sessions_are_a_clear_error_or_a_result(pristine: Path, tmp_path_factory: pytest.TempPathFactory, faults: list[str], seed: int,
                                                         solver: str, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path_factory.mktemp("case") / "s"
    shutil.copytree(pristine, root)
    rng = np.random.default_rng(seed)
    for fault in faults:
        _damage(root, fault, rng)
    code = main(["run", str(root), "--solver", solver, "--json"])
    err = capsys.readouterr().err
    assert code in (0, 2), (faults, solver, err)
    assert "Traceback" not in err and "internal error" not in err, (faults, err)
    if code == 2:
        assert err.startswith("fusegraph run: error:") and err.count("\n") == 1, err
    else:  # the loader saw nothing wrong: only faults it cannot see may pass (none of these can)
        pytest.fail(f"{faults} passed as a valid session")


GENERIC_FAULTS = ("nan_value", "time_backwards", "truncated", "drop_block", "scale_57", "duplicate_row", "swap_columns", "empty_stream",
                  "extra_stream", "key_typo")
SYSTEMS = {"head": "online", "attitude9": "online", "gaze": "online", "bicycle": "online", "walking": "online", "ultrasonic": "online"}


@pytest.fixture(scope="module")
def every_system(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = {}
    for system in SYSTEMS:
        root = tmp_path_factory.mktemp("fuzz_all") / system
        duration = {"walking": "20"}.get(system, "10")  # the shortest each simulator makes
        assert main(["simulate", system, "--seed", "2", "--duration", duration, "--out", str(root)]) == 0
        out[system] = root
    return out


def _damage_largest(root: Path, fault: str, rng: np.random.Generator) -> None:
    """A fault in the session's largest stream file (never the truth): what a recording of any system can suffer."""
    path = max((p for p in root.glob("*.csv") if p.name != "truth.csv"), key=lambda p: p.stat().st_size)
    lines = path.read_text().splitlines()
    header, table = lines[0], [line.split(",") for line in lines[1:]]
    if fault == "nan_value":
        table[int(rng.integers(len(table)))][1] = "nan"
    elif fault == "time_backwards":
        i = int(rng.integers(1, len(table)))
        table[i][0] = repr(float(table[i - 1][0]) - 0.5)
    elif fault == "truncated":
        text = "\n".join(lines)
        path.write_text(text[: int(len(text) * 0.7)])
        return
    elif fault == "drop_block":  # a dropout: a fifth of the rows gone from the middle
        n = len(table)
        del table[int(0.4 * n) : int(0.6 * n)]
    elif fault == "scale_57":
        table = [[r[0], *(repr(float(v) * 57.3) if v not in ("", "nan") else v for v in r[1:])] for r in table]
    elif fault == "duplicate_row":
        i = int(rng.integers(len(table)))
        table.insert(i, list(table[i]))
    elif fault == "swap_columns":  # the first two value columns in each other's place
        table = [[r[0], r[2], r[1], *r[3:]] if len(r) > 2 else r for r in table]
    elif fault == "empty_stream":
        table = []
    elif fault == "extra_stream":  # a file and a stream of a kind nobody declared
        (root / "extra.csv").write_text("t,a\n0.0,1.0\n1.0,2.0\n")
        toml = root / "session.toml"
        toml.write_text(toml.read_text() + '\n[streams.extra]\nkind = "thermometer"\nfile = "extra.csv"\n')
        return
    elif fault == "key_typo":  # a misspelled key in the stream's entry
        toml = root / "session.toml"
        text = toml.read_text()
        toml.write_text(text.replace(f'file = "{path.name}"', f'fiel = "{path.name}"', 1))
        return
    path.write_text("\n".join([header, *(",".join(r) for r in table)]) + "\n")


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(system=st.sampled_from(sorted(SYSTEMS)), fault=st.sampled_from(GENERIC_FAULTS), seed=st.integers(0, 1000))
def test_every_system_gives_a_clear_error_or_a_result_on_a_damaged_recording(every_system: dict[str, Path], tmp_path_factory: pytest.TempPathFactory,
                                                                             system: str, fault: str, seed: int, capsys: pytest.CaptureFixture[str]) -> None:
    """Any system, any of these faults: exit 0 (a dropout is bridged and said; a scaled stream or swapped columns a
    loader cannot always tell) or exit 2 with a one-line error naming the file or stream, never a traceback or an
    internal error; faults the loader can see are an error or a one-line warning."""
    root = tmp_path_factory.mktemp("case_all") / system
    shutil.copytree(every_system[system], root)
    _damage_largest(root, fault, np.random.default_rng(seed))
    code = main(["run", str(root), "--solver", SYSTEMS[system], "--json", "--out", str(tmp_path_factory.mktemp("out"))])
    err = capsys.readouterr().err
    assert code in (0, 2), (system, fault, err)
    assert "Traceback" not in err and "internal error" not in err, (system, fault, err)
    lines = err.strip().splitlines()
    assert all(line.startswith(("warning: ", "fusegraph run: error: ")) for line in lines), err  # one line each
    if code == 2:
        assert lines[-1].startswith("fusegraph run: error:") and (".csv" in lines[-1] or "session.toml" in lines[-1]), err
    if fault in ("nan_value", "time_backwards", "truncated", "empty_stream", "extra_stream", "key_typo"):
        assert code == 2, (system, fault, "a fault the loader sees passed")
    # a repeated range row is two transmitters at one range (LIAS UWB has 3,908 such at its 1 cm resolution): not a fault
    if (fault == "drop_block" or (fault == "duplicate_row" and system != "ultrasonic")) and code == 0:
        assert any(line.startswith("warning: ") for line in lines), (system, fault, "passed unsaid")
