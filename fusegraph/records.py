"""Typed views of a session, per system: what the gaze, cyclist, walking and ultrasonic pipelines read.

A simulator fills one with its truth, a ``from_session`` reader fills one from any Session (a recording has
NaN where it has no truth). They live below ``systems/`` and ``scenarios/`` so that both can use them and
neither imports the other.

Ultrasonic/UWB sessions on disk: ``ranges.csv`` (kind ``ranges``) has one row per distance heard: ``t`` (the
epoch's emission time, shared by its rows), ``receiver`` (index into ``receivers_m``), ``range_m``; an optional
``truth_label`` column (scoring only: the transmitter index, ``-1 - n`` for an echo of n) is never read by an
estimator. ``truth.csv`` (kind ``tag_position``): ``t, tag, x, y, z`` per transmitter and epoch.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from .factors.attitude import AttitudeTrack
from .factors.gaze import SceneCamera
from .factors.ranging import BeaconRanges
from .geometry import FloatArray
from .session import KIND_COLUMNS, Session, SessionError, Stream, read_stream_csv


@dataclass(frozen=True)
class GazeScenarioConfig:
    """Everything that defines a simulated gaze session."""

    duration_s: float = 40.0
    """Length, seconds."""
    switch_s: float = 25.0
    """When the subject looks from the first mark to the second, seconds."""
    wall_m: float = 1.0
    """Distance to the wall, metres."""
    target_depth_m: float | None = None
    """None: the gaze targets lie on the wall x = ``wall_m``. Set (a recording without a wall): each
    fixation point is held at this depth along its first ray, metres."""
    first_mark_xz_m: tuple[float, float] = (0.0, 0.0)
    """First mark on the wall (X, Z), metres."""
    second_mark_xz_m: tuple[float, float] = (-0.25, -0.15)
    """Second mark (X, Z), metres."""
    imu_rate_hz: float = 100.0
    """Head IMU rate, Hz."""
    tracker_rate_hz: float = 60.0
    """Eye tracker rate, Hz."""
    camera: SceneCamera = field(default_factory=SceneCamera)
    """Scene camera (the pixel noise is drawn with its ``pixel_sigma``)."""
    jitter_m: float = 0.003
    """Fixational jitter of the true gaze point on the wall, metres."""
    gyro_sigma_rad_s: float = 0.003
    """Gyro white noise, rad/s per sample."""
    gyro_bias_deg_s: float = 0.3
    """Gyro bias per axis (sigma), deg/s."""
    accel_sigma_m_s2: float = 0.05
    """Accelerometer noise, m/s^2."""
    mag_sigma: float = 0.01
    """Magnetometer noise (field of norm 1)."""
    nod_deg: float = 15.0
    """Nodding amplitude (pitch), degrees."""
    shake_deg: float = 20.0
    """Shaking amplitude (yaw), degrees."""
    saccade_every_s: float | None = None
    """None: the two marks (the second from ``switch_s``). Set (scene viewing): a new mark every this many seconds, each
    uniform within +-``viewing_half_m`` of the wall's centre in X and Z (marks drawn apart from the other noise, so a
    seed's head motion and sensor noise are the two-mark scenario's)."""
    viewing_half_m: float = 0.3
    """Half the side of the square the viewing marks are drawn in, metres (+-17 deg at 1 m)."""

    @classmethod
    def declared(cls, header: Mapping[str, Any], gaze_meta: Mapping[str, Any], duration_s: float) -> GazeScenarioConfig:
        """What the gaze graph needs from a session's declarations: the wall (``wall_m``) or the fixation depth (``target_depth_m``)
        from ``[session]``, the scene camera from the gaze stream's metadata (``focal_px``, ``width_px``, ``height_px``, ``pixel_sigma``)."""
        return cls(duration_s=duration_s, switch_s=float(header.get("switch_s", np.nan)), wall_m=float(header.get("wall_m", np.nan)),
                   target_depth_m=float(header["target_depth_m"]) if "wall_m" not in header else None, camera=SceneCamera.from_meta(gaze_meta))


