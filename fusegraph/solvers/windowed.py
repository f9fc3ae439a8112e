"""A recording of any length smoothed in overlapping windows, in memory that does not grow with it.

A batch smoother holds every keyframe of the recording at once: on a 285 Hz 9-axis recording ~0.8 GB per hour, so a
day does not fit. Here the recording comes in blocks (a Session each, in time order: read from disk a block at a time,
or cut from a Session in memory); each window is the batch over its kept stretch plus ``margin_s`` on each side (the
estimate near a window's ends has the evidence of one side only, so those seconds are solved and dropped), and the two
windows' estimates are blended over the middle of their overlap so the result has no step at the seam. Only one
window's samples and graph are held at a time.

The world frame of a window's solve is its own: where gravity and a magnetometer fix it (ENU) the windows agree by
themselves; without a magnetometer the heading is arbitrary per window, and each window is turned about the vertical
onto the one before it over their overlap (``align_heading``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..estimate import Estimate
from ..geometry import FloatArray, euler_zyx_from_quat, quat_conjugate, quat_from_rotvec, quat_multiply, quat_normalize, rotvec_from_quat
from ..session import Session, Stream


@dataclass(frozen=True)
class Windows:
    """How a long recording is cut for a batch smoother."""

    window_s: float = 600.0
    """Seconds of each window's estimate that are kept (its middle). A recording no longer than ``window_s`` + 2
    ``margin_s`` is solved whole. 10 min of 285 Hz 9-axis data is ~150 MB of graph."""
    margin_s: float = 60.0
    """Seconds solved on each side of the kept part and dropped; the neighbours are blended over its middle half.
    A minute lets the gyro bias and the magnetometer's levelling settle (the batch's heading pass levels with the
    previous pass's attitude), well beyond the bias walk's correlation over one keyframe."""

    def __post_init__(self) -> None:
        if not (self.window_s > 0 and self.margin_s >= 0 and self.window_s >= self.margin_s):
            raise ValueError(f"windows: window_s ({self.window_s}) must be > 0 and >= margin_s ({self.margin_s}) >= 0")

    def needed(self, duration_s: float) -> bool:
        """Whether a recording this long is cut at all."""
        return duration_s > self.window_s + 2.0 * self.margin_s


def recording_span(session: Session) -> tuple[float, float]:
    """First and last sample time over the session's streams, a calibration recording (its own clock) aside."""
    timed = [s for s in session.streams.values() if not s.own_recording and len(s)]
    return min(float(s.t[0]) for s in timed), max(float(s.t[-1]) for s in timed)


def session_blocks(session: Session, block_s: float) -> Iterator[Session]:
    """``session`` cut into blocks of ``block_s`` seconds in time order (the truth left out: a smoother never reads it)."""
    lo, end = recording_span(session)
    while lo <= end:
        hi = lo + block_s
        yield Session(session.system, {name: (s if s.own_recording else s.select((s.t >= lo) & (s.t < hi))) for name, s in session.streams.items()},
                      None, session.meta, session.path)
        lo = hi


class _Buffer:
    """The blocks received and not yet solved past, per stream."""

    def __init__(self) -> None:
        self.parts: dict[str, list[Stream]] = {}
        self.whole: dict[str, Stream] = {}
        self.template: Session | None = None

    def add(self, block: Session) -> None:
        self.template = self.template or block
        for name, stream in block.streams.items():
            if stream.own_recording:
                self.whole[name] = stream
            elif len(stream):
                self.parts.setdefault(name, []).append(stream)

    @property
    def start_s(self) -> float:
        return min((float(p[0].t[0]) for p in self.parts.values() if p), default=np.inf)

    @property
    def end_s(self) -> float:
        return max((float(p[-1].t[-1]) for p in self.parts.values() if p), default=-np.inf)

    def between(self, lo: float, hi: float) -> Session:
        """A session of the samples in [lo, hi]."""
        assert self.template is not None
        streams: dict[str, Stream] = dict(self.whole)
        for name, parts in self.parts.items():
            t = np.concatenate([p.t for p in parts])
            keep = (t >= lo) & (t <= hi)
            values = np.concatenate([p.values for p in parts])[keep]
            streams[name] = replace(parts[0], t=t[keep], values=values)
        return Session(self.template.system, streams, None, self.template.meta, self.template.path)

    def drop_before(self, t_s: float) -> None:
        for name, parts in self.parts.items():
            kept = [p.select(p.t >= t_s) for p in parts if p.t[-1] >= t_s]
            self.parts[name] = [p for p in kept if len(p)]


