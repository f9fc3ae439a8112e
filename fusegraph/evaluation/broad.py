"""BROAD: every trial through every attitude9 solver and the peers, scored by the benchmark's own metric."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..estimate import Estimate
from ..graphs.attitude9 import Attitude9Model
from ..progress import progress
from ..session import Session
from ..systems.attitude9 import METHODS, run_batch, run_ekf, run_online


def bench_broad(
    directory: str | Path | None = None,
    methods: Sequence[str] = tuple(METHODS),
    trials: Sequence[str] = (),
    model: Attitude9Model | None = None,
    show_progress: bool = True,
) -> dict[str, Any]:
    """Every BROAD trial in ``directory``, every method, in one run: RMSE (deg) and speed per trial and mean.

    ``trials`` keeps the files whose name starts with one of these prefixes (e.g. ``"01"``); all by default.
    The same ``model`` (one parameter set) serves every trial; the truth is used only to score.
    """
    from ..datasets.broad import DEFAULT_DIR, load_broad, trial_paths
    from ..metrics import broad_errors

    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {', '.join(unknown)} (have: {', '.join(METHODS)})")
    paths = [p for p in trial_paths(directory or DEFAULT_DIR) if not trials or any(p.stem.startswith(x) for x in trials)]
    if not paths:
        raise ValueError(f"{directory or DEFAULT_DIR}: no BROAD trial (*.mat) matches")
    runs: dict[str, Callable[[Session], Estimate]] = dict(METHODS)
    if model is not None:
        runs.update(online=lambda s: run_online(s, model), batch=lambda s: run_batch(s, model), ekf=lambda s: run_ekf(s, model))
    out: dict[str, Any] = {"trials": {}, "mean": {}}
    jobs = [(path, method) for path in paths for method in methods]
    session: Session | None = None
    for path, method in progress(jobs, desc="bench broad", enabled=None if show_progress else False):
        if session is None or session.path is None or session.meta["session"]["trial"] != path.stem:
            session = load_broad(path)
        assert session.truth is not None
        estimate = runs[method](session)
        movement = session.stream("movement").values[:, 0]
        errors = broad_errors(estimate.quat_wxyz, session.truth.values, movement)
        duration = float(session.stream("gyro").t[-1] - session.stream("gyro").t[0])
        out["trials"].setdefault(path.stem, {})[method] = {
            "total": errors.total,
            "heading": errors.heading,
            "inclination": errors.inclination,
            "x_realtime": duration / estimate.runtime_s,
        }
    for method in methods:
        rows = [trial[method] for trial in out["trials"].values()]
        out["mean"][method] = {key: float(np.mean([r[key] for r in rows])) for key in ("total", "heading", "inclination", "x_realtime")}
    return out
