"""Pedestrian positioning over floors: PDR steps as odometry, image fixes, elevator map constraints.

Front end (``frontends.pdr``; each step's activity by the waist classifier, ``frontends.activity``) -> one odometry
factor per detected step (stride in the direction of travel, gyro heading change, a riser up or down for a stair step)
and one per elevator ride (the floors it moved, from the double-integrated vertical acceleration), image-match fixes as
robust pose priors, and the map constraint that a ride ends in the elevator. Methods on the same measurements: dead
reckoning (steps and rides only), the paper's Kalman framework (EKF on x, y, z, heading; fixes gated by their
innovation), iSAM2 online (causal: the steps classified causally too) and batch.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import gtsam
import numpy as np
from scipy.stats import chi2

from ..factors.odometry import FixNoise, OdometryNoise, PlanarMotion, dead_reckon, level_pose, odometry_sigmas
from ..factors.ranging import BeaconRanges, beacon_ranges_from
from ..frontends.activity import with_activity
from ..frontends.pdr import Cycle, PdrConfig, Ride, SpeedModel, detect_rides, front_end
from ..geometry import FloatArray
from ..graphs.planar import PlanarGraph, causal_online, poses_of, range_schedule, start_from_ranges
from ..metrics import track_errors
from ..records import Building, Fixes, WalkingSession
from ..results import WalkRun
from ..session import Session, SessionError
from ..solvers.batch import solve_python_loop
from ..solvers.online import OnlineConfig
from ..tuned import value

STEP_NOISE = OdometryNoise(distance_frac=0.08, lateral_frac=0.05, floor_m=0.02, yaw_rad=math.radians(0.5), yaw_frac=0.03, vertical_m=0.03)
"""A detected step: 8 % of its length along, 5 % across, 0.5 deg heading, 3 cm height."""
RIDE_NOISE = OdometryNoise(floor_m=0.2, yaw_rad=math.radians(1.0), vertical_m=0.1)
"""An elevator ride: the person stands (20 cm shuffle), floors are whole."""
FIX_NOISE = FixNoise(position_m=0.5, heading_rad=math.radians(5.0), height_m=0.3, kernel="cauchy", kernel_width=float(value("walking_fixes", "kernel_width")))
"""An image-match fix, Cauchy-robust (a fifth of them are wrong by metres). The kernel is wide (after 20 s of steps a
correct fix is often 3 m from the prediction, and a 1-sigma kernel threw those away too): its width is chosen with the
rejection threshold by ``fusegraph tune walking_fixes`` on the pendulum gait's tuning seeds (``tuned.toml``)."""
REJECT_SIGMAS = float(value("walking_fixes", "reject_sigmas"))
"""Batch: a fix further than this many position sigmas from the robust solution is dropped and the graph solved
again (the same study)."""
ELEVATOR_SIGMAS_M = np.array([0.7, 0.7, 50.0])
"""A ride starts and ends in the elevator car (position known to 0.7 m; the height is left to the ride)."""
START_SIGMAS = np.array([1e-3, 1e-3, math.radians(2.0), 0.2, 0.2, 0.05])
"""The start pose is known (the entrance)."""
ONLINE = OnlineConfig(window_s=30.0, reanchor_every=100, relinearize_threshold=0.05, covariance=False)
"""iSAM2 keeps the last 30 s as variables (a wrong fix can still be outvoted), re-anchors every 100 steps."""
VEHICLE_ONLINE = OnlineConfig(window_s=5.0, reanchor_every=50, relinearize_threshold=0.05, covariance=False)
"""A session driven by wheel odometry (a state every 0.1-0.2 s, Plaza): iSAM2 keeps the last 5 s as variables and
re-anchors every 50 states (5-10 s): iSAM2 hands every Python range factor a copy of all its variables, so a small
window is what keeps it fast (the 30 s step window: Plaza2 42x real time against 123x)."""
WAIST = PdrConfig()
"""Front-end settings for the waist IMU (its step thresholds chosen by ``bench gait`` on Mobilise-D: ``PdrConfig``)."""


@dataclass(frozen=True)
class Event:
    """One odometry increment on the timeline: a step or a ride."""

    t: float
    motion: PlanarMotion
    noise: OdometryNoise
    ride: bool


