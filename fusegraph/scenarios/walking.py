"""Scenario ``walking``: a person with a waist IMU walking through a 3-floor building, with image fixes.

Two gaits (``WalkingScenarioConfig.gait``). ``pendulum`` is the independent one of ``scenarios.gait`` (an
inverted-pendulum pelvis with stride variability, heel strikes and a tilted belt IMU), on which the
activity detector is scored. ``signature`` (the default, the positioning benches' walk) is the first
generator: the walker's waist follows a gait model per step (phase 0 = heel strike): the forward speed surges
(``v + B cos 2 pi phase``, so forward acceleration goes negative then positive), the waist rises and
falls (lowest at heel strike: vertical acceleration positive then negative), sways sideways once
per stride, and rolls. The activity signatures are the ones the walking-analysis paper detects:
going UP stairs the waist rolls once per stride (roll-rate period twice the vertical period), on
flat ground and down stairs mostly once per step; going DOWN stairs the vertical swing is much
larger than the forward one. An elevator ride is a smooth vertical acceleration pulse, cruise and
opposite pulse with the person standing. The IMU reads the specific force and body rate of that
motion (with noise and a small gyro bias). World frame ENU; the body frame x forward, y left, z up.

The tour (seeded: speeds, distances, turns) walks floor 0, rides and climbs between floors (at
least 6 elevator rides, two flights up and two down) and comes back to the start. Image fixes
(position + heading) come every ~``fix_every_s`` while walking; a fraction are wrong by metres.
A separate calibration walk (straight legs at known speeds) lets the speed regression be fitted
per person, as a user would.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
from scipy.ndimage import gaussian_filter1d

from ..catalogue import check_sensors
from ..factors.imu import GRAVITY_M_S2
from ..geometry import FloatArray
from ..records import Building, Fixes, WalkingScenarioConfig, WalkingSession
from ..session import KIND_COLUMNS, Session, Stream
from .gait import PendulumGait, Walker, turn_progress

if TYPE_CHECKING:
    from ..frontends.pdr import SpeedModel


class _Tour:
    """Accumulates a smooth kinematic timeline, step by step."""

    def __init__(self, rate_hz: float, start: tuple[float, float, float, float], gait: PendulumGait | None = None) -> None:
        self.gait = gait
        self.step_speed: list[float] = []
        self.step_end_t: list[float] = []
        self.dt = 1.0 / rate_hz
        self.t = 0.0
        self.x, self.y, self.z, self.yaw = start
        self.rows: list[tuple[float, ...]] = []  # t, forward speed, yaw, z, lateral, roll, pitch, vertical elevator speed
        self.step_index = 0
        self.step_t: list[float] = []
        self.step_activity: list[str] = []
        self.rides: list[tuple[float, float, float]] = []
        self.walking: list[tuple[float, float]] = []

    def _emit(self, duration: float, fn: Callable[[float], tuple[float, ...]]) -> None:
        n = max(1, round(duration / self.dt))
        for j in range(n):
            phase = j / n
            self.rows.append((self.t, *fn(phase)))
            self.t += self.dt

    def stand(self, duration: float) -> None:
        z, yaw = self.z, self.yaw
        self._emit(duration, lambda p: (0.0, yaw, z, 0.0, 0.0, 0.0, 0.0))

    def step(self, kind: str, speed: float, period: float, dyaw: float, scale: float = 1.0) -> None:
        """One step of ``kind`` at mean speed ``speed`` (m/s) lasting ``period`` s, turning ``dyaw``."""
        k = self.step_index
        rise = {"flat": 0.0, "stairs_up": 0.175, "stairs_down": -0.175}[kind]
        # gait amplitudes: vertical A grows with speed on flat ground; down stairs the vertical swing dominates
        amp_v = {"flat": 0.005 + 0.015 * speed, "stairs_up": 0.01, "stairs_down": 0.03}[kind] * scale
        amp_f = {"flat": 0.2 * speed, "stairs_up": 0.15, "stairs_down": 0.04}[kind] * scale
        roll_step, roll_stride = {"flat": (2.0, 0.4), "stairs_up": (0.5, 4.0), "stairs_down": (2.0, 0.5)}[kind]
        sway = 0.02 * scale
        z0, yaw0 = self.z, self.yaw
        self.step_t.append(self.t)
        self.step_activity.append(kind)
        self.step_speed.append(speed)
        if self.gait is not None:
            self._emit(period, self.gait.step(kind, speed, period, yaw0, dyaw, z0, rise, k, scale))
            self.step_end_t.append(self.t)
            self._finish_step(z0 + rise, yaw0, dyaw, speed, period)
            return

        def sample(p: float) -> tuple[float, ...]:
            s = turn_progress(p)
            return (
                speed + amp_f * math.cos(2 * math.pi * p),
                yaw0 + dyaw * s,
                z0 + rise * s + amp_v * (1 - math.cos(2 * math.pi * p)),
                sway * math.sin(math.pi * (k + p)),
                math.radians(roll_step * math.sin(2 * math.pi * p) + roll_stride * math.sin(math.pi * (k + p))) * scale,
                math.radians(1.5 * math.sin(2 * math.pi * p + 0.5)) * scale,
                0.0,
            )

        self._emit(period, sample)
        self._finish_step(z0 + rise, yaw0, dyaw, speed, period)

    def _finish_step(self, z: float, yaw0: float, dyaw: float, speed: float, period: float) -> None:
        self.z = z
        self.yaw = yaw0 + dyaw
        self.x += speed * period * math.cos(yaw0 + dyaw / 2)
        self.y += speed * period * math.sin(yaw0 + dyaw / 2)
        self.step_index += 1

    def walk_to(self, target: tuple[float, float], speed: float) -> None:
        """Flat steps toward ``target``, turning at most 30 deg per step; first and last steps at half speed."""
        t0 = self.t
        period = 1.0 / (1.0 + 0.65 * speed)
        first = True
        while True:
            if self.gait is not None:
                period = self.gait.period("flat", speed)
            dx, dy = target[0] - self.x, target[1] - self.y
            remaining = math.hypot(dx, dy)
            stride = speed * period
            if remaining < 0.6 * stride:
                break
            dyaw = max(-math.radians(30), min(math.radians(30), math.remainder(math.atan2(dy, dx) - self.yaw, 2 * math.pi)))
            last = remaining < 1.6 * stride
            ease = 0.5 if (first or last) else 1.0
            self.step("flat", speed * ease, period, dyaw, scale=ease)
            first = False
        self.walking.append((t0, self.t))

    def face(self, yaw: float) -> None:
        """Turn in place (two slow shuffling steps' time, no gait signal)."""
        yaw0, dyaw = self.yaw, math.remainder(yaw - self.yaw, 2 * math.pi)
        z = self.z
        self._emit(1.5, lambda p: (0.0, yaw0 + dyaw * turn_progress(p), z, 0.0, 0.0, 0.0, 0.0))
        self.yaw = yaw0 + dyaw

    def stairs(self, kind: str, steps: int, tread: float) -> None:
        t0 = self.t
        period = 1.0 / (1.4 if kind == "stairs_up" else 1.8)
        for _ in range(steps):
            if self.gait is not None:
                period = self.gait.period(kind, 0.0)
            self.step(kind, tread / period, period, 0.0)
        self.walking.append((t0, self.t))

    def elevator(self, floors: int, floor_height: float) -> None:
        """Stand, ride ``floors`` (negative = down) with a smooth acceleration pulse, stand."""
        self.stand(2.0)
        start = self.t
        distance = abs(floors) * floor_height
        accel, top = 0.8, 1.2
        ramp = top / accel
        cruise = max(distance - top * ramp, 0.0) / top
        sign = 1.0 if floors > 0 else -1.0
        total = 2 * ramp + cruise
        z0, yaw = self.z, self.yaw

        def vz(tau: float) -> float:
            if tau < ramp:
                return accel * tau
            if tau < ramp + cruise:
                return top
            return max(top - accel * (tau - ramp - cruise), 0.0)

        n = max(1, round(total / self.dt))
        z = z0
        for j in range(n):
            v = sign * vz(j * self.dt)
            self.rows.append((self.t, 0.0, yaw, z, 0.0, 0.0, 0.0, v))
            z += v * self.dt
            self.t += self.dt
        self.z = z0 + sign * distance
        self.rides.append((start, self.t, float(floors)))
        self.stand(2.0)


def _imu(tour: _Tour, rng: np.random.Generator, config: WalkingScenarioConfig) -> tuple[FloatArray, ...]:
    rows = np.array(tour.rows)
    t, speed, yaw, z_gait, lateral, roll, pitch, _vz = rows.T
    dt = tour.dt
    # velocity jumps at bout starts/stops smoothed over ~0.1 s (gait initiation is not instantaneous); the pendulum
    # gait's steps jump only in their mean speed, so that is what is smoothed, its within-step surge kept as it is
    if tour.gait is not None:
        mean = np.zeros(len(t))
        for start, end, v in zip(np.searchsorted(t, np.array(tour.step_t) - 1e-9), np.searchsorted(t, np.array(tour.step_end_t) - 1e-9),
                                 tour.step_speed, strict=True):
            mean[start:end] = v
        speed = gaussian_filter1d(mean, 5) + (speed - mean)
    else:
        speed = gaussian_filter1d(speed, 5)
    # positions integrate the smoothed speed along the heading from the start (the origin)
    x = np.cumsum(speed * np.cos(yaw)) * dt
    y = np.cumsum(speed * np.sin(yaw)) * dt
    z = z_gait  # floor height, stairs, gait bounce and elevator rides are all in the z column
    left = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1)
    pos = np.stack([x, y, z], axis=1)
    pos_gait = pos.copy()
    pos_gait[:, :2] += lateral[:, None] * left
    vel = np.gradient(pos_gait, dt, axis=0)
    acc_world = np.gradient(vel, dt, axis=0)
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    # world_R_body = Rz(yaw) Ry(pitch) Rx(roll), rows stacked
    R = np.empty((len(t), 3, 3))
    R[:, 0, 0] = cy * cp
    R[:, 0, 1] = cy * sp * sr - sy * cr
    R[:, 0, 2] = cy * sp * cr + sy * sr
    R[:, 1, 0] = sy * cp
    R[:, 1, 1] = sy * sp * sr + cy * cr
    R[:, 1, 2] = sy * sp * cr - cy * sr
    R[:, 2, 0] = -sp
    R[:, 2, 1] = cp * sr
    R[:, 2, 2] = cp * cr
    specific = acc_world + np.array([0.0, 0.0, GRAVITY_M_S2])
    accel = np.einsum("nji,nj->ni", R, specific)
    droll, dpitch, dyaw = (np.gradient(a, dt) for a in (roll, pitch, yaw))
    gyro = np.stack([droll - dyaw * sp, dpitch * cr + dyaw * sr * cp, -dpitch * sr + dyaw * cr * cp], axis=1)
    if tour.gait is not None:
        # heel-strike transients shake the sensor along the body's vertical; the IMU sits tilted on the belt
        accel[:, 2] += tour.gait.impacts(t, np.array(tour.step_t), tuple(tour.step_activity), np.array(tour.step_speed))
        imu_R_body = tour.gait.walker.imu_R_body
        accel, gyro = accel @ imu_R_body.T, gyro @ imu_R_body.T
    bias = rng.normal(0.0, math.radians(config.gyro_bias_sigma_deg_s), 3)
    gyro_meas = gyro + bias + rng.normal(0.0, config.gyro_sigma_rad_s, gyro.shape)
    accel_meas = accel + rng.normal(0.0, config.accel_sigma_m_s2, accel.shape)
    return t, accel_meas, gyro_meas, pos, yaw


