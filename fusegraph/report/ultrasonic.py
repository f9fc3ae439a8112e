"""The ultrasonic bench as text, and the tracks of one run as a figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..metrics import identity_map
from ..records import RangeEpochs
from ..results import TrackingRun


def plot_ultrasonic(epochs: RangeEpochs, run: TrackingRun, path: str | Path) -> None:
    """Top view of every transmitter (truth and estimate), each one's error over time, and the REST
    model's probability beside the truth's rests."""
    from ..report.plots import plt, save_figure  # headless pyplot

    assert epochs.positions is not None
    truth = epochs.positions
    n = truth.shape[1]
    mapping = np.array([identity_map(run.positions[k], truth[k]) for k in range(len(epochs.t))])  # (K, N): track -> truth
    matched = np.full_like(truth, np.nan)
    rest = np.full(truth.shape[:2], np.nan)
    for k in range(len(epochs.t)):
        ok = mapping[k] >= 0
        matched[k, mapping[k][ok]] = run.positions[k][ok]
        if run.rest_probability is not None:
            rest[k, mapping[k][ok]] = run.rest_probability[k][ok]
    error_mm = 1e3 * np.linalg.norm(matched - truth, axis=2)
    speed = np.linalg.norm(np.gradient(truth, epochs.t, axis=0), axis=2)
    fig = plt.figure(figsize=(15, 8))
    grid = fig.add_gridspec(2, 2, width_ratios=[1, 1.4])
    top, err, modes = fig.add_subplot(grid[:, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])
    colours = plt.get_cmap("tab20")(np.arange(n) % 20)
    top.plot(epochs.receivers[:, 0], epochs.receivers[:, 1], "ks", ms=5, label="receiver (2.5 m up)")
    for i in range(n):
        top.plot(truth[:, i, 0], truth[:, i, 1], "-", color=colours[i], lw=3, alpha=0.3)
        top.plot(matched[:, i, 0], matched[:, i, 1], "-", color=colours[i], lw=0.8)
        err.plot(epochs.t, error_mm[:, i], color=colours[i], lw=0.6)
    top.plot([], [], "k-", lw=3, alpha=0.3, label="truth")
    top.plot([], [], "k-", lw=0.8, label="fusegraph")
    top.set(xlabel="x (m)", ylabel="y (m)", title=f"{n} transmitters, top view", aspect="equal")
    top.legend(fontsize=8, loc="lower right")
    err.axhline(50.0, color="r", ls=":", lw=1)
    err.set(yscale="log", ylim=(0.1, 500), ylabel="position error (mm)", title="error per transmitter (red: 5 cm, track lost)")
    picture = np.where(speed < 0.01, 1.0, 0.0) * 0.5 + np.nan_to_num(rest) * 0.5  # both at rest: 1, neither: 0
    modes.imshow(picture.T, aspect="auto", cmap="viridis", vmin=0, vmax=1, interpolation="nearest",
                 extent=(epochs.t[0], epochs.t[-1], n - 0.5, -0.5))
    modes.set(xlabel="time (s)", ylabel="transmitter",
              title="REST: truth at rest and model probability (yellow both, teal one of them, purple neither)")
    save_figure(fig, path)


def format_ultrasonic_table(result: dict[str, object]) -> str:
    sim = result["sim"]
    assert isinstance(sim, dict)
    header = f"{'N':>3} {'method':<22}{'assoc':>8}{'unamb.':>8}{'oracle':>8}{'or.unamb':>9}{'rmse mm':>9}{'all mm':>8}{'lost %':>8}{'swaps':>7}"
    lines = [header + f"{'ms/ep':>8}{'p99 ms':>8}{'s':>6}{'capped':>8}"]
    for n, methods in sim.items():
        for method, r in methods.items():
            lines.append(
                f"{n:>3} {method:<22}{r['assoc_acc']:>8.4f}{r['assoc_acc_unambiguous']:>8.4f}{r['oracle_acc']:>8.4f}{r['oracle_acc_unambiguous']:>9.4f}"
                f"{1e3 * r['rmse_m']:>9.1f}{1e3 * r['rmse_all_m']:>8.0f}{100 * r['lost_frac']:>8.2f}{r['identity_swaps']:>7.1f}"
                f"{r['ms_per_epoch']:>8.2f}{r['ms_p99']:>8.2f}{r['seconds_scored']:>6.0f}{r['capped_epochs']:>8.0f}"
            )
    crossing = result["crossing"]
    assert isinstance(crossing, dict)
    lines.append(f"crossings (closest approach 5, 7, 10 cm; 0.3-1 m/s; head-on and side by side): {crossing['swaps']} identity swaps "
                 f"in {crossing['runs']} runs")
    lines.append("means over seeds (p99: the worst seed); accuracies as fractions; rmse over tracked transmitter-epochs (within 5 cm), "
                 "all = every epoch with an estimate;")
    lines.append("the combinatorial search runs on the first s seconds (capped = epochs where its time cap stopped the search); "
                 "Stone Soup's GNN and JPDA (tuned settings) on the first s seconds too, beside fusegraph's run scored there (peer window)")
    uwb = result.get("uwb")
    if isinstance(uwb, dict):
        lines.append(
            f"uwb (import uwb + the ultrasonic preset's online solver; 3 tags on one body, 8 anchors, planar): every estimate's RMSE "
            f"labelled {uwb['labelled_rmse_m']:.3f} m, unlabelled {uwb['unlabelled_rmse_m']:.3f} m "
            f"(ratio {uwb['unlabelled_rmse_m'] / uwb['labelled_rmse_m']:.2f}), association {uwb['assoc_acc']:.3f}, "
            f"lost {uwb.get('lost_frac', float('nan')):.3f}, "
            f"clock offset {uwb['clock_offset_s'] * 1e3:.0f} ms (raw ranges vs motion capture), {uwb['ms_per_epoch']:.2f} ms/epoch; "
            f"self-check: association from geometry alone {uwb.get('assoc_expected_geometry', float('nan')):.2f} (a lower bound, no truth); "
            f"ceiling: the ranges assigned against the true tag positions {uwb.get('assoc_oracle', float('nan')):.3f}"
        )
        lines.append(f"uwb figures: {result.get('uwb_status', '')}")
    else:
        lines.append(f"uwb: {result.get('uwb_status', 'not run')} (--uwb DIR)")
    return "\n".join(lines)
