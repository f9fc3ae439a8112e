"""A head-worn eye tracker's recording (Tobii Pro Glasses 3 export: ``imudata.gz``, ``gazedata.gz``) as a gaze Session.

The export is gzip-compressed JSON lines ``{"type", "timestamp" (s, the glasses' clock), "data"}``
(``../shared/data/gaze_tobii/SOURCE_README.md``). What becomes of each field:

* IMU lines with ``gyroscope`` (DEGREES per second, converted to rad/s) and ``accelerometer`` (m/s^2):
  streams ``gyro`` and ``accel`` at their ~117 Hz. The glasses' head-unit frame is x left, y up,
  z forward; fusegraph's head frame is x forward, y left, z up, so head = (z, x, y) of the glasses
  (a rotation: both frames are right-handed).
* IMU lines with ``magnetometer`` (microtesla, ~10 Hz): stream ``mag`` linearly interpolated onto the
  gyro times (the gaze system takes its IMU sampled together); ``[session] mag_rate_hz`` keeps the
  true rate, and the 9-axis graph uses one heading factor per keyframe, not one per copy.
* gaze lines: ``gaze2d`` (normalised, origin top left, v down) -> stream ``gaze`` (kind ``pixel``)
  in pixels from the image centre, u right, v up, for the 1920 x 1080 scene camera; its focal
  length 880 px follows from the manufacturer's field of view (95 x 63 deg: 960 / tan 47.5 deg =
  880, 540 / tan 31.5 deg = 881). Lines with an empty ``data`` (the eyes not tracked: blinks) carry
  no measurement; their count is kept in ``[session] gaze_untracked``. ``gaze3d`` agrees with the
  pixel rays to a median 1.1 deg (a 0.9 deg camera tilt), so the camera is taken as looking along
  the head's x axis.
* There is no wall: the gaze targets are anywhere in the room, at a median 3 m (``gaze3d``).
  ``[session] target_depth_m = 2`` tells the gaze system to hold each fixation point at that depth
  along its first ray instead of on a wall plane.

No ground truth: ``bench gaze-recorded`` scores what must hold physically (fixations).
"""

from __future__ import annotations

import gzip
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..session import KIND_COLUMNS, Session, SessionError, Stream

#: Where the recording lives beside the repository (tests skip when it is absent).
DEFAULT_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "gaze_tobii"

WIDTH_PX, HEIGHT_PX = 1920, 1080
FOCAL_PX = 880.0
"""Scene camera focal length from the manufacturer's field of view, pixels."""
PIXEL_SIGMA = 15.0
"""Gaze pixel noise declared to the estimators: the tracker's ~0.6 deg accuracy plus fixational
jitter, about 1 deg at 880 px per radian; the same figure for the EKF and the graph."""
TARGET_DEPTH_M = 2.0
"""Depth at which each fixation point is held (a room; only the direction matters without head translation)."""

#: glasses head-unit axes (x left, y up, z forward) -> fusegraph head axes (x forward, y left, z up)
HEAD_FROM_GLASSES = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _lines(path: Path) -> list[tuple[int, dict[str, Any]]]:
    if not path.is_file():
        raise SessionError(f"{path}: not found (a Tobii Pro Glasses 3 export folder has imudata.gz and gazedata.gz)")
    out = []
    try:
        with gzip.open(path, "rt", encoding="utf-8") as handle:
            for number, line in enumerate(handle, start=1):
                if not line.strip():
                    continue
                try:
                    out.append((number, json.loads(line)))
                except json.JSONDecodeError as exc:
                    raise SessionError(f"{path}: line {number} is not JSON ({exc.msg})") from None
    except (OSError, EOFError) as exc:
        raise SessionError(f"{path}: not a readable gzip file ({exc})") from None
    return out


def _vector(path: Path, number: int, data: dict[str, Any], key: str, size: int) -> list[float]:
    value = data.get(key)
    if not isinstance(value, list) or len(value) != size or not all(isinstance(v, (int, float)) for v in value):
        raise SessionError(f"{path}: line {number}: '{key}' must be a list of {size} numbers, got {value!r}")
    return [float(v) for v in value]


