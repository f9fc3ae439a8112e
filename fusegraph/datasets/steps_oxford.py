"""Oxford step-counter recordings (phone accelerometer, manually counted steps).

``<recording>/accelerometer.csv``: no header; timestamp (ns), sensor type, ax, ay, az (m/s^2).
``stats.csv``: ``#dir, user, phone, position, surface, duration(s), steps`` with the true count.
Salvi et al., EMBC 2018, CC BY 4.0.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import FloatArray

DEFAULT_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "steps_oxford"


@dataclass(frozen=True)
class StepRecording:
    """One recording: accelerometer samples and the manually counted steps."""

    name: str
    t: FloatArray
    """Seconds from the first sample, shape (N,)."""
    accel_m_s2: FloatArray
    """Accelerometer, phone frame, shape (N, 3)."""
    true_steps: int
    """Manually counted steps (stats.csv)."""
    position: str
    """Where the phone was carried (FrontPocket, BackPocket, NeckPouch, ...)."""


def read_stats(directory: Path) -> dict[str, tuple[str, int]]:
    """recording -> (position, steps) from stats.csv; raises naming the file and row."""
    path = Path(directory) / "stats.csv"
    out: dict[str, tuple[str, int]] = {}
    for row, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) < 7:
            raise ValueError(f"{path}, row {row}: expected 7 fields, got {len(fields)}")
        try:
            out[fields[0]] = (fields[3], int(fields[6]))
        except ValueError as err:
            raise ValueError(f"{path}, row {row}: steps {fields[6]!r} is not an integer") from err
    return out


def load_recording(directory: Path, name: str, stats: dict[str, tuple[str, int]] | None = None) -> StepRecording:
    """One recording; samples out of time order are sorted, repeated stamps dropped (both counted in errors)."""
    directory = Path(directory)
    stats = stats if stats is not None else read_stats(directory)
    if name not in stats:
        raise ValueError(f"{directory / 'stats.csv'}: no row for recording {name!r}")
    path = directory / name / "accelerometer.csv"
    data = np.loadtxt(path, delimiter=",", ndmin=2)
    if data.shape[1] < 5:
        raise ValueError(f"{path}: expected 5 columns (ns, type, ax, ay, az), got {data.shape[1]}")
    order = np.argsort(data[:, 0], kind="stable")
    data = data[order]
    keep = np.concatenate([[True], np.diff(data[:, 0]) > 0])
    data = data[keep]
    position, steps = stats[name]
    return StepRecording(name=name, t=(data[:, 0] - data[0, 0]) * 1e-9, accel_m_s2=data[:, 2:5].copy(), true_steps=steps, position=position)


def recordings(directory: Path = DEFAULT_DIR) -> list[str]:
    """Recordings present in the folder that stats.csv counts."""
    stats = read_stats(directory)
    return sorted(name for name in stats if (Path(directory) / name / "accelerometer.csv").is_file())
