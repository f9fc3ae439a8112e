"""Graph builders: measurements (in arrival order) -> factors on keyframe states; one builder per system."""

from .attitude9 import Attitude9Builder, Attitude9Model
from .head import HeadGraphBuilder, HeadModel, head_model_for
from .increment import GraphIncrement

__all__ = ["Attitude9Builder", "Attitude9Model", "GraphIncrement", "HeadGraphBuilder", "HeadModel", "head_model_for"]
