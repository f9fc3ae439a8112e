"""Live in the lab: streams in over the Lab Streaming Layer, the causal estimate out, the session recorded.

``run_live`` resolves one LSL stream per declared input (``NAME=lsl:STREAM``), feeds every sample to the
same online solver as replay, as it arrives, and publishes the estimate as an LSL stream. Sample times
are LSL time stamps (the sender's capture times) moved onto this machine's clock with a line through the
time corrections of the sender's host (``ClockMap``), so a tracker that stamps its samples when they were
taken arrives "late" exactly as in a recorded session. Systems:

* ``head``: inputs ``gyro`` (3 channels, rad/s), ``tracker`` (4: quaternion wxyz), optional ``accel``
  (3, m/s^2); one estimate per gyro sample.
* ``attitude9``: inputs ``imu`` (9 channels: gyro rad/s, accelerometer m/s^2, magnetometer, sampled
  together), optional ``tracker`` (4); one estimate per keyframe (the 9-axis graph updates per keyframe).

* ``gaze``: inputs ``imu`` (9 channels, as attitude9), ``gaze`` (2: the eye tracker's pixel u right, v up from
  the image centre), optional ``tracker`` (4); ``--session-toml`` must give the wall (``wall_m``) or the
  fixation depth (``target_depth_m``) in ``[session]`` and the scene camera on the gaze stream; one estimate
  per gaze sample, right after the iSAM2 update that added it (the replay's).

The output stream of head and attitude9 (type ``Orientation``) has channels ``qw qx qy qz`` and the attitude
covariance's 9 entries (rad^2, NaN when the solver does not compute it); gaze's (type ``Gaze``) has the fixated
point ``gaze_x_m gaze_y_m gaze_z_m`` (world frame) and the head attitude ``qw qx qy qz`` at the gaze sample.
Each estimate is stamped with the sample time it describes; the stream's nominal rate is the gyro's (head), the
gaze input's (gaze) or irregular (attitude9, one per keyframe).
``--record DIR`` writes what was received as a session directory (and ``DIR.xdf`` beside it), so ``fusegraph run DIR --solver batch``
smooths the live run afterwards.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .session import KIND_COLUMNS, Session, SessionError, Stream

#: What each system reads live: input name -> (stream kind, channels, required).
LIVE_INPUTS: dict[str, dict[str, tuple[str, int, bool]]] = {
    "head": {"gyro": ("gyro", 3, True), "tracker": ("attitude", 4, True), "accel": ("accel", 3, False)},
    "attitude9": {"imu": ("imu9", 9, True), "tracker": ("attitude", 4, False)},
    "gaze": {"imu": ("imu9", 9, True), "gaze": ("pixel", 2, True), "tracker": ("attitude", 4, False)},
}
OUTPUT_CHANNELS = ("qw", "qx", "qy", "qz", *(f"cov{i}{j}" for i in range(3) for j in range(3)))
"""Channels of the published attitude estimate (head, attitude9)."""
GAZE_CHANNELS = ("gaze_x_m", "gaze_y_m", "gaze_z_m", "qw", "qx", "qy", "qz")
"""Channels of the published gaze estimate."""


@dataclass
class LiveStats:
    """What a live run did."""

    received: dict[str, int] = field(default_factory=dict)
    """Samples received per input."""
    rejected: int = 0
    """Samples the solver refused (not finite, implausible, out of order)."""
    published: int = 0
    """Estimates pushed to the output stream."""
    seconds: float = 0.0
    """Wall time of the run."""
    solve_s: float = 0.0
    """Time inside the solver."""
    too_late: int = 0
    """Samples that came after the online solver's window had passed their time: no factor or no estimate."""
    behind: int = 0
    """Samples that arrived after a sample due later (sample time + declared latency) had been used: the live estimate
    then parts from the replay's, which takes every sample in the order it was due."""