def _fixes(rng: np.random.Generator, t: FloatArray, pos: FloatArray, yaw: FloatArray, walking: list[tuple[float, float]],
           config: WalkingScenarioConfig) -> Fixes:
    times: list[float] = []
    for start, end in walking:
        s = start + rng.uniform(0.3, 1.0) * config.fix_every_s
        while s < end:
            times.append(s)
            s += config.fix_every_s * rng.uniform(0.6, 1.4)
    ft = np.array(sorted(times))
    idx = np.clip(np.searchsorted(t, ft), 0, len(t) - 1)
    truth = np.column_stack([pos[idx], yaw[idx]])
    noise = np.column_stack([rng.normal(0, config.fix_position_sigma_m, (len(ft), 2)), rng.normal(0, 0.05, len(ft)),
                             rng.normal(0, math.radians(config.fix_heading_sigma_deg), len(ft))])
    correct = truth + noise
    wrong = rng.random(len(ft)) < config.wrong_fix_fraction
    measured = correct.copy()
    angle = rng.uniform(-math.pi, math.pi, len(ft))
    dist = rng.uniform(*config.wrong_fix_m, len(ft))
    measured[wrong, 0] += (dist * np.cos(angle))[wrong]
    measured[wrong, 1] += (dist * np.sin(angle))[wrong]
    measured[wrong, 3] += rng.normal(0, math.radians(20.0), len(ft))[wrong]
    return Fixes(t=ft, pose=measured, correct_pose=correct, wrong=wrong)


