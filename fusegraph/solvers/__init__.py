"""Solvers: online iSAM2 (re-anchored), batch Levenberg-Marquardt, and a batched multiple-model filter for many
point targets (the papers' filters and the peers' adapters are in ``fusegraph.baselines``)."""

from .batch import BatchConfig, BatchResult, solve_batch, solve_python_loop
from .multiple_model import MotionModes, PointBank
from .online import OnlineConfig, OnlineSmoother

__all__ = [
    "BatchConfig",
    "BatchResult",
    "MotionModes",
    "OnlineConfig",
    "OnlineSmoother",
    "PointBank",
    "solve_batch",
    "solve_python_loop",
]
