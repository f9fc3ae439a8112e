"""`fusegraph bench speed`: its parts on small inputs (the bench itself is a benchmark, not a test: no timing is asserted)."""

from __future__ import annotations

import numpy as np
import pytest

from fusegraph.evaluation.runner import simulated_sessions
from fusegraph.evaluation.speed import format_speed, live_sample_times, repeated, repeated_blocks


def test_a_recording_repeated_to_a_length_keeps_its_rate_and_streams() -> None:
    _, session = simulated_sessions("attitude9", [0], 20.0)[0]
    long = repeated(session, 65.0)
    gyro = long.stream("gyro")
    assert set(long.streams) == {"gyro", "accel", "mag", "mag_cal"} and long.truth is None
    assert len(long.stream("mag_cal")) == len(session.stream("mag_cal"))  # a calibration recording is not repeated
    assert abs(gyro.t[-1] - 65.0) < 0.02 and np.all(np.diff(gyro.t) > 0)  # one clock on, no step backwards at a seam
    assert np.allclose(np.median(np.diff(gyro.t)), np.median(np.diff(session.stream("gyro").t)))


def test_the_live_tracker_is_timed_per_gyro_sample_and_the_table_reads() -> None:
    live = live_sample_times(duration_s=5.0)
    assert live["samples"] > 400 and live["max_ms"] >= live["p99_ms"] >= live["median_ms"] > 0.0
    found = {"systems": {"attitude9": {"online": {"x_realtime": 400.0, "peer": "vqf", "ratio_to_peer": 0.04}, "vqf": {"x_realtime": 10000.0},
                                       "online_every2": {"x_realtime": 480.0, "peer": "vqf", "ratio_to_peer": 0.048, "total_deg": 1.945,
                                                         "total_deg_every_keyframe": 1.932}}},
             "live": live, "memory": {"batch_peak_mb_1h": 300.0, "batch_peak_mb_24h": None, "runs": {
                 "batch_peak_mb_1h": {"peak_mb": 300.0, "samples": 1026000.0, "missing": 0.0, "seconds": 9.0, "hours": 1.0}, "batch_peak_mb_24h": None}},
             "cohort": {"recordings_per_hour_per_core_online": 9000.0, "mean_recording_s": 190.0}, "data": {"attitude9": "simulated"}}
    text = format_speed(found)
    assert "attitude9      online              400.0          vqf   0.040" in text
    assert "attitude9      online_every2       480.0          vqf   0.048" in text
    assert "update_every = 2 (iSAM2 every second keyframe): mean total 1.945 deg against 1.932 at every keyframe (simulated test seeds)" in text
    assert "peak RSS on 1 h (1026000 samples, 0 without an estimate): 300 MB, 400x real time" in text


def test_a_repeated_recording_in_blocks_is_the_same_samples_as_whole() -> None:
    _, session = simulated_sessions("attitude9", [0], 20.0)[0]
    whole = repeated(session, 65.0)
    blocks = list(repeated_blocks(session, 65.0, block_s=7.0))
    assert len(blocks) == 10  # 65 s in blocks of 7 s
    for name in ("gyro", "accel", "mag"):
        np.testing.assert_array_equal(np.concatenate([b.stream(name).t for b in blocks]), whole.stream(name).t)
        np.testing.assert_array_equal(np.concatenate([b.stream(name).values for b in blocks]), whole.stream(name).values)


def test_a_solve_pauses_the_collector_and_restores_it() -> None:
    """``Preset.solve`` runs with the cyclic collector off (``solvers.pause.collector_paused``) and leaves it as it found
    it, on or off, also when the solver raises."""
    import gc

    from fusegraph.solvers.pause import collector_paused

    seen = []
    for before in (True, False):
        (gc.enable if before else gc.disable)()
        with collector_paused():
            seen.append(gc.isenabled())
        assert gc.isenabled() == before
        with pytest.raises(RuntimeError), collector_paused():
            raise RuntimeError("a solver failed")
        assert gc.isenabled() == before
    gc.enable()
    assert seen == [False, False]
