"""The gaze report as text and as a figure."""

from __future__ import annotations

from ..geometry import FloatArray
from ..scenarios.gaze import GazeSession


def plot_gaze(session: GazeSession, estimates: dict[str, FloatArray], path: str) -> None:
    """Like the paper's figure: gaze point X and Z on the wall over time, truth and each method."""
    from ..report.plots import plt, save_figure  # headless pyplot

    fig, axes = plt.subplots(2, 1, figsize=(12, 7), sharex=True)
    for c, (ax, name) in enumerate(zip(axes, ("X (horizontal)", "Z (vertical)"), strict=True)):
        ax.plot(session.tracker_t, 1000 * session.truth_gaze_xz_m[:, c], "k-", lw=2, alpha=0.5, label="truth")
        for method, est in estimates.items():
            ax.plot(session.tracker_t, 1000 * est[:, c], lw=0.8, label=method)
        ax.set_ylabel(f"gaze {name} on the wall (mm)")
        ax.set_ylim(1000 * session.truth_gaze_xz_m[:, c].min() - 150, 1000 * session.truth_gaze_xz_m[:, c].max() + 150)
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("time (s)")
    fig.suptitle(f"gaze point on the wall while nodding and shaking the head; the mark changes at {session.config.switch_s:.0f} s")
    save_figure(fig, path)


def format_gaze_table(report: dict[str, object]) -> str:
    methods = report["methods"]
    assert isinstance(methods, dict)
    lines = [f"{'method':20s}{'X rms mm':>10s}{'Z rms mm':>10s}{'x real time':>13s}"]
    for name, r in methods.items():
        lines.append(f"{name:20s}{r['rms']['x_mm']:10.1f}{r['rms']['z_mm']:10.1f}{r['x_realtime']:13.0f}")
    ekf = methods["ekf"]["rms"]
    for name in ("online", "batch"):
        r = methods[name]["rms"]
        lines.append(f"{name}/ekf: X {r['x_mm'] / ekf['x_mm']:.2f}, Z {r['z_mm'] / ekf['z_mm']:.2f}")
    return "\n".join(lines)
