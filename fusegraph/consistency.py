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

import math
from collections.abc import Mapping
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


def saturation_level(values: FloatArray) -> float | None:
    """The magnitude at which a stream clips (its range), or None: the largest absolute value of an axis when at least
    ``CLIPPED_MIN_SAMPLES`` samples of that axis sit at it (within 1e-6 of it, relative) and no axis reads beyond it (a
    range bounds every axis: a smooth periodic motion sampled in step with its period repeats its peak, and is no range)."""
    magnitude = np.abs(np.asarray(values, dtype=float))
    if magnitude.size == 0 or not np.isfinite(magnitude).any():
        return None
    top = np.nanmax(magnitude, axis=0)
    at_top = (magnitude >= top * (1.0 - 1e-6)) & (top > 0)
    clipped = (at_top.sum(axis=0) >= CLIPPED_MIN_SAMPLES) & (top >= np.max(top) * (1.0 - 1e-6))
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


def tracker_against_gyro(gyro_t: FloatArray, gyro: FloatArray, tracker_t: FloatArray, quat: FloatArray) -> dict[str, float] | None:
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
    for name, order in (("as written", (0, 1, 2, 3)), ("scalar last", (3, 0, 1, 2))):
        q = quat_normalize(quat[:, order])
        turned = np.rad2deg(rotvec_from_quat(quat_multiply(quat_conjugate(q[i[moving]]), q[j[moving]])))
        out[name] = float(np.median(np.linalg.norm(turned - by_gyro[moving], axis=1)))
        if name == "as written":  # a small turn's rotation vector takes the gyro's column order
            for swap, columns in SWAPS.items():
                out[swap] = float(np.median(np.linalg.norm(turned - by_gyro[moving][:, columns], axis=1)))
    return out


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


def check_streams(streams: Mapping[str, Any]) -> list[str]:
    """Every consistency check the streams allow; a ``ConsistencyError`` names the stream and the likely cause. Returns
    what a check could not decide (one line per warning, naming the stream)."""
    said: list[str] = []
    gyros = [s for s in streams.values() if s.kind == "gyro" and len(s) > 20]
    accels = [s for s in streams.values() if s.kind == "accel" and len(s) > 20]
    for gyro in gyros:
        for accel in _same_body(gyro, accels):
            fit = gyro_against_gravity(gyro.t, gyro.values, accel.values)
            if fit is not None:
                _name_mistake(fit, "deg/s" if not _declared_units(gyro.meta) else None, gyro.name,
                              f"the gyro turns gravity {fit['as written']:.1f} deg away from where '{accel.name}' sees it a second later")
        for tracker in (s for s in streams.values() if s.kind == "attitude" and len(s) > 20 and s.meta.get("role") != "truth"):
            fit = tracker_against_gyro(gyro.t, gyro.values, tracker.t, tracker.values)
            if fit is not None:
                _name_mistake(fit, "scalar last", tracker.name,
                              f"the rotation over 0.2 s of '{tracker.name}' is {fit['as written']:.1f} deg (median) from the gyro's", swapped=gyro.name)
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
