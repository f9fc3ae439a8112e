"""One module per sensor: a measurement dataclass and the gtsam factor(s) it becomes."""

from .attitude import (
    AttitudeMeasurement,
    AttitudeNoise,
    attitude_prior_factor,
    error_state_factor,
    gauss_markov_factor,
    markov_prior_factor,
)
from .gyro import GyroInterval, GyroNoise, bias_prior_factor, bias_walk_factor, integrate_gyro, preintegration_params

__all__ = [
    "AttitudeMeasurement",
    "AttitudeNoise",
    "GyroInterval",
    "GyroNoise",
    "attitude_prior_factor",
    "bias_prior_factor",
    "bias_walk_factor",
    "error_state_factor",
    "gauss_markov_factor",
    "integrate_gyro",
    "markov_prior_factor",
    "preintegration_params",
]