def events_from(cycles: list[Cycle], rides: list[Ride], speed: SpeedModel, building: Building) -> list[Event]:
    """Steps and rides as odometry increments in time order (a cycle called not walking moves nothing but the heading)."""
    out: list[Event] = []
    for c in cycles:
        if c.activity in ("flat", "not_walking"):  # not walking (standing, sitting, a transition): no travel (docs/systems/walking.md)
            length, up = speed.speed(c.vertical_pp_m_s2) * c.period_s if c.activity == "flat" else 0.0, 0.0
        else:
            length, up = building.tread_m, building.riser_m * (1.0 if c.activity == "stairs_up" else -1.0)
        motion = PlanarMotion(forward_m=length * math.cos(c.travel_rad), left_m=length * math.sin(c.travel_rad), up_m=up, dyaw_rad=c.dyaw_rad)
        out.append(Event(c.t, motion, STEP_NOISE, False))
    for r in rides:
        floors = round(r.up_m / building.floor_height_m)
        out.append(Event(r.end_s, PlanarMotion(forward_m=0.0, up_m=floors * building.floor_height_m), RIDE_NOISE, True))
    return sorted(out, key=lambda e: e.t)


def _fix_schedule(session: WalkingSession, times: FloatArray) -> list[list[int]]:
    """Fixes per state index (nearest state in time), in the order they become known."""
    per_state: list[list[int]] = [[] for _ in times]
    for k, ft in enumerate(session.fixes.t):
        per_state[int(np.argmin(np.abs(times - ft)))].append(k)
    return per_state


def _build(session: WalkingSession, events: list[Event], fixes: FloatArray, on_state: Callable[[PlanarGraph, int], None] | None = None,
           keep: np.ndarray | None = None, fix_noise: FixNoise = FIX_NOISE) -> PlanarGraph:
    start = level_pose(*session.start_pose)
    graph = PlanarGraph(start, START_SIGMAS if session.start_sigmas is None else session.start_sigmas, start_t=float(session.t[0]))
    times = np.array([float(session.t[0])] + [e.t for e in events])
    schedule = _fix_schedule(session, times)
    elevator = np.array([*session.building.elevator_xy_m, 0.0])
    r = 0
    attach, first, order = np.zeros(0, int), np.zeros(0, int), np.zeros(0, int)
    if session.beacons is not None and len(session.beacons.t) and len(times) > 1:
        attach, first = range_schedule(times, session.beacons.t)
        order = np.argsort(first, kind="stable")
    for i, e in enumerate(events, start=1):
        if e.ride:
            graph.add_position(i - 1, elevator, ELEVATOR_SIGMAS_M)
        graph.add_odometry(e.motion, e.noise, e.t)
        if e.ride:
            graph.add_position(i, elevator, ELEVATOR_SIGMAS_M)
        for k in schedule[i - 1] + (schedule[i] if i == len(events) else []):
            if keep is not None and not keep[k]:
                continue
            graph.add_fix(i - 1 if k in schedule[i - 1] else i, level_pose(*fixes[k]), fix_noise)
        while r < len(order) and first[order[r]] <= i:
            _add_beacon_range(graph, session.beacons, int(order[r]), int(attach[order[r]]), times)  # type: ignore[arg-type]
            r += 1
        if on_state is not None:
            on_state(graph, i)
    return graph


#: Walking speed that bounds how far the walker moves between a range and the state it attaches to, m/s.
_WALK_SPEED_M_S = 1.5


def _add_beacon_range(graph: PlanarGraph, ranges: BeaconRanges, n: int, state: int, times: FloatArray) -> None:
    """Range ``n`` on its nearest state; the walker's motion over the time between them widens the sigma."""
    moved = _WALK_SPEED_M_S * abs(float(ranges.t[n]) - float(times[state]))
    noise = replace(ranges.noise, sigma_m=float(np.hypot(ranges.noise.sigma_m, moved)))
    b = int(ranges.beacon[n])
    graph.add_range(state, b, ranges.beacons_m[b], float(ranges.range_m[n]), noise)


