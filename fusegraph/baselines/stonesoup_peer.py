"""The best public peer for range association: Stone Soup's GNN and JPDA trackers on the same epochs.

Each transmitter is a Stone Soup track with a nearly-constant-velocity state (x, vx, y, vy, z, vz)
(``ConstantVelocity`` per axis). At every epoch the tracks are predicted to the emission time, then
each receiver's distances are the detections of a one-dimensional range measurement model from that
receiver (``ReceiverRange``, EKF linearisation), processed receiver after receiver at the same time
stamp:

* ``gnn``: ``DistanceHypothesiser`` (Mahalanobis distance, gate ``gate_sigmas``) and
  ``GNNWith2DAssignment``: the globally nearest assignment of distances to tracks.
* ``jpda``: ``PDAHypothesiser`` and ``JPDAwithLBP`` (loopy belief propagation: plain enumeration over
  12 tracks and 12 distances per receiver is far too slow); each track's posterior is the Gaussian
  mixture of its hypotheses reduced to one Gaussian. The soft association is scored by its most
  probable assignment, as the bench scores every method.

Tracks start from the first epoch's distances alone (``frontends.association.locate``, as fusegraph's
tracker does; never from the truth). The free settings (process noise, gate, detection probability,
clutter density) are chosen by ``fusegraph tune stonesoup_gnn`` / ``stonesoup_jpda`` on tuning seeds
(``tuned.toml``).
"""

from __future__ import annotations

import datetime
import functools
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..frontends.association import locate
from ..geometry import FloatArray
from ..records import RangeEpochs


@dataclass(frozen=True)
class StoneSoupConfig:
    """The free settings of the Stone Soup trackers (Stone Soup leaves them to the user)."""

    process_noise: float = 0.5
    """ConstantVelocity noise diffusion coefficient per axis, m^2/s^3."""
    gate_sigmas: float = 4.0
    """GNN: largest Mahalanobis distance of an assignment (missed distance), sigmas."""
    prob_detect: float = 0.95
    """JPDA: probability that a receiver hears a transmitter's direct path."""
    clutter_density: float = 1.0
    """JPDA: density of false distances (echoes) per metre of range."""
    initial_speed_sigma_m_s: float = 0.5
    """Velocity sigma of a new track, m/s."""
    initial_position_sigma_m: float = 0.02
    """Position sigma of a new track, metres."""


def tuned_config(method: str) -> StoneSoupConfig:
    """The settings ``fusegraph tune stonesoup_<method> --write`` chose (``tuned.toml``)."""
    from ..tuned import tuned

    chosen = tuned(f"stonesoup_{method}")
    fields = StoneSoupConfig.__dataclass_fields__
    return StoneSoupConfig(**{k: float(v) for k, v in chosen.items() if k in fields})


@functools.cache
def _stonesoup() -> Any:
    """Stone Soup's classes (imported on first use: the package is large)."""
    from stonesoup.base import Property
    from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement
    from stonesoup.types.array import StateVector, StateVectors

    class ReceiverRange(NonLinearGaussianMeasurement):  # type: ignore[misc]
        """The distance from a known receiver to the transmitter's position."""

        receiver: np.ndarray = Property(doc="receiver position (3,), metres")

        @property
        def ndim_meas(self) -> int:
            return 1

        def function(self, state: Any, noise: Any = False, **kwargs: Any) -> Any:
            positions = np.asarray(state.state_vector[self.mapping, :], dtype=float)
            out = np.linalg.norm(positions - self.receiver[:, None], axis=0)[None, :]
            if noise is True:
                out = out + self.rvs(num_samples=out.shape[1], **kwargs)
            elif noise is not False:
                out = out + noise
            return StateVectors(out) if out.shape[1] > 1 else StateVector(out)

        def jacobian(self, state: Any, **kwargs: Any) -> np.ndarray:
            position = np.asarray(state.state_vector[self.mapping, 0], dtype=float).ravel()
            offset = position - self.receiver
            jac = np.zeros((1, state.state_vector.shape[0]))
            jac[0, list(self.mapping)] = offset / max(float(np.linalg.norm(offset)), 1e-9)
            return jac

    return ReceiverRange


