"""Gaze in world coordinates: camera model, projection factor, the graph against the truth and the EKF."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from conftest import assert_jacobians_match

from fusegraph.factors.gaze import FixationNoise, SceneCamera, fixation_walk, gaze_factor
from fusegraph.graphs.attitude9 import X
from fusegraph.metrics import gaze_rms_mm
from fusegraph.scenarios.gaze import GazeScenarioConfig, simulate_gaze
from fusegraph.systems import gaze


def test_camera_project_and_ray_are_inverse() -> None:
    cam = SceneCamera()
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(0.5, 3, 20), rng.uniform(-1, 1, 20), rng.uniform(-1, 1, 20)])
    rays = cam.ray(cam.project(points))
    np.testing.assert_allclose(rays, points / np.linalg.norm(points, axis=1, keepdims=True), atol=1e-12)
    # a point to the left (+y) and up (+z) of the head shows left (u < 0) and up (v > 0)
    u, v = cam.project(np.array([[1.0, 0.2, 0.1]]))[0]
    assert u < 0 < v


def test_gaze_factor_matches_the_camera_model_and_its_jacobians() -> None:
    cam = SceneCamera(cauchy_k=0.0)
    head = gtsam.Pose3(gtsam.Rot3.Ypr(0.2, -0.1, 0.05), np.array([0.01, -0.02, 0.03]))
    offset = gtsam.Rot3.Ypr(0.03, 0.02, -0.01)  # the gyro's rotation from the keyframe to the sample
    point = np.array([1.0, 0.15, -0.1])
    camera_R = head.rotation().compose(offset)
    uv = cam.project((camera_R.matrix().T @ (point - head.translation()))[None, :])[0]
    values = gtsam.Values()
    values.insert(X(0), head)
    values.insert(7, point)
    factor = gaze_factor(X(0), 7, uv, offset, cam)
    assert np.abs(factor.unwhitenedError(values)).max() < 1e-9  # pixels: exact data
    assert_jacobians_match(factor, values)


def test_fixation_walk_absorbs_a_saccade() -> None:
    """A 0.3 m jump costs what the Cauchy kernel says, k^2/2 log(1 + (r/k)^2), a few percent of a Gaussian's
    r^2/2 (r = 0.3 m / sigma, ~67 sigmas here) with the tuned kernel width."""
    noise = FixationNoise()
    f = fixation_walk(1, 2, 0.2, noise)
    values = gtsam.Values()
    values.insert(1, np.array([1.0, 0.0, 0.0]))
    values.insert(2, np.array([1.0, 0.3, 0.0]))
    r = 0.3 / (noise.drift_m_per_sqrt_s * np.sqrt(0.2))
    k = noise.cauchy_k
    assert f.error(values) == pytest.approx(0.5 * k**2 * np.log1p((r / k) ** 2), rel=1e-9)
    assert f.error(values) < 0.05 * 0.5 * r**2


@pytest.fixture(scope="module")
def session() -> gaze.GazeSession:
    return simulate_gaze(0, GazeScenarioConfig(duration_s=20.0, switch_s=12.0))


def test_graph_finds_the_gaze_point_and_beats_the_ekf(session: gaze.GazeSession) -> None:
    online = gaze.run_online(session).points_xz_m
    batch = gaze.run_batch(session).points_xz_m
    ekf = gaze.run_ekf(session).points_xz_m
    r = {name: gaze_rms_mm(est, session) for name, est in (("online", online), ("batch", batch), ("ekf", ekf))}
    # the figures `fusegraph report gaze` prints; bounds with margin over the measured ones (online ~6, batch ~3 mm)
    assert r["batch"]["x_mm"] < 8 and r["batch"]["z_mm"] < 8, r
    assert r["online"]["x_mm"] < 15 and r["online"]["z_mm"] < 15, r
    # the EKF's open noise figures are tuned on seeds 100-119 (seed 0 here is a test seed): it is a fair
    # baseline now (~10/6 mm over seeds 0-9), so the graph must beat it, not a crippled version of it
    assert r["ekf"]["x_mm"] < 25 and r["ekf"]["z_mm"] < 25, r
    for axis in ("x_mm", "z_mm"):
        assert r["online"][axis] < r["ekf"][axis] and r["batch"][axis] < 0.6 * r["ekf"][axis], r


def test_online_is_causal(session: gaze.GazeSession) -> None:
    """Cutting the future changes no gaze estimate made before the cut."""
    from dataclasses import replace

    cut_s = 8.0
    short = replace(session, t=session.t[session.t < cut_s], gyro_rad_s=session.gyro_rad_s[session.t < cut_s],
                    accel_m_s2=session.accel_m_s2[session.t < cut_s], mag=session.mag[session.t < cut_s],
                    tracker_t=session.tracker_t[session.tracker_t < cut_s], gaze_px=session.gaze_px[session.tracker_t < cut_s],
                    truth_quat_wxyz=session.truth_quat_wxyz[session.t < cut_s], truth_gaze_xz_m=session.truth_gaze_xz_m[session.tracker_t < cut_s])
    full = gaze.run_online(session).points_xz_m
    part = gaze.run_online(short).points_xz_m
    done = np.all(np.isfinite(part), axis=1)
    done &= short.tracker_t <= short.t[-1] - 0.2  # the short run's last keyframe period: carried from its last keyframe at its end
    np.testing.assert_allclose(part[done], full[: len(part)][done], atol=1e-9)


def test_report_rows_tell_every_method_its_sigmas_halved_and_doubled(session: gaze.GazeSession) -> None:
    from fusegraph.evaluation.gaze import _report_runners

    runners = _report_runners(noise_rows=True)
    assert set(runners) == {"ekf", "online", "batch"} | {f"{m}_noise_x{k:g}" for m in ("ekf", "online", "batch") for k in (0.5, 2.0)}
    from fusegraph.evaluation.gaze import noise_scaled

    scaled, model, ekf = noise_scaled(session, 2.0)
    base_model, base_ekf = gaze.GazeModel(), gaze.GazeEkfConfig()
    assert scaled.config.camera.pixel_sigma == 2.0 * session.config.camera.pixel_sigma
    assert model.head.imu.gyro_noise_rad_s_sqrt_hz == 2.0 * base_model.head.imu.gyro_noise_rad_s_sqrt_hz
    assert model.head.mag.heading_sigma_deg == 2.0 * base_model.head.mag.heading_sigma_deg
    assert ekf.head.gyro_sigma_rad_s == 2.0 * base_ekf.head.gyro_sigma_rad_s and ekf.pixel_sigma == 2.0 * base_ekf.pixel_sigma


def test_live_gaze_solver_publishes_what_the_replay_estimates() -> None:
    # the live loop's solver fed sample by sample (each gaze sample once its time has come, the IMU as it arrives)
    # must give every gaze sample the replay's point and attitude: the same graph, updated at the same samples
    from fusegraph.live import GAZE_CHANNELS, SOLVERS
    from fusegraph.scenarios.gaze import gaze_session

    recorded = gaze_session(3, duration_s=8.0)
    data = gaze.from_session(recorded)
    replay = gaze.run_online(data)
    solver = SOLVERS["gaze"](recorded)
    imu = np.hstack([data.gyro_rad_s, data.accel_m_s2, data.mag])
    published: dict[float, list[float]] = {}
    j = 0
    for i, t in enumerate(data.t):
        while j < len(data.tracker_t) and data.tracker_t[j] <= t:
            assert solver.push("gaze", float(data.tracker_t[j]), data.gaze_px[j]) == []
            j += 1
        published.update(solver.push("imu", float(t), imu[i]))
        solver.maintain()
    have = np.all(np.isfinite(replay.points_xz_m), axis=1) & (data.tracker_t <= data.t[-1] - 0.2)
    # the replay also pushes the last, partial block and the gaze after the last keyframe when the session ends; live waits for them
    assert len(published) >= have.sum() - 10 and len(published[next(iter(published))]) == len(GAZE_CHANNELS)
    index = {float(t): n for n, t in enumerate(data.tracker_t)}
    rows = np.array(list(published.values()))
    at = np.array([index[t] for t in published])
    np.testing.assert_allclose(rows[:, 1:3], replay.points_xz_m[at], atol=1e-9)  # world y, z = the wall's X, Z
    np.testing.assert_allclose(rows[:, 3:], replay.world_R_head[at], atol=1e-9)


def test_live_gaze_sample_after_its_keyframe_left_the_window_is_counted_not_fatal() -> None:
    # a gaze stream that stalls for 2 s and then delivers its backlog: samples whose keyframe the online solver has
    # marginalised (its window is 1 s) cannot get a factor; they are counted and the solver carries on
    from fusegraph.live import SOLVERS
    from fusegraph.scenarios.gaze import gaze_session

    recorded = gaze_session(3, duration_s=8.0)
    data = gaze.from_session(recorded)
    solver = SOLVERS["gaze"](recorded)
    imu = np.hstack([data.gyro_rad_s, data.accel_m_s2, data.mag])
    stalled = (data.tracker_t >= 3.0) & (data.tracker_t < 4.0)
    published = 0
    j = 0
    for i, t in enumerate(data.t):
        while j < len(data.tracker_t) and data.tracker_t[j] <= (t - 2.0 if stalled[j] else t):
            solver.push("gaze", float(data.tracker_t[j]), data.gaze_px[j])
            j += 1
        published += len(solver.push("imu", float(t), imu[i]))
        solver.maintain()
    assert solver.graph.too_late > 0.5 * stalled.sum()
    assert published >= len(data.tracker_t) - stalled.sum() - 15 and published + solver.graph.too_late <= len(data.tracker_t)


def test_a_sample_that_looks_away_from_its_keyframes_point_takes_its_own_rays_point() -> None:
    """``factors.gaze.sample_points``: a sample whose ray sees its keyframe's fixation point within the gate keeps that
    point; one that looks elsewhere (after a saccade inside the keyframe) takes where its own ray meets the wall; a
    sample without an attitude keeps the keyframe's point."""
    from fusegraph.factors.gaze import sample_points

    camera = SceneCamera(focal_px=880.0, pixel_sigma=5.0)
    point = np.array([1.0, 0.0, 0.0])  # the keyframe's point on the wall x = 1 m, straight ahead
    looked = np.array([[1.0, 0.0, 0.0], [1.0, 0.004, 0.0], [1.0, 0.2, -0.1], [1.0, 0.2, -0.1]])  # on it, 0.26 deg off, a saccade away
    rays = looked / np.linalg.norm(looked, axis=1, keepdims=True)
    attitude = np.tile([1.0, 0.0, 0.0, 0.0], (4, 1))
    attitude[3] = np.nan
    out = sample_points(np.tile(point, (4, 1)), attitude, rays, camera, True, 3.0)
    # 3 sigmas of 5 px at 880 px is 0.98 deg: the 0.26 deg sample is noise, the 12.6 deg one a saccade
    np.testing.assert_allclose(out[:2], np.tile(point, (2, 1)))
    np.testing.assert_allclose(out[2], [1.0, 0.2, -0.1], atol=1e-12)  # on the wall, where it looked
    np.testing.assert_allclose(out[3], point)
    depth = sample_points(np.tile(point, (4, 1)), attitude, rays, camera, False, 3.0)  # no wall: the plane facing the eye
    np.testing.assert_allclose(depth[2], [1.0, 0.2, -0.1], atol=1e-12)


