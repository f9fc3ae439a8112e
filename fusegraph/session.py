"""Session: named, time-stamped sensor streams plus metadata, stored as a directory a person can edit.

Layout of a session directory::

    session.toml     [session] system, description, world_frame; [streams.<name>] kind, file,
                     latency_s, noise and frame fields; optional [truth] file
    <stream>.csv     header row, first column ``t`` = SAMPLE time in seconds, then the kind's columns
    truth.csv        optional ground truth, same rules

A stream's ``latency_s`` says how long after its sample time a sample ARRIVES; online replay orders
by arrival, factors attach at the sample time. Loading validates everything and raises
``SessionError`` naming the file, row and problem; gaps in time (dropouts) are legal.
"""

from __future__ import annotations

import csv
import math
import tomllib
import warnings
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .catalogue import TRUTH_KEYS, CatalogueError, SensorKind, check_keys, suggest
from .sensors import sensor_catalogue

FloatArray = NDArray[np.float64]

#: Columns after ``t`` that each stream kind must have, in order (from the sensor catalogue).
RATE_KINDS = ("gyro", "accel", "mag", "pixel", "wheel_odometry")
"""Stream kinds sampled at a rate: integrated or differenced, so one sample is no recording."""
FAST_KINDS = ("gyro", "accel", "pixel")
"""Kinds that sample motion many times a second (an IMU, an eye tracker): a median spacing beyond
``MAX_FAST_SPACING_S`` is time stamps in other units, not a sensor."""
MAX_FAST_SPACING_S = 0.5
"""No IMU or eye tracker samples slower than 2 Hz; stamps in ms of a 100 Hz IMU are 10 "s" apart."""
KIND_COLUMNS: dict[str, tuple[str, ...]] = {kind: entry.columns for kind, entry in sensor_catalogue().items()}

#: Quaternions whose norm departs from 1 by more than this are an error (less: normalised).
UNIT_NORM_TOLERANCE = 0.01

#: Gap between samples, in multiples of the median period, above which a dropout is reported.
GAP_FACTOR = 1.5


class SessionError(ValueError):
    """A session directory or stream that cannot be used as it is; the message says where and why."""


class NotApplicableError(SessionError):
    """A solver that cannot take this session's streams (the 9-axis EKF without a magnetometer): an ablation variant that
    drops what it needs is 'not applicable' for it, not a failed run."""


class SessionWarning(UserWarning):
    """Something in a session that was repaired on loading (e.g. quaternions normalised); the message says what."""


CALIBRATION_ROLE = "calibration recording"
"""The ``role`` of a stream that is a calibration recording (``Stream.own_recording``)."""


@dataclass(frozen=True)
class Stream:
    """One sensor stream: sample times and values, with its metadata from session.toml."""

    name: str
    """Stream name, the key under ``[streams]`` (e.g. ``gyro``, ``tracker``)."""
    kind: str
    """Measurement kind, a key of ``KIND_COLUMNS``; decides the columns and the factor."""
    t: FloatArray
    """Sample times in seconds, strictly increasing, shape (N,)."""
    values: FloatArray
    """Samples, shape (N, len(columns)), in SI units of the kind."""
    columns: tuple[str, ...]
    """Column names of ``values``."""
    latency_s: float = 0.0
    """Arrival time minus sample time, seconds (a late sensor's transport delay)."""
    meta: Mapping[str, Any] = field(default_factory=dict)
    """Every other field of the stream's table in session.toml (rates, noise, frames)."""

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def arrival_t(self) -> FloatArray:
        """When each sample becomes available to an online estimator, seconds."""
        return self.t + self.latency_s

    def gaps(self) -> list[tuple[float, float]]:
        """Dropouts: (start, end) sample times of intervals longer than GAP_FACTOR x the median period."""
        if len(self) < 3:
            return []
        dt = np.diff(self.t)
        median = float(np.median(dt))
        idx = np.nonzero(dt > GAP_FACTOR * median)[0]
        return [(float(self.t[i]), float(self.t[i + 1])) for i in idx]

    @property
    def own_recording(self) -> bool:
        """A calibration recording (``role = 'calibration recording'``: e.g. the magnetometer's figure-eight): a recording of
        its own, on its own clock, taken whole wherever the session is cut."""
        return self.meta.get("role") == CALIBRATION_ROLE

    def select(self, mask: NDArray[np.bool_]) -> Stream:
        """The same stream restricted to the samples where ``mask`` is true."""
        return Stream(self.name, self.kind, self.t[mask], self.values[mask], self.columns, self.latency_s, self.meta)


