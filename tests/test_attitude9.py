"""9-axis attitude: accelerometer and magnetometer factors, the graph, the scenario, BROAD (skips without data)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from conftest import assert_jacobians_match, cut_streams, random_rot3, requires_shared_data, solve_saying

from fusegraph.factors.accel import GravityNoise, gravity_factor
from fusegraph.factors.mag import FieldReference, MagNoise, field_norm_dip, fit_mag_calibration, heading_factor, heading_sigma_rad
from fusegraph.geometry import quat_conjugate, quat_multiply
from fusegraph.graphs.attitude9 import Attitude9Builder, Attitude9Model, fill_samples, initial_attitude
from fusegraph.metrics import broad_errors
from fusegraph.scenarios.attitude9 import simulate_attitude9
from fusegraph.systems import attitude9

FIELD = 50.0 * np.array([0.0, np.cos(np.deg2rad(65)), -np.sin(np.deg2rad(65))])  # uT, ENU, 65 deg dip


def _pose_values(rot: gtsam.Rot3) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(0, gtsam.Pose3(rot, np.array([0.3, -0.2, 1.0])))
    return values


def test_heading_and_gravity_factor_jacobians_match_numerical() -> None:
    rng = np.random.default_rng(3)
    for _ in range(5):
        rot = random_rot3(rng, 1.0)
        mag = rot.unrotate(FIELD) + rng.normal(0, 2.0, 3)
        level = rot.compose(gtsam.Rot3.Expmap(rng.normal(0, 0.05, 3)))  # levelled with a slightly different attitude
        assert_jacobians_match(heading_factor(0, level, mag, 0.1), _pose_values(rot))
        accel = rot.unrotate(np.array([0.0, 0.0, 9.81])) + rng.normal(0, 0.5, 3)
        assert_jacobians_match(gravity_factor(0, accel, GravityNoise(cauchy_k=0.0)), _pose_values(rot))


def test_heading_factor_carries_no_tilt_information() -> None:
    rng = np.random.default_rng(4)
    rot = random_rot3(rng, 0.6)
    factor = heading_factor(0, rot, rot.unrotate(FIELD), 0.05)
    base = factor.whitenedError(_pose_values(rot))
    east_tilt = gtsam.Rot3.Rx(np.deg2rad(5.0)).compose(rot)  # world-frame tilt about east
    north_tilt = gtsam.Rot3.Ry(np.deg2rad(5.0)).compose(rot)  # ... about north
    yaw = gtsam.Rot3.Rz(np.deg2rad(5.0)).compose(rot)
    np.testing.assert_allclose(factor.whitenedError(_pose_values(east_tilt)), base, atol=1e-9)  # exactly blind
    # about north: the horizontal direction turns by 1 - cos(5 deg) at most, 0.4 % of a 5 deg yaw
    assert np.abs(factor.whitenedError(_pose_values(north_tilt)) - base).max() < 0.004 * np.deg2rad(5.0) / 0.05
    assert np.abs(factor.whitenedError(_pose_values(yaw)) - base).max() == pytest.approx(np.sin(np.deg2rad(5.0)) / 0.05, rel=1e-6)
    jacobian = factor.linearize(_pose_values(rot)).jacobian()[0]
    assert np.allclose(jacobian[:, 3:], 0.0)  # nor on the position


def test_disturbed_field_inflates_the_heading_sigma() -> None:
    noise, reference = MagNoise(), FieldReference(50.0, np.deg2rad(65))
    calm = heading_sigma_rad(noise, reference, 50.0, np.deg2rad(65))
    assert calm == pytest.approx(np.deg2rad(noise.heading_sigma_deg))
    assert heading_sigma_rad(noise, reference, 60.0, np.deg2rad(65)) == pytest.approx(calm * (1 + noise.norm_gain * 0.2))
    assert heading_sigma_rad(noise, reference, 50.0, np.deg2rad(75)) > 3 * calm
    norm, dip = field_norm_dip(gtsam.Rot3(), FIELD)
    assert norm == pytest.approx(50.0) and np.rad2deg(dip) == pytest.approx(65.0)


def test_calibration_fit_recovers_gain_and_offset() -> None:
    rng = np.random.default_rng(5)
    directions = rng.normal(size=(500, 3))
    true_field = 48.0 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    gain, offset = np.array([1.1, 0.92, 1.03]), np.array([12.0, -7.0, 3.0])
    raw = (true_field - offset) / gain + rng.normal(0, 0.1, true_field.shape)
    cal = fit_mag_calibration(raw)
    scale = np.prod(gain) ** (1 / 3)  # the fit normalises the gains (heading needs the shape only)
    np.testing.assert_allclose(np.array(cal.gain) * scale, gain, rtol=5e-3)
    np.testing.assert_allclose(np.array(cal.offset) * scale, offset, atol=0.1)  # uT, ~noise level
    with pytest.raises(ValueError, match="at least 9 readings"):
        fit_mag_calibration(raw[:5])


def test_initial_attitude_is_triad_in_enu() -> None:
    rot = random_rot3(np.random.default_rng(6), 1.0)
    found = initial_attitude(rot.unrotate(np.array([0, 0, 9.81])), rot.unrotate(FIELD))
    assert found.between(rot).axisAngle()[1] == pytest.approx(0.0, abs=1e-9)


def test_fill_samples_is_exact_for_constant_rates() -> None:
    t = np.arange(0.0, 1.0, 0.01)
    rate = np.array([0.3, -0.2, 0.5])
    gyro = np.tile(rate, (len(t), 1))
    from fusegraph.geometry import quat_from_rotvec

    truth = quat_from_rotvec(np.outer(t, rate))
    kf = np.arange(0, len(t), 20)
    for blend in (False, True):
        out = fill_samples(t, gyro, kf, truth[kf], np.zeros((len(kf), 3)), blend)
        np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", out, truth)), 1.0, atol=1e-12)


def test_builder_names_the_sample_whose_time_goes_back() -> None:
    builder = Attitude9Builder()
    builder.add_samples(np.array([0.0, 0.01]), np.zeros((2, 3)), np.tile([0, 0, 9.81], (2, 1)), np.tile(FIELD, (2, 1)))
    with pytest.raises(ValueError, match="sample 2: time 0.005000 s does not increase"):
        builder.add_samples(np.array([0.005]), np.zeros((1, 3)), np.array([[0, 0, 9.81]]), FIELD[None])


@pytest.mark.parametrize("interval_mean", [False, True])
def test_the_graph_does_not_depend_on_how_samples_are_blocked(interval_mean: bool) -> None:
    """A recording pushed at once or in blocks of 7 (keyframes closing inside blocks, rests carried across them)
    gives the same keyframes, factors, initial values and heading readings (each keyframe's own, or its interval's mean
    gathered across blocks): the block handling is vectorised, not the model."""
    session = simulate_attitude9(4, duration_s=6.0)
    data = attitude9.imu9(session)
    assert data.mag is not None
    model = Attitude9Model(mag=MagNoise(interval_mean=interval_mean))
    builders = [Attitude9Builder(model, deferred_mag=True), Attitude9Builder(model, deferred_mag=True)]
    builders[0].add_samples(data.t, data.gyro, data.accel, data.mag)
    for i in range(0, len(data.t), 7):
        builders[1].add_samples(data.t[i : i + 7], data.gyro[i : i + 7], data.accel[i : i + 7], data.mag[i : i + 7])
    whole, blocked = (b.take() for b in builders)
    assert builders[0].keyframe_index == builders[1].keyframe_index and len(builders[0].keyframe_index) > 20
    assert len(whole.factors) == len(blocked.factors)
    assert [type(f) for _, f in whole.factors] == [type(f) for _, f in blocked.factors]
    assert whole.graph().error(whole.values) == pytest.approx(blocked.graph().error(whole.values), rel=1e-12)
    assert whole.values.equals(blocked.values, 1e-12)
    readings = [np.array([m for _, m in b.mag_readings]) for b in builders]
    assert readings[0].shape == (len(builders[0].keyframe_index), 3) and np.allclose(readings[0], readings[1], rtol=0.0, atol=1e-12)
    own = data.mag[builders[0].keyframe_index]  # the keyframes' own readings
    assert np.array_equal(readings[0], own) != interval_mean


def test_the_interval_mean_carries_each_reading_to_the_keyframe_with_the_gyro() -> None:
    """Noise-free readings of a body turning at varying rates (gtsam's Rot3 products, a gyro biased by a known bias) all
    carry to the keyframe's own reading: their mean is it to rounding (1e-12 of a unit field)."""
    from fusegraph.factors.mag import interval_mean_reading

    rng = np.random.default_rng(5)
    bias = np.array([0.02, -0.01, 0.03])
    rates = rng.normal(0.0, 2.0, (40, 3))  # rad/s: up to ~0.1 rad per 5 ms sample, ~1 rad over the interval
    dt = rng.uniform(0.004, 0.006, 40)
    world_R_body = [random_rot3(rng)]
    for rate, step in zip(rates[1:], dt[1:], strict=True):  # sample j's rate turns the body from sample j-1 to j
        world_R_body.append(world_R_body[-1].compose(gtsam.Rot3.Expmap(rate * step)))
    field_world = np.array([0.0, 0.45, -0.89])
    readings = np.array([r.unrotate(field_world) for r in world_R_body])
    mean = interval_mean_reading(readings, rates + bias, dt, bias)
    assert np.allclose(mean, readings[-1], rtol=0.0, atol=1e-12)
    assert not np.allclose(interval_mean_reading(readings, rates, dt, bias), readings[-1], atol=1e-3)  # the bias matters


def test_a_long_push_finds_each_closing_sample_as_the_look_ahead_does() -> None:
    """``_first_due`` by binary search over t + dt/2 (a long push) answers as the chunked look-ahead, also where
    the sample times jitter (a real logger's) and a keyframe's time falls exactly on the rule's boundary."""
    from fusegraph.graphs.attitude9 import _first_due

    rng = np.random.default_rng(7)
    for jitter in (0.0, 0.2):
        dt = (1.0 / 286.5) * (1.0 + jitter * rng.uniform(-1.0, 1.0, 5000))
        t = np.cumsum(dt)
        due_s = t + 0.5 * dt
        assert (np.diff(due_s) > 0).all()
        starts = rng.integers(0, 4900, 300)
        for start in starts:
            keyframe_s = float(t[start - 1]) if start > 0 else float(t[0])
            for period in (0.2, 0.05, float(t[min(start + 40, 4999)] - keyframe_s)):  # the last: on the boundary
                assert _first_due(t, dt, int(start), keyframe_s, period, due_s) == _first_due(t, dt, int(start), keyframe_s, period)


def test_a_late_tracker_meets_the_same_gyro_in_blocks_or_sample_by_sample() -> None:
    """Online, a late tracker sample is carried to its keyframe by the gyro samples kept for it (the last
    ``RECENT_GYRO_S``, joined from the pushed blocks every ``_JOIN_BLOCKS`` or when a tracker sample comes): blocks of 7
    and a sample at a time (a live feed) over 24 s make the same factors and values, and every reading is carried as
    the batch builder, which keeps every sample, carries it."""
    session = simulate_attitude9(3, duration_s=24.0, sensors=("gyro", "accel", "mag", "tracker"))
    data, track = attitude9.imu9(session), attitude9.attitude_tracker(session)
    assert data.mag is not None and track is not None
    built = []
    for size in (7, 1):
        builder = Attitude9Builder()
        for i in range(0, len(data.t), size):
            j = min(i + size, len(data.t))
            builder.add_samples(data.t[i:j], data.gyro[i:j], data.accel[i:j], data.mag[i:j])
            builder.feed_tracker(track, float(data.t[j - 1]))
        built.append((builder, builder.take()))
    (blocks, by_blocks), (single, by_sample) = built
    assert blocks.tracker_factors == single.tracker_factors > 0.9 * len(track.t) and blocks.tracker_dropped == single.tracker_dropped
    assert by_blocks.values.equals(by_sample.values, 1e-12)
    assert by_blocks.graph().error(by_blocks.values) == pytest.approx(by_sample.graph().error(by_blocks.values), rel=1e-12)
    batch = Attitude9Builder(deferred_mag=True)
    batch.add_samples(data.t, data.gyro, data.accel, data.mag)
    batch.feed_tracker(track)
    # online, the readings taken in the last latency (100 ms) have not arrived when the data ends: the newest keyframe
    # holds another reading (each keyframe keeps its latest) or none
    compared = [k for k in single.tracker_readings if k < max(single.tracker_readings)]
    assert len(compared) >= len(batch.tracker_readings) - 2
    assert all(batch.tracker_readings[k].equals(single.tracker_readings[k], 1e-12) for k in compared)


def test_the_replay_pushed_whole_equals_a_feed_sample_by_sample() -> None:
    """``run_online`` pushes the whole session once and updates iSAM2 as each keyframe closes (``on_keyframe``); a live
    feed pushes a sample at a time, feeds the tracker samples that have arrived and updates when a keyframe has closed.
    Same updates on the same factors, so the same causal estimate (1e-9 rad: only the floating-point order differs),
    and the late tracker's gyro samples, kept from a push that reaches far past the newest keyframe, are the same."""
    from fusegraph.solvers.online import OnlineSmoother

    session = simulate_attitude9(3, duration_s=12.0, sensors=("gyro", "accel", "mag", "tracker"))
    replay = attitude9.run_online(session)
    data, track = attitude9.imu9(session), attitude9.attitude_tracker(session)
    assert data.mag is not None and track is not None
    builder = Attitude9Builder(attitude9.model_for(session))
    solver = OnlineSmoother(builder, attitude9.ONLINE_CONFIG)
    for i in range(len(data.t)):
        keyframes = len(builder.keyframe_t)
        builder.add_samples(data.t[i : i + 1], data.gyro[i : i + 1], data.accel[i : i + 1], data.mag[i : i + 1])
        if len(builder.keyframe_t) > keyframes:
            builder.feed_tracker(track, float(data.t[i]))
            solver.update()
    builder.feed_tracker(track, float(data.t[-1]))
    solver.update()
    fed = fill_samples(data.t, data.gyro, np.array(builder.keyframe_index), np.array(builder.posterior_quat), np.array(builder.posterior_gyro_bias), False)
    assert replay.extras["tracker_factors"] == builder.tracker_factors > 0
    assert np.max(np.abs(np.abs(np.sum(replay.quat_wxyz * fed, axis=1)) - 1.0)) < 1e-9


def test_the_recording_declares_its_motion_and_the_default_is_chosen_on_broad() -> None:
    from dataclasses import replace

    from fusegraph.tuned import tuned

    session = simulate_attitude9(4, duration_s=2.0)
    assert attitude9.model_for(session).motion.velocity_sigma_m_s == tuned("broad_motion")["velocity_sigma_m_s"]
    assert attitude9.model_for(session, solver="batch").motion.velocity_sigma_m_s == tuned("broad_motion_batch")["velocity_sigma_m_s"]
    assert attitude9.model_for(session).imu.accel_bias_walk_m_s2_sqrt_s == tuned("broad_bias")["accel_bias_walk_m_s2_sqrt_s"]
    assert attitude9.model_for(session, solver="batch").imu.gyro_bias_walk_rad_s_sqrt_s == tuned("broad_bias_batch")["gyro_bias_walk_rad_s_sqrt_s"]
    accel = session.stream("accel")
    declared = {**accel.meta, "velocity_sigma_m_s": 2.0, "noise_m_s2_sqrt_hz": 0.02, "sigma_deg": 3.0, "bias_rw_m_s2_sqrt_s": 3e-3}
    gyro = session.stream("gyro")
    walking = replace(session, streams={**session.streams, "accel": replace(accel, meta=declared),
                                        "gyro": replace(gyro, meta={**gyro.meta, "bias_rw_sigma": 2e-4, "rest_rate_sigma_rad_s": 0.02})})
    model = attitude9.model_for(walking)
    assert model.motion.velocity_sigma_m_s == 2.0 and model.gravity is not None and model.gravity.sigma_deg == 3.0
    assert model.imu.accel_noise_m_s2_sqrt_hz == 0.02
    assert model.imu.accel_bias_walk_m_s2_sqrt_s == 3e-3 and model.imu.gyro_bias_walk_rad_s_sqrt_s == 2e-4
    assert model.motion.rest_rate_sigma_rad_s == 0.02 and model.motion.velocity_sigma_m_s == 2.0  # a worn sensor's swaying rests
    assert attitude9.model_for(session).motion.rest_rate_sigma_rad_s == tuned("broad_rest")["rest_rate_sigma_rad_s"]
    walking.validate()  # the key is in the gyro's catalogue entry
    # an explicit model is taken as given
    assert attitude9.model_for(walking, attitude9.broad_model()).motion.velocity_sigma_m_s == tuned("broad_motion")["velocity_sigma_m_s"]


def _score(estimate, session, mask=None):  # type: ignore[no-untyped-def]
    mask = np.ones(len(session.truth.t)) if mask is None else mask
    return broad_errors(estimate.quat_wxyz, session.truth.values, mask)


def test_noise_free_scenario_recovers_the_truth() -> None:
    session = simulate_attitude9(1, profile="noise_free", disturbance_uT=0.0, duration_s=30.0)
    online, batch = attitude9.run_online(session), attitude9.run_batch(session)
    # what is left without noise: the gyro bias and calibration are learnt from the data (the first
    # seconds of online), truth accelerations are finite differences, and the motion priors are priors
    assert _score(batch, session).total < 0.5  # deg
    assert _score(online, session).total < 1.5  # deg, causal
    assert _score(online, session).inclination < 0.5 and _score(batch, session).inclination < 0.3


def test_magnetic_disturbance_does_not_tilt_the_estimate() -> None:
    session = simulate_attitude9(2, duration_s=60.0, disturbance_uT=40.0)
    start, stop = session.meta["truth_extra"]["disturbance_s"]
    inside = ((session.truth.t > start) & (session.truth.t < stop)).astype(float)
    for estimate in (attitude9.run_online(session), attitude9.run_batch(session)):
        errors = _score(estimate, session, inside)
        # 40 uT of steel turns the field by ~40 deg; gating + Cauchy keep the heading within a few
        # degrees, and the heading-only factor keeps the inclination at its undisturbed level
        assert errors.inclination < 0.6, estimate.method
        assert errors.heading < 4.0, estimate.method


def test_online_estimate_is_causal() -> None:
    session = simulate_attitude9(3, duration_s=20.0)
    full = attitude9.run_online(session)
    cut = 1234
    from dataclasses import replace

    streams = {name: s if name == "mag_cal" else replace(s, t=s.t[:cut], values=s.values[:cut]) for name, s in session.streams.items()}
    truncated = replace(session, streams=streams)
    early = attitude9.run_online(truncated)
    np.testing.assert_allclose(early.quat_wxyz, full.quat_wxyz[:cut], atol=1e-9)  # the future changes nothing


def test_an_online_solver_updating_every_few_keyframes_carries_each_sample_from_the_last_solved_one() -> None:
    """``[online] update_every = 3``: iSAM2 solves the first keyframe and then every third, and the keyframes between
    have no posterior of their own (the causal fill once indexed past the end of the solved ones and raised, and the
    first keyframes waited for the first due update without an estimate). Every sample has an attitude, carried on by the
    gyro from the last solved keyframe: causal (a recording cut short gives the same samples), and near the estimate that
    updates at every keyframe (within 3x its total error: fewer updates, each a later look at the same data; measured
    1.15x). The session's declaration is the config's; a value that is not a whole number of keyframes is an error
    naming the key."""
    from dataclasses import replace

    from fusegraph.systems.attitude9 import ONLINE_CONFIG

    session = simulate_attitude9(3, duration_s=20.0)
    sparse = attitude9.run_online(session.with_meta(online={"update_every": 3}))
    np.testing.assert_array_equal(sparse.quat_wxyz, attitude9.run_online(session, config=replace(ONLINE_CONFIG, update_every=3)).quat_wxyz)
    assert np.isfinite(sparse.quat_wxyz).all()
    assert _score(sparse, session).total < 3.0 * _score(attitude9.run_online(session), session).total
    cut = 1234
    streams = {name: s if name == "mag_cal" else replace(s, t=s.t[:cut], values=s.values[:cut]) for name, s in session.streams.items()}
    early = attitude9.run_online(replace(session, streams=streams).with_meta(online={"update_every": 3}))
    np.testing.assert_allclose(early.quat_wxyz, sparse.quat_wxyz[:cut], atol=1e-9)
    for wrong in (-1, 1.5, "2", True):
        with pytest.raises(ValueError, match=r"\[online\] update_every"):
            attitude9.run_online(session.with_meta(online={"update_every": wrong}))


def test_the_online_solver_eliminates_in_time_order_with_the_accuracy_of_its_default_order() -> None:
    """The builder tells the online solver each variable's keyframe (a per-keyframe point another sensor adds too; the
    tracker's frame and the calibration span many), so iSAM2 eliminates in time order (an update re-eliminates only the
    keyframes its factors reach: BROAD's online about 5 % faster, interleaved best-of-5 runs) and, where the tree stays in that
    order, folds old keyframes into its own linear factors instead of re-linearising a new solver. On this simulated
    60 s the estimate moves 0.001 deg RMS, 0.007 at most (measured) against gtsam's default order; the bounds are 10x."""
    builder = Attitude9Builder(prefix="t")
    assert builder.keyframe_of(builder.X(7)) == 7 and builder.keyframe_of(builder.B(0)) == 0 and builder.keyframe_of(builder.V(12)) == 12
    point = int(gtsam.symbol("g", 3))
    assert builder.keyframe_of(builder.calibration_key) is None and builder.keyframe_of(point) is None
    builder.add_variable(point, np.zeros(3), per_keyframe=True)
    assert builder.keyframe_of(int(gtsam.symbol("g", 5))) == 5

    from dataclasses import replace

    session = simulate_attitude9(3, duration_s=60.0)
    ordered = attitude9.run_online(session)
    default = attitude9.run_online(session, config=replace(attitude9.ONLINE_CONFIG, time_ordered=False))
    assert ordered.extras["in_place"] >= 1 and default.extras["in_place"] == 0 and default.extras["reanchors"] >= 25
    turn = quat_multiply(quat_conjugate(ordered.quat_wxyz), default.quat_wxyz)
    angle_deg = np.degrees(2 * np.arccos(np.clip(np.abs(turn[:, 0]), 0, 1)))
    assert np.sqrt(np.mean(angle_deg**2)) < 0.01 and angle_deg.max() < 0.07


@requires_shared_data("broad")
def test_bench_on_the_attached_magnet_trial(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """The bench is a report over the imported trial: `import broad` + `report attitude9 DIR --json` prints its figures
    to the last digit."""
    pytest.importorskip("vqf")
    import json

    from fusegraph.cli import main
    from fusegraph.datasets.broad import DEFAULT_DIR
    from fusegraph.evaluation.broad import bench_broad

    result = bench_broad(trials=("32",), methods=("vqf", "online"), show_progress=False)
    (stem,) = result["trials"]
    assert stem.startswith("32_")
    row = result["trials"][stem]
    assert set(row) == {"vqf", "online"} and set(row["online"]) == {"total", "heading", "inclination", "x_realtime"}
    assert result["mean"]["vqf"]["total"] == pytest.approx(7.67, abs=0.05)  # ../shared/data/README.md's VQF figure
    # the magnet rides on the sensor: VQF's heading follows it; the heading-only factor with
    # norm/dip gating and the Cauchy kernel does not (measured 2.4 deg)
    assert row["online"]["total"] < 0.5 * row["vqf"]["total"]
    ratio = result["ratios"]["online/vqf"]  # one trial: it is the worst, and its ratio the means'
    assert set(result["ratios"]) == {"online/vqf"} and ratio["worst_trial"] == stem
    assert ratio["worst_trial_ratio"] == pytest.approx(row["online"]["total"] / row["vqf"]["total"]) == pytest.approx(ratio["total"])
    (trial,) = DEFAULT_DIR.glob("32_*.mat")
    assert main(["import", "broad", str(trial), "--out", str(tmp_path / stem)]) == 0
    capsys.readouterr()
    assert main(["report", "attitude9", str(tmp_path / stem), "--solvers", "vqf,online", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert "tuned.toml [broad_mag]" in report["in_sample"][stem]  # a shared trial: the settings on main were chosen on it
    for method in ("vqf", "online"):
        assert report["methods"][method]["metrics"] == result["methods"][method]["metrics"]
        assert report["sessions"][stem][method]["metrics"] == result["sessions"][stem][method]["metrics"]
        assert report["sessions"][stem][method]["metrics"]["total_deg"] == row[method]["total"]


def test_late_attitude_tracker_in_its_own_frame_joins_the_graph() -> None:
    """Noise-free, no translation: online and batch with a tracker in a rotated room frame, 100 ms late,
    recover the truth to the limits of the noise-free test above (calibration fitted from data)."""
    session = simulate_attitude9(3, duration_s=12.0, sensors=("gyro", "accel", "mag", "tracker"), profile="noise_free", translation_m=0.0)
    assert session.stream("tracker").latency_s == pytest.approx(0.1)
    for run in (attitude9.run_online, attitude9.run_batch):
        estimate = run(session)
        assert estimate.extras["tracker_factors"] > 0.9 * len(session.stream("tracker").t)
        errors = broad_errors(estimate.quat_wxyz, session.truth.values, np.ones(len(estimate.t)))  # type: ignore[union-attr]
        # what remains is the fitted magnetometer calibration's heading bias, shared by every keyframe through
        # the one tracker alignment (measured 0.49-0.52 deg heading for the batch, seed 3); inclination as above
        assert errors.total < 0.6 and errors.inclination < 0.3, (estimate.method, errors)


def test_tracker_holds_heading_through_a_magnetic_disturbance() -> None:
    """A strong disturbance over half the session: with the tracker, heading stays within 1 deg online on every seed and
    is better on average than the magnetometer-only online estimate, which the disturbance pulls further. (Seeds 5-8:
    with the zero-rate update at rest the magnetometer-only estimate on seed 5 alone came out as good, 0.61 against 0.63
    deg; over the four, 0.52 against 0.36.)"""
    kwargs = {"duration_s": 30.0, "disturbance_uT": 60.0, "disturbance_window": (0.3, 0.8)}
    headings = []
    for seed in (5, 6, 7, 8):
        with_tracker = simulate_attitude9(seed, sensors=("gyro", "accel", "mag", "tracker"), **kwargs)  # type: ignore[arg-type]
        without = with_tracker.without("tracker")
        headings.append([broad_errors(attitude9.run_online(s).quat_wxyz, s.truth.values, np.ones(len(s.truth.t))).heading  # type: ignore[union-attr]
                         for s in (with_tracker, without)])
    tracked, alone = np.array(headings).T
    assert np.all(tracked < 1.0) and tracked.mean() < alone.mean(), headings


def test_batch_initial_attitudes_hold_while_the_hand_accelerates() -> None:
    """``inertial_initial`` low-passes the specific force in the gyro's frame: with accelerations that turn single
    accelerometer readings 25 deg from vertical (95th percentile), every keyframe after the first 10 s starts within
    4 deg of the truth (measured 2.6 at most; what is left is the unestimated gyro bias, up to 0.01 rad/s here, between
    heading corrections and the 3 s low-pass's lag)."""
    session = simulate_attitude9(2, duration_s=40.0, profile="noise_free", disturbance_uT=0.0)
    data = attitude9.imu9(session)
    builder, increment = attitude9._build_batch(session, data, attitude9.model_for(session, None, "batch"))
    values = builder.inertial_initial(gtsam.Values(increment.values))
    index = np.array(builder.keyframe_index)
    truth = [gtsam.Rot3.Quaternion(*q) for q in session.truth.values[index]]  # type: ignore[union-attr]
    error_deg = np.array([np.degrees(np.linalg.norm(gtsam.Rot3.Logmap(truth[k].between(values.atPose3(builder.X(k)).rotation()))))
                          for k in range(len(index))])
    up_body = np.array([r.unrotate(np.array([0.0, 0.0, 1.0])) for r in truth])
    measured = data.accel[index] / np.linalg.norm(data.accel[index], axis=1)[:, None]
    tilt_deg = np.degrees(np.arccos(np.clip(np.sum(measured * up_body, axis=1), -1.0, 1.0)))
    assert np.percentile(tilt_deg, 95) > 20.0
    settled = np.array(builder.keyframe_t) - builder.keyframe_t[0] > 10.0
    assert error_deg[settled].max() < 4.0, error_deg[settled].max()


def test_a_diverged_batch_is_repaired_from_the_causal_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    """Started 170 deg off in heading (where the heading factor's projected error pulls to the flip), the
    batch's own residual check notices and solves again from the online estimate."""
    from fusegraph.graphs import attitude9 as graph

    session = simulate_attitude9(4, duration_s=15.0, disturbance_uT=0.0)

    def turned(self: Attitude9Builder, values: gtsam.Values) -> gtsam.Values:
        for k in range(len(self.keyframe_t)):
            pose = values.atPose3(self.X(k))
            values.update(self.X(k), gtsam.Pose3(gtsam.Rot3.Rz(np.deg2rad(170.0)).compose(pose.rotation()), pose.translation()))
        return values

    monkeypatch.setattr(graph.Attitude9Builder, "inertial_initial", turned)
    estimate = attitude9.run_batch(session)
    assert estimate.extras["check"] == "repaired", estimate.extras
    assert _score(estimate, session).total < 1.0


@requires_shared_data("broad")
def test_broad_trial_08_batch_does_not_slide_to_the_flipped_heading() -> None:
    """The regression trial (fast rotation with breaks): it once converged to 95 deg of heading error."""
    from fusegraph.datasets.broad import DEFAULT_DIR, load_broad

    session = load_broad(DEFAULT_DIR / "08_undisturbed_fast_rotation_with_breaks_A.mat")
    estimate = attitude9.run_batch(session)
    errors = broad_errors(estimate.quat_wxyz, session.truth.values, session.stream("movement").values[:, 0])  # type: ignore[union-attr]
    assert estimate.extras["check"] == "ok"
    assert errors.heading < 5.0, errors  # VQF offline: 2.1 deg on this trial


def test_a_dropout_of_every_imu_stream_is_bridged_reported_and_recovered() -> None:
    """1 s without gyro, accel and mag during a simulated motion (seed 4, 12-13 s: a hand at 100-180 deg/s, the field
    clean for 8 s after): each solver says so once (time and length); the batch is within 2 deg of its undamaged
    estimate from the gap on, the online estimate from 3 s after it (issue target: 5 s). Measured on seeds 0-9 at 5 s
    after: at most 1.2 deg; 3 s after: seed 4 0.25 deg (7.4 deg before the online restart re-levelled from 1 s of
    specific force and field in the gyro's frame, ``_Restart``). A gap followed by the scenario's disturbance (20-21 s)
    leaves only 1 s of clean field: 0.4-4 deg at 5 s over seeds 0-5 (10-24 deg without the restart)."""

    from fusegraph.evaluation.runner import simulated_sessions, solve_session
    from fusegraph.geometry import quat_conjugate, quat_multiply, rotvec_from_quat
    from fusegraph.metrics import on_truth_times

    _, session = simulated_sessions("attitude9", [4], duration_s=40.0)[0]
    damaged = cut_streams(session, ("gyro", "accel", "mag"), 12.0, 13.0)
    gyro_deg_s = np.rad2deg(np.linalg.norm(session.stream("gyro").values[(session.stream("gyro").t > 11) & (session.stream("gyro").t < 14)], axis=1))
    assert np.median(gyro_deg_s) > 50.0  # the gap is in motion
    for solver in ("online", "batch"):
        whole = solve_session(session, solver).estimate
        outcome, said = solve_saying(damaged, solver, "bridged")
        broken = outcome.estimate
        assert len(said) == 1 and "1.01 s after t = 11.99 s" in said[0]  # last sample before, first after: 11.99 -> 13.00, said
        at = np.array([14.0, 16.0, 18.0, 20.0]) if solver == "batch" else np.array([16.0, 18.0, 20.0])
        a, b = on_truth_times(whole, at).quat_wxyz, on_truth_times(broken, at).quat_wxyz
        apart_deg = np.rad2deg(np.linalg.norm(rotvec_from_quat(quat_multiply(quat_conjugate(a), b)), axis=1))
        assert np.all(apart_deg < 2.0), (solver, apart_deg)


def test_a_dropout_of_the_magnetometer_alone_is_cut_from_every_stream_said_once_and_bridged() -> None:
    """The magnetometer missing for 1 s (the gyro and accelerometer running on): one warning names the stream and the
    span, the samples of the others there are left out, and the graph bridges the gap as a dropout of all; the peers run
    on the same cut streams. A stream at another rate is still an error naming it."""
    from dataclasses import replace

    from fusegraph.evaluation.runner import simulated_sessions
    from fusegraph.session import SessionError

    _, session = simulated_sessions("attitude9", [0], duration_s=20.0)[0]
    mag = session.stream("mag")
    damaged = cut_streams(session, ("mag",), 12.0, 13.0)
    for solver in ("batch", "vqf"):
        result, said = solve_saying(damaged, solver, "has no sample")
        assert len(said) == 1 and "stream 'mag' has no sample at 100 times between t = 12.00 and 12.99 s" in said[0], said
        assert result.metrics["truth_samples_missing"] == 100 and "inside its dropouts" in result.metrics["truth_samples_missing_why"]
    slow = replace(mag, t=mag.t[::2], values=mag.values[::2])
    with pytest.raises(SessionError, match="stream 'mag' must be sampled with 'gyro'"):
        replace(session, streams={**session.streams, "mag": slow}).synchronous("gyro", "accel", "mag")


def _gap_at_rest(session, start_s: float, end_s: float, turn_quat_wxyz: np.ndarray | None = None):  # type: ignore[no-untyped-def]
    """The session without gyro/accel/mag in [start_s, end_s); with ``turn_quat_wxyz``, the sensor turned by it (in its own
    frame) during the gap and set down again: every later reading and the truth are of the turned body."""
    from dataclasses import replace

    from fusegraph.geometry import matrix_from_quat, quat_multiply
    from fusegraph.systems.attitude9 import model_for

    turn = np.eye(3) if turn_quat_wxyz is None else matrix_from_quat(turn_quat_wxyz[None])[0]
    cal = model_for(session).mag_calibration
    gain, offset = np.asarray(cal.gain), np.asarray(cal.offset)
    streams = dict(session.streams)
    for name in ("gyro", "accel", "mag"):
        stream = session.stream(name)
        values, after = stream.values.copy(), stream.t >= end_s
        if name == "mag":  # calibrated = gain * raw + offset turns with the body; the raw reading is what the file holds
            values[after] = ((values[after] * gain + offset) @ turn - offset) / gain
        else:
            values[after] = values[after] @ turn
        kept = (stream.t < start_s) | (stream.t >= end_s)
        streams[name] = replace(stream, t=stream.t[kept], values=values[kept])
    truth = session.truth
    if turn_quat_wxyz is not None:
        quats, after = truth.values.copy(), truth.t >= end_s
        quats[after] = quat_multiply(quats[after], np.tile(turn_quat_wxyz, (int(after.sum()), 1)))
        truth = replace(truth, values=quats)
    return replace(session, streams=streams, truth=truth)


@requires_shared_data("broad")
def test_a_dropout_at_rest_costs_nothing_and_a_body_moved_in_it_is_found_again() -> None:
    """BROAD, 1 s without the IMU while the sensor rests (20-21 s): still before and after with gravity and the field where
    they were, the bridge holds the attitude (as fast as the still gyro turned); the whole-trial error within 0.5 deg of the
    undamaged run's (measured +0.17 / +0.07 deg online and +0.07 / +0.06 batch on trials 15 and 21; 1.4 / 0.8 deg online
    before the rest bridge: the heading after the gap came from the field again). The same gap with the sensor turned
    60 deg and set down: the field has moved, the bridge is the usual wide one, and the online estimate is within 2.5 deg of
    the turned truth 5 s later (measured 1.4 deg with the settings of 2026-11-26; 2.06 with those of 2026-11-27, and 1.94
    with them but the start's field kept as the reference)."""
    import warnings

    from fusegraph.datasets.broad import DEFAULT_DIR, load_broad
    from fusegraph.evaluation.runner import solve_session
    from fusegraph.geometry import quat_from_rotvec
    from fusegraph.metrics import on_truth_times

    for trial in ("15_undisturbed_fast_translation_A", "21_undisturbed_fast_combined"):
        session = load_broad(DEFAULT_DIR / f"{trial}.mat")
        damaged = _gap_at_rest(session, 20.0, 21.0)
        for solver in ("online", "batch"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                whole, broken = (solve_session(s, solver).metrics["total_deg"] for s in (session, damaged))
            assert abs(broken - whole) < 0.5, (trial, solver, whole, broken)
    session = load_broad(DEFAULT_DIR / "01_undisturbed_slow_rotation_A.mat")
    moved = _gap_at_rest(session, 20.0, 21.0, quat_from_rotvec(np.deg2rad([18.0, 12.0, 60.0])))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        estimate = solve_session(moved, "online").estimate
    i = int(np.searchsorted(moved.truth.t, 26.0))
    error = broad_errors(on_truth_times(estimate, moved.truth.t[i : i + 1]).quat_wxyz, moved.truth.values[i : i + 1], np.ones(1))
    assert error.total < 2.5, error


def _turning(seconds: float, rate_hz: float = 5.0, seed: int = 0) -> list[gtsam.Rot3]:
    """Keyframe attitudes of a hand turning the sensor about every axis (smooth random rates up to ~1 rad/s)."""
    rng = np.random.default_rng(seed)
    steps = int(seconds * rate_hz)
    rates = np.cumsum(rng.normal(0, 0.15, (steps, 3)), axis=0)
    rates -= np.linspace(0, 1, steps)[:, None] * rates[-1]  # bounded
    out, R = [], gtsam.Rot3()
    for w in rates:
        R = R.compose(gtsam.Rot3.Expmap(np.clip(w, -1.0, 1.0) / rate_hz))
        out.append(R)
    return out


def test_a_carried_magnet_is_separated_from_the_earth_field_by_the_rotation() -> None:
    from fusegraph.factors.mag import HardIron

    earth = np.array([0.0, 20.0, -40.0])  # uT, ENU: north and down (dip 63 deg)
    reference = FieldReference(float(np.linalg.norm(earth)), float(np.arctan2(40.0, 20.0)))
    noise = MagNoise(hard_iron_s=5.0, hard_iron_fit=0.1, hard_iron_min=0.2)
    magnet = np.array([10.0, -5.0, 8.0])  # uT in the sensor frame, 14 uT: a magnet riding on the sensor
    rng = np.random.default_rng(1)
    tracker = HardIron(noise, reference)
    for k, R in enumerate(_turning(20.0)):
        reading = R.unrotate(earth) + magnet + rng.normal(0, 0.3, 3)
        corrected = tracker.correct(0.2 * k, R, reading)
    assert tracker.trusted and np.linalg.norm(tracker.bias - magnet) < 0.5  # uT: 0.3 uT noise over ~25 readings in memory
    assert np.linalg.norm(corrected - R.unrotate(earth)) < 1.5  # the reading is the Earth's field again (noise + the estimate)
    # a magnet near the path: the field depends on where the sensor is, in the world frame, not on the sensor: no b is taken
    tracker = HardIron(noise, reference)
    for k, R in enumerate(_turning(20.0, seed=2)):
        nearby = 15.0 * np.array([np.sin(0.3 * k), np.cos(0.2 * k), 0.5])  # uT, changes as the sensor moves about
        tracker.correct(0.2 * k, R, R.unrotate(earth + nearby) + rng.normal(0, 0.3, 3))
        assert not tracker.trusted, k
    # the sensor held still: b cannot be told from the field, so nothing is corrected
    tracker = HardIron(noise, reference)
    for k in range(100):
        tracker.correct(0.2 * k, gtsam.Rot3(), earth + magnet)
    assert not tracker.trusted and not tracker.bias.any()


def test_the_hard_iron_estimate_solves_its_normal_equations() -> None:
    """``HardIron._solve`` (B eliminated first, in floats) gives what numpy's 6 x 6 solve of the same normal equations
    gives: [[W I, C], [C^T, W (1 + 1e-6) I]] [B; b] = [sum w R m; sum w m], built here from the readings and attitudes
    with the same forgetting. 1e-9 relative: rounding (Schur complement and cofactors against LU)."""
    from fusegraph.factors.mag import HardIron

    earth = np.array([0.0, 20.0, -40.0])
    noise = MagNoise(hard_iron_s=5.0, hard_iron_fit=0.1, hard_iron_min=0.2)
    tracker = HardIron(noise, FieldReference(float(np.linalg.norm(earth)), float(np.arctan2(40.0, 20.0))))
    rng = np.random.default_rng(4)
    W, C, v, t_prev = 0.0, np.zeros((3, 3)), np.zeros(6), None
    for k, R in enumerate(_turning(8.0, seed=5)):
        t = 0.2 * k + 0.05 * rng.random()  # uneven intervals: the forgetting differs per reading
        reading = R.unrotate(earth) + np.array([4.0, -2.0, 3.0]) + rng.normal(0, 0.3, 3)
        tracker.correct(t, R, reading)
        forget = np.exp(-(t - t_prev) / noise.hard_iron_s) if t_prev is not None else 1.0
        t_prev = t
        W, C = forget * W + 1.0, forget * C + R.matrix()
        v = forget * v + np.concatenate((R.matrix() @ reading, reading))
    normal = np.block([[W * np.eye(3), C], [C.T, W * (1.0 + 1e-6) * np.eye(3)]])
    expected = np.linalg.solve(normal, v)
    field, bias = tracker._solve()
    np.testing.assert_allclose(np.r_[field, bias], expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())


def test_the_hard_iron_estimates_3x3_solve_is_numpys() -> None:
    from fusegraph.factors.mag import _solve3_floats

    rng = np.random.default_rng(3)
    for _ in range(50):
        a = rng.normal(size=(3, 3))
        a = a @ a.T + 0.01 * np.eye(3)  # symmetric positive definite, as the Schur complement is
        y = rng.normal(size=3)
        np.testing.assert_allclose(_solve3_floats(a.tolist(), y.tolist()), np.linalg.solve(a, y), rtol=1e-8, atol=1e-10)  # cofactors vs LU: rounding
    with pytest.raises(np.linalg.LinAlgError):
        _solve3_floats(np.ones((3, 3)).tolist(), [1.0, 1.0, 1.0])


def test_the_undisturbed_field_is_followed_and_a_steady_new_one_taken_while_turning() -> None:
    """``FieldTracker`` (VQF's rule): a field that agrees with the reference pulls it at the time constant; one that
    disagrees but holds steady while the sensor turns becomes the reference after ``new_field_s``; held still, or
    wandering as a magnet's field does while the sensor moves, it does not."""
    from fusegraph.factors.mag import FieldTracker

    start = FieldReference(41.6, np.radians(71.3))
    dt, turning, still = 0.2, np.radians(60.0), np.radians(2.0)
    follow = FieldTracker(MagNoise(reference_tau_s=20.0), start)
    for k in range(101):  # 20 s at a field 6 % stronger, 2 deg less dip: within VQF's 10 % / 10 deg
        ref = follow.update(k * dt, 44.1, np.radians(69.3), turning)
    # the start's field has agreed from the start, so every step pulls: after 20 s, one time constant, 1 - 1/e of the way
    # (the first reading starts the clock)
    assert ref.norm == pytest.approx(41.6 + 2.5 * (1 - np.exp(-1.0)), abs=1e-9)
    assert ref.dip_rad == pytest.approx(np.radians(71.3) - np.radians(2.0) * (1 - np.exp(-1.0)), abs=1e-9)
    new = FieldTracker(MagNoise(new_field_s=20.0), start)
    for k in range(150):  # 30 s at 55 uT, 60 deg: off the reference (32 %), steady, turning
        ref = new.update(k * dt, 55.0 + 0.2 * np.sin(k), np.radians(60.0), turning)
        if k * dt < 20.0 - 1e-9:
            assert ref == start, k
    assert ref.norm == pytest.approx(55.0, abs=0.1) and ref.dip_rad == pytest.approx(np.radians(60.0))
    held = FieldTracker(MagNoise(new_field_s=20.0), start)
    for k in range(150):  # the same field read by a still sensor: a magnet's reads as steadily
        assert held.update(k * dt, 55.0, np.radians(60.0), still) == start
    wandering = FieldTracker(MagNoise(new_field_s=20.0), start)
    for k in range(300):  # a magnet near the path: the field jumps by 20 % as the sensor moves about
        assert wandering.update(k * dt, 55.0 + 11.0 * (k % 2), np.radians(60.0), turning) == start
    unchanged = FieldTracker(MagNoise(), start)  # both settings 0: the start's reference throughout
    assert unchanged.update(0.0, 44.1, np.radians(69.3), turning) == start


def test_a_new_place_field_is_taken_and_said() -> None:
    """The sensor carried to a place where the Earth's field is stronger and dips less (north unchanged): the online
    estimate with a new field taken after 20 s of turning and the reference not followed otherwise (VQF's default and the
    model's choice until 2026-11-27; BROAD's study, all in one room, now chooses no new field and a following of 60 s,
    so the recording declares it on its mag stream) takes it as the reference, says so in a warning and in
    ``extras['new_field_s']``, and keeps its heading."""
    import warnings
    from dataclasses import replace

    from fusegraph.geometry import matrix_from_quat
    from fusegraph.session import SessionWarning

    session = simulate_attitude9(4, duration_s=70.0, disturbance_uT=0.0)
    mag, truth, extra = session.stream("mag"), session.truth, session.meta["truth_extra"]
    dip = np.radians(55.0)
    there = 60.0 * np.array([0.0, np.cos(dip), -np.sin(dip)])  # uT, ENU: 20 % stronger than the start's 50, 10 deg less dip
    moved = mag.t >= 10.0
    true_body = np.einsum("nji,j->ni", matrix_from_quat(truth.values[moved]), there)  # world_R_body^T B
    raw = mag.values.copy()
    raw[moved] = (true_body - np.asarray(extra["mag_offset_uT"])) / np.asarray(extra["mag_gain"])  # noise-free there: the rule, not noise
    # the recording declares the tracking on its mag stream (the user's way)
    session = replace(session, streams={**session.streams, "mag": replace(mag, values=raw, meta={**mag.meta, "new_field_s": 20.0, "reference_tau_s": 0.0})})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        estimate = attitude9.run_online(session)
    said = [str(w.message) for w in caught if issubclass(w.category, SessionWarning) and "reference field" in str(w.message)]
    assert len(said) == 1, said
    # the dip as levelled with the estimated tilt: within 0.3 deg of the place's 55 (said 55.0 with the settings of
    # 2026-11-26, 55.1 with those of 2026-11-27)
    assert abs(float(said[0].split(" and dip ")[1].split(" deg")[0]) - 55.0) < 0.3, said
    (t_new,) = estimate.extras["new_field_s"]
    assert 30.0 <= t_new < 45.0  # 20 s of turning after the move, once a reading disagrees with the start's field
    after = np.zeros(len(truth.t))
    after[truth.t > t_new + 5.0] = 1.0
    # measured 0.12 deg; judged against the start's field throughout (new_field_s 0) the gate keeps the heading sigma
    # inflated and the heading wanders to 1.3 deg
    assert _score(estimate, session, after).heading < 0.6


def test_the_scale_map_turns_the_preintegrated_rotation_as_the_scale_error_does() -> None:
    from fusegraph.factors.gyro import rate_matrix, scale_rate_map

    # a 0.2 s interval at 286 Hz whose axis turns fast (BROAD's fast trials reach 500 deg/s): the readings scaled by
    # (I + K) against the same readings with the bias moved by -M c
    rng = np.random.default_rng(3)
    dt = 1.0 / 286.0
    t = np.arange(57) * dt
    omega = np.stack([8.0 * np.sin(2 * np.pi * 3 * t), 6.0 * np.cos(2 * np.pi * 2 * t + 1), 5.0 + 2.0 * t], axis=1)
    bias = np.array([0.01, -0.02, 0.005])
    K = rng.normal(0.0, 0.005, (3, 3))

    def turned(readings: np.ndarray, b: np.ndarray) -> gtsam.Rot3:
        params = gtsam.PreintegrationParams.MakeSharedU(9.81)
        params.setGyroscopeCovariance(1e-6 * np.eye(3))
        params.setAccelerometerCovariance(1e-4 * np.eye(3))
        params.setIntegrationCovariance(1e-8 * np.eye(3))
        pim = gtsam.PreintegratedImuMeasurements(params, gtsam.imuBias.ConstantBias(np.zeros(3), b))
        for w in readings:
            pim.integrateMeasurement(np.array([0.0, 0.0, 9.81]), w, dt)
        return pim.deltaRij()

    def off_deg(b: np.ndarray) -> float:
        return float(np.rad2deg(np.linalg.norm(gtsam.Rot3.Logmap(scaled.between(turned(omega, b))))))

    scaled = turned(omega + omega @ K.T, bias)
    exact = off_deg(bias - scale_rate_map(omega, np.full(len(t), dt), bias) @ K.ravel())
    mean_rate = off_deg(bias - rate_matrix(omega.mean(0)) @ K.ravel())
    # second order in K (0.5 %) is what is left; the mean rate's map misses the turning axis by a large part of the effect
    assert exact < 0.01 < mean_rate and off_deg(bias) > 0.2


def test_the_batch_estimates_the_gyro_scale_a_recording_declares() -> None:
    from dataclasses import replace

    session = simulate_attitude9(0, gyro_scale_error=0.02, duration_s=40.0)
    true_scale = np.array(session.meta["truth_extra"]["gyro_scale_error"])
    gyro = session.stream("gyro")
    declared = replace(session, streams={**session.streams, "gyro": replace(gyro, meta={**gyro.meta, "scale_sigma": 0.05})})
    plain, calibrated = attitude9.run_batch(session), attitude9.run_batch(declared)
    K = np.array(calibrated.extras["gyro_calibration"])
    # K corrects the reading: (I + K)(I + S) ~ I, so K's diagonal ~ -S; 40 s of +-60 / 35 deg swings with noise and a
    # disturbance leave ~0.2 % on the swung axes (x, y) and more on the least turned one (measured 0.0158 / 0.0144 / -0.0071
    # against 0.0158 / 0.0144 / 0.008 over 60 s)
    assert np.allclose(np.diag(K)[:2], -true_scale[:2], atol=0.004)
    assert _score(calibrated, session).total < 0.7 * _score(plain, session).total
    assert "gyro_calibration" not in plain.extras


def test_the_zero_rate_update_reads_the_bias_from_a_rest() -> None:
    from fusegraph.factors.imu import FREE_GYRO_BIAS_RAD_S, ZERO_RATE_SCATTER_FLOOR_RAD_S, rest_reading, steady_rest, zero_rate_factor

    rng = np.random.default_rng(5)
    bias = np.array([0.01, -0.004, 0.002])
    gyro = bias + rng.normal(0.0, 0.003, (57, 3))
    dt = np.full(57, 1.0 / 286.0)
    reading = rest_reading(gyro, dt)
    assert np.allclose(reading[0], gyro.mean(0), atol=1e-15) and reading[1] == pytest.approx(gyro.std(0).mean() / np.sqrt(57))
    factor = zero_rate_factor(7, reading)
    assert np.array_equal(factor.prior().gyroscope(), reading[0])
    sigmas = factor.noiseModel().sigmas()
    assert np.allclose(sigmas[:3], FREE_GYRO_BIAS_RAD_S) and np.allclose(sigmas[3:], reading[1])  # the accelerometer's part free
    assert zero_rate_factor(7, reading, 0.01).noiseModel().sigmas()[3] == 0.01  # a rest's own rate where larger
    assert rest_reading(np.tile(bias, (57, 1)), dt)[1] == pytest.approx(ZERO_RATE_SCATTER_FLOOR_RAD_S / np.sqrt(57))
    # the same readings, column-major: the same bits (an imported session and one in memory agree to the last digit)
    again = rest_reading(np.asfortranarray(gyro), dt)
    assert np.array_equal(again[0], reading[0]) and again[1] == reading[1]
    # the next interval of the same rest agrees; one whose body turns at 0.01 rad/s more (a slow rest edge) does not
    assert steady_rest(reading, rest_reading(bias + rng.normal(0.0, 0.003, (57, 3)), dt))
    assert not steady_rest(reading, rest_reading(bias + [0.0, 0.0, 0.01] + rng.normal(0.0, 0.003, (57, 3)), dt))


def test_a_rest_pins_the_gyro_bias_only_with_the_zero_rate_update() -> None:
    from dataclasses import replace

    from fusegraph.factors.imu import MotionPriors

    # 20 s lying still: readings = bias + noise; the field and gravity constant
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 20.0, 0.01)
    bias = np.array([0.02, -0.01, 0.015])
    gyro = bias + rng.normal(0.0, 0.004, (len(t), 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0.0, 0.02, (len(t), 3))
    mag = np.array([0.0, 20.0, -45.0]) + rng.normal(0.0, 0.3, (len(t), 3))
    found = {}
    for sigma in (np.inf, 0.0):
        builder = Attitude9Builder(Attitude9Model(motion=MotionPriors(rest_rate_sigma_rad_s=sigma)), deferred_mag=True)
        builder.add_samples(t, gyro, accel, mag)
        graph = builder.take().graph()
        found[sigma] = sum(isinstance(graph.at(i), gtsam.PriorFactorConstantBias) for i in range(graph.size()))
    assert found[np.inf] == 1  # the start-up prior alone
    assert found[0.0] > 90  # nearly every keyframe of the rest (the first 0.54 s are not yet one: window, interval, one before)
    assert replace(Attitude9Model()).motion.rest_rate_sigma_rad_s == np.inf  # off unless chosen (the 9-axis system: tuned.toml)
    from fusegraph.tuned import tuned

    for solver, study in (("online", "broad_rest"), ("batch", "broad_rest_batch")):
        assert attitude9.broad_model(solver).motion.rest_rate_sigma_rad_s == tuned(study)["rest_rate_sigma_rad_s"]


def test_the_broad_bench_says_what_its_figures_are() -> None:
    from fusegraph.evaluation.broad import figures_are

    assert figures_are(["01_undisturbed_slow_rotation_A", "02_undisturbed_slow_rotation_B"]).startswith(
        "in-sample: the settings on main were chosen on 1 of these 2 trials")
    assert figures_are(["02_undisturbed_slow_rotation_B"]).startswith("held out: no setting on main was chosen on any of these 1 trials")
