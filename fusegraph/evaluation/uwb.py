"""A recorded UWB run through the session path: imported twice (the ranges unlabelled, and labelled as a UWB system
reports them), each run by the ultrasonic preset's online solver and scored by its own scorer."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from ..datasets.importers import uwb_session
from ..metrics import oracle_labels, score_run
from ..session import SessionError
from .runner import solve_session


def bench_uwb(directory: str | Path) -> dict[str, Any]:
    """``labelled_rmse_m`` / ``unlabelled_rmse_m`` (the preset's ``rmse_all_m``: every estimate, lost tracks included),
    ``assoc_acc`` and ``lost_frac`` of the unlabelled run, the clock offset the import found from the raw ranges,
    ms per epoch, the association the geometry alone allows (no truth; near chance: a warning), and ``assoc_oracle``: the
    association of the ranges assigned against the TRUE tag positions through the declared calibration (the ceiling any
    tracker meets: neighbouring tags' ranges at an anchor differ by less than the range noise; truth only scores it)."""
    session = uwb_session(Path(directory), labelled=False)
    if session.truth is None:
        raise SessionError(f"{directory}: no motion_capture_<run>.csv beside the UWB run: nothing to score against "
                           "(`import uwb` + `run` track it without)")
    unlabelled = solve_session(session, "online")
    labelled = solve_session(uwb_session(Path(directory), labelled=True), "online")
    assert unlabelled.metrics is not None and labelled.metrics is not None
    epochs = unlabelled.estimate.extras["epochs"]  # the run's own epochs, as its scorer reads them
    oracle = score_run(epochs, oracle_labels(epochs, gate_chi2=1e12), None)  # no gate: every UWB range is some tag's
    expected = float(unlabelled.estimate.extras.get("assoc_expected_geometry", float("nan")))
    tags = int(unlabelled.session.streams_of_kind("ranges")[0].meta["transmitters"])
    if expected < 1.0 / tags + 0.1:  # the geometry tells (almost) no range set apart: the tracker's continuity is all it has
        warnings.warn(f"UWB self-check: from the geometry alone the association is {expected:.0%} (chance {1 / tags:.0%}): the unlabelled "
                      "association is no better than guessing", RuntimeWarning, stacklevel=2)
    return {
        "labelled_rmse_m": labelled.metrics["rmse_all_m"],
        "unlabelled_rmse_m": unlabelled.metrics["rmse_all_m"],
        "assoc_acc": unlabelled.metrics["assoc_acc"],
        "lost_frac": unlabelled.metrics["lost_frac"],
        "clock_offset_s": float(unlabelled.session.meta["session"]["truth_clock_offset_s"]),
        "ms_per_epoch": unlabelled.metrics["ms_per_epoch"],
        "assoc_expected_geometry": expected,
        "assoc_oracle": oracle.assoc_acc,
    }
