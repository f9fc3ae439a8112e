"""Figures a person can look at: estimates against the reference, per axis, with 3-sigma bands."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # headless: figures go to files
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from ..estimate import Estimate  # noqa: E402
from ..geometry import FloatArray, euler_zyx_from_quat, wrap_angle  # noqa: E402
from ..metrics import AXES  # noqa: E402


def plot_attitude_axes(
    t_truth: FloatArray,
    quat_truth: FloatArray,
    estimates: Sequence[Estimate],
    path: str | Path,
    title: str = "",
    labels: dict[str, str] | None = None,
) -> Path:
    """Per axis: the angles over time (top) and each method's error with its 3-sigma band (bottom).

    Like the head-tracking paper's Fig. 3/4: the reference and every estimate, azimuth, elevation, roll.
    """
    labels = labels or {}
    truth = np.rad2deg(euler_zyx_from_quat(quat_truth))
    fig, axes = plt.subplots(2, 3, figsize=(15, 7), sharex=True)
    banded = False
    for a, axis_name in enumerate(AXES):
        top, bottom = axes[0, a], axes[1, a]
        largest = 0.0
        top.plot(t_truth, truth[:, a], color="black", lw=2.0, label="reference (lag-free)")
        for estimate in estimates:
            name = labels.get(estimate.method, estimate.method)
            angles = np.rad2deg(estimate.euler_zyx[:, a])
            (line,) = top.plot(estimate.t, angles, lw=1.0, label=name)
            error = np.rad2deg(wrap_angle(estimate.euler_zyx[:, a] - euler_zyx_from_quat(quat_truth)[:, a]))
            bottom.plot(estimate.t, error, lw=0.8, color=line.get_color(), label=name)
            if np.isfinite(error).any():
                largest = max(largest, float(np.nanpercentile(np.abs(error), 99)))
            if estimate.cov is not None:
                # body z, y, x are close to azimuth, elevation, roll at the moderate tilts of these scenes
                body = (2, 1, 0)[a]
                sigma = 3.0 * np.rad2deg(np.sqrt(np.clip(estimate.cov[:, body, body], 0.0, None)))
                if np.isfinite(sigma).any():  # no band where the method gives no covariance
                    bottom.fill_between(estimate.t, -sigma, sigma, where=np.isfinite(sigma), color=line.get_color(), alpha=0.12, lw=0)
                    banded = True
        top.set_title(axis_name)
        top.set_ylabel("angle [deg]")
        bottom.set_xlabel("time [s]")
        bottom.axhline(0.0, color="black", lw=0.5)
        # +-4 deg shows a good estimate's detail; a larger error widens the axis so it is seen, not cut off
        limit = min(180.0, max(4.0, 1.1 * largest))
        bottom.set_ylim(-limit, limit)
        for ax in (top, bottom):
            ax.grid(alpha=0.3)
    for a in range(3):
        axes[1, a].set_ylabel("error [deg]" + (" (band: 3 sigma)" if banded else ""))
    axes[0, 0].legend(loc="best", fontsize=8)
    if title:
        fig.suptitle(title)
    return save_figure(fig, path)


def grouped_bars(ax: Any, labels: Sequence[str], series: Mapping[str, Sequence[float | None]]) -> None:
    """Bars side by side per label, one colour per series (None: no bar), labels under the groups."""
    x = np.arange(len(labels))
    width = 0.8 / max(len(series), 1)
    for i, (name, values) in enumerate(series.items()):
        heights = [np.nan if v is None else v for v in values]
        ax.bar(x + (i - (len(series) - 1) / 2) * width, heights, width, label=name)
    ax.set_xticks(x, labels, fontsize=7)


def save_figure(fig: Figure, path: str | Path, dpi: int = 110) -> Path:
    """Lay the figure out, write it (creating the folder) and free it."""
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