@dataclass(frozen=True)
class Session:
    """A recording or simulation: streams by name, optional truth, and free metadata."""

    system: str
    """Which system this session belongs to (``head``, ``attitude9``, ...): picks the graph builder."""
    streams: Mapping[str, Stream]
    """Sensor streams by name."""
    truth: Stream | None = None
    """Ground truth, if known (an ``attitude`` stream for attitude systems)."""
    meta: Mapping[str, Any] = field(default_factory=dict)
    """The ``[session]`` table and any other top-level tables of session.toml."""
    path: Path | None = None
    """Directory the session was loaded from, if any."""

    @property
    def where(self) -> str:
        """How errors name this session: its session.toml, or ``<system> session`` when it was not loaded from disk."""
        return f"{self.path / 'session.toml'}" if self.path else f"{self.system} session"

    def validate(self) -> None:
        """The checks ``load_session`` makes, for a Session built in memory too (every solver runs them first): each
        stream's kind and keys are the catalogue's, its times finite and never going back, its values finite and
        plausible (magnitudes, unit quaternions, the declared rate), the streams on one clock. A SessionError names the
        stream and the likely cause.

        A session is immutable: a second call (every solver of a report validates the same session) repeats the first's
        warnings without checking again."""
        for message, category in self._checked():
            warnings.warn(message, category, stacklevel=2)

    def _checked(self) -> list[tuple[Warning | str, type[Warning]]]:
        """``_validate``'s warnings, made once (a SessionError raised each time)."""
        said = self.__dict__.get("_validation_warnings")
        if said is None:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                self._validate()
            said = [(w.message, w.category) for w in caught]
            object.__setattr__(self, "_validation_warnings", said)  # a frozen dataclass: a cache, not a field
        return list(said)

    def with_meta(self, **tables: Any) -> Session:
        """The same session with these metadata tables replaced (``gait={...}``: a setting a solver reads). Its streams,
        truth and path are the same, so ``validate``'s checks (which read no metadata) are made once for both."""
        said = self._checked()
        out = replace(self, meta={**self.meta, **tables})
        object.__setattr__(out, "_validation_warnings", said)
        return out

    def _validate(self) -> None:
        where = self.where
        catalogue = sensor_catalogue()
        if not self.streams:
            raise SessionError(f"{where}: no streams")
        for name, stream in self.streams.items():
            label = f"{where}: stream '{name}'"
            if stream.kind not in catalogue:
                raise SessionError(f"{label}: kind = {stream.kind!r} is not one of {', '.join(catalogue)}{suggest(stream.kind, catalogue)}")
            entry = catalogue[stream.kind]
            try:
                check_keys(stream.meta, entry.key_names, label)
            except CatalogueError as err:
                raise SessionError(f"{err} (see `fusegraph sensors {stream.kind}`)") from None
            t, values = np.asarray(stream.t, dtype=float), np.asarray(stream.values, dtype=float)
            if t.ndim != 1 or not len(t):
                raise SessionError(f"{label}: no samples (the stream is empty)")
            if values.ndim != 2 or len(values) != len(t):
                raise SessionError(f"{label}: values of shape {values.shape} for {len(t)} times (one row of {len(entry.columns)} per sample)")
            if not np.isfinite(t).all():
                raise SessionError(f"{label}: sample {int(np.argmin(np.isfinite(t)))}: time is {t[~np.isfinite(t)][0]} (times must be finite)")
            if len(t) < 2 and stream.kind in RATE_KINDS:
                raise SessionError(f"{label}: one sample: a {stream.kind} stream needs at least two (a truncated export, or the wrong file?)")
            if stream.kind in FAST_KINDS and len(t) > 2:
                spacing = float(np.median(np.diff(t)))
                if spacing > MAX_FAST_SPACING_S:
                    raise SessionError(f"{label}: median sample interval {spacing:.4g} s ({1 / spacing:.3g} Hz): a {stream.kind} samples far "
                                       "faster; time stamps in milliseconds (or us, ns)? convert them to seconds")
            step = np.diff(t)
            back = step < 0 if entry.repeated_times else step <= 0
            if back.any():
                i = int(np.argmax(back)) + 1
                what = "goes backwards" if step[i - 1] < 0 else "repeats"
                raise SessionError(f"{label}: sample {i}: time {what} (t = {t[i]!r} after {t[i - 1]!r})")
            if not np.isfinite(values).all():
                i = int(np.argmax(~np.isfinite(values).all(axis=1)))
                raise SessionError(f"{label}: sample {i}: a value is NaN or infinite (leave the sample out for a dropout)")
            check_plausible(entry, t, values, {k: v for k, v in stream.meta.items() if k not in ("units", "frame_R_sensor")}, label)
        check_overlap(self.streams, where)
        from .consistency import ConsistencyError, check_streams

        try:
            undecided = check_streams(self.streams, self.truth)
        except ConsistencyError as err:
            raise SessionError(f"{where}: {err}") from None
        for line in undecided:
            warnings.warn(f"{where}: {line}", SessionWarning, stacklevel=3)

    def usable(self) -> Session:
        """The session a solver reads: a dead magnetometer left out, a ranges row written twice in its epoch kept once
        (``consistency.repairs``; ``validate`` warns of each). The same session when nothing is left out."""
        from .consistency import repairs

        found = repairs(self.streams)
        if not found:
            return self
        streams = {}
        for name, stream in self.streams.items():
            if name not in found:
                streams[name] = stream
            else:
                keep = found[name][1]
                if keep is not None:
                    streams[name] = stream.select(keep)
        return Session(self.system, streams, self.truth, self.meta, self.path)

    def stream(self, name: str) -> Stream:
        """The stream called ``name``; a SessionError lists the ones that exist."""
        try:
            return self.streams[name]
        except KeyError:
            where = f"{self.path / 'session.toml'}: " if self.path else ""
            raise SessionError(f"{where}no stream '{name}' (have: {', '.join(self.streams)})") from None

    def synchronous(self, *names: str) -> list[Stream]:
        """The named streams, checked to be sampled together with the first (a SessionError names the odd one).

        Streams of one clock where one misses samples the others have (a dropout of one stream) are cut to the times they
        all have, with a warning per stream that lost samples (the solver then bridges the gap as a dropout of all)."""
        streams = [self.stream(name) for name in names]
        first = streams[0]
        if all(len(s) == len(first) and np.allclose(s.t, first.t) for s in streams[1:]):
            return streams
        ticks = _shared_clock(streams)
        if ticks is None:
            odd = next(s for s in streams[1:] if len(s) != len(first) or not np.allclose(s.t, first.t))
            raise SessionError(f"{self.where}: stream '{odd.name}' must be sampled with '{first.name}' (same times)")
        shared, everywhere = ticks[0], ticks[0]
        for other in ticks[1:]:
            shared, everywhere = np.intersect1d(shared, other), np.union1d(everywhere, other)
        cut = [s.select(np.isin(tk, shared)) for s, tk in zip(streams, ticks, strict=True)]
        if any(len(c) < 0.5 * len(s) for c, s in zip(cut, streams, strict=True)):
            raise SessionError(f"{self.where}: streams {', '.join(repr(n) for n in names)} share fewer than half their sample times: "
                               "sample them together (same times)")
        period = float(np.median(np.diff(first.t)))
        for stream, tk in zip(streams, ticks, strict=True):  # one line per stream that misses samples the others have
            absent = everywhere[~np.isin(everywhere, tk)] * period / 1000.0
            if len(absent):
                others = ", ".join(f"'{n}'" for n in names if n != stream.name)
                warnings.warn(f"{self.where}: stream '{stream.name}' has no sample at {len(absent)} times between t = {absent[0]:.2f} and "
                              f"{absent[-1]:.2f} s where {others} have one: those are left out too (a dropout of every stream there)",
                              SessionWarning, stacklevel=2)
        return cut

    def streams_of_kind(self, kind: str) -> list[Stream]:
        """All streams of one kind, in declaration order."""
        return [s for s in self.streams.values() if s.kind == kind]

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample over all streams."""
        starts = [float(s.t[0]) for s in self.streams.values()]
        ends = [float(s.t[-1]) for s in self.streams.values()]
        return max(ends) - min(starts)

    def without(self, *names: str) -> Session:
        """The same session with some streams removed (for ablations)."""
        for name in names:
            self.stream(name)
        kept = {k: v for k, v in self.streams.items() if k not in names}
        return Session(self.system, kept, self.truth, self.meta, self.path)


def _shared_clock(streams: list[Stream]) -> list[NDArray[np.int64]] | None:
    """Each stream's stamps in thousandths of the first's median period when all run at one rate (median periods within
    1 %) and so may be one clock with samples missing; None otherwise."""
    periods = [float(np.median(np.diff(s.t))) if len(s) > 1 else np.nan for s in streams]
    if not np.all(np.isfinite(periods)) or min(periods) <= 0 or max(periods) > 1.01 * min(periods):
        return None
    return [np.round(s.t / (periods[0] / 1000.0)).astype(np.int64) for s in streams]


@dataclass(frozen=True)
class ArrivalEvent:
    """One sample in the order an online estimator receives it."""

    arrival_t: float
    stream: Stream
    index: int

    @property
    def t(self) -> float:
        """Sample time of the event, seconds."""
        return float(self.stream.t[self.index])

    @property
    def values(self) -> FloatArray:
        return self.stream.values[self.index]


def replay_in_arrival_order(session: Session, last_streams: tuple[str, ...] = (), kinds: tuple[str, ...] | None = None) -> Iterator[ArrivalEvent]:
    """Every sample of every stream (``kinds``: of the streams of those kinds only), sorted by arrival time.

    Ties (to a microsecond) go to the streams named in ``last_streams`` last, so that a sample
    arriving at the same instant as, say, a gyro sample is used in that gyro step's estimate.
    """
    streams: list[Stream] = [s for s in session.streams.values() if kinds is None or s.kind in kinds]
    if not streams:
        return
    arrivals = [s.arrival_t for s in streams]
    table = np.concatenate(
        [
            np.stack([np.round(a * 1e6).astype(np.int64), np.full(len(a), int(s.name in last_streams)), np.full(len(a), rank), np.arange(len(a))], axis=1)
            for rank, (s, a) in enumerate(zip(streams, arrivals, strict=True))
        ]
    )
    order = np.lexsort((table[:, 3], table[:, 2], table[:, 1], table[:, 0]))
    for rank, index in table[order][:, 2:].tolist():
        yield ArrivalEvent(float(arrivals[rank][index]), streams[rank], index)


# --------------------------------------------------------------------------------------------- I/O


def check_overlap(streams: Mapping[str, Stream], where: str) -> None:
    """Every stream (a calibration recording, ``role = 'calibration recording'``, aside) must share time with
    the others: one that starts after they end (or ends before they start) is on another clock."""
    timed = {n: s for n, s in streams.items() if len(s) and not s.own_recording}
    if len(timed) < 2:
        return
    for name, stream in timed.items():
        others = [s for n, s in timed.items() if n != name]
        start, end = min(float(s.t[0]) for s in others), max(float(s.t[-1]) for s in others)
        if float(stream.t[0]) > end or float(stream.t[-1]) < start:
            rest = ", ".join(f"'{n}'" for n in timed if n != name)
            raise SessionError(f"{where}: stream '{name}' ({stream.t[0]:.3f} .. {stream.t[-1]:.3f} s) does not overlap {rest} "
                               f"({start:.3f} .. {end:.3f} s): another clock, or times in other units (ms? ns?)")


def read_session_spec(root: Path) -> tuple[Path, dict[str, Any], str]:
    """session.toml read and its header checked: (its path, the tables, the system)."""
    toml_path = root / "session.toml"
    if not toml_path.is_file():
        raise SessionError(f"{toml_path}: not found (a session is a directory with session.toml)")
    try:
        spec = tomllib.loads(toml_path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SessionError(f"{toml_path}: not valid TOML: {exc}") from None
    header = spec.get("session", {})
    system = header.get("system")
    if not isinstance(system, str):
        raise SessionError(f"{toml_path}: [session] needs system = \"<name>\" (e.g. \"head\")")
    stream_specs = spec.get("streams", {})
    if not stream_specs:
        raise SessionError(f"{toml_path}: no [streams.<name>] tables")
    for name, table in stream_specs.items():
        if not isinstance(table, Mapping):
            raise SessionError(f"{toml_path}: [streams.{name}] must be a table (kind = ..., file = ...)")
    return toml_path, spec, system


def load_session(directory: str | Path) -> Session:
    """Read and validate a session directory (see the module docstring for the format)."""
    root = Path(directory)
    toml_path, spec, system = read_session_spec(root)
    stream_specs = spec["streams"]
    streams = {}
    for name, table in stream_specs.items():
        streams[name] = _load_stream(root, toml_path, name, table)
    check_overlap(streams, str(toml_path))
    table = _truth_table(toml_path, spec)
    # ground truth may have gaps (occluded markers), written as NaN rows; sensors may not
    truth = None if table is None else _load_stream(root, toml_path, "truth", table, allow_nan=True)
    meta = {k: v for k, v in spec.items() if k not in ("streams", "truth")}
    return Session(system, streams, truth, meta, root)


def _truth_table(toml_path: Path, spec: Mapping[str, Any]) -> dict[str, Any] | None:
    """The session's ``[truth]`` table checked (its kind ``attitude`` unless it says otherwise), or None without one."""
    if "truth" not in spec:
        return None
    table = dict(spec["truth"])
    table.setdefault("kind", "attitude")
    try:
        check_keys(table, (k.name for k in TRUTH_KEYS), f"{toml_path}: [truth]")
    except CatalogueError as err:
        raise SessionError(str(err)) from None
    return table