def _gait(seed: int, config: WalkingScenarioConfig, stream: int) -> PendulumGait | None:
    """The seed's walker (the same for its tour and its calibration walk; own random streams, so the
    signature gait's draws are unchanged); None for the signature gait."""
    if config.gait == "signature":
        return None
    if config.gait != "pendulum":
        raise ValueError(f"walking gait {config.gait!r}: use 'signature' or 'pendulum'")
    walker = Walker.draw(np.random.default_rng([seed, 7]))
    return PendulumGait(walker, np.random.default_rng([seed, 8, stream]))


SIMULATED_WAIST_HEIGHT_M = 0.9
"""The simulated walker's waist height declared to ``--solver gait``, m (the pendulum gait draws legs of 0.82-0.98 m)."""


def simulate_walking(seed: int = 0, config: WalkingScenarioConfig | None = None) -> WalkingSession:
    """The seeded tour: floor 0 -> elevator and stairs between floors -> back to the start."""
    config = config or WalkingScenarioConfig()
    b = config.building
    rng = np.random.default_rng(seed)
    start = (0.0, 0.0, 0.0, 0.0)
    tour = _Tour(config.rate_hz, start, _gait(seed, config, 0))
    tour.stand(3.0)
    ex, ey = b.elevator_xy_m
    fx, fy = b.stairs_foot_xy_m
    flight = 20
    top_x = fx + flight * b.tread_m

    def speed() -> float:
        return float(rng.uniform(0.8, 1.5))

    def wander() -> None:
        for _ in range(int(rng.integers(1, 3))):
            tour.walk_to((float(rng.uniform(-5, 25)), float(rng.uniform(-10, 15))), speed())

    def to_elevator() -> None:
        tour.walk_to((ex - 1.5, ey), speed())
        tour.walk_to((ex, ey), 0.8)

    def flight_up() -> None:
        tour.walk_to((fx - 1.5, fy), speed())
        tour.walk_to((fx, fy), 0.8)
        tour.face(0.0)
        tour.stairs("stairs_up", flight, b.tread_m)

    def flight_down() -> None:
        tour.walk_to((top_x + 1.5, fy), speed())
        tour.walk_to((top_x, fy), 0.8)
        tour.face(math.pi)
        tour.stairs("stairs_down", flight, b.tread_m)

    floor = 0
    rides = 0
    # a fixed itinerary with seeded speeds and wandering: rides up and down, two flights each way
    itinerary = ["ride+2", "down", "ride-1", "up", "ride+1", "ride-2", "up", "ride+1", "down", "down", "ride+2", "ride-2"]
    for leg in itinerary:
        wander()
        if leg.startswith("ride"):
            floors = int(leg[4:])
            to_elevator()
            tour.elevator(floors, b.floor_height_m)
            floor += floors
            rides += 1
            tour.walk_to((ex - 2.0, ey + 1.0), 0.8)
        elif leg == "up":
            flight_up()
            floor += 1
        else:
            flight_down()
            floor -= 1
    if floor != 0 or rides < config.elevator_rides:
        raise AssertionError("itinerary must end on floor 0 with enough rides")
    wander()
    tour.walk_to((start[0], start[1]), speed())
    tour.stand(3.0)
    t, accel, gyro, pos, yaw = _imu(tour, rng, config)
    fixes = _fixes(rng, t, pos, yaw, tour.walking, config)
    return WalkingSession(
        t=t, accel_m_s2=accel, gyro_rad_s=gyro, fixes=fixes, truth_xyz_m=pos, truth_yaw_rad=yaw,
        step_t=np.array(tour.step_t), step_activity=tuple(tour.step_activity), rides=np.array(tour.rides),
        building=b, start_pose=np.array(start),
    )


