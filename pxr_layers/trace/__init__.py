"""Embree wavefront path tracer: SceneData + RenderSpec -> linear RGBA image."""

from .integrator import TraceSettings
from .render import RenderResult, render

__all__ = ["RenderResult", "TraceSettings", "render"]
