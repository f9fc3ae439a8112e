"""An independent gait for the walking scenario: the pelvis of an inverted-pendulum walker.

The walking scenario's first generator (``gait = "signature"``) draws each activity with the signature
the detector looks for (roll-rate period twice the vertical one up stairs, vertical swing far above the
forward one down stairs), so a confusion table on it says little about the detector. This model knows
nothing of those rules; it is built from how a pelvis moves:

* **Flat ground**: during single support the pelvis vaults over the stance leg (an inverted pendulum of
  the walker's leg length, its arc flattened by knee flexion and pelvic list to the 3-5 cm a pelvis
  really rises); the forward speed trades with height (lowest at mid-stance, where the pelvis is
  highest), the double-support transition joins two arcs at heel strike. Cadence grows with speed as a
  power law (step frequency ~1.8 v^0.45 Hz, about 2 Hz at 1.3 m/s).
* **Pelvis rotations**: obliquity (roll) and transverse rotation (yaw) once per stride, anterior tilt
  (pitch) twice, tilted back in loading response (``TILT_PHASE_RAD``), with per-walker amplitudes; the
  lateral sway towards the stance foot once per stride.
* **Stairs**: up, the stance leg lifts the body over most of each step (knee and hip extension) and
  the trunk leans forward; down, the stance leg carries the body over the step, then lowers it
  (controlled lowering) until the leading foot's contact arrests the fall (weight acceptance). The
  pelvis surges forward and sways more than on flat ground. Cadences per walker.
* **Stride-to-stride variability**: step period and length vary (AR(1), coefficient of variation ~3 %).
* **Heel-strike transients**: a damped ~18 Hz oscillation of the soft tissue at each foot contact,
  strongest going down stairs, in the accelerometer only (it moves the sensor, not the pelvis).
* **Checked against real waists**: ``bench walking`` prints the per-step medians (pelvis excursion, vertical
  RMS, vertical-to-horizontal ratio, step duration, the sagittal rotation's correlation with the vertical
  acceleration) of this gait beside UCI HAPT's (users 1-10, the same front end and code,
  ``evaluation.activity.step_statistics``); the stairs' shape constants and tilt phase below and the arc and
  cadence ranges were set so the two agree (a test), never from a detector's or classifier's score.
* **Sensor on the belt**: a fixed mounting tilt per walk (pitch up to 15 deg, roll up to 8 deg, yaw up to
  10 deg): the IMU axes are not the body's.

A walker is drawn once per seed (``Walker.draw``); the calibration walk of the same seed uses the same
walker, as a person calibrates their own gait.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..factors.imu import GRAVITY_M_S2
from ..geometry import FloatArray, matrix_from_quat, quat_from_euler_zyx


@dataclass(frozen=True)
class Walker:
    """One person's gait and how the IMU sits on their belt."""

    leg_m: float
    """Leg length (hip to floor), metres."""
    arc_fraction: float
    """Share of the stiff-leg pendulum's rise the pelvis really makes (knee flexion, pelvic list)."""
    cadence_gain: float
    """Step frequency = cadence_gain * speed^cadence_power, Hz (speed in m/s) on flat ground."""
    cadence_power: float
    """Exponent of that power law."""
    stairs_up_hz: float
    """Step frequency going up stairs, Hz."""
    stairs_down_hz: float
    """Step frequency going down stairs, Hz."""
    sway_m: float
    """Lateral pelvis sway amplitude, metres (once per stride)."""
    obliquity_deg: float
    """Pelvic obliquity (roll) amplitude, degrees (once per stride)."""
    rotation_deg: float
    """Pelvic transverse rotation (yaw oscillation) amplitude, degrees (once per stride)."""
    tilt_deg: float
    """Pelvic anterior tilt (pitch) oscillation amplitude, degrees (twice per stride)."""
    stair_lean_deg: float
    """Forward trunk lean on stairs, degrees."""
    variability: float
    """Coefficient of variation of step period and length."""
    impact_m_s2: float
    """Heel-strike transient amplitude on flat ground at 1 m/s, m/s^2."""
    mount_ypr_deg: tuple[float, float, float]
    """The IMU's mounting rotation on the belt (yaw, pitch, roll of body_R_imu), degrees."""

    @classmethod
    def draw(cls, rng: np.random.Generator) -> Walker:
        """A plausible adult: each field uniform in its ``WALKER_RANGES`` range (from the gait literature)."""
        drawn = {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in WALKER_RANGES.items()}
        mount = tuple(float(rng.uniform(-limit, limit)) for limit in MOUNT_LIMITS_DEG)
        return cls(**drawn, mount_ypr_deg=(mount[0], mount[1], mount[2]))

    @property
    def imu_R_body(self) -> FloatArray:
        """Rotation taking body-frame vectors into the IMU's axes (the transpose of body_R_imu)."""
        yaw, pitch, roll = (math.radians(a) for a in self.mount_ypr_deg)
        return matrix_from_quat(quat_from_euler_zyx(np.array([[yaw, pitch, roll]])))[0].T


