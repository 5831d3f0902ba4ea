"""Plain data that ``stage/`` produces from a USD stage and ``trace/`` consumes.

Nothing here imports pxr: everything downstream of the stage reader is testable without USD.

Conventions (hold for every field below):

* Lengths are in **metres** in world space: the stage reader multiplies by the stage's
  ``metersPerUnit``. Light sizes are already folded into ``world_from_light``.
* Transforms are 4×4 float64 matrices in the **column-vector** convention,
  ``p_world = world_from_x @ [x, y, z, 1]`` (USD stores row vectors; the reader transposes).
* Colours are linear RGB in the rendering colour space (linear Rec.709 / sRGB primaries).
* Light radiance is in the UsdLux unit (1 = one nit at exposure 0), with ``intensity``,
  ``exposure``, ``color``, colour temperature and ``normalize`` already folded in, so the
  tracer never needs the authored attributes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Mapping

import numpy as np

from .recipe.model import DEFAULT_CONFORM_POLICY, DEFAULT_PIXEL_ASPECT_RATIO, Recipe
from .request import DEFAULT_RESOLUTION
from .colour import REC709_LUMINANCE  # noqa: F401 (part of the plain data: the rendering colour space's)
from .shader_nodes import ShaderNode, WrapMode  # noqa: F401 (WrapMode: part of the plain data)

FLOAT = np.float32
INDEX = np.int32



@dataclass(frozen=True)
class TextureHeader:
    """What an image file's header says, before any pixel is decoded (texture_files.py).

    width, height : texels of the finest level
    channels      : as stored (1 grey, 2 grey + alpha, 3 RGB, 4 RGBA, more: only 4 are read)
    stored        : how its values are kept in memory, one of texture_files.STORED_TYPES
                    ("uint8", "uint16", "half", "float")
    file_levels   : MIP levels the file holds (1: the image alone)
    wrap_modes    : (s, t) from the ``wrapmodes`` metadata, None where absent
    """

    width: int
    height: int
    channels: int
    stored: str
    file_levels: int
    wrap_modes: tuple[WrapMode | None, WrapMode | None]


@dataclass(frozen=True)
class TextureImage:
    """An image a material or a light reads: decoded, or a file the tracer reads lazily.

    pixels : (h, w, c) float32, linear values (``sourceColorSpace`` already applied), the
             file's channels: c = 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA (lookups read
             grey as rgb and a missing alpha as 1, as UsdUVTexture expands them);
             row 0 is the **top** row of the file, so UsdUVTexture's st = (0, 0) is
             ``pixels[h - 1, 0]``. None: not decoded — ``path`` is a file on disk that the
             tracer's texture cache (trace/texture_cache.py) reads at the MIP levels the
             frame needs, in its own precision, decoding ``color_space`` at lookup.
    header      : the file's header (lazy images; None for decoded ones)
    color_space : "raw" or "sRGB", how a lazy image's colour channels are decoded
    user        : the prim that first reads it, for the warnings about it
    """

    path: str
    pixels: np.ndarray | None = None
    header: TextureHeader | None = None
    color_space: str = "raw"
    user: str = ""


Color = tuple[float, float, float] | ShaderNode
Scalar = float | ShaderNode


@dataclass(frozen=True)
class Material:
    """A surface as the tracer's lobes see it: UsdPreviewSurface's inputs (with the spec's
    fallbacks for anything not authored) and what MaterialX looks add to them.

    Any input typed Color or Scalar is a constant or a ShaderNode tree evaluated per
    shading point (shader_nodes.py: components 0–2 of a colour, 0 of a scalar).

    opacity       presence: below opacity_threshold the surface is cut out; with
                  opacity_threshold 0, a fraction 1 − opacity of the light passes straight
                  through (alpha blending, as Storm and the UsdPreviewSurface spec's
                  "translucent" read it; no refraction).
    normal        tangent-space shading normal (x along ∂P/∂s, y along ∂P/∂t, z the
                  interpolated normal), unnormalised; None: the interpolated normal.
    transmission  the fraction of the non-metallic base that is a smooth dielectric of
                  ``ior`` (refraction, tinted by transmission_color) instead of diffuse;
                  thin_walled: the dielectric is a thin sheet (no bending).
    hair          a MaterialX chiang_hair_bsdf (trace/hair.py) instead of the surface lobes:
                  the hair_* fields are its inputs (tint_R, tint_TT, tint_TRT,
                  roughness_R/TT/TRT as (longitudinal variance v, azimuthal s),
                  cuticle_angle, absorption_coefficient), with ``ior``; the surface fields
                  other than opacity and emission are unused.
    """

    name: str
    path: str
    diffuse_color: Color = (0.18, 0.18, 0.18)
    emissive_color: Color = (0.0, 0.0, 0.0)
    roughness: Scalar = 0.5
    metallic: Scalar = 0.0
    specular_color: Color = (0.0, 0.0, 0.0)
    use_specular_workflow: bool = False
    ior: float = 1.5
    opacity: Scalar = 1.0
    opacity_threshold: float = 0.0
    clearcoat: Scalar = 0.0
    clearcoat_roughness: Scalar = 0.01
    normal: ShaderNode | None = None
    transmission: Scalar = 0.0
    transmission_color: Color = (1.0, 1.0, 1.0)
    thin_walled: bool = False
    hair: bool = False
    hair_tint_r: Color = (1.0, 1.0, 1.0)
    hair_tint_tt: Color = (1.0, 1.0, 1.0)
    hair_tint_trt: Color = (1.0, 1.0, 1.0)
    hair_roughness_r: tuple[float, float] = (0.1, 0.1)
    hair_roughness_tt: tuple[float, float] = (0.05, 0.05)
    hair_roughness_trt: tuple[float, float] = (0.2, 0.2)
    hair_cuticle_angle: float = 0.5
    hair_absorption: Color = (0.0, 0.0, 0.0)

    @property
    def emits(self) -> bool:
        """Whether the surface may send light of its own (a textured emission may)."""
        return isinstance(self.emissive_color, ShaderNode) or max(self.emissive_color) > 0


DEFAULT_MATERIAL_PATH = "<default>"


@dataclass(frozen=True)
class Mesh:
    """One renderable gprim (or one instance of it), triangulated, in world space.

    points            : (v, 3) float32, metres, world space
    triangles         : (t, 3) int32 indices into points, counter-clockwise seen from the
                        front (``orientation = leftHanded`` already flipped)
    normal_values     : (n, 3) float32 unit shading normals, world space, or None (flat
                        shading from the geometric normal); rows no corner refers to are
                        unspecified
    normal_indices    : (t, 3) int32 index into normal_values per triangle corner (None with
                        it). Smooth meshes have one normal per point (often ``triangles``
                        itself); hard edges and faceVarying normals add values of their own.
    uvs               : (t, 3, 2) float32 st per triangle corner (the primvar the bound
                        material reads), or None
    triangle_material : (t,) int32 index into SceneData.materials (GeomSubsets resolved)
    primvars          : name → (t, 3, w) float32 values per triangle corner of the primvars
                        its materials' primvar readers read (w = 1–4 components)
    instance          : for a point-instanced gprim, N, its instance's position in the
                        innermost UsdGeom.PointInstancer's arrays (the ``instance_<N>`` of
                        its path); -1 for a gprim that is not point-instanced. Native
                        (scenegraph) instances are not point instances: -1.
    prototype         : -1: points and normals are in world metres, as above. Else the
                        mesh is one placement of a surface it shares with every mesh of the
                        same prototype number: they share every geometry array (points,
                        triangles, normal_values, normal_indices, uvs, triangle_material,
                        primvars: the same objects), in the surface's own space, and the
                        tracer builds that geometry once and instances it (Embree two-level
                        scenes) instead of a copy per placement.
    world_from_points : with a prototype, (4, 4) float64, column convention: the placement,
                        own space → world metres; a similarity (rotation, mirror, uniform
                        scale, translation). None without one.
    motion_points     : for a mesh that moves over the camera's shutter (prototype −1 only),
                        (k, v, 3) float32 its points in world metres at k ≥ 2 evenly spaced
                        times from shutter:open (0) to shutter:close (k − 1), every moving
                        mesh of a scene at the same k (SceneData's motion steps); None: it
                        stands still (points is where it is at the frame's time either way)
    motion_normals    : (k, n, 3) float32 normal_values at those times; None without
                        motion_points or without normal_values
    motion_world_from_points : for a placement of a prototype that moves over the shutter,
                        (k, 4, 4) float64 its placements (similarities, metres) at those k
                        times; None: it stands still

    The placements of one surface share their read-only triangles, normal_indices and uvs
    arrays; only points and normal_values are their own (all of them, when instanced).
    """

    name: str
    path: str
    points: np.ndarray
    triangles: np.ndarray
    normal_values: np.ndarray | None
    normal_indices: np.ndarray | None
    uvs: np.ndarray | None
    triangle_material: np.ndarray
    instance: int = -1
    primvars: Mapping[str, np.ndarray] = field(default_factory=dict)
    prototype: int = -1
    world_from_points: np.ndarray | None = None
    motion_points: np.ndarray | None = None
    motion_normals: np.ndarray | None = None
    motion_world_from_points: np.ndarray | None = None

    @property
    def normals(self) -> np.ndarray | None:
        """(t, 3, 3) float32 unit shading normal per triangle corner (a new array), or None."""
        if self.normal_values is None:
            return None
        return np.take(self.normal_values, self.normal_indices, axis=0)


StrandShape = Literal["linear", "bezier", "bspline", "catmullRom", "sphere"]


@dataclass(frozen=True)
class Strands:
    """A BasisCurves or Points prim as Embree draws it, world metres: round tubes swept along
    its curves (a sphere at every point of the curve, of its radius there), or spheres.

    shape    : the curves' basis ("linear", or cubic "bezier", "bspline", "catmullRom"), or
               "sphere" for points
    vertices : (v, 4) float32 control points x, y, z and radius (metres), each curve's in
               order (periodic and pinned curves with their wrapped or phantom vertices)
    segments : (s,) int32 the first vertex of each segment, which reads 2 vertices (linear)
               or 4 (cubic); for points, every vertex (one sphere each)
    material : index into SceneData.materials
    normals  : (v, 3) float32 unit normals at the vertices of curves drawn as flat ribbons
               facing them (cubic shapes only: linear ribbons are given as bezier); None:
               round tubes
    motion_vertices : (k, v, 4) float32 the vertices at k ≥ 2 evenly spaced times over the
               shutter (Embree interpolates between them at each ray's time), or None for
               strands that stand still (``vertices`` are the frame's either way)
    """

    name: str
    path: str
    shape: StrandShape
    vertices: np.ndarray
    segments: np.ndarray
    material: int
    normals: np.ndarray | None = None
    motion_vertices: np.ndarray | None = None

    @property
    def span(self) -> int:
        """Vertices from a segment's first to its last: 0 for a sphere, 1 linear, 3 cubic."""
        return {"sphere": 0, "linear": 1}.get(self.shape, 3)


LightKind = Literal["rect", "disk", "sphere", "cylinder", "distant", "dome", "point", "line"]


@dataclass(frozen=True)
class IesProfile:
    """An IES LM-63 photometric profile (type C), as stage/ies.py reads it.

    vertical   : (V,) float64 radians, ascending, 0 = the light's emission axis (−Z, "down"
                 in IES terms) up to at most π
    horizontal : (H,) float64 radians, ascending from 0 to 2π inclusive: the file's
                 symmetries (one plane, a quadrant, a half) already unfolded (then
                 candela[0] == candela[-1]; a full 0–360° file keeps its own 360° plane)
    candela    : (H, V) float64 luminous intensity, the file's candela multiplier and ballast
                 factor applied
    power      : the profile's mean intensity (candela) over the sphere, or over the
                 hemisphere when its vertical angles span no more than π/2 (+0.1 rad): the
                 divisor ``shaping:ies:normalize`` applies (as hdEmbree, Karma and RenderMan do)
    """

    path: str
    vertical: np.ndarray
    horizontal: np.ndarray
    candela: np.ndarray
    power: float


@dataclass(frozen=True)
class LightShaping:
    """UsdLuxShapingAPI of one light, with the UsdLux documentation's semantics (evaluated
    in trace/light_kernels/shaping.py). θ is the angle between the light's −Z axis and the emission
    direction; the factors multiply the light's radiance:

    cone      : 1 − smoothstep(θ; cone_angle · (1 − cone_softness), cone_angle), in radians
                from the degrees here (softness 0: 1 up to cone_angle, 0 beyond)
    focus     : lerp(|cos θ|^focus, focus_tint, 1) per channel, when focus > 0
    ies       : the profile's intensity at (θ scaled by ies_angle_scale, φ), divided by its
                power when ies_normalize

    cone_softness is clamped to [0, 1], and a negative cone_angle or focus read as 0, by the
    reader. The reader gives a light a LightShaping only when one of these changes its
    emission.
    """

    cone_angle: float = 180.0
    cone_softness: float = 0.0
    focus: float = 0.0
    focus_tint: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ies: IesProfile | None = None
    ies_angle_scale: float = 0.0
    ies_normalize: bool = False


@dataclass(frozen=True)
class Light:
    """A UsdLux light.

    world_from_light : (4, 4) float64; maps the light's local frame (emission along −Z
                       for rect/disk/distant, UsdLux sizes in local units) to world metres.
    radiance         : (3,) float64 emitted radiance (see module docstring). For a distant
                       light this is the radiance inside its cone; with ``angle = 0`` it is
                       the irradiance on a surface facing the light.
    width, height    : rect size in local units
    radius           : disk / sphere / cylinder radius in local units
    length           : cylinder length along local X in local units
    angle            : distant light angular diameter in degrees
    texture          : index into SceneData.textures, None = constant: a dome's lat-long
                       image (its orientation, ``poleAxis`` and up axis, in world_from_light),
                       or a rect's colour map, whose top-left corner is at local (+X, +Y) and
                       bottom-right at (−X, −Y) (UsdLux RectLight), so it reads unmirrored from
                       the lit side
    shaping          : ShapingAPI controls that change the emission, None = none
    diffuse, specular: UsdLux's non-physical multipliers of the light's effect on diffuse and
                       on every other (specular, coat, transmission) response
    camera_visible   : whether camera rays see the light's shape (or a dome as background);
                       reflections and everything else always see it
    light_link       : indices into SceneData.meshes this light illuminates, None = every mesh
                       (``collection:lightLink``); emissive surfaces are not linked
    shadow_link      : indices into SceneData.meshes that block this light, None = every mesh
                       and light shape (``collection:shadowLink``); with a tuple, only those
                       meshes block it (no light shape does)

    kind "point" is a SphereLight with ``treatAsPoint`` and "line" a CylinderLight with
    ``treatAsLine``: collapsed to their centre or axis with the power of the shape they stand
    for (radius, length as authored), so the hint changes noise, not brightness; they have no
    shape to hit (never seen by camera or BSDF rays).
    """

    name: str
    path: str
    kind: LightKind
    world_from_light: np.ndarray
    radiance: np.ndarray
    width: float = 1.0
    height: float = 1.0
    radius: float = 0.5
    length: float = 1.0
    angle: float = 0.53
    texture: int | None = None
    shaping: LightShaping | None = None
    diffuse: float = 1.0
    specular: float = 1.0
    camera_visible: bool = True
    light_link: tuple[int, ...] | None = None
    shadow_link: tuple[int, ...] | None = None


@dataclass(frozen=True)
class Camera:
    """A UsdGeom.Camera.

    world_from_camera : (4, 4) float64, camera looks along its local −Z with +Y up,
                        translation in metres (any scale removed)
    focal_length, *_aperture, *_aperture_offset : in the same (authored) unit, only their
                        ratios matter for the field of view
    clipping          : (near, far) in metres
    lens_radius       : the thin lens's aperture radius in metres, focalLength / (2 · fStop)
                        (0: a pinhole, everything sharp; UsdGeom's fStop fallback)
    focus_distance    : metres from the lens to the plane in focus (> 0 with a lens)
    motion_times      : (k,) float64 the times, in frames relative to the frame rendered, from
                        shutter:open to shutter:close, at which the camera moves (its transform's
                        own samples between them); empty: it stands still over the shutter
    motion_transforms : (k, 4, 4) float64 world_from_camera at each of them (rigid, metres)
    shutter           : (shutter:open, shutter:close) in frames relative to the frame rendered,
                        open ≤ close (an instant when equal): when objects move too
    """

    name: str
    path: str
    world_from_camera: np.ndarray
    projection: Literal["perspective", "orthographic"] = "perspective"
    focal_length: float = 50.0
    horizontal_aperture: float = 20.955
    vertical_aperture: float = 15.2908
    horizontal_aperture_offset: float = 0.0
    vertical_aperture_offset: float = 0.0
    clipping: tuple[float, float] = (0.01, 1.0e6)
    lens_radius: float = 0.0
    focus_distance: float = 0.0
    motion_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    motion_transforms: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    shutter: tuple[float, float] = (0.0, 0.0)


DEFAULT_INCLUDED_PURPOSES = ("default", "render")
"""Gprim purposes that render without RenderSettings (UsdRender's includedPurposes fallback)."""
DEFAULT_BINDING_PURPOSES = ("full", "")
"""Material binding purposes, strongest first, without RenderSettings ("" = allPurpose)."""


@dataclass(frozen=True)
class RenderSpec:
    """What to render at one frame, flattened from the recipe, its RenderSettings and the
    request (after OpenUSD's UsdRenderComputeSpec): the one source for the stage's read and
    the tracer.

    camera                    : the render camera at the frame
    resolution                : (width, height) in pixels
    pixel_aspect_ratio        : a pixel's width over its height: the image's aspect ratio
                                is width × pixel_aspect_ratio / height (the products'
                                Product.pixel_aspect_ratio, adjustPixelAspectRatio resolved;
                                their EXR headers say the same)
    aspect_ratio_conform_policy : how the camera's aperture fits that aspect (UsdRender's
                                aspectRatioConformPolicy, recipe.model.CONFORM_POLICIES)
    settings_path             : the RenderSettings prim read, if any
    included_purposes         : gprim purposes that render (the settings' includedPurposes)
    material_binding_purposes : binding purposes, strongest first ("" = allPurpose)
    frame                     : the time code asked for; None = the stage's start (NaN in
                                SceneData.frame when the stage has none: the earliest sample)
    depth_of_field            : whether the camera's lens blurs what is out of focus (the
                                settings' disableDepthOfField turns it off)
    motion_blur               : whether the shutter stays open (the settings'
                                disableMotionBlur or instantaneousShutter close it)
    recipe                    : the recipe the frame delivers
    """

    camera: Camera
    resolution: tuple[int, int] = DEFAULT_RESOLUTION
    pixel_aspect_ratio: float = DEFAULT_PIXEL_ASPECT_RATIO
    aspect_ratio_conform_policy: str = DEFAULT_CONFORM_POLICY
    settings_path: str | None = None
    included_purposes: tuple[str, ...] = DEFAULT_INCLUDED_PURPOSES
    material_binding_purposes: tuple[str, ...] = DEFAULT_BINDING_PURPOSES
    frame: float | None = None
    depth_of_field: bool = True
    motion_blur: bool = True
    recipe: Recipe | None = None


@dataclass(frozen=True)
class SceneData:
    """Everything the tracer needs about a stage at one time code."""

    stage_path: str
    frame: float
    meshes: tuple[Mesh, ...]
    materials: tuple[Material, ...]
    lights: tuple[Light, ...]
    textures: tuple[TextureImage, ...] = ()
    strands: tuple[Strands, ...] = ()
    meters_per_unit: float = 1.0
    up_axis: Literal["Y", "Z"] = "Y"
    warnings: tuple[str, ...] = field(default=())
