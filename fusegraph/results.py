"""What reports draw, below both the systems that make results and the report layer that draws them: the types a figure,
a table or a page is handed (``report/`` imports none of ``systems/`` or ``evaluation/``; ``systems/`` may import this).

A ``Trace`` is one solver's estimate on one session as a figure needs it: components over time, the truth on the same
times, the error and its 3-sigma band where the solver gives one. ``trace_of`` makes it from any ``Estimate`` or
``PointEstimate`` and the session's truth.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .estimate import Estimate, PointEstimate, Result
from .geometry import FloatArray, euler_zyx_from_quat, wrap_angle
from .session import Stream


def flatten(metrics: Mapping[str, Any], prefix: str = "") -> dict[str, float]:
    """Nested metrics as ``a.b`` -> number (lists and strings are left out)."""
    out: dict[str, float] = {}
    for key, value in metrics.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(flatten(value, name + "."))
        elif isinstance(value, bool):
            continue
        elif isinstance(value, int | float) and value is not None:
            out[name] = float(value)
    return out


WALK_METHODS = ("dead_reckoning", "ekf", "online", "batch")
"""The walking system's trajectory methods, in the order its tables and figures show them."""


@dataclass
class TrackingRun:
    """A method's output over a session."""

    positions: FloatArray
    """(K, N, 3) estimated positions, in the method's own transmitter order."""
    labels: list[list[np.ndarray]]
    """Per epoch and receiver: the method's transmitter of each distance, or -1."""
    ms_per_epoch: FloatArray
    """Processing time of every epoch, ms."""
    extras: dict[str, float] = field(default_factory=dict)
    rest_probability: FloatArray | None = None
    """(K, N) probability of the REST motion model per transmitter (fusegraph only)."""


@dataclass(frozen=True)
class WalkRun:
    """One method's trajectory: a position per event (start included)."""

    method: str
    t: FloatArray
    xyz: FloatArray
    seconds: float


@dataclass(frozen=True)
class SummaryRow:
    variant: str
    solver: str
    runs: int
    failed: int
    mean: tuple[float, ...]
    half_width_95: tuple[float, ...]
    solver_s: float
    names: tuple[str, ...] = ("azimuth", "elevation", "roll")
    """The metrics summarised (head: RMS per axis in rad; other systems: their preset's metric keys)."""
    not_applicable: str = ""
    """Why the solver cannot take this variant at all (it drops a stream the solver needs); empty when it can."""


MAX_POINTS = 2000
"""Samples kept per trace (evenly strided): a page stays light, and a screen has fewer pixels than that per curve."""


@dataclass(frozen=True)
class Trace:
    """One solver's estimate on one session, as a figure draws it."""

    solver: str
    """The solver's name (``online``, ``batch``, ``ekf``, a peer)."""
    t: FloatArray
    """Times, s, shape (N,)."""
    components: tuple[str, ...]
    """Names of the drawn components, with their unit (``azimuth_deg``, ``x_m``)."""
    values: FloatArray
    """The estimate's components, shape (N, D); NaN where it has none."""
    truth: FloatArray | None
    """The truth's components at ``t`` (nearest truth sample), shape (N, D), or None without truth."""
    error: FloatArray | None
    """Estimate minus truth per component (angles wrapped), shape (N, D), or None without truth."""
    sigma3: FloatArray | None
    """Three standard deviations per component from the solver's own covariance (attitude: about the body axes, a
    small-angle reading of the Euler error), shape (N, D), or None when the solver gives none."""


def trace_of(solver: str, estimate: Result, truth: Stream | None) -> Trace:
    """The trace of an attitude (azimuth, elevation, roll in degrees) or of points (each point's coordinates in metres),
    with the truth where its kind matches."""
    from .metrics import nearest_samples

    stride = max(1, int(np.ceil(len(estimate.t) / MAX_POINTS)))
    t = np.asarray(estimate.t[::stride], dtype=float)
    truth_values: FloatArray | None = None
    sigma3: FloatArray | None = None
    if isinstance(estimate, Estimate):
        components: tuple[str, ...] = ("azimuth_deg", "elevation_deg", "roll_deg")
        values = np.rad2deg(euler_zyx_from_quat(estimate.quat_wxyz[::stride]))
        if estimate.cov is not None:
            sigma3 = 3.0 * np.rad2deg(np.sqrt(np.clip(np.diagonal(estimate.cov[::stride], axis1=1, axis2=2)[:, ::-1], 0.0, None)))
        if truth is not None and truth.kind == "attitude" and len(truth):
            ok = np.all(np.isfinite(truth.values), axis=1)
            at = nearest_samples(truth.t[ok], t)
            truth_values = np.rad2deg(euler_zyx_from_quat(truth.values[ok][at]))
            truth_values[np.abs(truth.t[ok][at] - t) > 0.1] = np.nan  # no truth sample near: nothing to compare
    elif isinstance(estimate, PointEstimate):
        k = estimate.points.shape[1]
        components = tuple(f"{a}_m" if k == 1 else f"{a}{i}_m" for i in range(k) for a in estimate.axes)
        values = estimate.points[::stride].reshape(len(t), -1)
        if truth is not None and truth.kind == "position" and k == 1 and truth.values.shape[1] == len(estimate.axes):
            at = nearest_samples(truth.t, t)
            truth_values = np.asarray(truth.values[at], dtype=float)
            truth_values[np.abs(truth.t[at] - t) > 0.1] = np.nan
    else:
        raise TypeError(f"{solver}: no trace for a {type(estimate).__name__}")
    error = None
    if truth_values is not None:
        error = values - truth_values
        if isinstance(estimate, Estimate):
            error = np.rad2deg(wrap_angle(np.deg2rad(error)))
    return Trace(solver, t, components, values, truth_values, error, sigma3)