def simulate_calibration_walk(seed: int = 0, speeds_m_s: tuple[float, ...] = (0.7, 0.9, 1.1, 1.3, 1.5), leg_m: float = 15.0,
                              config: WalkingScenarioConfig | None = None) -> WalkingSession:
    """Straight legs of ``leg_m`` at known speeds, turning back between them: data to fit the speed model."""
    config = config or WalkingScenarioConfig()
    rng = np.random.default_rng(seed + 10_000)
    tour = _Tour(config.rate_hz, (0.0, 0.0, 0.0, 0.0), _gait(seed, config, 1))
    tour.stand(2.0)
    bouts = []
    for i, v in enumerate(speeds_m_s):
        target = (leg_m if i % 2 == 0 else 0.0, 0.0)
        tour.face(0.0 if i % 2 == 0 else math.pi)
        t0 = tour.t
        tour.walk_to(target, v)
        bouts.append((t0, tour.t, v))
        tour.stand(2.0)
    t, accel, gyro, pos, yaw = _imu(tour, rng, config)
    return WalkingSession(
        t=t, accel_m_s2=accel, gyro_rad_s=gyro, fixes=Fixes(np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4)), np.zeros(0, bool)),
        truth_xyz_m=pos, truth_yaw_rad=yaw, step_t=np.array(tour.step_t), step_activity=tuple(tour.step_activity),
        rides=np.zeros((0, 3)), building=config.building, start_pose=np.zeros(4), bouts=np.array(bouts),
    )


