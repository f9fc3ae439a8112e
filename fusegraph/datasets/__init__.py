"""Loaders that turn real recordings into Sessions."""
