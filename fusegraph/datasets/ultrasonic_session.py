"""Ultrasonic/UWB sessions on disk: unlabelled distances per receiver and epoch, as a session directory.

``ranges.csv`` (kind ``ranges``) has one row per distance heard: ``t`` (the epoch's emission time,
shared by its rows), ``receiver`` (index into ``receivers_m``), ``range_m``; an optional
``truth_label`` column (scoring only: the transmitter index, ``-1 - n`` for an echo of n) is never
read by an estimator. ``truth.csv`` (kind ``tag_position``): ``t, tag, x, y, z`` per transmitter and epoch.
"""

from __future__ import annotations

import numpy as np

from ..geometry import FloatArray
from ..scenarios.ultrasonic import RangeEpochs
from ..session import KIND_COLUMNS, Session, SessionError, Stream, read_stream_csv


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
    labels_all = _labels(session, stream.name)
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
    return RangeEpochs(times, receivers, ranges, labels, positions, float(stream.meta.get("sigma_m", 0.005)))


def _labels(session: Session, name: str) -> FloatArray | None:
    """The optional ``truth_label`` column of the stream's file (scoring only)."""
    stream = session.stream(name)
    if "truth_label" in stream.columns:
        return stream.values[:, stream.columns.index("truth_label")]
    if session.path is None:
        return None
    path = session.path / str(session.stream(name).meta.get("file", f"{name}.csv"))
    header = path.read_text(encoding="utf-8-sig").splitlines()[0].split(",")
    if "truth_label" not in [h.strip() for h in header]:
        return None
    _, values = read_stream_csv(path, ("truth_label",), name, repeated_times=True)
    return values[:, 0]
