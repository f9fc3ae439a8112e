"""A Pupil Labs recording (a Pupil Cloud export of a Pupil Invisible or a Neon: ``imu.csv``, ``gaze.csv``, ``blinks.csv``)
as a gaze Session.

Which device made it (``pupil_device``): ``--device`` when told; else the export's ``info.json`` (a Neon's names its
``module_serial_number``, a Pupil Invisible's its ``glasses_serial_number``); else ``imu.csv``'s quaternion columns
(filled: a Neon, whose IMU has a magnetometer and whose export carries its fused attitude; empty: a Pupil Invisible).
The session says which and why (``[session] device``, ``device_from``). The two differ in the IMU's axes, the camera and
the attitude the export carries:

=================  =====================================  ==============================================
                   Pupil Invisible                        Neon
=================  =====================================  ==============================================
IMU axes           x right, y down, z forward (right       x right, y forward, z up (the module's top bar)
                   temple)
scene camera       along the IMU's z (left temple; no      the IMU rotated by -102 deg about its x: looking
                   calibration between them in the         12 deg below the IMU's forward (Pupil Labs' IMU
                   export)                                 documentation: a fixed offset)
camera, datasheet  1088 x 1080 px, 82 x 82 deg             1600 x 1200 px, 103 x 77 deg
device attitude    roll and pitch only (no heading):       ``quaternion w/x/y/z``: the IMU in the world (its
                   not imported                            rotation from IMU to world axes), imported as
                                                           stream ``device_attitude`` (kind ``attitude``, the
                                                           head in the world); read by no solver, scored as
                                                           the bench's ``device`` row
=================  =====================================  ==============================================

fusegraph's head frame is the scene camera's, in fusegraph axes (x forward, y left, z up): gyro and accelerometer are
rotated into it (``PupilDevice.head_from_imu``), so the gaze rays and the IMU share one frame.

What becomes of each file (columns found by their header names, any order; ``../shared/data/gaze_pupil_invisible``):

* ``imu.csv``: ``timestamp [ns]`` (the phone's clock, as the gaze's), ``gyro x/y/z [deg/s]`` (converted to rad/s),
  ``acceleration x/y/z [g]`` (times 9.80665 to m/s^2), in the device's IMU axes (above). No magnetometer readings are
  exported: the session declares ``use_mag = false``. In both files a row whose timestamp repeats or goes back is
  dropped and said (``MAX_REPEATED_FRACTION`` of them at most; more is an error).
* ``gaze.csv``: per gaze sample the ray's ``azimuth [deg]`` (to the right) and ``elevation [deg]`` (up) in the scene
  camera, which the export computed from ``gaze x/y [px]`` with the camera's own intrinsics and lens distortion. The
  ray is projected into a distortion-free pinhole camera (stream ``gaze``, kind ``pixel``: u right, v up from the
  centre, ``u = f tan(az)``, ``v = f tan(el) / cos(az)``) whose focal length follows from the datasheet's horizontal
  field of view (Pupil Invisible: 544 / tan 41 deg = 626 px; Neon: 800 / tan 51.5 deg = 637 px): the pinhole the gaze
  system models is then exact.
  An export without the azimuth and elevation columns (older Pupil Cloud exports) gives its rays from ``gaze x/y [px]``:
  through the camera's own intrinsics and distortion (OpenCV's model) when the folder holds the export's
  ``scene_camera.json``, else through the datasheet's pinhole centred on the image, said in a warning (a few degrees off
  towards the edges, the same in every method, so a fixation's spread barely changes). Rows inside a blink (``blink id``) or with ``worn`` = 0 carry no gaze:
  dropped and counted (``[session] gaze_untracked``).
* ``fixation id`` (Pupil Cloud's own fixation detector, which reads the gaze) -> stream ``fixation`` (kind ``flag``,
  0 outside a fixation): the fixations that score every method (JSON ``fixation_source: "device"``). ``worn``,
  ``fixation id`` and ``blink id`` may be missing (an export without the cloud's detectors): every sample is then taken
  as worn and outside a blink, and without fixation ids the bench scores fixations of the eye-in-head speed.
* ``fixations.csv`` and ``blinks.csv`` (``<kind> id``, ``start timestamp [ns]``, ``end timestamp [ns]``): where the gaze
  rows lack their ``fixation id`` or ``blink id`` column (exports differ), each gaze sample takes the id of the interval
  it falls in (start included, end not: the end is the first sample after the event), so the device's fixations still
  score and blinks still carry no gaze; where the rows have the column, the row's own id is used, the file not read.

No ground truth: ``bench gaze-recorded`` scores the dispersion of the world gaze ray in the device's fixations.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..session import KIND_COLUMNS, Session, SessionError, Stream

#: Where the recording lives beside the repository (tests skip when it is absent).
DEFAULT_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "gaze_pupil_invisible"

GAZE_SIGMA_DEG = 1.0
"""Gaze noise declared to the estimators, degrees: the figure the Tobii import declares (its 15 px at 880 px)."""
TARGET_DEPTH_M = 2.0
"""Depth at which each fixation point is held (no wall; only the direction matters without head translation)."""
STANDARD_GRAVITY_M_S2 = 9.80665

#: Scene camera axes (OpenCV: x right, y down, z forward) -> fusegraph head axes (x forward, y left, z up)
HEAD_FROM_CAMERA = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def _about_x(angle_deg: float) -> np.ndarray:
    c, s = np.cos(np.deg2rad(angle_deg)), np.sin(np.deg2rad(angle_deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class PupilDevice:
    """A Pupil Labs eye tracker as its export reads (the table in the module docstring)."""

    name: str
    """``Pupil Invisible`` or ``Neon``."""
    key: str
    """``invisible`` or ``neon`` (``--device``)."""
    head_from_imu: np.ndarray
    """3 x 3 rotation: a vector in the IMU's axes -> the same vector in the head frame (the scene camera's, x forward,
    y left, z up)."""
    width_px: int
    """Scene camera image width, pixels (datasheet)."""
    height_px: int
    """Scene camera image height, pixels (datasheet)."""
    field_of_view_deg: float
    """Scene camera horizontal field of view, degrees (datasheet)."""

    @property
    def focal_px(self) -> float:
        """Focal length of the distortion-free pinhole the rays are projected into, pixels."""
        return (self.width_px / 2) / float(np.tan(np.deg2rad(self.field_of_view_deg / 2)))

    @property
    def pixel_sigma(self) -> float:
        """``GAZE_SIGMA_DEG`` in this pinhole's pixels at the image centre."""
        return self.focal_px * float(np.tan(np.deg2rad(GAZE_SIGMA_DEG)))


