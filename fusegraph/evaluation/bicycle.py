"""The cyclist report: thigh pitch/roll RMS in the braking phase over simulated seeds, with wrong-noise rows."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..geometry import FloatArray
from ..graphs.bicycle import BicycleModel
from ..report.bicycle import plot_bicycle
from ..scenarios.bicycle import BicycleScenarioConfig, BicycleSession, simulate_bicycle
from ..systems.bicycle import METHODS, NO_REMOVAL_EKF, PAPER_EKF, RUNNERS, braking_rms_deg

NOISE_FACTORS = (0.5, 2.0)
"""The report's wrong-declaration rows: every sensor sigma told x0.5 and x2 (``<method>_noise_x0.5``, ``_x2``)."""


def _noisy_runner(method: str, factor: float) -> Callable[[BicycleSession], FloatArray]:
    """A method told every sensor sigma ``factor`` times its figure (the EKFs' tuned figures, the graph's declarations)."""

    def run(s: BicycleSession) -> FloatArray:
        if method in ("no_removal", "paper_pipeline"):
            config = NO_REMOVAL_EKF if method == "no_removal" else PAPER_EKF
            return RUNNERS[method](s, config.with_noise_scaled(factor))  # type: ignore[operator]
        model = BicycleModel()
        scaled = replace(model, frame=model.frame.with_noise_scaled(factor), thigh=model.thigh.with_noise_scaled(factor))
        return RUNNERS[method](s, scaled)  # type: ignore[operator]

    return run


def _report_runners(noise_rows: bool) -> dict[str, Callable[[BicycleSession], FloatArray]]:
    runners: dict[str, Callable[[BicycleSession], FloatArray]] = dict(RUNNERS)  # type: ignore[arg-type]
    if noise_rows:
        runners.update({f"{m}_noise_x{k:g}": _noisy_runner(m, k) for m in METHODS for k in NOISE_FACTORS})
    return runners


def bicycle_report(seeds: tuple[int, ...] = (0, 1, 2), plot: str | None = None, noise_rows: bool = True) -> dict[str, object]:
    """``fusegraph report bicycle``: braking-phase thigh pitch/roll RMS per method (RMS over seeds), speed; the stand ride too.
    With ``noise_rows`` also every method told its sensor sigmas x0.5 and x2 (``NOISE_FACTORS``), on the downhill ride."""
    out: dict[str, object] = {}
    for ride in ("downhill", "stand"):
        runners = _report_runners(noise_rows and ride == "downhill")
        sq: dict[str, list[float]] = {m: [0.0, 0.0, 0.0, 0.0] for m in runners}
        first: dict[str, FloatArray] = {}
        session0 = None
        for seed in seeds:
            s = simulate_bicycle(seed, BicycleScenarioConfig(ride=ride))
            session0 = session0 or s
            for name, run in runners.items():
                start = time.perf_counter()
                q = run(s)
                seconds = time.perf_counter() - start
                if seed == seeds[0]:
                    first[name] = q
                r = braking_rms_deg(q, s)
                sq[name][0] += r["pitch_deg"] ** 2
                sq[name][1] += r["roll_deg"] ** 2
                sq[name][2] += seconds
                sq[name][3] += float(s.t[-1] - s.t[0])
        methods = {m: {"rms": {"pitch_deg": float(np.sqrt(v[0] / len(seeds))), "roll_deg": float(np.sqrt(v[1] / len(seeds)))},
                       "x_realtime": v[3] / v[2]} for m, v in sq.items()}
        if ride == "downhill":
            out["methods"] = methods
            if plot is not None and session0 is not None:
                plot_bicycle(session0, {m: first[m] for m in METHODS}, plot)
        else:
            out["stand"] = {"methods": methods, "note": "same phase (30-35 s): the rider stops pedalling and holds the thigh; no translation"}
    out["seeds"] = list(seeds)
    return out
