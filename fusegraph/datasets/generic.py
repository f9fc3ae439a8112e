"""The formats users already have: a vendor's CSV export and a Lab Streaming Layer recording (XDF), mapped onto
catalogue kinds and written as (or added to) a session directory.

* ``import csv FILE --kind KIND --columns t=Timestamp,wx=GyrX,... [--units deg/s] [--time-units ms]``: one stream.
  Every column of the kind is named (``fusegraph sensors KIND`` lists them), the time column too; values are converted
  to SI on import (the kind's accepted units), times to seconds.
* ``import xdf FILE.xdf --map LSL_NAME=STREAM[:KIND] ...``: every mapped LSL stream (LabRecorder's format, read with
  ``pyxdf``: its clock offsets applied, so every stream is on the recording machine's clock), each channel in the
  kind's column order. A stream of the XDF that no ``--map`` names is listed, never silently used.

Into a new folder (``--system`` says whose session it is) or an existing session (the stream is added; the same
name again is an error). ``--truth`` makes the stream the session's truth instead (kind attitude, position, ...). A CSV is
read and written a block at a time (``iter_csv_stream``, ``import_csv``; ``--onto`` too, ``onto_times``): an export of any
length in memory that does not grow with it.
"""

from __future__ import annotations

import csv
import math
import re
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..geometry import FloatArray
from ..sensors import sensor_catalogue
from ..session import (
    CSV_BLOCK_ROWS,
    KIND_COLUMNS,
    Session,
    SessionError,
    SessionWarning,
    Stream,
    iter_stream_csv,
    load_session,
    read_session_spec,
    save_session,
    session_toml,
    stream_toml,
    write_stream_csv_blocks,
)

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "iso": 1.0}
"""``--time-units`` -> seconds per unit; ``iso``: ISO 8601 date-times (``2024-05-01 12:00:00.010``, a ``T`` and a zone offset
allowed), read as seconds since 1970-01-01 UTC (a time without a zone as if UTC: only differences matter within a session)."""


def parse_columns(text: str, kind: str) -> dict[str, str]:
    """``t=Timestamp,wx=GyrX,...`` -> {kind column: file column}; every column of the kind and ``t`` must be named."""
    wanted = ("t", *KIND_COLUMNS[kind])
    mapping: dict[str, str] = {}
    for item in text.split(","):
        ours, sep, theirs = item.partition("=")
        if not sep or not ours.strip() or not theirs.strip():
            raise SessionError(f"--columns {text!r}: write OURS=THEIRS pairs, e.g. {','.join(f'{c}=<header of {c}>' for c in wanted)}")
        if ours.strip() not in wanted:
            raise SessionError(f"--columns: {ours.strip()!r} is not a column of kind {kind} (its columns: {', '.join(wanted)})")
        mapping[ours.strip()] = theirs.strip()
    missing = [c for c in wanted if c not in mapping]
    if missing:
        raise SessionError(f"--columns: name the file's column for {', '.join(missing)} too (kind {kind} has {', '.join(wanted)})")
    return mapping


def csv_stream(path: str | Path, kind: str, columns: dict[str, str], name: str | None = None, units: str | None = None,
               time_units: str = "s", delimiter: str | None = None, decimal: str = ".") -> Stream:
    """One stream of ``kind`` from a CSV with a header row, its columns picked by ``columns`` (kind column -> header): the
    blocks of ``iter_csv_stream`` held whole."""
    blocks = list(iter_csv_stream(path, kind, columns, units, time_units, delimiter, decimal))
    t = np.concatenate([b[0] for b in blocks])
    values = np.concatenate([b[1] for b in blocks])
    return Stream(name or kind, kind, t, values, _entry(kind).columns, 0.0, {"description": csv_description(Path(path), columns, units)})


def csv_description(path: Path, columns: dict[str, str], units: str | None) -> str:
    """What an imported CSV stream says it was made from (its ``description``)."""
    return f"imported from {path.name} ({', '.join(f'{k}={v}' for k, v in columns.items())}" + (f"; converted from {units}" if units else "") + ")"


