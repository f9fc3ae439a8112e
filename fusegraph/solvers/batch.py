"""Batch smoothing: Gauss-Newton (Levenberg-Marquardt as the fallback) over a whole session's graph, then marginal covariances."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import gtsam
import numpy as np

from ..geometry import FloatArray


@dataclass(frozen=True)
class BatchConfig:
    """Settings of the batch smoother."""

    max_iterations: int = 50
    """Iteration cap (each solver's)."""
    gauss_newton: bool = True
    """With an elimination ordering: Gauss-Newton with step halving, driven from Python, whose last
    factorisation also gives the covariances; Levenberg-Marquardt only if it fails. On the 600 s realistic head
    session (seed 0) both took 3 iterations to the same optimum (cost 44179.1157), LM 7.2 s plus 1.3 s to
    relinearise and eliminate again for the covariances, Gauss-Newton 3 factorisations in all."""
    relative_error_tol: float = 1e-5
    """Stop when the error decreases by less than this fraction (1e-7 cost the 600 s head batch a fourth
    iteration, 1.8 s, that lowered the cost by 6e-6 of 4.4e4)."""
    stop_when_predicted: bool = True
    """Gauss-Newton also stops after a full step whose new cost its linear model predicted to within
    ``relative_error_tol`` (the linearisation held over the whole step, so the point is the minimum of a model that is
    right there: another step would lower the cost by about that tolerance), instead of taking that further step to see
    it. On BROAD's head sessions (the first four trials) 3, 3, 3, 4 iterations became 2, 2, 2, 3, the attitudes moved by
    at most 0.006 deg, and the batch ran 189x -> 214x real time."""
    covariance: bool = True
    """Compute marginal covariances of the requested keys."""
    covariance_stride: int = 25
    """Compute them for every this many requested keys (each costs ~0.5 ms on a 600 s head graph); callers
    interpolate. The smoother's covariance follows the sensor schedule smoothly: on head seeds 100-101 (60 s,
    realistic) the NEES was 3.2016 / 3.2014 / 3.2005 with every keyframe's / every 5th / every 25th (0.5 s with the
    20 ms head keyframes of that measurement; 1 s with today's 40 ms)."""


@dataclass
class BatchResult:
    values: gtsam.Values
    covariances: dict[int, FloatArray]
    iterations: int
    final_error: float


def solve_batch(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    marginal_keys: Iterable[int] = (),
    config: BatchConfig | None = None,
    ordering: Sequence[int] | None = None,
) -> BatchResult:
    """Optimise ``graph`` from ``initial``; marginal covariances for ``marginal_keys``.

    ``ordering`` (all keys) replaces COLAMD for both the optimisation and the covariances: a system's
    builder knows its graph's banded structure, and COLAMD is slow on dense columns.
    """
    cfg = config or BatchConfig()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(cfg.max_iterations)
    params.setRelativeErrorTol(cfg.relative_error_tol)
    elimination = None
    if ordering is not None:
        elimination = gtsam.Ordering()
        for key in ordering:
            elimination.push_back(key)
        params.setOrdering(elimination)
    tree: gtsam.GaussianBayesTree | None = None
    values: gtsam.Values | None = None
    iterations, final_error = 0, float("nan")
    if elimination is not None and cfg.gauss_newton:
        steps = _gauss_newton(graph, initial, cfg.max_iterations, cfg.relative_error_tol, elimination, cfg.stop_when_predicted)
        if steps.converged:
            values, tree, iterations, final_error = steps.values, steps.tree, steps.iterations, steps.error
    if values is None:  # no ordering, or Gauss-Newton did not converge: the damped solver
        optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
        values, iterations = optimizer.optimize(), optimizer.iterations()
        final_error = graph.error(values)
    covariances: dict[int, FloatArray] = {}
    keys = list(marginal_keys)
    if cfg.covariance and keys:
        wanted = keys[:: cfg.covariance_stride]
        if keys[-1] not in wanted:
            wanted.append(keys[-1])
        if elimination is not None:
            if tree is None:
                tree = graph.linearize(values).eliminateMultifrontal(elimination)
            covariances = {key: np.asarray(tree.marginalCovariance(key)) for key in wanted}
        else:
            marginals = gtsam.Marginals(graph, values)
            covariances = {key: np.asarray(marginals.marginalCovariance(key)) for key in wanted}
    return BatchResult(values, covariances, iterations, final_error)


@dataclass
class _Steps:
    values: gtsam.Values
    error: float
    iterations: int
    converged: bool
    tree: gtsam.GaussianBayesTree | None
    """The factorisation whose step met the tolerance (linearised one step before ``values``: a negligible step, or one its
    linear model predicted to within the tolerance)."""


def _gauss_newton(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int, relative_error_tol: float,
                  elimination: gtsam.Ordering | None = None, stop_when_predicted: bool = False) -> _Steps:
    """Gauss-Newton steps, each halved until the cost does not rise; stops when one lowers it by less than the tolerance,
    or (``stop_when_predicted``, see ``BatchConfig``) when a full step's new cost is what its linear model predicted,
    to within the tolerance.

    A step that cannot lower the cost even at 1/1024 of its length is not taken: the result says it did not converge.
    """
    values = gtsam.Values(initial)
    error = graph.error(values)
    tree = None
    for iteration in range(1, max_iterations + 1):
        linear = graph.linearize(values)
        if elimination is None:
            delta = linear.optimize()
        else:
            tree = linear.eliminateMultifrontal(elimination)
            delta = tree.optimize()
        step = 1.0
        while True:
            candidate = values.retract(delta if step == 1.0 else delta.scale(step))
            new_error = graph.error(candidate)
            if new_error <= error:
                break
            step *= 0.5
            if step < 1e-3:
                return _Steps(values, error, iteration, False, tree)
        converged = error - new_error <= relative_error_tol * max(error, 1e-12)
        if stop_when_predicted and step == 1.0 and not converged:
            converged = abs(new_error - linear.error(delta)) <= relative_error_tol * max(new_error, 1e-12)
        values, error = candidate, new_error
        if converged:
            return _Steps(values, error, iteration, True, tree)
    return _Steps(values, error, max_iterations, False, tree)


def solve_python_loop(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int = 30, relative_error_tol: float = 1e-5) -> BatchResult:
    """Gauss-Newton with step halving, driven from Python, for graphs with many ``CustomFactor``s.

    gtsam's C++ optimizers hand their own ``Values`` to every Python ``CustomFactor`` callback as a
    COPY of all variables, so one iteration costs (number of custom factors) x (number of
    variables): measured on Plaza2 (4,090 poses, 1,816 range factors) 2.7 s per iteration against
    0.13 s for the same linearise + eliminate called from Python, where the callback gets a
    reference. Same iterations, same result.
    """
    steps = _gauss_newton(graph, initial, max_iterations, relative_error_tol)
    return BatchResult(values=steps.values, covariances={}, iterations=steps.iterations, final_error=steps.error)


def chain_levenberg(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, order: gtsam.Ordering, max_iterations: int) -> gtsam.Values:
    """Levenberg-Marquardt over a chain of keyframes in the given elimination order (the 9-axis batch's passes)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    # stop when a step lowers the cost by less than 1e-5 of it: at 1e-3 the passes stopped short of the optimum and the
    # result depended on the start (BROAD trial 15: 1.61 deg total, 1.85 from a smoothed start; at 1e-6 both starts reach
    # one cost, 7583.43, and 0.81 deg, which 1e-5 reaches too). The eleven trials' mean: 2.02 -> 2.01 deg, ~5 % slower.
    params.setRelativeErrorTol(1e-5)
    # gtsam's default factor 10 made lambda oscillate 10 <-> 100 on the Cauchy pass (30 tiny steps). Gauss-Newton with step
    # halving (``_gauss_newton``, the head batch's) on BROAD's 13 trials: 3-11 steps on the first pass and 2-4 on the Cauchy
    # pass, the same final costs (to 0.01 of 1,700-9,900), the same errors and the same time (497x real time against 488x)
    params.setlambdaFactor(3.0)
    params.setOrdering(order)  # the chain's time order: COLAMD would spend longer than the solve
    return gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
