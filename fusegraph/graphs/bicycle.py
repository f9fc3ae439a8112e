"""Two bodies in one graph: the bicycle frame and the rider's thigh, coupled by their shared translation.

Each body is a 9-axis chain (``graphs.attitude9``, keys prefixed so both live in one graph: frame
``F``/``f``/``G``, thigh ``T``/``t``/``U`` for pose, velocity, bias). The coupling is one C++
``BetweenFactorVector`` per keyframe between the two velocities: the thigh IMU moves with the bicycle
give or take the pedalling (its lever arm swings at the cadence: ~0.6 m/s), so the deceleration the
frame IMU feels when braking is the one the thigh's accelerometer must also contain, with no
subtract-then-filter stages. The coupling sigma is loose while the thigh pedals and tight when it is
held still (judged from the thigh gyro over the keyframe). The frame moves along its own axis
(``factors.vehicle``, non-holonomic): without it nothing pins the tilt while riding, and the causal
thigh estimate drifted 3-5 deg before the stop. A bicycle travels: the zero-mean
position/velocity priors of a body-worn sensor are opened up; rests (start, after the stop) pin the
velocities.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..factors.imu import MotionPriors
from ..factors.mag import MagNoise
from ..factors.vehicle import NonholonomicNoise, nonholonomic_factor
from ..geometry import FloatArray
from .attitude9 import Attitude9Builder, Attitude9Model
from .increment import GraphIncrement

TRAVEL = MotionPriors(position_sigma_m=math.inf, velocity_sigma_m_s=math.inf)
"""A bicycle goes kilometres at up to ~15 m/s: no zero-mean position/velocity pseudo-measurements (the
start pose fixes the gauge; rests still pin the velocity). A 5 m position prior made the thigh 2-4 deg
worse; 50-500 m left iSAM2 with an indeterminate system."""


@dataclass(frozen=True)
class CouplingNoise:
    """How far the thigh IMU's velocity may be from the frame IMU's."""

    pedalling_m_s: float = 0.8
    """While pedalling (lever arm 0.2 m swinging +-20 deg at ~1.3 Hz), m/s."""
    still_m_s: float = 0.1
    """While the thigh is held on the frame, m/s."""
    pedalling_gyro_rad_s: float = 0.5
    """Thigh gyro RMS over a keyframe above which the thigh counts as pedalling, rad/s."""


@dataclass(frozen=True)
class BicycleModel:
    """Both bodies' 9-axis models and the coupling."""

    # the magnetometer settings these were built with (the BROAD-chosen ones were not re-checked on the cyclist)
    frame: Attitude9Model = field(default_factory=lambda: Attitude9Model(motion=TRAVEL, mag=MagNoise()))
    thigh: Attitude9Model = field(default_factory=lambda: Attitude9Model(motion=TRAVEL, mag=MagNoise()))
    coupling: CouplingNoise = field(default_factory=CouplingNoise)
    nonholonomic: NonholonomicNoise | None = field(default_factory=NonholonomicNoise)
    """The frame moves along its own axis (None = off)."""
    use_coupling: bool = True
    """False = two independent chains (an ablation: the thigh alone in the graph)."""


class CoupledBuilder:
    """Speaks the online solver's protocol for the two chains plus the coupling factors."""

    linear_keys: tuple[int, ...] = ()

    def __init__(self, model: BicycleModel, deferred_mag: bool = False) -> None:
        self.model = model
        self.frame = Attitude9Builder(model.frame, deferred_mag=deferred_mag, prefix="f")
        self.thigh = Attitude9Builder(model.thigh, deferred_mag=deferred_mag, prefix="t")
        self._coupled = 0
        self._constrained = 0
        self._oldest = 0
        self._thigh_gyro: list[FloatArray] = []

    @property
    def keyframe_t(self) -> list[float]:
        return self.thigh.keyframe_t

    @property
    def oldest_allowed_keyframe(self) -> int:
        return self._oldest

    @oldest_allowed_keyframe.setter
    def oldest_allowed_keyframe(self, k: int) -> None:
        self._oldest = self.frame.oldest_allowed_keyframe = self.thigh.oldest_allowed_keyframe = k

    @property
    def started(self) -> bool:
        return self.thigh.started and self.frame.started

    @property
    def latest_keyframe(self) -> int:
        return min(self.thigh.latest_keyframe, self.frame.latest_keyframe)

    def state_keys(self, k: int) -> tuple[int, int | None]:
        return self.thigh.X(k), self.thigh.B(k)

    def read_latest(self, isam: gtsam.ISAM2, k: int) -> tuple[gtsam.Rot3, FloatArray]:
        self.frame.read_latest(isam, k)
        return self.thigh.read_latest(isam, k)

    def set_latest(self, state: gtsam.Rot3, bias: FloatArray, /) -> None:
        """``read_latest`` already took both states."""

    def add_samples(self, t: FloatArray, thigh: tuple[FloatArray, FloatArray, FloatArray], frame: tuple[FloatArray, FloatArray, FloatArray]) -> None:
        """Synchronous samples of both IMUs: (gyro, accel, mag) each."""
        self.frame.add_samples(t, frame[0], frame[1], frame[2])
        self.thigh.add_samples(t, thigh[0], thigh[1], thigh[2])
        self._thigh_gyro.extend(np.atleast_2d(thigh[0]))

    def take(self) -> GraphIncrement:
        out = self.frame.take()
        out.extend(self.thigh.take())
        if self.model.use_coupling:
            index = self.thigh.keyframe_index
            while self._coupled <= self.latest_keyframe:
                k = self._coupled
                lo = index[k - 1] if k > 0 else 0
                gyro = np.array(self._thigh_gyro[lo : index[k] + 1])
                rms = float(np.sqrt(np.mean(np.sum(gyro**2, axis=1))))
                c = self.model.coupling
                sigma = c.pedalling_m_s if rms > c.pedalling_gyro_rad_s else c.still_m_s
                out.add(k, gtsam.BetweenFactorVector(self.frame.V(k), self.thigh.V(k), np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
                self._coupled += 1
        if self.model.nonholonomic is not None:
            while self._constrained <= self.latest_keyframe:
                k = self._constrained
                out.add(k, nonholonomic_factor(self.frame.X(k), self.frame.V(k), self.model.nonholonomic))
                self._constrained += 1
        return out