def iter_csv_stream(path: str | Path, kind: str, columns: dict[str, str], units: str | None = None, time_units: str = "s",
                    delimiter: str | None = None, decimal: str = ".", block_rows: int = CSV_BLOCK_ROWS) -> Iterator[tuple[FloatArray, FloatArray]]:
    """A vendor CSV's samples a block of ``block_rows`` rows at a time (a long export is never held whole): (times in seconds
    on the file's clock, values in the kind's SI units). The delimiter is the header's (comma, semicolon, tab, or spaces:
    ``WHITESPACE``) unless given; ``decimal``: the numbers' decimal mark (``,`` in many European exports). Parsed by pandas' C reader; every row is
    checked across the blocks: a cell that is not a number, a time that goes back or repeats with other values is an error
    naming its line (a data row's: the header is line 1), and a row that repeats the one before it exactly (a logger's double
    write) is kept once, with one warning at the end."""
    import pandas as pd

    path = Path(path)
    entry = _entry(kind)
    factor = _unit_factor(kind, units)
    if time_units not in TIME_UNITS:
        raise SessionError(f"--time-units {time_units!r}: one of {', '.join(TIME_UNITS)}")
    if not path.is_file():
        raise SessionError(f"{path}: not found")
    with path.open(newline="", encoding="utf-8-sig") as handle:
        first = handle.readline()
    if not first.strip():
        raise SessionError(f"{path}: empty file (expected a header row)")
    sep = delimiter or _delimiter(path, first)
    header = _fields(first, sep)
    absent = [theirs for theirs in columns.values() if theirs not in header]
    if absent:
        raise SessionError(f"{path}: column{'s' if len(absent) > 1 else ''} {', '.join(repr(a) for a in absent)} not in the header "
                           f"(have: {', '.join(header)})")
    order = [header.index(columns[c]) for c in ("t", *entry.columns)]
    named = ["t", *entry.columns]
    before = 0  # data rows read so far
    repeats, first_repeat = 0, 0
    try:
        iso = time_units == "iso"
        types = {i: str if iso and i == order[0] else float for i in set(order)}
        reader = pd.read_csv(path, sep=sep, decimal=decimal, header=None, skiprows=1, names=list(range(len(header))), usecols=sorted(set(order)),
                             dtype=types, chunksize=block_rows, skip_blank_lines=True, encoding="utf-8-sig")  # type: ignore[call-overload]
        previous: np.ndarray | None = None  # the last row kept
        for chunk in reader:
            if iso:  # the date-times as seconds since 1970 UTC (NaN where a cell is empty)
                stamps = pd.to_datetime(chunk[order[0]], format="ISO8601", utc=True)
                chunk[order[0]] = np.where(stamps.isna(), np.nan, stamps.to_numpy(dtype="datetime64[ns]").astype(np.int64) / 1e9)
            table = chunk[order].to_numpy(dtype=float)
            bad = np.flatnonzero(~np.isfinite(table).all(axis=1))
            if len(bad):
                i = int(bad[0])
                j = int(np.flatnonzero(~np.isfinite(table[i]))[0])
                raise SessionError(f"{path}: line {before + i + 2}: column {columns[named[j]]!r} is {table[i, j]} (leave the row out for a dropout)")
            joined = table if previous is None else np.vstack([previous, table])
            offset = 0 if previous is None else 1  # joined row j is data row before - offset + j
            step = np.diff(joined[:, 0])
            back = np.flatnonzero(step < 0)
            if len(back):
                j = int(back[0]) + 1
                line = before - offset + j + 2
                raise SessionError(f"{path}: line {line}: time {float(joined[j, 0])!r} goes back from {float(joined[j - 1, 0])!r} on line {line - 1} "
                                   f"({len(back)} such row{'s' if len(back) > 1 else ''} in lines {before + 2}-{before + len(table) + 1}): "
                                   "rows out of order, or two recordings in one file?")
            same_time = np.flatnonzero(step == 0) + 1
            exact = same_time[np.all(joined[same_time] == joined[same_time - 1], axis=1)]
            other = np.setdiff1d(same_time, exact)
            if len(other):
                j = int(other[0])
                line = before - offset + j + 2
                raise SessionError(f"{path}: line {line}: time {float(joined[j, 0])!r} repeats line {line - 1} with other values ({len(other)} such "
                                   f"row{'s' if len(other) > 1 else ''} in lines {before + 2}-{before + len(table) + 1}): a time column with too "
                                   "few digits (--time-units?), or the wrong column?")
            if len(exact):
                first_repeat = first_repeat or before - offset + int(exact[0]) + 2
                repeats += len(exact)
            kept = np.delete(joined, exact, axis=0)[offset:]
            before += len(table)
            if len(kept):
                previous = kept[-1:]
                yield kept[:, 0] * TIME_UNITS[time_units], kept[:, 1:] * factor
    except (ValueError, pd.errors.ParserError) as err:
        raise SessionError(_unreadable(path, sep, header, order, decimal, time_units == "iso") or f"{path}: not a CSV pandas can read ({err})") from None
    except pd.errors.EmptyDataError:
        pass
    if not before:
        raise SessionError(f"{path}: no samples after the header")
    if repeats:
        warnings.warn(f"{path}: {repeats} row{'s' if repeats > 1 else ''} repeat the row before exactly (first: line {first_repeat}): "
                      "a logger's double write? kept once", SessionWarning, stacklevel=3)


