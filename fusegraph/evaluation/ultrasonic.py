"""The ultrasonic bench: simulated transmitters with unknown association (N = 3, 6, 12), crossings, the peers,
and the recorded UWB run."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..metrics import identity_map, oracle_labels, score_run
from ..records import RangeEpochs
from ..report.ultrasonic import plot_ultrasonic
from ..results import TrackingRun
from ..systems.ultrasonic import run_combinatorial, run_fusegraph


def crossing_epochs(closest_m: float, speed_m_s: float, head_on: bool, seed: int = 0, rate_hz: float = 40.0) -> RangeEpochs:
    """Two transmitters passing each other: head-on (opposite directions) or side by side (one overtakes)."""
    from ..scenarios.ultrasonic import UltrasonicScenarioConfig, hear

    cfg = UltrasonicScenarioConfig(transmitters=2, rate_hz=rate_hz)
    t = np.arange(0.0, 3.0, 1.0 / rate_hz)
    centre = np.array([1.0, 0.75, 0.9])
    s = np.clip((t - 0.5) / 2.0, 0.0, 1.0)  # both move for 2 s, passing at the middle
    a = centre + np.outer(speed_m_s * 2.0 * (s - 0.5), [1.0, 0.0, 0.0]) + [0.0, -closest_m / 2, 0.0]
    if head_on:
        b = centre + np.outer(-speed_m_s * 2.0 * (s - 0.5), [1.0, 0.0, 0.0]) + [0.0, closest_m / 2, 0.0]
    else:  # side by side: b starts ahead at half the speed, a overtakes it at the middle
        b = centre + np.outer(0.5 * speed_m_s * 2.0 * (s - 0.5), [1.0, 0.0, 0.0]) + [0.0, closest_m / 2, 0.0]
    positions = np.stack([a, b], axis=1)
    rng = np.random.default_rng(seed)
    ranges, labels = hear(positions, cfg.receivers, rng, cfg)
    return RangeEpochs(t, cfg.receivers.copy(), ranges, labels, positions, cfg.range_sigma_m)


def bench_ultrasonic(
    transmitter_counts: tuple[int, ...] = (3, 6, 12),
    seeds: tuple[int, ...] = (0, 1, 2),
    duration_s: float = 20.0,
    baseline_s: float = 5.0,
    show_progress: bool = True,
    uwb_dir: str | None = "default",
    plot: str | Path | None = None,
    peer_s: float = 2.0,
    peers: tuple[str, ...] = ("gnn", "jpda"),
) -> dict[str, object]:
    """Simulation (both methods and the oracle per N), crossings; the JSON of ``fusegraph bench ultrasonic``.
    ``plot``: a PNG of fusegraph's run at the largest N and the first seed (``plot_ultrasonic``).
    ``peers``: Stone Soup's trackers (``stonesoup_gnn``, ``stonesoup_jpda``, with their tuned settings) on the first
    ``peer_s`` seconds (Stone Soup needs ~1 s per epoch at N = 12), beside ``fusegraph_peer_window``: fusegraph's causal
    run scored on the same epochs."""
    from ..baselines.stonesoup_peer import run_stonesoup, tuned_config
    from ..progress import progress
    from ..scenarios.ultrasonic import simulate_ultrasonic

    sim: dict[str, dict[str, dict[str, float]]] = {}
    jobs = [(n, seed) for n in transmitter_counts for seed in seeds]
    rows: dict[tuple[int, str], list[dict[str, float]]] = {}
    for n, seed in progress(jobs, desc="bench ultrasonic", enabled=None if show_progress else False):
        epochs = simulate_ultrasonic(seed, transmitters=n, duration_s=duration_s)
        oracle = score_run(epochs, oracle_labels(epochs), None)
        short = _head(epochs, baseline_s)
        ours = run_fusegraph(epochs, n)
        if plot is not None and n == max(transmitter_counts) and seed == seeds[0]:
            plot_ultrasonic(epochs, ours, plot)
        window = _head(epochs, peer_s)
        compared: list[tuple[str, TrackingRun, RangeEpochs]] = [("fusegraph", ours, epochs), ("combinatorial", run_combinatorial(short, n), short)]
        if peers:
            compared.append(("fusegraph_peer_window", _first_epochs(ours, len(window.t)), window))
            compared += [(f"stonesoup_{p}", run_stonesoup(window, n, p, tuned_config(p)), window) for p in peers]
        for method, run, scored in compared:
            score = score_run(scored, run.labels, run.positions)
            oracle_here = oracle if scored is epochs else score_run(scored, oracle_labels(scored), None)
            rows.setdefault((n, method), []).append({
                "assoc_acc": score.assoc_acc,
                "assoc_acc_unambiguous": score.assoc_acc_unambiguous,
                "oracle_acc": oracle_here.assoc_acc,
                "oracle_acc_unambiguous": oracle_here.assoc_acc_unambiguous,
                "rmse_m": score.rmse_m,
                "rmse_all_m": score.rmse_all_m,
                "lost_frac": score.lost_frac,
                "identity_swaps": float(score.identity_swaps),
                "ms_per_epoch": float(np.mean(run.ms_per_epoch)),
                "ms_p99": float(np.percentile(run.ms_per_epoch, 99)),
                "seconds_scored": float(scored.t[-1] - scored.t[0] + 1 / 40),
                "capped_epochs": float(run.extras.get("capped_epochs", 0)),
            })
    for (n, method), runs in rows.items():
        sim.setdefault(str(n), {})[method] = {key: float(np.mean([r[key] for r in runs])) for key in runs[0]}
        sim[str(n)][method]["ms_p99"] = float(np.max([r["ms_p99"] for r in runs]))  # the worst seed's p99
    swaps = runs_done = 0
    for closest in (0.05, 0.07, 0.10):
        for speed in (0.3, 0.6, 1.0):
            for head_on in (True, False):
                epochs = crossing_epochs(closest, speed, head_on, seed=runs_done)
                run = run_fusegraph(epochs, 2)
                assert epochs.positions is not None
                start = identity_map(run.positions[0], epochs.positions[0])
                end = identity_map(run.positions[-1], epochs.positions[-1])
                swaps += int(np.any(start != end))
                runs_done += 1
    uwb: dict[str, float] | None = None
    uwb_status = "skipped"
    if uwb_dir is not None:
        from ..datasets.uwb_lias import DEFAULT_DIR
        from .uwb import bench_uwb

        directory = DEFAULT_DIR if uwb_dir == "default" else Path(uwb_dir)
        uwb_status = f"recording not found at {directory}"
        if directory.is_dir():
            uwb_status = "ran"
            uwb = bench_uwb(directory)
            uwb_status = uwb_figures_are(directory)
    return {"sim": sim, "crossing": {"runs": runs_done, "swaps": swaps}, "uwb": uwb, "uwb_status": uwb_status}


def _first_epochs(run: TrackingRun, count: int) -> TrackingRun:
    """A causal run's output over its first epochs (what it gave there, whatever came later)."""
    return TrackingRun(run.positions[:count], run.labels[:count], run.ms_per_epoch[:count], dict(run.extras))


def _head(epochs: RangeEpochs, seconds: float) -> RangeEpochs:
    keep = int(np.searchsorted(epochs.t, epochs.t[0] + seconds))
    return RangeEpochs(
        epochs.t[:keep], epochs.receivers, epochs.ranges[:keep], None if epochs.labels is None else epochs.labels[:keep],
        None if epochs.positions is None else epochs.positions[:keep], epochs.range_sigma_m,
    )


def uwb_figures_are(directory: Path) -> str:
    """What the UWB figures of a run are: in-sample where the calibrated tracker's settings (``tuned.toml``
    ``[uwb_calibrated]``) were chosen on this run, with the leave-one-run-out figure; held out where not."""
    from ..tuned import tuned

    table = tuned("uwb_calibrated")
    runs = table.get("runs", [])
    if directory.name in runs:
        return (f"ran; in-sample: the calibrated tracker's settings were chosen on this run among {', '.join(runs)} "
                f"(leave-one-run-out: {table.get('cross_validated')} m every estimate's RMSE, in-sample {table.get('in_sample')} m)")
    return "ran; held out: no setting was chosen on this run"
