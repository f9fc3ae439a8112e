"""Seeded simulators of each system, with ground truth."""

from .head import PROFILES, HeadScenarioConfig, simulate_head

SCENARIOS = {"head": simulate_head}
"""Scenario name -> simulator ``f(seed, **overrides) -> Session``."""

__all__ = ["PROFILES", "SCENARIOS", "HeadScenarioConfig", "simulate_head"]
