"""The Plaza range + odometry runs (gtsam's Plaza1, Plaza2) through the session path: each imported as a walking
session driven by wheel odometry (``datasets.importers.plaza_session``, start found from the ranges), run by the
walking preset's ``dead_reckoning``, ``online`` and ``batch`` solvers and scored by its scorer."""

from __future__ import annotations

from typing import Any

from ..datasets.importers import plaza_session
from .runner import report_sessions


def bench_plaza(names: tuple[str, ...] = ("Plaza1", "Plaza2")) -> dict[str, dict[str, float]]:
    """Per recording: odometry-only, online and batch RMSE (m), and speed (x real time) of online and batch."""
    report = plaza_report(names)
    out: dict[str, dict[str, float]] = {}
    for name in names:
        rows = report["sessions"][name]
        out[name] = {
            "odometry_rmse_m": rows["dead_reckoning"]["metrics"]["rmse_m"],
            "online_rmse_m": rows["online"]["metrics"]["rmse_m"],
            "batch_rmse_m": rows["batch"]["metrics"]["rmse_m"],
            "online_x_realtime": rows["online"]["x_realtime"],
            "batch_x_realtime": rows["batch"]["x_realtime"],
        }
    return out


def plaza_report(names: tuple[str, ...] = ("Plaza1", "Plaza2")) -> dict[str, Any]:
    """``report walking`` over the imported Plaza runs (dead reckoning, online, batch)."""
    return report_sessions("walking", [(name, plaza_session(name)) for name in names], ["dead_reckoning", "online", "batch"], show_progress=False)
