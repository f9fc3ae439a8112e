"""Graph builders: measurements (in arrival order) -> factors on keyframe states; one builder per system."""

from .head import HeadGraphBuilder, HeadModel, head_model_for
from .increment import GraphIncrement

__all__ = ["GraphIncrement", "HeadGraphBuilder", "HeadModel", "head_model_for"]
