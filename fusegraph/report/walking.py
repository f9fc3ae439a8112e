"""The walking bench as text, and the walk's trajectories as a figure."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..records import ACTIVITIES, WalkingSession
from ..results import WALK_METHODS as METHODS
from ..results import WalkRun


def plot_walk(session: WalkingSession, runs: dict[str, WalkRun], path: Path) -> None:
    """Top view and height over time of the truth and every method, fixes marked (wrong ones as x)."""
    from ..report.plots import plt, save_figure  # headless pyplot

    fig, (top, height) = plt.subplots(1, 2, figsize=(15, 6), gridspec_kw={"width_ratios": [1.3, 1]})
    top.plot(session.truth_xyz_m[:, 0], session.truth_xyz_m[:, 1], "k-", lw=2, alpha=0.4, label="truth")
    height.plot(session.t, session.truth_xyz_m[:, 2], "k-", lw=2, alpha=0.4, label="truth")
    for name, run in runs.items():
        top.plot(run.xyz[:, 0], run.xyz[:, 1], lw=1, label=name)
        height.plot(run.t, run.xyz[:, 2], lw=1, label=name)
    f = session.fixes
    top.plot(f.pose[~f.wrong, 0], f.pose[~f.wrong, 1], "g^", label="image fix")
    top.plot(f.pose[f.wrong, 0], f.pose[f.wrong, 1], "rx", ms=9, label="wrong image fix")
    top.set(xlabel="east (m)", ylabel="north (m)", title="walk, top view", aspect="equal")
    height.set(xlabel="time (s)", ylabel="height (m)", title="floors (3.5 m apart)")
    top.legend(fontsize=8)
    save_figure(fig, path)


def plot_gait_statistics(rows: dict[str, dict[str, np.ndarray]], names: tuple[str, ...], path: Path) -> None:
    """Per statistic (``names``, the rows' columns) and class, the distribution over steps of the simulated pendulum gait
    beside UCI HAPT's real waists (``evaluation.walking.step_rows``)."""
    from ..report.plots import plt, save_figure  # headless pyplot

    classes = ("flat", "stairs_up", "stairs_down")
    fig, axes = plt.subplots(1, len(names), figsize=(4 * len(names), 4))
    for i, (ax, name) in enumerate(zip(axes, names, strict=True)):
        for j, source in enumerate(("pendulum_gait", "hapt")):
            if source not in rows:
                continue
            data = [rows[source][a][:, i] for a in classes]
            box = ax.boxplot(data, positions=np.arange(len(classes)) * 3 + j, widths=0.8, showfliers=False, patch_artist=True)
            for patch in box["boxes"]:
                patch.set_facecolor("tab:orange" if source == "hapt" else "tab:blue")
        ax.set_xticks(np.arange(len(classes)) * 3 + 0.5, classes, fontsize=8)
        ax.set_title(name, fontsize=9)
    axes[0].legend([plt.Rectangle((0, 0), 1, 1, color=c) for c in ("tab:blue", "tab:orange")], ["pendulum gait", "UCI HAPT"], fontsize=8)
    fig.suptitle("per-step statistics: the simulated gait (blue) against real waists (orange), the same front end and code")
    save_figure(fig, path)


def plot_oxford(oxford: Mapping[str, Mapping[str, Any]], path: Path) -> None:
    """Each Oxford recording's count error against the phone's peak threshold (the search ``bench walking`` makes), the
    threshold chosen without the recording marked, and the hand count's 0."""
    from ..report.plots import plt, save_figure  # headless pyplot

    fig, ax = plt.subplots(figsize=(9, 5))
    for name, row in oxford.items():
        by_peak, true = row["counted_by_peak"], float(row["true"])
        peaks = np.array([float(p) for p in by_peak])
        error = 100.0 * (np.array([float(c) for c in by_peak.values()]) - true) / true
        (line,) = ax.plot(peaks, error, "o-", ms=3, lw=1, label=name)
        chosen = float(row["peak_threshold_m_s2"])
        ax.plot([chosen], [100.0 * (float(row["counted"]) - true) / true], "s", ms=9, mfc="none", color=line.get_color())
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set(xscale="log", xlabel="peak threshold (m/s^2)", ylabel="count error vs the hand count (%)", ylim=(-20, 10),
           title="Oxford phone steps: count error per peak threshold\nsquare: the threshold chosen without the recording (cross-validated)")
    ax.legend(fontsize=7)
    save_figure(fig, path)


def format_walking_table(result: dict[str, object]) -> str:
    """The bench's tables as text."""
    lines = []
    cols = [*ACTIVITIES, "not_walking", "none"]  # a step the classifier took for not walking climbs no stairs
    for key, title in (("confusion", "independent (pendulum) gait by fusegraph's waist classifier, which the walk's graph takes"),
                       ("confusion_causal", "independent (pendulum) gait by the classifier run causally (the online, EKF and dead reckoning's steps)"),
                       ("confusion_paper_rules", "independent (pendulum) gait by the paper's rules"),
                       ("confusion_signature_gait", "signature gait (the first generator) by fusegraph's waist classifier")):
        conf = result.get(key)
        if not isinstance(conf, dict):
            continue
        lines.append(f"activity on the {title} (rows true, columns detected; per walking cycle, per ride for the elevator)")
        lines.append(f"{'':12s}" + "".join(f"{c:>12s}" for c in cols) + f"{'correct':>10s}")
        for a in ACTIVITIES:
            row = conf.get(a, {})
            total = sum(row.values())
            lines.append(f"{a:12s}" + "".join(f"{row.get(c, 0):12d}" for c in cols) + (f"{100 * row.get(a, 0) / total:9.1f}%" if total else f"{'-':>10s}"))
        lines.append("")
    stats = result.get("gait_statistics")
    if isinstance(stats, dict):
        lines.append("per-step medians, the pendulum gait (seeds 0-2) against UCI HAPT's real waists (the same front end and code)")
        lines.append(f"{'':26s}{'steps':>7s}{'excursion cm':>14s}{'vert. RMS m/s2':>16s}{'vert./horiz.':>14s}{'duration s':>12s}{'vert.~pitch':>13s}")
        for a in ("flat", "stairs_up", "stairs_down"):
            for source in ("pendulum_gait", "hapt"):
                if source in stats:
                    r = stats[source][a]
                    lines.append(f"{a + ' ' + source:26s}{int(r['steps']):7d}{100 * r['excursion_m']:14.1f}{r['vertical_rms_m_s2']:16.2f}"
                                 f"{r['vertical_to_horizontal']:14.2f}{r['duration_s']:12.2f}{r['vertical_pitch_corr']:13.2f}")
        lines.append("")
    for key, title in (("walking", "walking, pendulum gait (20% wrong fixes)"), ("walking_no_wrong_fixes", "walking, pendulum gait (every fix correct)"),
                       ("walking_signature_gait", "signature gait (20% wrong fixes)")):
        if key not in result:
            continue
        table = result[key]
        assert isinstance(table, dict)
        lines.append("")
        lines.append(f"{title:44s}{'rmse_m':>10s}{'final_m':>10s}{'seconds':>10s}")
        for name in METHODS:
            r = table[name]
            lines.append(f"{name:44s}{r['rmse_m']:10.2f}{r['final_error_m']:10.2f}{r['seconds']:10.2f}")
    walking, clean = result["walking"], result["walking_no_wrong_fixes"]
    assert isinstance(walking, dict) and isinstance(clean, dict)
    lines.append(f"batch rmse with wrong fixes / without: {walking['batch']['rmse_m'] / clean['batch']['rmse_m']:.2f}")
    oxford = result.get("oxford") or {}
    assert isinstance(oxford, dict)
    if oxford:
        lines.append("")
        lines.append(f"{'oxford recording':40s}{'true':>8s}{'counted':>9s}{'error':>8s}{'peak':>7s}{'in-sample':>11s}{'foot switches':>15s}{'phone':>7s}")
        for name, r in oxford.items():
            switches, phone = ("-" if r.get(key) is None else str(r[key]) for key in ("foot_switches", "phone"))
            lines.append(f"{name:40s}{r['true']:8d}{r['counted']:9d}{100 * (r['counted'] - r['true']) / r['true']:7.1f}%{r['peak_threshold_m_s2']:7.2f}"
                         f"{r['counted_in_sample']:11d}{switches:>15s}{phone:>7s}")
        first = next(iter(oxford.values()))
        lines.append("counted: cross-validated, each recording with the peak threshold (m/s^2) that counts the OTHER recordings best "
                     f"(leave-one-recording-out); in-sample: the threshold chosen on all of them ({first['peak_threshold_in_sample_m_s2']:g} m/s^2)")
        lines.append("true: counted by hand (stats.csv); foot switches: the dataset's insoles (stepcounter.csv, heel contacts);"
                     " phone: the phone's own step counter, not in these recordings")
    plaza = result.get("plaza") or {}
    assert isinstance(plaza, dict)
    if plaza:
        lines.append("")
        lines.append(f"{'plaza':10s}{'odometry_m':>12s}{'online_m':>10s}{'batch_m':>10s}{'batch/odo':>10s}{'online x rt':>13s}")
        for name, r in plaza.items():
            lines.append(f"{name:10s}{r['odometry_rmse_m']:12.2f}{r['online_rmse_m']:10.2f}{r['batch_rmse_m']:10.2f}"
                         f"{r['batch_rmse_m'] / r['odometry_rmse_m']:10.2f}{r['online_x_realtime']:13.0f}")
    return "\n".join(lines)
