"""The simulated eye on a recorded head motion (``scenarios.eye``) and the gaze benchmark it makes (``import broad --system
gaze``, scored by ``metrics.gaze_ray_errors``)."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import SHARED_DATA, requires_shared_data

from fusegraph.factors.gaze import SceneCamera
from fusegraph.frontends.gaze_timing import device_fixations
from fusegraph.geometry import quat_from_rotvec, quat_multiply
from fusegraph.metrics import gaze_ray_errors
from fusegraph.records import GazeScenarioConfig, GazeSession
from fusegraph.scenarios.eye import EyeConfig, measure_pupil, simulate_eye


def _head(duration_s: float = 60.0, rate_hz: float = 200.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A head turning +-30 deg in yaw and +-10 deg in pitch at 0.3 and 0.45 Hz, at rest in position."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    yaw = np.radians(30.0) * np.sin(2 * np.pi * 0.3 * t)
    pitch = np.radians(10.0) * np.sin(2 * np.pi * 0.45 * t)
    quat = quat_multiply(quat_from_rotvec(np.c_[0 * t, 0 * t, yaw]), quat_from_rotvec(np.c_[0 * t, pitch, 0 * t]))
    return t, quat, np.zeros((len(t), 3))


PERFECT = replace(EyeConfig(), vor_gain=1.0, precision_deg=0.0, accuracy_deg=0.0, delay_s=0.0)
"""An eye that counter-rotates exactly and a tracker without noise or delay."""


def _session(trace_t: np.ndarray, head_ray: np.ndarray, t: np.ndarray) -> GazeSession:
    camera = SceneCamera(focal_px=880.0, width_px=1920, height_px=1080)
    n = len(trace_t)
    return GazeSession(t, np.zeros((len(t), 3)), np.zeros((len(t), 3)), np.zeros((len(t), 3)), trace_t, camera.project(head_ray),
                       np.full((len(t), 4), np.nan), np.full((n, 2), np.nan), GazeScenarioConfig(camera=camera))


def test_a_perfect_eye_holds_its_target_and_the_true_attitude_scores_zero() -> None:
    t, quat, position = _head()
    trace = simulate_eye(t, quat, position, np.random.default_rng(0), PERFECT, (47.5, 31.5))
    fixating = trace.fixation > 0
    assert fixating.mean() > 0.6 and len(trace.targets_m) > 50  # mostly fixations, many of them
    # in a fixation the world ray points at the target from the (still) head
    target = trace.targets_m[trace.fixation[fixating].astype(int) - 1]
    aim = target / np.linalg.norm(target, axis=1, keepdims=True)
    np.testing.assert_allclose(trace.true_world_ray[fixating], aim, atol=1e-9)
    # the tracker's ray turned by the true attitude is the true world ray (ray -> pixel -> ray: rounding only)
    index = np.clip(np.searchsorted(t, trace.t), 0, len(t) - 1)
    session = _session(trace.t, trace.head_ray, t)
    fixations = [f.rows for f in device_fixations(session, trace.fixation)]  # the simulator's labels pick what scores
    errors = gaze_ray_errors(quat[index], session, trace.true_world_ray, fixations)
    assert errors["gaze_error_deg"] < 1e-6 and errors["fixations"] > 50
    # an attitude 2 deg off in heading is 2 deg off in the world at every level sample (the gaze within 31 deg of level:
    # the angle between two rays turned 2 deg about the vertical is 2 deg x cos(elevation))
    off = quat_multiply(np.tile(quat_from_rotvec(np.array([0.0, 0.0, np.radians(2.0)])), (len(index), 1)), quat[index])
    assert 1.6 < gaze_ray_errors(off, session, trace.true_world_ray, fixations)["gaze_error_deg"] <= 2.0 + 1e-9


def test_the_eye_slips_by_the_rest_of_the_head_turn_and_stays_in_the_camera_view() -> None:
    t, quat, position = _head()
    trace = simulate_eye(t, quat, position, np.random.default_rng(1), replace(PERFECT, vor_gain=0.9), (47.5, 31.5))
    fixating = trace.fixation > 0
    target = trace.targets_m[trace.fixation[fixating].astype(int) - 1]
    aim = target / np.linalg.norm(target, axis=1, keepdims=True)
    slip_deg = np.degrees(np.arccos(np.clip(np.sum(trace.true_world_ray[fixating] * aim, axis=1), -1, 1)))
    # a tenth of the head's turn in a fixation: the head turns up to ~60 deg/s here, a fixation lasts up to 2 s
    assert 0.05 < float(np.median(slip_deg)) < 2.0 and float(slip_deg.max()) < 12.0
    ray = trace.head_ray
    assert np.all(ray[:, 0] > 0) and np.all(np.abs(ray[:, 2] / ray[:, 0]) <= np.tan(np.radians(31.5)) + 1e-9)


def test_durations_blinks_and_noise_follow_the_configuration() -> None:
    t, quat, position = _head(600.0, 100.0)
    config = EyeConfig()
    trace = simulate_eye(t, quat, position, np.random.default_rng(2), config, (90.0, 90.0))
    ids = trace.fixation[trace.fixation > 0]
    counts = np.bincount(ids.astype(int))[1:]
    durations = counts[counts > 0] / config.rate_hz
    # the log-normal's median (0.216 s), cut by the head's turns and the 20 ms sample grid: within 40 %
    assert 0.6 * config.fixation_median_s < float(np.median(durations)) < 1.4 * config.fixation_median_s
    missing = 1.0 - len(trace.t) / (600.0 * config.rate_hz)
    # 17 blinks of 0.278 s a minute hide ~8 % of the samples
    assert 0.04 < missing < 0.12
    np.testing.assert_allclose(np.diff(trace.t).min(), 1.0 / config.rate_hz, rtol=1e-6)


@requires_shared_data("gaze_pupil_invisible")
def test_the_eye_s_measured_parameters_are_the_shipped_pupil_recording_s() -> None:
    found = measure_pupil(SHARED_DATA / "gaze_pupil_invisible")
    config = EyeConfig()
    assert found["fixation_median_s"] == pytest.approx(config.fixation_median_s, abs=0.0005)
    assert found["fixation_log_sigma"] == pytest.approx(config.fixation_log_sigma, abs=0.005)
    assert (found["eye_sigma_azimuth_deg"], found["eye_sigma_elevation_deg"]) == pytest.approx(config.eye_sigma_deg, abs=0.05)
    assert found["blink_s"] == pytest.approx(config.blink_s, abs=0.0005)
    assert found["precision_deg"] == pytest.approx(config.precision_deg, abs=0.005)


@requires_shared_data("broad")
def test_import_broad_as_gaze_scores_the_world_ray_of_each_method(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from fusegraph.cli import main
    from fusegraph.session import load_session

    trial = SHARED_DATA / "broad" / "01_undisturbed_slow_rotation_A.mat"
    assert main(["import", "broad", str(trial), "--system", "gaze", "--out", str(tmp_path / "g")]) == 0
    session = load_session(tmp_path / "g")
    assert session.system == "gaze" and session.meta["session"]["gaze_truth"] == "world_ray"
    assert session.meta["session"]["head_motion"] == "free"  # a hand-held sensor: the head is the 9-axis system's model
    assert session.stream("fixation").meta["role"] == "scoring only"
    # the delay is found from the gaze and the gyro (the eye's was 9.5 ms; one 285 Hz sample is 3.5 ms)
    assert abs(session.stream("gaze").meta["time_offset_s"] - EyeConfig().delay_s) < 0.01
    capsys.readouterr()
    found = {}
    for solver in ("imu_only", "gyro"):
        assert main(["run", str(tmp_path / "g"), "--solver", solver, "--json", "--out", str(tmp_path / f"{solver}.csv")]) == 0
        found[solver] = json.loads(capsys.readouterr().out)["metrics"]
    # the raw gyro drifts tens of degrees in 200 s; the 9-axis attitude holds the gaze within a few
    assert found["imu_only"]["gaze_error_deg"] < 3.0 < found["gyro"]["gaze_error_deg"]
    assert found["imu_only"]["fixations"] == found["gyro"]["fixations"] > 100
    # its picture: the world gaze against the eye's and the angle between them (not a wall the eye never looked at)
    assert main(["run", str(tmp_path / "g"), "--solver", "imu_only", "--out", str(tmp_path / "i.csv"), "--plot", str(tmp_path / "g.png")]) == 0
    assert (tmp_path / "g.png").stat().st_size > 20_000
