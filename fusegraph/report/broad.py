"""BROAD bench as text and as a figure."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def format_broad_table(result: dict[str, Any]) -> str:
    """The bench as text: per trial and mean, total/heading/inclination RMSE (deg) and x real time."""
    methods = list(result["mean"])
    head = f"{'trial':<34}" + "".join(f"{m:>26}" for m in methods)
    sub = f"{'':<34}" + "".join(f"{'tot  head  incl   x rt':>26}" for _ in methods)
    lines = [head, sub]

    def cells(row: dict[str, dict[str, float]]) -> str:
        return "".join(f"{row[m]['total']:>7.2f}{row[m]['heading']:>6.2f}{row[m]['inclination']:>6.2f}{row[m]['x_realtime']:>7.0f}" for m in methods)

    for stem, row in result["trials"].items():
        lines.append(f"{stem[:34]:<34}" + cells(row))
    lines.append(f"{'mean':<34}" + cells(result["mean"]))
    ratios = [f"{pair}: total {r['total']:.2f}, inclination {r['inclination']:.2f}, speed {r['speed']:.3f}; worst trial "
              f"{r['worst_trial']} {r['worst_trial_ratio']:.2f}x" for pair, r in result.get("ratios", {}).items()]
    published = [f"published by the benchmark's authors (all 39 trials, tuned): {name} total {f['total']:.2f}, heading {f['heading']:.2f}, "
                 f"inclination {f['inclination']:.2f}" for name, f in result.get("published", {}).items()]
    settings = ["settings on main (tuned.toml; the mean total RMSE of the trials they were chosen on, in-sample / leave-one-trial-out):"] + [
        f"  {study:<20} {row['in_sample']:.3f} / {row['cross_validated']:.3f} deg over {row['trials']} trials"
        + (f" (chosen by {row['unit']}: {row['score_in_sample']:.3f} / {row['score_cross_validated']:.3f})" if "score_in_sample" in row else "")
        for study, row in result.get("settings", {}).items() if row.get("in_sample") is not None and row.get("cross_validated") is not None]
    label = [f"these figures are {result['figures_are']}"] if "figures_are" in result else []
    label += [f"{solver}: mean total {row['in_sample_on_main']:.3f} deg in-sample (settings on main); leave-one-trial-out with every study re-chosen "
              f"{row['cross_validated']:.3f} deg ({row['cross_validated_peer_ratio']:.2f}x its peer, inclination "
              f"{row['cross_validated_inclination_peer_ratio']:.2f}x), the same procedure in-sample {row['in_sample']:.3f} "
              f"(cross-validated, tune broad_nested{'' if solver == 'online' else ' --solver batch'} --rule {row.get('rule', 'best')}"
              + ("" if row["current"] else "; STALE: measured against other settings than main's") + ")"
              for solver, row in result.get("nested", {}).items()]
    return "\n".join(lines + ["RMSE in degrees (BROAD metric, movement phases, no alignment); x rt = times faster than real time"] + label + ratios + published
                     + (settings if len(settings) > 1 else []))


def plot_broad(result: dict[str, Any], path: str | Path) -> Path:
    """Grouped bars of the total and the inclination RMSE per trial and method (log scale), as a PNG."""
    import matplotlib.pyplot as plt

    from ..report.plots import grouped_bars, save_figure

    trials = list(result["trials"])
    methods = list(result["mean"])
    fig, axes = plt.subplots(2, 1, figsize=(max(8, 1.1 * len(trials) + 2), 7), sharex=True)
    labels = [t.split("_", 1)[0] + "\n" + t.split("_", 1)[-1].replace("undisturbed_", "").replace("disturbed_", "")[:18] for t in trials] + ["mean"]
    for ax, key in zip(axes, ("total", "inclination"), strict=True):
        grouped_bars(ax, labels, {m: [result["trials"][t][m][key] for t in trials] + [result["mean"][m][key]] for m in methods})
    axes[0].set_ylabel("total RMSE (deg)")
    axes[1].set_ylabel("inclination RMSE (deg)")
    axes[0].set_yscale("log")
    axes[1].set_yscale("log")
    axes[0].legend(ncol=len(methods), fontsize=8)
    fig.suptitle("BROAD: orientation error per trial (log scale)")
    return save_figure(fig, path, dpi=120)
