"""UsdLux lights → scene.Light, with every scalar control folded into ``radiance``.

radiance = intensity · 2^exposure · color · blackbody(colorTemperature) / sizeFactor

blackbody(T) (:func:`blackbody_rgb`) is the Planckian locus as hdEmbree, UsdLux's reference
renderer, computes it: Gf.Color's SetFromPlanckianLocus in linear Rec.709 (1000–15000 K,
clamped beyond), divided by its Rec.709 luminance so that luminance is 1 (6500 K gives
(1.04, 0.98, 1.04), not the exact white the schema text promises: the locus passes beside
D65). Below about 1900 K the locus leaves the Rec.709 gamut and its blue goes negative; that
is clipped to 0 before normalising (hdEmbree keeps it), since negative radiance would make
negative pixels. UsdLux.BlackbodyTemperatureAsRgb is not used: it is a table clamped at
10000 K (11000 K's blue comes out 5 % low).

``sizeFactor`` is 1 unless ``normalize`` is on. Then, following the UsdLux normalize docs:

* rect, disk, sphere, cylinder: the light's world-space surface area **in stage units**
  (the transform's scale included, metersPerUnit *not* applied). Measuring in stage units
  keeps the authored look when a layer stack is re-unitised only through metersPerUnit,
  which is how DCCs treat it. The cylinder emits from its side only (UsdLux: no end caps),
  so its area is 2πr·length. Non-uniform scale: exact for rect and disk, Thomsen's
  ellipsoid formula for the sphere, Ramanujan's ellipse perimeter for the cylinder.
  ``treatAsPoint`` and ``treatAsLine`` (kinds "point" and "line") keep the sphere's and
  cylinder's sizes and so their area: the hint changes how the light is sampled, not its power.
* distant: π·sin²θ for θ = angle/2 ≤ π/2, (2 − sin²θ)·π beyond, 1 for angle 0.
* dome: ignored.

``world_from_light`` maps the light's local frame (in local units) to world metres: the full
world transform (rotation, scale, translation) followed by the metersPerUnit scale, so the
tracer gets world sizes by multiplying the local sizes by it. Domes get only their world
rotation (they sit at infinity), composed with +90° about X when the dome's pole is Z
(DomeLight_1 with ``poleAxis`` "Z", or "scene" on a Z-up stage). The plain DomeLight is
always Y-up, as its schema says. The tracer can therefore always read the lat-long image in
the OpenEXR convention (+Y up, longitude 0 → +Z, longitude π/2 → +X) in the light's frame.

Shaping (ShapingAPI, scene.LightShaping): the ``inputs:shaping:*`` values at the frame, so an
applied ShapingAPI with nothing authored has the schema's fallbacks (a 90° cone); without it
there is no shaping. A light gets a LightShaping only when it changes the emission: the cone
when its smooth start cone_angle · (1 − softness) is below the widest angle the light emits
at (90° for the one-sided rect and disk, 180° for the others), the focus when it is > 0 with a
focusTint other than white, an IES profile (stage/ies.py) when its file is readable. Shaping
does not apply to distant and dome lights: one warning when its authored values would change
them (the fallbacks of an applied ShapingAPI alone do not count).

Textures (``inputs:texture:file``): a dome's lat-long image and a rect's colour map, read
raw when float and as sRGB when 8-bit (TextureLibrary's "auto"), their NaN, infinite and
negative texels as 0 with a warning (TextureLibrary.load's ``light``). An empty ``@@`` is
no texture; a missing file is a warning and a constant light.

Camera visibility (``camera_visible``): UsdLux has no attribute for it and says a light is
seen (a directly visible light of intensity 1 gives pixel value 1). Stages written for
particular renderers say otherwise with their attributes; the first of _CAMERA_VISIBILITY
authored on the light wins: the renderer-neutral names first (``inputs:visibility:camera``,
Omniverse's ``visibleInPrimaryRay``), then RenderMan's, Arnold's and Karma's. 0 or false
hides; Karma's ``rendervisibility`` is a ray-type rule (see _karma_sees_primary: "-primary"
hides, "*" shows). The ``primvars:`` ones are inherited from ancestors as constant primvars
are. When authored ones disagree, the light is named (with their values) in one warning.

Values (values.checked, one rule with materials): every control is a finite number in its
range, else a StageError naming the prim and the attribute: intensity, colour, sizes and
the diffuse and specular multipliers ≥ 0, colorTemperature ≥ 1, a distant light's angle
within 0–360°, the ShapingAPI values finite (NaN is no cone that is not there), sizes at
most placement.MAX_WORLD_COORDINATE in metres; a light's brightest radiance, intensity ·
2^exposure · colour times its IES profile's peak, at most values.MAX_RADIANCE. A light whose
transform puts it out of that reach is skipped with a warning, as a gprim is; an IES profile
whose candela values are all 0 gets a warning that its lights are black.

Linking: ``light_link`` and ``shadow_link`` are the meshes (indices into SceneData.meshes,
tested by Mesh.path) that the light's ``collection:lightLink`` and ``collection:shadowLink``
include, by the collection's own membership query (includeRoot, includes, excludes,
expansionRule, membershipExpression); None when every mesh is. A point-instanced mesh's
path is under its instancer (``<instancer>/instance_N/...``), so including the instancer or
an ancestor includes its instances; its prototype's own path is not consulted. A native
instance's meshes have their instance-proxy paths.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
from pxr import Gf, Sdf, Usd, UsdLux

from pxr_layers.errors import StageError
from pxr_layers.scene import REC709_LUMINANCE, IesProfile, Light, LightKind, LightShaping

from . import values
from .context import ReadContext
from .ies import read_ies
from .placement import MAX_WORLD_COORDINATE
from .surfaces import find_primvar
from .textures import TextureLibrary, anchored_asset_path
from .transforms import Z_UP_FROM_Y_UP, column_matrix, nearest_rotation, to_metres
from .values import MAX_RADIANCE

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
_REC709 = Gf.ColorSpace(Gf.ColorSpaceNames.LinearRec709)
# Kinds that emit at most 90° off their −Z axis (one-sided); the others reach 180°.
_ONE_SIDED_KINDS = ("rect", "disk")
# Kinds ShapingAPI does not apply to.
_UNSHAPED_KINDS = ("distant", "dome")
# A few float32 ulps, relative: how close to an emission limit an authored angle is at it.
_FLOAT32_ROUNDING = 4.0 * float(np.finfo(np.float32).eps)


def _karma_sees_primary(rule: object) -> bool:
    """Whether Karma's ``rendervisibility`` rule shows an object to camera (primary) rays:
    its ray-type patterns apply left to right, ``-x`` or ``^x`` removing and any other adding
    (``*`` is every type); the set starts empty, or full when the first pattern removes."""
    patterns = str(rule).replace(",", " ").split()
    seen = bool(patterns) and patterns[0][0] in "-^"
    for pattern in patterns:
        if pattern.lstrip("-^+") in ("*", "primary"):
            seen = pattern[0] not in "-^"
    return seen


# Where stages say whether the camera sees a light, strongest first, and how each value
# reads: the renderer-neutral names, then RenderMan's, Arnold's (its visibility flag, then its
# camera contribution weight: 0 hides) and Karma's (a ray-type rule, then its light-geometry
# toggle).
_CAMERA_VISIBILITY: tuple[tuple[str, Callable[[object], bool]], ...] = (
    ("inputs:visibility:camera", bool),
    ("visibleInPrimaryRay", bool),
    ("primvars:ri:attributes:visibility:camera", bool),
    ("primvars:arnold:visibility:camera", bool),
    ("primvars:arnold:camera", bool),
    ("primvars:karma:object:rendervisibility", _karma_sees_primary),
    ("karma:light:renderlightgeo", bool),
)


def is_supported_light(prim: Usd.Prim) -> bool:
    return any(prim.IsA(schema) for schema in SUPPORTED_LIGHT_TYPES)


def read_lights(
    context: ReadContext, prims: Sequence[Usd.Prim], textures: TextureLibrary, mesh_paths: Sequence[str]
) -> list[Light]:
    """Convert the supported UsdLux light prims of one read (see :func:`is_supported_light`).

    mesh_paths : the Mesh.path of each of SceneData.meshes, in order: what light_link and
                 shadow_link index
    """
    profiles: dict[str, IesProfile | None] = {}  # resolved path → profile: each file parsed once
    members = [Sdf.Path(path) for path in mesh_paths]
    lights = (_read_light(context, prim, textures, profiles, members) for prim in prims)
    return [light for light in lights if light is not None]


def _read_light(
    context: ReadContext,
    prim: Usd.Prim,
    textures: TextureLibrary,
    profiles: dict[str, IesProfile | None],
    mesh_paths: Sequence[Sdf.Path],
) -> Light | None:
    """The light, or None (with a warning) when its transform puts it beyond
    MAX_WORLD_COORDINATE, as the placement does with gprims."""
    time = context.time
    light = UsdLux.LightAPI(prim)
    path = str(prim.GetPath())
    world_from_local = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
    linear = world_from_local[:3, :3]

    def checked(attribute: Usd.Attribute, least: float | None = 0.0, most: float | None = None) -> float:
        return values.checked(_number(context, attribute), attribute.GetName(), file=context.file, prim=path,
                              least=least, most=most)

    def size(attribute: Usd.Attribute) -> float:
        # Larger, the light would reach past where geometry may be placed (and its area and
        # sampling overflow float32): a mistake in the value or its units.
        return checked(attribute, 0.0, MAX_WORLD_COORDINATE / context.meters_per_unit)

    color_attribute = light.GetColorAttr()
    color = np.array(values.checked_all(values.reals(color_attribute, time, 3, context.file) or (1.0, 1.0, 1.0),
                                        color_attribute.GetName(), file=context.file, prim=path, least=0.0))
    intensity, exposure = checked(light.GetIntensityAttr()), checked(light.GetExposureAttr(), None)
    if light.GetEnableColorTemperatureAttr().Get(time):
        color = color * blackbody_rgb(checked(light.GetColorTemperatureAttr(), 1.0))
    brightest = intensity * float(color.max())
    log2_brightest = math.log2(brightest) + exposure if brightest > 0 else -math.inf
    _check_brightness(context, path, log2_brightest, "intensity · 2^exposure · color")
    radiance = intensity * 2.0**exposure * color if brightest > 0 else np.zeros(3)
    normalize = bool(light.GetNormalizeAttr().Get(time))
    _note_ignored_controls(context, prim, light)

    fields: dict[str, object] = {}
    size_factor = 1.0
    kind: LightKind
    if prim.IsA(UsdLux.RectLight):
        kind = "rect"
        rect = UsdLux.RectLight(prim)
        width, height = size(rect.GetWidthAttr()), size(rect.GetHeightAttr())
        fields.update(width=width, height=height, texture=_light_texture(context, prim, textures))
        size_factor = width * height * _parallelogram_area(linear)
    elif prim.IsA(UsdLux.DiskLight):
        kind = "disk"
        radius = size(UsdLux.DiskLight(prim).GetRadiusAttr())
        fields.update(radius=radius)
        size_factor = math.pi * radius**2 * _parallelogram_area(linear)
    elif prim.IsA(UsdLux.SphereLight):
        sphere = UsdLux.SphereLight(prim)
        kind = "point" if sphere.GetTreatAsPointAttr().Get(time) else "sphere"
        radius = size(sphere.GetRadiusAttr())
        fields.update(radius=radius)
        size_factor = _ellipsoid_area(radius * np.linalg.svd(linear, compute_uv=False))
    elif prim.IsA(UsdLux.CylinderLight):
        cylinder = UsdLux.CylinderLight(prim)
        kind = "line" if cylinder.GetTreatAsLineAttr().Get(time) else "cylinder"
        radius, length = size(cylinder.GetRadiusAttr()), size(cylinder.GetLengthAttr())
        fields.update(radius=radius, length=length)
        size_factor = _cylinder_side_area(linear, radius, length)
    elif prim.IsA(UsdLux.DistantLight):
        kind = "distant"
        angle = checked(UsdLux.DistantLight(prim).GetAngleAttr(), 0.0, 360.0)  # a diameter: 360° is all round
        fields.update(angle=angle)
        size_factor = distant_size_factor(angle)
    else:
        kind = "dome"
        normalize = False  # UsdLux: the dome family ignores normalize
        fields.update(texture=_light_texture(context, prim, textures))
        texture_format = prim.GetAttribute("inputs:texture:format").Get(time)
        if fields["texture"] is not None and texture_format not in (None, "automatic", "latlong"):
            context.diagnostics.note(
                "dome-format",
                "dome textures are read as lat-long only (texture:format ignored): {prims}",
                path,
            )
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
    if kind not in ("dome", "distant") and not _within_reach(world_from_local, fields):
        context.diagnostics.note(
            "light-out-of-reach",
            f"lights placed beyond {MAX_WORLD_COORDINATE:g} m from the origin (or whose size there overflows) "
            "skipped: {prims}",
            path,
        )
        return None
    shaping = _shaping(context, prim, kind, profiles)
    if shaping is not None and shaping.ies is not None:
        peak = float(shaping.ies.candela.max()) / (shaping.ies.power if shaping.ies_normalize else 1.0)
        _check_brightness(context, path, log2_brightest + math.log2(peak) if peak > 0 else -math.inf,
                          f"intensity · 2^exposure · color · the IES profile's peak ({peak:g})")
    return Light(
        name=prim.GetName(),
        path=path,
        kind=kind,
        world_from_light=world_from_local,
        radiance=radiance.astype(np.float64),
        shaping=shaping,
        diffuse=checked(light.GetDiffuseAttr()),
        specular=checked(light.GetSpecularAttr()),
        camera_visible=_camera_visible(context, prim),
        light_link=_members(light.GetLightLinkCollectionAPI(), mesh_paths),
        shadow_link=_members(light.GetShadowLinkCollectionAPI(), mesh_paths),
        **fields,
    )


def _number(context: ReadContext, attribute: Usd.Attribute) -> float:
    """A light's scalar attribute at the read's time (its schema's fallback when unauthored);
    StageError when it is authored as something else than a number (values.real). A
    negative intensity, colour or size would make negative (or NaN) pixels, which no layer
    can hold: the callers' ranges say so (values.checked)."""
    value = values.real(attribute, context.time, context.file)
    if value is None:  # blocked (= None): the schema's fallback, as for an unauthored attribute
        fallback = attribute.GetPrim().GetPrimDefinition().GetAttributeFallbackValue(attribute.GetName())
        value = float(fallback) if fallback is not None else 0.0
    return value


def _check_brightness(context: ReadContext, path: str, log2_radiance: float, what: str) -> None:
    """StageError naming the light when its brightest radiance, 2^log2_radiance (``what`` makes
    it), is above MAX_RADIANCE. In powers of two: 2^exposure itself overflows a float past
    exposure 1023."""
    if log2_radiance > math.log2(MAX_RADIANCE):
        raise StageError(f"{what} reaches 2^{log2_radiance:.4g}: more than a render can hold (at most "
                         f"2^{math.log2(MAX_RADIANCE):.1f}, {MAX_RADIANCE:g})", file=context.file, prim=path)


def _within_reach(world_from_light: np.ndarray, fields: dict[str, object]) -> bool:
    """Whether a light of the local sizes ``fields`` (width, height, radius, length) under
    ``world_from_light`` ((4, 4), metres) lies within MAX_WORLD_COORDINATE of the origin:
    its centre's distance plus its local half-extent times the transform's largest scale."""
    half_width, half_height = float(fields.get("width", 0.0)) / 2, float(fields.get("height", 0.0)) / 2
    radius, half_length = float(fields.get("radius", 0.0)), float(fields.get("length", 0.0)) / 2
    extent = max(math.hypot(half_width, half_height), math.hypot(radius, half_length))
    with np.errstate(over="ignore", invalid="ignore"):
        scale = float(np.linalg.svd(world_from_light[:3, :3], compute_uv=False)[0])
        reach = float(np.linalg.norm(world_from_light[:3, 3])) + extent * scale
    return reach <= MAX_WORLD_COORDINATE  # False for NaN too


def blackbody_rgb(kelvin: float) -> np.ndarray:
    """(3,) float64 linear Rec.709 colour of a blackbody at ``kelvin``, of luminance 1 (see
    the module docstring: hdEmbree's Planckian locus, out-of-gamut negatives clipped)."""
    color = Gf.Color(_REC709)
    color.SetFromPlanckianLocus(float(kelvin), 1.0)
    rgb = np.maximum(np.array(color.GetRGB(), dtype=np.float64), 0.0)
    return rgb / float(rgb @ np.asarray(REC709_LUMINANCE))


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


def _asset(prim: Usd.Prim, name: str, time: Usd.TimeCode) -> tuple[Usd.Attribute, Sdf.AssetPath] | None:
    """The attribute ``name`` and the asset path it holds at ``time``; None when it holds
    none or the empty ``@@`` (UsdLux's "no file", not an error)."""
    attribute = prim.GetAttribute(name)
    asset = attribute.Get(time) if attribute else None
    return (attribute, asset) if isinstance(asset, Sdf.AssetPath) and asset.path else None


def _resolved(context: ReadContext, prim: Usd.Prim, found: tuple[Usd.Attribute, Sdf.AssetPath], what: str,
              consequence: str) -> str | None:
    """The resolved path of an :func:`_asset`, or None after a warning (once per file) naming
    where the file was looked for, the light, and the ``consequence``."""
    attribute, asset = found
    if asset.resolvedPath:
        return asset.resolvedPath
    missing = anchored_asset_path(attribute, asset, context.time)
    context.diagnostics.warn(f"{what} not found: {missing} ({prim.GetPath()}); {consequence}",
                             once_key=f"{what}:{missing}")
    return None


def _light_texture(context: ReadContext, prim: Usd.Prim, textures: TextureLibrary) -> int | None:
    """The index in SceneData.textures of the light's ``inputs:texture:file``, or None."""
    found = _asset(prim, "inputs:texture:file", context.time)
    resolved = found and _resolved(context, prim, found, "light texture", "the light is a constant colour")
    if not resolved:
        return None
    # Light images are HDR floats (read raw); an 8-bit one is sRGB-encoded like any LDR image.
    loaded = textures.load(resolved, "auto", str(prim.GetPath()), light=True)
    return None if loaded is None else loaded.index


def _shaping(
    context: ReadContext, prim: Usd.Prim, kind: LightKind, profiles: dict[str, IesProfile | None]
) -> LightShaping | None:
    """The light's ShapingAPI values that change its emission (see the module docstring)."""
    time = context.time
    # On lights shaping does not apply to, only authored values say something was meant: the
    # fallbacks of an applied ShapingAPI (a 90° cone) are nobody's intent there (the usd-wg
    # normals asset applies it to distant lights and authors only pre-"inputs:" names).
    authored_only = kind in _UNSHAPED_KINDS

    def attribute(name: str) -> Usd.Attribute | None:
        found = prim.GetAttribute(f"inputs:shaping:{name}")
        return None if not found or (authored_only and not found.HasAuthoredValue()) else found

    def value(name: str, unset: object) -> object:
        found = attribute(name)
        got = found.Get(time) if found else None
        return unset if got is None else got

    def number(name: str, unset: float) -> float:
        """A finite number (values.checked: NaN is an error naming it, not a cone that is not there)."""
        found = attribute(name)
        got = values.real(found, time, context.file) if found else None
        if got is None:
            return unset
        return values.checked(got, found.GetName(), file=context.file, prim=str(prim.GetPath()))

    # Unset (no ShapingAPI and nothing authored): no cone. Negative angles would invert the
    # smooth step's edges; softness and focus are clamped as UsdLux says.
    cone_angle = max(number("cone:angle", 180.0), 0.0)
    softness = min(max(number("cone:softness", 0.0), 0.0), 1.0)
    focus = max(number("focus", 0.0), 0.0)
    tint_attribute = attribute("focusTint")
    tint_values = values.reals(tint_attribute, time, 3, context.file) if tint_attribute else None
    tint = values.checked_all(tint_values, tint_attribute.GetName(), file=context.file, prim=str(prim.GetPath()),
                              least=0.0) if tint_values else (0.0, 0.0, 0.0)
    ies = _asset(prim, "inputs:shaping:ies:file", time)
    widest = 90.0 if kind in _ONE_SIDED_KINDS else 180.0
    # Below the smooth start the factor is 1 (softness 0: up to the cone angle itself). The
    # values are float32: a start within their rounding of the widest angle is at it
    # (100° softened by 0.1 starts at 90°).
    has_cone = cone_angle * (1.0 - softness) < widest * (1.0 - _FLOAT32_ROUNDING)
    has_focus = focus > 0.0 and tint != (1.0, 1.0, 1.0)
    if kind in _UNSHAPED_KINDS:
        if has_cone or has_focus or ies:
            context.diagnostics.note(
                "unshaped-kinds",
                "light shaping (cone, focus, IES) does not apply to distant and dome lights, ignored on: {prims}",
                str(prim.GetPath()),
            )
        return None
    profile = _ies_profile(context, prim, ies, profiles) if ies else None
    if not (has_cone or has_focus or profile):
        return None
    shaping: dict[str, object] = {}
    if has_cone:
        shaping.update(cone_angle=cone_angle, cone_softness=softness)
    if has_focus:
        shaping.update(focus=focus, focus_tint=tint)
    if profile:
        # A profile of no power is black whatever its normalisation: there is nothing to divide by.
        normalize = bool(value("ies:normalize", False)) and profile.power > 0.0
        shaping.update(ies=profile, ies_angle_scale=number("ies:angleScale", 0.0), ies_normalize=normalize)
    return LightShaping(**shaping)


def _ies_profile(
    context: ReadContext,
    prim: Usd.Prim,
    found: tuple[Usd.Attribute, Sdf.AssetPath],
    profiles: dict[str, IesProfile | None],
) -> IesProfile | None:
    """The light's IES profile (parsed once per read), or None after a warning (once per file)."""
    keeps = "the light keeps the rest of its shaping"
    resolved = _resolved(context, prim, found, "IES profile", keeps)
    if resolved is None:
        return None
    if resolved not in profiles:
        path = str(prim.GetPath())
        try:
            profile, notes = read_ies(resolved)
        except StageError as error:
            context.diagnostics.warn(f"IES profile unusable ({path}; {keeps}): {error}", once_key=f"ies:{resolved}")
            profile, notes = None, ()
        for note in notes:
            context.diagnostics.warn(f"IES profile {resolved} ({path}): {note}", once_key=f"ies note:{resolved}")
        if profile is not None and not profile.candela.max() > 0.0:
            context.diagnostics.warn(f"IES profile {resolved} ({path}): every candela value is 0: the lights that "
                                     "use it are black", once_key=f"ies black:{resolved}")
        profiles[resolved] = profile
    return profiles[resolved]


def _camera_visible(context: ReadContext, prim: Usd.Prim) -> bool:
    """Whether camera rays see the light (see the module docstring and _CAMERA_VISIBILITY)."""
    authored = []
    for name, reads in _CAMERA_VISIBILITY:
        if name.startswith("primvars:"):
            primvar = find_primvar(prim, name.removeprefix("primvars:"))
            value = primvar.Get(context.time) if primvar else None
        else:
            attribute = prim.GetAttribute(name)
            value = attribute.Get(context.time) if attribute and attribute.HasAuthoredValue() else None
        if value is not None:
            authored.append((name, value, reads(value)))
    if not authored:
        return True
    if len({seen for _, _, seen in authored}) > 1:
        values = ", ".join(f"{name} = {value!r}" for name, value, _ in authored)
        context.diagnostics.note(
            "camera-visibility",
            "lights whose camera visibility attributes disagree (the first one listed is used): {prims}",
            f"{prim.GetPath()} ({values})",
        )
    return authored[0][2]


def _members(collection: Usd.CollectionAPI, mesh_paths: Sequence[Sdf.Path]) -> tuple[int, ...] | None:
    """Indices of the meshes the collection includes; None when it includes every one."""
    query = collection.ComputeMembershipQuery()
    members = tuple(index for index, path in enumerate(mesh_paths) if query.IsPathIncluded(path))
    return None if len(members) == len(mesh_paths) else members


def _note_ignored_controls(context: ReadContext, prim: Usd.Prim, light: UsdLux.LightAPI) -> None:
    """One warning per kind of authored light control the tracer does not implement."""
    path = str(prim.GetPath())
    diagnostics = context.diagnostics
    if light.GetFiltersRel().GetTargets():
        diagnostics.note("filters", "light filters ignored on: {prims}", path)
    # Applying ShadowAPI with untouched defaults changes nothing (Houdini does that on every
    # light), so only authored values count.
    if any(
        prim.GetAttribute(f"inputs:shadow:{name}").HasAuthoredValue()
        for name in ("enable", "color", "distance", "falloff", "falloffGamma")
    ):
        diagnostics.note("shadow", "shadow controls (ShadowAPI) ignored on: {prims}", path)
    if prim.IsA(UsdLux.DomeLight) or prim.IsA(UsdLux.DomeLight_1):
        portals = prim.GetRelationship("portals")
        if portals and portals.GetTargets():
            diagnostics.note("portals", "dome light portals ignored on: {prims}", path)