def load_tobii(directory: str | Path = DEFAULT_DIR) -> Session:
    """The export folder as a gaze Session (see the module docstring)."""
    directory = Path(directory)
    imu_path, gaze_path = directory / "imudata.gz", directory / "gazedata.gz"
    gyro_t, gyro, accel, mag_t, mag = [], [], [], [], []
    for number, line in _lines(imu_path):
        data = line.get("data") or {}
        if "gyroscope" in data:
            gyro_t.append(float(line["timestamp"]))
            gyro.append(_vector(imu_path, number, data, "gyroscope", 3))
            accel.append(_vector(imu_path, number, data, "accelerometer", 3))
        elif "magnetometer" in data:
            mag_t.append(float(line["timestamp"]))
            mag.append(_vector(imu_path, number, data, "magnetometer", 3))
    if len(gyro_t) < 2 or len(mag_t) < 2:
        raise SessionError(f"{imu_path}: needs gyroscope and magnetometer lines (found {len(gyro_t)} and {len(mag_t)})")
    gaze_t, gaze_uv, untracked = [], [], 0
    for number, line in _lines(gaze_path):
        if line.get("type") != "gaze":
            continue
        data = line.get("data") or {}
        if "gaze2d" not in data:
            untracked += 1
            continue
        gaze_t.append(float(line["timestamp"]))
        gaze_uv.append(_vector(gaze_path, number, data, "gaze2d", 2))
    if not gaze_t:
        raise SessionError(f"{gaze_path}: no tracked gaze sample")
    t = np.asarray(gyro_t)
    for name, times in (("imu", t), ("magnetometer", np.asarray(mag_t)), ("gaze", np.asarray(gaze_t))):
        back = np.nonzero(np.diff(times) <= 0)[0]
        if back.size:
            raise SessionError(
                f"{imu_path if name != 'gaze' else gaze_path}: {name} timestamps not increasing at sample {back[0] + 1} "
                f"({times[back[0]]:.6f} then {times[back[0] + 1]:.6f} s)"
            )
    gyro_head = np.deg2rad(np.asarray(gyro)) @ HEAD_FROM_GLASSES.T  # deg/s -> rad/s, glasses axes -> head axes
    accel_head = np.asarray(accel) @ HEAD_FROM_GLASSES.T
    mag_head = np.asarray(mag) @ HEAD_FROM_GLASSES.T
    mag_on_imu = np.stack([np.interp(t, mag_t, mag_head[:, c]) for c in range(3)], axis=1)
    uv = np.asarray(gaze_uv)
    pixels = np.stack([(uv[:, 0] - 0.5) * WIDTH_PX, (0.5 - uv[:, 1]) * HEIGHT_PX], axis=1)  # from the centre, u right, v up
    rate = 1.0 / float(np.median(np.diff(t)))
    imu_meta = {"rate_hz": rate, "frame": "head (x forward, y left, z up)"}
    streams = {
        "gyro": Stream("gyro", "gyro", t, gyro_head, KIND_COLUMNS["gyro"], 0.0, dict(imu_meta)),
        "accel": Stream("accel", "accel", t.copy(), accel_head, KIND_COLUMNS["accel"], 0.0, dict(imu_meta)),
        "mag": Stream("mag", "mag", t.copy(), mag_on_imu, KIND_COLUMNS["mag"], 0.0, {**imu_meta, "unit": "uT"}),
        "gaze": Stream(
            "gaze",
            "pixel",
            np.asarray(gaze_t),
            pixels,
            KIND_COLUMNS["pixel"],
            0.0,
            {
                "rate_hz": 1.0 / float(np.median(np.diff(gaze_t))),
                "focal_px": FOCAL_PX,
                "width_px": WIDTH_PX,
                "height_px": HEIGHT_PX,
                "pixel_sigma": PIXEL_SIGMA,
            },
        ),
    }
    meta = {
        "session": {
            "system": "gaze",
            "dataset": "Tobii Pro Glasses 3",
            "target_depth_m": TARGET_DEPTH_M,
            "gaze_untracked": untracked,
            "mag_rate_hz": 1.0 / float(np.median(np.diff(mag_t))),
            "description": "head-worn eye tracker: IMU, magnetometer, gaze in the scene camera; no ground truth",
        }
    }
    return Session("gaze", streams, None, meta, directory)