class ClockMap:
    """One stream's time stamps moved onto this machine's clock: stamp + offset, the offset a line fitted to LSL's
    time-correction estimates over the last ``window_s`` (a mean until they span ``fit_span_s``).

    LSL re-estimates a connection's clock offset every few seconds, each time with noise (+-20 us on the loopback,
    more across a network). Applied as they come (LSL's ``proc_clocksync``), each new estimate steps the stamps: the
    interval the gyro integrates over is then off by that step and the estimate parts from the replay's. A true offset
    changes slowly (two machines' clocks drift apart by tens of ppm), which the line follows.
    """

    def __init__(self, correction: Callable[[float], float], now: float, first_timeout_s: float = 10.0, window_s: float = 60.0,
                 fit_span_s: float = 10.0) -> None:
        self._correction = correction
        """LSL's estimate of the offset, given a timeout in seconds (an inlet's ``time_correction``)."""
        self.window_s = window_s
        """How far back the estimates are fitted, seconds."""
        self.fit_span_s = fit_span_s
        """The shortest span of estimates a line is fitted over; a mean before, seconds."""
        self._readings: list[tuple[float, float]] = [(now, float(correction(first_timeout_s)))]  # the first one blocks
        self._offset, self._slope, self._t_ref = self._readings[0][1], 0.0, now

    def refresh(self, now: float) -> None:
        """Read LSL's newest estimate (instant after the first; a new one every few seconds) and refit."""
        try:
            value = float(self._correction(0.005))
        except (TimeoutError, RuntimeError):  # the connection is re-syncing or lost: keep the line, never stall the loop
            return
        if value == self._readings[-1][1]:
            return  # not re-estimated since
        self._readings.append((now, value))
        while self._readings[0][0] < now - self.window_s:
            self._readings.pop(0)
        t = np.array([r[0] for r in self._readings])
        offset = np.array([r[1] for r in self._readings])
        self._t_ref = float(t[-1])
        if len(t) >= 3 and t[-1] - t[0] >= self.fit_span_s:
            self._slope, self._offset = (float(v) for v in np.polyfit(t - self._t_ref, offset, 1))
        else:
            self._slope, self._offset = 0.0, float(offset.mean())

    def __call__(self, stamp: float) -> float:
        """The stamp on this machine's clock."""
        return stamp + self._offset + self._slope * (stamp - self._t_ref)


def _require_pylsl() -> Any:
    try:
        import pylsl
    except (ImportError, RuntimeError) as err:  # pylsl raises RuntimeError when liblsl cannot be loaded
        raise SessionError(f"the Lab Streaming Layer is not available here ({err}); install the 'pylsl' package (its wheel ships liblsl)") from None
    return pylsl


def parse_inputs(system: str, specs: list[str]) -> dict[str, str]:
    """``NAME=lsl:STREAM`` items -> {input name: LSL stream name}, checked against the system's inputs."""
    if system not in LIVE_INPUTS:
        raise SessionError(f"live: {system} has no live mode yet (have: {', '.join(LIVE_INPUTS)})")
    known = LIVE_INPUTS[system]
    out: dict[str, str] = {}
    for spec in specs:
        name, _, source = spec.partition("=")
        if not source.startswith("lsl:") or not name:
            raise SessionError(f"--in {spec!r}: write NAME=lsl:STREAM, e.g. gyro=lsl:HMD_gyro")
        if name not in known:
            raise SessionError(f"--in {spec!r}: {system} reads {', '.join(known)}")
        out[name] = source[4:]
    missing = [n for n, (_, _, required) in known.items() if required and n not in out]
    if missing:
        raise SessionError(f"live {system}: --in needed for {', '.join(missing)}")
    return out


def declared_session(system: str, toml_path: Path | None) -> Session:
    """The sensors' declarations (noise, rates, latency) from a session.toml, without any samples."""
    import tomllib

    spec: dict[str, Any] = {"session": {"system": system}, "streams": {}}
    if toml_path is not None:
        try:
            spec = tomllib.loads(Path(toml_path).read_text())
        except (OSError, tomllib.TOMLDecodeError) as err:
            raise SessionError(f"{toml_path}: {err}") from None
    streams = {}
    for name, table in spec.get("streams", {}).items():
        kind = table.get("kind", name)
        meta = {k: v for k, v in table.items() if k not in ("kind", "file", "latency_s")}
        streams[name] = Stream(name, kind, np.zeros(0), np.zeros((0, len(KIND_COLUMNS.get(kind, ())))), KIND_COLUMNS.get(kind, ()),
                               float(table.get("latency_s", 0.0)), meta)
    for name, (kind, _, _) in LIVE_INPUTS[system].items():
        if kind != "imu9" and not any(s.kind == kind for s in streams.values()):
            streams[name] = Stream(name, kind, np.zeros(0), np.zeros((0, len(KIND_COLUMNS[kind]))), KIND_COLUMNS[kind], 0.0, {})
    return Session(system, streams, None, {k: v for k, v in spec.items() if k not in ("streams", "truth")})


