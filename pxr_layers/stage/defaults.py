"""What a stage without a camera or without lights gets, as usdview and usdrecord give it.

Both are authored as ordinary prims in the shot's session layer, under ``/pxrLayers``, so
everything downstream sees them as it sees the stage's own: the camera is a UsdGeom.Camera
that recipes and ``--camera`` can name, the lights are UsdLux prims whose names label their
path events (``C.*<L.'defaultKey'>``) and get per-light layers.

The automatic camera (``/pxrLayers/autoCamera``), aimed anew at every frame, looks at the
bounding box of what renders (the render purposes, at the frame's time) from the stage's
front, as usdview's and usdrecord's free camera does: from +Z looking down −Z on a Y-up stage,
from −Y looking down +Y on a Z-up one, its up the stage's up axis (``--auto-camera
three-quarter``: from 30° to the right and 20° above instead). A flat subject, less than a
tenth as tall as it is deep (a ground with decals), is seen from 45° above: from the front it
would be a line. Its 35 mm lens has a gate of the
render's own aspect ratio (36 mm wide), and it stands as close as it can while all eight
corners of the box project inside the frame with a margin (the box fills 1/AUTO_CAMERA_MARGIN
of the frame's width or height, whichever binds: a tight fit of the box, not of its bounding
sphere). A coarse subdivision cage counts by its limit surface, which renders, not by its
cage. Its clipping range hugs the box.

The default rig (``/pxrLayers/defaultLights``) is a look-development turntable rig placed
from the render camera at every frame (directions from the camera's heading, elevations from
the stage's up axis, so the rig turns with the camera and never lights from below):

* ``defaultKey``: a DistantLight from 45° to the camera's left and 35° above, irradiance 5;
* ``defaultFill``: from 60° to the right and 10° above, irradiance 1.25 (a 4:1 key-to-fill);
* ``defaultRim``: from behind, 150° to the right and 40° above, irradiance 3: an edge light;
* ``defaultDome``: a white DomeLight of radiance 0.3, which also reads as a mid-grey backdrop.

The distant lights are ``normalize``d, so their intensity is the irradiance they give a
surface facing them, whatever their angle. A 0.18 grey card facing the camera comes out near
0.25 (mid grey in an sRGB preview); a white diffuse surface facing the key near 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdSkel

from pxr_layers.errors import PxrLayersError
from pxr_layers.request import AUTO_CAMERA_VIEWS

from .surfaces import refined_control_points

ROOT = "/pxrLayers"
AUTO_CAMERA_PATH = f"{ROOT}/autoCamera"
DEFAULT_LIGHTS_PATH = f"{ROOT}/defaultLights"

AUTO_CAMERA_THREE_QUARTER_DEGREES = (30.0, 20.0)  # azimuth to the right, elevation
AUTO_CAMERA_FOCAL_LENGTH_MM = 35.0
AUTO_CAMERA_APERTURE_WIDTH_MM = 36.0
AUTO_CAMERA_MARGIN = 1.15  # the box spans 87 % of the binding dimension
# A subject less than this tall for its depth (a ground, decals on it) is seen from this
# elevation (degrees): from the front it would be an edge, a line of pixels.
AUTO_CAMERA_FLAT_RATIO = 0.1
AUTO_CAMERA_FLAT_ELEVATION = 45.0
FRAMING_REFINED_FACES = 2048  # cages up to this many faces are framed by their limit surface

DEFAULT_UV_SET = "st"  # the texture coordinates a texture reads when nothing names them (USD's convention)


@dataclass(frozen=True)
class RigLight:
    """One distant light of the default rig: where it comes from relative to the camera
    (degrees: azimuth to the camera's right from its view axis, elevation above the
    horizon), its irradiance and its angular diameter."""

    name: str
    azimuth: float
    elevation: float
    irradiance: float
    angle: float


DEFAULT_DOME_NAME = "defaultDome"
DEFAULT_DOME_INTENSITY = 0.3
DEFAULT_RIG = (
    RigLight("defaultKey", -45.0, 35.0, 5.0, 3.0),
    RigLight("defaultFill", 60.0, 10.0, 1.25, 10.0),
    RigLight("defaultRim", 150.0, 40.0, 3.0, 3.0),
)


def _from_y_up(vector: np.ndarray, up_axis: str) -> np.ndarray:
    """A direction given for a Y-up stage, on a stage of ``up_axis`` (Z-up: front is −Y)."""
    x, y, z = vector
    return np.array([x, -z, y]) if up_axis == "Z" else np.array([x, y, z])


def _looking_along(direction: np.ndarray, up: np.ndarray) -> np.ndarray:
    """(3, 3) rotation, rows = the local X, Y, Z axes in world space (USD's row convention),
    whose local −Z points along ``direction`` and whose local +Y leans toward ``up``."""
    back = -direction / np.linalg.norm(direction)
    right = np.cross(up, back)
    if np.linalg.norm(right) < 1e-9:  # looking straight up or down
        right = np.cross(np.array([1.0, 0.0, 0.0]) if abs(back[0]) < 0.9 else np.array([0.0, 1.0, 0.0]), back)
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(back, right), back])


def _up_vector(up_axis: str) -> np.ndarray:
    return np.array([0.0, 0.0, 1.0]) if up_axis == "Z" else np.array([0.0, 1.0, 0.0])


def _define_in_session(stage: Usd.Stage):
    """An edit context writing to the session layer (the stage's own layers stay untouched)."""
    return Usd.EditContext(stage, Usd.EditTarget(stage.GetSessionLayer()))


def _transform(rotation_rows: np.ndarray, translation: np.ndarray) -> Gf.Matrix4d:
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_rows
    matrix[3, :3] = translation
    return Gf.Matrix4d(*matrix.ravel().tolist())


def _set_transform(xformable: UsdGeom.Xformable, matrix: Gf.Matrix4d) -> None:
    xformable.ClearXformOpOrder()
    xformable.AddTransformOp().Set(matrix)


def define_auto_camera(stage: Usd.Stage) -> str:
    """Define the automatic camera (not yet aimed: :func:`frame_auto_camera` aims it per frame)."""
    with _define_in_session(stage):
        camera = UsdGeom.Camera.Define(stage, AUTO_CAMERA_PATH)
        camera.CreateFocalLengthAttr(AUTO_CAMERA_FOCAL_LENGTH_MM)
        camera.CreateHorizontalApertureAttr(AUTO_CAMERA_APERTURE_WIDTH_MM)
    return AUTO_CAMERA_PATH


def frame_auto_camera(stage: Usd.Stage, time: Usd.TimeCode, purposes: tuple[str, ...], up_axis: str,
                      aspect: float, view: str = AUTO_CAMERA_VIEWS[0]) -> bool:
    """Aim the automatic camera at the bounding box of what renders at ``time``.

    purposes : the gprim purposes that render (the settings' includedPurposes)
    aspect   : the render's width / height (pixel aspect included): the gate's own
    view     : one of AUTO_CAMERA_VIEWS (request.py)
    Returns False when nothing has a bounding box (a dome alone): the camera then stands at
    the origin looking to the front, which is all a sky needs.
    """
    tokens = [UsdGeom.Tokens.default_ if purpose == "default" else purpose for purpose in purposes]
    box = _subject_box(stage, UsdGeom.BBoxCache(time, tokens, useExtentsHint=True), time)
    up = _up_vector(up_axis)
    assert view in AUTO_CAMERA_VIEWS, view
    azimuth, elevation = AUTO_CAMERA_THREE_QUARTER_DEGREES if view == "three-quarter" else (0.0, 0.0)
    framed = not box.IsEmpty() and all(math.isfinite(value) for value in (*box.GetMin(), *box.GetMax()))
    if framed:
        low, high = np.array(box.GetMin(), dtype=np.float64), np.array(box.GetMax(), dtype=np.float64)
        front = _from_y_up(np.array([0.0, 0.0, 1.0]), up_axis)
        if np.dot(high - low, up) < AUTO_CAMERA_FLAT_RATIO * np.dot(high - low, np.abs(front)):
            elevation = max(elevation, AUTO_CAMERA_FLAT_ELEVATION)  # a ground seen edge-on is nothing
    azimuth, elevation = math.radians(azimuth), math.radians(elevation)
    toward_eye = _from_y_up(np.array([math.sin(azimuth) * math.cos(elevation), math.sin(elevation),
                                      math.cos(azimuth) * math.cos(elevation)]), up_axis)
    rotation = _looking_along(-toward_eye, up)
    if framed:
        centre = 0.5 * (low + high)
        corners = np.array([[(low, high)[(i >> axis) & 1][axis] for axis in range(3)] for i in range(8)])
        right, camera_up, back = ((corners - centre) @ rotation.T).T
        # Half-widths of the frame per unit of depth, shrunk by the margin; a corner at
        # (x, y, z) in the camera's axes fits when |x| <= tan * (distance - z).
        tan_x = 0.5 * AUTO_CAMERA_APERTURE_WIDTH_MM / AUTO_CAMERA_FOCAL_LENGTH_MM / AUTO_CAMERA_MARGIN
        tan_y = tan_x / aspect
        extent = max(float(np.linalg.norm(high - low)), 1e-6)
        distance = float(np.max(np.maximum(back + np.abs(right) / tan_x, back + np.abs(camera_up) / tan_y)))
        distance = max(distance, float(back.max()) + 1e-3 * extent)  # every corner in front of the lens
        eye = centre + toward_eye * distance
        clipping = (0.5 * (distance - float(back.max())), 2.0 * (distance - float(back.min())))
    else:
        eye, clipping = np.zeros(3), (0.01, 1.0e6)
    with _define_in_session(stage):
        camera = UsdGeom.Camera.Get(stage, AUTO_CAMERA_PATH)
        _set_transform(camera, _transform(rotation, eye))
        camera.CreateClippingRangeAttr(Gf.Vec2f(*clipping))
        camera.CreateVerticalApertureAttr(AUTO_CAMERA_APERTURE_WIDTH_MM / aspect)
    return framed


def _subject_box(stage: Usd.Stage, cache: UsdGeom.BBoxCache, time: Usd.TimeCode) -> Gf.Range3d:
    """The world box of what renders: each boundable's bound (visibility and purposes as
    ``cache`` computes them), a coarse subdivision cage's replaced by its limit surface's. An
    instance counts by its whole bound (cages included): a set of thousands of instances is
    not walked prim by prim at every frame."""
    box = Gf.Range3d()
    file = stage.GetRootLayer().identifier
    prims = iter(Usd.PrimRange(stage.GetPseudoRoot()))
    for prim in prims:
        if is_ours(prim.GetPath()):  # not the draw-mode cards an earlier frame authored
            prims.PruneChildren()
            continue
        if not (prim.IsInstance() or prim.IsA(UsdGeom.Boundable)):
            continue
        prims.PruneChildren()  # the bound holds the children (a PointInstancer's prototypes)
        bound = cache.ComputeWorldBound(prim).ComputeAlignedRange()
        if not bound.IsEmpty() and prim.IsA(UsdGeom.Mesh):
            bound = _limit_surface_box(UsdGeom.Mesh(prim), time, file) or bound
        box.UnionWith(bound)
    return box


def _limit_surface_box(mesh: UsdGeom.Mesh, time: Usd.TimeCode, file: str) -> Gf.Range3d | None:
    """The world box of a coarse subdivision cage's limit surface, or None to keep its cage's.

    A coarse cage's limit surface can be far smaller than the cage (the no-crease pyramid's
    is 60 % of it); the hull of its twice-refined control points bounds it closely. Only
    cages of at most FRAMING_REFINED_FACES faces (a dense cage's limit is its cage), not
    skinned (posed later). Whatever the reader would refuse keeps the cage's box: the reader
    says why."""
    counts = mesh.GetFaceVertexCountsAttr().Get(time)
    if counts is None or len(counts) > FRAMING_REFINED_FACES or mesh.GetPrim().HasAPI(UsdSkel.BindingAPI):
        return None
    try:
        points = refined_control_points(mesh.GetPrim(), time, file, 2)
    except (ValueError, PxrLayersError):
        return None
    if points is None:
        return None
    world = np.asarray(mesh.ComputeLocalToWorldTransform(time))  # row vectors: p_world = p @ M
    points = points @ world[:3, :3] + world[3, :3]
    return Gf.Range3d(Gf.Vec3d(*points.min(axis=0)), Gf.Vec3d(*points.max(axis=0)))


def define_default_lights(stage: Usd.Stage) -> tuple[str, ...]:
    """Author the default rig (not yet aimed: :func:`aim_default_lights` aims it per frame);
    returns the light prim paths."""
    with _define_in_session(stage):
        UsdGeom.Scope.Define(stage, DEFAULT_LIGHTS_PATH)
        dome = UsdLux.DomeLight.Define(stage, f"{DEFAULT_LIGHTS_PATH}/{DEFAULT_DOME_NAME}")
        dome.CreateIntensityAttr(DEFAULT_DOME_INTENSITY)
        paths = [str(dome.GetPath())]
        for rig_light in DEFAULT_RIG:
            light = UsdLux.DistantLight.Define(stage, f"{DEFAULT_LIGHTS_PATH}/{rig_light.name}")
            light.CreateIntensityAttr(rig_light.irradiance)
            light.CreateAngleAttr(rig_light.angle)
            light.CreateNormalizeAttr(True)
            paths.append(str(light.GetPath()))
    return tuple(paths)


def aim_default_lights(stage: Usd.Stage, view_direction: np.ndarray, up_axis: str) -> None:
    """Turn the default rig to a camera looking along ``view_direction`` (3,), world space."""
    up = _up_vector(up_axis)
    heading = view_direction - np.dot(view_direction, up) * up
    if np.linalg.norm(heading) < 1e-6:  # looking straight down or up: head to the stage's front
        heading = -_from_y_up(np.array([0.0, 0.0, 1.0]), up_axis)
    heading = heading / np.linalg.norm(heading)
    right = np.cross(heading, up)
    with _define_in_session(stage):
        for rig_light in DEFAULT_RIG:
            azimuth, elevation = math.radians(rig_light.azimuth), math.radians(rig_light.elevation)
            toward_light = (math.cos(elevation) * (math.sin(azimuth) * right - math.cos(azimuth) * heading)
                            + math.sin(elevation) * up)
            # A distant light shines along its local −Z.
            light = UsdLux.DistantLight.Get(stage, f"{DEFAULT_LIGHTS_PATH}/{rig_light.name}")
            _set_transform(light, _transform(_looking_along(-toward_light, up), np.zeros(3)))


def is_ours(path: Sdf.Path | str) -> bool:
    """Whether a prim path is one pxr-layers authored (under ``/pxrLayers``)."""
    text = str(path)
    return text == ROOT or text.startswith(ROOT + "/")