def beacon_ranges(seed: int, t: FloatArray, truth_xyz_m: FloatArray, building: Building, rate_hz: float = 1.0, sigma_m: float = 0.15,
                  nlos_frac: float = 0.05) -> tuple[FloatArray, FloatArray, np.ndarray, FloatArray]:
    """UWB beacons under the ceiling at the corners of each floor's walked area (2 m beyond it), ranges at
    ``rate_hz`` from every beacon of the walker's floor: white noise ``sigma_m`` and, on a fraction
    ``nlos_frac``, a non-line-of-sight excess of 0.5-3 m (always longer). Returns (beacons_m, t, beacon, range_m)."""
    rng = np.random.default_rng([seed, 3])
    floor = np.round(truth_xyz_m[:, 2] / building.floor_height_m).astype(int)
    beacons = []
    for f in range(building.floors):
        xy = truth_xyz_m[floor == f, :2]
        if not len(xy):
            continue
        lo, hi = xy.min(axis=0) - 2.0, xy.max(axis=0) + 2.0
        z = f * building.floor_height_m + 2.5
        beacons += [(lo[0], lo[1], z), (hi[0], lo[1], z), (hi[0], hi[1], z), (lo[0], hi[1], z)]
    beacons_m = np.array(beacons)
    beacon_floor = np.round((beacons_m[:, 2] - 2.5) / building.floor_height_m).astype(int)
    rows = np.arange(0, len(t), max(1, int(round(1.0 / (rate_hz * float(np.median(np.diff(t))))))))
    times, which, ranges = [], [], []
    for i in rows:
        for b in np.flatnonzero(beacon_floor == floor[i]):
            d = float(np.linalg.norm(truth_xyz_m[i] - beacons_m[b])) + rng.normal(0.0, sigma_m)
            if rng.random() < nlos_frac:
                d += rng.uniform(0.5, 3.0)
            times.append(t[i])
            which.append(b)
            ranges.append(d)
    return beacons_m, np.array(times), np.array(which), np.array(ranges)


