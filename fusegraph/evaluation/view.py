"""``fusegraph view``: run a session's solver (or read an estimate CSV) and write everything to look at: the
estimate as CSV and TUM, the system's picture, and for attitudes the 3D scene (``report.scene``). It runs solvers, so it
lives in evaluation; what it writes is drawn by ``report``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..estimate import Estimate
from ..report.scene import head_scene, write_head_scene
from ..session import Session

SOLVER_METHODS = {"online": "isam2", "batch": "batch", "ekf": "method2"}
"""CLI solver names -> head methods."""


def view_session(session: Session, out: Path, solver: str) -> list[Path]:
    """Any system's session: run the solver, write its estimate (CSV; TUM for attitudes) and the preset's picture."""
    from ..report.pictures import PICTURES
    from ..report.tum import write_tum
    from ..systems.presets import preset_for

    preset = preset_for(session)
    estimate = preset.solve(session, solver)
    written = [estimate.save_csv(out / f"{preset.estimate_name}_{solver}.csv")]
    if isinstance(estimate, Estimate):
        written.append(write_tum(out / f"estimate_{solver}.tum", estimate.t, estimate.quat_wxyz, comment=f"fusegraph {session.system} {solver}"))
    return written + PICTURES[preset.name](session, [estimate], out)


def view(path: str | Path, out_dir: str | Path, solver: str = "batch", truth_path: str | Path | None = None) -> list[Path]:
    """Everything a person needs to look at one result; returns the files written.

    ``path`` is a session directory (the solver runs first) or an estimate CSV written by
    ``fusegraph run`` (then ``truth_path``, a TUM file or a session directory, adds the truth).
    """
    from ..report.plots import plot_attitude_axes
    from ..report.tum import read_tum, write_tum
    from ..session import SessionError, load_session

    source, out = Path(path), Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    truth_t = truth_q = None
    if (source / "session.toml").is_file():
        from ..systems import head

        session = load_session(source)
        if session.system != "head":
            return view_session(session, out, solver)
        estimate = head.run_method(session, SOLVER_METHODS.get(solver, solver))
        if session.truth is not None:
            truth_t, truth_q = session.truth.t, session.truth.values
        name = solver
    elif source.suffix == ".csv" and source.is_file():
        estimate = Estimate.load_csv(source)
        name = source.stem
    else:
        raise SessionError(f"{source}: neither a session directory (with session.toml) nor an estimate CSV")
    if truth_path is not None:
        truth_source = Path(truth_path)
        if (truth_source / "session.toml").is_file():
            truth = load_session(truth_source).truth
            if truth is None:
                raise SessionError(f"{truth_source}/session.toml: the session has no [truth]")
            truth_t, truth_q = truth.t, truth.values
        else:
            truth_t, _, truth_q = read_tum(truth_source)
    written = [
        estimate.save_csv(out / f"estimate_{name}.csv"),
        write_tum(out / f"estimate_{name}.tum", estimate.t, estimate.quat_wxyz, comment=f"fusegraph {name}"),
    ]
    if truth_t is not None and truth_q is not None:
        written.append(write_tum(out / "truth.tum", truth_t, truth_q, comment="truth"))
        on_estimate_times = np.array([np.interp(estimate.t, truth_t, truth_q[:, i]) for i in range(4)]).T
        plot_truth_t, plot_truth_q = estimate.t, on_estimate_times / np.linalg.norm(on_estimate_times, axis=1, keepdims=True)
    else:
        plot_truth_t, plot_truth_q = estimate.t, estimate.quat_wxyz
    title = f"{source.name}: {estimate.method}" + ("" if truth_t is not None else " (no truth given)")
    written.append(plot_attitude_axes(plot_truth_t, plot_truth_q, [estimate], out / f"attitude_{name}.png", title=title))
    scene = head_scene(estimate, truth_t, truth_q, title=f"{title}: 3D view")
    written += write_head_scene(scene, out)
    return written
