"""Stages for the camera's tests (depth of field, motion blur): an emissive shape in front of
a camera on a centimetre stage, and the beauty it renders with nothing but the light the
camera sees directly."""

from __future__ import annotations

import numpy as np

from pxr_layers.jobs.frame import render_frame
from pxr_layers.request import RenderRequest

GLOW = """
    def Scope "Looks"
    {
        def Material "glow"
        {
            token outputs:surface.connect = </World/Looks/glow/Surface.outputs:surface>
            def Shader "Surface"
            {
                uniform token info:id = "UsdPreviewSurface"
                color3f inputs:diffuseColor = (0, 0, 0)
                color3f inputs:emissiveColor = (1, 1, 1)
                token outputs:surface
            }
        }
    }"""
"""/World/Looks/glow: emits 1 in every channel, reflects nothing."""

BLACK = """
    def Material "black"
    {
        token outputs:surface.connect = </World/black/Surface.outputs:surface>
        def Shader "Surface"
        {
            uniform token info:id = "UsdPreviewSurface"
            color3f inputs:diffuseColor = (0, 0, 0)
            token outputs:surface
        }
    }"""
"""/World/black (a Material directly under /World): reflects and emits nothing."""


APERTURE, FOCAL = 36.0, 50.0
"""The camera of centimetre_stage: a 50 mm lens on a 36 mm square gate (tenths of a scene
unit, as UsdGeom says, on a centimetre stage)."""


def centimetre_stage(path, body: str, *, camera: str = "", metadata: str = ""):
    """Write at `path` a centimetre stage (Y up, defaultPrim /World; `metadata`: more layer
    metadata lines): `body` in /World, then /World/Camera at the origin looking down −Z
    (APERTURE, FOCAL; `camera`: more of its attribute lines). Returns `path`."""
    path.write_text(f"""#usda 1.0
(
    upAxis = "Y"
    metersPerUnit = 0.01
    defaultPrim = "World"
    {metadata}
)
def Xform "World"
{{{body}
    def Camera "Camera"
    {{
        float focalLength = {FOCAL}
        float horizontalAperture = {APERTURE}
        float verticalAperture = {APERTURE}
        float2 clippingRange = (0.1, 100000)
        {camera}
    }}
}}
""")
    return path


def quad(name: str, half_width: float, half_height: float, distance: float) -> str:
    """A Mesh /World/`name` bound to /World/Looks/glow: a rectangle `distance` down −Z."""
    w, h, z = half_width, half_height, -distance
    return f"""
    def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-{w}, -{h}, {z}), ({w}, -{h}, {z}), ({w}, {h}, {z}), (-{w}, {h}, {z})]
        rel material:binding = </World/Looks/glow>
    }}"""


def beauty(path, resolution: int, spp: int, frame: float | None = None) -> np.ndarray:
    """The beauty's mean of channels (h, w) float64: what the camera sees directly
    (max_depth 0, no default lights, no index)."""
    request = RenderRequest(stage=path, resolution=(resolution, resolution), spp=spp, max_depth=0, norm_bounces=0,
                            keep_index=False, previews=False, default_lights=False)
    return render_frame(request, frame, output=path.parent).rgba[..., :3].mean(axis=2).astype(np.float64)
