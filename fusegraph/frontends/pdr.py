"""Walking analysis from a waist IMU (or a phone's accelerometer alone): steps, heading of travel, activity.

The steps of the walking-analysis paper, each a function a user can call on its own:

- ``gravity_filter``: the gravity vector in the body frame by a Kalman filter driven by the gyro
  (state g, g_{t+1} = g_t - (omega x g) dt, measured by the accelerometer with a noise that grows
  when |a| departs from g); without a gyro the prediction is a random walk (a low-pass filter).
- ``detect_cycles``: one walking cycle per step: a positive-then-negative peak pair of the
  (low-passed) vertical acceleration, and, when asked, the forward negative-then-positive pair with
  its steep rising slope.
- heading of travel: PCA of the horizontal acceleration around each cycle, the forward sign from
  the order of the vertical and forward peaks (forward acceleration follows the vertical one's
  derivative: a forward surge falls after heel strike while the vertical acceleration falls too).
- speed from the vertical peak-to-peak amplitude (``SpeedModel``, fit per person with
  ``fit_speed_model``); stride length = speed x cycle time.
- activity per cycle: stairs up when the roll rate's period is about twice the vertical period,
  stairs down when the vertical peak-to-peak is much larger than the forward one, else flat.
- ``detect_rides``: elevator rides from the strongly low-passed vertical acceleration (up = peak
  then valley, down = valley then peak), floors from its double integral.

Zero-phase filters are used (the front end looks ~1 s ahead): a step becomes known about a second
after it happened.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.signal import butter, filtfilt, find_peaks

from ..factors.imu import GRAVITY_M_S2
from ..geometry import FloatArray, wrap_angle


@dataclass(frozen=True)
class PdrConfig:
    """Front-end settings (defaults for a waist or pocket sensor)."""

    gravity_accel_sigma: float = 2.0
    """Accelerometer noise in the gravity filter, m/s^2 (gait accelerations count as noise)."""
    gravity_accel_gate: float = 3.0
    """Extra accelerometer sigma per m/s^2 that |a| departs from g."""
    gravity_process_sigma: float = 0.02
    """Process noise of the gravity state per sqrt(s) with a gyro, m/s^2."""
    gravity_process_sigma_no_gyro: float = 0.5
    """The same without a gyro (a random walk: low-pass), m/s^2 per sqrt(s)."""
    lowpass_hz: float = 2.5
    """Low-pass of the vertical and forward acceleration for peak finding, Hz."""
    peak_threshold_m_s2: float = 0.1
    """A vertical peak (positive or negative) must exceed this, m/s^2. Chosen with ``forward_slope_m_s3`` by ``bench gait``'s
    rule (step F1 against the reference system, ``frontends.gait.StepDetection``) on the two Mobilise-D participants in
    ../shared/data/mobgap, lower-back sensors like HAPT's waist phone; no HAPT recording and no simulated walk chose it
    (it was 0.3 by hand before, ``frontends.gait.HAND_SET_DETECTION``)."""
    min_period_s: float = 0.25
    """Shortest step, seconds."""
    max_period_s: float = 1.2
    """Longest step, seconds; a longer gap ends a walking bout."""
    require_forward_pair: bool = True
    """Also require the forward negative-then-positive pair (needs a usable forward axis)."""
    forward_slope_m_s3: float = 0.5
    """Steep-slope test: the forward rise from its valley to its peak, m/s^3 at least (chosen as ``peak_threshold_m_s2``;
    1.5 by hand before)."""
    pca_window_s: float = 2.0
    """Window of horizontal acceleration around a cycle for the PCA heading, seconds."""
    travel_median_cycles: int = 7
    """Heading of travel: median of the PCA direction over this many windows up to the current one
    (the sensor does not turn on the body, so the direction changes slowly; one window's PCA scatters ~10 deg)."""
    roll_window_s: float = 4.0
    """Window of roll rate around a cycle for its period (two strides or more), seconds."""
    stairs_up_ratio: tuple[float, float] = (1.6, 2.5)
    """Roll-rate period / vertical period range that means stairs up."""
    stairs_down_ratio: float = 3.0
    """Vertical peak-to-peak / forward peak-to-peak above this means stairs down."""
    ride_lowpass_hz: float = 0.3
    """Low-pass of the vertical acceleration for elevator rides, Hz."""
    ride_threshold_m_s2: float = 0.3
    """An elevator pulse exceeds this, m/s^2."""
    ride_max_s: float = 40.0
    """Longest time between a ride's two pulses, seconds."""


@dataclass(frozen=True)
class SpeedModel:
    """Walking speed = intercept + slope x vertical peak-to-peak acceleration (per person)."""

    intercept_m_s: float = 0.35
    """m/s."""
    slope_s: float = 0.12
    """(m/s) per (m/s^2)."""

    def speed(self, peak_to_peak_m_s2: float) -> float:
        return max(self.intercept_m_s + self.slope_s * peak_to_peak_m_s2, 0.0)


@dataclass(frozen=True)
class Cycle:
    """One detected walking cycle (one step)."""

    t: float
    """Time of its vertical positive peak (heel strike), seconds."""
    period_s: float
    """Cycle time, seconds."""
    vertical_pp_m_s2: float
    """Vertical peak-to-peak acceleration in the cycle."""
    forward_pp_m_s2: float
    """Forward peak-to-peak acceleration in the cycle."""
    travel_rad: float
    """Direction of travel in the body's horizontal frame (0 = body x), radians."""
    dyaw_rad: float
    """Heading change (gyro about gravity) since the previous cycle, radians; 0 without a gyro."""
    activity: str
    """flat, stairs_up or stairs_down."""


@dataclass(frozen=True)
class Ride:
    """One detected elevator ride."""

    start_s: float
    end_s: float
    up_m: float
    """Height change from the double integral of the vertical acceleration, metres."""


def _lowpass(x: FloatArray, fs: float, hz: float) -> FloatArray:
    b, a = butter(2, hz / (fs / 2))
    return np.asarray(filtfilt(b, a, x, axis=0))


def gravity_filter(t: FloatArray, accel: FloatArray, gyro: FloatArray | None, config: PdrConfig = PdrConfig()) -> FloatArray:
    """Gravity (the accelerometer's reading at rest) in the body frame per sample, shape (N, 3): a 3-state Kalman filter,
    the gravity turned by the gyro (``g <- (I - dt [omega]x) g``, process noise ``gravity_process_sigma``), the
    accelerometer as its measurement with a sigma that grows with the reading's distance from 1 g.

    Written out in scalars (the symmetric covariance as six floats) and compiled by numba (``_gravity_compiled``): a
    per-sample loop of 3 x 3 numpy products spent its time in numpy's per-call overhead (1.9 s for a 12-minute walk at
    100 Hz), the scalars in Python took 0.35 s, compiled ~3 ms (a test holds it to the matrix form)."""
    from ._gravity_compiled import gravity_loop  # numba's import (~1 s) only when a walking front end first runs

    accel = np.ascontiguousarray(accel, dtype=float)
    g0 = accel[: max(1, min(len(accel), 20))].mean(axis=0)
    q = config.gravity_process_sigma if gyro is not None else config.gravity_process_sigma_no_gyro
    rates = np.zeros((0, 3)) if gyro is None else np.ascontiguousarray(gyro, dtype=float)
    return np.asarray(gravity_loop(np.ascontiguousarray(t, dtype=float), accel, rates, gyro is not None, g0 / np.linalg.norm(g0) * GRAVITY_M_S2,
                                   q, config.gravity_accel_sigma, config.gravity_accel_gate, GRAVITY_M_S2))


def vertical_horizontal(accel: FloatArray, gravity: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Vertical acceleration (up positive, gravity removed) and horizontal acceleration in the body's
    levelled frame (axes: body x projected on the horizontal, then up x that), shapes (N,) and (N, 2)."""
    up = gravity / np.linalg.norm(gravity, axis=1, keepdims=True)
    vertical = np.einsum("ni,ni->n", accel, up) - GRAVITY_M_S2
    horizontal = accel - (vertical + GRAVITY_M_S2)[:, None] * up
    e1 = np.array([1.0, 0.0, 0.0]) - up[:, 0:1] * up
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(up, e1)
    return vertical, np.stack([np.einsum("ni,ni->n", horizontal, e1), np.einsum("ni,ni->n", horizontal, e2)], axis=1)


def _dominant_period(x: FloatArray, fs: float, lo_s: float, hi_s: float) -> float:
    """The fundamental period of ``x``: the first autocorrelation peak above half the highest one."""
    x = x - x.mean()
    n = len(x)
    if n < int(hi_s * fs) + 2 or not np.any(x):
        return math.nan
    ac = np.correlate(x, x, mode="full")[n - 1 :]
    ac = ac / ac[0]
    lo, hi = int(lo_s * fs), min(int(hi_s * fs), n - 1)
    peaks, _ = find_peaks(ac[lo:hi])
    if len(peaks) == 0:
        return math.nan
    best = float(ac[lo + peaks].max())
    for p in peaks:
        if ac[lo + p] >= 0.5 * best and ac[lo + p] > 0.2:
            return (lo + p) / fs
    return math.nan


def front_end(t: FloatArray, accel: FloatArray, gyro: FloatArray | None, config: PdrConfig = PdrConfig(),
              gravity: FloatArray | None = None) -> tuple[FloatArray, list[Cycle]]:
    """The walking front end of one recording: ``gravity_filter``'s gravity and the ``detect_cycles`` found with it (the
    filter runs once for everything after it that needs gravity; ``gravity``: its output when the caller has it, for the
    same ``gravity_*`` settings)."""
    gravity = gravity_filter(t, accel, gyro, config) if gravity is None else gravity
    return gravity, detect_cycles(t, accel, gyro, config, gravity)


def detect_cycles(t: FloatArray, accel: FloatArray, gyro: FloatArray | None = None, config: PdrConfig = PdrConfig(),
                  gravity: FloatArray | None = None) -> list[Cycle]:
    """Walking cycles with their heading of travel, amplitudes, heading change and activity
    (``gravity``: ``gravity_filter``'s output when the caller already has it)."""
    fs = 1.0 / float(np.median(np.diff(t)))
    gravity = gravity_filter(t, accel, gyro, config) if gravity is None else gravity
    vertical, horizontal = vertical_horizontal(accel, gravity)
    v = _lowpass(vertical, fs, config.lowpass_hz)
    h = _lowpass(horizontal, fs, config.lowpass_hz)
    up = gravity / GRAVITY_M_S2
    yaw = np.zeros(len(t)) if gyro is None else np.concatenate([[0.0], np.cumsum(np.einsum("ni,ni->n", gyro, up)[1:] * np.diff(t))])
    pos, _ = find_peaks(v, height=config.peak_threshold_m_s2, distance=max(1, int(config.min_period_s * fs)))
    neg, _ = find_peaks(-v, height=config.peak_threshold_m_s2, distance=max(1, int(config.min_period_s * fs)))
    dv = np.gradient(v) * fs
    half = int(config.pca_window_s * fs / 2)
    cycles: list[Cycle] = []
    recent: list[float] = []
    last_yaw = 0.0
    previous_period = math.nan
    for k, p in enumerate(pos):
        end = int(pos[k + 1]) if k + 1 < len(pos) else len(v) - 1
        period = (end - p) / fs
        if period > config.max_period_s:  # the last step of a bout: take the previous cycle's time
            period = previous_period if not math.isnan(previous_period) else config.max_period_s
            end = min(int(p + period * fs), len(v) - 1)
        j = np.searchsorted(neg, p)
        if j >= len(neg) or neg[j] >= end:
            continue  # no negative peak before the next positive one: not a step
        lo, hi = max(0, p - half), min(len(v), p + half)
        window = h[lo:hi]
        cov = np.cov(window.T)
        w, vecs = np.linalg.eigh(cov)
        axis = vecs[:, -1]
        forward = window @ axis
        # the forward surge follows the vertical acceleration's derivative (see the module docstring)
        if float(np.dot(forward - forward.mean(), dv[lo:hi])) < 0:
            axis = -axis
        # the sensor does not turn on the body: the median over recent cycles is the direction used
        # (one window's PCA scatters ~10 deg, and a turn's centripetal acceleration can take it over)
        recent.append(float(math.atan2(axis[1], axis[0])))
        travel = _circular_median(recent[-config.travel_median_cycles :])
        axis = np.array([math.cos(travel), math.sin(travel)])
        f_cycle = h[p:end] @ axis
        if len(f_cycle) < 3:
            continue
        if config.require_forward_pair:
            # a speed change between steps adds a ramp to the forward acceleration; the gait surge is
            # periodic (equal at both ends of the cycle), so the line through the ends is taken out
            f_cycle = f_cycle - np.linspace(f_cycle[0], f_cycle[-1], len(f_cycle)) + f_cycle[0]
            i_min = int(np.argmin(f_cycle))
            i_max = i_min + int(np.argmax(f_cycle[i_min:]))
            rise = (f_cycle[i_max] - f_cycle[i_min]) / max((i_max - i_min) / fs, 1.0 / fs)
            if i_max == i_min or rise < config.forward_slope_m_s3:
                continue
        v_pp = float(v[p:end].max() - v[p:end].min())
        f_pp = float(f_cycle.max() - f_cycle.min())
        activity = "flat"
        if gyro is not None:
            roll_axis = np.array([axis[0], axis[1]])
            # roll = rotation about the travel direction, taken in the levelled body frame
            r_lo, r_hi = max(0, p - int(config.roll_window_s * fs / 2)), min(len(v), p + int(config.roll_window_s * fs / 2))
            roll_rate = gyro[r_lo:r_hi, 0] * roll_axis[0] + gyro[r_lo:r_hi, 1] * roll_axis[1]
            roll_period = _dominant_period(roll_rate, fs, config.min_period_s, 2.5)
            ratio = roll_period / period if period > 0 else math.nan
            if config.stairs_up_ratio[0] <= ratio <= config.stairs_up_ratio[1]:
                activity = "stairs_up"
        if activity == "flat" and f_pp > 0 and v_pp / f_pp > config.stairs_down_ratio:
            activity = "stairs_down"
        dyaw = float(yaw[p] - last_yaw)  # the first cycle: since the start (turns in place included)
        last_yaw = float(yaw[p])
        previous_period = period
        cycles.append(Cycle(t=float(t[p]), period_s=period, vertical_pp_m_s2=v_pp, forward_pp_m_s2=f_pp,
                            travel_rad=travel, dyaw_rad=dyaw, activity=activity))
    return cycles


def _circular_median(angles: list[float]) -> float:
    """Median of angles taken as offsets from the newest one (safe across +-pi)."""
    ref = angles[-1]
    return float(ref + np.median(wrap_angle(np.array(angles) - ref)))


def fit_speed_model(cycles: list[Cycle], bouts: FloatArray) -> SpeedModel:
    """Least squares speed = a + b pp over the cycles of legs walked at known speeds (rows start, end, speed)."""
    x, y = [], []
    for c in cycles:
        for start, end, speed in bouts:
            if start <= c.t < end:
                x.append(c.vertical_pp_m_s2)
                y.append(speed)
    if len(x) < 4:
        raise ValueError(f"only {len(x)} cycles fall inside the calibration legs: need at least 4")
    slope, intercept = np.polyfit(np.array(x), np.array(y), 1)
    return SpeedModel(intercept_m_s=float(intercept), slope_s=float(slope))


def detect_rides(t: FloatArray, accel: FloatArray, gyro: FloatArray | None, cycles: list[Cycle], config: PdrConfig = PdrConfig(),
                 gravity: FloatArray | None = None) -> list[Ride]:
    """Elevator rides: a pulse and the opposite pulse of the strongly low-passed vertical acceleration
    while no walking cycle happens; the height change is the double integral between them."""
    fs = 1.0 / float(np.median(np.diff(t)))
    gravity = gravity_filter(t, accel, gyro, config) if gravity is None else gravity
    vertical, _ = vertical_horizontal(accel, gravity)
    low = _lowpass(vertical, fs, config.ride_lowpass_hz)
    step_t = np.array([c.t for c in cycles])
    peaks, _ = find_peaks(np.abs(low), height=config.ride_threshold_m_s2, distance=int(1.0 * fs))
    rides: list[Ride] = []
    used = -1
    for a_i, a in enumerate(peaks):
        if a <= used:
            continue
        for b in peaks[a_i + 1 :]:
            if (t[b] - t[a]) > config.ride_max_s:
                break
            if np.sign(low[b]) == np.sign(low[a]):
                continue
            # no steps during the ride
            if np.any((step_t > t[a] - 1.0) & (step_t < t[b] + 1.0)):
                break
            # integrate from where the first pulse starts to where the second ends
            lo = a
            while lo > 0 and abs(low[lo]) > 0.05:
                lo -= 1
            hi = b
            while hi < len(low) - 1 and abs(low[hi]) > 0.05:
                hi += 1
            seg = vertical[lo:hi] - np.median(vertical[max(0, lo - int(fs)) : lo + 1])
            vel = np.cumsum(seg) / fs
            vel -= np.linspace(0.0, vel[-1], len(vel))  # the car is at rest at both ends
            up = float(np.sum(vel) / fs)
            rides.append(Ride(start_s=float(t[lo]), end_s=float(t[hi]), up_m=up))
            used = int(b)
            break
    return rides


PHONE = PdrConfig(require_forward_pair=False, peak_threshold_m_s2=0.5)
"""Accelerometer-only phone (Oxford): vertical peak pairs only (a pocket has no steady forward axis). Its peak threshold
was set by hand with the Oxford recordings at hand; ``bench walking`` chooses it from ``PHONE_PEAK_THRESHOLDS_M_S2`` by
leave-one-recording-out on them, and every fold chose 0.5 m/s^2 (the counts are cross-validated)."""
PHONE_PEAK_THRESHOLDS_M_S2 = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 1.0, 1.5, 2.0)
"""The phone's peak thresholds ``bench walking`` tries (``[steps] peak_threshold_m_s2``); a tie goes to the first."""


def declared_number(table: str, key: str, value: Any, least: float = 0.0) -> float:
    """A number a session declares in ``[table] key``, at least ``least``; a ValueError naming the key otherwise."""
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"[{table}] {key} = {value!r}: not a number") from None
    if not number >= least:  # NaN too
        raise ValueError(f"[{table}] {key} = {value!r}: must be at least {least:g}")
    return number


def phone_config(meta: Mapping[str, Any]) -> PdrConfig:
    """``PHONE`` with the peak threshold a session declares (``[steps] peak_threshold_m_s2``), which ``--solver steps``
    reads."""
    declared = meta.get("steps", {}).get("peak_threshold_m_s2")
    return PHONE if declared is None else replace(PHONE, peak_threshold_m_s2=declared_number("steps", "peak_threshold_m_s2", declared))


def step_times(t: FloatArray, accel: FloatArray, config: PdrConfig = PHONE) -> FloatArray:
    """Times of the walking cycles (steps) in an accelerometer-only recording, seconds."""
    return np.array([c.t for c in detect_cycles(t, accel, None, config)], dtype=float)


def count_steps(t: FloatArray, accel: FloatArray, config: PdrConfig = PHONE) -> int:
    """Walking cycles (steps) in an accelerometer-only recording."""
    return len(step_times(t, accel, config))
