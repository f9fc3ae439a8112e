"""Oxford step-counter recordings (phone accelerometer, manually counted steps).

``<recording>/accelerometer.csv``: no header; timestamp (ns), sensor type, ax, ay, az (m/s^2).
``stats.csv``: ``#dir, user, phone, position, surface, duration(s), steps`` with the true count.
``<recording>/stepcounter.csv``: no header; timestamp (ns), right foot, left foot (0/1). Despite its name it is not
the phone's step counter: the dataset's collection app writes there the contact states it polls every ~10 ms from
its foot-switch insoles (a BLE board, one bit per foot; the phone's hardware step counter is not recorded in these
folders). Its rising edges, both feet, equal the manual counts of stats.csv on every shared recording.
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
    foot_switch_steps: int | None = None
    """Steps the foot-switch insoles recorded (``stepcounter.csv``: heel contacts of both feet); None without the file."""


def count_foot_switch_steps(path: Path) -> int:
    """Heel contacts in a ``stepcounter.csv`` (rising edges of the right and left contact columns)."""
    data = np.loadtxt(path, delimiter=",", ndmin=2)
    if data.shape[1] < 3:
        raise ValueError(f"{path}: expected 3 columns (ns, right foot 0/1, left foot 0/1), got {data.shape[1]}")
    states = data[:, 1:3]
    bad = np.flatnonzero(~np.isin(states, (0.0, 1.0)).all(axis=1))
    if bad.size:
        raise ValueError(f"{path}, row {bad[0] + 1}: foot contact states must be 0 or 1, got {states[bad[0]].tolist()}")
    states = states[np.argsort(data[:, 0], kind="stable")]
    return int(np.sum(np.diff(states, axis=0) > 0))


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
    switches = directory / name / "stepcounter.csv"
    return StepRecording(name=name, t=(data[:, 0] - data[0, 0]) * 1e-9, accel_m_s2=data[:, 2:5].copy(), true_steps=steps, position=position,
                         foot_switch_steps=count_foot_switch_steps(switches) if switches.is_file() else None)


def recordings(directory: Path = DEFAULT_DIR) -> list[str]:
    """Recordings present in the folder that stats.csv counts."""
    stats = read_stats(directory)
    return sorted(name for name in stats if (Path(directory) / name / "accelerometer.csv").is_file())
