"""The head system's reports and benches: the paper's Table 1 over simulated seeds (with wrong-noise and
assumed-latency rows), the speed bench on a long session and the hour-long soak."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..baselines.ekf import HeadEkfConfig
from ..geometry import (
    FloatArray,
)
from ..graphs.head import HeadModel, head_model_for
from ..metrics import AXES, AttitudeScore, mean_scores, score_attitude
from ..progress import progress as progress_bar
from ..session import Session
from ..systems.head import METHODS, TUNED_EKF, run_batch, run_ekf, run_isam2, run_method

#: Rows of the head report with the noise declared wrong: (row, method, factor on every declared sigma).
NOISE_ROWS = tuple((f"{m}_noise_x{k:g}", m, k) for m in ("method2", "isam2", "batch") for k in (0.5, 2.0))


def with_noise_scaled(session: Session, factor: float) -> tuple[Session, HeadModel, HeadEkfConfig]:
    """What the estimators are told when every noise sigma is declared ``factor`` times the truth: the graph's
    model (gyro white noise and bias walk, tracker white and slowly varying error) and the EKF's figures."""
    model = head_model_for(session)
    gyro = replace(model.gyro, white_sigma_rad_s=factor * model.gyro.white_sigma_rad_s, bias_rw_sigma=factor * model.gyro.bias_rw_sigma)
    tracker = replace(model.tracker, white_sigma_deg=factor * model.tracker.white_sigma_deg, markov_sigma_deg=factor * model.tracker.markov_sigma_deg)
    base = TUNED_EKF
    ekf = replace(base, gyro_sigma_rad_s=factor * base.gyro_sigma_rad_s, tracker_sigma_rad=factor * base.tracker_sigma_rad)
    return session, replace(model, gyro=gyro, tracker=tracker), ekf


@dataclass
class HeadReport:
    """The paper's Table 1 for the simulated scenario: per method, mean over seeds of RMS per axis."""

    profile: str
    seeds: list[int]
    duration_s: float
    scores: dict[str, AttitudeScore]
    ms_per_40ms: dict[str, float]
    per_seed: dict[str, list[AttitudeScore]]
    latency: dict[str, float] | None = None
    """With an assumed latency: true, assumed, and the mean over seeds of fusegraph's final online estimate and sigma."""

    def as_json(self) -> dict[str, Any]:
        """``{"methods": {name: {"rms_rad": {...}, "ms_per_40ms": x, "nees": x}}}`` plus run info."""
        methods = {
            name: {"rms_rad": dict(zip(AXES, (float(v) for v in score.rms_rad), strict=True)), "ms_per_40ms": self.ms_per_40ms[name], "nees": score.nees}
            for name, score in self.scores.items()
        }
        out: dict[str, Any] = {"methods": methods, "profile": self.profile, "seeds": self.seeds, "duration_s": self.duration_s}
        if self.latency is not None:
            out["latency"] = self.latency
        return out

    def ratio_to(self, reference: str = "method2") -> dict[str, list[float]]:
        """Each method's RMS divided by the reference's, per axis."""
        ref = self.scores[reference].rms_rad
        return {name: [float(v) for v in score.rms_rad / ref] for name, score in self.scores.items()}

    def table(self) -> str:
        """The table as text: RMS in 1e-2 rad, ratio to Method II, time per 40 ms of data, NEES."""
        ratios = self.ratio_to()
        width = max(len(LABELS[name]) for name in self.scores)
        lines = [
            f"head tracking, profile {self.profile}, seeds {_seed_text(self.seeds)}, {self.duration_s:g} s each; RMS after the first second",
            f"{'method':<{width}} {'azimuth':>8} {'elev.':>8} {'roll':>8}   {'ratio to Method II (az/el/roll)':<32} {'ms/40ms':>8} {'NEES':>6}",
            f"{'':<{width}} {'[1e-2 rad]':>26}",
        ]
        for name, score in self.scores.items():
            rms = score.rms_rad * 100
            ratio = "/".join(f"{r:.2f}" for r in ratios[name])
            nees = f"{score.nees:6.2f}" if score.nees is not None else f"{'-':>6}"
            lines.append(f"{LABELS[name]:<{width}} {rms[0]:8.3f} {rms[1]:8.3f} {rms[2]:8.3f}   {ratio:<32} {self.ms_per_40ms[name]:8.3f} {nees}")
        if self.latency is not None:
            lat = self.latency
            lines.append(
                f"latency: true {1000 * lat['true']:.1f} ms, assumed {1000 * lat['assumed']:.1f} ms, "
                f"estimated online at the end {1000 * lat['estimated']:.1f} ms (sigma {1000 * lat['sigma']:.1f} ms, mean over seeds)"
            )
        return "\n".join(lines)


