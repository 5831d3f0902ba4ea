"""UsdLux lights → scene.Light, with every scalar control folded into ``radiance``.

radiance = intensity · 2^exposure · color · blackbody(colorTemperature) / sizeFactor

blackbody is UsdLux.BlackbodyTemperatureAsRgb as is. It is normalised to luminance 1, so
6500 K gives (1.04, 0.98, 1.03) rather than the exact white the schema text promises; using
USD's own function keeps renders consistent with other UsdLux renderers.

``sizeFactor`` is 1 unless ``normalize`` is on. Then, following the UsdLux normalize docs:

* rect, disk, sphere, cylinder: the light's world-space surface area **in stage units**
  (the transform's scale included, metersPerUnit *not* applied). Measuring in stage units
  keeps the authored look when a layer stack is re-unitised only through metersPerUnit,
  which is how DCCs treat it. The cylinder emits from its side only (UsdLux: no end caps),
  so its area is 2πr·length. Non-uniform scale: exact for rect and disk, Thomsen's
  ellipsoid formula for the sphere, Ramanujan's ellipse perimeter for the cylinder.
* distant: π·sin²θ for θ = angle/2 ≤ π/2, (2 − sin²θ)·π beyond, 1 for angle 0.
* dome: ignored.

``world_from_light`` maps the light's local frame (in local units) to world metres: the full
world transform (rotation, scale, translation) followed by the metersPerUnit scale, so the
tracer gets world sizes by multiplying the local sizes by it. Domes get only their world
rotation (they sit at infinity), composed with +90° about X when the dome's pole is Z
(DomeLight_1 with ``poleAxis`` "Z", or "scene" on a Z-up stage). The plain DomeLight is
always Y-up, as its schema says. The tracer can therefore always read the lat-long image in
the OpenEXR convention (+Y up, longitude 0 → +Z, longitude π/2 → +X) in the light's frame.
"""

from __future__ import annotations

import math

import numpy as np
from pxr import Sdf, Usd, UsdLux

from pxr_layers.scene import Light, LightKind

from .context import ReadContext
from .textures import TextureLibrary, anchored_asset_path
from .transforms import Z_UP_FROM_Y_UP, column_matrix, nearest_rotation, to_metres

SUPPORTED_LIGHT_TYPES = (
    UsdLux.RectLight,
    UsdLux.DiskLight,
    UsdLux.SphereLight,
    UsdLux.CylinderLight,
    UsdLux.DistantLight,
    UsdLux.DomeLight,
    UsdLux.DomeLight_1,
)
# Exponent of Knud Thomsen's ellipsoid surface approximation (at most 1.06 % off, exact
# for spheres).
_THOMSEN_P = 1.6075


def is_supported_light(prim: Usd.Prim) -> bool:
    return any(prim.IsA(schema) for schema in SUPPORTED_LIGHT_TYPES)


