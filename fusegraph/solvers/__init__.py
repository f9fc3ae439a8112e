"""Solvers: online iSAM2 (re-anchored), batch Levenberg-Marquardt, the papers' EKF baselines, and a batched
multiple-model filter for many point targets."""

from .batch import BatchConfig, BatchResult, solve_batch, solve_python_loop
from .ekf import HeadEkf, HeadEkfConfig, run_head_ekf
from .ekf9 import Ekf9Config, run_ekf9
from .ekf_gaze import GazeEkfConfig, run_gaze_ekf
from .multiple_model import MotionModes, PointBank
from .online import OnlineConfig, OnlineSmoother

__all__ = [
    "BatchConfig",
    "BatchResult",
    "Ekf9Config",
    "GazeEkfConfig",
    "HeadEkf",
    "HeadEkfConfig",
    "MotionModes",
    "OnlineConfig",
    "OnlineSmoother",
    "PointBank",
    "run_ekf9",
    "run_gaze_ekf",
    "run_head_ekf",
    "solve_batch",
    "solve_python_loop",
]
