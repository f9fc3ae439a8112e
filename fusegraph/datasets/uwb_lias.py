"""UWB ranging of 3 tags on a rigid trolley from 8 anchors, with motion capture (Jiang et al., ICRA 2023).

One run per folder (read in place, e.g. ``../shared/data/uwb_lias`` fast, ``uwb_lias_slow``): ``UWB_<run>.csv`` (no
header: a wall-clock time, then 24 ranges in metres ordered a0-t0, a0-t1, a0-t2, a1-t0, ... a7-t2; some
empty), ``motion_capture_<run>.csv`` (header ``time,x,y,z,rotation,,,``: centroid
position in metres and a quaternion; optional: without it the run has no truth), ``README.md`` (the dataset's own, or a copy
renamed ``SOURCE_README.md``: anchor coordinates, tag offsets in the
trolley frame, as Markdown tables).

The quaternion is stored SCALAR FIRST (w, x, y, z), as SOURCE_README.md says; its rigid body frame
is the motion capture's, turned half a turn about x from the frame the tag offsets are given in
(z down: the first sample reads w = 0.004, x = 0.9998). Composing the offsets through that half turn
explains the labelled ranges with a spread (MAD after a bias per anchor) of 4.9 cm; the earlier
reading (scalar last, offsets as given) left 10.4 cm, the documented order without the half turn
20 cm. ``tests/test_ultrasonic.py`` checks it on the data.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import FloatArray
from ..session import SessionError

DEFAULT_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "uwb_lias"
def run_files(directory: Path) -> tuple[Path, Path | None]:
    """The one run in a folder: its ``UWB_*.csv`` and the ``motion_capture_*.csv`` of the same run name (None: a run
    without motion capture, which tracks but has no truth to score)."""
    ranges = sorted(directory.glob("UWB_*.csv"))
    if len(ranges) != 1:
        found = ", ".join(p.name for p in ranges) or "none"
        raise SessionError(f"{directory}: one UWB run per folder (UWB_<run>.csv with motion_capture_<run>.csv); found {found}")
    run = ranges[0].name.removeprefix("UWB_")
    mocap = directory / f"motion_capture_{run}"
    return ranges[0], mocap if mocap.is_file() else None


@dataclass(frozen=True)
class UwbRecording:
    """Ranges per epoch, anchor and tag, and the motion capture of the trolley."""

    t: FloatArray
    """UWB epoch times (K,), seconds since midnight of the recording day."""
    ranges: FloatArray
    """(K, anchors, tags) ranges in metres, NaN where missing; labelled (tag known)."""
    anchors: FloatArray
    """(A, 3) anchor positions, metres."""
    tag_offsets: FloatArray
    """(T, 3) tag positions in the trolley frame, metres."""
    mocap_t: FloatArray
    """Motion capture times (M,), seconds since midnight."""
    mocap_position: FloatArray
    """(M, 3) trolley centroid, metres."""
    mocap_quat_wxyz: FloatArray
    """(M, 4) attitude of the motion-capture rigid body (z down), scalar first as in the file."""
    local_R_offsets: FloatArray = field(default_factory=lambda: np.diag([1.0, -1.0, -1.0]))
    """Rotation from the frame the tag offsets are given in (z up) to the rigid-body frame (z down):
    half a turn about x."""

    def between(self, start_s: float, end_s: float = np.inf) -> UwbRecording:
        """The UWB epochs from ``start_s`` to ``end_s`` seconds after the first (the motion capture is kept whole)."""
        from dataclasses import replace

        keep = (self.t >= self.t[0] + start_s) & (self.t <= self.t[0] + end_s)
        return replace(self, t=self.t[keep], ranges=self.ranges[keep])

    def tags_truth(self, t: FloatArray) -> FloatArray:
        """(len(t), T, 3) tag positions from the motion capture (centroid + R local_R_offsets offset), interpolated at t."""
        from ..geometry import matrix_from_quat, quat_normalize

        pos = np.column_stack([np.interp(t, self.mocap_t, self.mocap_position[:, i]) for i in range(3)])
        idx = np.clip(np.searchsorted(self.mocap_t, t), 0, len(self.mocap_t) - 1)
        rot = matrix_from_quat(quat_normalize(self.mocap_quat_wxyz[idx]))
        return pos[:, None, :] + np.einsum("nij,tj->nti", rot, self.tag_offsets @ self.local_R_offsets.T)


def _seconds(stamp: str, path: Path, row: int) -> float:
    try:
        clock = stamp.strip().split(" ")[1]
        h, m, s = clock.split(":")
        return 3600.0 * int(h) + 60.0 * int(m) + float(s)
    except (IndexError, ValueError):
        raise SessionError(f"{path}: row {row}: time '{stamp}' is not 'YYYY-MM-DD H:MM:SS.fff'") from None


def _table(text: str, label: str) -> FloatArray:
    rows = re.findall(rf"\|\s*{label}\s+(\d+)\s*\|\s*([-\d.]+)\s*\|\s*([-\d.]+)\s*\|\s*([-\d.]+)\s*\|", text)
    return np.array([[float(x), float(y), float(z)] for _, x, y, z in sorted(rows, key=lambda r: int(r[0]))])


README_NAMES = ("README.md", "SOURCE_README.md")
"""Where the anchors and tag offsets are: the dataset's own README.md (as published), or SOURCE_README.md (a copy renamed
beside the runs); looked for in the run's folder and the folders above it (the published layout keeps one README at the top)."""


