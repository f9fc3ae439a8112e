"""A chain of level poses tied by odometry, with absolute fixes, map constraints and beacon ranges.

One builder serves the walker (steps, image fixes, elevator constraints) and the Plaza vehicle
(wheel odometry, biased beacon ranges), online and batch: ``graph``/``initial`` hold every factor
and guess for a batch solve, ``take()`` hands what was added since the last call (each factor
tagged with the oldest state it touches) to the re-anchoring iSAM2 solver
(``solvers.online.OnlineSmoother``), whose protocol this builder speaks. State ``i`` is the pose
after the ``i``-th increment (state 0 the start), at time ``keyframe_t[i]``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import gtsam
import numpy as np

from ..factors.odometry import FixNoise, OdometryNoise, PlanarMotion, fix_factor, odometry_factor, position_factor
from ..factors.ranging import RangeNoise, bias_prior, bias_walk, range_factor
from ..geometry import FloatArray
from .increment import GraphIncrement

if TYPE_CHECKING:
    from ..solvers.online import OnlineConfig


def X(i: int) -> int:
    """Pose key of state i."""
    return int(gtsam.symbol("x", i))


def B(beacon: int, serial: int) -> int:
    """Key of a beacon's ``serial``-th range-bias variable (beacon ids below 1000)."""
    return int(gtsam.symbol("b", serial * 1000 + beacon))


@dataclass(frozen=True)
class _BiasLink:
    """The newest bias variable of one beacon."""

    serial: int
    """Its number in the beacon's chain."""
    window: int
    """The window of states it covers."""
    last_use: int
    """The newest state a range tied to it."""