def run_dead_reckoning(session: WalkingSession, events: list[Event]) -> WalkRun:
    t0 = time.perf_counter()
    poses = dead_reckon(level_pose(*session.start_pose), [e.motion for e in events])
    return WalkRun("dead_reckoning", np.array([float(session.t[0])] + [e.t for e in events]), np.array([p.translation() for p in poses]),
                   time.perf_counter() - t0)


def run_batch(session: WalkingSession, events: list[Event], fixes: FloatArray, fix_noise: FixNoise = FIX_NOISE,
              reject_sigmas: float = REJECT_SIGMAS) -> WalkRun:
    """Levenberg-Marquardt with the Cauchy fixes, then once more without the fixes the solution puts
    more than ``REJECT_SIGMAS`` position sigmas away (a wrong match still pulls a little through a wide kernel)."""
    t0 = time.perf_counter()
    graph = _build(session, events, fixes, fix_noise=fix_noise)
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-6)

    def solve(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values) -> gtsam.Values:
        if session.beacons is not None:  # Python range factors: driven from Python (see solve_python_loop), 20x faster
            return solve_python_loop(graph, initial, relative_error_tol=1e-6).values
        return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()

    values = solve(graph.graph, graph.initial)
    times = np.array(graph.keyframe_t)
    solved = poses_of(values, graph.count)
    if len(fixes):
        state = [int(np.argmin(np.abs(times - ft))) for ft in session.fixes.t]
        gap = np.linalg.norm(fixes[:, :2] - solved[state, :2], axis=1)
        keep = gap <= reject_sigmas * fix_noise.position_m
        if not keep.all():
            graph = _build(session, events, fixes, keep=keep, fix_noise=fix_noise)
            values = solve(graph.graph, values)
            solved = poses_of(values, graph.count)
    return WalkRun("batch", times, solved[:, :3], time.perf_counter() - t0)


def run_online(session: WalkingSession, events: list[Event], fixes: FloatArray, config: OnlineConfig = ONLINE) -> WalkRun:
    """iSAM2 after every step; the position kept for a step is the estimate when it was added (causal)."""
    t0 = time.perf_counter()
    xyz = np.zeros((len(events) + 1, 3))
    xyz[0] = session.start_pose[:3]
    solve = causal_online(config)

    def on_state(graph: PlanarGraph, i: int) -> None:
        xyz[i] = solve(graph).translation()

    graph = _build(session, events, fixes, on_state)
    return WalkRun("online", np.array(graph.keyframe_t), xyz, time.perf_counter() - t0)


def run_ekf(session: WalkingSession, events: list[Event], fixes: FloatArray, gate_prob: float = 0.999) -> WalkRun:
    """The paper's Kalman framework: x, y, z, heading predicted by each step, corrected by fixes
    (an innovation gate at ``gate_prob`` turns away fixes too far from the prediction) and by the
    elevator position."""
    t0 = time.perf_counter()
    x = np.array(session.start_pose, dtype=float)
    P = np.diag(np.square([START_SIGMAS[3], START_SIGMAS[4], START_SIGMAS[5], START_SIGMAS[2]]))
    times = np.array([float(session.t[0])] + [e.t for e in events])
    schedule = _fix_schedule(session, times)
    R_fix = np.diag(np.square([FIX_NOISE.position_m, FIX_NOISE.position_m, FIX_NOISE.height_m, FIX_NOISE.heading_rad]))
    gate4 = chi2.ppf(gate_prob, 4)
    out = np.zeros((len(events) + 1, 3))
    out[0] = x[:3]

    def update(z: FloatArray, H: FloatArray, R: FloatArray, gate: float | None, angle_row: int | None = None) -> None:
        nonlocal x, P
        y = z - H @ x
        if angle_row is not None:
            y[angle_row] = math.remainder(y[angle_row], 2 * math.pi)
        S = H @ P @ H.T + R
        if gate is not None and float(y @ np.linalg.solve(S, y)) > gate:
            return
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ y
        P = (np.eye(4) - K @ H) @ P

    elevator_H = np.eye(4)[:2]
    R_elev = np.diag(np.square(ELEVATOR_SIGMAS_M[:2]))
    for i, e in enumerate(events, start=1):
        if e.ride:
            update(np.array(session.building.elevator_xy_m), elevator_H, R_elev, None)
        m, yaw = e.motion, x[3]
        c, s = math.cos(yaw), math.sin(yaw)
        x = x + np.array([c * m.forward_m - s * m.left_m, s * m.forward_m + c * m.left_m, m.up_m, m.dyaw_rad])
        F = np.eye(4)
        F[0, 3] = -s * m.forward_m - c * m.left_m
        F[1, 3] = c * m.forward_m - s * m.left_m
        sig = odometry_sigmas(m, e.noise)
        G = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        P = F @ P @ F.T + G @ np.diag(np.square([sig[3], sig[4], sig[5], sig[2]])) @ G.T
        if e.ride:
            update(np.array(session.building.elevator_xy_m), elevator_H, R_elev, None)
        for k in schedule[i]:
            update(fixes[k], np.eye(4), R_fix, gate4, angle_row=3)
        out[i] = x[:3]
    return WalkRun("ekf", times, out, time.perf_counter() - t0)


