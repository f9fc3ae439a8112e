"""fusegraph: factor-graph smoothing for human motion from wearable and environmental sensors."""

from .estimate import Estimate
from .session import ArrivalEvent, Session, SessionError, Stream, load_session, replay_in_arrival_order, save_session

__version__ = "0.1.0"

__all__ = [
    "ArrivalEvent",
    "Estimate",
    "Session",
    "SessionError",
    "Stream",
    "__version__",
    "load_session",
    "replay_in_arrival_order",
    "save_session",
]
