"""The papers' filters and searches (the head EKFs, the 9-axis EKF, the gaze EKF, the combinatorial ultrasonic
search) and the peers' adapters (VQF, Stone Soup): each consumes the same Session a preset's own solvers do."""

from .ekf import HeadEkf, HeadEkfConfig, run_head_ekf
from .ekf9 import Ekf9Config, run_ekf9
from .ekf_gaze import GazeEkfConfig, run_gaze_ekf

__all__ = ["Ekf9Config", "GazeEkfConfig", "HeadEkf", "HeadEkfConfig", "run_ekf9", "run_gaze_ekf", "run_head_ekf"]