def _stream_spec(root: Path, toml_path: Path, name: str, table: Mapping[str, Any]) -> tuple[Stream, Path]:
    """A stream's table checked against the catalogue: the Stream without samples, and its CSV's path."""
    where = f"{toml_path}: stream '{name}'"
    kind = table.get("kind")
    catalogue = sensor_catalogue()
    if kind not in catalogue:
        hint = suggest(str(kind), catalogue) if isinstance(kind, str) else ""
        raise SessionError(f"{where}: kind = {kind!r} is not one of {', '.join(catalogue)}{hint} (see `fusegraph sensors`)")
    entry = catalogue[kind]
    if name != "truth":
        try:
            check_keys(table, entry.key_names, where)
        except CatalogueError as err:
            raise SessionError(f"{err} (see `fusegraph sensors {kind}`)") from None
    file = table.get("file", f"{name}.csv")
    latency = table.get("latency_s", 0.0)
    if not isinstance(latency, int | float) or not math.isfinite(latency) or latency < 0:
        raise SessionError(f"{where}: latency_s must be a finite number >= 0 (got {latency!r})")
    meta = {k: v for k, v in table.items() if k not in ("kind", "file", "latency_s")}
    return Stream(name, kind, np.zeros(0), np.zeros((0, len(entry.columns))), entry.columns, float(latency), meta), root / file


