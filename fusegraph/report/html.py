"""A report to look at in a browser: one self-contained HTML file (plotly's script embedded once, no network), the table,
then per session an interactive figure of each solver's estimate against the truth, its error with the solver's own
3-sigma band, and the session's warnings. It draws the report and traces it is handed (``results.Trace``)."""

from __future__ import annotations

import html
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..results import Trace

COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")


def session_figure(name: str, traces: Sequence[Trace]) -> Any:
    """One session: a row per component (estimates and truth), then a row per component of the error with each solver's
    3-sigma band, where there is a truth."""
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    components = traces[0].components
    with_error = any(t.error is not None for t in traces)
    rows = len(components) * (2 if with_error else 1)
    titles = [*components, *(f"error {c}" for c in components)] if with_error else list(components)
    fig = make_subplots(rows=rows, cols=1, shared_xaxes=True, subplot_titles=titles, vertical_spacing=0.03)
    truth_drawn = False
    for index, trace in enumerate(traces):
        colour = COLOURS[index % len(COLOURS)]
        for d, _component in enumerate(trace.components[: len(components)]):
            fig.add_trace(go.Scatter(x=trace.t, y=trace.values[:, d], name=trace.solver, legendgroup=trace.solver, showlegend=d == 0,
                                     line={"color": colour, "width": 1.2}), row=d + 1, col=1)
            if trace.truth is not None and not truth_drawn:
                fig.add_trace(go.Scatter(x=trace.t, y=trace.truth[:, d], name="truth", legendgroup="truth", showlegend=d == 0,
                                         line={"color": "black", "width": 1.0, "dash": "dot"}), row=d + 1, col=1)
            if trace.error is not None:
                row = len(components) + d + 1
                if trace.sigma3 is not None:
                    band = np.concatenate([trace.sigma3[:, d], -trace.sigma3[::-1, d]])
                    fig.add_trace(go.Scatter(x=np.concatenate([trace.t, trace.t[::-1]]), y=band, fill="toself", fillcolor=colour,
                                             opacity=0.15, line={"width": 0}, name=f"{trace.solver} 3-sigma", legendgroup=trace.solver,
                                             showlegend=False, hoverinfo="skip"), row=row, col=1)
                fig.add_trace(go.Scatter(x=trace.t, y=trace.error[:, d], name=f"{trace.solver} error", legendgroup=trace.solver,
                                         showlegend=False, line={"color": colour, "width": 1.0}), row=row, col=1)
        truth_drawn = truth_drawn or trace.truth is not None
    fig.update_layout(height=170 * rows + 120, title=name, margin={"l": 60, "r": 20, "t": 60, "b": 40}, template="plotly_white",
                      legend={"orientation": "h", "y": 1.02, "x": 0})
    fig.update_xaxes(title_text="t [s]", row=rows, col=1)
    return fig


def write_html(report: Mapping[str, Any], table: str, traces: Mapping[str, Sequence[Trace]], path: str | Path) -> Path:
    """The page: the report's table as text, then per session its figure and warnings; plotly's script inlined once so the
    file works offline and alone."""
    from plotly.offline import get_plotlyjs

    path = Path(path)
    parts = [f"<h1>fusegraph report: {html.escape(str(report['system']))}</h1>",
             "<p>Means over the sessions each solver scored; each figure below: the estimates against the truth (dotted), the "
             "error and each solver's own 3-sigma band. Drag to zoom, double-click to reset, click a legend entry to hide it.</p>",
             f"<pre class='table'>{html.escape(table)}</pre>"]
    for name, session_traces in traces.items():
        parts.append(f"<h2 id='{html.escape(name)}'>{html.escape(name)}</h2>")
        if report.get("in_sample", {}).get(name):  # its figures are in-sample: say so where they are drawn
            parts.append("<p class='in-sample'>IN-SAMPLE: settings on main were chosen on this recording ("
                         + html.escape("; ".join(report["in_sample"][name])) + ")</p>")
        said = sorted({w for row in report["sessions"].get(name, {}).values() for w in row.get("warnings", [])})
        failed = [f"{solver}: {row['error']}" for solver, row in report["sessions"].get(name, {}).items() if row.get("status") == "failed"]
        if said or failed:
            parts.append("<ul class='warnings'>" + "".join(f"<li>warning: {html.escape(w)}</li>" for w in said)
                         + "".join(f"<li>failed: {html.escape(f)}</li>" for f in failed) + "</ul>")
        if session_traces:
            figure = session_figure(name, session_traces)
            parts.append(figure.to_html(full_html=False, include_plotlyjs=False, config={"responsive": True}))
    page = ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>fusegraph report</title>"
            "<style>body{font-family:sans-serif;margin:2em;max-width:1400px} pre.table{font-size:12px;overflow-x:auto;"
            "background:#f6f6f6;padding:1em} ul.warnings{color:#8a4b00;font-size:13px}</style>"
            f"<script type='text/javascript'>{get_plotlyjs()}</script></head><body>" + "\n".join(parts) + "</body></html>")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page, encoding="utf-8")
    return path
