"""Embedded default scenes and presets (declarative USD); found with importlib.resources."""