def read_light(context: ReadContext, prim: Usd.Prim, textures: TextureLibrary) -> Light:
    """Convert one supported UsdLux light prim (see :func:`is_supported_light`)."""
    time = context.time
    light = UsdLux.LightAPI(prim)
    path = str(prim.GetPath())
    world_from_local = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
    linear = world_from_local[:3, :3]
    color = np.array(light.GetColorAttr().Get(time), dtype=np.float64)
    radiance = (
        float(light.GetIntensityAttr().Get(time))
        * 2.0 ** float(light.GetExposureAttr().Get(time))
        * color
    )
    if light.GetEnableColorTemperatureAttr().Get(time):
        temperature = float(light.GetColorTemperatureAttr().Get(time))
        radiance = radiance * np.array(UsdLux.BlackbodyTemperatureAsRgb(temperature))
    normalize = bool(light.GetNormalizeAttr().Get(time))
    _note_ignored_controls(context, prim, light)

    fields: dict[str, object] = {}
    size_factor = 1.0
    kind: LightKind
    if prim.IsA(UsdLux.RectLight):
        kind = "rect"
        rect = UsdLux.RectLight(prim)
        width = float(rect.GetWidthAttr().Get(time))
        height = float(rect.GetHeightAttr().Get(time))
        fields.update(width=width, height=height)
        size_factor = width * height * _parallelogram_area(linear)
    elif prim.IsA(UsdLux.DiskLight):
        kind = "disk"
        radius = float(UsdLux.DiskLight(prim).GetRadiusAttr().Get(time))
        fields.update(radius=radius)
        size_factor = math.pi * radius**2 * _parallelogram_area(linear)
    elif prim.IsA(UsdLux.SphereLight):
        kind = "sphere"
        radius = float(UsdLux.SphereLight(prim).GetRadiusAttr().Get(time))
        fields.update(radius=radius)
        size_factor = _ellipsoid_area(radius * np.linalg.svd(linear, compute_uv=False))
    elif prim.IsA(UsdLux.CylinderLight):
        kind = "cylinder"
        cylinder = UsdLux.CylinderLight(prim)
        radius = float(cylinder.GetRadiusAttr().Get(time))
        length = float(cylinder.GetLengthAttr().Get(time))
        fields.update(radius=radius, length=length)
        size_factor = _cylinder_side_area(linear, radius, length)
    elif prim.IsA(UsdLux.DistantLight):
        kind = "distant"
        angle = float(UsdLux.DistantLight(prim).GetAngleAttr().Get(time))
        fields.update(angle=angle)
        size_factor = distant_size_factor(angle)
    else:
        kind = "dome"
        normalize = False  # UsdLux: the dome family ignores normalize
        fields.update(texture=_dome_texture(context, prim, textures))
        world_from_local = _dome_frame(context, prim, linear)

    if normalize:
        if size_factor > 0.0:
            radiance = radiance / size_factor
        else:
            context.diagnostics.note(
                "zero-size-light",
                "lights of zero size cannot be normalized (left as authored): {prims}",
                path,
            )
    if kind != "dome":
        world_from_local = to_metres(world_from_local, context.meters_per_unit)
    return Light(
        name=prim.GetName(),
        path=path,
        kind=kind,
        world_from_light=world_from_local,
        radiance=radiance.astype(np.float64),
        **fields,
    )


def distant_size_factor(angle_degrees: float) -> float:
    """UsdLux's normalize divisor for a distant light of angular diameter ``angle_degrees``."""
    theta_max = min(max(math.radians(angle_degrees) / 2.0, 0.0), math.pi)
    if theta_max == 0.0:
        return 1.0
    sin_squared = math.sin(theta_max) ** 2
    if theta_max <= math.pi / 2.0:
        return math.pi * sin_squared
    return (2.0 - sin_squared) * math.pi


def _parallelogram_area(linear: np.ndarray) -> float:
    """World area of the local unit square in the XY plane."""
    return float(np.linalg.norm(np.cross(linear[:, 0], linear[:, 1])))


def _ellipsoid_area(semi_axes: np.ndarray) -> float:
    a, b, c = (float(x) ** _THOMSEN_P for x in semi_axes)
    return 4.0 * math.pi * ((a * b + a * c + b * c) / 3.0) ** (1.0 / _THOMSEN_P)


def _cylinder_side_area(linear: np.ndarray, radius: float, length: float) -> float:
    """Side area of a radius × length cylinder along local X after ``linear``.

    The image is an elliptic cylinder along ``axis``; its area is the axis length times the
    perimeter of its cross-section perpendicular to the axis.
    """
    axis = linear[:, 0]
    axis_length = float(np.linalg.norm(axis))
    if axis_length == 0.0:
        return 0.0
    direction = axis / axis_length
    cross_section = linear[:, 1:3] - np.outer(direction, direction @ linear[:, 1:3])
    a, b = radius * np.linalg.svd(cross_section, compute_uv=False)
    perimeter = math.pi * (3.0 * (a + b) - math.sqrt(max((3.0 * a + b) * (a + 3.0 * b), 0.0)))
    return perimeter * length * axis_length