def _slice(estimate: Estimate, lo: float, hi: float, right_closed: bool = False) -> Estimate:
    keep = (estimate.t >= lo) & ((estimate.t <= hi) if right_closed else (estimate.t < hi))
    return replace(estimate, t=estimate.t[keep], quat_wxyz=estimate.quat_wxyz[keep], cov=None if estimate.cov is None else estimate.cov[keep])


def heading_offset_rad(reference_wxyz: FloatArray, other_wxyz: FloatArray) -> float:
    """The turn about the world's vertical that brings ``other``'s attitudes onto ``reference``'s (circular mean of the
    azimuth differences, rad)."""
    difference = euler_zyx_from_quat(reference_wxyz)[:, 0] - euler_zyx_from_quat(other_wxyz)[:, 0]
    finite = np.isfinite(difference)
    return float(np.arctan2(np.mean(np.sin(difference[finite])), np.mean(np.cos(difference[finite])))) if finite.any() else 0.0


def turned_about_vertical(estimate: Estimate, angle_rad: float) -> Estimate:
    """``estimate`` with its world frame turned by ``angle_rad`` about the vertical (the body-frame covariance unchanged)."""
    turn = quat_from_rotvec(np.array([0.0, 0.0, angle_rad]))
    return replace(estimate, quat_wxyz=quat_multiply(np.broadcast_to(turn, estimate.quat_wxyz.shape), estimate.quat_wxyz))


def blended(before: Estimate, after: Estimate) -> Estimate:
    """Two estimates of the same samples, weighed from all ``before`` at the first to all ``after`` at the last (on the
    geodesic between them, per sample); a sample one of them has no estimate for takes the other's."""
    if len(before.t) != len(after.t) or not np.array_equal(before.t, after.t):
        raise ValueError("blended: the two windows' estimates are not of the same samples")
    span = before.t[-1] - before.t[0] if len(before.t) > 1 else 1.0
    weight = ((before.t - before.t[0]) / span)[:, None]
    step = rotvec_from_quat(quat_multiply(quat_conjugate(before.quat_wxyz), after.quat_wxyz))
    quat = quat_normalize(quat_multiply(before.quat_wxyz, quat_from_rotvec(weight * step)))
    missing_before = ~np.isfinite(before.quat_wxyz).all(axis=1)
    missing_after = ~np.isfinite(after.quat_wxyz).all(axis=1)
    quat[missing_before] = after.quat_wxyz[missing_before]
    quat[missing_after & ~missing_before] = before.quat_wxyz[missing_after & ~missing_before]
    cov = None
    if before.cov is not None and after.cov is not None:
        cov = np.where((weight < 0.5)[:, :, None], before.cov, after.cov)
    return replace(after, quat_wxyz=quat, cov=cov)


def _windows_of(blocks: Iterable[Session], buffer: _Buffer, windows: Windows) -> Iterator[tuple[float, float, bool]]:
    """The windows of a recording given as ``blocks`` (Sessions in time order), each as (where its kept part starts, where
    it ends, whether it is the last) once ``buffer`` holds it and its right margin: a window is given when the one after it
    would not be the recording's last, and the recording's end goes to the last (one window more when over ``window_s``
    plus both margins remain). When the caller comes back, the buffer lets go of what the next window does not need."""
    def after(kept_from: float) -> float:  # the next window's kept part starts here; what it does not need is let go
        buffer.drop_before(kept_from + windows.window_s - windows.margin_s)
        return kept_from + windows.window_s

    kept_from: float | None = None
    for block in blocks:
        buffer.add(block)
        if kept_from is None and np.isfinite(buffer.start_s):
            kept_from = buffer.start_s
        while kept_from is not None and buffer.end_s >= kept_from + 2.0 * windows.window_s + windows.margin_s:
            yield kept_from, kept_from + windows.window_s, False
            kept_from = after(kept_from)
    if kept_from is None:
        raise ValueError("a windowed run: no samples")
    while buffer.end_s > kept_from + windows.window_s + 2.0 * windows.margin_s:  # one more full window before the last
        yield kept_from, kept_from + windows.window_s, False
        kept_from = after(kept_from)
    yield kept_from, buffer.end_s, True