def checked_sample(name: str, t: float, values: np.ndarray) -> np.ndarray:
    """A sample as the graph takes it (a tracker quaternion normalised); ValueError when not finite or a tracker
    quaternion's norm is not 1 within 1 % (the head tracker's own checks are ``OnlineHeadTracker``'s)."""
    if not np.all(np.isfinite(values)) or not np.isfinite(t):
        raise ValueError(f"{name} sample at t = {t!r}: not finite")
    if name != "tracker":
        return values
    norm = float(np.linalg.norm(values))
    if abs(norm - 1.0) > 0.01:
        raise ValueError(f"tracker sample at t = {t:.6f} s: quaternion norm {norm:.4g} is not 1")
    return values / norm


class _HeadSolver:
    """The head system's live solver: ``OnlineHeadTracker`` (it refuses bad samples and carries on)."""

    channels, stream_type, rate_of = OUTPUT_CHANNELS, "Orientation", "gyro"  # rate_of: the input whose rate the output has

    def __init__(self, declared: Session, estimate_first: bool = False) -> None:
        from .graphs.head import head_model_for
        from .systems.head import OnlineHeadTracker, carried_over_delay, gyro_delay_s

        self.tracker = OnlineHeadTracker(head_model_for(declared), estimate_first=estimate_first)
        self.gyro_delay_s = gyro_delay_s(declared)  # samples go in at their true time, estimates out at their stamps (as replay)
        self._carried_over_delay = carried_over_delay  # imported once, not per sample

    def push(self, name: str, t: float, values: np.ndarray) -> list[tuple[float, list[float]]]:
        if name == "tracker":
            self.tracker.add_tracker(t, values)
            return []
        if name == "accel":
            self.tracker.add_accel(t, values)
            return []
        now = self.tracker.add_gyro(t - self.gyro_delay_s, values)
        if now is None:
            return []
        if self.gyro_delay_s == 0.0:
            return [(now.t, [*now.quat_wxyz, *now.cov.reshape(-1)])]
        return [(t, [*self._carried_over_delay(now.quat_wxyz, values, self.gyro_delay_s), *now.cov.reshape(-1)])]

    def maintain(self) -> None:
        self.tracker.maintain()

    def too_late(self) -> int:
        return len(self.tracker.builder.too_late)


class _Attitude9Solver:
    """The 9-axis graph fed sample by sample; an estimate per keyframe, right after its iSAM2 update."""

    channels, stream_type, rate_of = OUTPUT_CHANNELS, "Orientation", None  # one per keyframe: declared irregular

    def __init__(self, declared: Session) -> None:
        from .graphs.attitude9 import Attitude9Builder
        from .solvers.online import OnlineSmoother
        from .systems.attitude9 import ONLINE_CONFIG, attitude_tracker, model_for

        self.builder = Attitude9Builder(model_for(declared))
        self.solver = OnlineSmoother(self.builder, ONLINE_CONFIG)
        self.last_t = -np.inf
        declared_tracker = attitude_tracker(declared)  # the declared noise, read as replay reads it
        self.tracker_sigma_rad = declared_tracker.sigma_rad if declared_tracker is not None else float(np.deg2rad(0.4))

    def push(self, name: str, t: float, values: np.ndarray) -> list[tuple[float, list[float]]]:
        from .geometry import rot3_from_quat_wxyz

        values = checked_sample(name, t, values)
        if name == "tracker":
            self.builder.add_attitude(t, rot3_from_quat_wxyz(values), self.tracker_sigma_rad)
            return []
        if t <= self.last_t:
            raise ValueError(f"imu sample at t = {t:.6f} s does not follow the previous one ({self.last_t:.6f} s)")
        keyframes = len(self.builder.keyframe_t)
        self.builder.add_samples(np.array([t]), values[None, 0:3], values[None, 3:6], values[None, 6:9])
        self.last_t = t
        if len(self.builder.keyframe_t) == keyframes:
            return []
        self.solver.update()
        k = self.builder.latest_keyframe
        return [(self.builder.keyframe_t[k], [*self.builder.posterior_quat[k], *[np.nan] * 9])]

    def maintain(self) -> None:
        self.solver.maintain()  # its re-anchorings run inside update (the replay's order): nothing is deferred

    def too_late(self) -> int:
        return int(self.builder.tracker_dropped)


class _Growing:
    """Rows appended one at a time, read as one array (a view; capacity doubles, so appending stays O(1))."""

    def __init__(self, width: int) -> None:
        self._rows = np.empty((64, width))
        self.n = 0

    def append(self, row: np.ndarray | float) -> None:
        if self.n == len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        self._rows[self.n] = row
        self.n += 1

    @property
    def view(self) -> np.ndarray:
        return self._rows[: self.n]


