"""Accelerometer as a gravity direction (optional, on top of the IMU factor's specific force).

``AttitudeFactorPose3``: the measured specific force, rotated to the world, points up. Trusted less
as |a| departs from g (the body accelerates) through a sigma that grows with the departure, and a
Cauchy kernel for shocks (tapping). It complements the IMU factor: the motion priors pin the tilt
only slowly, this pins it at every keyframe when the body does not accelerate.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import gtsam
import numpy as np

from ..catalogue import KeySpec, Magnitude, SensorKind
from ..geometry import FloatArray
from .imu import GRAVITY_M_S2
from .linear import robust

_UP = gtsam.Unit3(np.array([0.0, 0.0, 1.0]))


@dataclass(frozen=True)
class GravityNoise:
    """Noise of the accelerometer's gravity direction."""

    sigma_deg: float = 3.0
    """Direction sigma at rest, degrees."""
    inflation_deg_per_m_s2: float = 15.0
    """Extra sigma per m/s^2 that |a| departs from g, degrees."""
    cauchy_k: float = 2.0
    """Cauchy kernel width in sigmas; 0 = Gaussian."""


def declared_gravity(meta: Mapping[str, Any], noise: GravityNoise) -> GravityNoise:
    """``noise`` with what an accelerometer stream's session.toml entry declares (``sigma_deg``, ``inflation_deg_per_m_s2``)."""
    return replace(noise, sigma_deg=float(meta.get("sigma_deg", noise.sigma_deg)),
                   inflation_deg_per_m_s2=float(meta.get("inflation_deg_per_m_s2", noise.inflation_deg_per_m_s2)))


def gravity_sigma_rad(noise: GravityNoise, accel_body_m_s2: FloatArray, gravity_m_s2: float = GRAVITY_M_S2) -> float:
    a = np.asarray(accel_body_m_s2, dtype=float)
    departure = abs(math.sqrt(a @ a) - gravity_m_s2)  # scalar math: one factor per keyframe, np.linalg.norm's checks cost more than the sum
    return math.radians(noise.sigma_deg + noise.inflation_deg_per_m_s2 * departure)


def _gravity_model(noise: GravityNoise, accel_body_m_s2: FloatArray, gravity_m_s2: float) -> gtsam.noiseModel.Base:
    return robust(gtsam.noiseModel.Isotropic.Sigma(2, gravity_sigma_rad(noise, accel_body_m_s2, gravity_m_s2)), noise.cauchy_k)


def gravity_factor_rot3(rot_key: int, accel_body_m_s2: FloatArray, noise: GravityNoise, gravity_m_s2: float = GRAVITY_M_S2) -> gtsam.AttitudeFactorRot3:
    """As ``gravity_factor``, on a Rot3 attitude state (world_R_body): the specific force points up."""
    model = _gravity_model(noise, accel_body_m_s2, gravity_m_s2)
    return gtsam.AttitudeFactorRot3(rot_key, _UP, model, gtsam.Unit3(np.asarray(accel_body_m_s2, dtype=float)))


def gravity_factor(pose_key: int, accel_body_m_s2: FloatArray, noise: GravityNoise, gravity_m_s2: float = GRAVITY_M_S2) -> gtsam.AttitudeFactorPose3:
    """The specific force at rest points up in the world (ENU)."""
    model = _gravity_model(noise, accel_body_m_s2, gravity_m_s2)
    return gtsam.AttitudeFactorPose3(pose_key, _UP, model, gtsam.Unit3(np.asarray(accel_body_m_s2, dtype=float)))

CATALOGUE = (
    SensorKind(
        kind="accel",
        summary="accelerometer: specific force (gravity up plus the body's acceleration)",
        columns=("ax", "ay", "az"),
        units=("m/s^2", "m/s^2", "m/s^2"),
        frame="body (sensor) axes; at rest it reads +g along the body's up axis",
        factors="gravity direction (Rot3/Pose3 AttitudeFactor) per keyframe, sigma widened as |a| departs from g, Cauchy kernel; "
        "attitude9/gaze/bicycle: also the IMU factor's specific force (gaze: its departure from g widens that factor's "
        "accelerometer density, acceleration the head's motion priors do not model)",
        keys=(
            KeySpec("sigma_deg", 3.0, "head, attitude9: gravity direction sigma at rest, degrees (attitude9 default: chosen on BROAD)"),
            KeySpec("inflation_deg_per_m_s2", 15.0, "head, attitude9: extra sigma per m/s^2 that |a| departs from g, degrees"),
            KeySpec("velocity_sigma_m_s", None, "attitude9: zero-mean velocity prior per keyframe, m/s (default: chosen on BROAD's "
                    "hand-held trials, 0.25 for both estimates; a sensor that travels, e.g. on a walker's belt, needs ~2); with sigma_deg and "
                    "inflation_deg_per_m_s2 it replaces the 9-axis system's gravity settings too"),
            KeySpec("noise_m_s2_sqrt_hz", None, "attitude9: accelerometer white-noise density, m/s^2/sqrt(Hz) (default: chosen on BROAD, "
                    "0.02 online, 0.005 batch); with a wide velocity prior declare the wider 0.02 too: stiff specific force and a "
                    "loose velocity make a near-singular system that the solver must rebuild again and again"),
            KeySpec("bias_rw_m_s2_sqrt_s", None, "attitude9: accelerometer bias random walk, m/s^2/sqrt(s) (default: chosen on BROAD, "
                    "1e-5 for both estimates; a data sheet's bias instability belongs here)"),
        ),
        magnitude=(Magnitude("still median", 4.0, 20.0, "at rest |a| should be near g = 9.81 m/s^2: in g? set units = 'g' or convert"),),
        unit_conversions={"m/s^2": 1.0, "g": 9.80665},
    ),
)
