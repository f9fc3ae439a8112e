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

from pathlib import Path

import numpy as np

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


def trial_paths(directory: str | Path = DEFAULT_DIR) -> list[Path]:
    """Every ``*.mat`` trial in a directory, sorted by name."""
    directory = Path(directory)
    if not directory.is_dir():
        raise SessionError(f"{directory}: BROAD directory not found")
    return sorted(directory.glob("*.mat"))