class _LiveGazeData:
    """A gaze session whose arrays grow as the samples arrive (what ``GazeGraph`` reads)."""

    def __init__(self, config: Any, tracker_latency_s: float, tracker_sigma_rad: float) -> None:
        self.config = config
        self._imu, self._imu_t = _Growing(9), _Growing(1)
        self._gaze, self._gaze_t = _Growing(2), _Growing(1)
        self._tracker, self._tracker_t = _Growing(4), _Growing(1)
        self._tracker_latency_s, self._tracker_sigma_rad = tracker_latency_s, tracker_sigma_rad
        self._inputs = {"imu": (self._imu_t, self._imu), "gaze": (self._gaze_t, self._gaze), "tracker": (self._tracker_t, self._tracker)}

    t = property(lambda self: self._imu_t.view[:, 0])
    gyro_rad_s = property(lambda self: self._imu.view[:, 0:3])
    accel_m_s2 = property(lambda self: self._imu.view[:, 3:6])
    mag = property(lambda self: self._imu.view[:, 6:9])
    tracker_t = property(lambda self: self._gaze_t.view[:, 0])
    gaze_px = property(lambda self: self._gaze.view)

    @property
    def head_tracker(self) -> Any:
        from .factors.attitude import AttitudeTrack

        if not self._tracker.n:
            return None
        return AttitudeTrack(self._tracker_t.view[:, 0], self._tracker_latency_s, self._tracker.view, self._tracker_sigma_rad)

    def add(self, name: str, t: float, values: np.ndarray) -> None:
        """A sample of input ``name`` (imu, gaze, tracker) at ``t``; refused (ValueError) unless after that input's last."""
        times, rows = self._inputs[name]
        if times.n and t <= times.view[-1, 0]:
            raise ValueError(f"{name} sample at t = {t:.6f} s does not follow the previous one ({times.view[-1, 0]:.6f} s)")
        times.append(t)
        rows.append(values)


class _GazeSolver:
    """The gaze graph fed as samples arrive: the IMU in blocks of one keyframe's samples and iSAM2 after each, as the
    replay (``systems.gaze.run_online``) runs it; an estimate per gaze sample right after the update that added it."""

    channels, stream_type, rate_of = GAZE_CHANNELS, "Gaze", "gaze"

    def __init__(self, declared: Session) -> None:
        from .graphs.attitude9 import X
        from .records import GazeScenarioConfig
        from .solvers.online import OnlineSmoother
        from .systems.attitude9 import attitude_tracker
        from .systems.gaze import NEEDS_WALL, G, GazeGraph, block_size, model_for

        self._keys = (G, X)  # imported once, not per sample

        header = declared.meta.get("session", {})
        if "wall_m" not in header and "target_depth_m" not in header:
            raise SessionError(f"live gaze: --session-toml {NEEDS_WALL}")
        gaze = next(s for s in declared.streams.values() if s.kind == "pixel")
        tracker = attitude_tracker(declared)  # the declared noise and latency, read as replay reads them
        self.data = _LiveGazeData(GazeScenarioConfig.declared(header, gaze.meta, float("nan")), tracker.latency_s if tracker else 0.0,
                                  tracker.sigma_rad if tracker else float(np.deg2rad(0.4)))
        self.model = model_for(declared, "online")  # as the replay: the declared head motion and use_mag
        self.graph = GazeGraph(self.data, self.model)
        self.solver = OnlineSmoother(self.graph.builder, self.model.online)
        rate = next((s.meta.get("rate_hz") for s in declared.streams.values() if s.kind == "gyro" and "rate_hz" in s.meta), None)
        self._block_size = block_size  # imported once, not per sample
        self.block = None if rate is None else block_size(self.data, self.model, float(rate))
        self.pushed = 0

    def push(self, name: str, t: float, values: np.ndarray) -> list[tuple[float, list[float]]]:
        G, X = self._keys
        self.data.add(name, t, checked_sample(name, t, values))
        n = len(self.data.t)
        if name != "imu":
            return []
        if self.block is None:  # no rate declared: the replay's block from the first samples' spacing
            if n < 11:
                return []
            self.block = self._block_size(self.data, self.model)
        if n - self.pushed < self.block:
            return []
        added = self.graph.push(self.pushed, self.pushed + self.block)
        self.pushed += self.block
        if not self.solver.update():
            return []
        isam, builder = self.solver.isam, self.graph.builder
        k = builder.latest_keyframe
        if builder.posterior_gyro_bias:
            self.graph.gyro_bias = builder.posterior_gyro_bias[k]
        points: dict[int, np.ndarray] = {}
        rotations: dict[int, Any] = {}
        out = []
        for j in added:
            kj = int(self.graph.sample_keyframe[j])
            if kj < 0:
                continue  # before the first keyframe: no factor, no estimate (as the replay)
            if kj < builder.oldest_allowed_keyframe:
                self.graph.too_late += 1  # a late sample whose keyframe this update's re-anchoring marginalised
                continue
            if kj not in points:
                points[kj] = isam.calculateEstimatePoint3(G(kj))
                rotations[kj] = isam.calculateEstimatePose3(X(kj)).rotation()
            attitude = self.graph.sample_attitude(rotations[kj], j)
            point = self.graph.own_points(points[kj][None], attitude[None], np.array([j]))[0]  # as the replay
            out.append((float(self.data.tracker_t[j]), [*point, *attitude]))
        return out

    def maintain(self) -> None:
        self.solver.maintain()

    def too_late(self) -> int:
        return self.graph.too_late + int(self.graph.builder.tracker_dropped)