@dataclass(frozen=True)
class GazeSession:
    """A simulated gaze session with its truth."""

    t: FloatArray
    gyro_rad_s: FloatArray
    accel_m_s2: FloatArray
    mag: FloatArray
    tracker_t: FloatArray
    """Tracker sample times, seconds."""
    gaze_px: FloatArray
    """Gaze pixels (u right, v up), origin at the image centre, shape (M, 2)."""
    truth_quat_wxyz: FloatArray
    """Head attitude world_R_head at the IMU times."""
    truth_gaze_xz_m: FloatArray
    """True gaze point on the wall (X, Z) at the tracker times, shape (M, 2)."""
    config: GazeScenarioConfig
    head_tracker: AttitudeTrack | None = None
    """An optional head attitude tracker (its own room frame, possibly late)."""


class GazeData(Protocol):
    """What ``GazeGraph`` reads: a ``GazeSession``, or a live one whose arrays grow as samples arrive."""

    @property
    def t(self) -> FloatArray: ...  # IMU sample times, s

    @property
    def gyro_rad_s(self) -> FloatArray: ...

    @property
    def accel_m_s2(self) -> FloatArray: ...

    @property
    def mag(self) -> FloatArray: ...

    @property
    def tracker_t(self) -> FloatArray: ...  # gaze sample times, s

    @property
    def gaze_px(self) -> FloatArray: ...

    @property
    def config(self) -> GazeScenarioConfig: ...

    @property
    def head_tracker(self) -> AttitudeTrack | None: ...


@dataclass(frozen=True)
class BicycleScenarioConfig:
    """Everything that defines a simulated ride."""

    ride: str = "downhill"
    """'downhill' (outdoor, braking) or 'stand' (indoor trainer, no translation)."""
    duration_s: float = 40.0
    """Length, seconds."""
    rate_hz: float = 100.0
    """IMU rate, Hz."""
    brake_s: float = 30.0
    """Start of the hard braking (downhill), seconds."""
    decel_m_s2: float = 4.0
    """Braking deceleration, m/s^2."""
    top_speed_m_s: float = 8.0
    """Speed before braking, m/s."""
    slope_deg: float = 4.0
    """Road descent, degrees."""
    cadence_hz: float = 1.3
    """Pedalling rate, revolutions per second."""
    thigh_lever_m: float = 0.2
    """Distance from the hip to the thigh IMU, metres."""
    gyro_sigma_rad_s: float = 0.003
    """Gyro noise per sample, rad/s."""
    gyro_bias_deg_s: float = 0.2
    """Gyro bias per axis (sigma), deg/s."""
    accel_sigma_m_s2: float = 0.05
    """Accelerometer noise, m/s^2."""
    mag_sigma: float = 0.01
    """Magnetometer noise (field of norm 1)."""


@dataclass(frozen=True)
class BicycleSession:
    """Both IMUs' readings and the truth."""

    t: FloatArray
    thigh_gyro: FloatArray
    thigh_accel: FloatArray
    thigh_mag: FloatArray
    frame_gyro: FloatArray
    frame_accel: FloatArray
    frame_mag: FloatArray
    thigh_quat_wxyz: FloatArray
    """Truth: world_R_thigh."""
    frame_quat_wxyz: FloatArray
    """Truth: world_R_frame."""
    config: BicycleScenarioConfig

    @property
    def braking(self) -> np.ndarray:
        """The braking phase: from the brake to 5 s later (the stop and the held thigh)."""
        return (self.t >= self.config.brake_s) & (self.t < self.config.brake_s + 5.0)


ACTIVITIES = ("flat", "stairs_up", "stairs_down", "elevator")


@dataclass(frozen=True)
class Building:
    """Where things are: floors, the elevator shaft, the stairwell."""

    floor_height_m: float = 3.5
    """Height between floors, metres."""
    floors: int = 3
    """Number of floors (0 = ground)."""
    elevator_xy_m: tuple[float, float] = (20.0, 0.0)
    """Elevator car centre, metres."""
    stairs_foot_xy_m: tuple[float, float] = (0.0, 8.0)
    """Foot of every flight (the flights go +x from here, one floor each)."""
    riser_m: float = 0.175
    """Stair riser height, metres (20 steps per floor)."""
    tread_m: float = 0.28
    """Stair tread depth, metres."""