class PlanarGraph:
    """Accumulates the factors of a level-pose chain; see the module docstring."""

    def __init__(self, start: gtsam.Pose3, start_sigmas: FloatArray, start_t: float = 0.0, bias_window: int = 100) -> None:
        self.bias_window = bias_window
        """States per range-bias variable: a beacon's bias is a random-walk chain over windows."""
        self.graph = gtsam.NonlinearFactorGraph()
        """Every factor so far (batch)."""
        self.initial = gtsam.Values()
        """Every variable's initial guess (batch)."""
        self.keyframe_t: list[float] = [start_t]
        """Time of each state, seconds."""
        self.oldest_allowed_keyframe = 0
        """Set by the online solver: states older than this were marginalised."""
        self.latest = start
        """The newest state's current estimate (the online solver refreshes it); guesses compose on it."""
        self._increment = GraphIncrement()
        self._bias_link: dict[int, _BiasLink] = {}
        self._bias_estimate: dict[int, float] = {}
        self._add(0, gtsam.PriorFactorPose3(X(0), start, gtsam.noiseModel.Diagonal.Sigmas(np.asarray(start_sigmas, dtype=float))))
        self._insert(X(0), start)

    # --- what the online solver reads -------------------------------------------------------
    @property
    def started(self) -> bool:
        return True

    @property
    def latest_keyframe(self) -> int:
        return len(self.keyframe_t) - 1

    @property
    def count(self) -> int:
        """Number of states."""
        return len(self.keyframe_t)

    def take(self) -> GraphIncrement:
        out, self._increment = self._increment, GraphIncrement()
        return out

    def state_keys(self, k: int) -> tuple[int, int | None]:
        return X(k), None

    def read_latest(self, isam: gtsam.ISAM2, k: int) -> tuple[gtsam.Pose3, FloatArray]:
        return isam.calculateEstimatePose3(X(k)), np.zeros(3)

    def set_latest(self, world_T_body: gtsam.Pose3, bias: FloatArray) -> None:
        self.latest = world_T_body

    # --- factors ---------------------------------------------------------------------------------
    def _add(self, oldest: int, factor: gtsam.NonlinearFactor) -> None:
        if oldest < self.oldest_allowed_keyframe:
            raise ValueError(f"a factor on state {oldest} arrived after the online solver marginalised states before {self.oldest_allowed_keyframe}")
        self.graph.add(factor)
        self._increment.add(oldest, factor)

    def _insert(self, key: int, value: gtsam.Pose3 | FloatArray) -> None:
        if isinstance(value, gtsam.Pose3):
            self.initial.insert(key, value)
            self._increment.values.insert(key, value)
        else:
            self.initial.insert(key, np.asarray(value, dtype=float))
            self._increment.values.insert(key, np.asarray(value, dtype=float))

    def add_odometry(self, motion: PlanarMotion, noise: OdometryNoise, t: float) -> int:
        """A new state at time ``t`` after ``motion``; returns its index. Its guess composes the increment on ``latest``."""
        i = self.count
        if t < self.keyframe_t[-1]:
            raise ValueError(f"odometry at t={t:.3f} s goes back before the last state ({self.keyframe_t[-1]:.3f} s)")
        self._add(i - 1, odometry_factor(X(i - 1), X(i), motion, noise))
        self.latest = self.latest.compose(gtsam.Pose3(gtsam.Rot3.Yaw(motion.dyaw_rad), np.array([motion.forward_m, motion.left_m, motion.up_m])))
        self._insert(X(i), self.latest)
        self.keyframe_t.append(t)
        return i

    def add_fix(self, index: int, world_T_body: gtsam.Pose3, noise: FixNoise) -> None:
        """An absolute position + heading fix on state ``index`` (robust)."""
        self._add(index, fix_factor(X(index), world_T_body, noise))

    def add_position(self, index: int, world_t_body: FloatArray, sigmas_m: FloatArray) -> None:
        """A known position of state ``index`` (map constraint)."""
        self._add(index, position_factor(X(index), world_t_body, sigmas_m))

    def add_range(self, index: int, beacon: int, world_t_beacon: FloatArray, range_m: float, noise: RangeNoise) -> None:
        """A biased range from state ``index`` to a known beacon (beacon ids 0..999).

        A beacon's bias is a chain of variables, a new one per window of ``bias_window`` states,
        created on first use: from the prior for the beacon's first, else tied to the previous one
        by a random walk. Online, a beacon unheard for longer than the solver's window has had its
        bias marginalised away: the next variable starts from the last estimate with
        ``noise.reacquire_sigma_m``.
        """
        window = index // self.bias_window
        link = self._bias_link.get(beacon)
        if link is not None and window < link.window:
            raise ValueError(f"range on state {index} arrives after beacon {beacon}'s bias window {link.window} opened: add ranges in state order")
        alive = link is not None and link.last_use >= self.oldest_allowed_keyframe
        if link is None or window > link.window or not alive:
            serial = 0 if link is None else link.serial + 1
            key = B(beacon, serial)
            if link is None:
                self._add(index, bias_prior(key, noise))
                guess = noise.bias_prior_m
            elif alive:
                self._add(index, bias_walk(B(beacon, link.serial), key, window - link.window, noise))
                guess = self._bias_estimate.get(beacon, float(self.initial.atVector(B(beacon, link.serial))[0]))
            else:
                guess = self._bias_estimate.get(beacon, noise.bias_prior_m)
                self._add(index, bias_prior(key, replace(noise, bias_prior_m=guess, bias_sigma_m=noise.reacquire_sigma_m)))
            self._insert(key, np.array([guess]))
            link = _BiasLink(serial=serial, window=window, last_use=index)
        self._bias_link[beacon] = replace(link, last_use=max(link.last_use, index))
        self._add(index, range_factor(X(index), B(beacon, link.serial), world_t_beacon, range_m, noise))

    def feedback(self, read_vector: Callable[[int], FloatArray]) -> None:
        """Called by the online solver after each update: remember the live bias estimates."""
        for beacon, link in self._bias_link.items():
            if link.last_use >= self.oldest_allowed_keyframe:
                self._bias_estimate[beacon] = float(read_vector(B(beacon, link.serial))[0])

def poses_of(values: gtsam.Values, count: int) -> FloatArray:
    """(count, 4) rows x, y, z, yaw of states 0..count-1."""
    out = np.empty((count, 4))
    for i in range(count):
        pose = values.atPose3(X(i))
        out[i, :3] = pose.translation()
        out[i, 3] = pose.rotation().yaw()
    return out


