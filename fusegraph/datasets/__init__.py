"""Loaders that turn real recordings into Sessions."""

from ..metrics import BroadErrors, broad_errors
from .broad import load_broad, trial_paths
from .plaza import PlazaRecording, load_plaza
from .steps_oxford import StepRecording, load_recording, read_stats, recordings

__all__ = ["BroadErrors", "PlazaRecording", "StepRecording", "broad_errors", "load_broad", "load_plaza", "load_recording", "read_stats",
           "recordings", "trial_paths"]