INVISIBLE = PupilDevice("Pupil Invisible", "invisible", HEAD_FROM_CAMERA, 1088, 1080, 82.0)
"""Its IMU (x right, y down, z forward) shares the camera's axes: the glasses hold both, the export has no calibration
between them, and the camera is taken as looking along the IMU's z."""
NEON = PupilDevice("Neon", "neon", HEAD_FROM_CAMERA @ _about_x(-102.0).T, 1600, 1200, 103.0)
"""Its IMU (x right, y forward, z up) is the camera rotated by -102 deg about x (scene -> IMU ``R_x(-102 deg)``, Pupil
Labs' IMU documentation for Neon)."""
DEVICES = {device.key: device for device in (INVISIBLE, NEON)}
QUATERNION_COLUMNS = ("quaternion w", "quaternion x", "quaternion y", "quaternion z")
"""A Neon export's IMU attitude (IMU -> world), scalar first."""


def pupil_device(directory: Path, imu: dict[str, np.ndarray], told: str | None = None) -> tuple[PupilDevice, str]:
    """Which device made the export, and how that was decided: ``told`` (``invisible``/``neon``) if given; else the
    export's ``info.json``; else whether ``imu.csv``'s quaternion columns hold numbers (see the module docstring)."""
    import json

    if told is not None:
        if told not in DEVICES:
            raise SessionError(f"device {told!r}: not a Pupil Labs device fusegraph reads ({', '.join(DEVICES)})")
        return DEVICES[told], "told"
    info = directory / "info.json"
    if info.is_file():
        try:
            fields = json.loads(info.read_text())
        except ValueError as err:
            raise SessionError(f"{info}: not JSON ({err}); pass --device invisible|neon to read the export without it") from None
        if isinstance(fields, dict) and "module_serial_number" in fields:
            return NEON, f"{info.name}: module_serial_number"
        if isinstance(fields, dict) and "glasses_serial_number" in fields:
            return INVISIBLE, f"{info.name}: glasses_serial_number"
    if all(c in imu for c in QUATERNION_COLUMNS) and np.isfinite(imu["quaternion w"]).mean() > 0.5:
        return NEON, "imu.csv: quaternion columns filled"
    return INVISIBLE, "imu.csv: no quaternion"

