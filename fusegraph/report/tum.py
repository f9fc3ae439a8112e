"""TUM trajectory files (``timestamp tx ty tz qx qy qz qw`` per line), the format evo and most SLAM tools read.

Attitude-only systems write zero positions. Reading validates every line and names the file, the
line and the problem, like the session loader.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..geometry import FloatArray, quat_normalize
from ..session import SessionError


def write_tum(path: str | Path, t: FloatArray, quat_wxyz: FloatArray, position_m: FloatArray | None = None, comment: str = "") -> Path:
    """Write a TUM trajectory; rows without an estimate (NaN) are left out, and the comment says how many."""
    path = Path(path)
    quat = np.asarray(quat_wxyz, dtype=float)
    xyz = np.zeros((len(t), 3)) if position_m is None else np.asarray(position_m, dtype=float)
    have = np.all(np.isfinite(quat), axis=1) & np.all(np.isfinite(xyz), axis=1)
    q = quat_normalize(quat[have])
    table = np.column_stack([np.asarray(t)[have], xyz[have], q[:, 1], q[:, 2], q[:, 3], q[:, 0]])
    header = "timestamp tx ty tz qx qy qz qw"
    if comment:
        header = f"{comment}\n{header}"
    skipped = int((~have).sum())
    if skipped:
        header += f"\n{skipped} instants without an estimate (before the first fix) are not written"
    np.savetxt(path, table, fmt="%.9f", header=header, comments="# ")
    return path


def read_tum(path: str | Path) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Times (N,), positions (N, 3) in m and quaternions (N, 4) wxyz from a TUM file."""
    path = Path(path)
    if not path.is_file():
        raise SessionError(f"{path}: file not found")
    rows: list[list[float]] = []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.replace(",", " ").split()
        if len(fields) != 8:
            raise SessionError(f"{path}: line {line_no}: {len(fields)} fields, TUM has 8 (timestamp tx ty tz qx qy qz qw)")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise SessionError(f"{path}: line {line_no}: not a number in {text!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise SessionError(f"{path}: line {line_no}: NaN/inf in {text!r}")
        if rows and values[0] <= rows[-1][0]:
            raise SessionError(f"{path}: line {line_no}: time does not increase (t = {values[0]!r} after {rows[-1][0]!r})")
        if abs(np.linalg.norm(values[4:]) - 1.0) > 1e-3:
            raise SessionError(f"{path}: line {line_no}: quaternion norm {np.linalg.norm(values[4:]):.4f} is not 1")
        rows.append(values)
    if not rows:
        raise SessionError(f"{path}: no poses")
    table = np.asarray(rows)
    quat_wxyz = quat_normalize(np.column_stack([table[:, 7], table[:, 4:7]]))
    return table[:, 0], table[:, 1:4], quat_wxyz
