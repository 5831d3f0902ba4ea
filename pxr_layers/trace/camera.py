"""A UsdGeom pinhole camera with UsdRender's aperture conform policies (its rays are cast by
stages/camera.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import RenderSettingsError
from ..scene import FLOAT, RenderSpec


@dataclass(frozen=True)
class PinholeCamera:
    """Maps film positions to world rays.

    position          : (3,) metres
    world_from_camera : (3, 3) rotation (camera looks along −Z, +Y up)
    half_width, half_height : the film window at unit distance (tangents of half the FOV)
    offset_x, offset_y      : window centre at unit distance (aperture offsets)
    """

    position: np.ndarray
    world_from_camera: np.ndarray
    half_width: float
    half_height: float
    offset_x: float
    offset_y: float
    t_max: float

    @classmethod
    def from_spec(cls, spec: RenderSpec) -> PinholeCamera:
        camera = spec.camera
        if camera.projection != "perspective":
            raise RenderSettingsError(f"camera {camera.path}: {camera.projection} projection is not supported yet")
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
        # adjustPixelAspectRatio keeps both apertures: pixels stretch instead.
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
        )