@dataclass(frozen=True)
class WalkingScenarioConfig:
    """Everything that defines a simulated walk."""

    rate_hz: float = 100.0
    """IMU sample rate, Hz."""
    building: Building = field(default_factory=Building)
    """The building."""
    gyro_sigma_rad_s: float = 0.005
    """Gyro white noise per sample, rad/s."""
    gyro_bias_sigma_deg_s: float = 0.02
    """Constant gyro bias per axis, deg/s (drawn per seed)."""
    accel_sigma_m_s2: float = 0.05
    """Accelerometer white noise per sample, m/s^2."""
    fix_every_s: float = 20.0
    """Mean time between image fixes while walking, seconds."""
    fix_position_sigma_m: float = 0.3
    """Noise of a correct fix's position, metres."""
    fix_heading_sigma_deg: float = 3.0
    """Noise of a correct fix's heading, degrees."""
    wrong_fix_fraction: float = 0.2
    """Fraction of fixes that are wrong matches."""
    wrong_fix_m: tuple[float, float] = (3.0, 10.0)
    """How far off a wrong fix is, metres (uniform)."""
    elevator_rides: int = 6
    """Elevator rides in the tour (at least 6)."""
    gait: str = "signature"
    """How the waist moves: ``signature`` draws each activity with the signature the detector looks for (the
    first generator); ``pendulum`` is the independent gait of ``scenarios.gait`` (an inverted-pendulum walker
    drawn per seed, stride variability, heel-strike transients, a tilted belt IMU)."""


@dataclass(frozen=True)
class Fixes:
    """Image-match fixes: measured pose, the pose a correct match would have given, and which are wrong."""

    t: FloatArray
    """Fix times, seconds, shape (F,)."""
    pose: FloatArray
    """Measured (x, y, z, yaw), shape (F, 4)."""
    correct_pose: FloatArray
    """The same fix had the match been right (truth + ordinary noise), shape (F, 4)."""
    wrong: np.ndarray
    """True where the match is wrong, shape (F,)."""


@dataclass(frozen=True)
class WalkingSession:
    """A simulated walk: the waist IMU, the fixes and the truth."""

    t: FloatArray
    """IMU sample times, seconds, shape (N,)."""
    accel_m_s2: FloatArray
    """Specific force in the body frame, shape (N, 3)."""
    gyro_rad_s: FloatArray
    """Body rate, shape (N, 3)."""
    fixes: Fixes
    """Image-match fixes."""
    truth_xyz_m: FloatArray
    """Waist position (without the gait sway), shape (N, 3)."""
    truth_yaw_rad: FloatArray
    """Heading of the body x axis, shape (N,)."""
    step_t: FloatArray
    """Heel-strike times of every step, shape (S,)."""
    step_activity: tuple[str, ...]
    """Activity of each step: flat, stairs_up or stairs_down."""
    rides: FloatArray
    """Elevator rides: rows (start_s, end_s, floors moved (+up))."""
    building: Building
    """The building (known to the estimator: elevator position, floor height, stair size)."""
    start_pose: FloatArray
    """(x, y, z, yaw) at the start, known to the estimator."""
    bouts: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    """Calibration walks only: rows (start_s, end_s, true mean speed m/s) of each straight leg."""
    beacons: BeaconRanges | None = None
    """Optional ranges to known UWB beacons (the Plaza factors in the walker's graph)."""
    start_sigmas: FloatArray | None = None
    """Prior sigmas of the start (roll, pitch, yaw rad, x, y, z m); None: the walker's known entrance."""

    def activity_at(self, t: float, within_s: float = 0.25) -> str | None:
        """The activity of the true step nearest ``t`` when one is within ``within_s`` (a detected cycle's truth), else None."""
        step_t = np.asarray(self.step_t)
        if not len(step_t):
            return None
        j = int(np.argmin(np.abs(step_t - t)))
        return str(self.step_activity[j]) if abs(step_t[j] - t) < within_s else None


