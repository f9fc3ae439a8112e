"""UCI HAPT (Reyes-Ortiz et al., Neurocomputing 171, 2016): a waist-worn Galaxy S II's accelerometer and gyro at 50 Hz
with hand-labelled activity segments (``fusegraph import hapt DIR``).

Files in the folder: ``acc_expXX_userYY.txt`` (three columns, g, gravity included), ``gyro_expXX_userYY.txt`` (three
columns, rad/s; row i of both is sample i), ``labels.txt`` (experiment, user, activity id, first and last sample,
inclusive). One walking session per experiment: ``accel`` in m/s^2 (x 9.80665), ``gyro`` in rad/s, both in the phone's
own axes (undocumented: the walking front end finds gravity and the direction of travel from the data), and the labels
as the scoring-only stream ``activity`` (kind flag, role truth: the HAPT activity id per sample, 0 where no segment is
labelled). No positions: the session has no truth file.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..session import KIND_COLUMNS, Session, SessionError, Stream

DEFAULT_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "hapt"
"""Where the shared recordings are (``../shared/data/hapt`` beside the repository)."""

RATE_HZ = 50.0
"""HAPT's sampling rate, Hz."""

STANDARD_GRAVITY_M_S2 = 9.80665
"""1 g, m/s^2 (the accelerometer files are in g)."""

_NAME = re.compile(r"acc_exp(\d+)_user(\d+)\.txt$")


def experiments(directory: str | Path = DEFAULT_DIR) -> list[tuple[int, int]]:
    """(experiment, user) of every ``acc_expXX_userYY.txt`` in the folder, in order."""
    directory = Path(directory)
    if not directory.is_dir():
        raise SessionError(f"{directory}: HAPT folder not found")
    found = sorted((int(m[1]), int(m[2])) for p in directory.iterdir() if (m := _NAME.search(p.name)))
    if not found:
        raise SessionError(f"{directory}: no acc_expXX_userYY.txt (is this UCI HAPT's RawData folder?)")
    if not (directory / "labels.txt").is_file():
        raise SessionError(f"{directory}: labels.txt missing (the activity segments)")
    return found


def hapt_session(directory: str | Path, experiment: int, user: int) -> Session:
    """One experiment as a walking session (see the module docstring)."""
    directory = Path(directory)
    acc_path = directory / f"acc_exp{experiment:02d}_user{user:02d}.txt"
    gyro_path = directory / f"gyro_exp{experiment:02d}_user{user:02d}.txt"
    accel_g, gyro = _table(acc_path), _table(gyro_path)
    if len(accel_g) != len(gyro):
        raise SessionError(f"{gyro_path}: {len(gyro)} rows, {acc_path.name} has {len(accel_g)} (row i of both is sample i)")
    median_g = float(np.median(np.linalg.norm(accel_g, axis=1)))
    if not 0.5 < median_g < 2.0:
        raise SessionError(f"{acc_path}: median |a| = {median_g:.3g}, not about 1: HAPT's accelerometer files are in g")
    labels = np.loadtxt(directory / "labels.txt", dtype=int, ndmin=2)
    activity = np.zeros(len(accel_g))
    for exp, usr, act, first, last in labels:
        if exp == experiment and usr == user:
            activity[first : last + 1] = act
    t = np.arange(len(accel_g)) / RATE_HZ
    streams = {
        "accel": Stream("accel", "accel", t, accel_g * STANDARD_GRAVITY_M_S2, KIND_COLUMNS["accel"], 0.0, {"frame": "phone", "rate_hz": RATE_HZ}),
        "gyro": Stream("gyro", "gyro", t.copy(), gyro, KIND_COLUMNS["gyro"], 0.0, {"frame": "phone", "rate_hz": RATE_HZ}),
        "activity": Stream("activity", "flag", t.copy(), activity[:, None], KIND_COLUMNS["flag"], 0.0,
                           {"role": "truth", "description": "HAPT activity id per sample (0 unlabelled, 1 walking, 2 upstairs, 3 downstairs, "
                            "4 sitting, 5 standing, 6 lying, 7-12 transitions): scoring only"}),
    }
    name = f"exp{experiment:02d}_user{user:02d}"
    header = {"session": {"system": "walking", "dataset": "UCI HAPT", "trial": name, "subject": f"user{user:02d}",
                          "description": "waist-worn smartphone (belt), 50 Hz; activity hand-labelled from video"}}
    return Session("walking", streams, None, header)


def _table(path: Path) -> np.ndarray:
    if not path.is_file():
        raise SessionError(f"{path}: not found")
    try:
        values = np.loadtxt(path, ndmin=2)
    except ValueError as err:
        raise SessionError(f"{path}: {err}") from None
    if values.shape[1] != 3:
        raise SessionError(f"{path}: {values.shape[1]} columns, expected 3 (x, y, z)")
    return values


def hapt_sessions(directory: str | Path = DEFAULT_DIR) -> list[tuple[str, Session]]:
    """Every experiment of the folder as a walking session, named ``expXX_userYY``; given one recording's file
    (``acc_expXX_userYY.txt`` or its ``gyro_`` twin, ``labels.txt`` beside it), that experiment alone."""
    import re

    path = Path(directory)
    found = re.fullmatch(r"(?:acc|gyro)_exp(\d+)_user(\d+)\.txt", path.name) if path.is_file() else None
    if found:
        e, u = int(found.group(1)), int(found.group(2))
        return [(f"exp{e:02d}_user{u:02d}", hapt_session(path.parent, e, u))]
    return [(f"exp{e:02d}_user{u:02d}", hapt_session(directory, e, u)) for e, u in experiments(directory)]