LABELS_BASE = {"method2": "Method II", "isam2": "iSAM2", "batch": "batch"}


LABELS = {
    "tracker": "tracker",
    "gyro": "gyro",
    "kalman": "Kalman",
    "method1": "Method I",
    "method2": "Method II",
    "isam2": "iSAM2",
    "batch": "batch",
    "method2_wrong_d": "Method II, assumed d",
    "isam2_td": "iSAM2, d estimated",
    "batch_td": "batch, d estimated",
    "method1_paper_values": "Method I, paper's noise",
    "method2_paper_values": "Method II, paper's noise",
    **{row: f"{LABELS_BASE[m]}, noise x{k:g}" for row, m, k in NOISE_ROWS},
}


def _seed_text(seeds: list[int]) -> str:
    if seeds and seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 2:
        return f"{seeds[0]}-{seeds[-1]}"
    return ",".join(str(s) for s in seeds)


LATENCY_ROWS = ("method2_wrong_d", "isam2_td", "batch_td")
"""Extra rows when the latency is only assumed: Method II with the wrong d, fusegraph estimating it."""


def head_report(
    seeds: Sequence[int],
    profile: str = "realistic",
    duration_s: float = 10.0,
    methods: Sequence[str] = METHODS,
    model: HeadModel | None = None,
    progress: Callable[[str], None] | None = None,
    latency_true_s: float | None = None,
    latency_assumed_s: float | None = None,
    noise_rows: bool = True,
) -> HeadReport:
    """Simulate each seed, run every method on it, score against the lag-free reference.

    ``noise_rows``: also Method II, iSAM2 and batch told every noise sigma x0.5 and x2 of the truth
    (``<method>_noise_x0.5``, ``<method>_noise_x2``): what a wrong declaration costs.

    With ``latency_true_s`` and ``latency_assumed_s`` the tracker really lags by the true latency; the
    paper's rows, ``isam2`` and ``batch`` are given it (oracle), while ``method2_wrong_d`` uses the
    assumed one and ``isam2_td``/``batch_td`` start from it as a prior and estimate it.
    """
    from ..scenarios.head import simulate_head

    if (latency_true_s is None) != (latency_assumed_s is None):
        raise ValueError("give both --latency-true and --latency-assumed, or neither")
    rows = list(methods) + (list(LATENCY_ROWS) if latency_assumed_s is not None else [])
    if noise_rows and model is None:
        rows += [row for row, _, _ in NOISE_ROWS]
    rows += [f"{m}_paper_values" for m in ("method1", "method2") if m in methods]
    per_seed: dict[str, list[AttitudeScore]] = {m: [] for m in rows}
    runtime: dict[str, float] = dict.fromkeys(rows, 0.0)
    estimated: list[tuple[float, float]] = []
    true_kw: dict[str, Any] = {} if latency_true_s is None else {"tracker_latency_s": latency_true_s}
    for n, seed in enumerate(progress_bar(seeds, len(seeds), "head report (seeds)")):
        oracle = simulate_head(seed, profile=profile, duration_s=duration_s, **true_kw)
        assumed = None
        if latency_assumed_s is not None:
            assumed = simulate_head(seed, profile=profile, duration_s=duration_s, tracker_latency_assumed_s=latency_assumed_s, **true_kw)
        assert oracle.truth is not None
        noisy = {row: (method, factor) for row, method, factor in NOISE_ROWS}
        for row in rows:
            session = oracle if row not in LATENCY_ROWS else assumed
            assert session is not None
            if row in noisy:
                method, factor = noisy[row]
                _, scaled, ekf = with_noise_scaled(session, factor)  # the EKF row scales its tuned figures
                estimate = run_ekf(session, method, ekf) if method == "method2" else run_method(session, method, scaled)
            else:
                estimate = run_method(session, row.removesuffix("_wrong_d").removesuffix("_td"), model)
            per_seed[row].append(score_attitude(estimate, oracle.truth.t, oracle.truth.values))
            runtime[row] += estimate.runtime_s
            if row == "isam2_td":
                estimated.append((estimate.extras["latency_s"], estimate.extras["latency_sigma_s"]))
        if progress is not None:
            progress(f"seed {seed} done ({n + 1}/{len(seeds)})")
    blocks = len(seeds) * duration_s / 0.04
    latency = None
    if latency_assumed_s is not None and latency_true_s is not None:
        latency = {
            "true": latency_true_s,
            "assumed": latency_assumed_s,
            "estimated": float(np.mean([e for e, _ in estimated])),
            "sigma": float(np.mean([sg for _, sg in estimated])),
        }
    return HeadReport(
        profile,
        list(seeds),
        duration_s,
        {m: mean_scores(per_seed[m]) for m in rows},
        {m: 1000.0 * runtime[m] / blocks for m in rows},
        per_seed,
        latency,
    )


