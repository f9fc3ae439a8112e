"""Estimate: what every solver returns — attitude at given times with covariance — and its CSV form."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from .geometry import FloatArray, euler_zyx_from_quat
from .session import KIND_COLUMNS, SessionError, read_stream_csv

COV_COLUMNS = ("cov_xx", "cov_xy", "cov_xz", "cov_yy", "cov_yz", "cov_zz")
_UPPER = (np.array([0, 0, 0, 1, 1, 2]), np.array([0, 1, 2, 1, 2, 2]))


@dataclass
class Estimate:
    """A time series of attitudes world_R_body from one method.

    Covariances are of the right (body-frame) perturbation ``world_R_body * Exp(delta)``, rad^2,
    gtsam's convention; NaN rows where the method had no estimate yet.
    """

    method: str
    """Name of the method that produced it (``isam2``, ``batch``, ``method2``...)."""
    t: FloatArray
    """Times of the estimates, seconds, shape (N,)."""
    quat_wxyz: FloatArray
    """Attitude quaternions, shape (N, 4)."""
    cov: FloatArray | None = None
    """Attitude covariances (N, 3, 3) in rad^2, or None when the method has none."""
    runtime_s: float = float("nan")
    """Wall time the method spent producing this estimate, seconds."""
    extras: dict[str, Any] = field(default_factory=dict)
    """Method-specific results (estimated bias, calibration, diagnostics)."""

    @property
    def euler_zyx(self) -> FloatArray:
        """(azimuth, elevation, roll) in rad."""
        return euler_zyx_from_quat(self.quat_wxyz)

    def save_csv(self, path: str | Path) -> Path:
        """CSV with t, qw..qz, azimuth/elevation/roll in degrees and the 6 covariance entries."""
        return save_csv_pieces([self], path)

    def _write_rows(self, handle: Any, header: bool) -> None:
        euler_deg = np.rad2deg(self.euler_zyx)
        cov = np.full((len(self.t), 6), np.nan) if self.cov is None else self.cov[:, _UPPER[0], _UPPER[1]]
        columns = ("t", *KIND_COLUMNS["attitude"], "azimuth_deg", "elevation_deg", "roll_deg", *COV_COLUMNS)
        data = np.column_stack([self.t, self.quat_wxyz, euler_deg, cov])
        np.savetxt(handle, data, delimiter=",", header=",".join(columns) if header else "", comments="", fmt="%.10g")

    @classmethod
    def load_csv(cls, path: str | Path, method: str = "") -> Estimate:
        """Read an estimate CSV written by ``save_csv`` (covariance columns optional)."""
        path = Path(path)
        t, quat = read_stream_csv(path, KIND_COLUMNS["attitude"], allow_nan=True)
        cov = None
        header = path.read_text().splitlines()[0].split(",")
        if all(c in header for c in COV_COLUMNS):
            _, upper = read_stream_csv(path, COV_COLUMNS, allow_nan=True)
            if not np.all(np.isnan(upper)):
                cov = np.empty((len(t), 3, 3))
                cov[:, _UPPER[0], _UPPER[1]] = upper
                cov[:, _UPPER[1], _UPPER[0]] = upper
        if len(t) == 0:
            raise SessionError(f"{path}: no rows")
        return cls(method or path.stem, t, quat, cov)


R = TypeVar("R", "Estimate", "PointEstimate")
"""An attitude or a point estimate (``save_csv_pieces`` writes either)."""


def save_csv_pieces(pieces: Iterable[R], path: str | Path, each: Callable[[R], None] | None = None) -> Path:
    """Consecutive pieces of one estimate (a windowed smoother's, as they come) written as one ``save_csv`` file, each
    piece appended and let go; ``each(piece)`` after each is written."""
    path = Path(path)
    with path.open("w") as handle:
        for n, piece in enumerate(pieces):
            piece._write_rows(handle, header=n == 0)
            if each is not None:
                each(piece)
    return path


@dataclass
class PointEstimate:
    """A time series of K points from one method: a gaze point on a wall (K = 1, X and Z), a walker's
    position (K = 1, x y z), every ultrasonic transmitter (K = N, x y z each). NaN where none.

    The position counterpart of ``Estimate`` (evo's PosePath3D beside its PoseTrajectory3D)."""

    method: str
    """Name of the method that produced it (``online``, ``batch``, ``ekf``...)."""
    t: FloatArray
    """Times, seconds, shape (N,)."""
    points: FloatArray
    """Points, shape (N, K, D) in metres."""
    axes: tuple[str, ...] = ("x", "y", "z")
    """Names of the D coordinates (``X_m``, ``Z_m`` for a wall point; ``x``, ``y``, ``z`` for positions)."""
    runtime_s: float = float("nan")
    """Wall time the method spent, seconds."""
    extras: dict[str, Any] = field(default_factory=dict)
    """Method-specific results (labels, per-epoch times, diagnostics)."""

    @property
    def columns(self) -> tuple[str, ...]:
        """CSV columns after ``t``: the axes, suffixed with the point index when there are several."""
        k = self.points.shape[1]
        return self.axes if k == 1 else tuple(f"{a}{i}" for i in range(k) for a in self.axes)

    def save_csv(self, path: str | Path) -> Path:
        """CSV with ``t`` and every point's coordinates."""
        return save_csv_pieces([self], path)

    def _write_rows(self, handle: Any, header: bool) -> None:
        data = np.column_stack([self.t, self.points.reshape(len(self.t), -1)])
        np.savetxt(handle, data, delimiter=",", header=",".join(("t", *self.columns)) if header else "", comments="", fmt="%.10g")


Result = Estimate | PointEstimate
"""What any method of any system returns."""