WHITESPACE = r"\s+"
"""The delimiter of a file whose columns are separated by spaces (or tabs and spaces mixed), as pandas names it."""


def _delimiter(path: Path, header: str) -> str:
    """The header line's delimiter: a comma, semicolon or tab, else spaces where they separate several names."""
    try:
        return csv.Sniffer().sniff(header, delimiters=",;\t").delimiter
    except csv.Error:
        if len(header.split()) > 1:
            return WHITESPACE
        raise SessionError(f"{path}: line 1: no delimiter between the column names ({header.strip()[:60]!r}): a comma, semicolon, tab or "
                           "spaces") from None


def _fields(line: str, sep: str) -> list[str]:
    """A line's fields, stripped."""
    cells = line.split() if sep == WHITESPACE else next(csv.reader([line], delimiter=sep), [])
    return [cell.strip() for cell in cells]


def _unreadable(path: Path, sep: str, header: list[str], order: list[int], decimal: str, iso: bool = False) -> str | None:
    """What the C reader could not parse, read again row by row (without holding the rows): the first cell of ``order``
    that is not a number (the time with ``iso``: not an ISO 8601 date-time), or a row with more fields than the header,
    with its line; None if every row reads."""
    from datetime import datetime

    with path.open(newline="", encoding="utf-8-sig") as handle:
        reader = (_fields(text, sep) for text in handle) if sep == WHITESPACE else csv.reader(handle, delimiter=sep)
        next(reader)
        for line, row in enumerate(reader, start=2):
            if not row or all(not cell.strip() for cell in row):
                continue
            if len(row) > len(header):
                return f"{path}: line {line}: {len(row)} fields, the header has {len(header)}"
            for n, i in enumerate(order):
                cell = row[i].strip() if i < len(row) else ""
                if iso and n == 0:
                    try:
                        datetime.fromisoformat(cell)
                    except ValueError:
                        return f"{path}: line {line}: column {header[i]!r} " + ("is empty" if not cell else f"is not an ISO 8601 date-time ({cell!r})")
                elif not _is_number(cell.replace(decimal, ".") if decimal != "." else cell):
                    hint = (" (a decimal comma? pass --decimal ,)" if decimal == "." and re.fullmatch(r"[-+]?\d+,\d+", cell)
                            else " (a date-time? pass --time-units iso)" if n == 0 and re.match(r"\d{4}-\d\d-\d\d", cell) else "")
                    return f"{path}: line {line}: column {header[i]!r} " + ("is empty" if not cell else f"is not a number ({cell!r}){hint}")
    return None