IMU_COLUMNS = ("timestamp [ns]", "gyro x [deg/s]", "gyro y [deg/s]", "gyro z [deg/s]",
               "acceleration x [g]", "acceleration y [g]", "acceleration z [g]")
GAZE_COLUMNS = ("timestamp [ns]",)
GAZE_RAYS = ("azimuth [deg]", "elevation [deg]")
"""The export's own rays (preferred); else ``GAZE_PIXELS``."""
GAZE_PIXELS = ("gaze x [px]", "gaze y [px]")
GAZE_OPTIONAL = ("worn", "fixation id", "blink id")


def _table(path: Path, needed: tuple[str, ...], optional: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """The named columns of a CSV export as float arrays (empty cells NaN), the ``optional`` ones where the header has
    them; an error names the file and what is missing."""
    if not path.is_file():
        raise SessionError(f"{path}: not found (a Pupil Cloud export folder of a Pupil Invisible or a Neon has imu.csv and gaze.csv)")
    with path.open(newline="", encoding="utf-8") as handle:
        reader = csv.reader(handle)
        header = next(reader, None)
        if header is None:
            raise SessionError(f"{path}: empty file")
        missing = [c for c in needed if c not in header]
        if missing:
            raise SessionError(f"{path}: no column {', '.join(repr(c) for c in missing)} (found {', '.join(header)}); "
                               "a Pupil Cloud export of a Pupil Invisible or a Neon recording has them")
        names = [*needed, *(c for c in optional if c in header)]
        index = [header.index(c) for c in names]
        rows = []
        for number, row in enumerate(reader, start=2):
            try:
                rows.append([float(row[i]) if row[i].strip() else np.nan for i in index])
            except (ValueError, IndexError):
                raise SessionError(f"{path}: line {number} is not a row of numbers in {', '.join(names)}") from None
    if not rows:
        raise SessionError(f"{path}: no rows")
    values = np.asarray(rows)
    return {c: values[:, j] for j, c in enumerate(names)}


def _interval_ids(path: Path, id_column: str, t_ns: np.ndarray) -> np.ndarray:
    """Per sample (``t_ns``), the id of the interval of a Pupil Cloud event file (``fixations.csv``, ``blinks.csv``) it falls
    in, 0 outside every interval. An interval holds its start and not its end (the end is the first sample after it: so
    the shared export's blink ids on the gaze rows read)."""
    events = _table(path, (id_column, "start timestamp [ns]", "end timestamp [ns]"))
    start, end, ids = events["start timestamp [ns]"], events["end timestamp [ns]"], events[id_column]
    bad = ~(np.isfinite(start) & np.isfinite(end) & (end > start))
    if bad.any():
        raise SessionError(f"{path}: line {int(np.argmax(bad)) + 2}: an interval without a start and an end after it")
    order = np.argsort(start, kind="stable")  # the detector's events do not overlap: each sample looks up the last that started
    start, end, ids = start[order], end[order], ids[order]
    last = np.searchsorted(start, t_ns, side="right") - 1
    inside = (last >= 0) & (t_ns < end[np.maximum(last, 0)])
    return np.where(inside, ids[np.maximum(last, 0)], 0.0)


def undistorted_rays(x_px: np.ndarray, y_px: np.ndarray, camera_matrix: np.ndarray, dist_coefs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scene-camera pixels (x right, y down) as (azimuth to the right, elevation up) in degrees, through the camera's
    intrinsics and OpenCV's distortion model (k1, k2, p1, p2[, k3[, k4, k5, k6]]), inverted by fixed-point iteration."""
    k = np.zeros(8)
    k[: min(8, len(dist_coefs))] = np.asarray(dist_coefs, dtype=float).ravel()[:8]
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    xd = (x_px - camera_matrix[0, 2]) / camera_matrix[0, 0]
    yd = (y_px - camera_matrix[1, 2]) / camera_matrix[1, 1]
    x, y = xd.copy(), yd.copy()
    for _ in range(50):  # converges to 1e-12 within ~20 iterations over a wide-angle lens's field
        r2 = x * x + y * y
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        x = (xd - (2 * p1 * x * y + p2 * (r2 + 2 * x * x))) / radial
        y = (yd - (p1 * (r2 + 2 * y * y) + 2 * p2 * x * y)) / radial
    return np.rad2deg(np.arctan(x)), np.rad2deg(np.arctan2(-y, np.sqrt(1 + x * x)))


def _rays_from_pixels(directory: Path, gaze: dict[str, np.ndarray], device: PupilDevice) -> tuple[np.ndarray, np.ndarray]:
    """(azimuth, elevation) in degrees from ``gaze x/y [px]``: the export's ``scene_camera.json`` if the folder has it,
    else the datasheet's pinhole centred on the image (with a warning)."""
    import json
    import warnings

    x, y = gaze["gaze x [px]"], gaze["gaze y [px]"]
    intrinsics = directory / "scene_camera.json"
    if intrinsics.is_file():
        try:
            camera = json.loads(intrinsics.read_text())
            return undistorted_rays(x, y, np.asarray(camera["camera_matrix"], dtype=float), np.asarray(camera["dist_coefs"], dtype=float))
        except (ValueError, KeyError, IndexError, TypeError) as err:
            raise SessionError(f"{intrinsics}: not a Pupil scene camera file (camera_matrix 3 x 3, dist_coefs): {err}") from None
    f = device.focal_px
    warnings.warn(f"{directory / 'gaze.csv'}: no azimuth/elevation columns and no scene_camera.json: the gaze rays come from the "
                  f"pixels through the {device.name} datasheet's pinhole ({f:.0f} px, centred; no lens distortion), a few degrees off "
                  "towards the image's edges", stacklevel=3)
    return undistorted_rays(x, y, np.array([[f, 0, device.width_px / 2], [0, f, device.height_px / 2], [0, 0, 1]]), np.zeros(5))


MAX_REPEATED_FRACTION = 0.01
"""Rows whose timestamp repeats or goes back that an export may hold and still load (dropped, said); more is an error:
the file is likely two recordings or out of order."""


def _in_time_order(path: Path, table: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The table's rows whose timestamp is later than every row's before it: a row that repeats a stamp or goes back
    (a phone's clock can) is dropped and said in a warning with its count and first row; more than
    ``MAX_REPEATED_FRACTION`` of them is an error."""
    import warnings

    ns = table["timestamp [ns]"]
    if not np.isfinite(ns).all():
        raise SessionError(f"{path}: a row without a timestamp (row {int(np.argmin(np.isfinite(ns))) + 2})")
    keep = np.ones(len(ns), dtype=bool)
    keep[1:] = ns[1:] > np.maximum.accumulate(ns)[:-1]
    dropped = np.nonzero(~keep)[0]
    if not dropped.size:
        return table
    where = f"{dropped.size} rows whose timestamp repeats or goes back, the first at row {dropped[0] + 2}"
    if dropped.size > MAX_REPEATED_FRACTION * len(ns):
        raise SessionError(f"{path}: {where} (over {100 * MAX_REPEATED_FRACTION:g} % of its rows: two recordings in one file, or not "
                           "in time order?)")
    warnings.warn(f"{path}: {where}: dropped", stacklevel=3)
    return {column: values[keep] for column, values in table.items()}


def pinhole_pixels(azimuth_deg: np.ndarray, elevation_deg: np.ndarray, focal_px: float) -> np.ndarray:
    """The gaze rays (azimuth to the right, elevation up) as pixels of a pinhole camera (u right, v up from the centre)."""
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    return focal_px * np.stack([np.tan(az), np.tan(el) / np.cos(az)], axis=1)


def load_pupil(directory: str | Path = DEFAULT_DIR, device: str | None = None) -> Session:
    """The export folder as a gaze Session (see the module docstring); ``device`` (``invisible``/``neon``) overrides
    what the export says of itself."""
    directory = Path(directory)
    imu_path, gaze_path = directory / "imu.csv", directory / "gaze.csv"
    imu = _in_time_order(imu_path, _table(imu_path, IMU_COLUMNS, QUATERNION_COLUMNS))
    made_by, made_by_from = pupil_device(directory, imu, device)
    gaze = _in_time_order(gaze_path, _table(gaze_path, GAZE_COLUMNS, GAZE_RAYS + GAZE_PIXELS + GAZE_OPTIONAL))
    has_rays = all(c in gaze for c in GAZE_RAYS)
    if not has_rays and not all(c in gaze for c in GAZE_PIXELS):
        raise SessionError(f"{gaze_path}: neither {' and '.join(map(repr, GAZE_RAYS))} nor {' and '.join(map(repr, GAZE_PIXELS))} "
                           "columns; a Pupil Cloud export of a Pupil Invisible or a Neon recording has one pair")
    if not has_rays:
        gaze["azimuth [deg]"], gaze["elevation [deg]"] = _rays_from_pixels(directory, gaze, made_by)
    n = len(gaze["timestamp [ns]"])
    for kind in ("fixation", "blink"):  # an export whose gaze rows lack the id column: from the event file, where there is one
        if f"{kind} id" not in gaze and (directory / f"{kind}s.csv").is_file():
            gaze[f"{kind} id"] = _interval_ids(directory / f"{kind}s.csv", f"{kind} id", gaze["timestamp [ns]"])
    worn = gaze.get("worn", np.ones(n))
    blink = gaze.get("blink id", np.zeros(n))
    t0_ns = float(imu["timestamp [ns]"][0])  # the IMU's first sample is t = 0 (stamps of ~1.6e18 ns read as float64 keep 256 ns: far below a sample)
    t = (imu["timestamp [ns]"] - t0_ns) * 1e-9
    gaze_t = (gaze["timestamp [ns]"] - t0_ns) * 1e-9
    gyro = np.stack([imu[c] for c in IMU_COLUMNS[1:4]], axis=1)
    accel = np.stack([imu[c] for c in IMU_COLUMNS[4:7]], axis=1)
    for name, values, path in (("gyro", gyro, imu_path), ("acceleration", accel, imu_path)):
        bad = np.nonzero(~np.isfinite(values).all(axis=1))[0]
        if bad.size:
            raise SessionError(f"{path}: {name} empty or not a number at row {bad[0] + 2}")
    tracked = (worn != 0) & ~(blink > 0) & np.isfinite(gaze["azimuth [deg]"]) & np.isfinite(gaze["elevation [deg]"])
    if not tracked.any():
        raise SessionError(f"{gaze_path}: no gaze sample outside blinks with the glasses worn")
    pixels = pinhole_pixels(gaze["azimuth [deg]"][tracked], gaze["elevation [deg]"][tracked], made_by.focal_px)
    imu_meta = {"rate_hz": 1.0 / float(np.median(np.diff(t))), "frame": "head (the scene camera's: x forward, y left, z up)"}
    head_from_imu = made_by.head_from_imu
    streams = {
        "gyro": Stream("gyro", "gyro", t, np.deg2rad(gyro) @ head_from_imu.T, KIND_COLUMNS["gyro"], 0.0, dict(imu_meta)),
        "accel": Stream("accel", "accel", t.copy(), STANDARD_GRAVITY_M_S2 * accel @ head_from_imu.T, KIND_COLUMNS["accel"], 0.0, dict(imu_meta)),
        "gaze": Stream("gaze", "pixel", gaze_t[tracked], pixels, KIND_COLUMNS["pixel"], 0.0,
                       {"rate_hz": 1.0 / float(np.median(np.diff(gaze_t[tracked]))), "focal_px": made_by.focal_px,
                        "width_px": made_by.width_px, "height_px": made_by.height_px, "pixel_sigma": made_by.pixel_sigma}),
    }
    if made_by is NEON and all(c in imu for c in QUATERNION_COLUMNS):
        streams["device_attitude"] = _device_attitude(imu_path, imu, t, head_from_imu)
    if "fixation id" in gaze:  # the device's detector; without it the bench finds fixations from the eye-in-head speed
        streams["fixation"] = Stream("fixation", "flag", gaze_t[tracked].copy(), np.nan_to_num(gaze["fixation id"][tracked])[:, None],
                                     KIND_COLUMNS["flag"], 0.0,
                                     {"description": "the device's fixation id per gaze sample (Pupil Cloud's detector), 0 outside a fixation"})
    meta = {
        "session": {
            "system": "gaze",
            "dataset": f"Pupil Labs {made_by.name}",
            "device": made_by.key,
            "device_from": made_by_from,
            "target_depth_m": TARGET_DEPTH_M,
            "use_mag": False,
            "gaze_untracked": int((~tracked).sum()),
            "description": "head-worn eye tracker: IMU (no magnetometer), gaze rays in the scene camera, the device's fixations; no ground truth",
        }
    }
    return Session("gaze", streams, None, meta, directory)


def _device_attitude(path: Path, imu: dict[str, np.ndarray], t: np.ndarray, head_from_imu: np.ndarray) -> Stream:
    """The export's own attitude (IMU -> world quaternions, scalar first) as the head's in the world, at the IMU rows
    that hold one (the rest dropped and said); an error where no row does or a quaternion is far from unit norm."""
    import warnings

    import gtsam

    from ..geometry import quat_multiply, quat_wxyz_from_rot3
    from ..session import UNIT_NORM_TOLERANCE

    quat = np.stack([imu[c] for c in QUATERNION_COLUMNS], axis=1)
    held = np.isfinite(quat).all(axis=1)
    if not held.any():
        raise SessionError(f"{path}: the quaternion columns are empty (a Neon export carries its attitude there; pass --device "
                           "invisible if the export is a Pupil Invisible's)")
    if not held.all():
        warnings.warn(f"{path}: {int((~held).sum())} of {held.size} rows carry no quaternion: the device's attitude skips them",
                      stacklevel=3)
    norm = np.linalg.norm(quat[held], axis=1)
    if np.any(np.abs(norm - 1.0) > UNIT_NORM_TOLERANCE):
        row = int(np.flatnonzero(held)[np.argmax(np.abs(norm - 1.0))]) + 2
        raise SessionError(f"{path}: row {row}: quaternion norm {norm.max():.3f}, not a rotation (columns w, x, y, z?)")
    imu_R_head = quat_wxyz_from_rot3(gtsam.Rot3(head_from_imu.T))
    world_R_head = quat_multiply(quat[held] / norm[:, None], imu_R_head)  # head -> IMU -> world
    return Stream("device_attitude", "attitude", t[held].copy(), world_R_head, KIND_COLUMNS["attitude"], 0.0,
                  {"description": "the device's own head attitude (its IMU's fused quaternion through the camera's axes); read by no "
                                  "solver, scored as the bench's device row"})