def readme_file(directory: Path) -> Path:
    """The README with the anchor and tag tables for a run folder (``README_NAMES``, here or up to two folders above)."""
    for folder in (directory, directory.parent, directory.parent.parent):
        for name in README_NAMES:
            candidate = folder / name
            if candidate.is_file() and "Anchor" in candidate.read_text(errors="replace"):
                return candidate
    raise SessionError(f"{directory}: no README.md (or SOURCE_README.md) with the anchors' and tags' tables here or above: "
                       "keep the dataset's README.md beside the runs, as published")


def load_uwb_lias(directory: str | Path = DEFAULT_DIR) -> UwbRecording:
    """One run (any speed): ranges, anchors and tag offsets, motion capture (empty arrays when the folder has none)."""
    directory = Path(directory)
    ranges_file, mocap_file = run_files(directory)
    readme_path = readme_file(directory)
    readme = readme_path.read_text()
    anchors, tags = _table(readme, "Anchor"), _table(readme, "Tag")
    if anchors.shape != (8, 3) or tags.shape != (3, 3):
        raise SessionError(f"{readme_path}: expected 8 anchors and 3 tags, found {len(anchors)} and {len(tags)}")
    t, ranges = [], []
    with open(ranges_file) as f:
        for row, line in enumerate(f, start=1):
            cells = line.rstrip("\n").split(",")
            if len(cells) != 25:
                raise SessionError(f"{ranges_file}: row {row}: {len(cells)} columns, expected 25 (time + 24 ranges)")
            t.append(_seconds(cells[0], ranges_file, row))
            ranges.append([float(c) if c.strip() not in ("", "nan", "NaN") else np.nan for c in cells[1:]])
    mt: list[float] = []
    mp: list[list[float]] = []
    mq: list[list[float]] = []
    if mocap_file is not None:
        with open(mocap_file) as f:
            next(f)
            for row, line in enumerate(f, start=2):
                cells = line.rstrip("\n").split(",")
                if len(cells) < 8:
                    raise SessionError(f"{mocap_file}: row {row}: {len(cells)} columns, expected 8")
                mt.append(_seconds(cells[0], mocap_file, row))
                mp.append([float(c) for c in cells[1:4]])
                mq.append([float(c) for c in cells[4:8]])  # w, x, y, z
    return UwbRecording(
        np.array(t), np.array(ranges).reshape(-1, 8, 3), anchors, tags, np.array(mt), np.array(mp).reshape(-1, 3), np.array(mq).reshape(-1, 4)
    )


