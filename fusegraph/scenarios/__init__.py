"""Seeded simulators of each system, with ground truth."""

from collections.abc import Callable

from ..session import Session
from .attitude9 import Attitude9ScenarioConfig, simulate_attitude9
from .bicycle import bicycle_session
from .gaze import gaze_session
from .head import PROFILES, HeadScenarioConfig, simulate_head
from .registry import SIMULATORS, Simulator
from .walking import walking_session

SCENARIOS: dict[str, Callable[..., Session]] = {"head": simulate_head, "attitude9": simulate_attitude9, "gaze": gaze_session, "bicycle": bicycle_session,
                                               "walking": walking_session}
"""Scenario name -> simulator ``f(seed, **overrides) -> Session``."""

__all__ = [
    "PROFILES",
    "SCENARIOS",
    "SIMULATORS",
    "Simulator",
    "Attitude9ScenarioConfig",
    "HeadScenarioConfig",
    "bicycle_session",
    "gaze_session",
    "simulate_attitude9",
    "simulate_head",
    "walking_session",
]