def import_csv(out: str | Path, path: str | Path, kind: str, columns: dict[str, str], name: str | None = None, units: str | None = None,
               time_units: str = "s", system: str | None = None, truth: bool = False, onto: str | None = None, decimal: str = ".",
               block_rows: int = CSV_BLOCK_ROWS) -> tuple[Path, int]:
    """``import csv``: the CSV as a stream of a new session in ``out`` or added to the session there (as ``add_to_session``
    says), read and written a block at a time: neither it nor the session's other streams are held whole (``block_rows``:
    ``iter_csv_stream``'s). ``onto``: put on the times of that stream of the session (``onto_times``, read a block at a time
    too; what was bridged said as a warning and in the stream's description). Returns the session's folder and the samples
    written."""
    root, path = Path(out), Path(path)
    name = "truth" if truth else (name or kind)
    toml = root / "session.toml"
    if onto is not None and not toml.is_file():
        raise SessionError(f"--onto {onto}: --out {root} has no session yet; import the stream whose times to take first")
    spec: Any = destination(root, system, [name], truth)
    origin = None if spec is None else float(spec["session"].get("time_origin_s", 0.0))  # a new session's start at its first sample
    if onto is not None and onto not in spec["streams"]:
        raise SessionError(f"--onto {onto}: {toml} has no stream {onto!r} (has: {', '.join(spec['streams'])})")

    if onto is not None and kind in NOT_INTERPOLATED:
        raise SessionError(f"--onto {onto}: a {kind} stream is not interpolated (import it on its own times)")
    source = iter_csv_stream(path, kind, columns, units, time_units, decimal=decimal, block_rows=block_rows)
    resampling = None
    if onto is not None:
        resampling = Resampling(name, onto)
        table = spec["streams"][onto]
        entry = _entry(table.get("kind", ""))
        target = iter_stream_csv(root / table.get("file", f"{onto}.csv"), entry.columns, onto, repeated_times=entry.repeated_times,
                                 block_rows=block_rows)
        shift = float(spec["session"].get("time_origin_s", 0.0))  # the target's times on the source's clock, as its stamps are
        source = onto_times(source, (t + shift for t, _ in target), resampling)

    def moved() -> Iterator[tuple[FloatArray, FloatArray]]:
        nonlocal origin
        for t, values in source:
            origin = float(t[0]) if origin is None else origin
            yield t - origin, values

    columns_out = _entry(kind).columns
    created = not root.exists()
    root.mkdir(parents=True, exist_ok=True)
    partial = root / f"{name}.csv.partial"
    try:
        rows = write_stream_csv_blocks(partial, moved(), columns_out)
        said = resampling.said() if resampling is not None else ""  # no target time inside its span: an error, nothing kept
    except BaseException:
        partial.unlink(missing_ok=True)
        if created:
            root.rmdir()
        raise
    partial.replace(root / f"{name}.csv")
    if said:
        warnings.warn(f"{root}: {said}", SessionWarning, stacklevel=2)
    description = csv_description(path, columns, units) + (f"; {said}" if said else "")
    stream = Stream(name, kind, np.zeros(0), np.zeros((0, len(columns_out))), columns_out, 0.0, {"description": description})
    if spec is not None:
        with toml.open("a") as handle:
            handle.write("\n" + "\n".join(stream_toml(stream, truth=truth)) + "\n")
    else:
        header = {"system": system, "time_origin_s": origin, "description": NEW_SESSION}
        toml.write_text(session_toml(Session(str(system), {} if truth else {name: stream}, stream if truth else None, {"session": header})))
    return root, rows


NOT_INTERPOLATED = ("attitude", "ranges", "tag_position", "beacon_ranges", "flag")
"""Kinds ``--onto`` refuses: a quaternion, a set of ranges or a flag is not a linear quantity between two samples."""


