"""The cyclist report as text and as a figure."""

from __future__ import annotations

import numpy as np

from ..geometry import FloatArray, euler_zyx_from_quat
from ..scenarios.bicycle import BicycleSession


def plot_bicycle(s: BicycleSession, estimates: dict[str, FloatArray], path: str) -> None:
    """Like the paper's figure: thigh pitch and roll, truth and each method, braking shaded."""
    from ..report.plots import plt, save_figure  # headless pyplot

    truth = np.degrees(euler_zyx_from_quat(s.thigh_quat_wxyz))
    fig, axes = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    for ax, c, name in ((axes[0], 1, "pitch"), (axes[1], 2, "roll")):
        ax.plot(s.t, truth[:, c], "k-", lw=2, alpha=0.5, label="truth")
        for method, q in estimates.items():
            ax.plot(s.t, np.degrees(euler_zyx_from_quat(q))[:, c], lw=0.8, label=method)
        ax.axvspan(s.config.brake_s, s.config.brake_s + 5.0, color="0.9")
        ax.set_ylabel(f"thigh {name} (deg)")
        ax.set_xlim(s.config.brake_s - 8, s.config.brake_s + 8)
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("time (s); braking phase shaded")
    save_figure(fig, path)


def format_bicycle_table(report: dict[str, object]) -> str:
    lines = []
    for title, block in (("downhill, braking phase", report["methods"]), ("stand (indoor trainer), same phase", report["stand"]["methods"])):  # type: ignore[index]
        assert isinstance(block, dict)
        lines.append(f"{title}")
        lines.append(f"{'method':28s}{'pitch deg':>10s}{'roll deg':>10s}{'x real time':>13s}")
        for m, r in block.items():
            lines.append(f"{m:28s}{r['rms']['pitch_deg']:10.2f}{r['rms']['roll_deg']:10.2f}{r['x_realtime']:13.0f}")
        p = block["paper_pipeline"]["rms"]
        for m in ("online", "batch"):
            r = block[m]["rms"]
            lines.append(f"{m}/paper_pipeline: pitch {r['pitch_deg'] / p['pitch_deg']:.2f}, roll {r['roll_deg'] / p['roll_deg']:.2f}")
        lines.append("")
    return "\n".join(lines).rstrip()