def run_stonesoup(epochs: RangeEpochs, transmitters: int, method: str = "gnn", config: StoneSoupConfig | None = None) -> Any:
    """Stone Soup's ``gnn`` or ``jpda`` tracker over the epochs; a ``systems.ultrasonic.TrackingRun``."""
    from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
    from stonesoup.dataassociator.probability import JPDAwithLBP
    from stonesoup.gater.distance import DistanceGater
    from stonesoup.hypothesiser.distance import DistanceHypothesiser
    from stonesoup.hypothesiser.probability import PDAHypothesiser
    from stonesoup.measures import Mahalanobis
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.state import GaussianState
    from stonesoup.types.track import Track
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    from ..results import TrackingRun

    if method not in ("gnn", "jpda"):
        raise ValueError(f"unknown Stone Soup tracker {method!r} (gnn or jpda)")
    cfg = config or StoneSoupConfig()
    receiver_range = _stonesoup()
    transition = CombinedLinearGaussianTransitionModel([ConstantVelocity(cfg.process_noise)] * 3)
    predictor = ExtendedKalmanPredictor(transition)
    updater = ExtendedKalmanUpdater(measurement_model=None)
    sigma2 = np.array([[epochs.range_sigma_m**2]])
    models = [receiver_range(ndim_state=6, mapping=(0, 2, 4), noise_covar=sigma2, receiver=np.asarray(r, dtype=float)) for r in epochs.receivers]
    if method == "gnn":
        hypothesiser = DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=cfg.gate_sigmas)
        associator: Any = GNNWith2DAssignment(hypothesiser)
    else:
        pda = PDAHypothesiser(predictor, updater, clutter_spatial_density=cfg.clutter_density, prob_detect=cfg.prob_detect)
        associator = JPDAwithLBP(DistanceGater(pda, Mahalanobis(), cfg.gate_sigmas))
    t0 = datetime.datetime(2000, 1, 1)

    def stamp(t: float) -> datetime.datetime:
        return t0 + datetime.timedelta(seconds=float(t))

    start = time.perf_counter()
    found = locate(epochs.receivers, epochs.ranges[0], transmitters)
    first_ms = 1e3 * (time.perf_counter() - start)
    covar = np.diag([cfg.initial_position_sigma_m**2, cfg.initial_speed_sigma_m_s**2] * 3)
    tracks = []
    for n in range(transmitters):
        p = found[n].position_m if n < len(found) else np.mean(epochs.receivers, axis=0) - [0.0, 0.0, 1.5]  # unfound: below the board
        tracks.append(Track([GaussianState(np.array([[p[0]], [0.0], [p[1]], [0.0], [p[2]], [0.0]]), covar, timestamp=stamp(epochs.t[0]))]))
    positions = np.full((len(epochs.t), transmitters, 3), np.nan)
    labels: list[list[np.ndarray]] = []
    times = []
    for k, t in enumerate(epochs.t):
        start = time.perf_counter()
        when = stamp(t)
        epoch_labels = []
        for r, heard in enumerate(epochs.ranges[k]):
            detections = [Detection(np.array([[d]]), timestamp=when, measurement_model=models[r]) for d in heard]
            order = {id(det): i for i, det in enumerate(detections)}
            hypotheses = associator.associate(tracks, set(detections), when)
            # each distance labelled with its most probable track (GNN: the one track that took it)
            label = np.full(len(heard), -1)
            best = np.full(len(heard), -np.inf)
            for n, track in enumerate(tracks):
                for hypothesis, probability in _posterior(track, hypotheses[track], updater, method == "jpda"):
                    i = order[id(hypothesis.measurement)]
                    if probability > best[i]:
                        best[i], label[i] = probability, n
            epoch_labels.append(label)
        labels.append(epoch_labels)
        positions[k] = [np.asarray(track.state_vector, dtype=float)[[0, 2, 4], 0] for track in tracks]
        times.append(1e3 * (time.perf_counter() - start) + (first_ms if k == 0 else 0.0))
    return TrackingRun(positions, labels, np.asarray(times), {})


def _posterior(track: Any, chosen: Any, updater: Any, soft: bool) -> list[tuple[Any, float]]:
    """Append the track's posterior for its hypotheses; return those with a distance and their probabilities.

    GNN (``soft`` false): one hypothesis, updated or carried as the prediction. JPDA: every hypothesis updated and
    the mixture reduced to one Gaussian by its weights.
    """
    from stonesoup.types.update import GaussianStateUpdate

    if not soft:
        track.append(updater.update(chosen) if chosen else chosen.prediction)
        return [(chosen, 1.0)] if chosen else []
    states = [updater.update(h) if h else h.prediction for h in chosen]
    means = np.hstack([np.asarray(s.state_vector, dtype=float) for s in states])
    covs = np.stack([np.asarray(s.covar, dtype=float) for s in states])
    mean, cov = _reduce(means, covs, np.array([float(h.probability) for h in chosen]))
    track.append(GaussianStateUpdate(mean, cov, chosen, states[0].timestamp))
    return [(h, float(h.probability)) for h in chosen if h]


def _reduce(means: FloatArray, covs: FloatArray, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """One Gaussian with the mixture's mean and covariance (moment matching)."""
    w = weights / weights.sum()
    mean = means @ w
    spread = means - mean[:, None]
    cov = np.einsum("k,kij->ij", w, covs) + (spread * w) @ spread.T
    return mean[:, None], cov
