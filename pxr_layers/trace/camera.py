"""A UsdGeom camera, a thin lens (a pinhole without depth of field), with UsdRender's
aperture conform policies (its rays are cast by stages/camera.py)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import RenderSettingsError
from ..recipe.model import fitted_pixel_aspect, view_problem
from ..scene import RenderSpec

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class ThinLensCamera:
    """Maps film positions and lens positions to world rays.

    position          : (3,) metres, the lens's centre
    world_from_camera : (3, 3) rotation (camera looks along −Z, +Y up)
    half_width, half_height : the film window at unit distance (tangents of half the FOV)
    offset_x, offset_y      : window centre at unit distance (aperture offsets)
    t_max             : the far clipping distance, metres
    lens_radius       : metres; 0 is a pinhole (no depth of field)
    focus_distance    : metres along −Z to the plane in focus (what the film window, scaled
                        by it, shows sharp)
    motion_times      : (k,) float64 shutter fractions in [0, 1], ascending, 0 and 1 at its
                        ends, at which the camera's pose is known; empty: it stands still
    motion_rotations  : (k, 4) float64 unit quaternions (w, x, y, z) of world_from_camera there,
                        each on the same side as the one before (the short way round)
    motion_positions  : (k, 3) float64 metres

    Motion: each camera sample opens at a time drawn over the shutter (uniform, stratified
    over a pixel's samples), and the camera's pose there is interpolated between the two
    known poses around it (positions linearly, rotations by slerp): the camera's motion blur.

    The thin lens as pbrt's (Pharr et al., "Physically Based Rendering", 4th ed., 5.2.3):
    the pinhole's ray through a film position meets the plane in focus at one point; every
    ray from the lens disc toward that point makes the pixel. A point at distance d images
    to a disc of radius lens_radius · |d − focus_distance| / (d · focus_distance) at unit
    distance: the circle of confusion, as a real lens of that focal length and f-number
    focused there gives (the field of view being the pinhole's, focused at infinity).
    """

    position: np.ndarray
    world_from_camera: np.ndarray
    half_width: float
    half_height: float
    offset_x: float
    offset_y: float
    t_max: float
    lens_radius: float = 0.0
    focus_distance: float = 0.0
    motion_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    motion_rotations: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    motion_positions: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @classmethod
    def from_spec(cls, spec: RenderSpec) -> ThinLensCamera:
        """The camera of ``spec``: a pixel is ``spec.pixel_aspect_ratio`` times as wide as it
        is tall, so the image aspect is width × pixel_aspect_ratio / height, and the
        aperture is fitted to it by ``spec.aspect_ratio_conform_policy`` (UsdRender's
        rules). Its lens is the camera's unless ``spec.depth_of_field`` is off, its motion
        over the shutter unless ``spec.motion_blur`` is. Raises RenderSettingsError for a
        projection other than perspective, a pixel aspect ratio that is not a positive
        number or an unknown policy."""
        camera = spec.camera
        if camera.projection != "perspective":
            raise RenderSettingsError(f"camera {camera.path}: {camera.projection} projection is not supported yet")
        problem = view_problem(spec.pixel_aspect_ratio, spec.aspect_ratio_conform_policy)
        if problem:
            raise RenderSettingsError(f"{spec.settings_path or 'the render settings'}: {problem[0]} {problem[1]}")
        width, height = spec.resolution
        h_aperture, v_aperture = camera.horizontal_aperture, camera.vertical_aperture
        image_aspect = width * spec.pixel_aspect_ratio / height
        aperture_aspect = h_aperture / v_aperture
        policy = spec.aspect_ratio_conform_policy
        if policy == "adjustApertureWidth" or (policy == "expandAperture" and image_aspect > aperture_aspect) or (
            policy == "cropAperture" and image_aspect < aperture_aspect
        ):
            h_aperture = v_aperture * image_aspect
        elif policy in ("adjustApertureHeight", "expandAperture", "cropAperture"):
            v_aperture = h_aperture / image_aspect
        else:  # adjustPixelAspectRatio keeps both apertures: pixels stretch instead.
            stretched = fitted_pixel_aspect((h_aperture, v_aperture), spec.resolution)
            if not math.isclose(stretched, spec.pixel_aspect_ratio, rel_tol=1e-5):
                logger.warning("camera %s: adjustPixelAspectRatio stretches the pixels to %g at %dx%d, but the "
                               "recipe resolved them to %g (another resolution, or animated apertures): the "
                               "EXR headers say %g", camera.path, stretched, width, height,
                               spec.pixel_aspect_ratio, spec.pixel_aspect_ratio)
        matrix = np.asarray(camera.world_from_camera, np.float64)
        rotation = matrix[:3, :3] / np.linalg.norm(matrix[:3, :3], axis=0, keepdims=True)
        focal = camera.focal_length
        return cls(
            position=matrix[:3, 3].astype(np.float64),
            world_from_camera=rotation,
            half_width=h_aperture / 2 / focal,
            half_height=v_aperture / 2 / focal,
            offset_x=camera.horizontal_aperture_offset / focal,
            offset_y=camera.vertical_aperture_offset / focal,
            t_max=float(camera.clipping[1]),
            lens_radius=camera.lens_radius if spec.depth_of_field else 0.0,
            focus_distance=camera.focus_distance,
            **(_motion(camera.motion_times, camera.motion_transforms) if spec.motion_blur else {}),
        )


def _motion(times: np.ndarray, transforms: np.ndarray) -> dict[str, np.ndarray]:
    """ThinLensCamera's motion fields from scene.Camera's (times in frames, (k, 4, 4) rigid
    transforms); none for a camera standing still."""
    if len(times) < 2:
        return {}
    rotations = np.array([_quaternion(transform[:3, :3]) for transform in transforms])
    for number in range(1, len(rotations)):  # q and −q are one rotation: take the short way
        if rotations[number] @ rotations[number - 1] < 0:
            rotations[number] = -rotations[number]
    return {"motion_times": (times - times[0]) / (times[-1] - times[0]), "motion_rotations": rotations,
            "motion_positions": np.ascontiguousarray(transforms[:, :3, 3], np.float64)}


def _quaternion(rotation: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a (3, 3) rotation matrix (Shepperd's method: from
    its largest diagonal term, so no division by a small number)."""
    trace = np.trace(rotation)
    m = rotation
    if trace > max(m[0, 0], m[1, 1], m[2, 2]):
        w = math.sqrt(1 + trace) / 2
        q = [w, (m[2, 1] - m[1, 2]) / (4 * w), (m[0, 2] - m[2, 0]) / (4 * w), (m[1, 0] - m[0, 1]) / (4 * w)]
    elif m[0, 0] >= m[1, 1] and m[0, 0] >= m[2, 2]:
        x = math.sqrt(1 + 2 * m[0, 0] - trace) / 2
        q = [(m[2, 1] - m[1, 2]) / (4 * x), x, (m[0, 1] + m[1, 0]) / (4 * x), (m[0, 2] + m[2, 0]) / (4 * x)]
    elif m[1, 1] >= m[2, 2]:
        y = math.sqrt(1 + 2 * m[1, 1] - trace) / 2
        q = [(m[0, 2] - m[2, 0]) / (4 * y), (m[0, 1] + m[1, 0]) / (4 * y), y, (m[1, 2] + m[2, 1]) / (4 * y)]
    else:
        z = math.sqrt(1 + 2 * m[2, 2] - trace) / 2
        q = [(m[1, 0] - m[0, 1]) / (4 * z), (m[0, 2] + m[2, 0]) / (4 * z), (m[1, 2] + m[2, 1]) / (4 * z), z]
    q = np.array(q)
    return q / np.linalg.norm(q)
