"""Solvers: online iSAM2 (re-anchored), batch Levenberg-Marquardt, and the papers' EKF baselines."""

from .batch import BatchConfig, BatchResult, solve_batch
from .ekf import HeadEkf, HeadEkfConfig, run_head_ekf
from .online import OnlineConfig, OnlineSmoother

__all__ = ["BatchConfig", "BatchResult", "HeadEkf", "HeadEkfConfig", "OnlineConfig", "OnlineSmoother", "run_head_ekf", "solve_batch"]