def _load_stream(root: Path, toml_path: Path, name: str, table: Mapping[str, Any], allow_nan: bool = False) -> Stream:
    empty, path = _stream_spec(root, toml_path, name, table)
    entry = sensor_catalogue()[empty.kind]
    t, values = read_stream_csv(path, entry.columns, name, allow_nan=allow_nan, repeated_times=entry.repeated_times)
    if name != "truth":
        values = check_plausible(entry, t, values, table, f"{path} (stream '{name}')")
    return replace(empty, t=t, values=values)


def recording_times_s(directory: str | Path) -> tuple[float, float] | None:
    """A session directory's recording's first and last sample times, s (over its streams, a calibration recording left
    out), from each CSV's first and last lines alone: a long recording is not read to learn them. None where a line does
    not read as a time (reading the session says why)."""
    root = Path(directory)
    _, spec, _ = read_session_spec(root)
    spans = [csv_time_span(root / table.get("file", f"{name}.csv")) for name, table in spec["streams"].items()
             if table.get("role") != CALIBRATION_ROLE]
    if not spans or any(span is None for span in spans):
        return None
    return min(span[0] for span in spans if span is not None), max(span[1] for span in spans if span is not None)


def csv_time_span(path: Path) -> tuple[float, float] | None:
    """A stream CSV's first and last time, s, from its first and last lines alone; None where a line does not read as a
    time (reading the file says why)."""
    if not path.is_file() or _csv_encoding(path) != "utf-8-sig":
        return None
    with path.open("rb") as handle:
        lines = handle.read(4096).splitlines()[1:2]  # the first data row
        handle.seek(max(0, path.stat().st_size - 4096))
        lines += [line for line in handle.read().splitlines() if line.strip()][-1:]  # the last
    try:
        return float(lines[0].split(b",")[0]), float(lines[-1].split(b",")[0])
    except (IndexError, ValueError):
        return None