WALKER_RANGES: dict[str, tuple[float, float]] = {
    "leg_m": (0.82, 0.98), "arc_fraction": (0.6, 0.9), "cadence_gain": (1.65, 1.95), "cadence_power": (0.35, 0.55),
    "stairs_up_hz": (1.45, 1.85), "stairs_down_hz": (1.65, 2.05), "sway_m": (0.015, 0.035), "obliquity_deg": (3.0, 6.0),
    "rotation_deg": (3.0, 7.0), "tilt_deg": (1.0, 2.5), "stair_lean_deg": (5.0, 12.0), "variability": (0.02, 0.04),
    "impact_m_s2": (1.0, 3.0),
}
"""Range of each ``Walker`` field a walk is drawn from (uniform)."""
MOUNT_LIMITS_DEG = (10.0, 15.0, 8.0)
"""Largest mounting yaw, pitch and roll of the belt IMU, degrees (uniform in +-)."""


class PendulumGait:
    """Per-step pelvis kinematics of a ``Walker`` (the rows the walking scenario's tour integrates)."""

    def __init__(self, walker: Walker, rng: np.random.Generator) -> None:
        self.walker = walker
        self._rng = rng
        self._wobble = 0.0  # AR(1) state of the stride-to-stride variation

    def _vary(self) -> float:
        """The next step's relative deviation (AR(1), correlation 0.5, stationary CV ``variability``)."""
        rho = 0.5
        self._wobble = rho * self._wobble + math.sqrt(1 - rho**2) * float(self._rng.normal(0.0, self.walker.variability))
        return self._wobble

    def period(self, kind: str, speed_m_s: float) -> float:
        """Duration of the next step, seconds (cadence of the activity and speed, with variation)."""
        w = self.walker
        hz = {"flat": w.cadence_gain * max(speed_m_s, 0.3) ** w.cadence_power, "stairs_up": w.stairs_up_hz, "stairs_down": w.stairs_down_hz}[kind]
        return (1.0 + self._vary()) / hz

    def step(self, kind: str, speed: float, period: float, yaw0: float, dyaw: float, z0: float, rise: float, k: int,
             scale: float) -> Callable[[float], tuple[float, ...]]:
        """Step ``k``: its rows (forward speed, yaw, z, lateral, roll, pitch, vertical elevator speed) at phase p
        (0 = heel strike), the same tuple as the tour's other motions."""
        w = self.walker
        theta = math.asin(min(0.95, 0.5 * speed * period / w.leg_m))
        # the pendulum of this step's own length: a short (eased) step already rises less, no further scale
        bounce = w.arc_fraction * w.leg_m * (1.0 - math.cos(theta))
        lean = 0.0 if kind == "flat" else w.stair_lean_deg

        def height(p: float) -> float:
            """Pelvis height above the step's start level."""
            if kind == "flat":
                # inverted pendulum: lowest at heel strike (double support), highest at mid-stance; the
                # arcs of consecutive steps join smoothly through the short double-support phase
                return bounce * math.sin(math.pi * p) ** 2
            if kind == "stairs_up":
                # lifted by the stance leg in the first UP_LIFT of the step, a small settle after
                return rise * _smoothstep(min(p / UP_LIFT, 1.0)) + 0.008 * scale * math.sin(math.pi * p) ** 2
            # stairs down: carried over the stance leg, then lowered by it in the last DOWN_LOWERING of the step
            # (controlled lowering), the fall arrested at the leading foot's contact (weight acceptance)
            carried = 0.012 * scale * math.sin(math.pi * min(p / (1.0 - DOWN_LOWERING), 1.0))
            return rise * _smoothstep(max(0.0, (p - 1.0 + DOWN_LOWERING) / DOWN_LOWERING)) + carried

        def forward(p: float) -> float:
            if kind != "flat":
                return speed * (1.0 + STAIR_SURGE * math.cos(2 * math.pi * p))
            # energy exchange: speed lowest where the pelvis is highest (v^2 + 2 g h constant), mean = speed
            v_sq = speed**2 + GRAVITY_M_S2 * bounce - 2.0 * GRAVITY_M_S2 * bounce * math.sin(math.pi * p) ** 2
            return math.sqrt(max(v_sq, 0.01 * speed**2))

        def sample(p: float) -> tuple[float, ...]:
            stride_phase = math.pi * (k + p)  # once per stride = half a turn per step
            yaw = yaw0 + dyaw * turn_progress(p) + math.radians(w.rotation_deg * scale) * math.sin(stride_phase)
            roll = math.radians(w.obliquity_deg * scale) * math.sin(stride_phase + 0.4)
            pitch = math.radians(lean + w.tilt_deg * scale * math.sin(2 * math.pi * p + (DOWN_TILT_PHASE_RAD if kind == "stairs_down" else TILT_PHASE_RAD)))
            sway = w.sway_m * scale * (STAIR_SWAY if kind != "flat" else 1.0)
            return (forward(p), yaw, z0 + height(p), sway * math.sin(stride_phase), roll, pitch, 0.0)

        return sample

    def impacts(self, t: FloatArray, step_t: FloatArray, kinds: tuple[str, ...], speeds: FloatArray) -> FloatArray:
        """Heel-strike transients (m/s^2 along the body's vertical) at every step time, shape (N,)."""
        out = np.zeros(len(t))
        gain = {"flat": 1.0, "stairs_up": 0.6, "stairs_down": 1.8}
        for ts, kind, v in zip(step_t, kinds, speeds, strict=True):
            i0 = int(np.searchsorted(t, ts))
            i1 = int(np.searchsorted(t, ts + 0.15))
            tau = t[i0:i1] - ts
            amplitude = self.walker.impact_m_s2 * gain[kind] * (max(v, 0.3) if kind == "flat" else 1.0)
            out[i0:i1] += amplitude * np.exp(-tau / 0.03) * np.sin(2 * np.pi * 18.0 * tau)
        return out


