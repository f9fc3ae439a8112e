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