def smooth_in_windows(
    blocks: Iterable[Session],
    solve: Callable[[Session], Estimate],
    windows: Windows,
    align_heading: bool,
    progress: Callable[[float], None] | None = None,
) -> Iterator[Estimate]:
    """The smoothed estimate of a recording given as ``blocks`` (Sessions in time order), in pieces in time order: each
    window ``solve``d (a batch over a Session) and the pieces of consecutive windows blended over ``margin_s`` around
    their seam. ``progress(t_s)`` after each window. Pieces share the method name and carry the window's extras."""
    buffer = _Buffer()
    half = 0.5 * windows.margin_s
    tail: Estimate | None = None  # the previous window over [seam - half, seam + half]
    for kept_from, seam_hi, last in _windows_of(blocks, buffer, windows):
        lo = kept_from - windows.margin_s  # the first window: nothing lies before its start
        hi = seam_hi if last else seam_hi + windows.margin_s
        estimate = solve(buffer.between(lo, hi))
        if tail is not None:
            this = _slice(estimate, tail.t[0], tail.t[-1], right_closed=True)
            if align_heading:
                estimate = turned_about_vertical(estimate, heading_offset_rad(tail.quat_wxyz, this.quat_wxyz))
                this = _slice(estimate, tail.t[0], tail.t[-1], right_closed=True)
            yield blended(tail, this)
            start = np.nextafter(tail.t[-1], np.inf)
        else:
            start = lo
        if last:
            yield _slice(estimate, start, np.inf)
        else:
            yield _slice(estimate, start, seam_hi - half)
            tail = _slice(estimate, seam_hi - half, seam_hi + half, right_closed=True)
            if len(tail.t) == 0:
                tail = None
        if progress is not None:
            progress(hi)


Events = list[tuple[FloatArray, FloatArray]]
"""What an event detector finds in a stretch of recording: one (times (N,), rows (N, ...)) pair per kind of event."""


def events_in_windows(blocks: Iterable[Session], detect: Callable[[Session], Events], windows: Windows,
                      progress: Callable[[float], None] | None = None) -> Iterator[Events]:
    """The events of a recording given as ``blocks`` (Sessions in time order), window by window: ``detect`` runs on each
    window's kept part plus ``margin_s`` on each side (an event near a window's end is found with the samples around it,
    as in the whole recording), and each window gives the events whose times fall in its kept part, so every event comes
    from exactly one window, in time order. Only one window's samples are held. ``progress(t_s)`` after each."""
    buffer = _Buffer()
    for lo, hi, last in _windows_of(blocks, buffer, windows):
        found = detect(buffer.between(lo - windows.margin_s, hi if last else hi + windows.margin_s))
        if progress is not None:
            progress(hi)
        yield [(t[keep], rows[keep]) for t, rows in found for keep in [(t >= lo) & ((t < hi) | last)]]


def joined(pieces: Iterable[Estimate], ranked: Mapping[str, Sequence[str]] | None = None) -> Estimate:
    """The pieces of ``smooth_in_windows`` as one estimate: runtime summed over the windows, and their extras merged (counts
    summed, other numbers their largest, lists joined, a text ``ranked`` by its key's order from best to worst: the
    worst; ``windows``: how many)."""
    parts = [p for p in pieces if len(p.t)]
    if not parts:
        raise ValueError("joined: no estimate")
    covs = [p.cov for p in parts if p.cov is not None]
    cov: FloatArray | None = np.concatenate(covs) if len(covs) == len(parts) else None
    windows: dict[int, tuple[dict[str, Any], float]] = {}  # a window's pieces share its extras: count it once
    for p in parts:
        windows.setdefault(id(p.extras), (p.extras, p.runtime_s))
    runtime = float(sum(r for _, r in windows.values() if np.isfinite(r)))
    merged: dict[str, Any] = {}
    for extras, _ in windows.values():
        for key, value in extras.items():
            if key not in merged:
                merged[key] = list(value) if isinstance(value, list) else value
            elif isinstance(value, bool) or value is None:
                continue
            elif isinstance(value, int):
                merged[key] += value
            elif isinstance(value, float):
                merged[key] = value if not np.isfinite(merged[key]) or value > merged[key] else merged[key]
            elif isinstance(value, list):
                merged[key] += value
            elif isinstance(value, str) and ranked and key in ranked:
                merged[key] = max(merged[key], value, key=list(ranked[key]).index)
    merged["windows"] = len(windows)
    return Estimate(parts[0].method, np.concatenate([p.t for p in parts]), np.concatenate([p.quat_wxyz for p in parts]), cov, runtime, merged)
