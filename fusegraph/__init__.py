"""fusegraph: factor-graph smoothing for human motion from wearable and environmental sensors."""

from .estimate import Estimate
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
    "Session",
    "SessionError",
    "Stream",
    "__version__",
    "load_session",
    "replay_in_arrival_order",
    "save_session",
]
