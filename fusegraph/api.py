"""One way in from Python, the same calls the command line makes: a session (simulated, loaded or imported), any solver by
name, its score against the truth, the system's picture, a report over many sessions and its page.

    import fusegraph as fg

    session = fg.simulate("attitude9", seed=0)            # or fg.load_session("sessions/mine"), fg.import_dataset(...)
    for solver in fg.solver_names(session.system):            # online, batch, the paper's baseline, the peers
        estimate = fg.solve(session, solver)              # the same as `fusegraph run SESSION --solver SOLVER`
        print(solver, fg.score(session, estimate))        # None without truth
    fg.plot(session, [fg.solve(session, "batch")], "out")  # the system's figure
    found = fg.run_report("attitude9", [session], html="out/report.html")   # = `fusegraph report attitude9 DIR --html`
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from .estimate import Result
from .session import Session


def simulate(system: str, seed: int = 0, duration_s: float | None = None, **options: Any) -> Session:
    """A seeded simulated session of ``system`` with its truth (``fusegraph simulate``; settings are chosen on seeds 100-119,
    reports score 0-9)."""
    from .scenarios import SIMULATORS

    if system not in SIMULATORS:
        raise KeyError(f"no simulator for {system!r} (systems: {', '.join(SIMULATORS)})")
    return SIMULATORS[system].simulate(seed, duration_s, **options)


def import_dataset(name: str, source: str | Path, out: str | Path, **options: Any) -> list[Session]:
    """A public dataset's recording(s) as sessions written under ``out`` (``fusegraph import``; ``fusegraph datasets`` lists
    the names and layouts) and loaded back."""
    from .datasets.importers import import_recording
    from .session import load_session

    return [load_session(path) for path in import_recording(name, source, out, **options)]


def solver_names(system: str) -> Mapping[str, str]:
    """The system's solvers by name, each with a line saying what it is."""
    from .systems.presets import PRESETS

    return PRESETS[system].solvers


def solve(session: Session, solver: str = "batch") -> Result:
    """Run one solver on a session (its checks first, as loading does): an ``Estimate`` (attitudes with covariance) or a
    ``PointEstimate`` (points)."""
    from .systems.presets import preset_for

    return preset_for(session).solve(session, solver)


def score(session: Session, estimate: Result) -> dict[str, Any] | None:
    """The system's metrics of an estimate against the session's truth (the keys `run --json` prints); None without truth."""
    from .systems.presets import preset_for

    return preset_for(session).score(session, estimate)


def plot(session: Session, estimates: Sequence[Result], out: str | Path) -> list[Path]:
    """The system's picture of the estimates against the truth, written into the folder ``out``; the files written."""
    from .report.pictures import PICTURES

    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    return PICTURES[session.system](session, list(estimates), folder)


def run_report(system: str, sessions: Sequence[Session | str | Path], solvers: Sequence[str] | None = None, html: str | Path | None = None,
           include_suspect: bool = False) -> dict[str, Any]:
    """Every solver (or ``solvers``) on every session: the dict `report --json` prints (means, a row per session, the
    suspect and the unscored said); with ``html``, also the page `report --html` writes."""
    from .evaluation.runner import load_sessions, report_sessions
    from .report.tables import format_session_report

    named: list[tuple[str, Session]] = []
    for index, item in enumerate(sessions):
        if isinstance(item, Session):
            named.append((item.path.name if item.path else f"session{index}", item))
        else:
            named += load_sessions([item])
    traces: dict[str, list[Any]] | None = {} if html is not None else None
    found = report_sessions(system, named, solvers, show_progress=False, include_suspect=include_suspect, traces=traces)
    if html is not None and traces is not None:
        from .report.html import write_html

        write_html(found, format_session_report(found), traces, html)
    return found