@dataclass(frozen=True)
class RangeEpochs:
    """What the receivers heard, epoch by epoch, with the truth for scoring."""

    t: FloatArray
    """Emission times (K,), seconds."""
    receivers: FloatArray
    """Receiver positions (R, 3), metres."""
    ranges: list[list[FloatArray]]
    """ranges[k][r]: distances heard by receiver r at epoch k, sorted ascending (metres)."""
    labels: list[list[np.ndarray]] | None
    """Truth: the transmitter of each distance, or -1 - n for an echo of transmitter n."""
    positions: FloatArray | None
    """Truth positions (K, N, 3), metres."""
    range_sigma_m: float = 0.005
    """Range noise the session declares, metres."""
    tag_offsets_m: FloatArray | None = None
    """(N, 3) the tags' positions on one rigid body, in its frame (metres), when the session declares them."""
    planar: bool = False
    """The tags move in a horizontal plane (the receivers' mean height): tracked and scored in x, y."""
    declared_transmitters: int = 0
    """How many transmitters the session says emit each epoch."""
    labelled: bool = False
    """The ranging system knows each range's tag (a ``tag`` column): ranges[k][r] is then in tag order, NaN where
    receiver r did not hear that tag."""
    calibration: tuple[FloatArray, FloatArray, FloatArray] | None = None
    """A range calibration per receiver and tag the session declares: (bias_m, scale, sigma_m), each (R, N)."""

    @property
    def transmitters(self) -> int:
        if self.positions is not None:
            return int(self.positions.shape[1])
        return self.declared_transmitters


def session_from_epochs(epochs: RangeEpochs, meta: dict[str, object] | None = None) -> Session:
    """A RangeEpochs (simulated or imported) as a Session with a ``ranges`` stream and tag truth."""
    rows: list[tuple[float, int, float, float]] = []
    for k, t in enumerate(epochs.t):
        for r, heard in enumerate(epochs.ranges[k]):
            labels = epochs.labels[k][r] if epochs.labels is not None else np.full(len(heard), np.nan)
            rows += [(float(t), r, float(d), float(lab)) for d, lab in zip(heard, labels, strict=True)]
    table = np.array(rows, dtype=float).reshape(-1, 4)
    stream_meta: dict[str, object] = {
        "receivers_m": epochs.receivers.tolist(), "transmitters": int(epochs.transmitters), "sigma_m": float(epochs.range_sigma_m)
    }
    if epochs.tag_offsets_m is not None:
        stream_meta.update(tag_offsets_m=np.asarray(epochs.tag_offsets_m).tolist(), planar=bool(epochs.planar))
    if epochs.calibration is not None:
        stream_meta.update(zip(("range_bias_m", "range_scale", "range_sigma_m"), (np.asarray(v).tolist() for v in epochs.calibration), strict=True))
    # the truth labels ride along as an extra column that estimators never read (see the module docstring)
    columns = (*KIND_COLUMNS["ranges"], "truth_label") if epochs.labels is not None else KIND_COLUMNS["ranges"]
    ranges = Stream("ranges", "ranges", table[:, 0], table[:, 1 : 1 + len(columns)], columns, 0.0, stream_meta)
    truth = None
    if epochs.positions is not None:
        k_count, n = epochs.positions.shape[:2]
        t = np.repeat(epochs.t, n)
        tags = np.tile(np.arange(n, dtype=float), k_count)
        truth = Stream("truth", "tag_position", t, np.column_stack([tags, epochs.positions.reshape(-1, 3)]), KIND_COLUMNS["tag_position"])
    header = {"session": {"system": "ultrasonic", "world_frame": "room, z up (receivers on the ceiling)", **(meta or {})}}
    return Session("ultrasonic", {"ranges": ranges}, truth, header)


