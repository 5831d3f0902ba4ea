"""What a RenderSettings prim says beyond the recipe, and the render camera → scene.Camera."""

from __future__ import annotations

import math

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdRender

from pxr_layers.errors import StageError
from pxr_layers.scene import DEFAULT_BINDING_PURPOSES, DEFAULT_INCLUDED_PURPOSES, Camera

from . import values
from .context import ReadContext
from .motion import transform_times
from .transforms import column_matrix, rigid_in_metres, transform_errors_name


def settings_fields(settings: UsdRender.Settings | None, time: Usd.TimeCode) -> dict[str, object]:
    """RenderSpec fields from the settings: the purposes of gprims that render and of
    material bindings (the defaults without settings), and whether depth of field is on
    (``disableDepthOfField``, the settings' own: every product of a frame shares one trace)
    and motion blur (``disableMotionBlur``, ``instantaneousShutter``).
    The products' view (camera, resolution, pixel aspect, conform policy) comes from the
    recipe (``Recipe.shared_view``)."""
    if settings is None:
        return {"included_purposes": DEFAULT_INCLUDED_PURPOSES, "material_binding_purposes": DEFAULT_BINDING_PURPOSES}
    purposes = settings.GetIncludedPurposesAttr().Get(time)
    return {
        "settings_path": str(settings.GetPath()),
        "included_purposes": DEFAULT_INCLUDED_PURPOSES if purposes is None else tuple(str(p) for p in purposes),
        "material_binding_purposes": _binding_purposes(settings, time),
        "depth_of_field": not settings.GetDisableDepthOfFieldAttr().Get(time),
        "motion_blur": not (settings.GetDisableMotionBlurAttr().Get(time)
                            or settings.GetInstantaneousShutterAttr().Get(time)),
    }


def _binding_purposes(settings: UsdRender.Settings, time: Usd.TimeCode) -> tuple[str, ...]:
    attribute = settings.GetMaterialBindingPurposesAttr()
    value = attribute.Get(time) if attribute else None
    if value is None:
        return DEFAULT_BINDING_PURPOSES
    # UsdRender spells allPurpose "allPurpose"; UsdShade's binding API spells it "".
    return tuple("" if str(token) in ("", "allPurpose") else str(token) for token in value)


def camera_prim(context: ReadContext, path: str) -> Usd.Prim:
    """The camera prim at ``path``; StageError naming it when it is missing or not a Camera."""
    if not Sdf.Path.IsValidPathString(path) or not Sdf.Path(path).IsAbsolutePath():
        raise StageError(f"camera: not an absolute prim path: {path!r}", file=context.file)
    prim = context.stage.GetPrimAtPath(path)
    if not prim or not prim.IsActive():
        raise StageError("the camera does not exist", file=context.file, prim=path)
    if not prim.IsA(UsdGeom.Camera):
        raise StageError(f"the camera is a {prim.GetTypeName() or 'typeless prim'}, not a Camera",
                         file=context.file, prim=path)
    return prim