@dataclass
class Resampling:
    """What ``onto_times`` did, for the line that says so (filled as its blocks are drawn)."""

    name: str
    """The stream put on the other's times."""
    target: str
    """The stream whose times it is put on."""
    samples: int = 0
    """Its own samples read."""
    made: int = 0
    """Samples made at the target's times."""
    outside: int = 0
    """Target times outside its span, left out."""
    bridged_s: float = 0.0
    """The largest interval of its own an interpolated sample bridges, s."""
    medians_s: list[float] = field(default_factory=list)
    """The median interval of each block of its own samples, s."""
    span_s: tuple[float, float] = (math.inf, -math.inf)
    """Its first and last sample time, s."""
    target_span_s: tuple[float, float] = (math.inf, -math.inf)
    """The target's first and last time, s."""

    def said(self) -> str:
        """The line saying how (an error when no target time fell inside its span)."""
        if not self.made:
            raise SessionError(f"--onto {self.target}: '{self.name}' ({self.span_s[0]:.3f} .. {self.span_s[1]:.3f} s) does not overlap '{self.target}' "
                               f"({self.target_span_s[0]:.3f} .. {self.target_span_s[1]:.3f} s): another clock or time unit?")
        return (f"'{self.name}' ({self.samples} samples on its own clock) interpolated linearly onto the {self.made} times of '{self.target}'"
                + (f" ({self.outside} of its times outside '{self.name}''s span left out)" if self.outside else "")
                + f"; the largest interval bridged {self.bridged_s:.4g} s (its median {float(np.median(self.medians_s)):.4g} s)")


def onto_times(source: Iterable[tuple[FloatArray, FloatArray]], targets: Iterable[FloatArray], kept: Resampling) -> Iterator[tuple[FloatArray, FloatArray]]:
    """A stream given in blocks (times increasing, values) at the times of another given in blocks (on the same clock): each
    column interpolated linearly between the two samples around each target time, at the target times inside its span
    only, a block of target times at a time; the source is held only from the sample before the target's block on, so
    neither is held whole, and read to its end. ``kept`` is filled as it goes (its median interval: the median of its
    blocks' medians)."""
    blocks = iter(source)
    own_t, own_v = np.zeros(0), np.zeros((0, 0))
    ended = False

    def read(t: FloatArray) -> None:
        kept.samples += len(t)
        kept.span_s = (min(kept.span_s[0], float(t[0])), float(t[-1]))
        if len(t) > 1:
            kept.medians_s.append(float(np.median(np.diff(t))))

    for times in targets:
        if not len(times):
            continue
        kept.target_span_s = (min(kept.target_span_s[0], float(times[0])), max(kept.target_span_s[1], float(times[-1])))
        while not ended and (not len(own_t) or own_t[-1] < times[-1]):
            block = next(blocks, None)
            if block is None:
                ended = True
                break
            t, values = block
            read(t)
            own_t, own_v = np.concatenate([own_t, t]), (values if not len(own_v) else np.concatenate([own_v, values]))
        if not len(own_t):
            break
        inside = (times >= kept.span_s[0]) & (times <= own_t[-1])
        kept.outside += int((~inside).sum())
        t = times[inside]
        if len(t):
            right = np.clip(np.searchsorted(own_t, t), 1, len(own_t) - 1)
            kept.bridged_s = max(kept.bridged_s, float(np.max(own_t[right] - own_t[right - 1])))
            kept.made += len(t)
            yield t, np.column_stack([np.interp(t, own_t, own_v[:, c]) for c in range(own_v.shape[1])])
        start = max(int(np.searchsorted(own_t, times[-1], side="right")) - 1, 0)  # the last sample at or before the block's end on
        own_t, own_v = own_t[start:], own_v[start:]
    for t, _ in blocks:  # the rest, past the target's end, read for its checks and its count alone
        read(t)


