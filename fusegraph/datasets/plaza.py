"""The Plaza range + odometry recordings that ship with gtsam (``Plaza1_.mat``, ``Plaza2_.mat``).

A vehicle with wheel odometry (``DR``: t, distance, heading change per interval), range-only radio
beacons (``TD``: t, sender, beacon id, range; ``TL``: beacon id, x, y) and ground truth (``GT``: t,
x, y, heading). Djugash, Hamner, Roth, "Navigating with Ranging Radios: Five Data Sets with Ground
Truth", 2009. Beacons are indexed by id, never by row.

Measured here: ranges read long by about 2.8 m (median against ground truth, spread ~1 m), so a
bias per beacon belongs in the graph; Plaza2's ground-truth heading is reversed (it points against
the direction of travel by pi), so the start heading is taken from ground truth and flipped when
it disagrees with the first metres travelled.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np
import scipy.io
from numpy.typing import NDArray

from ..geometry import FloatArray

RECORDINGS = ("Plaza1", "Plaza2")
WHEEL_ODOMETRY = {"distance_frac": 0.02, "lateral_frac": 0.02, "floor_m": 0.005, "yaw_sigma_deg": 0.1, "yaw_frac": 0.02}
"""What the import declares for the wheel odometry per interval (0.1-0.2 s): 2 % of distance, 0.1 deg heading (the
per-interval odometry of both runs is good to a few mm against the ground truth's increments)."""
BEACON_RANGES = {"sigma_m": 1.0, "bias_sigma_m": 5.0, "kernel_width": 1.5}
"""What the import declares for the radio ranges: 1 m noise, Huber against multipath, a bias per beacon with a 5 m prior."""


@dataclass(frozen=True)
class PlazaRecording:
    """One Plaza run: odometry increments, beacon ranges, beacon positions and ground truth."""

    name: str
    """Recording name, e.g. ``Plaza1``."""
    odometry_t: FloatArray
    """End time of each odometry interval, seconds, shape (N,)."""
    distance_m: FloatArray
    """Distance travelled in each interval, metres, shape (N,)."""
    dyaw_rad: FloatArray
    """Heading change in each interval, radians, shape (N,)."""
    range_t: FloatArray
    """Range times, seconds, shape (M,)."""
    range_beacon: NDArray[np.int64]
    """Beacon id of each range, shape (M,)."""
    range_m: FloatArray
    """Measured ranges, metres, shape (M,)."""
    beacons: dict[int, FloatArray]
    """Beacon id -> world position (x, y), metres."""
    truth_t: FloatArray
    """Ground-truth times, seconds, shape (N + 1,): the start, then each odometry time."""
    truth_xy: FloatArray
    """Ground-truth positions, metres, shape (N + 1, 2)."""
    start_yaw_rad: float
    """Heading at the start, aligned with the direction of travel."""

    @property
    def duration_s(self) -> float:
        return float(self.truth_t[-1] - self.truth_t[0])



def plaza_path(name: str) -> Path:
    """Where gtsam keeps the recording (installed with the gtsam wheel)."""
    if name not in RECORDINGS:
        raise ValueError(f"unknown Plaza recording {name!r}: use one of {', '.join(RECORDINGS)}")
    return Path(gtsam.findExampleDataFile(f"{name}_.mat"))


def load_plaza(name: str) -> PlazaRecording:
    """Read one recording; raises ValueError naming the file and the problem."""
    path = plaza_path(name)
    mat = scipy.io.loadmat(str(path))
    for field in ("DR", "TD", "TL", "GT"):
        if field not in mat:
            raise ValueError(f"{path}: no '{field}' matrix")
    dr, td, tl, gt = (np.asarray(mat[f], dtype=float) for f in ("DR", "TD", "TL", "GT"))
    if len(gt) != len(dr) + 1 or not np.allclose(gt[1:, 0], dr[:, 0]):
        raise ValueError(f"{path}: GT rows do not line up with DR (expected the start plus one row per interval)")
    beacons = {int(row[0]): row[1:3].copy() for row in tl}
    unknown = sorted({int(b) for b in td[:, 2]} - set(beacons))
    if unknown:
        raise ValueError(f"{path}: ranges to beacons {unknown} that TL does not place")
    travelled = np.linalg.norm(gt[:, 1:3] - gt[0, 1:3], axis=1)
    far = int(np.argmax(travelled > 10.0))
    direction = math.atan2(gt[far, 2] - gt[0, 2], gt[far, 1] - gt[0, 1])
    yaw = float(gt[0, 3])
    # a heading that points against the travel is the reversed convention (Plaza2)
    if abs(math.remainder(direction - yaw, 2 * math.pi)) > math.pi / 2:
        yaw = math.remainder(yaw + math.pi, 2 * math.pi)
    return PlazaRecording(
        name=name,
        odometry_t=dr[:, 0].copy(),
        distance_m=dr[:, 1].copy(),
        dyaw_rad=dr[:, 2].copy(),
        range_t=td[:, 0].copy(),
        range_beacon=td[:, 2].astype(int),
        range_m=td[:, 3].copy(),
        beacons=beacons,
        truth_t=gt[:, 0].copy(),
        truth_xy=gt[:, 1:3].copy(),
        start_yaw_rad=yaw,
    )


def beacon_table(rec: PlazaRecording) -> tuple[FloatArray, np.ndarray]:
    """Beacon positions (rows, z = 0) and each range's row: Plaza names beacons by id."""
    ids = sorted(rec.beacons)
    row = {b: i for i, b in enumerate(ids)}
    return np.array([np.append(rec.beacons[b], 0.0) for b in ids]), np.array([row[b] for b in rec.range_beacon])