def score(run: WalkRun, session: WalkingSession) -> dict[str, float]:
    """3D position RMSE over the run's states and the error at the end (``metrics.track_errors``)."""
    return track_errors(run.t, run.xyz, session.t, session.truth_xyz_m)


def analyse(session: WalkingSession, speed: SpeedModel, config: PdrConfig = WAIST, causal: bool = False,
            front: tuple[FloatArray, list[Cycle]] | None = None) -> tuple[list[Cycle], list[Ride], list[Event]]:
    """Steps (activity by the waist classifier, ``frontends.activity``; ``causal``: from the steps up to it), rides, their
    odometry. ``front``: the gravity filter's output (a per-sample loop) and its ``detect_cycles`` when the caller has them."""
    gravity, found = front or front_end(session.t, session.accel_m_s2, session.gyro_rad_s, config)
    rides = detect_rides(session.t, session.accel_m_s2, session.gyro_rad_s, found, config, gravity)
    cycles = with_activity(session.t, session.accel_m_s2, session.gyro_rad_s, gravity, found, causal=causal)
    return cycles, rides, events_from(cycles, rides, speed, session.building)


#: Start sigmas when the start is found from the ranges (``graphs.planar.start_from_ranges``): within ~1 m and
#: ~7 deg on the Plaza runs, refined by the rest of the run.
RANGE_START_SIGMAS = np.array([1e-3, 1e-3, math.radians(10.0), 2.0, 2.0, 1e-3])
#: Seconds of odometry and ranges a start is found from when the session gives none.
RANGE_START_WINDOW_S = 60.0


def _beacons_of(session: Session, where: str) -> BeaconRanges | None:
    """The session's ranges to known beacons (one ``beacon_ranges`` stream at most), if any."""
    streams = session.streams_of_kind("beacon_ranges")
    if len(streams) > 1:
        raise SessionError(f"{where}: one beacon_ranges stream at most (have: {', '.join(b.name for b in streams)})")
    try:
        return beacon_ranges_from(streams[0], where) if streams else None
    except ValueError as err:
        raise SessionError(str(err)) from None


