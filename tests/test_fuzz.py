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
