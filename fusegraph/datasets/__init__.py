"""Loaders that turn real recordings into Sessions."""

from .broad import BroadErrors, broad_errors, load_broad, trial_paths

__all__ = ["BroadErrors", "broad_errors", "load_broad", "trial_paths"]