def vehicle_from_session(session: Session) -> tuple[WalkingSession, list[Event]]:
    """A session driven by wheel odometry (kind ``wheel_odometry``: row i = the motion from row i-1's time to
    row i's; the first row is the start) instead of a waist IMU; ``start_pose`` optional when the session
    has beacon ranges (then found from the first minute of odometry and ranges, never from the truth)."""
    where = session.where
    streams = session.streams_of_kind("wheel_odometry")
    if len(streams) != 1:
        raise SessionError(f"{where}: a session without a waist gyro needs one wheel_odometry stream (have {len(streams)})")
    odo = streams[0]
    noise = OdometryNoise(**{k: float(odo.meta[k]) for k in ("distance_frac", "lateral_frac", "floor_m", "yaw_frac") if k in odo.meta},
                          **({"yaw_rad": math.radians(float(odo.meta["yaw_sigma_deg"]))} if "yaw_sigma_deg" in odo.meta else {}))
    events = [Event(float(t), PlanarMotion(forward_m=float(d), dyaw_rad=float(h)), noise, False) for t, (d, h) in zip(odo.t[1:], odo.values[1:], strict=True)]
    beacons = _beacons_of(session, where)
    header = session.meta.get("session", {})
    truth = np.full((len(odo), 3), np.nan)
    if session.truth is not None and session.truth.kind == "position" and len(session.truth) == len(odo):
        truth = session.truth.values.copy()
    if "start_pose" in header:
        start, sigmas = np.asarray(header["start_pose"], dtype=float), None
    elif beacons is not None:
        pose = start_from_ranges(odo.t, [e.motion for e in events], noise, beacons.t, beacons.beacon, beacons.range_m, beacons.beacons_m,
                                 beacons.noise, window_s=RANGE_START_WINDOW_S)
        start, sigmas = np.r_[pose.translation(), pose.rotation().yaw()], RANGE_START_SIGMAS
    else:
        raise SessionError(f"{where}: [session] needs start_pose = [x, y, z, yaw] (no beacon ranges to find the start from)")
    empty = np.zeros((len(odo), 3))
    walk = WalkingSession(t=odo.t, accel_m_s2=empty, gyro_rad_s=empty, fixes=Fixes(np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4)), np.zeros(0, dtype=bool)),
                          truth_xyz_m=truth, truth_yaw_rad=np.full(len(odo), np.nan), step_t=np.zeros(0), step_activity=(), rides=np.zeros((0, 3)),
                          building=Building(), start_pose=start, beacons=beacons, start_sigmas=sigmas)
    return walk, events


def from_session(session: Session) -> tuple[WalkingSession, SpeedModel]:
    """A walking session directory's content: waist ``gyro`` and ``accel`` sampled together, optional
    ``fixes`` (kind ``pose``), ``[building]`` (the map), ``start_pose`` in ``[session]``, the person's
    ``[speed_model]``; the truth (waist position) is optional. Without a ``start_pose`` and without fixes or beacons (a
    waist recording alone: UCI HAPT, a user's own) the walk starts at x, y, z, yaw = 0, said in a warning: the
    trajectory is then relative to where it began; fixes or beacons are in a map frame, which needs the start in it."""
    where = session.where
    gyro, accel = session.synchronous("gyro", "accel")
    header, table = session.meta.get("session", {}), session.meta.get("building", {})
    if "start_pose" not in header:
        if "fixes" in session.streams or session.streams_of_kind("beacon_ranges"):
            raise SessionError(f"{where}: [session] needs start_pose = [x, y, z, yaw] (the known start, in the frame of its fixes "
                               "or beacons)")
        warnings.warn(f"{where}: no [session] start_pose: the walk starts at x, y, z, yaw = 0 (a trajectory relative to where it "
                      "began; declare start_pose for a map frame)", stacklevel=2)
        header = {**header, "start_pose": [0.0, 0.0, 0.0, 0.0]}
    try:
        fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items()}
        building = Building(**fields)
    except TypeError as err:
        raise SessionError(f"{where}: [building]: {err}") from None
    model = session.meta.get("speed_model", {})
    speed = SpeedModel(**model) if model else SpeedModel()
    if "fixes" in session.streams:
        f = session.stream("fixes")
        if f.kind != "pose":
            raise SessionError(f"{where}: stream 'fixes' must be of kind 'pose', not '{f.kind}'")
        fixes = Fixes(f.t, f.values, f.values, np.zeros(len(f), dtype=bool))
    else:
        fixes = Fixes(np.zeros(0), np.zeros((0, 4)), np.zeros((0, 4)), np.zeros(0, dtype=bool))
    truth = np.full((len(gyro), 3), np.nan)
    if session.truth is not None and session.truth.kind == "position" and len(session.truth) == len(gyro):
        truth = session.truth.values.copy()
    beacons = _beacons_of(session, where)
    walk = WalkingSession(t=gyro.t, accel_m_s2=accel.values, gyro_rad_s=gyro.values, fixes=fixes, truth_xyz_m=truth,
                          truth_yaw_rad=np.full(len(gyro), np.nan), step_t=np.zeros(0), step_activity=(), rides=np.zeros((0, 3)),
                          building=building, start_pose=np.asarray(header["start_pose"], dtype=float), beacons=beacons)
    return walk, speed
