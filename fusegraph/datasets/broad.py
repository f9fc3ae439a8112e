"""BROAD benchmark trials (Laidig et al., Data 2021) as Sessions, and the benchmark's own error metric.

A trial file ``NN_<name>.mat`` holds gyro (rad/s), accelerometer (m/s^2) and magnetometer (uT)
samples at ~285.7 Hz, already synchronised and in the sensor frame, the optical ground truth
``opt_quat`` (w, x, y, z; sensor-to-earth, earth frame ENU; NaN where the markers were occluded)
and a ``movement`` mask. The session has streams ``gyro``, ``accel``, ``mag`` and ``movement``
(kind ``flag``) and the truth; system ``attitude9``.

Metric (the benchmark's): q_err = q_est * q_true^-1 in the earth frame; total = 2 acos(|w|),
heading = 2 atan(|z / w|), inclination = 2 acos(sqrt(w^2 + z^2)); RMSE in degrees over the samples
with ``movement`` set and a finite truth. No alignment of any kind.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import FloatArray, quat_conjugate, quat_multiply, quat_normalize
from ..session import KIND_COLUMNS, Session, SessionError, Stream

#: Where the recordings live beside the repository (tests skip when it is absent).
DEFAULT_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "broad"


def load_broad(path: str | Path) -> Session:
    """One BROAD trial as a Session (system ``attitude9``)."""
    import scipy.io

    path = Path(path)
    if not path.is_file():
        raise SessionError(f"{path}: BROAD trial not found")
    try:
        data = scipy.io.loadmat(path, squeeze_me=True)
    except (ValueError, OSError, NotImplementedError) as exc:
        raise SessionError(f"{path}: not a readable MATLAB v5 file ({exc})") from None
    missing = [k for k in ("imu_gyr", "imu_acc", "imu_mag", "opt_quat", "movement", "sampling_rate") if k not in data]
    if missing:
        raise SessionError(f"{path}: keys {', '.join(missing)} missing (have: {', '.join(k for k in data if not k.startswith('__'))})")
    rate = float(data["sampling_rate"])
    n = int(np.asarray(data["imu_gyr"]).shape[0])
    t = np.arange(n) / rate
    for key in ("imu_gyr", "imu_acc", "imu_mag"):
        bad = np.nonzero(~np.all(np.isfinite(data[key]), axis=1))[0]
        if bad.size:
            raise SessionError(f"{path}: {key} row {bad[0]} is not finite ({bad.size} such rows)")
    meta = {"rate_hz": rate, "frame": "sensor"}
    streams = {
        "gyro": Stream("gyro", "gyro", t, np.asarray(data["imu_gyr"], dtype=float), KIND_COLUMNS["gyro"], 0.0, dict(meta)),
        "accel": Stream("accel", "accel", t, np.asarray(data["imu_acc"], dtype=float), KIND_COLUMNS["accel"], 0.0, dict(meta)),
        "mag": Stream("mag", "mag", t, np.asarray(data["imu_mag"], dtype=float), KIND_COLUMNS["mag"], 0.0, {**meta, "unit": "uT"}),
        "movement": Stream("movement", "flag", t, np.asarray(data["movement"], dtype=float)[:, None], KIND_COLUMNS["flag"], 0.0, {}),
    }
    truth = Stream("truth", "attitude", t, np.asarray(data["opt_quat"], dtype=float), KIND_COLUMNS["attitude"], 0.0,
                   {"frame": "earth_R_sensor", "world_frame": "ENU", "source": "optical motion capture"})
    session_meta = {"session": {"system": "attitude9", "dataset": "BROAD", "trial": path.stem, "world_frame": "ENU"}}
    return Session("attitude9", streams, truth, session_meta, path.parent)


@dataclass(frozen=True)
class BroadErrors:
    """The benchmark's RMSE, degrees."""

    total: float
    heading: float
    inclination: float
    samples: int
    """Samples scored (movement set, truth finite)."""
    failed: int = 0
    """Of those, samples where the estimate was not finite (scored as 180 deg)."""


def broad_errors(estimate_quat_wxyz: FloatArray, truth_quat_wxyz: FloatArray, movement: FloatArray) -> BroadErrors:
    """Total, heading and inclination RMSE (deg) as the benchmark defines them.

    Samples are those in movement with a finite truth. A sample where the ESTIMATE is not finite is not
    dropped (a method must not escape its hard samples): it is scored as failing, 180 deg in all three.
    """
    scored = (np.asarray(movement) > 0) & np.all(np.isfinite(truth_quat_wxyz), axis=1)
    if not scored.any():
        raise ValueError("no sample to score (no movement with a finite truth)")
    estimate = np.asarray(estimate_quat_wxyz, dtype=float)[scored]
    failed = ~np.all(np.isfinite(estimate), axis=1) | (np.linalg.norm(np.nan_to_num(estimate), axis=1) < 1e-9)
    estimate = np.where(failed[:, None], np.array([1.0, 0.0, 0.0, 0.0]), estimate)
    q_err = quat_multiply(quat_normalize(estimate), quat_conjugate(quat_normalize(truth_quat_wxyz[scored])))
    w = np.clip(np.abs(q_err[:, 0]), 0.0, 1.0)
    z = q_err[:, 3]
    total = np.where(failed, np.pi, 2.0 * np.arccos(w))
    heading = np.where(failed, np.pi, 2.0 * np.arctan(np.abs(z) / np.maximum(w, 1e-12)))
    inclination = np.where(failed, np.pi, 2.0 * np.arccos(np.clip(np.sqrt(w**2 + z**2), 0.0, 1.0)))

    def rmse(x: FloatArray) -> float:
        return float(np.rad2deg(np.sqrt(np.mean(x**2))))

    return BroadErrors(rmse(total), rmse(heading), rmse(inclination), int(scored.sum()), int(failed.sum()))


def trial_paths(directory: str | Path = DEFAULT_DIR) -> list[Path]:
    """Every ``*.mat`` trial in a directory, sorted by name."""
    directory = Path(directory)
    if not directory.is_dir():
        raise SessionError(f"{directory}: BROAD directory not found")
    return sorted(directory.glob("*.mat"))