def head_bench(
    duration_s: float = 600.0, repeat: int = 3, seed: int = 0, profile: str = "realistic", progress: Callable[[str], None] | None = None
) -> dict[str, float]:
    """Speed of the whole causal loop and of the batch smoother on one long session (median of repeats).

    ``x_realtime_first_minute`` / ``_last_minute``: data seconds per wall second over the first and
    the last 60 s of the session (replay, factor building, solving, an estimate at every gyro sample).
    """
    import resource

    from ..scenarios.head import simulate_head

    session = simulate_head(seed, profile=profile, duration_s=duration_s)
    first, last, batch = [], [], []
    for r in progress_bar(range(repeat), repeat, "head bench (repeats)"):
        estimate = run_isam2(session, None)
        wall, t = estimate.extras["wall_s"], estimate.t
        minute = min(60.0, duration_s / 2)
        first.append(minute / _wall_between(t, wall, t[0], t[0] + minute))
        last.append(minute / _wall_between(t, wall, t[-1] - minute, t[-1]))
        batch.append(run_batch(session, None).runtime_s)
        if progress is not None:
            progress(f"repeat {r + 1}/{repeat}: first minute {first[-1]:.1f}x, last minute {last[-1]:.1f}x real time, batch {batch[-1]:.2f} s")
    peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return {
        "x_realtime_first_minute": float(np.median(first)),
        "x_realtime_last_minute": float(np.median(last)),
        "batch_s": float(np.median(batch)),
        "peak_rss_mb": float(peak_rss_mb),
        "duration_s": float(duration_s),
        "repeat": int(repeat),
    }


def head_soak(duration_s: float = 3600.0, block_s: float = 600.0, seed: int = 0) -> dict[str, Any]:
    """``fusegraph bench soak``: the online head tracker over ``duration_s`` of data in one run; speed per block
    (data seconds per wall second) and peak memory, to show both stay flat over hours."""
    import resource

    from ..scenarios.head import simulate_head

    session = simulate_head(seed, duration_s=duration_s)
    estimate = run_isam2(session, None)
    wall, t = estimate.extras["wall_s"], estimate.t
    starts = np.arange(t[0], t[-1] - 0.5 * block_s, block_s)
    speed = [block_s / _wall_between(t, wall, float(a), min(float(a) + block_s, float(t[-1]))) for a in starts]
    return {"duration_s": duration_s, "block_s": block_s, "x_realtime_per_block": [float(x) for x in speed],
            "last_over_first": float(speed[-1] / speed[0]), "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "finite": bool(np.isfinite(estimate.quat_wxyz[len(t) // 100 :]).all())}


def _wall_between(t: FloatArray, wall: FloatArray, t0: float, t1: float) -> float:
    i0, i1 = int(np.searchsorted(t, t0)), int(np.searchsorted(t, t1)) - 1
    return float(wall[i1] - wall[i0])