SOLVERS: dict[str, Callable[..., Any]] = {"head": _HeadSolver, "attitude9": _Attitude9Solver, "gaze": _GazeSolver}


def run_live(
    system: str,
    inputs: dict[str, str],
    out_name: str,
    declared: Session,
    duration_s: float | None = None,
    record: Path | None = None,
    resolve_timeout_s: float = 10.0,
    should_stop: Callable[[], bool] | None = None,
    on_ready: Callable[[], None] | None = None,
    estimate_first: bool = False,
) -> LiveStats:
    """Read the inputs, publish estimates, until ``duration_s`` passes, ``should_stop()`` or Ctrl-C.

    Each input travels on its own connection, so a tracker sample due at the same instant as a gyro sample (sample time
    + declared latency) may reach us just after it; the estimate for that gyro sample then lacks it, where the replay
    has it (counted in ``LiveStats.behind``). Waiting for it would cost that latency on every dropped sample.

    ``estimate_first`` (head): publish each gyro sample's estimate before the iSAM2 update it makes due, which then
    runs before the next sample is read (``OnlineHeadTracker``); no sample's latency holds an update."""
    if estimate_first and system != "head":
        raise SessionError(f"live {system}: --estimate-first is for head (the others publish what an update gives)")
    pylsl = _require_pylsl()
    spec = LIVE_INPUTS[system]
    # the solver first: what the declarations lack (gaze's wall) is said before any stream is waited for
    solver = SOLVERS[system](declared, estimate_first=True) if estimate_first else SOLVERS[system](declared)
    inlets = {}
    clocks: dict[str, ClockMap] = {}
    host_clocks: dict[str, ClockMap] = {}
    rates: dict[str, float] = {}
    for name, stream_name in inputs.items():
        found = pylsl.resolve_byprop("name", stream_name, 1, resolve_timeout_s)
        if not found:
            raise SessionError(f"--in {name}=lsl:{stream_name}: no LSL stream of that name answered within {resolve_timeout_s:g} s")
        channels = found[0].channel_count()
        if channels != spec[name][1]:
            raise SessionError(f"--in {name}=lsl:{stream_name}: {channels} channels, {system} {name} needs {spec[name][1]}")
        inlets[name] = pylsl.StreamInlet(found[0], max_buflen=10)
        inlets[name].open_stream(timeout=resolve_timeout_s)
        # one clock per sending host: its streams share one offset. Estimated per connection, the offsets differed by
        # ~20 us on the loopback and a tracker sample due with a gyro sample ranked after it on every tie
        host = found[0].hostname()
        if host not in host_clocks:
            # the first clock sync blocks: done before data flows; later ones return LSL's newest estimate at once
            host_clocks[host] = ClockMap(inlets[name].time_correction, pylsl.local_clock(), first_timeout_s=resolve_timeout_s)
        clocks[name] = host_clocks[host]
        rates[name] = float(found[0].nominal_srate())
    # the stream whose samples make the estimates (the gyro) is polled last: a sample of another stream due at the same
    # instant, sent first but on its own connection, is then more often in the same pile (the replay's order)
    driver = next(iter(spec))
    inlets = dict(sorted(inlets.items(), key=lambda item: item[0] == driver))
    rate = rates.get(solver.rate_of, 0.0) if solver.rate_of is not None else 0.0  # 0: LSL's irregular rate
    info = pylsl.StreamInfo(out_name, solver.stream_type, len(solver.channels), rate, pylsl.cf_double64, f"fusegraph-{system}-{out_name}")
    labels = info.desc().append_child("channels")
    for label in solver.channels:
        labels.append_child("channel").append_child_value("label", label)
    outlet = pylsl.StreamOutlet(info)
    stats = LiveStats(received=dict.fromkeys(inputs, 0))
    due = {name: declared.streams[name].latency_s if name in declared.streams else 0.0 for name in inputs}
    recorded: dict[str, list[tuple[float, np.ndarray]]] = {name: [] for name in inputs}
    transit: dict[str, list[float]] = {name: [] for name in inputs}  # arrival - sample time, s

    def arrival_order(t: float, name: str) -> tuple[int, bool]:
        # to the microsecond, as the replay ranks them: a tracker stamp plus its 0.1 s latency is not bit-equal to the gyro
        # stamp due at the same instant; at the same instant the other stream's sample goes first
        return round((t + due[name]) * 1e6), name == driver

    newest = (-(2**62), False)  # the latest arrival order used so far
    start = time.perf_counter()
    clock_checked = start
    if on_ready is not None:
        on_ready()
    try:
        while not (should_stop is not None and should_stop()) and (duration_s is None or time.perf_counter() - start < duration_s):
            got = []
            for name, inlet in inlets.items():
                chunk, stamps = inlet.pull_chunk(timeout=0.0)
                to_local = clocks[name]
                got += [(to_local(ts), name, np.asarray(sample, dtype=float)) for sample, ts in zip(chunk, stamps, strict=True)]
                if stamps and record is not None:
                    transit[name].append(pylsl.local_clock() - to_local(stamps[-1]))
            if time.perf_counter() - clock_checked > 1.0:  # LSL's newest offset estimates, once a second (instant)
                clock_checked = time.perf_counter()
                for clock in host_clocks.values():
                    clock.refresh(pylsl.local_clock())
            if not got:
                time.sleep(0.0002)
                continue
            # samples that piled up (the solver was busy) go in the order they were due to arrive, sample time plus
            # their stream's declared latency, a tracker sample before a gyro one due at the same instant: the
            # replay's order. By sample time alone a late tracker sample jumped ahead of gyro samples and the
            # estimate parted from the replay's for the rest of the run.
            for order, (t, name, values) in sorted(((arrival_order(t, name), (t, name, values)) for t, name, values in got), key=lambda row: row[0]):
                stats.received[name] += 1
                if order < newest:
                    stats.behind += 1
                newest = max(newest, order)
                if record is not None:
                    recorded[name].append((t, values))
                tick = time.perf_counter()
                try:
                    estimates = solver.push(name, t, values)
                except ValueError:
                    stats.rejected += 1
                    continue
                finally:
                    stats.solve_s += time.perf_counter() - tick
                for t_est, row in estimates:
                    outlet.push_sample(row, t_est)
                    stats.published += 1
            # the solver's housekeeping (a re-anchoring) once the pile's estimates are out, not before them
            tick = time.perf_counter()
            solver.maintain()
            stats.solve_s += time.perf_counter() - tick
    except KeyboardInterrupt:
        pass
    stats.seconds = time.perf_counter() - start
    stats.too_late = solver.too_late()
    if record is not None:
        reference = float(np.median(transit[next(iter(inputs))])) if transit[next(iter(inputs))] else 0.0
        lateness = {n: max(0.0, float(np.median(v)) - reference) for n, v in transit.items() if v}
        save_recording(system, declared, recorded, record, lateness)
    return stats


