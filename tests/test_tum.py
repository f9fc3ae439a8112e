"""TUM files: exact round trip, the format evo reads, clear errors for bad lines."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fusegraph import SessionError
from fusegraph.geometry import quat_normalize
from fusegraph.report.tum import read_tum, write_tum


def sample_trajectory(n: int = 50) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    t = 100.0 + np.arange(n) * 0.01
    quat = quat_normalize(rng.normal(size=(n, 4)))
    xyz = rng.normal(size=(n, 3))
    return t, xyz, quat


def test_round_trip(tmp_path: Path) -> None:
    t, xyz, quat = sample_trajectory()
    t_back, xyz_back, quat_back = read_tum(write_tum(tmp_path / "a.tum", t, quat, xyz))
    # written with 9 decimals: nanosecond / nanometre resolution
    np.testing.assert_allclose(t_back, t, atol=1e-9)
    np.testing.assert_allclose(xyz_back, xyz, atol=1e-9)
    np.testing.assert_allclose(quat_back, quat, atol=1e-8)


def test_rows_without_estimate_are_left_out_and_said(tmp_path: Path) -> None:
    t, xyz, quat = sample_trajectory(5)
    quat[:2] = np.nan
    path = write_tum(tmp_path / "b.tum", t, quat)
    assert "2 instants without an estimate" in path.read_text()
    assert len(read_tum(path)[0]) == 3


def test_evo_reads_our_files(tmp_path: Path) -> None:
    file_interface = pytest.importorskip("evo.tools.file_interface")
    t, xyz, quat = sample_trajectory()
    trajectory = file_interface.read_tum_trajectory_file(str(write_tum(tmp_path / "c.tum", t, quat, xyz)))
    np.testing.assert_allclose(trajectory.timestamps, t, atol=1e-9)
    np.testing.assert_allclose(trajectory.positions_xyz, xyz, atol=1e-9)
    np.testing.assert_allclose(trajectory.orientations_quat_wxyz, quat, atol=1e-8)  # evo keeps w first internally


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0 0 0 0 0 0 0\n", r"line 1: 7 fields, TUM has 8"),
        ("0 0 0 0 0 0 0 1\n0 0 0 0 0 0 0 1\n", r"line 2: time does not increase"),
        ("0 0 0 0 0 0 0 2\n", r"line 1: quaternion norm 2.0000 is not 1"),
        ("# only a comment\n", r"no poses"),
        ("0 0 0 x 0 0 0 1\n", r"line 1: not a number"),
    ],
)
def test_bad_files_name_the_line(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.tum"
    path.write_text(text)
    with pytest.raises(SessionError, match=message):
        read_tum(path)
