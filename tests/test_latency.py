"""Latency as a variable: the offset Jacobian, recovery of the true delay, and no failure when it is unobservable."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest

from fusegraph import Session, Stream
from fusegraph.factors.latency import apparent_markov_factor, apparent_white_factor, offset_column
from fusegraph.scenarios import simulate_head
from fusegraph.session import KIND_COLUMNS
from fusegraph.systems.head import run_batch, run_isam2


@pytest.mark.parametrize("seed", range(3))
def test_offset_jacobian_is_minus_the_body_rate(seed: int) -> None:
    rng = np.random.default_rng(seed)
    omega = rng.normal(0, 1.5, 3)
    start = gtsam.Rot3.Expmap(rng.normal(0, 1, 3))

    def attitude(t: float) -> gtsam.Rot3:
        return start.compose(gtsam.Rot3.Expmap(omega * t))

    stamp, step = 0.7, 1e-6

    def residual(delta: float) -> np.ndarray:  # Log(X(stamp)^-1 X(stamp - delta))
        return gtsam.Rot3.Logmap(attitude(stamp).between(attitude(stamp - delta)))

    numeric = (residual(step) - residual(-step)) / (2 * step)
    np.testing.assert_allclose(offset_column(omega)[:, 0], numeric, atol=1e-8)


def test_apparent_error_factors_are_the_stated_laws() -> None:
    rng = np.random.default_rng(4)
    rate_prev, rate_next = rng.normal(0, 1, 3), rng.normal(0, 1, 3)
    applied_prev, applied_next, delta = 0.01, 0.02, 0.035
    e_prev, e_next = rng.normal(0, 0.01, 3), rng.normal(0, 0.01, 3)
    # apparent errors of those sensor errors, with the remainders delta - applied
    g_prev = e_prev - rate_prev * (delta - applied_prev)
    g_next = e_next - rate_next * (delta - applied_next)
    values = gtsam.Values()
    values.insert(1, g_prev)
    values.insert(2, g_next)
    values.insert(3, np.array([delta]))
    sigma, tau, dt = 0.012, 2.0, 0.02
    phi = np.exp(-dt / tau)
    drive = sigma * np.sqrt(1 - phi**2)
    factor = apparent_markov_factor(1, 2, 3, rate_prev, rate_next, applied_prev, applied_next, dt, sigma, tau)
    assert factor.error(values) == pytest.approx(0.5 * np.sum(((e_next - phi * e_prev) / drive) ** 2), rel=1e-9)
    white = apparent_white_factor(2, 3, rate_next, applied_next)
    values.update(2, -rate_next * (delta - applied_next))  # a white-noise sensor: e = 0
    assert white.error(values) == pytest.approx(0.0, abs=1e-12)


def test_wrong_assumed_latency_is_recovered() -> None:
    session = simulate_head(
        7, profile="ideal", duration_s=8.0, tracker_latency_s=0.14, tracker_latency_assumed_s=0.1,
        gyro_white_sigma_rad_s=0.003, gyro_bias_rw_sigma=1e-4, tracker_white_sigma_deg=0.1, tracker_drop_fraction=0.0,
    )
    assert session.stream("tracker").latency_s == 0.1
    online, batch = run_isam2(session), run_batch(session)
    # low noise: the delay is observable to about a millisecond from 8 s of head motion
    assert online.extras["latency_s"] == pytest.approx(0.14, abs=2e-3)
    assert batch.extras["latency_s"] == pytest.approx(0.14, abs=1e-3)
    assert batch.extras["latency_sigma_s"] < 1e-3


def test_stationary_stretch_leaves_the_latency_to_its_prior() -> None:
    rng = np.random.default_rng(0)
    t_gyro = np.arange(301) / 100.0
    gyro = Stream("gyro", "gyro", t_gyro, rng.normal(0.0, 0.01, (301, 3)) + [0.02, -0.01, 0.03], KIND_COLUMNS["gyro"], 0.0,
                  {"rate_hz": 100.0, "noise_sigma_rad_s": 0.01, "calibrated": True})
    t_tracker = np.arange(150) / 50.0
    quats = np.tile([0.9, 0.1, 0.3, 0.3], (150, 1)) / np.linalg.norm([0.9, 0.1, 0.3, 0.3])
    tracker = Stream("tracker", "attitude", t_tracker, quats, KIND_COLUMNS["attitude"], 0.1, {"noise_sigma_deg": 0.5, "latency_sigma_s": 0.03})
    session = Session("head", {"gyro": gyro, "tracker": tracker})
    for estimate in (run_isam2(session), run_batch(session)):
        assert np.all(np.isfinite(estimate.quat_wxyz[t_gyro >= 0.2]))
        # no rotation, no information: the prior holds the latency (gyro noise looks like tiny rates,
        # so a little is "learnt": the sigma shrinks somewhat, the estimate stays well inside the prior)
        assert estimate.extras["latency_s"] == pytest.approx(0.1, abs=0.015)
        assert 0.5 * 0.03 < estimate.extras["latency_sigma_s"] <= 0.03


def test_a_drifting_latency_rebuilds_the_online_solver_as_its_segments_come() -> None:
    """A drifting latency adds a session-wide variable every second (``LATENCY_SEGMENT_S``), which iSAM2 cannot
    marginalise (it sits at the root): the re-anchoring after each new one rebuilds the solver, the others marginalise
    in place (11 of 19 here), and the estimate is the fixed-latency model's (0.13992 s against 0.13980 s)."""
    session = simulate_head(
        7, profile="ideal", duration_s=8.0, tracker_latency_s=0.14, tracker_latency_assumed_s=0.1,
        gyro_white_sigma_rad_s=0.003, gyro_bias_rw_sigma=1e-4, tracker_white_sigma_deg=0.1, tracker_drop_fraction=0.0,
    )
    tracker = session.stream("tracker")
    drifting = replace(session, streams={**session.streams, "tracker": replace(tracker, meta={**tracker.meta, "latency_rw_s_per_sqrt_s": 1e-4})})
    online = run_isam2(drifting)
    assert 0 < online.extras["in_place"] < online.extras["reanchors"]
    assert online.extras["latency_s"] == pytest.approx(0.14, abs=2e-3)