def walking_session(seed: int = 0, profile: str | None = None, duration_s: float | None = None, sensors: tuple[str, ...] | None = None,
                    gait: str = "signature") -> Session:
    """The walk as a session (``fusegraph simulate walking``): waist ``gyro`` and ``accel``, the image
    ``fixes`` (kind ``pose``: x, y, z, yaw in radians), the building and the start in the metadata,
    the waist position as truth. The per-person speed model is fitted on the scenario's calibration
    walk (as a user would on theirs) and stored in ``[speed_model]``. With ``beacons`` among ``sensors``,
    ranges to UWB beacons (``beacons``, kind beacon_ranges; see ``beacon_ranges``) are written too. ``gait``: the
    scenario's gait model (``signature`` or ``pendulum``, ``WalkingScenarioConfig.gait``)."""
    if profile not in (None, "realistic"):
        raise ValueError(f"--profile {profile} does not apply to walking (its noise is the realistic one)")
    if duration_s is not None:
        raise ValueError("--duration does not apply to walking: the tour decides its length (about 12 minutes)")
    if gait not in ("signature", "pendulum"):
        raise ValueError(f"--gait {gait}: walking's gait models are signature and pendulum")
    config = WalkingScenarioConfig(gait=gait)
    return session_of_walk(simulate_walking(seed, config), calibrated_speed(seed, config), seed, sensors)


def calibrated_speed(seed: int, config: WalkingScenarioConfig | None = None) -> SpeedModel:
    """The speed regression fitted on the seed's calibration walk (its own walker, as a user calibrates on theirs)."""
    from ..frontends.pdr import detect_cycles, fit_speed_model

    cal = simulate_calibration_walk(seed, config=config)
    return fit_speed_model(detect_cycles(cal.t, cal.accel_m_s2, cal.gyro_rad_s), cal.bouts)


def session_of_walk(w: WalkingSession, speed: SpeedModel, seed: int, sensors: tuple[str, ...] | None = None,
                    correct_fixes: bool = False) -> Session:
    """A simulated walk as the session ``walking_session`` writes (``speed``: the person's calibrated model);
    ``correct_fixes``: the fixes a correct match gives at the same times (no wrong match), for what wrong fixes cost."""
    sensors = check_sensors("walking", sensors or ("gyro", "accel", "fixes"), ("gyro", "accel"), ("fixes", "beacons"))
    streams = {
        "gyro": Stream("gyro", "gyro", w.t, w.gyro_rad_s, KIND_COLUMNS["gyro"]),
        "accel": Stream("accel", "accel", w.t, w.accel_m_s2, KIND_COLUMNS["accel"]),
    }
    if "fixes" in sensors:
        streams["fixes"] = Stream("fixes", "pose", w.fixes.t, w.fixes.correct_pose if correct_fixes else w.fixes.pose, KIND_COLUMNS["pose"])
    if "beacons" in sensors:
        beacons_m, bt, which, ranges = beacon_ranges(seed, w.t, w.truth_xyz_m, w.building)
        streams["beacons"] = Stream("beacons", "beacon_ranges", bt, np.column_stack([which, ranges]), KIND_COLUMNS["beacon_ranges"],
                                    meta={"beacons_m": beacons_m.tolist(), "sigma_m": 0.15, "bias_sigma_m": 0.3})
    b = w.building
    fixes = "image fixes, none wrong" if correct_fixes else "image fixes (some wrong)"
    meta = {
        "session": {"description": f"walking scenario, seed {seed}: a 3-floor building tour, waist IMU, {fixes}",
                    "world_frame": "ENU", "start_pose": [float(v) for v in w.start_pose]},
        "building": {"floor_height_m": b.floor_height_m, "floors": b.floors, "elevator_xy_m": list(b.elevator_xy_m),
                     "stairs_foot_xy_m": list(b.stairs_foot_xy_m), "riser_m": b.riser_m, "tread_m": b.tread_m},
        "speed_model": {"intercept_m_s": speed.intercept_m_s, "slope_s": speed.slope_s},
        # the waist's height --solver gait needs: the middle of the pendulum gait's leg lengths (0.82-0.98 m)
        "person": {"sensor_height_m": SIMULATED_WAIST_HEIGHT_M},
    }
    truth = Stream("truth", "position", w.t, w.truth_xyz_m, KIND_COLUMNS["position"])
    return Session("walking", streams, truth, meta)