def test_scene_viewing_gaze_points_follow_each_saccade() -> None:
    """On the scene-viewing scenario (a new mark every 0.33 s) the online gaze point follows the saccades; each sample
    given its keyframe's fixation point instead (the gate at 1e6 sigmas) is off by the saccades inside a keyframe."""
    from dataclasses import replace

    from fusegraph.scenarios.gaze import viewing_config

    session = simulate_gaze(0, replace(viewing_config(), duration_s=10.0, switch_s=6.0))
    assert len(np.unique(session.truth_gaze_xz_m.round(2), axis=0)) > 20  # a mark per 0.33 s (jitter rounded away)
    model = gaze.GazeModel()
    kept = replace(model, fixation=replace(model.fixation, sample_gate_sigmas=1e6))
    own, old = (gaze_rms_mm(gaze.run_online(session, m).points_xz_m, session) for m in (model, kept))
    # measured 10.4 / 6.6 mm over seeds 0-9 of the 40 s scenario (report gaze --viewing; 120 / 121 with every sample its keyframe point)
    assert max(own.values()) < 40 and min(old.values()) > 2.5 * max(own.values()), (own, old)


def test_batch_heading_is_levelled_from_the_inertial_start_not_dead_reckoning() -> None:
    """The batch's first heading pass levels the field with its initial attitudes. Dead-reckoned from a zero gyro bias
    they tilt more the longer the session runs, a tilt error becomes heading error through the dip, and on scene-viewing
    seed 101 the Cauchy pass that follows could not leave it (Levenberg-Marquardt took no step): the gaze's X drifted to
    -126 mm at 40 s (85 mm RMS). Started from the inertial filter, as the 9-axis batch is, it lands at the online's."""
    from fusegraph.scenarios.gaze import viewing_config

    session = simulate_gaze(101, viewing_config())
    rms = gaze_rms_mm(gaze.run_batch(session).points_xz_m, session)
    # measured 8.8 / 6.8 mm (85 / 7.6 before); seeds 100-109 of the scenario 9.5-11.2 mm hypot
    assert rms["x_mm"] < 20 and rms["z_mm"] < 20, rms