def read_camera(context: ReadContext, prim: Usd.Prim) -> Camera:
    """A UsdGeom.Camera with its clipping range in metres and a rigid world transform.

    Raises StageError naming the prim and attribute for what would give a black or NaN
    image: a focal length or aperture that is not a positive finite number, a clipping
    range that is not 0 <= near < far, a negative or infinite fStop, a shutter that closes
    before it opens, a value of another type than the schema's (values.py), a world
    transform that is not finite.

    The lens (UsdGeomCamera): fStop 0 is a pinhole; above, a thin lens of aperture diameter
    focalLength / fStop (focalLength in tenths of a scene unit) focused at focusDistance
    (scene units). An fStop without a positive focusDistance has nothing to focus on: a
    warning, and a pinhole.

    The shutter (shutter:open, shutter:close, frames relative to the frame rendered): the
    camera's world transform at both ends and at every sample its xformOps (its own and its
    ancestors') author between them (:func:`camera_motion`).
    """
    time = context.time
    camera = UsdGeom.Camera(prim)
    path = str(prim.GetPath())

    def number(attribute: Usd.Attribute) -> float:
        value = values.real(attribute, time, context.file)
        if value is None:
            raise StageError(f"{attribute.GetName()} has no value", file=context.file, prim=path)
        return value

    def positive(attribute: Usd.Attribute) -> float:
        value = number(attribute)
        if not (math.isfinite(value) and value > 0.0):
            raise StageError(f"{attribute.GetName()} is {value:g}: it must be a positive number",
                             file=context.file, prim=path)
        return value

    def finite(attribute: Usd.Attribute) -> float:
        value = number(attribute)
        if not math.isfinite(value):
            raise StageError(f"{attribute.GetName()} is {value:g}: it must be a finite number",
                             file=context.file, prim=path)
        return value

    clipping = values.reals(camera.GetClippingRangeAttr(), time, 2, context.file)
    if clipping is None:
        raise StageError("clippingRange has no value", file=context.file, prim=path)
    near, far = clipping
    if not (math.isfinite(near) and math.isfinite(far) and 0.0 <= near < far):
        raise StageError(f"clippingRange is ({near:g}, {far:g}): it must be 0 <= near < far",
                         file=context.file, prim=path)
    with transform_errors_name(prim, context.file):
        world = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
    if not all(math.isfinite(value) for value in world.ravel()):
        raise StageError("the camera's world transform is not finite (NaN or infinite xformOps)",
                         file=context.file, prim=path)
    projection = str(camera.GetProjectionAttr().Get(time))
    # An orthographic view has no lens: only its apertures size it.
    focal_length = (number(camera.GetFocalLengthAttr()) if projection == "orthographic"
                    else positive(camera.GetFocalLengthAttr()))
    f_stop, focus = finite(camera.GetFStopAttr()), finite(camera.GetFocusDistanceAttr())
    if f_stop < 0:
        raise StageError(f"fStop is {f_stop:g}: it must be 0 (no depth of field) or more", file=context.file, prim=path)
    if f_stop > 0 and not focus > 0:
        context.diagnostics.warn(f"{context.file}: camera {path}: fStop {f_stop:g} but focusDistance {focus:g}: "
                                 "no depth of field (a lens needs a positive focus distance)")
        f_stop = 0.0
    lens_radius = focal_length / 10 / (2 * f_stop) * context.meters_per_unit if f_stop > 0 else 0.0
    shutter = finite(camera.GetShutterOpenAttr()), finite(camera.GetShutterCloseAttr())
    if shutter[1] < shutter[0]:
        raise StageError(f"shutter:close ({shutter[1]:g}) is before shutter:open ({shutter[0]:g})",
                         file=context.file, prim=path)
    with transform_errors_name(prim, context.file):
        motion_times, motion_transforms = camera_motion(context, prim, shutter)
    return Camera(
        name=prim.GetName(),
        path=path,
        world_from_camera=rigid_in_metres(world, context.meters_per_unit),
        projection="orthographic" if projection == "orthographic" else "perspective",
        focal_length=focal_length,
        horizontal_aperture=positive(camera.GetHorizontalApertureAttr()),
        vertical_aperture=positive(camera.GetVerticalApertureAttr()),
        horizontal_aperture_offset=finite(camera.GetHorizontalApertureOffsetAttr()),
        vertical_aperture_offset=finite(camera.GetVerticalApertureOffsetAttr()),
        clipping=(near * context.meters_per_unit, far * context.meters_per_unit),
        lens_radius=lens_radius,
        focus_distance=focus * context.meters_per_unit if lens_radius > 0 else 0.0,
        motion_times=motion_times,
        motion_transforms=motion_transforms,
        shutter=shutter,
    )


MAX_MOTION_SAMPLES = 64
"""The most camera transforms kept over a shutter (evenly chosen from its authored samples):
a camera keyed on every subframe still costs a bounded table."""


def camera_motion(context: ReadContext, prim: Usd.Prim, shutter: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The camera's motion over `shutter` (frames relative to the context's time): times (k,)
    float64 relative to the frame, ascending, from shutter:open to shutter:close, and its
    rigid world transforms (k, 4, 4) in metres there; both empty when the shutter is an
    instant, the stage has no time, or the camera stands still over it."""
    still = np.zeros(0), np.zeros((0, 4, 4))
    if shutter[1] <= shutter[0] or context.time.IsDefault():
        return still
    frame = context.time.GetValue()
    ordered = transform_times(prim, Gf.Interval(frame + shutter[0], frame + shutter[1]))
    if len(ordered) > MAX_MOTION_SAMPLES:
        ordered = [ordered[round(i)] for i in np.linspace(0, len(ordered) - 1, MAX_MOTION_SAMPLES)]
    world = (column_matrix(UsdGeom.XformCache(Usd.TimeCode(t)).GetLocalToWorldTransform(prim)) for t in ordered)
    transforms = np.stack([rigid_in_metres(matrix, context.meters_per_unit) for matrix in world])
    if not np.isfinite(transforms).all():
        raise StageError("the camera's world transform over the shutter is not finite", file=context.file,
                         prim=str(prim.GetPath()))
    if np.allclose(transforms, transforms[0], rtol=0, atol=1e-12):
        return still
    return np.asarray(ordered) - frame, transforms
