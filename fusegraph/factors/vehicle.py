"""A wheeled vehicle's non-holonomic constraint: it moves along its own x axis.

In the vehicle's body frame the velocity has no sideways (y) and no vertical (z) component, give or
take slip and bumps: e = [R^T v]_{y,z}. This is what makes a bicycle frame's tilt observable while it
rides (an unaided IMU cannot tell a slope from an acceleration). gtsam has no C++ factor for it, so
it is one small ``CustomFactor`` per keyframe (not per sample) with analytic Jacobians: for a right
perturbation R Exp(w), d(R^T v) = [R^T v]x w; d(R^T v)/dv = R^T.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gtsam
import numpy as np

from ..geometry import FloatArray, skew


@dataclass(frozen=True)
class NonholonomicNoise:
    """How well the vehicle keeps to its axis."""

    lateral_m_s: float = 0.1
    """Sideways velocity sigma (slip, the rider's sway), m/s."""
    vertical_m_s: float = 0.1
    """Vertical velocity sigma (bumps), m/s."""


def nonholonomic_factor(pose_key: int, velocity_key: int, noise: NonholonomicNoise) -> gtsam.CustomFactor:
    """Sideways and vertical body-frame velocity ~ 0 (pose: world_T_body Pose3, velocity: world Vector3)."""

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[Any] | None) -> FloatArray:
        R = values.atPose3(this.keys()[0]).rotation().matrix()
        v = values.atVector(this.keys()[1])
        u = R.T @ v
        if jacobians is not None:
            jacobians[0] = np.hstack([skew(u)[1:], np.zeros((2, 3))])
            jacobians[1] = R.T[1:]
        return u[1:]

    model = gtsam.noiseModel.Diagonal.Sigmas(np.array([noise.lateral_m_s, noise.vertical_m_s]))
    return gtsam.CustomFactor(model, [pose_key, velocity_key], error)
