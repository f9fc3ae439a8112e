"""An ablation study's summary as text, CSV and a figure (bars with 95 % intervals per variant and solver)."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..results import SummaryRow


def summary_table(summary: Sequence[SummaryRow]) -> str:
    """Text table: each metric's mean +- 95 % half-width (head: RMS in 1e-2 rad)."""
    width = max([len(s.variant) for s in summary] + [7])
    names = summary[0].names if summary else ()
    head = names == ("azimuth", "elevation", "roll")
    scale = 100.0 if head else 1.0
    lines = [f"{'variant':<{width}} {'solver':<14} {'runs':>5} {'failed':>6}  " + " ".join(f"{n:>20}" for n in names) + f"  {'solver s':>8}",
             f"{'':<{width}} {'':<14} {'':>5} {'':>6}  " + ("RMS [1e-2 rad], mean +- 95% CI" if head else "mean +- 95% CI")]
    for s in summary:
        if s.not_applicable:
            lines.append(f"{s.variant:<{width}} {s.solver:<14} {s.runs:>5} {s.failed:>6}  not applicable: {s.not_applicable.split(': ', 1)[-1]}")
            continue
        cells = [f"{scale * m:9.4g} +-{scale * h:8.3g}" if np.isfinite(m) else f"{'-':>20}" for m, h in zip(s.mean, s.half_width_95, strict=True)]
        lines.append(f"{s.variant:<{width}} {s.solver:<14} {s.runs:>5} {s.failed:>6}  " + " ".join(f"{c:>20}" for c in cells) + f"  {s.solver_s:8.3f}")
    return "\n".join(lines)


def write_summary(summary: Sequence[SummaryRow], out_dir: str | Path) -> list[Path]:
    """summary.csv and summary.png (bars with 95 % intervals, one panel per axis)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    csv_path = out / "summary.csv"
    with csv_path.open("w", newline="") as handle:
        writer = csv.writer(handle)
        names = summary[0].names if summary else ()
        unit = "_rad" if names == ("azimuth", "elevation", "roll") else ""
        writer.writerow(["variant", "solver", "runs", "failed", *[f"{n}_{part}{unit}" for n in names for part in ("mean", "ci95")], "solver_s"])
        for s in summary:
            writer.writerow([s.variant, s.solver, s.runs, s.failed, *[v for pair in zip(s.mean, s.half_width_95, strict=True) for v in pair], s.solver_s])
    variants = list(dict.fromkeys(s.variant for s in summary))
    solvers = list(dict.fromkeys(s.solver for s in summary))
    names = summary[0].names if summary else ("azimuth", "elevation", "roll")
    head = names == ("azimuth", "elevation", "roll")
    fig, axes = plt.subplots(1, max(1, len(names)), figsize=(5 + 1.2 * len(variants) * max(1, len(names)), 4.5), sharey=False, squeeze=False)
    axes = axes[0]
    width = 0.8 / max(1, len(solvers))
    scale = 100.0 if head else 1.0
    for a, axis_name in enumerate(names):
        ax = axes[a]
        for j, solver in enumerate(solvers):
            cells = {s.variant: s for s in summary if s.solver == solver}
            means = [scale * cells[v].mean[a] if v in cells and a < len(cells[v].mean) else np.nan for v in variants]
            errs = [scale * cells[v].half_width_95[a] if v in cells and a < len(cells[v].mean) else np.nan for v in variants]
            ax.bar(np.arange(len(variants)) + j * width, means, width, yerr=errs, capsize=3, label=solver)
        ax.set_xticks(np.arange(len(variants)) + 0.4 - width / 2, variants, rotation=30, ha="right")
        ax.set_title(f"{axis_name} RMS" if head else axis_name)
        ax.set_ylabel(("1e-2 rad" if head else "mean") + " (bars: 95% CI over seeds)")
        shown = [s.mean[a] for s in summary if a < len(s.mean) and np.isfinite(s.mean[a])]
        if shown and min(shown) > 0:  # a log axis only where every bar is positive (a lost fraction of 0 has no log)
            ax.set_yscale("log")
        ax.grid(alpha=0.3, axis="y")
    axes[0].legend()
    fig.tight_layout()
    png = out / "summary.png"
    fig.savefig(png, dpi=100)
    plt.close(fig)
    return [csv_path, png]
