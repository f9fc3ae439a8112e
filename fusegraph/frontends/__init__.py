"""Signal processing that makes measurements from raw streams."""

from .association import assign_ranges, locate, trilaterate
from .pdr import Cycle, PdrConfig, Ride, SpeedModel, detect_cycles, detect_rides, fit_speed_model, gravity_filter

__all__ = [
    "Cycle",
    "PdrConfig",
    "Ride",
    "SpeedModel",
    "assign_ranges",
    "detect_cycles",
    "detect_rides",
    "fit_speed_model",
    "gravity_filter",
    "locate",
    "trilaterate",
]