def test_a_translating_head_keeps_its_tilt_when_the_accelerometer_beyond_gravity_is_unmodelled_acceleration() -> None:
    """The gaze head holds the eye within 5 cm and 0.3 m/s of rest; a head moved by a metre (|a| - g of 26 m/s^2 RMS, a
    trampoline's order) makes those priors wrong. Read as unmodelled acceleration (``unmodelled_acceleration``, the gaze
    head's default) the accelerometer's excess no longer tilts the head: batch inclination 0.15 deg, online total 5.7
    (measured), against 2.4 and 20.6 with the IMU factor taking the readings as exact. Bounds halfway in log between the
    two (seed 1, one 30 s simulation)."""
    from dataclasses import replace

    from fusegraph.metrics import broad_errors
    from fusegraph.scenarios.attitude9 import simulate_attitude9
    from fusegraph.systems import attitude9

    session = simulate_attitude9(1, duration_s=30.0, translation_m=1.0, disturbance_uT=0.0)
    head = gaze.GazeModel().head
    assert head.unmodelled_acceleration
    scored = np.ones(len(session.truth.t))  # type: ignore[union-attr]
    errors = {flag: (broad_errors(attitude9.run_online(session, replace(head, unmodelled_acceleration=flag)).quat_wxyz, session.truth.values, scored),  # type: ignore[union-attr]
                     broad_errors(attitude9.run_batch(session, replace(head, unmodelled_acceleration=flag)).quat_wxyz, session.truth.values, scored))  # type: ignore[union-attr]
              for flag in (True, False)}
    (online_on, batch_on), (online_off, batch_off) = errors[True], errors[False]
    assert batch_on.inclination < 0.6 < batch_off.inclination
    assert online_on.total < 11.0 < online_off.total


