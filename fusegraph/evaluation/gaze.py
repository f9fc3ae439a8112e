"""The gaze report: the gaze point on the wall over simulated seeds, with wrong-noise rows."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from ..baselines.ekf_gaze import GazeEkfConfig
from ..geometry import FloatArray
from ..metrics import gaze_rms_mm as rms_mm
from ..report.gaze import plot_gaze
from ..scenarios.gaze import GazeSession, simulate_gaze, viewing_config
from ..systems.gaze import METHODS, GazeEstimate, GazeModel, batch_model, run_batch, run_ekf, run_online

NOISE_FACTORS = (0.5, 2.0)
"""The report's wrong-declaration rows: every sensor sigma told x0.5 and x2 (``<method>_noise_x0.5``, ``_x2``)."""


def noise_scaled(session: GazeSession, factor: float, model: GazeModel | None = None) -> tuple[GazeSession, GazeModel, GazeEkfConfig]:
    """What the estimators are told when every sensor sigma is declared ``factor`` times its figure: the graph's head
    IMU, gravity and magnetometer sigmas and the pixel sigma (the session's camera), and the EKF's (tuned) figures.
    ``model``: the graph's model before scaling (default the online one)."""
    camera = session.config.camera
    scaled = replace(session, config=replace(session.config, camera=replace(camera, pixel_sigma=factor * camera.pixel_sigma)))
    model = model or GazeModel()
    ekf = GazeEkfConfig()
    return (scaled, replace(model, head=model.head.with_noise_scaled(factor)),
            replace(ekf, head=ekf.head.with_noise_scaled(factor), pixel_sigma=factor * ekf.pixel_sigma))


def _noisy_runner(method: str, factor: float) -> Callable[[GazeSession], GazeEstimate]:
    def run(session: GazeSession) -> GazeEstimate:
        scaled, model, ekf = noise_scaled(session, factor, batch_model() if method == "batch" else None)
        return run_ekf(session, ekf) if method == "ekf" else (run_online if method == "online" else run_batch)(scaled, model)

    return run


def _report_runners(noise_rows: bool) -> dict[str, Callable[[GazeSession], GazeEstimate]]:
    runners: dict[str, Callable[[GazeSession], GazeEstimate]] = {"ekf": run_ekf, "online": run_online, "batch": run_batch}
    if noise_rows:
        runners.update({f"{m}_noise_x{k:g}": _noisy_runner(m, k) for m in METHODS for k in NOISE_FACTORS})
    return runners


def gaze_report(seeds: tuple[int, ...] = (0,), plot: str | None = None, noise_rows: bool = True, viewing: bool = False) -> dict[str, object]:
    """``fusegraph report gaze``: RMS of the wall point per method (mean over seeds) and speed; with ``noise_rows`` also
    every method told its sensor sigmas x0.5 and x2 (``NOISE_FACTORS``); ``viewing``: the scene-viewing scenario
    (``scenarios.gaze.viewing_config``) instead of the two marks."""
    runners = _report_runners(noise_rows)
    sums: dict[str, dict[str, float]] = {m: {"x_mm": 0.0, "z_mm": 0.0, "seconds": 0.0, "duration": 0.0} for m in runners}
    first: dict[str, FloatArray] = {}
    session0 = None
    for seed in seeds:
        session = simulate_gaze(seed, viewing_config() if viewing else None)
        session0 = session0 or session
        for name, run in runners.items():
            result = run(session)
            est, seconds = result.points_xz_m, result.runtime_s
            if seed == seeds[0]:
                first[name] = est
            r = rms_mm(est, session)
            sums[name]["x_mm"] += r["x_mm"] ** 2
            sums[name]["z_mm"] += r["z_mm"] ** 2
            sums[name]["seconds"] += seconds
            sums[name]["duration"] += float(session.t[-1] - session.t[0])
    methods = {name: {"rms": {"x_mm": float(np.sqrt(v["x_mm"] / len(seeds))), "z_mm": float(np.sqrt(v["z_mm"] / len(seeds)))},
                      "x_realtime": v["duration"] / v["seconds"]} for name, v in sums.items()}
    if plot is not None and session0 is not None:
        plot_gaze(session0, {m: first[m] for m in METHODS}, plot)
    return {"methods": methods, "seeds": list(seeds), "scenario": "viewing" if viewing else "two_marks"}
