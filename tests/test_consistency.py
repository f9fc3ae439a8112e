"""Units and conventions found by consistency between streams (``fusegraph.consistency``, run by ``Session.validate``):
each likely mistake made on a simulated session is named; the session as simulated passes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fusegraph.evaluation.runner import simulated_sessions
from fusegraph.session import Session, SessionError


def _with(session: Session, name: str, values: np.ndarray, **meta: object) -> Session:
    stream = session.stream(name)
    return replace(session, streams={**session.streams, name: replace(stream, values=values, meta={**stream.meta, **meta})})


def test_a_gyro_in_degrees_per_second_is_named_even_when_its_motion_is_slow() -> None:
    _, session = simulated_sessions("attitude9", [0], duration_s=30.0)[0]
    session.validate()
    gyro = session.stream("gyro").values
    assert np.rad2deg(np.abs(gyro)).max() < 2000  # in deg/s it would pass the magnitude check: only consistency tells
    with pytest.raises(SessionError, match="degrees per second"):
        _with(session, "gyro", np.rad2deg(gyro)).validate()
    _with(session, "gyro", gyro, units="rad/s").validate()  # declared units are taken at their word


def test_tracker_quaternions_written_scalar_last_are_named() -> None:
    _, session = simulated_sessions("head", [0], duration_s=20.0)[0]
    session.validate()
    quat = session.stream("tracker").values
    with pytest.raises(SessionError, match="scalar LAST"):
        _with(session, "tracker", quat[:, [1, 2, 3, 0]]).validate()


def test_ranges_in_millimetres_and_normalised_pixels_are_named() -> None:
    _, ranges = simulated_sessions("ultrasonic", [0], duration_s=5.0)[0]
    ranges.validate()
    name = ranges.streams_of_kind("ranges")[0].name
    millimetres = ranges.stream(name).values.copy()
    millimetres[:, 1] *= 1000.0
    with pytest.raises(SessionError, match="millimetres"):
        _with(ranges, name, millimetres).validate()
    _, gaze = simulated_sessions("gaze", [0], duration_s=10.0)[0]
    gaze.validate()
    width = float(gaze.stream("gaze").meta["width_px"])
    with pytest.raises(SessionError, match="normalised"):
        _with(gaze, "gaze", gaze.stream("gaze").values / width).validate()


def test_gaze_pixels_with_v_down_or_u_left_are_named_by_the_head_s_turn() -> None:
    """During fixations the gaze pixel follows the head's turn (du/dt = f w_z, dv/dt = f w_y): slope ~0.5 as simulated
    (0.4 on the Tobii recording); a mirrored axis gives the same slope negative, named. The threshold is 0.2."""
    _, gaze = simulated_sessions("gaze", [0], duration_s=30.0)[0]
    gaze.validate()
    uv = gaze.stream("gaze").values
    with pytest.raises(SessionError, match="v pointing down"):
        _with(gaze, "gaze", uv * [1.0, -1.0]).validate()
    with pytest.raises(SessionError, match="u pointing left"):
        _with(gaze, "gaze", uv * [-1.0, 1.0]).validate()


def test_more_transmitters_declared_than_any_receiver_hears_is_a_warning() -> None:
    _, ranges = simulated_sessions("ultrasonic", [0], duration_s=5.0)[0]
    stream = ranges.streams_of_kind("ranges")[0]
    declared = int(stream.meta["transmitters"])
    with pytest.warns(UserWarning, match=f"transmitters = {declared + 2}, but no receiver hears more than {declared}"):
        _with(ranges, stream.name, stream.values, transmitters=declared + 2).validate()


def test_swapped_gyro_columns_and_a_calibration_in_another_unit_are_named() -> None:
    _, head = simulated_sessions("head", [0], duration_s=20.0)[0]
    gyro = head.stream("gyro").values
    with pytest.raises(SessionError, match="x, y columns swapped"):
        _with(head, "gyro", gyro[:, [1, 0, 2]]).validate()
    _, nine = simulated_sessions("attitude9", [0], duration_s=30.0)[0]
    nine.validate()
    with pytest.raises(SessionError, match="mag_cal'.*another unit"):
        _with(nine, "mag_cal", nine.stream("mag_cal").values * 57.3).validate()


def test_a_ranges_dropout_is_a_warning_said_once() -> None:
    """A ranges stream silent for 2 s: one line (a ranging system's own 0.1-0.3 s slots are not dropouts: LIAS UWB)."""
    _, ranges = simulated_sessions("ultrasonic", [0], duration_s=8.0)[0]
    stream = ranges.streams_of_kind("ranges")[0]
    kept = (stream.t < 3.0) | (stream.t >= 5.0)
    gap = replace(ranges, streams={**ranges.streams, stream.name: replace(stream, t=stream.t[kept], values=stream.values[kept])})
    with pytest.warns(UserWarning, match=r"1 dropout\(s\) of more than 0.5 s without a range, the longest 2\.\d\d s after t = 2\.9"):
        gap.validate()


# ------------------------------------------------------------------------------------------------ sensor frames (round three)

def _tilting_imu(tilt_deg: float, seed: int = 0) -> Session:
    """A 9-axis sensor that yaws freely and tilts at most ``tilt_deg`` (pitch and roll at two slow rates), its gyro, gravity
    and field as a noisy but right sensor reads them, in one frame: the physics the frame checks read and nothing else."""
    from fusegraph.geometry import matrix_from_quat, quat_conjugate, quat_from_euler_zyx, quat_multiply, rotvec_from_quat
    from fusegraph.session import Stream

    rng = np.random.default_rng(seed)
    rate = 100.0
    t = np.arange(0.0, 60.0, 1.0 / rate)
    euler = np.stack([0.8 * np.sin(0.31 * t) + 0.3 * t, np.deg2rad(tilt_deg) * np.sin(0.9 * t), np.deg2rad(tilt_deg) * np.sin(0.53 * t + 1.0)], axis=1)
    quat = quat_from_euler_zyx(euler)  # world_R_body
    step = rotvec_from_quat(quat_multiply(quat_conjugate(quat[:-1]), quat[1:])) * rate
    gyro = np.vstack([step[:1], step]) + rng.normal(0.0, 0.005, (len(t), 3))
    body_R_world = np.transpose(matrix_from_quat(quat), (0, 2, 1))
    accel = np.einsum("nij,j->ni", body_R_world, [0.0, 0.0, 9.81]) + rng.normal(0.0, 0.05, (len(t), 3))
    mag = np.einsum("nij,j->ni", body_R_world, [0.0, 20.0, -40.0]) + [5.0, -3.0, 8.0] + rng.normal(0.0, 0.3, (len(t), 3))
    streams = {name: Stream(name, kind, t, values, cols) for name, kind, values, cols in
               (("gyro", "gyro", gyro, ("wx", "wy", "wz")), ("accel", "accel", accel, ("ax", "ay", "az")), ("mag", "mag", mag, ("mx", "my", "mz")))}
    return Session("attitude9", streams, Stream("truth", "attitude", t, quat, ("qw", "qx", "qy", "qz")))


SWAP_XY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
NEGATE_X = np.diag([-1.0, 1.0, 1.0])
TURN_Z = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@pytest.mark.parametrize("tilt_deg", [12.0, 40.0])
@pytest.mark.parametrize("stream", ["accel", "mag"])
@pytest.mark.parametrize("damage", [SWAP_XY, NEGATE_X, TURN_Z], ids=["x-y-swapped", "x-negated", "turned-90-about-z"])
def test_an_accelerometer_or_magnetometer_in_another_frame_than_the_gyro_is_named(tilt_deg: float, stream: str, damage: np.ndarray) -> None:
    session = _tilting_imu(tilt_deg)
    session.validate()  # the right frames pass
    damaged = _with(session, stream, session.stream(stream).values @ damage.T)
    with pytest.raises(SessionError, match=rf"stream '{stream}': .* another frame than the gyro's.*frame_R_sensor"):
        damaged.validate()


def test_a_declared_frame_R_sensor_is_applied_on_loading(tmp_path) -> None:
    from fusegraph.session import load_session, save_session

    session = _tilting_imu(30.0)
    damaged = _with(session, "accel", session.stream("accel").values @ SWAP_XY.T)
    save_session(damaged, tmp_path / "s")
    toml = tmp_path / "s" / "session.toml"
    toml.write_text(toml.read_text().replace("[streams.accel]\n", "[streams.accel]\nframe_R_sensor = [[0, 1, 0], [1, 0, 0], [0, 0, 1]]\n"))
    loaded = load_session(tmp_path / "s")
    loaded.validate()
    np.testing.assert_allclose(loaded.stream("accel").values, session.stream("accel").values, atol=1e-6)  # CSV round trip


def test_the_gyro_in_another_frame_than_accelerometer_and_magnetometer_is_named_as_the_gyro() -> None:
    session = _tilting_imu(40.0)
    turned = _with(session, "gyro", session.stream("gyro").values @ TURN_Z.T)
    with pytest.raises(SessionError, match="stream 'gyro': gravity and the field both turn"):
        turned.validate()


def test_a_dead_magnetometer_is_left_out_with_one_warning_and_a_dead_gyro_is_an_error() -> None:
    session = _tilting_imu(30.0)
    mag = session.stream("mag").values
    for dead in (np.zeros_like(mag), np.tile(mag[0], (len(mag), 1))):
        broken = _with(session, "mag", dead)
        with pytest.warns(UserWarning, match="stream 'mag': .*dead.*solved without it"):
            broken.validate()
        assert "mag" not in broken.usable().streams and "mag" in session.usable().streams
    with pytest.raises(SessionError, match="stream 'gyro': every sample is zero"):
        _with(session, "gyro", np.zeros_like(mag)).validate()


def test_a_dead_magnetometer_solves_as_without_it() -> None:
    from fusegraph.systems.presets import PRESETS

    session = _tilting_imu(30.0)
    dead = _with(session, "mag", np.tile(session.stream("mag").values[0], (len(session.stream("mag")), 1)))
    with pytest.warns(UserWarning):
        by_dead = PRESETS["attitude9"].solve(dead, "online")
    without = PRESETS["attitude9"].solve(session.without("mag"), "online")
    np.testing.assert_allclose(by_dead.quat_wxyz, without.quat_wxyz)


def test_truth_conjugated_or_on_another_clock_is_named() -> None:
    session = _tilting_imu(30.0)
    truth = session.truth
    assert truth is not None
    conjugated = replace(session, truth=replace(truth, values=truth.values * [1.0, -1.0, -1.0, -1.0]))
    with pytest.raises(SessionError, match="truth: .*conjugated: written as body_R_world"):
        conjugated.validate()
    later = replace(session, truth=replace(truth, t=truth.t + 1000.0))
    with pytest.raises(SessionError, match=r"truth \(1000.000 .. .* does not overlap 'gyro'.*another clock \(about \+1000 s off\)"):
        later.validate()


def test_a_gyro_in_degrees_per_second_on_a_sensor_at_rest_is_found_by_the_field() -> None:
    session = _tilting_imu(0.0)
    n = len(session.stream("gyro"))
    rng = np.random.default_rng(3)
    still_gyro = np.tile(np.deg2rad([0.05, -0.03, 0.6]), (n, 1)) + rng.normal(0.0, 0.002, (n, 3))  # a bias mostly about the vertical
    still = {name: replace(session.stream(name), values=values) for name, values in (
        ("gyro", still_gyro), ("accel", np.tile([0.0, 0.0, 9.81], (n, 1)) + rng.normal(0.0, 0.05, (n, 3))),
        ("mag", np.tile([0.0, 20.0, -40.0], (n, 1)) + rng.normal(0.0, 0.3, (n, 3))))}
    at_rest = Session("attitude9", still)
    at_rest.validate()
    with pytest.raises(SessionError, match="stream 'gyro': the gyro turns the field .* at rest.*degrees per second"):
        _with(at_rest, "gyro", np.rad2deg(still_gyro)).validate()


def test_repeated_range_rows_are_a_warning_and_kept_once() -> None:
    _, session = simulated_sessions("ultrasonic", [0], duration_s=5.0)[0]
    ranges = session.stream("ranges")
    twice = np.repeat(np.arange(len(ranges)), 2)
    doubled = replace(session, streams={**session.streams, "ranges": replace(ranges, t=ranges.t[twice], values=ranges.values[twice])})
    with pytest.warns(UserWarning, match="stream 'ranges': .* rows repeat a row of their epoch exactly"):
        doubled.validate()
    np.testing.assert_array_equal(doubled.usable().stream("ranges").values, ranges.values)


QUIET_WORDS = ("another frame", "dead", "stuck", "repeat a row", "conjugated", "another clock", "degrees per second")
"""What the round-three checks say: none of it may be said of a recording as published."""


@pytest.mark.parametrize("dataset", ["broad", "gaze_tobii", "gaze_pupil_invisible", "uwb_lias", "hapt", "mobgap", "steps_oxford"])
def test_no_false_alarm_on_any_shared_recording(dataset: str) -> None:
    import warnings

    from conftest import SHARED_DATA

    from fusegraph.datasets import importers

    source = SHARED_DATA / dataset
    if not source.is_dir():
        pytest.skip(f"real recordings not found at {source} (CI has them beside the repo)")
    if dataset == "hapt":
        from fusegraph.datasets.hapt import hapt_sessions as sessions_of
    elif dataset == "mobgap":
        from fusegraph.datasets.mobgap_lab import mobgap_sessions as sessions_of
    else:
        sessions_of = {"broad": importers.broad_sessions, "steps_oxford": importers.oxford_sessions,
                       "gaze_tobii": lambda s: [("tobii", importers.tobii_session(s))],
                       "gaze_pupil_invisible": lambda s: [("pupil", importers.pupil_session(s))],
                       "uwb_lias": lambda s: [("uwb", importers.uwb_session(s))]}[dataset]
    found = sessions_of(source)
    assert found
    for name, session in found:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            session.validate()
        said = [str(w.message) for w in caught if any(word in str(w.message) for word in QUIET_WORDS)]
        assert not said, f"{name}: {said}"


def test_a_broad_trial_with_its_accelerometer_axes_swapped_is_named(tmp_path) -> None:
    from conftest import SHARED_DATA

    from fusegraph.datasets.importers import broad_sessions

    trial = SHARED_DATA / "broad" / "04_undisturbed_slow_rotation_with_breaks_A.mat"
    if not trial.is_file():
        pytest.skip(f"real recordings not found at {trial.parent} (CI has them beside the repo)")
    _, session = broad_sessions(trial)[0]
    for stream, damage in (("accel", SWAP_XY), ("accel", NEGATE_X), ("accel", TURN_Z), ("mag", SWAP_XY)):
        with pytest.raises(SessionError, match=rf"stream '{stream}': .*another frame"):
            _with(session, stream, session.stream(stream).values @ damage.T).validate()


def test_free_fall_and_bouncing_are_no_unit_error_but_g_at_rest_is() -> None:
    """An accelerometer's unit is judged where it rests: a trampoline's airborne half (|a| ~ 0) is motion, not a unit."""
    session = _tilting_imu(20.0)
    accel = session.stream("accel").values.copy()
    airborne = (np.arange(len(accel)) // 50) % 3 != 0  # two of every three half-seconds in free fall
    bouncing = accel.copy()
    bouncing[airborne] = np.random.default_rng(1).normal(0.0, 0.05, (int(airborne.sum()), 3))
    _with(session, "accel", bouncing).validate()
    with pytest.raises(SessionError, match="stream 'accel'.*at rest.*in g\\? set units = 'g'"):
        load_accel_in_g = _with(session, "accel", accel / 9.81)
        from fusegraph.sensors import sensor_catalogue
        from fusegraph.session import check_plausible

        check_plausible(sensor_catalogue()["accel"], session.stream("accel").t, load_accel_in_g.stream("accel").values, {}, "stream 'accel'")


def test_the_largest_value_met_apart_is_no_clip_and_a_rail_is() -> None:
    from fusegraph.consistency import saturation_level

    rng = np.random.default_rng(2)
    values = rng.normal(0.0, 5.0, (20000, 3))
    values[rng.choice(20000, 10, replace=False), 0] = 30.83  # the largest reading, met ten times apart (a long recording)
    assert saturation_level(values) is None
    values[5000:5012, 1] = 30.83  # the signal runs into the rail and stays there
    assert saturation_level(values) == pytest.approx(30.83)


def test_a_batch_that_did_not_converge_is_suspect() -> None:
    from fusegraph.consistency import suspect_reasons

    assert suspect_reasons({}, {"check": "suspect", "heading_residual_median_deg": 95.0}) == [
        "the batch did not converge (median heading residual 95 deg)"]
    assert suspect_reasons({}, {"iterations": 50, "max_iterations": 50})[0].startswith("the batch stopped at its cap of 50 iterations")
    assert suspect_reasons({}, {"iterations": 3, "max_iterations": 50, "check": "ok"}) == []


def test_a_tracker_is_checked_against_the_gyro_without_truth_too() -> None:
    _, session = simulated_sessions("head", [0], duration_s=20.0)[0]
    bare = replace(session, truth=None)
    bare.validate()
    with pytest.raises(SessionError, match="scalar LAST"):
        _with(bare, "tracker", bare.stream("tracker").values[:, [1, 2, 3, 0]]).validate()
