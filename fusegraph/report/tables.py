"""Reports over sessions as text and as a figure: one row per solver (means over the sessions it scored), then one
row per session and solver; sessions without truth show what can be said without it."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..results import flatten


def _keys(headline: list[str], rows: list[dict[str, float]]) -> list[str]:
    """The system's headline metrics (the report's ``metric_keys``) that any row has (else every key the rows have)."""
    present = set().union(*[set(r) for r in rows]) if rows else set()
    keys = [k for k in headline if k in present]
    return keys or sorted(present)


def provenance_line(in_sample: dict[str, list[str]], count: int) -> str:
    """What a report's figures are: which sessions are recordings that settings on main were chosen on (``in_sample``:
    the choices by session, ``provenance.choices_that_saw``), whose figures are therefore in-sample."""
    if not in_sample:
        return "what these figures are: held out: no session is a recording (or simulated seed) any setting on main was chosen on"
    choices = sorted({what for whats in in_sample.values() for what in whats})
    studies = [c[len("tuned.toml [") : -1] for c in choices if c.startswith("tuned.toml [")]  # one entry for tuned.toml's studies
    choices = ([f"tuned.toml [{', '.join(studies)}]"] if studies else []) + [c for c in choices if not c.startswith("tuned.toml [")]
    names = ", ".join(list(in_sample)[:6]) + (f" and {len(in_sample) - 6} more" if len(in_sample) > 6 else "")
    return (f"what these figures are: IN-SAMPLE for {len(in_sample)} of the {count} sessions, recordings or simulated seeds that settings on main "
            "were chosen on "
            f"({'; '.join(choices)}): {names}" + ("; the others held out" if len(in_sample) < count else ""))


def format_session_report(report: dict[str, Any]) -> str:
    """The report as a text table (numbers as the JSON holds them, 4 significant digits), columns as wide as their content;
    a run not scored (a NaN figure) or suspect says why in its row and is counted apart from the means."""
    system = report["system"]
    methods = report["methods"]
    headline = list(report.get("metric_keys", []))
    keys = _keys(headline, [flatten(m["metrics"]) for m in methods.values()])
    width = max([len(n) for n in methods] + [8]) + 2
    cell = max([len(k) for k in keys] + [10]) + 2
    count = len(report["sessions"])
    suspect_in = any(m.get("suspect_in_means") for m in methods.values())
    lines = [f"{system}: {count} session{'s' if count != 1 else ''}; means over the sessions each solver scored"
             + ("" if suspect_in else " (suspect runs left out)")
             + (f"; data: {', '.join(report['datasets'])}" if report.get("datasets") else ""),
             provenance_line(report.get("in_sample", {}), count),
             f"{'solver':<{width}}" + "".join(f"{k:>{cell}}" for k in keys) + f"{'x real time':>13}{'scored':>8}{'not scored':>12}{'suspect':>9}{'failed':>8}"]
    for name, row in methods.items():
        flat = flatten(row["metrics"])
        cells = "".join(f"{flat[k]:{cell}.4g}" if k in flat else f"{'-':>{cell}}" for k in keys)
        lines.append(f"{name:<{width}}{cells}{row['x_realtime']:13.1f}{row['sessions_scored']:8d}{row.get('sessions_not_scored', 0):12d}"
                     f"{row.get('sessions_suspect', 0):9d}{row['sessions_failed']:8d}")
    lines.append("")
    session_width = max([len(s) for s in report["sessions"]] + [7]) + 2
    lines.append(f"{'session':<{session_width}}{'solver':<{width}}result")
    for session, per_solver in report["sessions"].items():
        for name, row in per_solver.items():
            if row["status"] == "n/a":
                text = f"not applicable: {row['error']}"
            elif row["status"] != "ok":
                text = f"FAILED {row['error']}"
            elif row["metrics"]:
                flat = flatten(row["metrics"])
                text = "  ".join(f"{k} {flat[k]:.4g}" for k in _keys(headline, [flat]))
            else:
                nt = row.get("no_truth", {})
                text = "no truth: " + "  ".join(f"{k} {v:.4g}" for k, v in nt.items())
            if row["status"] == "ok":
                text += f"  ({row['x_realtime']:.1f}x real time)"
                if "not_scored" in row:
                    text += f"  NOT SCORED: {row['not_scored']}"
                if "suspect" in row:
                    text += f"  SUSPECT: {'; '.join(row['suspect'])}"
                text += "".join(f"\n{'':<{session_width}}{'':<{width}}warning: {w}" for w in row.get("warnings", []))
            lines.append(f"{session:<{session_width}}{name:<{width}}{text}")
    return "\n".join(lines)


MAX_BAR_SESSIONS = 8
"""Over this many sessions a report's figure is a summary per solver (one point per session) instead of a bar per session
and solver, which grew into a strip 6,732 px wide over 17 sessions."""


def plot_session_report(report: dict[str, Any], path: str | Path) -> Path:
    """Bars per session and solver of the system's first headline metric (without truth anywhere: x real time); over
    ``MAX_BAR_SESSIONS`` sessions, a summary per solver."""
    from .plots import grouped_bars, plt, save_figure

    system = report["system"]
    sessions = list(report["sessions"])
    flat_rows = [flatten(r["metrics"]) for per in report["sessions"].values() for r in per.values() if r["status"] == "ok"]
    keys = _keys(list(report.get("metric_keys", [])), flat_rows)
    key = keys[0] if keys else None
    series: dict[str, list[float | None]] = {}
    for solver in report["solvers"]:
        values: list[float | None] = []
        for session in sessions:
            row = report["sessions"][session][solver]
            if row["status"] != "ok":
                values.append(None)
            elif key is not None:
                value = flatten(row["metrics"]).get(key)
                values.append(None if value is None or not np.isfinite(value) else value)
            else:
                values.append(row["x_realtime"])
        series[solver] = values
    if len(sessions) > MAX_BAR_SESSIONS:  # a summary: each solver's sessions as points, their mean as a bar; the figure keeps its size
        fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(series) + 2.0), 4.5))
        for index, values in enumerate(series.values()):
            points = np.array([v for v in values if v is not None], dtype=float)
            if len(points):
                ax.bar(index, float(np.mean(points)), color="0.85", width=0.6)
                ax.scatter(index + np.linspace(-0.2, 0.2, len(points)), points, s=12, zorder=3)
        ax.set_xticks(range(len(series)), list(series), rotation=30, ha="right")
        ax.set(ylabel=key or "x real time",
               title=f"{system}: {key or 'speed (no truth)'} over {len(sessions)} sessions (points: sessions; bar: mean)")
    else:
        fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(sessions) * max(1, len(series)) / 2), 4.5))
        grouped_bars(ax, sessions, series)
        ax.set(ylabel=key or "x real time", title=f"{system}: {key or 'speed (no truth)'} per session and solver")
        ax.legend(fontsize=8)
    ax.grid(alpha=0.3, axis="y")
    return save_figure(fig, path)
