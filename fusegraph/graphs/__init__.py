"""Graph builders: measurements (in arrival order) -> factors on keyframe states; one builder per system."""

from .attitude9 import Attitude9Builder, Attitude9Model
from .bicycle import BicycleModel, CoupledBuilder, CouplingNoise
from .head import HeadGraphBuilder, HeadModel, head_model_for
from .increment import GraphIncrement
from .planar import PlanarGraph

__all__ = [
    "Attitude9Builder",
    "Attitude9Model",
    "BicycleModel",
    "CoupledBuilder",
    "CouplingNoise",
    "GraphIncrement",
    "HeadGraphBuilder",
    "HeadModel",
    "PlanarGraph",
    "head_model_for",
]