def epochs_from_session(session: Session) -> RangeEpochs:
    """The session's ``ranges`` stream (and truth, labels when present) as per-epoch sorted distances."""
    where = session.where
    streams = session.streams_of_kind("ranges")
    if not streams:
        raise SessionError(f"{where}: an ultrasonic session needs a stream of kind 'ranges' (see `fusegraph sensors ranges`)")
    stream = streams[0]
    for key in ("receivers_m", "transmitters"):
        if key not in stream.meta:
            raise SessionError(f"{where}: [streams.{stream.name}] needs {key} (see `fusegraph sensors ranges`)")
    receivers = np.asarray(stream.meta["receivers_m"], dtype=float)
    if receivers.ndim != 2 or receivers.shape[1] != 3:
        raise SessionError(f"{where}: receivers_m must be a list of [x, y, z] (got shape {receivers.shape})")
    n = int(stream.meta["transmitters"])
    receiver = stream.values[:, 0]
    if np.any(receiver != np.round(receiver)) or receiver.min() < 0 or receiver.max() >= len(receivers):
        bad = int(np.argmax((receiver != np.round(receiver)) | (receiver < 0) | (receiver >= len(receivers))))
        raise SessionError(f"{where}: stream '{stream.name}' line {bad + 2}: receiver {receiver[bad]:g} "
                           f"is not an index of receivers_m (0..{len(receivers) - 1})")
    labels_all = _column(session, stream.name, "truth_label")
    tag_all = _column(session, stream.name, "tag")
    times, starts = np.unique(stream.t, return_index=True)
    ends = np.append(starts[1:], len(stream.t))
    ranges: list[list[FloatArray]] = []
    labels: list[list[np.ndarray]] | None = [] if labels_all is not None else None
    for a, b in zip(starts, ends, strict=True):
        rec, dist = receiver[a:b].astype(int), stream.values[a:b, 1]
        per = []
        per_label = []
        for r in range(len(receivers)):
            mask = rec == r
            if tag_all is not None:  # labelled: in tag order, NaN for a tag this receiver did not hear
                tag = tag_all[a:b][mask].astype(int)
                heard = np.full(n, np.nan)
                heard[tag[(tag >= 0) & (tag < n)]] = dist[mask][(tag >= 0) & (tag < n)]
                per.append(heard)
                if labels_all is not None:
                    per_label.append(np.arange(n))
                continue
            order = np.argsort(dist[mask])
            per.append(dist[mask][order])
            if labels_all is not None:
                per_label.append(labels_all[a:b][mask][order].astype(int))
        ranges.append(per)
        if labels is not None:
            labels.append(per_label)
    positions = None
    truth = session.truth
    if truth is not None and truth.kind == "tag_position":
        positions = np.full((len(times), n, 3), np.nan)
        k = np.searchsorted(times, truth.t)
        ok = (k < len(times)) & (truth.values[:, 0] < n)
        positions[k[ok], truth.values[ok, 0].astype(int)] = truth.values[ok, 1:4]
    offsets = stream.meta.get("tag_offsets_m")
    tag_offsets = None
    if offsets is not None:
        tag_offsets = np.asarray(offsets, dtype=float)
        if tag_offsets.ndim != 2 or tag_offsets.shape[1] != 3 or len(tag_offsets) != n:
            raise SessionError(f"{where}: [streams.{stream.name}] tag_offsets_m must be {n} rows of [x, y, z] (one per transmitter; "
                               f"got shape {tag_offsets.shape})")
    calibration = None
    if "range_bias_m" in stream.meta:
        parts = []
        for key, default in (("range_bias_m", None), ("range_scale", 1.0), ("range_sigma_m", None)):
            if stream.meta.get(key, default) is None:
                raise SessionError(f"{where}: [streams.{stream.name}] range_bias_m needs {key} too (a calibration per receiver and tag)")
            value = np.asarray(stream.meta.get(key, default), dtype=float) * np.ones((len(receivers), n))
            if value.shape != (len(receivers), n):
                raise SessionError(f"{where}: [streams.{stream.name}] {key} must be {len(receivers)} rows (receivers) of {n} (tags)")
            parts.append(value)
        calibration = (parts[0], parts[1], parts[2])
    return RangeEpochs(times, receivers, ranges, labels, positions, float(stream.meta.get("sigma_m", 0.005)), tag_offsets,
                       bool(stream.meta.get("planar", False)), n, tag_all is not None, calibration)


def _column(session: Session, name: str, column: str) -> FloatArray | None:
    """An optional column of a ranges stream: ``truth_label`` (scoring only) or ``tag`` (the ranging system's own label)."""
    stream = session.stream(name)
    if column in stream.columns:
        return stream.values[:, stream.columns.index(column)]
    if session.path is None:
        return None
    path = session.path / str(session.stream(name).meta.get("file", f"{name}.csv"))
    header = path.read_text(encoding="utf-8-sig").splitlines()[0].split(",")
    if column not in [h.strip() for h in header]:
        return None
    _, values = read_stream_csv(path, (column,), name, repeated_times=True)
    return values[:, 0]
