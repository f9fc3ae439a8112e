"""Batch smoothing: Levenberg-Marquardt over a whole session's graph, then marginal covariances."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import gtsam
import numpy as np

from ..geometry import FloatArray


@dataclass(frozen=True)
class BatchConfig:
    """Settings of the batch smoother."""

    max_iterations: int = 50
    """Levenberg-Marquardt iteration cap."""
    relative_error_tol: float = 1e-7
    """Stop when the error decreases by less than this fraction."""
    covariance: bool = True
    """Compute marginal covariances of the requested keys."""
    covariance_stride: int = 5
    """Compute them for every this many requested keys (each costs ~0.2 ms); callers interpolate."""


@dataclass
class BatchResult:
    values: gtsam.Values
    covariances: dict[int, FloatArray]
    iterations: int
    final_error: float


def solve_batch(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, marginal_keys: Iterable[int] = (), config: BatchConfig | None = None) -> BatchResult:
    """Optimise ``graph`` from ``initial``; marginal covariances for ``marginal_keys``."""
    cfg = config or BatchConfig()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.max_iterations)
    params.setRelativeErrorTol(cfg.relative_error_tol)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    values = optimizer.optimize()
    covariances: dict[int, FloatArray] = {}
    keys = list(marginal_keys)
    if cfg.covariance and keys:
        marginals = gtsam.Marginals(graph, values)
        covariances = {key: np.asarray(marginals.marginalCovariance(key)) for key in keys[:: cfg.covariance_stride]}
        if keys[-1] not in covariances:
            covariances[keys[-1]] = np.asarray(marginals.marginalCovariance(keys[-1]))
    return BatchResult(values, covariances, optimizer.iterations(), graph.error(values))
