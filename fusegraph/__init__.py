"""fusegraph: factor-graph smoothing for human motion from wearable and environmental sensors."""

from .api import import_dataset, plot, run_report, score, simulate, solve, solver_names
from .estimate import Estimate, PointEstimate
from .session import ArrivalEvent, Session, SessionError, Stream, load_session, replay_in_arrival_order, save_session

__version__ = "0.1.0"


def __getattr__(name: str) -> object:
    """``fusegraph.OnlineHeadTracker`` (the live head tracker) without importing gtsam's graphs at ``import fusegraph``."""
    if name == "OnlineHeadTracker":
        from .systems.head import OnlineHeadTracker

        return OnlineHeadTracker
    raise AttributeError(f"module 'fusegraph' has no attribute {name!r}")


__all__ = [
    "ArrivalEvent",
    "Estimate",
    "OnlineHeadTracker",
    "PointEstimate",
    "Session",
    "SessionError",
    "Stream",
    "__version__",
    "import_dataset",
    "load_session",
    "plot",
    "replay_in_arrival_order",
    "run_report",
    "save_session",
    "score",
    "simulate",
    "solve",
    "solver_names",
]