_TRUTH_SOURCE = "\0truth"
"""``iter_session_blocks``'s key for the truth among the streams it reads (no stream's name)."""


def iter_session_blocks(directory: str | Path, block_s: float = 60.0, truth: bool = False) -> Iterator[Session]:
    """A session directory read ``block_s`` seconds at a time, in time order (its CSVs streamed: a recording of any length
    in memory that does not grow with it), each block a Session of every stream's samples in [lo, lo + block_s). With
    ``truth``, each block's truth is the truth's samples within its streams' first and last (None where it has none; the
    truth follows the streams' blocks and is read no further than they go), else the truth is not read. A calibration
    recording (``role``) comes whole in every block. The first CSV block of each stream gets every check of
    ``load_session`` (units, magnitudes, rate), the rest its unit and frame conversion; the clocks' overlap is not checked
    (it needs every stream's end)."""
    root = Path(directory)
    toml_path, spec, system = read_session_spec(root)
    catalogue = sensor_catalogue()
    truth_table = _truth_table(toml_path, spec) if truth else None
    follower: tuple[Stream, Iterator[tuple[FloatArray, FloatArray]]] | None = None
    if truth_table is not None:
        truth_empty, truth_path = _stream_spec(root, toml_path, "truth", truth_table)
        truth_entry = catalogue[truth_empty.kind]
        follower = (truth_empty, iter_stream_csv(truth_path, truth_entry.columns, "truth", allow_nan=True, repeated_times=truth_entry.repeated_times))
    whole: dict[str, Stream] = {}
    readers: dict[str, tuple[Stream, Iterator[tuple[FloatArray, FloatArray]]]] = {}
    for name, table in spec["streams"].items():
        if table.get("role") == CALIBRATION_ROLE:
            whole[name] = _load_stream(root, toml_path, name, table)
            continue
        empty, path = _stream_spec(root, toml_path, name, table)
        entry = catalogue[empty.kind]
        label = f"{path} (stream '{name}')"

        def converted(entry: SensorKind = entry, path: Path = path, name: str = name, table: Mapping[str, Any] = table,
                      label: str = label) -> Iterator[tuple[FloatArray, FloatArray]]:
            for n, (t, values) in enumerate(iter_stream_csv(path, entry.columns, name, repeated_times=entry.repeated_times)):
                yield t, (check_plausible(entry, t, values, table, label) if n == 0 else to_si(entry, values, table, label))

        readers[name] = (empty, converted())
    meta = {k: v for k, v in spec.items() if k not in ("streams", "truth")}
    pending: dict[str, tuple[FloatArray, FloatArray]] = {}
    done: set[str] = set()

    sources = {**readers, **({_TRUTH_SOURCE: follower} if follower is not None else {})}

    def pull(name: str, until_s: float) -> None:  # read the stream on until a sample at or after until_s (or its end)
        t, values = pending.get(name, (np.zeros(0), np.zeros((0, len(sources[name][0].columns)))))
        while name not in done and (len(t) == 0 or t[-1] < until_s):
            nxt = next(sources[name][1], None)
            if nxt is None:
                done.add(name)
                break
            t, values = np.concatenate([t, nxt[0]]), np.concatenate([values, nxt[1]])
        pending[name] = (t, values)

    def take(name: str, hi: float) -> Stream:  # the source's samples before hi (read on as far as needed); the rest stays
        pull(name, hi)
        t, values = pending[name]
        n = int(np.searchsorted(t, hi, side="left"))
        pending[name] = (t[n:], values[n:])
        return replace(sources[name][0], t=t[:n], values=values[:n])

    for name in readers:
        pull(name, -np.inf)
    lo = min((float(t[0]) for t, _ in pending.values() if len(t)), default=np.inf)
    while any(len(t) for name, (t, _) in pending.items() if name != _TRUTH_SOURCE):
        hi = lo + block_s
        streams = dict(whole)
        for name in readers:
            streams[name] = take(name, hi)
        block_truth = None
        if follower is not None:
            part = take(_TRUTH_SOURCE, hi)
            heard = [s.t for name, s in streams.items() if name in readers and len(s)]
            if heard:
                inside = (part.t >= min(float(h[0]) for h in heard)) & (part.t <= max(float(h[-1]) for h in heard))
                if inside.any():
                    block_truth = replace(part, t=part.t[inside], values=part.values[inside])
        yield Session(system, streams, block_truth, meta, root)
        lo = hi


STILL_WINDOW_S = 0.5
"""The stretch over which a sample at rest is judged (a step or a bounce moves the norm within it)."""


