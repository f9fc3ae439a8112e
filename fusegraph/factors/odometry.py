"""Planar odometry on level poses: a walker's detected steps and a vehicle's wheel odometry.

A state is a ``gtsam.Pose3`` ``world_T_body`` held level (roll and pitch pinned near zero by the
factors), so one representation carries floors (``z``) for a walker and stays cheap for a vehicle.
An odometry measurement is the displacement from one state to the next in the FIRST state's
frame (forward, left, up) plus the heading change; it becomes a C++ ``BetweenFactorPose3`` whose
sigmas grow with the distance travelled. An absolute fix (image match) is a ``PriorFactorPose3``
with a robust kernel, since some matches are wrong by metres; a map constraint (an elevator's
known position) is a ``GPSFactor`` on the position alone.

World frame: ENU, yaw about +z from +x (east), radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gtsam
import numpy as np

from ..catalogue import KeySpec, SensorKind
from ..geometry import FloatArray


@dataclass(frozen=True)
class PlanarMotion:
    """One odometry increment, expressed in the frame of the state it starts from."""

    forward_m: float
    """Displacement along the body's x axis (heading direction), metres."""
    left_m: float = 0.0
    """Displacement along the body's y axis, metres."""
    up_m: float = 0.0
    """Height change, metres (stairs, an elevator ride)."""
    dyaw_rad: float = 0.0
    """Heading change, radians, counter-clockwise seen from above."""


@dataclass(frozen=True)
class OdometryNoise:
    """How much an odometry increment is trusted; sigmas grow with the distance covered."""

    distance_frac: float = 0.05
    """Sigma of the along-track displacement per metre travelled (step-length or wheel-scale error)."""
    lateral_frac: float = 0.05
    """Sigma of the cross-track displacement per metre travelled."""
    floor_m: float = 0.01
    """Smallest translation sigma, metres (so a zero-length increment keeps a finite sigma)."""
    yaw_rad: float = math.radians(0.5)
    """Heading-change sigma per increment, radians (gyro noise and bias over one step)."""
    yaw_frac: float = 0.02
    """Extra heading-change sigma per radian turned (gyro scale error)."""
    vertical_m: float = 0.02
    """Sigma of the height change, metres."""
    tilt_rad: float = 1e-3
    """Sigma holding roll and pitch level, radians (the states are planar poses)."""


@dataclass(frozen=True)
class FixNoise:
    """An absolute fix's trust (image match, map); the kernel keeps wrong ones from pulling."""

    position_m: float = 0.5
    """Horizontal position sigma, metres."""
    heading_rad: float = math.radians(5.0)
    """Heading sigma, radians."""
    height_m: float = 0.2
    """Height sigma, metres."""
    kernel: str = "cauchy"
    """Robust kernel: 'cauchy', 'huber' or 'none'."""
    kernel_width: float = 1.0
    """Kernel width in whitened units (sigmas)."""


def level_pose(x_m: float, y_m: float, z_m: float, yaw_rad: float) -> gtsam.Pose3:
    """A level ``world_T_body`` from position and heading."""
    return gtsam.Pose3(gtsam.Rot3.Yaw(yaw_rad), np.array([x_m, y_m, z_m], dtype=float))


def yaw_of(pose: gtsam.Pose3) -> float:
    """Heading of a (near-)level pose, radians in (-pi, pi]."""
    return float(pose.rotation().yaw())


def robust(model: gtsam.noiseModel.Base, kernel: str, width: float) -> gtsam.noiseModel.Base:
    """Wrap a Gaussian model in the named M-estimator ('none' returns it unchanged)."""
    if kernel == "none":
        return model
    estimators = {"cauchy": gtsam.noiseModel.mEstimator.Cauchy, "huber": gtsam.noiseModel.mEstimator.Huber}
    if kernel not in estimators:
        raise ValueError(f"unknown robust kernel {kernel!r}: use one of cauchy, huber, none")
    return gtsam.noiseModel.Robust.Create(estimators[kernel](width), model)


