"""Embree wavefront path tracer: SceneData + RenderSpec -> linear RGBA image (and the
data AOVs: depth, normals, positions, ids)."""

from .aovs import DATA_AOVS, render_data_aovs
from .integrator import TraceSettings
from .render import DEFAULT_BATCH_PATHS, Film, batch_pixels, prepare, trace_pixels

__all__ = ["DATA_AOVS", "DEFAULT_BATCH_PATHS", "Film", "TraceSettings", "batch_pixels", "prepare", "render_data_aovs",
           "trace_pixels"]