def xdf_streams(path: str | Path, mapping: dict[str, tuple[str, str]], units: dict[str, str] | None = None) -> tuple[dict[str, Stream], list[str]]:
    """The mapped streams of an XDF file (LSL stream name -> (our stream name, kind); ``units`` by our stream name) and the
    names of the file's LSL streams that no mapping names (reported, never used)."""
    import pyxdf

    path = Path(path)
    if not path.is_file():
        raise SessionError(f"{path}: not found")
    try:
        ids = {name: sid for sid, name in xdf_stream_names(path).items()}  # a name given twice: its last stream, as before
        unknown = [n for n in mapping if n not in ids]
        if unknown:
            raise SessionError(f"{path}: no LSL stream {', '.join(repr(n) for n in unknown)} (the file has: {', '.join(ids) or 'none'})")
        # only the mapped streams are read into memory: an EEG or a video stream beside the IMU's is skipped chunk by chunk
        found, _ = pyxdf.load_xdf(str(path), select_streams=sorted({ids[n] for n in mapping}))
    except SessionError:
        raise
    except Exception as exc:  # noqa: BLE001 - pyxdf's own errors are many kinds; name the file
        raise SessionError(f"{path}: not a readable XDF file ({type(exc).__name__}: {exc})") from None
    by_name = {str(s["info"]["name"][0]): s for s in found}
    out: dict[str, Stream] = {}
    for lsl_name, (name, kind) in mapping.items():
        entry = _entry(kind)
        xdf = by_name[lsl_name]
        values = np.asarray(xdf["time_series"], dtype=float)
        t = np.asarray(xdf["time_stamps"], dtype=float)
        if values.ndim != 2 or values.shape[1] != len(entry.columns):
            raise SessionError(f"{path}: LSL stream {lsl_name!r} has {values.shape[1] if values.ndim == 2 else 1} channels; kind {kind} "
                               f"needs {len(entry.columns)} ({', '.join(entry.columns)})")
        if not len(t):
            raise SessionError(f"{path}: LSL stream {lsl_name!r} holds no samples")
        unit = (units or {}).get(name)
        out[name] = Stream(name, kind, t, values * _unit_factor(kind, unit), entry.columns, 0.0,
                           {"description": f"LSL stream {lsl_name!r} of {path.name}" + (f"; converted from {unit}" if unit else "")})
    return out, [n for n in ids if n not in mapping]


def xdf_stream_names(path: Path) -> dict[int, str]:
    """An XDF file's streams, id -> name, from their header chunks alone (every other chunk skipped unread: the names of a
    recording of any size, read before any sample is). The format: the magic ``XDF:``, then chunks of [a byte saying how
    many bytes hold the length: 1, 4 or 8][the length][a 2-byte tag][the content]; a stream header (tag 2) holds the
    stream's 4-byte id and its XML ``<info><name>``."""
    from xml.etree import ElementTree

    from pyxdf.pyxdf import open_xdf  # pyxdf's opener: a .xdfz is gzip; checks the magic

    names: dict[int, str] = {}
    with open_xdf(str(path)) as handle:
        while size := handle.read(1):
            if size[0] not in (1, 4, 8):
                raise ValueError(f"a chunk's length takes {size[0]} bytes at byte {handle.tell() - 1} (1, 4 or 8 in XDF)")
            length = int.from_bytes(handle.read(size[0]), "little")
            tag = int.from_bytes(handle.read(2), "little")
            if tag == 2:
                sid = int.from_bytes(handle.read(4), "little")
                names[sid] = str(ElementTree.fromstring(handle.read(length - 6)).findtext("name", default=""))
            else:
                handle.seek(length - 2, 1)
    return names


def write_xdf(session: Session, path: str | Path) -> Path:
    """The session's streams as an XDF 1.0 file (LabRecorder's format): one LSL stream per session stream, named after
    it, its kind as the stream type, double64 channels in the kind's column order, every sample with its time stamp
    (``import xdf PATH --map NAME=NAME`` reads it back). What ``fusegraph live --record`` writes beside the session."""
    import struct
    from xml.sax.saxutils import escape

    def chunk(tag: int, content: bytes) -> bytes:
        return struct.pack("<BQH", 8, len(content) + 2, tag) + content

    data = b"XDF:" + chunk(1, b"<?xml version='1.0'?><info><version>1.0</version></info>")
    for sid, (name, stream) in enumerate(session.streams.items(), start=1):
        values = np.asarray(stream.values, dtype=float)
        columns = "".join(f"<channel><label>{escape(c)}</label></channel>" for c in stream.columns)
        info = (f"<?xml version='1.0'?><info><name>{escape(name)}</name><type>{escape(stream.kind)}</type>"
                f"<channel_count>{values.shape[1]}</channel_count><nominal_srate>0</nominal_srate><channel_format>double64</channel_format>"
                f"<source_id>fusegraph:{escape(session.system)}:{escape(name)}</source_id><created_at>0</created_at>"
                f"<desc><channels>{columns}</channels></desc></info>")
        data += chunk(2, struct.pack("<I", sid) + info.encode())
        samples = np.column_stack([stream.t, values])
        body = b"".join(struct.pack("<Bd", 8, row[0]) + struct.pack(f"<{values.shape[1]}d", *row[1:]) for row in samples)
        data += chunk(3, struct.pack("<I", sid) + struct.pack("<BI", 4, len(samples)) + body)
        footer = (f"<?xml version='1.0'?><info><first_timestamp>{stream.t[0]!r}</first_timestamp><last_timestamp>{stream.t[-1]!r}"
                  f"</last_timestamp><sample_count>{len(stream.t)}</sample_count></info>")
        data += chunk(6, struct.pack("<I", sid) + footer.encode())
    path = Path(path)
    path.write_bytes(data)
    return path


