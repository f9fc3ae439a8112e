"""The waist benches' pictures: ``bench gait`` (each method's per-bout stride length and walking speed against the
reference system's) and ``bench activity`` (each method's confusion)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def plot_per_bout(bouts: list[dict[str, Any]], mae: dict[str, tuple[float | None, float | None]], path: str | Path,
                  by_speed: dict[str, dict[str, dict[str, Any]]] | None = None, slow_m_s: float = 0.8) -> Path:
    """Two panels (stride length, walking speed): per bout, each method's mean against the reference's, the diagonal
    for agreement; ``mae``: each method's (stride length, speed) MAE for its legend entry. With ``by_speed`` (``bench
    gait``'s) a third: each method's step F1 on the bouts slower than ``slow_m_s`` and on the others. PNG."""
    from .plots import plt, save_figure  # headless pyplot

    fig, axes = plt.subplots(1, 3 if by_speed else 2, figsize=(16.5 if by_speed else 11, 5))
    if by_speed:
        _plot_step_f1_by_speed(axes[2], by_speed, slow_m_s)
    for ax, (key, unit, which) in zip(axes[:2], (("stride_length_m", "m", 0), ("walking_speed_m_s", "m/s", 1)), strict=True):
        top = 0.0
        for method, errors in mae.items():
            pairs = [(b["reference"][key], b[method][key]) for b in bouts
                     if method in b and b["reference"][key] is not None and b[method][key] is not None]
            if not pairs:
                continue
            x, y = zip(*pairs, strict=True)
            top = max(top, *x, *y)
            label = f"{method} ({len(pairs)} bouts" + (f", MAE {errors[which]:.3f} {unit})" if errors[which] is not None else ")")
            ax.plot(x, y, "o", ms=6, alpha=0.75, label=label)
        ax.plot([0, 1.1 * top], [0, 1.1 * top], "k--", lw=0.8, label="agreement")
        name = "stride length" if which == 0 else "walking speed"
        ax.set(xlabel=f"reference {name} per bout ({unit})", ylabel=f"method's mean in the bout ({unit})", title=name,
               xlim=(0, 1.1 * top), ylim=(0, 1.1 * top), aspect="equal")
        ax.legend(fontsize=8, loc="lower right")
    return save_figure(fig, path)


def _plot_step_f1_by_speed(ax: Any, by_speed: dict[str, dict[str, dict[str, Any]]], slow_m_s: float) -> None:
    """Grouped bars: each method's step F1 on the slow bouts and on the others, the bouts and contacts under each band."""
    bands = (("slow", f"under {slow_m_s:g} m/s"), ("not_slow", f"{slow_m_s:g} m/s and faster"))
    width = 0.8 / max(len(by_speed), 1)
    for i, (method, scores) in enumerate(by_speed.items()):
        values = [scores[band]["step_f1"] or 0.0 for band, _ in bands]
        bars = ax.bar([b + (i - (len(by_speed) - 1) / 2) * width for b in range(len(bands))], values, width, label=method)
        ax.bar_label(bars, fmt="%.2f", fontsize=8)
    first = next(iter(by_speed.values()))
    ax.set_xticks(range(len(bands)), [f"{name}\n({first[band]['bouts']} bouts, {first[band]['contacts']} contacts)" for band, name in bands])
    ax.set(ylabel="step F1", ylim=(0, 1.25), title="steps by the reference bout's speed")
    ax.legend(fontsize=8, loc="upper left", ncol=len(by_speed))


def plot_confusions(methods: dict[str, dict[str, Any]], path: str | Path, title: str = "") -> Path:
    """``bench activity --plot``: one panel per method, its confusion (rows: the label, columns: the class called, each
    row's fractions, the cycles per label beside the row's name), ``title`` above them. PNG."""
    from .plots import plt, save_figure  # headless pyplot

    fig, axes = plt.subplots(1, len(methods), figsize=(4.8 * len(methods), 4.2), squeeze=False)
    for ax, (name, m) in zip(axes[0], methods.items(), strict=True):
        labels = list(m["confusion"])
        called = list(next(iter(m["confusion"].values())))
        grid = [[m["confusion"][a][b] or 0.0 for b in called] for a in labels]
        ax.imshow(grid, vmin=0.0, vmax=1.0, cmap="Blues")
        for i, row in enumerate(grid):
            for j, v in enumerate(row):
                ax.text(j, i, f"{100 * v:.1f}%", ha="center", va="center", color="white" if v > 0.6 else "black", fontsize=9)
        ax.set_xticks(range(len(called)), [c.replace("_", "\n") for c in called])  # two lines: "stairs down" and "not walking" met
        ax.set_yticks(range(len(labels)), [f"{a.replace('_', ' ')}\n({m['cycles'][a]} cycles)" for a in labels])
        ax.set(xlabel="called", ylabel="label", title=name)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)