def test_the_unmodelled_acceleration_density_follows_the_readings_departure_from_gravity() -> None:
    """sqrt(d^2 + e^2 T): the declared density where the readings' norm is g, and e T of velocity over T where it departs."""
    from dataclasses import replace

    from fusegraph.graphs.attitude9 import Attitude9Builder

    head = gaze.GazeModel().head
    builder = Attitude9Builder(head)
    level = np.tile([0.0, 0.0, head.imu.gravity_m_s2], (40, 1))
    assert builder._unmodelled_density(level, 0.2) == pytest.approx(head.imu.accel_noise_m_s2_sqrt_hz)
    pushed = level + [3.0, 0.0, 4.0]  # |f| = g + e with e = hypot(3, 9.81 + 4) - 9.81
    excess = float(np.hypot(3.0, head.imu.gravity_m_s2 + 4.0) - head.imu.gravity_m_s2)
    assert builder._unmodelled_density(pushed, 0.2) == pytest.approx(np.hypot(head.imu.accel_noise_m_s2_sqrt_hz, excess * np.sqrt(0.2)))
    assert Attitude9Builder(replace(head, unmodelled_acceleration=False))._unmodelled_density(pushed, 0.2) is None


def test_a_session_declares_how_its_head_moves_and_a_free_head_takes_the_nine_axis_model() -> None:
    from dataclasses import replace

    from fusegraph.api import simulate
    from fusegraph.session import SessionError
    from fusegraph.systems import attitude9

    session = simulate("gaze", seed=0, duration_s=5.0)
    header = session.meta.get("session", {})
    seated = gaze.model_for(session, "batch")
    assert seated.head.motion == gaze.GazeModel().head.motion and seated.head.unmodelled_acceleration
    assert seated.fixation == gaze.batch_model().fixation  # the solver's own fixation setting either way
    free = replace(session, meta={**session.meta, "session": {**header, "head_motion": "free", "use_mag": False}})
    model = gaze.model_for(free, "batch")
    nine = attitude9.model_for(free)  # what the 9-axis system's online runs this IMU with
    assert (model.head.motion, model.head.mag, model.head.imu) == (nine.motion, nine.mag, nine.imu)
    assert model.head.motion != seated.head.motion and not model.head.use_mag and model.fixation == seated.fixation
    wrong = replace(session, meta={**session.meta, "session": {**header, "head_motion": "walking"}})
    with pytest.raises(SessionError, match="head_motion = 'walking': one of seated, free"):
        gaze.model_for(wrong, "online")
