"""One module per sensor: a measurement dataclass and the gtsam factor(s) it becomes."""

from .accel import GravityNoise, gravity_factor
from .attitude import (
    AttitudeMeasurement,
    AttitudeNoise,
    attitude_prior_factor,
    error_state_factor,
    gauss_markov_factor,
    markov_prior_factor,
)
from .gaze import FixationNoise, SceneCamera, fixation_walk, gaze_factor, wall_plane_prior
from .gyro import GyroInterval, GyroNoise, bias_prior_factor, bias_walk_factor, integrate_gyro, preintegration_params
from .imu import ImuNoise, MotionPriors
from .mag import FieldReference, MagCalibration, MagNoise, fit_mag_calibration, heading_factor
from .odometry import FixNoise, OdometryNoise, PlanarMotion, dead_reckon, fix_factor, level_pose, odometry_factor, position_factor
from .ranging import RangeNoise, range_factor
from .vehicle import NonholonomicNoise, nonholonomic_factor

__all__ = [
    "FixNoise",
    "FixationNoise",
    "NonholonomicNoise",
    "OdometryNoise",
    "PlanarMotion",
    "RangeNoise",
    "SceneCamera",
    "dead_reckon",
    "fix_factor",
    "fixation_walk",
    "gaze_factor",
    "level_pose",
    "nonholonomic_factor",
    "odometry_factor",
    "position_factor",
    "range_factor",
    "wall_plane_prior",
    "AttitudeMeasurement",
    "AttitudeNoise",
    "FieldReference",
    "GravityNoise",
    "GyroInterval",
    "GyroNoise",
    "ImuNoise",
    "MagCalibration",
    "MagNoise",
    "MotionPriors",
    "attitude_prior_factor",
    "bias_prior_factor",
    "bias_walk_factor",
    "error_state_factor",
    "fit_mag_calibration",
    "gauss_markov_factor",
    "gravity_factor",
    "heading_factor",
    "integrate_gyro",
    "markov_prior_factor",
    "preintegration_params",
]