def odometry_sigmas(motion: PlanarMotion, noise: OdometryNoise) -> FloatArray:
    """Sigmas in Pose3 tangent order (roll, pitch, yaw, forward, left, up)."""
    distance = math.hypot(motion.forward_m, motion.left_m)
    yaw = math.hypot(noise.yaw_rad, noise.yaw_frac * abs(motion.dyaw_rad))
    along = max(noise.distance_frac * distance, noise.floor_m)
    across = max(noise.lateral_frac * distance, noise.floor_m)
    return np.array([noise.tilt_rad, noise.tilt_rad, yaw, along, across, noise.vertical_m])


def odometry_factor(from_key: int, to_key: int, motion: PlanarMotion, noise: OdometryNoise) -> gtsam.BetweenFactorPose3:
    """``from^-1 * to`` = the measured increment, with distance-scaled sigmas."""
    # the measurement's translation is in the first state's frame: a Pose3 between factor's convention
    delta = gtsam.Pose3(gtsam.Rot3.Yaw(motion.dyaw_rad), np.array([motion.forward_m, motion.left_m, motion.up_m]))
    return gtsam.BetweenFactorPose3(from_key, to_key, delta, gtsam.noiseModel.Diagonal.Sigmas(odometry_sigmas(motion, noise)))


def fix_factor(key: int, world_T_body: gtsam.Pose3, noise: FixNoise, tilt_rad: float = 1e-3) -> gtsam.PriorFactorPose3:
    """An absolute position + heading fix, robust (some image matches are wrong by metres)."""
    sigmas = np.array([tilt_rad, tilt_rad, noise.heading_rad, noise.position_m, noise.position_m, noise.height_m])
    model = robust(gtsam.noiseModel.Diagonal.Sigmas(sigmas), noise.kernel, noise.kernel_width)
    return gtsam.PriorFactorPose3(key, world_T_body, model)


def position_factor(key: int, world_t_body: FloatArray, sigmas_m: FloatArray) -> gtsam.GPSFactor:
    """A known position with no heading information (a map constraint: the elevator's position)."""
    return gtsam.GPSFactor(key, np.asarray(world_t_body, dtype=float), gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas_m, dtype=float)))


def dead_reckon(start: gtsam.Pose3, motions: list[PlanarMotion]) -> list[gtsam.Pose3]:
    """Compose the increments from a start pose: the odometry-only trajectory (start included)."""
    poses = [start]
    for m in motions:
        poses.append(poses[-1].compose(gtsam.Pose3(gtsam.Rot3.Yaw(m.dyaw_rad), np.array([m.forward_m, m.left_m, m.up_m]))))
    return poses

CATALOGUE = (
    SensorKind(
        kind="wheel_odometry",
        summary="a vehicle's wheel odometry: distance and heading change per interval (row i = the motion from row i-1's time; "
        "the first row is the start)",
        columns=("distance_m", "dyaw_rad"),
        units=("m", "rad"),
        frame="body: forward along the heading; dyaw counter-clockwise seen from above",
        factors="BetweenFactorPose3 between consecutive level poses, sigmas growing with the distance",
        keys=(
            KeySpec("distance_frac", 0.02, "sigma of the distance per metre travelled (wheel scale)"),
            KeySpec("lateral_frac", 0.02, "sigma of the sideways slip per metre travelled"),
            KeySpec("floor_m", 0.005, "smallest translation sigma, m"),
            KeySpec("yaw_sigma_deg", 0.1, "heading-change sigma per interval, degrees"),
            KeySpec("yaw_frac", 0.02, "extra heading-change sigma per radian turned"),
        ),
    ),
    SensorKind(
        kind="pose",
        summary="absolute fix (image match): position and heading; some may be wrong",
        columns=("x", "y", "z", "yaw"),
        units=("m", "m", "m", "rad"),
        frame="world (ENU); yaw from east, counter-clockwise",
        factors="PriorFactorPose3 on the step state at the fix time with a robust (Cauchy) kernel",
    ),
    SensorKind(
        kind="position",
        summary="a position (truth of a walk or a gaze point, a motion-capture track)",
        columns=("x", "y", "z"),
        units=("m", "m", "m"),
        frame="world (ENU unless the session says)",
        factors="GPSFactor (position prior) where a system uses it as a measurement; otherwise truth for scoring",
    ),
)