NEW_SESSION = "imported (times from time_origin_s on the source's clock)"
"""The description a session made by an import says of itself."""


def destination(root: Path, system: str | None, names: list[str], truth: bool) -> dict[str, object] | None:
    """Where an import writes: the tables of the session already in ``root`` that the streams ``names`` (or with ``truth``,
    the one stream) may be added to, or None for a new session there; an error naming the clash otherwise (another system,
    a name or a truth it has already, a new session without ``--system`` or in a folder of other files)."""
    toml = root / "session.toml"
    if not toml.is_file():
        if system is None:
            raise SessionError(f"--out {root}: a new session: say whose with --system (head, attitude9, gaze, bicycle, walking, ultrasonic)")
        if root.exists() and any(root.iterdir()):
            raise SessionError(f"--out {root}: a folder with other files and no session.toml; give a new folder or a session to add to")
        return None
    _, spec, found = read_session_spec(root)
    if system is not None and system != found:
        raise SessionError(f"{toml}: a {found} session; --system {system} does not match")
    if truth and "truth" in spec:
        raise SessionError(f"{toml}: already has a truth (remove [truth] first to replace it)")
    clash = [] if truth else [n for n in names if n in spec["streams"]]
    if clash:
        raise SessionError(f"{toml}: already has stream {', '.join(repr(c) for c in clash)} (import it under another --name)")
    return spec


def add_to_session(out: str | Path, streams: dict[str, Stream], system: str | None, truth: bool = False) -> Path:
    """Write ``streams`` as a new session in ``out`` (``system`` required) or add them to the session already there.
    Times start at zero at the first sample of the new session (an added stream is moved by the same origin)."""
    root = Path(out)
    if truth and len(streams) != 1:
        raise SessionError("--truth: one stream at a time becomes the truth")
    if destination(root, system, list(streams), truth) is not None:
        session = load_session(root)
        origin = float(session.meta.get("session", {}).get("time_origin_s", 0.0))
    else:
        origin = min(float(s.t[0]) for s in streams.values())
        session = Session(str(system), {}, None, {"session": {"system": system, "time_origin_s": origin, "description": NEW_SESSION}})
    moved = {name: replace(s, t=s.t - origin) for name, s in streams.items()}
    if truth:
        (stream,) = moved.values()
        session = replace(session, truth=replace(stream, name="truth"))
    else:
        session = replace(session, streams={**session.streams, **moved})
    session = replace(session, path=None)
    for name, stream in session.streams.items():
        if not np.all(np.diff(stream.t) >= 0):
            raise SessionError(f"stream {name!r}: times go backwards (is --columns t= the time column?)")
    return save_session(session, root)


def _entry(kind: str):  # type: ignore[no-untyped-def]
    catalogue = sensor_catalogue()
    if kind not in catalogue:
        raise SessionError(f"--kind {kind!r}: not a stream kind (kinds: {', '.join(catalogue)})")
    return catalogue[kind]


def _unit_factor(kind: str, units: str | None) -> float:
    if units is None:
        return 1.0
    conversions = _entry(kind).unit_conversions
    if units not in conversions:
        accepted = ", ".join(conversions) or "none: the kind has one unit"
        raise SessionError(f"--units {units!r}: kind {kind} converts {accepted}")
    return float(conversions[units])


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
