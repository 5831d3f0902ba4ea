"""Embree wavefront path tracer: SceneData + RenderSpec -> linear RGBA image (and the
data AOVs: depth, normals, positions, ids)."""

from .aovs import DATA_AOVS, render_data_aovs
from .integrator import TraceSettings
from .render import RenderResult, render

__all__ = ["DATA_AOVS", "RenderResult", "TraceSettings", "render", "render_data_aovs"]
