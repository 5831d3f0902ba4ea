"""Embree wavefront path tracer: SceneData + RenderSpec -> linear RGBA image (and the
data AOVs: depth, normals, positions, ids)."""

from .aovs import DATA_AOVS, render_data_aovs
from .integrator import TraceSettings
from .render import Film, RenderResult, prepare, render, trace_pixels

__all__ = ["DATA_AOVS", "Film", "RenderResult", "TraceSettings", "prepare", "render", "render_data_aovs", "trace_pixels"]
