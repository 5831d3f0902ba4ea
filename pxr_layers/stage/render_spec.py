"""UsdRender settings and the render camera → scene.RenderSpec."""

from __future__ import annotations

from pxr import Sdf, Usd, UsdGeom, UsdRender

from pxr_layers.errors import StageError
from pxr_layers.scene import Camera, RenderSpec

from .context import ReadContext
from .transforms import column_matrix, rigid_in_metres

_DEFAULT_BINDING_PURPOSES = ("full", "")
_DEFAULT_INCLUDED_PURPOSES = ("default", "render")


def read_render_spec(
    context: ReadContext, camera_path: str | None, settings_path: str | None
) -> tuple[RenderSpec, tuple[str, ...]]:
    """Flatten the render settings and camera.

    settings_path : a RenderSettings prim to use; None → the stage's
                    ``renderSettingsPrimPath`` settings, if any
    camera_path   : overrides the settings' camera; with neither, the first
                    UsdGeom.Camera in traversal order is used

    Also returns the settings' ``includedPurposes`` (default, render without settings):
    which gprim purposes to render, a stage-reading concern RenderSpec does not carry.
    """
    stage, time = context.stage, context.time
    settings = _find_settings(context, settings_path)
    spec_fields: dict[str, object] = {}
    settings_camera = None
    included_purposes = _DEFAULT_INCLUDED_PURPOSES
    if settings is not None:
        purposes = settings.GetIncludedPurposesAttr().Get(time)
        if purposes is not None:
            included_purposes = tuple(str(purpose) for purpose in purposes)
        resolution = settings.GetResolutionAttr().Get(time)
        spec_fields.update(
            resolution=(int(resolution[0]), int(resolution[1])),
            pixel_aspect_ratio=float(settings.GetPixelAspectRatioAttr().Get(time)),
            aspect_ratio_conform_policy=str(settings.GetAspectRatioConformPolicyAttr().Get(time)),
            settings_path=str(settings.GetPath()),
            material_binding_purposes=_binding_purposes(settings, time),
        )
        targets = settings.GetCameraRel().GetForwardedTargets()
        if targets:
            settings_camera = targets[0]

    if camera_path is not None:
        camera_prim = _camera_prim(context, camera_path, "the requested camera")
    elif settings_camera is not None:
        camera_prim = _camera_prim(
            context, str(settings_camera), f"the camera of {settings.GetPath()}"
        )
    else:
        camera_prim = _first_camera(stage)
        if camera_prim is None:
            raise StageError(
                "no camera: the stage has no UsdGeom.Camera and none was given", file=context.file
            )
    return RenderSpec(camera=read_camera(context, camera_prim), **spec_fields), included_purposes


def _find_settings(context: ReadContext, settings_path: str | None) -> UsdRender.Settings | None:
    if settings_path is None:
        settings = UsdRender.Settings.GetStageRenderSettings(context.stage)
        return settings if settings else None
    prim = _prim_at(context, settings_path)
    if prim is None:
        raise StageError("render settings prim not found", file=context.file, prim=settings_path)
    if not prim.IsA(UsdRender.Settings):
        raise StageError(
            f"is a {prim.GetTypeName() or 'typeless prim'}, not RenderSettings",
            file=context.file,
            prim=settings_path,
        )
    return UsdRender.Settings(prim)


def _binding_purposes(settings: UsdRender.Settings, time: Usd.TimeCode) -> tuple[str, ...]:
    attribute = settings.GetMaterialBindingPurposesAttr()
    value = attribute.Get(time) if attribute else None
    if value is None:
        return _DEFAULT_BINDING_PURPOSES
    # UsdRender spells allPurpose "allPurpose"; UsdShade's binding API spells it "".
    return tuple("" if str(token) in ("", "allPurpose") else str(token) for token in value)


def _prim_at(context: ReadContext, path: str) -> Usd.Prim | None:
    if not Sdf.Path.IsValidPathString(path) or not Sdf.Path(path).IsAbsolutePath():
        raise StageError(f"not an absolute prim path: {path!r}", file=context.file)
    prim = context.stage.GetPrimAtPath(path)
    return prim if prim and prim.IsActive() else None


def _camera_prim(context: ReadContext, path: str, role: str) -> Usd.Prim:
    prim = _prim_at(context, path)
    if prim is None:
        raise StageError(f"{role} does not exist", file=context.file, prim=path)
    if not prim.IsA(UsdGeom.Camera):
        raise StageError(
            f"{role} is a {prim.GetTypeName() or 'typeless prim'}, not a Camera",
            file=context.file,
            prim=path,
        )
    return prim


def _first_camera(stage: Usd.Stage) -> Usd.Prim | None:
    predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
    for prim in stage.Traverse(predicate):
        if prim.IsA(UsdGeom.Camera):
            return prim
    return None


def read_camera(context: ReadContext, prim: Usd.Prim) -> Camera:
    """A UsdGeom.Camera with its clipping range in metres and a rigid world transform."""
    time = context.time
    camera = UsdGeom.Camera(prim)
    near, far = camera.GetClippingRangeAttr().Get(time)
    world = column_matrix(context.xform_cache.GetLocalToWorldTransform(prim))
    projection = str(camera.GetProjectionAttr().Get(time))
    return Camera(
        name=prim.GetName(),
        path=str(prim.GetPath()),
        world_from_camera=rigid_in_metres(world, context.meters_per_unit),
        projection="orthographic" if projection == "orthographic" else "perspective",
        focal_length=float(camera.GetFocalLengthAttr().Get(time)),
        horizontal_aperture=float(camera.GetHorizontalApertureAttr().Get(time)),
        vertical_aperture=float(camera.GetVerticalApertureAttr().Get(time)),
        horizontal_aperture_offset=float(camera.GetHorizontalApertureOffsetAttr().Get(time)),
        vertical_aperture_offset=float(camera.GetVerticalApertureOffsetAttr().Get(time)),
        clipping=(float(near) * context.meters_per_unit, float(far) * context.meters_per_unit),
    )
