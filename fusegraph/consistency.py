"""Units and conventions found by consistency between streams, not by magnitude alone (``Session.validate`` runs them).

A gyro in deg/s whose motion stays under 35 deg/s passes every magnitude check; so does a tracker quaternion written
x, y, z, w under a ``qw, qx, qy, qz`` header. Two sensors that see the same motion tell: the gyro must turn gravity as
the accelerometer sees it turn, and a tracker must rotate between its samples as far as the gyro integrates. Each check
compares the streams as written with the likely mistake (the factor 57.3, the columns reordered) and raises a
``SessionError`` naming the stream and the likely cause when the mistake fits far better; a stream that declares its
``units`` is taken at its word. Ranges far beyond the receivers' geometry (millimetres) and pixels inside [0, 1] with a
declared image size (normalised) are named too.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from .geometry import FloatArray, matrix_from_quat, quat_conjugate, quat_multiply, quat_normalize, rotvec_from_quat

DEG = np.pi / 180.0
CHECK_SPAN_S = 120.0
"""Seconds of a recording the checks read (its start): enough motion, bounded time."""
MISTAKE_FITS = 0.5
"""A mistaken reading is named when it fits with at most this fraction of the error of the reading as written..."""
MIN_MISFIT_DEG = 3.0
"""...and the reading as written is off by at least this much (median, degrees): noise alone is never named."""


RANGES_GAP_S = 0.5
"""A ranges stream silent this long is a dropout said once (a ranging system's own slots leave gaps of 0.1-0.3 s: LIAS UWB)."""
FOLLOWS = 0.2
"""Gaze pixels follow the head's turn when their slope against it is above this (measured as written: Tobii 0.43 / 0.39 for
u / v, simulations 0.44-0.58: the slow samples include some pursuit of head-fixed targets; mirrored, the same negative)."""


def _most_heard_per_epoch(t: FloatArray, receiver: FloatArray) -> int:
    """The most ranges one receiver took at one time (its epoch): the transmitters it hears (90th percentile over
    epochs, so that a rare echo is not one)."""
    key = np.stack([t, receiver], axis=1)
    _, counts = np.unique(key, axis=0, return_counts=True)
    return int(np.percentile(counts, 90))


CLIPPED_MIN_SAMPLES = 5
"""A sensor clips when at least this many samples of one axis sit exactly at its largest magnitude (a flat top: noise
never repeats a float extreme; 1,302 accelerometer samples at 1.99994 g in the Pupil Invisible trampoline recording)."""


CLIPPED_RUN = 3
"""...and at least this many of them in a row on one axis: a clipped signal stays at its rail while the motion is beyond it;
the largest value of a long recording met ten times apart (a 30-minute recording: +-30.83 m/s^2) is no rail."""


def saturation_level(values: FloatArray) -> float | None:
    """The magnitude at which a stream clips (its range), or None: the largest absolute value of an axis when at least
    ``CLIPPED_MIN_SAMPLES`` samples of that axis sit at it (within 1e-6 of it, relative), ``CLIPPED_RUN`` of them in a
    row, and no axis reads beyond it (a
    range bounds every axis: a smooth periodic motion sampled in step with its period repeats its peak, and is no range)."""
    magnitude = np.abs(np.asarray(values, dtype=float))
    if magnitude.size == 0 or not np.isfinite(magnitude).any():
        return None
    top = np.nanmax(magnitude, axis=0)
    at_top = (magnitude >= top * (1.0 - 1e-6)) & (top > 0)
    held = np.zeros(at_top.shape[1], dtype=bool)  # the signal runs into the rail and stays: samples in a row at it
    if len(at_top) >= CLIPPED_RUN:
        held = np.asarray(np.lib.stride_tricks.sliding_window_view(at_top, CLIPPED_RUN, axis=0).all(axis=-1).any(axis=0))
    clipped = (at_top.sum(axis=0) >= CLIPPED_MIN_SAMPLES) & held & (top >= np.max(top) * (1.0 - 1e-6))
    return float(top[clipped].min()) if clipped.any() else None


def stream_range(stream: Any) -> float:
    """A stream's range: its ``range`` metadata when declared (a data sheet's), else where it is seen to clip; inf when it never does."""
    if "range" in stream.meta:
        return float(stream.meta["range"])
    level = saturation_level(stream.values)
    return math.inf if level is None else level


def clipped_samples(values: FloatArray, level: float | None) -> np.ndarray:
    """Samples with any axis at the sensor's range ``level`` (``saturation_level``): what they read is a bound, not a measurement."""
    if level is None or not np.isfinite(level):
        return np.zeros(len(values), dtype=bool)
    return np.asarray((np.abs(values) >= level * (1.0 - 1e-6)).any(axis=1))


class ConsistencyError(ValueError):
    """Two streams disagree in a way one unit or convention mistake explains (``session`` turns it into a SessionError)."""


def _declared_units(meta: Mapping[str, Any]) -> bool:
    return "units" in meta or "unit" in meta


def _integrated(t: FloatArray, omega: FloatArray) -> FloatArray:
    from .factors.gyro import integrate_gyro

    return integrate_gyro(t, omega, np.array([1.0, 0.0, 0.0, 0.0]))


def _angle_deg(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.rad2deg(np.arccos(np.clip(np.einsum("ni,ni->n", a, b), -1.0, 1.0)))


SWAPS = {"x, y": (1, 0, 2), "y, z": (0, 2, 1), "x, z": (2, 1, 0)}
"""Two columns of a 3-axis stream written in each other's place (against the other sensor of the same body)."""


def gyro_against_gravity(t: FloatArray, gyro: FloatArray, accel: FloatArray) -> dict[str, float] | None:
    """Median misfit (deg) of the gravity direction the accelerometer shows 1 s later against the one the gyro predicts:
    for the gyro as written (``as written``), x pi/180 (``deg/s``) and with two columns swapped (``SWAPS``' keys); None
    when the sensor hardly tilted (nothing to compare)."""
    keep = t <= t[0] + CHECK_SPAN_S
    t, gyro, accel = t[keep], gyro[keep], accel[keep]
    if len(t) < 20:
        return None
    dt = float(np.median(np.diff(t)))
    width = max(1, int(round(0.2 / dt)))  # a 0.2 s mean takes the steps' jolts out of the gravity direction
    kernel = np.ones(width) / width
    smooth = np.stack([np.convolve(accel[:, c], kernel, mode="same") for c in range(3)], axis=1)
    norm = np.linalg.norm(smooth, axis=1)
    up = smooth / np.maximum(norm, 1e-9)[:, None]
    lag = max(1, int(round(1.0 / dt)))
    i = np.arange(width, len(t) - lag - width, max(1, lag // 4))
    j = i + lag
    quiet = (np.abs(norm[i] - 9.81) < 1.5) & (np.abs(norm[j] - 9.81) < 1.5)
    tilted = quiet & (_angle_deg(up[i], up[j]) > 5.0)
    if tilted.sum() < 10:
        return None
    out = {}
    candidates = {"as written": gyro, "deg/s": gyro * DEG, **{name: gyro[:, order] for name, order in SWAPS.items()}}
    for name, rate in candidates.items():
        quat = _integrated(t, rate)
        relative = quat_multiply(quat_conjugate(quat[i[tilted]]), quat[j[tilted]])  # body at i -> body at j
        predicted = np.einsum("nji,nj->ni", matrix_from_quat(relative), up[i[tilted]])  # gravity seen from the body at j
        out[name] = float(np.median(_angle_deg(predicted, up[j[tilted]])))
    return out


def tracker_against_gyro(gyro_t: FloatArray, gyro: FloatArray, tracker_t: FloatArray, quat: FloatArray, conjugated: bool = False) -> dict[str, float] | None:
    """Median misfit (deg) between the rotation the tracker shows over 0.2 s and the one the gyro integrates (both in the
    body frame, which the head preset requires to be the same), for the quaternion columns as written (w, x, y, z:
    ``as written``), read as (x, y, z, w) (``scalar last``) and with two gyro columns swapped (``SWAPS``' keys); None
    without motion to compare. (The angle alone cannot tell: it is the same for any order.)"""
    keep = gyro_t <= gyro_t[0] + CHECK_SPAN_S
    gyro_t, gyro = gyro_t[keep], gyro[keep]
    inside = (tracker_t > gyro_t[0]) & (tracker_t < gyro_t[-1])
    tracker_t, quat = tracker_t[inside], quat[inside]
    if len(tracker_t) < 20 or len(gyro_t) < 20:
        return None
    j = np.searchsorted(tracker_t, tracker_t + 0.2)
    ok = j < len(tracker_t)
    i, j = np.flatnonzero(ok), j[ok]
    ok = tracker_t[j] - tracker_t[i] < 0.4
    i, j = i[ok], j[ok]
    integrated = _integrated(gyro_t, gyro)
    at = np.clip(np.searchsorted(gyro_t, tracker_t), 0, len(gyro_t) - 1)
    by_gyro = np.rad2deg(rotvec_from_quat(quat_multiply(quat_conjugate(integrated[at[i]]), integrated[at[j]])))
    moving = np.linalg.norm(by_gyro, axis=1) > 3.0
    if moving.sum() < 10:
        return None
    out = {}
    readings = [("as written", quat_normalize(quat)), ("scalar last", quat_normalize(quat[:, (3, 0, 1, 2)]))]
    if conjugated:
        readings.append(("conjugated", quat_conjugate(quat_normalize(quat))))
    for name, q in readings:
        turned = np.rad2deg(rotvec_from_quat(quat_multiply(quat_conjugate(q[i[moving]]), q[j[moving]])))
        out[name] = float(np.median(np.linalg.norm(turned - by_gyro[moving], axis=1)))
        if name == "as written" and not conjugated:  # a small turn's rotation vector takes the gyro's column order (a tracker's)
            for swap, columns in SWAPS.items():
                out[swap] = float(np.median(np.linalg.norm(turned - by_gyro[moving][:, columns], axis=1)))
            for k, matrix in enumerate(m for pair in signed_permutations() for m in (pair, -pair)):  # the gyro in another frame
                out[f"frame {k}"] = float(np.median(np.linalg.norm(turned - by_gyro[moving] @ matrix, axis=1)))
    return out


def gyro_frame_against_tracker(fit: Mapping[str, float]) -> FloatArray | None:
    """The signed permutation S with the tracker's turn = S^T (the gyro's), when it fits far better than the gyro as
    written and better than any other (``MISTAKE_FITS``, ``FRAME_UNIQUE``): the gyro's axes read the tracker's body
    axes as S says. None otherwise."""
    frames = sorted(((float(v), k) for k, v in fit.items() if k.startswith("frame ")))
    every = [m for pair in signed_permutations() for m in (pair, -pair)]
    (best, k), (second, _) = frames[0], frames[1]
    matrix = every[int(k.split()[1])]
    if np.allclose(matrix, np.eye(3)) or fit["as written"] < MIN_MISFIT_DEG:
        return None
    return matrix if best <= MISTAKE_FITS * fit["as written"] and best <= FRAME_UNIQUE * second else None


def pixels_against_gyro(gyro_t: FloatArray, gyro: FloatArray, pixel_t: FloatArray, uv: FloatArray, focal_px: float) -> tuple[float, float] | None:
    """Slopes of the gaze pixels' velocity (u, v) against what the head's turn makes a fixed world point do in the scene
    camera (``factors.gaze``: du/dt = f w_z, dv/dt = f w_y for a point ahead), fitted over the slow samples (fixations,
    smooth pursuit: the eye holds a world point, so the pixel follows the head; saccades are left out). About +1 each as
    written; a v written pointing down gives -1 for v. None without enough head motion to tell."""
    span = pixel_t <= pixel_t[0] + CHECK_SPAN_S
    t, uv = pixel_t[span], uv[span]
    ok = np.all(np.isfinite(uv), axis=1)
    t, uv = t[ok], uv[ok]
    if len(t) < 50:
        return None
    rate = np.stack([np.interp(t, gyro_t, gyro[:, axis]) for axis in (2, 1)], axis=1)  # w_z, w_y at the pixel times
    dt = np.diff(t)
    pixel_velocity = np.diff(uv, axis=0) / dt[:, None]
    expected = focal_px * 0.5 * (rate[1:] + rate[:-1])
    speed = np.linalg.norm(pixel_velocity, axis=1)
    slow = (dt > 0) & (dt < 0.1) & (speed < np.percentile(speed, 60))
    slopes = []
    for axis in range(2):
        x, y = expected[slow, axis], pixel_velocity[slow, axis]
        if np.sqrt(np.mean(x**2)) < focal_px * 5.0 * DEG:  # under ~5 deg/s of head turn about this axis: nothing to tell
            return None
        slopes.append(float(np.dot(x, y) / np.dot(x, x)))
    return slopes[0], slopes[1]


def _same_body(gyro: Any, accels: list[Any]) -> list[Any]:
    """The accelerometers sampled with a gyro, the one of its body alone when the names say (``thigh_gyro`` ->
    ``thigh_accel``): another body's tilt says nothing of this gyro."""
    together = [a for a in accels if len(a) == len(gyro) and np.allclose(a.t, gyro.t)]
    named = [a for a in together if a.name == gyro.name.replace("gyro", "accel")]
    return named or together


_CAUSES = {
    "deg/s": "{0:.1f} deg once x pi/180: degrees per second? set units = 'deg/s' or convert",
    "scalar last": "{0:.1f} deg with its columns read x, y, z, w: quaternions written scalar LAST? write qw, qx, qy, qz",
}


def _name_mistake(fit: Mapping[str, float], mistake: str | None, stream: str, finding: str, swapped: str | None = None) -> None:
    """Raise when one mistake fits far better than the streams as written (``MISTAKE_FITS``, ``MIN_MISFIT_DEG``): the
    named one (``mistake``) or two columns swapped (in ``swapped``'s stream, else ``stream``'s)."""
    written = fit["as written"]
    if written < MIN_MISFIT_DEG:
        return
    if mistake is not None and fit[mistake] <= MISTAKE_FITS * written:
        raise ConsistencyError(f"stream '{stream}': {finding}, " + _CAUSES[mistake].format(fit[mistake]))
    swap = min(SWAPS, key=lambda name: fit[name])
    if fit[swap] <= MISTAKE_FITS * written:
        raise ConsistencyError(f"stream '{swapped or stream}': {finding}, {fit[swap]:.1f} deg with its {swap} columns swapped: "
                               "axes written in each other's place? (or the other sensor's)")


def _body_stream(gyro: Any, candidates: list[Any], kind: str) -> Any | None:
    """The stream of ``kind`` on the gyro's body: the one named alike (``thigh_gyro`` -> ``thigh_mag``), else the only one."""
    named = [s for s in candidates if s.name == gyro.name.replace("gyro", kind)]
    if named or gyro.name != "gyro":  # a gyro named for its body (thigh_gyro) has its own streams or none
        return named[0] if named else None
    return candidates[0] if len(candidates) == 1 else None


def check_streams(streams: Mapping[str, Any], truth: Any | None = None) -> list[str]:
    """Every consistency check the streams allow; a ``ConsistencyError`` names the stream and the likely cause. Returns
    what a check could not decide or a solver leaves out (one line per warning, naming the stream)."""
    said: list[str] = [message for message, _ in repairs(streams).values()]
    live = {}
    for name, stream in streams.items():
        reason = dead_reason(stream)
        if reason is not None and stream.kind not in DROPPABLE_KINDS:
            raise ConsistencyError(f"stream '{name}': {reason}: nothing can be solved without it")
        if reason is None:
            live[name] = stream
            stuck = stuck_span(stream)
            if stuck is not None:
                said.append(f"stream '{name}': one reading repeated by {stuck[2]} samples from t = {stuck[0]:.2f} to {stuck[1]:.2f} s: "
                            "the sensor stuck there (its samples read nothing of the motion)")
    streams = live
    gyros = [s for s in streams.values() if s.kind == "gyro" and len(s) > 20]
    accels = [s for s in streams.values() if s.kind == "accel" and len(s) > 20]
    for gyro in gyros:
        mag = _body_stream(gyro, [s for s in streams.values() if s.kind == "mag" and len(s) > 20
                                  and not s.own_recording], "mag")
        if mag is not None and not _declared_units(gyro.meta):
            still = field_against_still_gyro(gyro, _body_stream(gyro, accels, "accel"), mag)
            if still is not None:
                _name_mistake(still, "deg/s", gyro.name, f"the gyro turns the field {still['as written']:.1f} deg (median) away from where "
                              f"'{mag.name}' sees it a second later on a sensor that gravity shows at rest")
        check_frames(gyro, _body_stream(gyro, _same_body(gyro, accels), "accel"), mag)  # after its units, before the gyro's own columns are blamed
        for accel in _same_body(gyro, accels):
            fit = gyro_against_gravity(gyro.t, gyro.values, accel.values)
            if fit is not None:
                _name_mistake(fit, "deg/s" if not _declared_units(gyro.meta) else None, gyro.name,
                              f"the gyro turns gravity {fit['as written']:.1f} deg away from where '{accel.name}' sees it a second later")
        if truth is not None and truth.kind == "attitude" and len(truth) > 20:
            truth_against_gyro(gyro, truth)
        for tracker in (s for s in streams.values() if s.kind == "attitude" and len(s) > 20 and s.meta.get("role") != "truth"):
            fit = tracker_against_gyro(gyro.t, gyro.values, tracker.t, tracker.values)
            if fit is not None:
                _name_mistake(fit, "scalar last", tracker.name,
                              f"the rotation over 0.2 s of '{tracker.name}' is {fit['as written']:.1f} deg (median) from the gyro's", swapped=gyro.name)
                frame = gyro_frame_against_tracker(fit)
                if frame is not None:
                    raise ConsistencyError(
                        f"stream '{gyro.name}': the rotation over 0.2 s of '{tracker.name}' is {fit['as written']:.1f} deg (median) from the "
                        f"gyro's, which reads the tracked body's axes as {describe_axes(frame)}: the gyro in another frame than the tracker's "
                        f"body? declare frame_R_sensor = {_matrix_toml(frame.T)} in [streams.{gyro.name}] (its axes into the body's), "
                        "or write its columns in the body's axes")
    if truth is not None and len(truth) and streams:
        start, end = min(float(s.t[0]) for s in streams.values()), max(float(s.t[-1]) for s in streams.values())
        if truth.t[-1] < start or truth.t[0] > end:
            raise truth_clock_error((float(truth.t[0]), float(truth.t[-1])), (start, end), float(np.median(truth.t)))
    for stream in (*gyros, *accels):
        level = saturation_level(stream.values)
        if level is not None:
            said.append(f"stream '{stream.name}': {int(clipped_samples(stream.values, level).sum())} samples at the sensor's range "
                        f"(+-{level:.4g} {'rad/s' if stream.kind == 'gyro' else 'm/s^2'}): clipped, not trusted as measurements")
    for stream in streams.values():
        if stream.kind == "ranges" and "receivers_m" in stream.meta and not _declared_units(stream.meta) and len(stream):
            receivers = np.atleast_2d(np.asarray(stream.meta["receivers_m"], dtype=float))
            extent = max(float(np.ptp(receivers, axis=0).max()), 1.0)
            typical = float(np.median(stream.values[:, 1]))
            if typical > 100.0 * extent:
                raise ConsistencyError(f"stream '{stream.name}': median range {typical:.4g} against receivers {extent:.3g} m apart: "
                                       "millimetres? convert the ranges to metres")
        if stream.kind == "pixel" and "width_px" in stream.meta and len(stream) > 10:
            values = np.asarray(stream.values, dtype=float)
            if float(stream.meta["width_px"]) > 10 and np.all(np.abs(values) <= 1.0):
                raise ConsistencyError(f"stream '{stream.name}': every pixel within [-1, 1] for a {stream.meta['width_px']:g} px wide image: "
                                       "normalised coordinates? write pixels from the image centre, u right, v up")
            for gyro in gyros:
                slopes = pixels_against_gyro(gyro.t, gyro.values, stream.t, values, float(stream.meta.get("focal_px", 500.0)))
                if slopes is not None and slopes[0] > FOLLOWS and slopes[1] < -FOLLOWS:
                    raise ConsistencyError(f"stream '{stream.name}': its v moves against the head's pitch on '{gyro.name}' (slope {slopes[1]:.2f}, "
                                           f"u {slopes[0]:.2f}): v pointing down? write v up (v = image centre row - row); or the gyro is in "
                                           "other axes than the camera's head frame (an import for another device: import pupil --device)")
                if slopes is not None and slopes[0] < -FOLLOWS and slopes[1] > FOLLOWS:
                    raise ConsistencyError(f"stream '{stream.name}': its u moves against the head's yaw on '{gyro.name}' (slope {slopes[0]:.2f}, "
                                           f"v {slopes[1]:.2f}): u pointing left? write u right (u = column - image centre column); or the "
                                           "gyro is in other axes than the camera's head frame (an import for another device: import pupil --device)")
        if stream.kind == "ranges" and len(stream) > 20:
            from .factors.gyro import GAP_PERIODS

            epochs = np.unique(stream.t)
            steps = np.diff(epochs)
            gaps = np.flatnonzero(steps > max(GAP_PERIODS * float(np.median(steps)), RANGES_GAP_S))
            if len(gaps):
                worst = int(gaps[np.argmax(steps[gaps])])
                said.append(f"stream '{stream.name}': {len(gaps)} dropout(s) of more than {RANGES_GAP_S:g} s without a range, the longest "
                            f"{steps[worst]:.2f} s after t = {epochs[worst]:.2f} s (the tracks coast there)")
        if stream.kind == "ranges" and "receivers_m" in stream.meta and len(stream) > 20:
            declared_receivers = len(np.atleast_2d(np.asarray(stream.meta["receivers_m"], dtype=float)))
            silent = sorted(set(range(declared_receivers)) - {int(r) for r in np.unique(stream.values[:, 0])})
            if silent:
                said.append(f"stream '{stream.name}': receiver(s) {', '.join(map(str, silent))} of receivers_m never heard a range "
                            "(switched off or unplugged? the others track without them)")
        if stream.kind == "ranges" and "transmitters" in stream.meta and len(stream) > 20:
            heard = _most_heard_per_epoch(stream.t, stream.values[:, 0])
            declared = int(stream.meta["transmitters"])
            if heard < declared:
                said.append(f"stream '{stream.name}': transmitters = {declared}, but no receiver hears more than {heard} in one epoch: "
                            f"{declared - heard} never transmit? (a missing transmitter's tracks are invented)")
    mags = [s for s in streams.values() if s.kind == "mag" and len(s) > 20]
    for cal in (s for s in mags if s.name.endswith("_cal")):  # a calibration recording and the stream it calibrates, said to share a unit
        for mag in (s for s in mags if s.name == cal.name[: -len("_cal")] and s.meta.get("unit") == cal.meta.get("unit")):
            ratio = float(np.median(np.linalg.norm(cal.values, axis=1)) / max(np.median(np.linalg.norm(mag.values, axis=1)), 1e-12))
            if not 1.0 / 3.0 < ratio < 3.0:  # offsets and disturbances change the norm by tens of percent, units by 10-100x
                raise ConsistencyError(f"stream '{cal.name}': its field is {ratio:.3g}x that of '{mag.name}' (median norm): another unit? "
                                       "write both in one unit")
    return said


# ------------------------------------------------------------------------------------------------ one frame for every IMU stream

AXIS_NAMES = ("x", "y", "z")
FRAME_LAG_S = 1.0
"""The still-sensor units check compares the field 1 s apart (the gyro's drift over it is far below the misfits sought)."""
FRAME_TURN_DEG = 5.0
"""...and the gyro turned at least this much between them (less tells no axis from another)."""
FRAME_UNIQUE = 0.6
"""A frame is named alone when it fits with at most this fraction of the misfit of the next best; a motion that turns
mostly about one axis (a head that looks around) leaves several frames that fit alike..."""
FRAME_CLEAR = 0.25
"""...and then the axes as written are said to be wrong only when the best fits with at most this fraction of their misfit
(the frames that fit are listed). On BROAD's translation trials, which hardly turn, the best frame fits with 0.6-0.7 of
the misfit of the axes as written, from the translation's acceleration, not the axes."""


def signed_permutations() -> list[FloatArray]:
    """The 24 signed permutation matrices up to an overall sign (M and -M carry a direction alike: the checks cannot tell
    them apart), each as the one of its pair with fewer minus signs: how axes are mislaid (swapped, negated, turned 90 deg)."""
    every = [np.eye(3)[list(order)] * np.asarray(signs)[:, None]
             for order in itertools.permutations(range(3)) for signs in itertools.product((1.0, -1.0), repeat=3)]
    out: list[FloatArray] = []
    for matrix in sorted(every, key=lambda m: int((m < 0).sum())):
        if not any(np.array_equal(-matrix, kept) for kept in out):
            out.append(matrix)
    return out


def describe_axes(stream_from_body: FloatArray) -> str:
    """``(+y, +x, +z)``: the body (gyro) axis each of a stream's x, y, z reads."""
    parts = []
    for row in np.asarray(stream_from_body):
        c = int(np.argmax(np.abs(row)))
        parts.append(f"{'+' if row[c] > 0 else '-'}{AXIS_NAMES[c]}")
    return "(" + ", ".join(parts) + ")"


def _smoothed(t: FloatArray, values: FloatArray, window_s: float = 0.2) -> FloatArray:
    """A moving mean over ``window_s`` (0.2 s takes the jolts out of gravity and the noise out of the field)."""
    return np.asarray(_moving_mean(values, max(1, int(round(window_s / float(np.median(np.diff(t))))))))


def _moving_mean(values: np.ndarray, width: int) -> np.ndarray:
    """Centred moving mean along the first axis (``width`` samples; the ends average what there is)."""
    flat = values.reshape(len(values), -1)
    total = np.vstack([np.zeros((1, flat.shape[1])), np.cumsum(flat, axis=0)])
    lo = np.clip(np.arange(len(flat)) - width // 2, 0, len(flat))
    hi = np.clip(lo + width, 0, len(flat))
    return ((total[hi] - total[lo]) / (hi - lo)[:, None]).reshape(values.shape)


FRAME_SETTINGS = ((1.0, 2.0), (2.0, 2.0))
"""(averaging window, lag) in seconds tried in turn by the frame checks: chosen on the shipped BROAD trials and the six
simulators for no false alarm (none in either) and the most signed permutations named (82 and 80 of 102 damages; 10 and
15, translations, hardly turn: nothing tells there). A longer window averages more of the body's own acceleration out,
a shorter one keeps a quick turn."""


def _frame_scorer(gyro_t: FloatArray, gyro: FloatArray, t: FloatArray, vectors: FloatArray, gravity: bool,
                  window_s: float, lag_s: float, quat: FloatArray | None = None) -> Callable[[FloatArray], tuple[float, FloatArray]] | None:
    """A function of a candidate M (``stream = M body``) giving the median misfit (deg) and the per-pair misfits (rad) of a
    vector fixed in the world (gravity, ``gravity``; else the field): each sample turned into the gyro's integration frame
    (``R M^T v``) and averaged over ``window_s`` (the body's own accelerations, steps and pedalling, average out there;
    gravity does not), two such means ``lag_s`` apart, where the gyro turned at least ``FRAME_TURN_DEG``, must point
    alike. A magnetometer's constant offset (hard iron) is fitted per candidate (linear least squares). ``quat``: the
    gyro already integrated at its times over the checked span (``_integrated``), when the caller has it. None when the
    gyro hardly turned (nothing tells)."""
    span = (t <= t[0] + CHECK_SPAN_S) & (t >= gyro_t[0]) & (t <= gyro_t[-1])
    t, vectors = t[span], vectors[span]
    if len(t) < 50:
        return None
    step = max(1, int(round(0.01 / float(np.median(np.diff(t))))))  # at most 100 Hz: the averages need no more
    t, vectors = t[::step], vectors[::step]
    if quat is None:
        quat = _integrated(gyro_t, gyro)
    turn = matrix_from_quat(quat[np.clip(np.searchsorted(gyro_t, t), 0, len(gyro_t) - 1)])
    dt = float(np.median(np.diff(t)))
    lag, width = max(1, int(round(lag_s / dt))), max(1, int(round(window_s / dt)))
    i = np.arange(width // 2, len(t) - lag - width // 2, max(1, lag // 4))
    j = i + lag
    relative = np.einsum("nba,nbc->nac", turn[i], turn[j])
    turned = np.rad2deg(np.arccos(np.clip((np.einsum("nii->n", relative) - 1.0) / 2.0, -1.0, 1.0)))
    keep = turned >= FRAME_TURN_DEG
    if keep.sum() < 5:
        return None
    i, j = i[keep], j[keep]
    # R M^T v = sum_kl M[l, k] R[:, :, k] v_l: the nine products averaged once, at the instants compared only
    mean_products = np.stack([np.stack([_moving_mean(turn[:, :, k] * vectors[:, l, None], width) for l in range(3)]) for k in range(3)])
    at_i, at_j = mean_products[:, :, i], mean_products[:, :, j]
    mean_turn = _moving_mean(turn, width)
    turn_i, turn_j = mean_turn[i], mean_turn[j]

    def score(matrix: FloatArray) -> tuple[float, FloatArray]:
        fixed_i, fixed_j = np.einsum("lk,klna->na", matrix, at_i), np.einsum("lk,klna->na", matrix, at_j)  # R M^T v, averaged
        if not gravity:  # R M^T (m - b): the offset b' = M^T b from (A_i - A_j) b' = u_i - u_j, A the averaged turns
            offset = np.linalg.lstsq((turn_i - turn_j).reshape(-1, 3), (fixed_i - fixed_j).reshape(-1), rcond=None)[0]
            fixed_i, fixed_j = fixed_i - turn_i @ offset, fixed_j - turn_j @ offset
        unit_i = fixed_i / np.maximum(np.linalg.norm(fixed_i, axis=1), 1e-12)[:, None]
        unit_j = fixed_j / np.maximum(np.linalg.norm(fixed_j, axis=1), 1e-12)[:, None]
        angles = np.deg2rad(_angle_deg(unit_i, unit_j))
        return float(np.rad2deg(np.median(angles))), angles

    return score


def frame_misfits(gyro_t: FloatArray, gyro: FloatArray, t: FloatArray, vectors: FloatArray, gravity: bool,
                  window_s: float = 1.0, lag_s: float = 2.0, quat: FloatArray | None = None) -> dict[str, Any] | None:
    """``_frame_scorer``'s misfit for every signed permutation M: ``{"misfits": [(M, deg), ...] best first, "identity":
    deg, "score": the scorer}``, or None when the gyro hardly turned."""
    score = _frame_scorer(gyro_t, gyro, t, vectors, gravity, window_s, lag_s, quat)
    if score is None:
        return None
    scored = sorted(((matrix, score(matrix)[0]) for matrix in signed_permutations()), key=lambda pair: pair[1])
    identity = next(deg for matrix, deg in scored if np.allclose(matrix, np.eye(3)))
    return {"misfits": scored, "identity": identity, "score": score}


ODD_TURN_MIN_DEG = 8.0
"""A turn by an odd angle (three free numbers) is fitted only where the axes as written are off by at least this much: on
Mobilise-D's slow walks the axes as written are off by 4-5 deg, and a fitted turn of 90-110 deg brought that to 1-2 deg."""


def fit_rotation(score: Callable[[FloatArray], tuple[float, FloatArray]], start: FloatArray) -> tuple[FloatArray, float, FloatArray]:
    """The M = exp(r) start that minimises ``score``'s per-pair misfits (robust least squares from r = 0): (M, its median
    misfit in deg, 1-sigma of r in deg per axis from the fit's Jacobian and residual spread)."""
    from scipy.optimize import least_squares

    from .geometry import quat_from_rotvec

    def matrix_of(rotvec: FloatArray) -> FloatArray:
        return np.asarray(matrix_from_quat(quat_from_rotvec(rotvec[None])[0]) @ start)

    found = least_squares(lambda r: score(matrix_of(r))[1], np.zeros(3), loss="soft_l1", f_scale=0.05, max_nfev=60)
    jac = np.asarray(found.jac)
    dof = max(1, len(found.fun) - 3)
    try:
        cov = np.linalg.inv(jac.T @ jac) * float(np.sum(found.fun**2)) / dof
        sigma = np.rad2deg(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
    except np.linalg.LinAlgError:  # a turn about an axis the motion never showed: unknown there
        sigma = np.full(3, np.inf)
    matrix = matrix_of(found.x)
    return matrix, score(matrix)[0], sigma


def fitted_rotation(fit: Mapping[str, Any]) -> tuple[FloatArray, float] | None:
    """The rotation (or reflection, from the best signed permutation's family) M that fits the stream best, by least
    squares on the per-pair misfits from the best signed permutation; (M, median misfit deg) when the axes as written are
    off by ``ODD_TURN_MIN_DEG`` and M, at least 10 deg from the identity, fits with at most ``FRAME_CLEAR`` of their
    misfit: a sensor mounted turned by an odd angle."""
    if fit["identity"] < ODD_TURN_MIN_DEG:
        return None
    matrix, deg, _ = fit_rotation(fit["score"], np.asarray(fit["misfits"][0][0]))
    departure = np.rad2deg(np.arccos(np.clip((np.trace(matrix) - 1.0) / 2.0, -1.0, 1.0))) if np.linalg.det(matrix) > 0 else 180.0
    if departure >= 10.0 and deg <= FRAME_CLEAR * fit["identity"]:
        return matrix, deg
    return None


def frames_found(streams: Mapping[str, Any]) -> list[dict[str, Any]]:
    """For ``fusegraph check``: each accelerometer and magnetometer against its body's gyro, where the motion tells: the
    misfit of its axes as written (deg), the best signed permutation and its misfit, and the rotation fitted from the
    identity (``frame_R_sensor`` to declare, the turn in deg and its 1-sigma per axis)."""
    out = []
    gyros = [s for s in streams.values() if s.kind == "gyro" and len(s) > 20]
    accels = [s for s in streams.values() if s.kind == "accel" and len(s) > 20]
    mags = [s for s in streams.values() if s.kind == "mag" and len(s) > 20 and not s.own_recording]
    for gyro in gyros:
        for stream, gravity in ((_body_stream(gyro, accels, "accel"), True), (_body_stream(gyro, mags, "mag"), False)):
            if stream is None:
                continue
            window_s, lag_s = FRAME_SETTINGS[0]
            fit = frame_misfits(gyro.t, gyro.values, stream.t, stream.values, gravity, window_s, lag_s)
            if fit is None:
                out.append({"gyro": gyro.name, "stream": stream.name, "told": False})
                continue
            matrix, deg, sigma = fit_rotation(fit["score"], np.eye(3))
            angle = float(np.rad2deg(np.arccos(np.clip((np.trace(matrix) - 1.0) / 2.0, -1.0, 1.0))))
            best, best_deg = fit["misfits"][0]
            out.append({"gyro": gyro.name, "stream": stream.name, "told": True, "misfit_as_written_deg": fit["identity"],
                        "best_axes": describe_axes(best), "best_misfit_deg": best_deg, "frame_R_sensor": matrix.T.tolist(),
                        "turn_deg": angle, "turn_sigma_deg": sigma.tolist(), "fitted_misfit_deg": deg})
    return out


def other_frame(fit: Mapping[str, Any] | None) -> list[FloatArray]:
    """The signed permutations that explain a stream far better than its axes as written, best first: one when it is
    better than any other (``MISTAKE_FITS``, ``FRAME_UNIQUE``), the few that fit alike when the motion cannot tell them
    apart but all fit far better than the axes as written (``FRAME_CLEAR``); empty when the axes as written may be right."""
    if fit is None:
        return []
    misfits = fit["misfits"]
    (best, best_deg), (_, second_deg) = misfits[0], misfits[1]
    if np.allclose(best, np.eye(3)) or fit["identity"] < MIN_MISFIT_DEG or best_deg > MISTAKE_FITS * fit["identity"]:
        return []
    if best_deg <= FRAME_UNIQUE * second_deg:
        return [np.asarray(best)]
    if best_deg <= FRAME_CLEAR * fit["identity"]:
        return [np.asarray(m) for m, deg in misfits if deg * FRAME_UNIQUE <= best_deg and not np.allclose(m, np.eye(3))][:3]
    return []


def _matrix_toml(matrix: FloatArray, digits: int = 0) -> str:
    return "[" + ", ".join("[" + ", ".join(f"{round(v, digits) + 0.0:g}" for v in row) + "]" for row in np.asarray(matrix)) + "]"


def _turn_text(matrix: FloatArray) -> str:
    """``31 deg about (0.99, 0.02, -0.1)`` (a reflection: ``a reflection``, with the matrix in the fix)."""
    if np.linalg.det(matrix) < 0:
        return "a reflection"
    angle = float(np.arccos(np.clip((np.trace(matrix) - 1.0) / 2.0, -1.0, 1.0)))
    axis = np.array([matrix[2, 1] - matrix[1, 2], matrix[0, 2] - matrix[2, 0], matrix[1, 0] - matrix[0, 1]])
    axis = axis / max(float(np.linalg.norm(axis)), 1e-12)
    return f"{np.rad2deg(angle):.0f} deg about ({', '.join(f'{a:.2f}' for a in axis)}) of its axes"


def gyro_swaps_against(gyro: Any, stream: Any, gravity: bool, window_s: float, lag_s: float) -> dict[str, float] | None:
    """``_frame_scorer``'s misfit of a stream in the gyro's frame for the gyro as written and with two columns swapped
    (``SWAPS``' keys), or None when the gyro hardly turned."""
    out = {}
    for name, rates in {"as written": gyro.values, **{swap: gyro.values[:, order] for swap, order in SWAPS.items()}}.items():
        score = _frame_scorer(gyro.t, rates, stream.t, stream.values, gravity, window_s, lag_s)
        if score is None:
            return None
        out[name] = score(np.eye(3))[0]
    return out


def check_frames(gyro: Any, accel: Any | None, mag: Any | None) -> None:
    """One frame for every IMU stream: gravity (``accel``) and the field (``mag``) must turn as the gyro says. A signed
    permutation that explains a stream far better than its axes as written is a ``ConsistencyError`` naming the stream and
    the ``frame_R_sensor`` to declare (or the gyro, when both other streams agree with each other and not with it)."""
    fits: dict[str, tuple[Any, list[FloatArray], dict[str, Any]]] = {}
    span = gyro.t <= gyro.t[0] + CHECK_SPAN_S + 1.0
    gyro_t, rates = gyro.t[span], gyro.values[span]
    quat = _integrated(gyro_t, rates)
    written: dict[str, float] = {}
    for stream, gravity in ((accel, True), (mag, False)):
        if stream is None:
            continue
        for window_s, lag_s in FRAME_SETTINGS:
            fit = frame_misfits(gyro_t, rates, stream.t, stream.values, gravity, window_s, lag_s, quat)
            if fit is not None:
                written[stream.name] = max(written.get(stream.name, 0.0), fit["identity"])
            frames = other_frame(fit)
            if not frames and fit is not None:
                turned = fitted_rotation(fit)
                if turned is not None:
                    raise ConsistencyError(
                        f"stream '{stream.name}': {'gravity' if gravity else 'the field'} turns {fit['identity']:.1f} deg (median) away from "
                        f"where the gyro '{gyro.name}' carries it, {turned[1]:.1f} deg with its axes turned by {_turn_text(turned[0])}: "
                        f"a sensor mounted turned against the gyro? declare frame_R_sensor = {_matrix_toml(turned[0].T, 4)} in "
                        f"[streams.{stream.name}] (its axes into the gyro's)")
            if frames and fit is not None:
                fits[stream.name] = (stream, frames, fit)
                break
    if not fits:  # no stream in another frame: the gyro's own columns swapped (a mirror is no frame) may still explain both
        for stream, gravity in ((s, g) for s, g in ((accel, True), (mag, False)) if s is not None and written.get(s.name, 0.0) >= ODD_TURN_MIN_DEG):
            for window_s, lag_s in FRAME_SETTINGS:
                swapped = gyro_swaps_against(gyro, stream, gravity, window_s, lag_s)
                if swapped is not None and swapped["as written"] >= ODD_TURN_MIN_DEG:  # Mobilise-D's walks: 4-5 deg as written, 1-2 swapped
                    _name_mistake(swapped, None, gyro.name, f"the gyro turns {'gravity' if gravity else 'the field'} {swapped['as written']:.1f} deg "
                                  f"(median) away from where '{stream.name}' sees it")
    odd = {name: (stream, frames, fit) for name, (stream, frames, fit) in fits.items() if frames}
    if len(odd) == 2:
        (_, f_a, _), (_, f_m, _) = odd.values()
        if len(f_a) == len(f_m) == 1 and (np.allclose(f_a[0], f_m[0]) or np.allclose(f_a[0], -f_m[0])):
            raise ConsistencyError(
                f"stream '{gyro.name}': gravity and the field both turn as if the gyro's axes were theirs turned: theirs read the gyro's "
                f"{describe_axes(f_a[0])}: the gyro in another frame than the accelerometer and magnetometer? declare frame_R_sensor = "
                f"{_matrix_toml(f_a[0])} in [streams.{gyro.name}] (its axes into theirs), or reorder its columns")
    for name, (stream, frames, fit) in odd.items():
        what = "gravity" if stream.kind == "accel" else "the field"
        best = fit["misfits"][0][1]
        axes = " or ".join(describe_axes(m) for m in frames)
        declare = (f"declare frame_R_sensor = {_matrix_toml(frames[0].T)}" if len(frames) == 1 else
                   f"the motion turns about too few axes to tell which; declare frame_R_sensor (e.g. {_matrix_toml(frames[0].T)})")
        raise ConsistencyError(
            f"stream '{name}': {what} turns {fit['identity']:.1f} deg (median) away from where the gyro '{gyro.name}' carries it, "
            f"{best:.1f} deg with its axes read as the gyro's {axes}: its axes in another frame than the gyro's "
            f"(columns swapped or negated, a chip mounted turned)? {declare} in [streams.{name}] (its axes into the gyro's), "
            "or write its columns in the gyro's axes")


def field_against_still_gyro(gyro: Any, accel: Any | None, mag: Any) -> dict[str, float] | None:
    """On a sensor that gravity shows at rest (it never tilts by ``FRAME_TURN_DEG``), the field tells what gravity cannot: the
    median misfit (deg) of the field 1 s later against the gyro's carry, as written and x pi/180 (``deg/s``: a bias in deg/s
    about the vertical read as rad/s turns the sensor tens of degrees a second). None where the sensor tilts (the gravity
    check decides there) or the gyro as written hardly turns. A magnet carried on a sensor that turns only about the
    vertical would look alike; it is not named here, only the units."""
    if accel is not None:
        up = _smoothed(accel.t, accel.values, 1.0)
        up /= np.maximum(np.linalg.norm(up, axis=1), 1e-12)[:, None]
        if float(np.max(_angle_deg(up, np.repeat(np.median(up, axis=0, keepdims=True) / np.linalg.norm(np.median(up, axis=0)), len(up), 0)))) > FRAME_TURN_DEG:
            return None
    out = {}
    for name, rate in (("as written", gyro.values), ("deg/s", gyro.values * DEG)):
        span = (mag.t <= mag.t[0] + CHECK_SPAN_S) & (mag.t >= gyro.t[0]) & (mag.t <= gyro.t[-1])
        t, field = mag.t[span], _smoothed(mag.t[span], mag.values[span])
        if len(t) < 50:
            return None
        inside = gyro.t <= t[-1] + 1.0
        quat = _integrated(gyro.t[inside], rate[inside])[np.clip(np.searchsorted(gyro.t[inside], t), 0, int(inside.sum()) - 1)]
        lag = max(1, int(round(FRAME_LAG_S / float(np.median(np.diff(t))))))
        i = np.arange(0, len(t) - lag, lag)
        j = i + lag
        carry = np.transpose(matrix_from_quat(quat_multiply(quat_conjugate(quat[i]), quat[j])), (0, 2, 1))
        predicted = np.einsum("nab,nb->na", carry, field[i])
        predicted /= np.maximum(np.linalg.norm(predicted, axis=1), 1e-12)[:, None]
        seen = field[j] / np.maximum(np.linalg.norm(field[j], axis=1), 1e-12)[:, None]
        out[name] = float(np.median(_angle_deg(predicted, seen)))
    return out


VECTOR_KINDS = ("gyro", "accel", "mag")
STUCK_S = 3.0
"""A vector stream whose every axis repeats one reading for this long (and at least ``STUCK_SAMPLES`` samples) is stuck there
(noise never repeats a float triple; BROAD's magnetometer holds a reading for 4 samples at most, its own slower rate; the
Tobii export's 10 Hz magnetometer, held at the gyro's rate, once for 1.4 s)."""
STUCK_SAMPLES = 20


def dead_reason(stream: Any) -> str | None:
    """Why a gyro, accelerometer or magnetometer stream measures nothing: every sample zero, or one constant reading."""
    if stream.kind not in VECTOR_KINDS or len(stream) < 2:
        return None
    values = np.asarray(stream.values, dtype=float)
    if not np.any(values):
        return "every sample is zero (a dead or unplugged sensor, or a column of another stream)"
    if np.all(values == values[0]):
        return f"every sample reads ({', '.join(f'{v:.4g}' for v in values[0])}): a dead or disconnected sensor"
    return None


def stuck_span(stream: Any) -> tuple[float, float, int] | None:
    """The longest stretch where a live vector stream repeats one reading (start, end, samples), when over ``STUCK_S``."""
    if stream.kind not in VECTOR_KINDS or len(stream) < STUCK_SAMPLES:
        return None
    same = np.all(np.diff(stream.values, axis=0) == 0, axis=1)
    if not same.any():
        return None
    edges = np.flatnonzero(np.diff(np.r_[0, same.astype(np.int8), 0]))
    starts, ends = edges[::2], edges[1::2]  # runs of repeats: samples starts[k] .. ends[k] read the same
    k = int(np.argmax(ends - starts))
    count = int(ends[k] - starts[k]) + 1
    first, last = float(stream.t[starts[k]]), float(stream.t[ends[k]])
    if count >= STUCK_SAMPLES and last - first >= STUCK_S:
        return first, last, count
    return None


DROPPABLE_KINDS = ("mag",)
"""A dead stream of these kinds is left out with a warning: every system that reads one runs without it (the 9-axis system
with gravity and the gyro alone; the EKFs of the papers that need it say so)."""


REPEATED_SHARE = 0.1
"""Two tags at one distance from a receiver give one range twice in an epoch where ranges are rounded (LIAS UWB, to the
millimetre: 1.2 % of its rows); a log written twice repeats half of them."""


def repeated_range_rows(stream: Any) -> np.ndarray | None:
    """Rows of a ranges stream that repeat an earlier row of the same epoch exactly (time, receiver, range) when over
    ``REPEATED_SHARE`` of the rows do: a log written twice. A mask of the rows to keep, or None."""
    if stream.kind != "ranges" or len(stream) < 2:
        return None
    rows = np.column_stack([stream.t, stream.values])
    _, first = np.unique(rows, axis=0, return_index=True)
    if len(first) >= (1.0 - REPEATED_SHARE) * len(rows):
        return None
    keep = np.zeros(len(rows), dtype=bool)
    keep[first] = True
    return keep


def repairs(streams: Mapping[str, Any]) -> dict[str, tuple[str, np.ndarray | None]]:
    """What a solver leaves out of the streams, by name: (the warning, the mask of samples kept, or None for the whole stream)."""
    out: dict[str, tuple[str, np.ndarray | None]] = {}
    for name, stream in streams.items():
        reason = dead_reason(stream)
        if reason is not None and stream.kind in DROPPABLE_KINDS:
            out[name] = (f"stream '{name}': {reason}; solved without it", None)
        keep = repeated_range_rows(stream)
        if keep is not None:
            out[name] = (f"stream '{name}': {int((~keep).sum())} of {len(keep)} rows repeat a row of their epoch exactly (time, receiver, "
                         "range): the log written twice? each kept once", keep)
    return out


def truth_clock_error(truth_s: tuple[float, float], streams_s: tuple[float, float], truth_middle_s: float | None = None) -> ConsistencyError:
    """The error of a truth whose first and last times (``truth_s``) overlap none of the streams' (``streams_s``): on another
    clock, by about the distance of its middle (``truth_middle_s``, default halfway) from theirs."""
    middle = 0.5 * (truth_s[0] + truth_s[1]) if truth_middle_s is None else truth_middle_s
    return ConsistencyError(f"truth ({truth_s[0]:.3f} .. {truth_s[1]:.3f} s) does not overlap the streams ({streams_s[0]:.3f} .. {streams_s[1]:.3f} s): "
                            f"on another clock (about {middle - 0.5 * (streams_s[0] + streams_s[1]):+.4g} s off)? write it on the sensors' clock; "
                            "nothing could be scored")


def truth_against_gyro(gyro: Any, truth: Any) -> None:
    """Truth that overlaps none of the gyro's time, or agrees with it only conjugated (written body_R_world), is a
    ``ConsistencyError`` naming ``truth``: it would score a right estimate as wrong, or nothing at all."""
    finite = np.all(np.isfinite(truth.values), axis=1)
    t, quat = truth.t[finite], truth.values[finite]
    if not len(t):
        return
    if t[-1] < gyro.t[0] or t[0] > gyro.t[-1]:
        offset = float(np.median(t) - np.median(gyro.t))
        raise ConsistencyError(f"truth ({t[0]:.3f} .. {t[-1]:.3f} s) does not overlap '{gyro.name}' ({gyro.t[0]:.3f} .. {gyro.t[-1]:.3f} s): "
                               f"on another clock (about {offset:+.4g} s off)? write it on the sensors' clock; nothing could be scored")
    fit = tracker_against_gyro(gyro.t, gyro.values, t, quat, conjugated=True)
    if fit is not None and fit["as written"] >= MIN_MISFIT_DEG and fit["conjugated"] <= MISTAKE_FITS * fit["as written"]:
        raise ConsistencyError(f"truth: its rotation over 0.2 s is {fit['as written']:.1f} deg (median) from the one of gyro '{gyro.name}', "
                               f"{fit['conjugated']:.1f} deg conjugated: written as body_R_world? write world_R_body (negate qx, qy, qz)")


SUSPECT_CLIPPED_SHARE = 0.05
"""A gyro clipped on more than this share of its samples gives a rotation that is a bound there, not a measurement: the
run is marked suspect (BROAD's fastest trials clip on none; a 250 deg/s gyro waved at 400 deg/s clipped on 37 %)."""
SUSPECT_GAP_S = 2.0
"""A gyro or accelerometer silent for longer than this is bridged by the motion model alone: the run is marked suspect."""


def suspect_reasons(streams: Mapping[str, Any], extras: Mapping[str, Any] | None = None) -> list[str]:
    """Why a run on these streams may be unreliable though it ran: a heavily clipped gyro, a long dropout bridged, and
    from the solver's own ``extras``: a batch that did not converge (the 9-axis batch's heading check, ``check =
    "suspect"``; a batch stopped at its iteration cap, ``iterations >= max_iterations``)."""
    reasons = []
    extras = extras or {}
    if extras.get("check") == "suspect":
        residual = float(extras.get("heading_residual_median_deg", float("nan")))
        reasons.append(f"the batch did not converge (median heading residual {residual:.0f} deg)")
    if "iterations" in extras and "max_iterations" in extras and int(extras["iterations"]) >= int(extras["max_iterations"]):
        reasons.append(f"the batch stopped at its cap of {int(extras['max_iterations'])} iterations without converging")
    for stream in streams.values():
        if stream.kind not in ("gyro", "accel") or len(stream) < 3:
            continue
        if stream.kind == "gyro":
            share = float(np.mean(clipped_samples(stream.values, saturation_level(stream.values))))
            if share > SUSPECT_CLIPPED_SHARE:
                reasons.append(f"'{stream.name}' clipped on {100 * share:.0f} % of its samples")
        steps = np.diff(stream.t)
        if float(np.max(steps)) > SUSPECT_GAP_S:
            worst = int(np.argmax(steps))
            reasons.append(f"'{stream.name}' silent for {steps[worst]:.1f} s after t = {stream.t[worst]:.1f} s (bridged by the motion model alone)")
    return reasons
