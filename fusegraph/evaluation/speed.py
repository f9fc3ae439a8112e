"""``fusegraph bench speed``: how fast each system runs against the peer measured beside it in the same run, the live
tracker's per-sample time, the batch's peak memory per hour of recording, and a cohort's throughput.

Every figure comes from a report over sessions (the path a user's recording takes); speed is the solvers' own time
(``Estimate.runtime_s``), x real time = seconds of data per second of solving. Without the BROAD folder the 9-axis and
recorded-head rows are measured on simulations and say so. A benchmark, not a test: timings are printed, never asserted.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..session import Session

MEMORY_SCRIPT = """
import resource, sys, time
import numpy as np
from fusegraph.datasets.importers import broad_sessions
from fusegraph.evaluation.speed import repeated_blocks
from fusegraph.scenarios import SIMULATORS
from fusegraph.systems import attitude9
from pathlib import Path
source, hours = sys.argv[1], float(sys.argv[2])
one = broad_sessions(Path(source))[0][1] if source != "-" else SIMULATORS["attitude9"].simulate(0, 120.0)
samples, missing, start = 0, 0, time.perf_counter()
for piece in attitude9.windowed_batch(repeated_blocks(one, hours * 3600.0)):
    samples += len(piece.t)
    missing += int((~np.isfinite(piece.quat_wxyz).all(axis=1)).sum())
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, samples, missing, time.perf_counter() - start)
"""
"""Run in a child process so that its peak RSS is the batch's alone (a fresh interpreter, one recording): the recording is
made a block at a time and the windowed batch's pieces are counted and let go, as a reader of a long file and a writer of
its estimate would."""


def repeated_blocks(session: Session, duration_s: float, block_s: float = 60.0) -> Iterator[Session]:
    """A long recording made of one repeated end to end (each copy's times moved on; the attitude jumps at the seams),
    ``block_s`` at a time in time order: the IMU streams only (a calibration recording in every block as it is), no truth."""
    streams = {name: s for name, s in session.streams.items() if s.kind in ("gyro", "accel", "mag") and not s.own_recording}
    kept = {name: s for name, s in session.streams.items() if s.own_recording}  # as recorded
    span = max(float(s.t[-1] - s.t[0]) for s in streams.values())
    period = float(np.median(np.diff(next(iter(streams.values())).t)))
    lo = 0.0
    while lo < duration_s:
        hi = min(lo + block_s, duration_s)
        out = {}
        for name, stream in streams.items():
            local = stream.t - stream.t[0]
            parts_t, parts_v = [], []
            for copy in range(int(lo // (span + period)), int(hi // (span + period)) + 1):
                t = local + copy * (span + period)
                keep = (t >= lo) & ((t < hi) | ((hi >= duration_s) & (t <= hi)))
                parts_t.append(t[keep])
                parts_v.append(stream.values[keep])
            out[name] = replace(stream, t=np.concatenate(parts_t), values=np.concatenate(parts_v))
        yield Session(session.system, {**out, **kept}, None, session.meta, None)
        lo = hi


def repeated(session: Session, duration_s: float) -> Session:
    """``repeated_blocks`` as one Session (held whole in memory)."""
    return next(repeated_blocks(session, duration_s, block_s=duration_s))


def _speeds(report: dict[str, Any], solvers: dict[str, str]) -> dict[str, dict[str, Any]]:
    return {key: {"x_realtime": float(report["methods"][solver]["x_realtime"])} for key, solver in solvers.items()}


def bench_speed(broad: Path | None = None, head_trials: int = 3, hours: float = 24.0, workers: int = 1, scheduler: str | None = None,
                progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """The speed bench; ``broad``: BROAD's folder (None: simulations), ``head_trials``: how many trials the recorded head
    rows run on (each is slow: Method II and iSAM2 on 285 Hz motion), ``hours``: the longest recording whose memory is
    measured (1 h, and 24 h when ``hours`` >= 24; 0: none)."""
    from ..datasets.importers import broad_sessions
    from .runner import report_sessions, simulated_sessions

    say = progress or (lambda _line: None)
    found: dict[str, Any] = {"systems": {}, "data": {}}
    if broad is not None and broad.is_dir():
        nine = broad_sessions(broad)
        head_recorded = broad_sessions(broad, system="head")[:head_trials]
        found["data"]["attitude9"] = f"BROAD, {len(nine)} trials"
        found["data"]["head_recorded"] = f"BROAD's motion as head sessions, {len(head_recorded)} trials"
    else:
        nine = simulated_sessions("attitude9", [0, 1, 2], 120.0)
        head_recorded = simulated_sessions("head", [0], 120.0)
        found["data"]["attitude9"] = "simulated (no BROAD folder): seeds 0-2, 120 s"
        found["data"]["head_recorded"] = "simulated (no BROAD folder): head seed 0, 120 s"
    say("attitude9")
    report = report_sessions("attitude9", nine, ["online", "batch", "vqf", "vqf_offline"], show_progress=False, workers=workers, scheduler=scheduler)
    rows = _speeds(report, {"online": "online", "batch": "batch", "vqf": "vqf", "vqf_offline": "vqf_offline"})
    rows["online"]["peer"], rows["online"]["ratio_to_peer"] = "vqf", rows["online"]["x_realtime"] / rows["vqf"]["x_realtime"]
    rows["batch"]["peer"], rows["batch"]["ratio_to_peer"] = "vqf_offline", rows["batch"]["x_realtime"] / rows["vqf_offline"]["x_realtime"]
    # the online with iSAM2 every second keyframe (``[online] update_every``), its error beside the default's (in-sample on BROAD)
    every2 = report_sessions("attitude9", [(name, s.with_meta(online={"update_every": 2})) for name, s in nine], ["online"], show_progress=False,
                             workers=workers, scheduler=scheduler)["methods"]["online"]
    rows["online_every2"] = {"x_realtime": float(every2["x_realtime"]), "peer": "vqf", "ratio_to_peer": float(every2["x_realtime"]) / rows["vqf"]["x_realtime"],
                             "total_deg": every2["metrics"].get("total_deg"),
                             "total_deg_every_keyframe": report["methods"]["online"]["metrics"].get("total_deg")}
    found["systems"]["attitude9"] = rows
    seconds = [r["online"]["runtime_s"] for r in report["sessions"].values() if r["online"]["status"] == "ok"]
    found["cohort"] = {"recordings_per_hour_per_core_online": 3600.0 / float(np.mean(seconds)) if seconds else None,
                       "mean_recording_s": float(np.mean([s.duration_s for _, s in nine]))}
    say("head on recorded motion")
    report = report_sessions("head", head_recorded, ["online", "batch", "ekf"], show_progress=False, workers=workers, scheduler=scheduler)
    rows = _speeds(report, {"isam2": "online", "batch": "batch", "method2": "ekf"})
    for key in ("isam2", "batch"):
        rows[key]["peer"], rows[key]["ratio_to_peer"] = "method2", rows[key]["x_realtime"] / rows["method2"]["x_realtime"]
    found["systems"]["head_recorded"] = rows
    say("head simulated")
    report = report_sessions("head", simulated_sessions("head", [0, 1, 2], 60.0), ["online", "ekf"], show_progress=False, workers=workers, scheduler=scheduler)
    rows = _speeds(report, {"online": "online", "method2": "ekf"})
    rows["online"]["peer"], rows["online"]["ratio_to_peer"] = "method2", rows["online"]["x_realtime"] / rows["method2"]["x_realtime"]
    found["systems"]["head"] = rows
    say("live")
    found["live"] = live_sample_times()
    found["memory"] = {"runs": {}}
    for key, length_h in (("batch_peak_mb_1h", 1.0), ("batch_peak_mb_24h", 24.0)):
        run = None
        if length_h <= hours:
            say(f"memory of the batch on {length_h:g} h")
            run = batch_peak_mb(broad, length_h)
        found["memory"][key] = None if run is None else run["peak_mb"]
        found["memory"]["runs"][key] = run
    return found


def live_sample_times(duration_s: float = 60.0, seed: int = 0) -> dict[str, float]:
    """The live head tracker fed a simulated session sample by sample in arrival order (in this process): the time each
    gyro sample's update took, p99 and worst, ms."""
    from ..scenarios.head import simulate_head
    from ..session import replay_in_arrival_order
    from ..systems.head import OnlineHeadTracker, RejectedSampleError, head_model_for

    session = simulate_head(seed, duration_s=duration_s)
    tracker = OnlineHeadTracker(head_model_for(session))
    times = []
    for event in replay_in_arrival_order(session):
        if event.stream.kind == "attitude":
            with contextlib.suppress(RejectedSampleError):  # refused and said by the tracker: the bench times the gyro's updates
                tracker.add_tracker(event.t, event.values)
            continue
        start = time.perf_counter()
        tracker.add_gyro(event.t, event.values)
        times.append(1e3 * (time.perf_counter() - start))
    values = np.asarray(times)
    return {"p99_ms": float(np.percentile(values, 99)), "max_ms": float(values.max()), "median_ms": float(np.median(values)),
            "samples": float(len(values))}


def batch_peak_mb(broad: Path | None, hours: float) -> dict[str, float] | None:
    """Peak RSS (MB) of a child process running the 9-axis batch, window by window, on a recording of ``hours`` (a BROAD
    trial repeated, or a simulation), made and let go a block at a time: {peak_mb, samples, missing, seconds}; None if
    the child failed."""
    source = str(broad / next(iter(sorted(p.name for p in broad.glob("*.mat"))))) if broad is not None and broad.is_dir() else "-"
    done = subprocess.run([sys.executable, "-c", MEMORY_SCRIPT, source, str(hours)], capture_output=True, text=True,
                          timeout=max(3600.0, 600.0 * hours))
    if done.returncode != 0:
        return None
    peak, samples, missing, seconds = (float(v) for v in done.stdout.split()[-4:])
    return {"peak_mb": peak, "samples": samples, "missing": missing, "seconds": seconds, "hours": hours}


def format_speed(found: dict[str, Any]) -> str:
    """The bench as a table: x real time per system and solver with its peer's and the ratio, then live, memory, cohort."""
    lines = [f"{'system':<15}{'solver':<13}{'x real time':>12}{'peer':>13}{'ratio':>8}"]
    for system, rows in found["systems"].items():
        for solver, row in rows.items():
            peer = row.get("peer", "")
            ratio = f"{row['ratio_to_peer']:.3f}" if "ratio_to_peer" in row else ""
            lines.append(f"{system:<15}{solver:<13}{row['x_realtime']:12.1f}{peer:>13}{ratio:>8}")
    every2 = found["systems"].get("attitude9", {}).get("online_every2")
    if every2 is not None and every2.get("total_deg") is not None and every2.get("total_deg_every_keyframe") is not None:
        lines.append(f"online_every2: the 9-axis online with [online] update_every = 2 (iSAM2 every second keyframe): mean total "
                     f"{every2['total_deg']:.3f} deg against {every2['total_deg_every_keyframe']:.3f} at every keyframe "
                     f"({'on BROAD: in-sample' if found['data'].get('attitude9', '').startswith('BROAD') else 'simulated test seeds'})")
    live = found["live"]
    lines.append(f"live head tracker, per gyro sample: median {live['median_ms']:.3f} ms, p99 {live['p99_ms']:.3f} ms, worst {live['max_ms']:.3f} ms")
    for key in ("batch_peak_mb_1h", "batch_peak_mb_24h"):
        run = found["memory"]["runs"].get(key)
        if run is None:
            lines.append(f"9-axis batch ({key}): not measured")
            continue
        lines.append(f"9-axis batch, windowed, peak RSS on {run['hours']:g} h ({run['samples']:.0f} samples, {run['missing']:.0f} without an "
                     f"estimate): {run['peak_mb']:.0f} MB, {3600.0 * run['hours'] / run['seconds']:.0f}x real time")
    cohort = found["cohort"]
    if cohort["recordings_per_hour_per_core_online"] is not None:
        lines.append(f"cohort: {cohort['recordings_per_hour_per_core_online']:.0f} recordings of {cohort['mean_recording_s']:.0f} s per hour per core "
                     "(9-axis online, solver time only)")
    lines.append("data: " + "; ".join(f"{k}: {v}" for k, v in found["data"].items()) + ". x real time = seconds of data per second of solving.")
    return "\n".join(lines)
