"""Step length from a waist IMU by the inverted pendulum (Zijlstra & Hof, "Assessment of spatio-temporal gait parameters
from trunk accelerations during human walking", Gait & Posture 18(2):1-10, 2003).

During a step the pelvis vaults over the stance leg like an inverted pendulum of length ``l`` (the sensor's height above
the ground); a vertical excursion ``h`` within the step then means a forward travel of ``2 sqrt(2 l h - h^2)`` (eq. 1 of
the paper). The paper's model underestimated the measured step length; it multiplies by a correction factor 1.25 fitted
on its own subjects (``CORRECTION``: a literature constant, not fitted to any recording here). ``h`` comes from the
vertical acceleration (gravity removed, levelled frame) integrated twice, the drift taken out by high-passes
(``PendulumConfig``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import butter, sosfiltfilt

from ..geometry import FloatArray
from .pdr import PdrConfig, vertical_horizontal
from .pdr import front_end as walking_front_end

CORRECTION = 1.25
"""Zijlstra & Hof (2003)'s correction of the pendulum's step length (their Results: the model underestimated by ~20 %)."""


@dataclass(frozen=True)
class PendulumConfig:
    """How the vertical excursion is integrated and scaled. ``bench gait`` chooses among ``PENDULUM_GRID`` by
    leave-one-participant-out; the defaults are its in-sample choice on the two Mobilise-D participants in
    ../shared/data/mobgap (stride-length MAE 0.156 m in-sample, 0.181 m leave-one-participant-out)."""

    accel_highpass_hz: float | None = 0.1
    """High-pass of the vertical acceleration before the first integral, Hz (None: none)."""
    highpass_hz: float = 1.2
    """High-pass after each integral (drift removal), Hz."""
    order: int = 4
    """Butterworth order of those high-passes (applied forward and backward: zero phase)."""
    correction: float = 1.0
    """Scale of the pendulum's step length (1: the pendulum as it is; Zijlstra & Hof's ``CORRECTION`` is the grid's other)."""


PENDULUM_GRID = tuple(PendulumConfig(0.1, hp, 4, k) for hp in (0.5, 0.7, 1.0, 1.2) for k in (1.0, CORRECTION))
"""The drift-removal corner (mobgap's reimplementation of Zijlstra's method: 0.1 Hz on the acceleration, 1 Hz after the
integral, 4th order) and the correction (none, or Zijlstra & Hof's)."""


def pelvis_excursion(vertical_m_s2: FloatArray, fs: float, highpass_hz: float = 0.5, accel_highpass_hz: float | None = None,
                     order: int = 2) -> FloatArray:
    """The pelvis's vertical displacement about its mean, m: the vertical acceleration (gravity removed) integrated twice,
    each integral high-passed (zero phase, Butterworth of ``order``) so an integration's drift does not enter."""
    sos = butter(order, highpass_hz / (fs / 2), btype="high", output="sos")
    acceleration = vertical_m_s2 if accel_highpass_hz is None else sosfiltfilt(butter(order, accel_highpass_hz / (fs / 2), btype="high", output="sos"),
                                                                                  vertical_m_s2)
    velocity = sosfiltfilt(sos, np.cumsum(acceleration) / fs)
    return np.asarray(sosfiltfilt(sos, np.cumsum(velocity) / fs))


def step_lengths(t: FloatArray, vertical_m_s2: FloatArray, steps_s: FloatArray, leg_m: float, config: PendulumConfig = PendulumConfig()) -> FloatArray:
    """Length of each step, m: the step from one contact to the next (the last contact takes its predecessor's length;
    NaN for a step longer than 1.2 s, a pause, and where the excursion exceeds the leg)."""
    steps_s = np.asarray(steps_s, dtype=float)
    out = np.full(len(steps_s), np.nan)
    if len(steps_s) < 2:
        return out
    fs = 1.0 / float(np.median(np.diff(t)))
    height = pelvis_excursion(vertical_m_s2, fs, config.highpass_hz, config.accel_highpass_hz, config.order)
    index = np.clip(np.searchsorted(t, steps_s), 0, len(t) - 1)
    for n in range(len(steps_s) - 1):
        if steps_s[n + 1] - steps_s[n] > 1.2:
            continue
        h = float(np.ptp(height[index[n] : index[n + 1] + 1]))
        if 0.0 < h < leg_m:
            out[n] = config.correction * 2.0 * np.sqrt(2.0 * leg_m * h - h * h)
    out[-1] = out[-2]
    return out


def strides(steps_s: FloatArray, step_m: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Strides as two consecutive steps (at most 2.4 s: two of the longest steps): (time of each stride's first contact,
    length m, speed m/s)."""
    steps_s, step_m = np.asarray(steps_s, dtype=float), np.asarray(step_m, dtype=float)
    if len(steps_s) < 3:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    duration = steps_s[2:] - steps_s[:-2]
    length = step_m[:-2] + step_m[1:-1]
    keep = (duration <= 2.4) & np.isfinite(length)
    return steps_s[:-2][keep], length[keep], length[keep] / duration[keep]


def waist_gait(t: FloatArray, accel_m_s2: FloatArray, gyro_rad_s: FloatArray, leg_m: float, front_end: PdrConfig,
               config: PendulumConfig = PendulumConfig()) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Steps and strides of one lower-back recording: the walking cycles (``pdr.detect_cycles`` with ``front_end``) as
    steps, the pendulum's step lengths, two steps a stride. Returns (step times, stride times, stride lengths, speeds)."""
    gravity, cycles = walking_front_end(t, accel_m_s2, gyro_rad_s, front_end)
    steps = np.array([c.t for c in cycles])
    vertical, _ = vertical_horizontal(accel_m_s2, gravity)
    return (steps, *strides(steps, step_lengths(t, vertical, steps, leg_m, config)))