def range_schedule(state_t: FloatArray, range_t: FloatArray) -> tuple[np.ndarray, np.ndarray]:
    """For each range: the state it attaches to (nearest in time) and the first state whose update may add
    it (the first at or after the range: causal)."""
    first = np.clip(np.searchsorted(state_t, range_t, side="left"), 1, len(state_t) - 1)
    earlier = np.abs(range_t - state_t[first - 1]) < np.abs(state_t[first] - range_t)
    return np.where(earlier, first - 1, first), first


def causal_online(config: OnlineConfig) -> Callable[[PlanarGraph], gtsam.Pose3]:
    """An ``on_state`` helper for the builders: the re-anchoring iSAM2 starts on the first call and is
    updated on every call; each call returns the newest pose as solved then (the causal estimate)."""
    from ..solvers.online import OnlineSmoother  # here: solvers.online imports graphs

    solver: OnlineSmoother | None = None

    def update(graph: PlanarGraph) -> gtsam.Pose3:
        nonlocal solver
        if solver is None:
            solver = OnlineSmoother(graph, config)
        solver.update()
        return graph.latest

    return update


def start_from_ranges(
    state_t: FloatArray, motions: list[PlanarMotion], noise: OdometryNoise, ranges_t: FloatArray, beacon: np.ndarray, range_m: FloatArray,
    beacons_m: FloatArray, range_noise: RangeNoise, window_s: float = 60.0, headings: int = 8,
) -> gtsam.Pose3:
    """The start pose from the first ``window_s`` of odometry and ranges to known beacons, no truth needed.

    The start position is first trilaterated from the window's ranges (the mover taken as still: a
    coarse guess), then the window's graph (odometry, ranges with their biases) is solved from
    ``headings`` evenly spread start headings with a loose start prior; the solution with the lowest
    error gives the start. Ranges fix where the track is; the odometry's shape fixes its heading.
    """
    from ..solvers.batch import solve_python_loop  # here: solvers import graphs

    end = int(np.searchsorted(state_t, state_t[0] + window_s, side="right"))
    end = max(end, min(len(state_t), 2))
    inside = ranges_t <= state_t[end - 1]
    if inside.sum() < 3:
        raise ValueError(f"fewer than 3 beacon ranges in the first {window_s:g} s: the start cannot be found from the ranges")
    position = _trilaterate(beacons_m[beacon[inside]], range_m[inside])
    attach, _ = range_schedule(state_t[:end], ranges_t[inside])
    loose = np.array([1e-3, 1e-3, 3.0, 30.0, 30.0, 1e-3])  # heading and position free, the state stays level
    best: tuple[float, gtsam.Pose3] | None = None
    for heading in np.linspace(-np.pi, np.pi, headings, endpoint=False):
        start = gtsam.Pose3(gtsam.Rot3.Yaw(float(heading)), np.array([position[0], position[1], 0.0]))
        graph = PlanarGraph(start, loose, start_t=float(state_t[0]))
        for i, motion in enumerate(motions[: end - 1], start=1):
            graph.add_odometry(motion, noise, float(state_t[i]))
        for n, state in zip(np.flatnonzero(inside), attach, strict=True):
            graph.add_range(int(state), int(beacon[n]), beacons_m[beacon[n]], float(range_m[n]), range_noise)
        result = solve_python_loop(graph.graph, graph.initial)
        if best is None or result.final_error < best[0]:
            best = (result.final_error, result.values.atPose3(X(0)))
    assert best is not None
    return best[1]


def _trilaterate(beacons_m: FloatArray, range_m: FloatArray) -> FloatArray:
    """Least-squares horizontal position from ranges to known beacons (linearised against the first)."""
    b = beacons_m[:, :2]
    a = 2.0 * (b[1:] - b[0])
    rhs = range_m[0] ** 2 - range_m[1:] ** 2 + np.sum(b[1:] ** 2, axis=1) - np.sum(b[0] ** 2)
    if len(a) < 2 or np.linalg.matrix_rank(a) < 2:
        return b.mean(axis=0)
    return np.linalg.lstsq(a, rhs, rcond=None)[0]