TILT_PHASE_RAD = 0.8 - math.pi
"""Phase of the pelvis's anterior tilt in a step (0 = heel strike): tilted back (posteriorly) in loading response, forward
through late stance (Perry & Burnfield, Gait Analysis, 2nd ed. 2010, the pelvis in the sagittal plane)."""
DOWN_TILT_PHASE_RAD = TILT_PHASE_RAD + math.pi / 2
"""Its phase going down stairs: a quarter step later, where UCI HAPT's waists show the sagittal rotation going with the
vertical acceleration no more than on the way up (correlation ~0.1; the flat phase gives -0.87)."""
STAIR_SURGE = 0.4
"""Forward speed oscillation on stairs, a fraction of the mean (the body moves forward mostly as the stance leg extends)."""
DOWN_LOWERING = 0.7
"""Share of a step down in which the stance leg lowers the body (ending at the next contact)."""
UP_LIFT = 0.8
"""Share of a step up in which the stance leg lifts the body (from contact)."""
STAIR_SWAY = 2.0
"""Lateral sway on stairs, times the walker's on flat ground (a wider base of support)."""


def _smoothstep(x: float) -> float:
    return x * x * (3.0 - 2.0 * x)


def turn_progress(p: float) -> float:
    """Share of a turn (or rise) done at phase p of a step: zero rate at both ends, so steps join smoothly."""
    return p - math.sin(2 * math.pi * p) / (2 * math.pi)
