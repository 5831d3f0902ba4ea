"""What a stage without a camera or without lights gets, as usdview and usdrecord give it.

Both are authored as ordinary prims in the shot's session layer, under ``/pxrLayers``, so
everything downstream sees them as it sees the stage's own: the camera is a UsdGeom.Camera
that recipes and ``--camera`` can name, the lights are UsdLux prims whose names label their
path events (``C.*<L.'defaultKey'>``) and get per-light layers.

The automatic camera (``/pxrLayers/autoCamera``) frames the bounding box of what renders
(the render purposes, at the frame's time) from the front, 30° to the right and 20° above
(front is +Z on a Y-up stage, −Y on a Z-up stage, the view USD's own cameras have), with a
35 mm lens on a 36 × 24 mm gate: the box's bounding sphere fills the narrower field of view
with a 5 % margin. Its clipping range hugs that sphere.

The default rig (``/pxrLayers/defaultLights``) is a white DomeLight of intensity 0.5 and a
DistantLight ``defaultKey`` of intensity 3 (angle 2°) from the upper front left: a grey 0.18
diffuse card facing the key comes out near 0.26, mid-grey in an sRGB preview.
"""

from __future__ import annotations

import math

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

ROOT = "/pxrLayers"
AUTO_CAMERA_PATH = f"{ROOT}/autoCamera"
DEFAULT_LIGHTS_PATH = f"{ROOT}/defaultLights"

AUTO_CAMERA_AZIMUTH_DEGREES = 30.0
AUTO_CAMERA_ELEVATION_DEGREES = 20.0
AUTO_CAMERA_FOCAL_LENGTH_MM = 35.0
AUTO_CAMERA_APERTURE_MM = (36.0, 24.0)
_FRAMING_MARGIN = 1.05

DEFAULT_UV_SET = "st"  # the texture coordinates a texture reads when nothing names them (USD's convention)
DEFAULT_DOME_INTENSITY = 0.5
DEFAULT_KEY_INTENSITY = 3.0
DEFAULT_KEY_ANGLE_DEGREES = 2.0
# Where the key light comes from, on a Y-up stage: up, to the front, from the left.
_KEY_FROM_Y_UP = np.array([-0.5, 1.0, 0.7])


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
        camera.CreateHorizontalApertureAttr(AUTO_CAMERA_APERTURE_MM[0])
        camera.CreateVerticalApertureAttr(AUTO_CAMERA_APERTURE_MM[1])
    return AUTO_CAMERA_PATH


def frame_auto_camera(stage: Usd.Stage, time: Usd.TimeCode, purposes: tuple[str, ...], up_axis: str) -> bool:
    """Aim the automatic camera at the bounding box of what renders at ``time``.

    purposes : the gprim purposes that render (the settings' includedPurposes)
    Returns False when nothing has a bounding box (a dome alone): the camera then stands at
    the origin looking to the front, which is all a sky needs.
    """
    tokens = [UsdGeom.Tokens.default_ if purpose == "default" else purpose for purpose in purposes]
    cache = UsdGeom.BBoxCache(time, tokens, useExtentsHint=True)
    box = Gf.Range3d()
    for prim in stage.GetPseudoRoot().GetChildren():
        if not is_ours(prim.GetPath()):  # not the draw-mode cards an earlier frame authored
            box.UnionWith(cache.ComputeWorldBound(prim).ComputeAlignedRange())
    up = _up_vector(up_axis)
    azimuth = math.radians(AUTO_CAMERA_AZIMUTH_DEGREES)
    elevation = math.radians(AUTO_CAMERA_ELEVATION_DEGREES)
    toward_eye = _from_y_up(np.array([math.sin(azimuth) * math.cos(elevation), math.sin(elevation),
                                      math.cos(azimuth) * math.cos(elevation)]), up_axis)
    framed = not box.IsEmpty() and all(math.isfinite(value) for value in (*box.GetMin(), *box.GetMax()))
    if framed:
        centre = np.array(box.GetMidpoint(), dtype=np.float64)
        radius = max(0.5 * float(np.linalg.norm(np.array(box.GetSize()))), 1e-6)
        half_angle = math.atan(0.5 * min(AUTO_CAMERA_APERTURE_MM) / AUTO_CAMERA_FOCAL_LENGTH_MM)
        distance = _FRAMING_MARGIN * radius / math.sin(half_angle)
        eye = centre + toward_eye * distance
        clipping = (max(distance - radius, 0.0) * 0.5 or radius * 1e-3, (distance + radius) * 2.0)
        rotation = _looking_along(centre - eye, up)
    else:
        eye, clipping = np.zeros(3), (0.01, 1.0e6)
        rotation = _looking_along(-_from_y_up(np.array([0.0, 0.0, 1.0]), up_axis), up)
    with _define_in_session(stage):
        camera = UsdGeom.Camera.Get(stage, AUTO_CAMERA_PATH)
        _set_transform(camera, _transform(rotation, eye))
        camera.CreateClippingRangeAttr(Gf.Vec2f(*clipping))
    return framed


def define_default_lights(stage: Usd.Stage, up_axis: str) -> tuple[str, ...]:
    """Author the default rig; returns the light prim paths."""
    with _define_in_session(stage):
        UsdGeom.Scope.Define(stage, DEFAULT_LIGHTS_PATH)
        dome = UsdLux.DomeLight.Define(stage, f"{DEFAULT_LIGHTS_PATH}/defaultDome")
        dome.CreateIntensityAttr(DEFAULT_DOME_INTENSITY)
        key = UsdLux.DistantLight.Define(stage, f"{DEFAULT_LIGHTS_PATH}/defaultKey")
        key.CreateIntensityAttr(DEFAULT_KEY_INTENSITY)
        key.CreateAngleAttr(DEFAULT_KEY_ANGLE_DEGREES)
        # A distant light shines along its local −Z: toward the stage from where the key is.
        rotation = _looking_along(-_from_y_up(_KEY_FROM_Y_UP, up_axis), _up_vector(up_axis))
        _set_transform(key, _transform(rotation, np.zeros(3)))
    return (str(dome.GetPath()), str(key.GetPath()))


def is_ours(path: Sdf.Path | str) -> bool:
    """Whether a prim path is one pxr-layers authored (under ``/pxrLayers``)."""
    text = str(path)
    return text == ROOT or text.startswith(ROOT + "/")
