"""Every system's simulator by name: ``SIMULATORS[system].simulate(seed, duration_s=None, **options) -> Session``.

Found by system name (``fusegraph simulate``, ``report`` over seeds, ``ablate``), so a preset never imports a simulator.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..session import Session


@dataclass(frozen=True)
class Simulator:
    """How one system's sessions are simulated."""

    simulate: Callable[..., Session]
    """``simulate(seed, duration_s=None, **options) -> Session`` with truth."""
    default_duration_s: float
    """Seconds ``simulate`` writes when no duration is given (NaN: the scenario's own length)."""
    min_duration_s: float = 1.0
    """Shortest simulation the system's scoring can use, seconds."""
    options: tuple[str, ...] = ()
    """Options of ``simulate`` beyond seed and duration that the CLI may pass (others are an error)."""
    profiles: tuple[str, ...] = ("realistic",)
    """Sensor error profiles it can simulate (the first is the default)."""


def _head_simulate(seed: int, duration_s: float | None = None, **options: Any) -> Session:
    from .head import simulate_head

    return simulate_head(seed, duration_s=duration_s or 10.0, **options)


def _attitude9_simulate(seed: int, duration_s: float | None = None, **options: Any) -> Session:
    from .attitude9 import simulate_attitude9

    return simulate_attitude9(seed, duration_s=duration_s or 10.0, **options)


def _gaze_simulate(seed: int, duration_s: float | None = None, **options: Any) -> Session:
    from .gaze import gaze_session

    return gaze_session(seed, duration_s=duration_s or 40.0, **{k: v for k, v in options.items() if v is not None})


def _bicycle_simulate(seed: int, duration_s: float | None = None, **options: Any) -> Session:
    from .bicycle import bicycle_session

    return bicycle_session(seed, duration_s=duration_s or 40.0, **options)


def _walking_simulate(seed: int, duration_s: float | None = None, **options: Any) -> Session:
    from .walking import walking_session

    session = walking_session(seed, **{k: v for k, v in options.items() if v is not None})
    if duration_s is not None:
        session = _clip(session, duration_s)
    return session


def _ultrasonic_simulate(seed: int, duration_s: float | None = None, **options: Any) -> Session:
    from ..records import session_from_epochs
    from .ultrasonic import simulate_ultrasonic

    epochs = simulate_ultrasonic(seed, duration_s=duration_s or 10.0, **options)
    return session_from_epochs(epochs, {"scenario": "ultrasonic", "seed": seed})


def _clip(session: Session, duration_s: float) -> Session:
    """The session's first ``duration_s`` seconds (every stream and the truth); a stream with no sample in them (image
    fixes that come later in the walk) is left out: an empty stream is no measurement, and a session refuses it."""
    from dataclasses import replace

    t0 = min(float(s.t[0]) for s in session.streams.values())
    keep = {name: s.select(s.t <= t0 + duration_s) for name, s in session.streams.items()}
    keep = {name: s for name, s in keep.items() if len(s)}
    truth = session.truth.select(session.truth.t <= t0 + duration_s) if session.truth is not None else None
    return replace(session, streams=keep, truth=truth)


SIMULATORS: dict[str, Simulator] = {
    "head": Simulator(_head_simulate, 10.0, options=("profile", "tracker_latency_s", "tracker_latency_assumed_s", "sensors", "tracker_gap_s"),
                      profiles=("realistic", "ideal")),
    "attitude9": Simulator(_attitude9_simulate, 10.0, options=("profile", "sensors", "gyro_scale_error"), profiles=("realistic", "noise_free")),
    "gaze": Simulator(_gaze_simulate, 40.0, 5.0, options=("sensors",)),
    "bicycle": Simulator(_bicycle_simulate, 40.0, 10.0),
    "walking": Simulator(_walking_simulate, float("nan"), 20.0, options=("sensors", "gait")),
    "ultrasonic": Simulator(_ultrasonic_simulate, 10.0, options=("transmitters",)),
}
"""Every system's simulator by name."""