def _dome_frame(context: ReadContext, prim: Usd.Prim, linear: np.ndarray) -> np.ndarray:
    world_from_dome = np.eye(4)
    world_from_dome[:3, :3] = nearest_rotation(linear)
    pole_is_z = False
    if prim.IsA(UsdLux.DomeLight_1):
        pole_axis = str(UsdLux.DomeLight_1(prim).GetPoleAxisAttr().Get(context.time))
        pole_is_z = pole_axis == "Z" or (pole_axis == "scene" and context.up_axis == "Z")
    return world_from_dome @ Z_UP_FROM_Y_UP if pole_is_z else world_from_dome


def _dome_texture(context: ReadContext, prim: Usd.Prim, textures: TextureLibrary) -> int | None:
    attribute = prim.GetAttribute("inputs:texture:file")
    asset = attribute.Get(context.time) if attribute else None
    if not isinstance(asset, Sdf.AssetPath) or not asset.path:
        return None
    path = str(prim.GetPath())
    texture_format = prim.GetAttribute("inputs:texture:format").Get(context.time)
    if texture_format not in (None, "automatic", "latlong"):
        context.diagnostics.note(
            "dome-format",
            "dome textures are read as lat-long only (texture:format ignored): {prims}",
            path,
        )
    if not asset.resolvedPath:
        missing = anchored_asset_path(attribute, asset, context.time)
        context.diagnostics.warn(
            f"dome texture not found: {missing} ({path}); the dome is a constant colour",
            once_key=f"texture:{missing}",
        )
        return None
    # Dome images are HDR floats (read raw); an 8-bit one is sRGB-encoded like any LDR image.
    loaded = textures.load(asset.resolvedPath, "auto", path)
    return None if loaded is None else loaded.index


def _note_ignored_controls(context: ReadContext, prim: Usd.Prim, light: UsdLux.LightAPI) -> None:
    """One warning per kind of authored light control the tracer does not implement."""
    time = context.time
    path = str(prim.GetPath())
    diagnostics = context.diagnostics

    def authored(name: str) -> bool:
        attribute = prim.GetAttribute(name)
        return bool(attribute) and attribute.HasAuthoredValue()

    # Applying ShapingAPI/ShadowAPI with untouched defaults changes nothing (Houdini does
    # that on every light), so only authored values count.
    if any(
        authored(f"inputs:shaping:{name}")
        for name in ("cone:angle", "cone:softness", "focus", "focusTint", "ies:file")
    ):
        diagnostics.note("shaping", "light shaping (cone, focus, IES) ignored on: {prims}", path)
    if light.GetFiltersRel().GetTargets():
        diagnostics.note("filters", "light filters ignored on: {prims}", path)
    for name in ("diffuse", "specular"):
        value = light.GetPrim().GetAttribute(f"inputs:{name}").Get(time)
        if value is not None and float(value) != 1.0:
            diagnostics.note(
                "multipliers", "diffuse/specular light multipliers ignored on: {prims}", path
            )
    if prim.IsA(UsdLux.RectLight) and authored("inputs:texture:file"):
        diagnostics.note("rect-texture", "RectLight textures ignored on: {prims}", path)
    for hint in ("treatAsPoint", "treatAsLine"):
        value = prim.GetAttribute(hint).Get(time) if prim.GetAttribute(hint) else None
        if value:
            diagnostics.note(
                "treat-as", "treatAsPoint/treatAsLine ignored (the light keeps its size): {prims}",
                path,
            )
    if any(
        authored(f"inputs:shadow:{name}")
        for name in ("enable", "color", "distance", "falloff", "falloffGamma")
    ):
        diagnostics.note("shadow", "shadow controls (ShadowAPI) ignored on: {prims}", path)
    for collection in (light.GetLightLinkCollectionAPI(), light.GetShadowLinkCollectionAPI()):
        include_root = collection.GetIncludeRootAttr().Get()
        if (
            include_root is False
            or collection.GetIncludesRel().GetTargets()
            or collection.GetExcludesRel().GetTargets()
        ):
            diagnostics.note("linking", "light and shadow linking ignored on: {prims}", path)
    if prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
        portals = prim.GetRelationship("portals")
        if portals and portals.GetTargets():
            diagnostics.note("portals", "dome light portals ignored on: {prims}", path)