def still_norms(t: FloatArray, values: FloatArray) -> FloatArray:
    """Norms of the samples at rest: where the norm varies by under 2 % of itself over ``STILL_WINDOW_S`` and is not near
    zero (free fall reads ~0 in any unit; a sensor at rest reads g, 1 in g): in any unit the reading of gravity alone."""
    if len(t) < 3:
        return np.zeros(0)
    norm = np.linalg.norm(values, axis=1)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    width = max(3, int(round(STILL_WINDOW_S / max(dt, 1e-9))))
    if len(norm) < width:
        return np.zeros(0)
    windows = np.lib.stride_tricks.sliding_window_view(norm, width)[:: max(1, width // 2)]
    mean, spread = windows.mean(axis=1), windows.std(axis=1)
    return np.asarray(mean[(spread < 0.02 * mean) & (mean > 0.5)])


def check_plausible(entry: SensorKind, t: FloatArray, values: FloatArray, keys: Mapping[str, Any], label: str) -> FloatArray:
    """The catalogue's checks on one stream: units converted, then magnitudes, quaternion norms, the
    declared rate and positive noise sigmas; returns the values in SI (normalised quaternions).

    A violation raises ``SessionError`` naming the stream and its likely cause."""
    units = keys.get("units")
    values = to_si(entry, values, keys, label)
    for spec in entry.keys:
        value = keys.get(spec.name)
        positive = spec.name.endswith(("sigma_rad_s", "sigma_deg", "sigma_m", "_sigma")) and spec.name != "markov_sigma_deg"
        if positive and isinstance(value, list):  # one per receiver and tag (a calibration table): each must be > 0
            flat = np.asarray(value, dtype=float).reshape(-1) if all(isinstance(v, int | float | list) for v in value) else np.array([np.nan])
            value = float(flat.min()) if flat.size and np.isfinite(flat).all() else float("nan")
        if positive and value is not None and (not isinstance(value, int | float) or not math.isfinite(value) or value <= 0):
            raise SessionError(f"{label}: {spec.name} = {value!r} must be a number > 0 (a sensor with no noise makes the graph singular)")
    finite = np.all(np.isfinite(values), axis=1)
    norms = np.linalg.norm(values[finite], axis=1) if finite.any() else np.zeros(1)
    for check in entry.magnitude:
        if check.statistic == "still median":
            still = still_norms(t[finite], values[finite])
            if not len(still):  # moving throughout (walking, bouncing): the median off free fall, and only a warning
                moving = norms[norms > 0.5]
                stat = float(np.median(moving)) if len(moving) else 0.0
                if not check.low <= stat <= check.high:
                    warnings.warn(f"{label}: no part at rest, and the median |value| off free fall is {stat:.4g}, outside [{check.low:g}, "
                                  f"{check.high:g}]: {check.likely_cause if units is None else 'in another unit than units says?'} "
                                  "(bouncing and falling alone can do this)", SessionWarning, stacklevel=3)
                continue
            stat = float(np.median(still))
        else:
            stat = float(np.max(norms)) if check.statistic == "max" else float(np.median(norms))
        if not check.low <= stat <= check.high:
            row = int(np.argmax(norms)) + 2 if check.statistic == "max" else None
            at = f" (line {row})" if row is not None else ""
            cause = check.likely_cause if units is None else f"units = {units!r} was applied: another unit still? check the file's unit"
            raise SessionError(f"{label}: {check.statistic} |value| {stat:.4g}{at} outside [{check.low:g}, {check.high:g}]: {cause}")
    if entry.unit_norm and finite.any():
        departure = np.abs(norms - 1.0)
        worst = int(np.argmax(departure))
        if departure[worst] > UNIT_NORM_TOLERANCE:
            line = int(np.nonzero(finite)[0][worst]) + 2
            raise SessionError(f"{label}: line {line}: quaternion norm {norms[worst]:.4g}, not 1 (more than 1 % off: not a rotation, or scaled?)")
        if departure[worst] > 1e-6:
            warnings.warn(f"{label}: quaternion norms up to {departure[worst]:.2e} off 1: normalised", SessionWarning, stacklevel=3)
        if departure[worst] > 1e-12:  # beyond float rounding: a written unit quaternion reads back bit-identical
            values = values.copy()
            values[finite] /= norms[:, None]
    if entry.check is not None:
        problem = entry.check(values, keys)
        if problem:
            raise SessionError(f"{label}: {problem}")
    rate = keys.get("rate_hz")
    if rate is not None and len(t) > 2:
        if not isinstance(rate, int | float) or not math.isfinite(rate) or rate <= 0:
            raise SessionError(f"{label}: rate_hz = {rate!r} must be a number > 0")
        unique = np.unique(t)
        if len(unique) > 2:
            median_dt = float(np.median(np.diff(unique)))
            if not 0.5 / rate <= median_dt <= 2.0 / rate:
                cause = "time stamps in milliseconds? convert to seconds" if median_dt > 100.0 / rate else "is rate_hz right?"
                raise SessionError(f"{label}: rate_hz = {rate:g} but the median sample interval is {median_dt:.6g} s ({1 / median_dt:.4g} Hz): {cause}")
    return values


def to_si(entry: SensorKind, values: FloatArray, keys: Mapping[str, Any], label: str) -> FloatArray:
    """A stream's values in SI and the gyro's axes: its declared ``units`` converted, its ``frame_R_sensor`` applied."""
    units = keys.get("units")
    if units is not None:
        if units not in entry.unit_conversions:
            accepted = ", ".join(entry.unit_conversions) or "none (the kind has one unit)"
            raise SessionError(f"{label}: units = {units!r} is not one this kind converts (accepted: {accepted})")
        values = values * entry.unit_conversions[units]
    if keys.get("frame_R_sensor") is not None:
        values = values @ frame_rotation(keys["frame_R_sensor"], entry.kind, label).T
    return values


def frame_rotation(value: Any, kind: str, label: str) -> FloatArray:
    """``frame_R_sensor`` as a 3 x 3 rotation or reflection (orthogonal within 1e-3): a SessionError names what is wrong."""
    if kind not in ("gyro", "accel", "mag"):
        raise SessionError(f"{label}: frame_R_sensor applies to gyro, accel and mag streams, not {kind}")
    try:
        matrix = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        matrix = np.zeros(0)
    if matrix.shape != (3, 3) or not np.allclose(matrix @ matrix.T, np.eye(3), atol=1e-3):
        raise SessionError(f"{label}: frame_R_sensor = {value!r} must be 3 rows of 3 numbers forming a rotation (or a signed "
                           "permutation), e.g. [[0, 1, 0], [1, 0, 0], [0, 0, 1]] for x and y swapped")
    return matrix


def read_stream_csv(
    path: Path, columns: tuple[str, ...], name: str = "", allow_nan: bool = False, repeated_times: bool = False
) -> tuple[FloatArray, FloatArray]:
    """Read ``t`` plus ``columns`` from a CSV with a header row; validate every row.

    Extra columns are allowed and ignored. Errors name the file, the line and the problem.
    ``allow_nan`` admits NaN values (never in ``t``): estimates use NaN for "no estimate yet".
    ``repeated_times`` lets consecutive rows share a time (one row per value of an epoch).
    UTF-8 with or without a byte-order mark (as spreadsheets write it) and UTF-16 with one are read.
    """
    blocks = list(iter_stream_csv(path, columns, name, allow_nan, repeated_times))
    if len(blocks) == 1:
        return blocks[0]
    return np.concatenate([b[0] for b in blocks]), np.concatenate([b[1] for b in blocks])


CSV_BLOCK_ROWS = 65536
"""Rows a streamed CSV yields at a time (``iter_stream_csv``): ~5 MB of a 9-axis stream."""


def iter_stream_csv(
    path: Path, columns: tuple[str, ...], name: str = "", allow_nan: bool = False, repeated_times: bool = False,
    block_rows: int | None = None,
) -> Iterator[tuple[FloatArray, FloatArray]]:
    """``read_stream_csv`` a block of ``block_rows`` rows (default ``CSV_BLOCK_ROWS``) at a time (a long recording is never
    held whole): the same checks, the same errors, at least one block.

    Parsed by pandas' C reader (exact round-trip floats) and checked a block at a time in numpy; a block it cannot read
    or that fails a check is read again row by row (``_iter_rows``), which says the line and the problem: a Python loop
    over every row spent 8.6 s loading BROAD's 13 trials."""
    block_rows = block_rows or CSV_BLOCK_ROWS
    label = f"{path}" + (f" (stream '{name}')" if name else "")
    if not path.is_file():
        raise SessionError(f"{label}: file not found")
    done = 0  # rows the fast reader has yielded
    try:
        for t, values in _iter_fast(path, columns, allow_nan, repeated_times, block_rows):
            done += len(t)
            yield t, values
        if done:
            return
    except _NotFastError:
        pass
    for t, values in _iter_rows(path, columns, name, allow_nan, repeated_times, block_rows):  # the rows after those yielded
        skip = min(done, len(t))
        done -= skip
        if skip < len(t):
            yield t[skip:], values[skip:]


def _csv_encoding(path: Path) -> str:
    """UTF-16 where the file starts with its byte-order mark, else UTF-8 with or without one (as spreadsheets write it)."""
    with path.open("rb") as handle:
        head = handle.read(2)
    return "utf-16" if head in (b"\xff\xfe", b"\xfe\xff") else "utf-8-sig"


class _NotFastError(Exception):
    """The fast reader cannot vouch for a block: the row-by-row reader reads the file and says what is wrong, if anything."""


def _iter_fast(path: Path, columns: tuple[str, ...], allow_nan: bool, repeated_times: bool, block_rows: int) -> Iterator[tuple[FloatArray, FloatArray]]:
    import pandas as pd

    encoding = _csv_encoding(path)
    try:
        with path.open(newline="", encoding=encoding) as handle:
            header = [h.strip() for h in next(csv.reader(handle))]
        wanted = ("t", *columns)
        if header[:1] != ["t"] or any(c not in header for c in wanted):
            raise _NotFastError
        index = [header.index(c) for c in wanted]
        reader = pd.read_csv(path, encoding=encoding, header=None, skiprows=1, usecols=index, dtype=float, chunksize=block_rows,
                             skip_blank_lines=True, names=list(range(len(header))))
        previous = -np.inf
        for chunk in reader:
            table = chunk[index].to_numpy(dtype=float)
            t, values = table[:, 0], table[:, 1:]
            steps = np.diff(np.concatenate([[previous], t]))
            if (not np.isfinite(t).all() or not (np.isfinite(values) | (allow_nan & np.isnan(values))).all()
                    or (steps < 0).any() or (not repeated_times and (steps == 0).any())):
                raise _NotFastError
            previous = float(t[-1]) if len(t) else previous
            yield t.copy(), values.copy()  # contiguous, as the row reader gives them
    except (ValueError, UnicodeDecodeError, StopIteration, pd.errors.ParserError, pd.errors.EmptyDataError):
        raise _NotFastError from None


def _iter_rows(
    path: Path, columns: tuple[str, ...], name: str, allow_nan: bool, repeated_times: bool, block_rows: int,
) -> Iterator[tuple[FloatArray, FloatArray]]:
    """``iter_stream_csv`` row by row in Python: every check with the line it fails on."""
    label = f"{path}" + (f" (stream '{name}')" if name else "")
    encoding = _csv_encoding(path)
    previous: float | None = None
    yielded = False
    try:
        with path.open(newline="", encoding=encoding) as handle:
            reader = csv.reader(handle)
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise SessionError(f"{label}: empty file (expected a header row: t, {', '.join(columns)})") from None
            wanted = ("t", *columns)
            missing = [c for c in wanted if c not in header]
            if missing:
                named = ", ".join(repr(c) for c in missing)
                raise SessionError(f"{label}: column{'s' if len(missing) > 1 else ''} {named} missing (have: {', '.join(header)})")
            if header[0] != "t":
                raise SessionError(f"{label}: first column must be 't' (sample time in seconds), found {header[0]!r}")
            idx = [header.index(c) for c in wanted]
            rows: list[list[float]] = []
            for line_no, row in enumerate(reader, start=2):
                if not row or all(not cell.strip() for cell in row):
                    continue
                if len(row) < len(header):
                    raise SessionError(f"{label}: line {line_no}: {len(row)} fields, header has {len(header)}")
                try:
                    values = [float(row[i]) for i in idx]
                except ValueError:
                    bad = next(wanted[j] for j, i in enumerate(idx) if not _is_float(row[i]))
                    raise SessionError(f"{label}: line {line_no}: column '{bad}' is not a number ({row[header.index(bad)]!r})") from None
                for col, v in zip(wanted, values, strict=True):
                    if not math.isfinite(v) and not (allow_nan and col != "t" and math.isnan(v)):
                        raise SessionError(f"{label}: line {line_no}: column '{col}' is {v} (NaN/inf not allowed; leave the row out for a dropout)")
                if previous is not None:
                    if values[0] == previous and not repeated_times:
                        raise SessionError(f"{label}: line {line_no}: duplicate time t = {values[0]!r} (same as line {line_no - 1})")
                    if values[0] < previous:
                        raise SessionError(f"{label}: line {line_no}: time goes backwards (t = {values[0]!r} after {previous!r})")
                previous = values[0]
                rows.append(values)
                if len(rows) >= block_rows:
                    table = np.asarray(rows, dtype=float)
                    rows = []
                    yielded = True
                    yield table[:, 0].copy(), table[:, 1:].copy()
    except UnicodeDecodeError as err:
        raise SessionError(f"{label}: not UTF-8 text ({err.reason} at byte {err.start}); save the CSV as UTF-8") from None
    if rows or not yielded:
        if not rows:
            raise SessionError(f"{label}: no samples (the stream is empty)")
        table = np.asarray(rows, dtype=float)
        yield table[:, 0].copy(), table[:, 1:].copy()


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def save_session(session: Session, directory: str | Path) -> Path:
    """Write a session directory that ``load_session`` reads back exactly (values to 17 digits)."""
    root = Path(directory)
    root.mkdir(parents=True, exist_ok=True)
    for stream in session.streams.values():
        write_stream_csv(root / f"{stream.name}.csv", stream.t, stream.values, stream.columns)
    if session.truth is not None:
        write_stream_csv(root / "truth.csv", session.truth.t, session.truth.values, session.truth.columns)
    (root / "session.toml").write_text(session_toml(session))
    return root


def session_toml(session: Session) -> str:
    """``session.toml``'s text for ``session`` (its streams' samples are not read: each table names its CSV)."""
    lines = ["[session]", f"system = {_toml_value(session.system)}"]
    header = dict(session.meta.get("session", {}))
    header.pop("system", None)
    lines += [f"{k} = {_toml_value(v)}" for k, v in header.items()]
    for table_name, table in session.meta.items():
        if table_name == "session" or not isinstance(table, Mapping):
            continue
        lines += ["", f"[{table_name}]"] + [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    for stream in session.streams.values():
        lines += ["", *stream_toml(stream)]
    if session.truth is not None:
        lines += ["", *stream_toml(session.truth, truth=True)]
    return "\n".join(lines) + "\n"


def stream_toml(stream: Stream, truth: bool = False) -> list[str]:
    """A stream's table in ``session.toml`` (``[streams.<name>]``, or ``[truth]``), its CSV ``<name>.csv`` (``truth.csv``)."""
    if truth:
        return ["[truth]", f"kind = {_toml_value(stream.kind)}", "file = \"truth.csv\"", *(f"{k} = {_toml_value(v)}" for k, v in stream.meta.items())]
    return [f"[streams.{stream.name}]", f"kind = {_toml_value(stream.kind)}", f"file = \"{stream.name}.csv\"", f"latency_s = {_toml_value(stream.latency_s)}",
            *(f"{k} = {_toml_value(v)}" for k, v in stream.meta.items())]


def write_stream_csv(path: Path, t: FloatArray, values: FloatArray, columns: tuple[str, ...]) -> None:
    """One stream as CSV: header ``t,<columns>``, full float precision."""
    write_stream_csv_blocks(path, [(t, values)], columns)


def write_stream_csv_blocks(path: Path, blocks: Iterable[tuple[FloatArray, FloatArray]], columns: tuple[str, ...]) -> int:
    """``write_stream_csv`` a block of (times, values) at a time, as they come (a long stream is never held whole); returns
    the rows written."""
    rows = 0
    with path.open("w") as handle:
        handle.write(",".join(("t", *columns)) + "\n")
        for t, values in blocks:
            np.savetxt(handle, np.column_stack([t, values]), delimiter=",", fmt="%.17g")
            rows += len(t)
    return rows


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to session.toml")