def clock_offset_from_ranges(rec: UwbRecording, search_s: float = 1.0, step_s: float = 0.005, widest_s: float = 16.0) -> float:
    """Motion-capture time minus UWB time, from the raw data alone: the offset at which the measured ranges
    best match the ranges the motion capture's tag positions give (a constant bias per anchor and tag
    removed; median absolute residual). No estimate enters, so the offset cannot favour any method.
    Searched over +-``search_s`` (a few ms on the fast run, about 0.3 s on the slow one) in 20 ms steps on every
    fourth epoch, the range doubled while the best lies at its edge (another run's clocks may differ by more; up to
    +-``widest_s``, else an error: the two files do not overlap), then on the ``step_s`` grid within 30 ms of the best
    over every epoch."""
    anchors = rec.anchors[None, :, None, :]

    def cost(offset: float, every: int = 1) -> float:
        t = rec.t[::every] + offset
        inside = (t >= rec.mocap_t[0]) & (t <= rec.mocap_t[-1])
        if inside.sum() < 100 // every:
            return np.inf
        tags = rec.tags_truth(t[inside])[:, None, :, :]  # (K, 1, T, 3)
        residual = rec.ranges[::every][inside] - np.linalg.norm(tags - anchors, axis=3)
        heard = np.isfinite(residual).any(axis=0)  # an anchor-tag pair that never ranged has no bias to remove
        residual = residual[:, heard] - np.nanmedian(residual[:, heard], axis=0, keepdims=True)
        return float(np.nanmedian(np.abs(residual)))

    span, costs = search_s, {}
    while True:
        coarse = 0.02 * np.round(np.arange(-span, span + 1e-9, 0.02) / 0.02)
        for o in coarse:
            if float(o) not in costs:
                costs[float(o)] = cost(float(o), every=4)
        centre = min(costs, key=lambda o: costs[o])
        if abs(centre) < span - 0.1 or not np.isfinite(costs[centre]):
            break
        if span >= widest_s:
            raise SessionError(f"UWB clock offset: the best match lies at +-{span:g} s, the edge of the search (do the UWB and "
                               "motion-capture files cover the same run?)")
        span = min(2.0 * span, widest_s)
    if not np.isfinite(costs[centre]):
        raise SessionError("UWB clock offset: the UWB and motion-capture times do not overlap at any offset searched")
    fine = step_s * np.round(np.arange(centre - 0.03, centre + 0.03 + 1e-9, step_s) / step_s)
    fine_costs = [cost(float(o)) for o in fine]
    return float(fine[int(np.argmin(fine_costs))])


def read_calibration(path: str | Path, anchors: int, tags: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A ``calibration.csv`` (``anchor,tag,bias_m,slope,sigma_m``: the dataset authors' static calibration) as (bias_m,
    scale = 1 + slope, sigma_m), each (anchors, tags); a pair the file lacks is an error naming it."""
    path = Path(path)
    if not path.is_file():
        raise SessionError(f"{path}: calibration file not found")
    lines = path.read_text().splitlines()
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    wanted = ("anchor", "tag", "bias_m", "slope", "sigma_m")
    if any(w not in header for w in wanted):
        raise SessionError(f"{path}: header must name {', '.join(wanted)} (have: {', '.join(header)})")
    table = np.full((3, anchors, tags), np.nan)
    for row, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        cells = dict(zip(header, (c.strip() for c in line.split(",")), strict=False))
        try:
            a, t = int(cells["anchor"]), int(cells["tag"])
            values = (float(cells["bias_m"]), 1.0 + float(cells["slope"]), float(cells["sigma_m"]))
        except (KeyError, ValueError):
            raise SessionError(f"{path}: row {row}: not anchor,tag,bias_m,slope,sigma_m numbers ({line!r})") from None
        if not (0 <= a < anchors and 0 <= t < tags):
            raise SessionError(f"{path}: row {row}: anchor {a} / tag {t} outside the run's {anchors} anchors and {tags} tags")
        table[:, a, t] = values
    missing = np.argwhere(np.isnan(table[0]))
    if len(missing):
        raise SessionError(f"{path}: no calibration for anchor {missing[0][0]}, tag {missing[0][1]} ({len(missing)} pairs missing)")
    if np.any(table[2] <= 0):
        raise SessionError(f"{path}: sigma_m must be > 0")
    return table[0], table[1], table[2]