def save_recording(system: str, declared: Session, recorded: dict[str, list[tuple[float, np.ndarray]]], directory: Path,
                   lateness_s: dict[str, float] | None = None) -> Path:
    """What a live run received, as a session directory (time-sorted; repeated stamps kept once). A stream's
    ``latency_s`` is the declared one, else how much later than the first input its samples arrived (median)."""
    from .session import save_session

    streams: dict[str, Stream] = {}

    def table(rows: list[tuple[float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
        rows = sorted(rows, key=lambda r: r[0])
        t = np.array([r[0] for r in rows])
        keep = np.r_[True, np.diff(t) > 0] if len(t) else np.zeros(0, bool)
        return t[keep], np.array([r[1] for r in rows])[keep]

    for name, rows in recorded.items():
        if not rows:
            continue
        t, values = table(rows)
        if name == "imu":
            for part, columns in (("gyro", slice(0, 3)), ("accel", slice(3, 6)), ("mag", slice(6, 9))):
                meta = dict(declared.streams[part].meta) if part in declared.streams else {}
                streams[part] = Stream(part, part, t, values[:, columns], KIND_COLUMNS[part], 0.0, meta)
            continue
        kind = LIVE_INPUTS[system][name][0]
        source = declared.streams.get(name) or next((s for s in declared.streams.values() if s.kind == kind), None)
        latency = source.latency_s if source is not None and source.latency_s > 0 else (lateness_s or {}).get(name, 0.0)
        streams[name] = Stream(name, kind, t, values, KIND_COLUMNS[kind], latency, {} if source is None else dict(source.meta))
    meta = {"session": {**declared.meta.get("session", {}), "system": system, "description": "recorded live over LSL by fusegraph live"}}
    session = Session(system, streams, None, meta)
    written = save_session(session, directory)
    from .datasets.generic import write_xdf

    write_xdf(session, Path(directory).with_suffix(".xdf"))  # the same streams in LabRecorder's format, beside the folder
    return written


# ------------------------------------------------------------------------------------------ bench


def bench_live(duration_s: float = 60.0, seed: int = 0, show_progress: bool = True, estimate_first: bool = False) -> dict[str, Any]:
    """``fusegraph bench live``: a simulated head session replayed in real time over the loopback into
    ``fusegraph live head`` (its own process), the estimates read back by an inlet.

    Latency is the time from a gyro sample's push to its estimate's arrival (LSL clock, one machine);
    lost = gyro samples from the first estimate on without an estimate. The RMS against the truth is
    printed beside the replay's (``run --solver online`` on the same session). ``estimate_first``: the live process and
    the replay both publish before the update (``fusegraph live --estimate-first``).
    """
    import re
    import signal
    import subprocess
    import sys
    import tempfile
    import threading

    from .metrics import score_attitude
    from .scenarios.head import simulate_head
    from .session import save_session
    from .systems.head import run_isam2

    pylsl = _require_pylsl()
    session = simulate_head(seed, duration_s=duration_s)
    gyro, tracker, truth = session.stream("gyro"), session.stream("tracker"), session.truth
    assert truth is not None
    tag = f"fgbench{seed}_{int(time.time() * 1000) % 100000}"
    outlets = {
        "gyro": pylsl.StreamOutlet(pylsl.StreamInfo(f"{tag}_gyro", "gyro", 3, float(gyro.meta.get("rate_hz", 100.0)), pylsl.cf_double64, f"{tag}g")),
        "tracker": pylsl.StreamOutlet(pylsl.StreamInfo(f"{tag}_tracker", "attitude", 4, float(tracker.meta.get("rate_hz", 50.0)),
                                                       pylsl.cf_double64, f"{tag}t")),
    }
    with tempfile.TemporaryDirectory() as tmp:
        toml = save_session(session, Path(tmp) / "declared") / "session.toml"
        command = [sys.executable, "-m", "fusegraph.cli", "live", "head", "--in", f"gyro=lsl:{tag}_gyro", "--in", f"tracker=lsl:{tag}_tracker",
                   "--out", f"lsl:{tag}_estimate", "--session-toml", str(toml), "--duration", f"{duration_s + 8.0:g}"]
        command += ["--estimate-first"] if estimate_first else []
        process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            found = pylsl.resolve_byprop("name", f"{tag}_estimate", 1, 20.0)
            if not found:
                why = process.stderr.read() if process.poll() is not None and process.stderr is not None else "still starting"
                raise SessionError(f"bench live: fusegraph live did not publish its estimate stream ({why})")
            inlet = pylsl.StreamInlet(found[0], max_buflen=10)
            inlet.open_stream(timeout=10.0)
            time.sleep(2.0)  # let the live process's inlets connect to ours
            received: list[tuple[float, float, list[float]]] = []  # (arrival, stamp, sample)
            done = threading.Event()

            def read() -> None:
                while not done.is_set():
                    sample, ts = inlet.pull_sample(timeout=0.05)  # returns with the first sample (a chunk pull waits its timeout out)
                    if sample is not None:
                        received.append((pylsl.local_clock(), float(ts), sample))

            # the reader thread must get the GIL as soon as an estimate arrives: Python's default 5 ms switch
            # interval (the replay loop below holds it between sleeps) would be measured as latency
            switch = sys.getswitchinterval()
            sys.setswitchinterval(1e-4)
            reader = threading.Thread(target=read, daemon=True)
            reader.start()
            t0 = pylsl.local_clock() + 0.5
            events = sorted([(float(t), 1, "gyro", i) for i, t in enumerate(gyro.t)]
                            + [(float(t) + tracker.latency_s, 0, "tracker", j) for j, t in enumerate(tracker.t)])
            pushed_at = np.full(len(gyro.t), np.nan)
            for when, _, name, i in events:
                target = t0 + when
                while (now := pylsl.local_clock()) < target:
                    time.sleep(min(0.0005, target - now))
                if name == "gyro":
                    pushed_at[i] = pylsl.local_clock()  # the push itself (the sleep above may overshoot its target)
                    outlets["gyro"].push_sample(list(gyro.values[i]), t0 + float(gyro.t[i]))
                else:
                    outlets["tracker"].push_sample(list(tracker.values[i]), t0 + float(tracker.t[i]))
            time.sleep(1.0)
            done.set()
            reader.join(timeout=2.0)
            sys.setswitchinterval(switch)
        finally:
            process.send_signal(signal.SIGINT)  # it stops as on Ctrl-C and prints what it did
            try:
                said, _ = process.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                said, _ = process.communicate()
    behind = re.search(r"(\d+) arrived behind a sample due after them", said or "")
    arrival = np.array([r[0] for r in received])
    stamp = np.array([r[1] for r in received])
    # the gyro sample each estimate is for: the nearest in time (LSL's clock correction moves a stamp by
    # microseconds either way; "the first at or after" then picked the next sample, 10 ms off, for some)
    sample = _nearest_index(gyro.t, stamp - t0)
    latency_ms = 1e3 * (arrival - pushed_at[sample])
    # lost: gyro samples from the first estimate on that got none (pushed, never answered). Before it, the
    # gyro samples due after the first fix but before the live process had received it are counted apart
    # (``before_first_fix``): the fix travels on its own connection and may arrive after them
    first_fix = float(tracker.t[0] + tracker.latency_s)
    first_estimate = int(sample.min()) if len(sample) else len(gyro.t)
    expected = len(gyro.t) - first_estimate
    before_first_fix = int(np.sum(gyro.t[:first_estimate] >= first_fix - 1e-9))
    t_session = stamp - t0
    quats = np.array([r[2][:4] for r in received]) if received else np.zeros((0, 4))
    from .estimate import Estimate

    replay = run_isam2(session, estimate_first=estimate_first)  # sampled at the gyro times, as the truth
    live_quat = np.full((len(replay.t), 4), np.nan)
    index = _nearest_index(replay.t, t_session)
    live_quat[index] = quats
    live = Estimate("live", replay.t, live_quat, None, 0.0)
    rms_live = score_attitude(live, truth.t, truth.values).rms_rad
    rms_replay = score_attitude(replay, truth.t, truth.values).rms_rad
    axes = ("azimuth", "elevation", "roll")
    return {
        "p50_ms": float(np.percentile(latency_ms, 50)) if len(latency_ms) else float("nan"),
        "p99_ms": float(np.percentile(latency_ms, 99)) if len(latency_ms) else float("nan"),
        "max_ms": float(latency_ms.max()) if len(latency_ms) else float("nan"),
        "lost": int(max(expected - len(np.unique(sample)), 0)),
        "before_first_fix": before_first_fix,
        "rms_deg": {a: float(np.rad2deg(v)) for a, v in zip(axes, rms_live, strict=True)},
        "replay_rms_deg": {a: float(np.rad2deg(v)) for a, v in zip(axes, rms_replay, strict=True)},
        "duration_s": duration_s,
        "estimate_first": estimate_first,
        "estimates": len(received),
        "behind": int(behind.group(1)) if behind else None,
        "latency_ms_by_second": [float(np.max(latency_ms[(stamp - t0 >= k) & (stamp - t0 < k + 1)], initial=0.0)) for k in range(int(duration_s))],
    }


def _nearest_index(times: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Index of the element of the increasing ``times`` nearest each ``query``."""
    right = np.clip(np.searchsorted(times, query), 1, len(times) - 1)
    return np.where(np.abs(times[right - 1] - query) <= np.abs(times[right] - query), right - 1, right)


def format_bench_live(result: dict[str, Any]) -> str:
    """The bench as text."""
    r, p = result["rms_deg"], result["replay_rms_deg"]
    return "\n".join([
        f"live head over LSL loopback, {result['duration_s']:g} s (gyro 100 Hz, tracker 50 Hz 100 ms late), {result['estimates']} estimates"
        + (" (estimate first, the update after it: live and replay)" if result.get("estimate_first") else ""),
        f"latency gyro push -> estimate arrival: p50 {result['p50_ms']:.2f} ms, p99 {result['p99_ms']:.2f} ms, max {result['max_ms']:.2f} ms; "
        f"lost {result['lost']} (and {result['before_first_fix']} gyro sample(s) due after the first fix that came before it)",
        f"samples that reached the live process behind a sample due after them: {result['behind']} (the live estimate parts from the "
        "replay's there: each stream has its own connection)",
        f"RMS deg  live    az {r['azimuth']:.3f} el {r['elevation']:.3f} roll {r['roll']:.3f}",
        f"         replay  az {p['azimuth']:.3f} el {p['elevation']:.3f} roll {p['roll']:.3f}",
    ])
