"""A shot: the stage composed once with its recipe layers and variants, then its recipe, a
frame's render spec and a frame's scene, all read from that one composition.

::

    shot = open_shot(request)                  # composition warnings are logged here, once
    recipe = shot.recipe(settings=..., camera=..., per_light=...)
    spec = shot.spec(frame, recipe)            # camera at the frame, resolution, purposes
    scene = shot.scene(spec)                   # SceneData at spec.frame (subdiv_level=N: uniform)
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass

from pxr import Usd, UsdGeom, UsdRender, UsdShade

from pxr_layers.recipe.model import Recipe
from pxr_layers.request import AUTO_CAMERA_VIEWS, RenderRequest, VariantSelection
from pxr_layers.scene import RenderSpec, SceneData

from . import schema
from .context import ReadContext
from .defaults import (AUTO_CAMERA_PATH, aim_default_lights, define_auto_camera, define_default_lights,
                       frame_auto_camera, is_ours)
from .diagnostics import Diagnostics
from .lights import is_supported_light
from .opening import compose_stage, resolve_time, trapped_usd_diagnostics
from .motion import Shutter
from .reader import read_scene
from .recipe_reader import find_settings, read_recipe
from .render_spec import camera_prim, read_camera, settings_fields
from .subdivision import PixelFootprint
from .walk import walk_stage

logger = logging.getLogger(__name__)

_LIGHT_GROUP = schema.ATTRIBUTE_PREFIX + "lightGroup"  # PxrLayersLightAPI's


@dataclass
class Shot:
    """One composed shot stage.

    file          : the shot's USD file as given (error messages name it)
    recipe_layers : the recipe layers composed over it, as given
    warnings      : what opening it warned of (logged once, when it was opened)
    first_camera  : the stage's first UsdGeom.Camera in traversal order, or the automatic one
    default_rig   : whether the default lights were authored (each frame's camera aims them)
    """

    stage: Usd.Stage
    file: str
    recipe_layers: tuple[str, ...]
    warnings: tuple[str, ...]
    first_camera: str
    up_axis: str
    meters_per_unit: float
    default_rig: bool = False

    def find_settings(self, settings: str | None = None) -> UsdRender.Settings | None:
        """The RenderSettings prim that applies (the one rule of :func:`recipe_reader.find_settings`)."""
        with trapped_usd_diagnostics(self.file):
            return find_settings(self.stage, self.file, settings, self.recipe_layers)

    def recipe(self, *, settings: str | None = None, camera: str | None = None, per_light: str | None = None,
               frame: float | None = None, check_colour: bool = True) -> Recipe:
        """The recipe of the settings that apply; the beauty alone for a stage without any.

        frame : the time at which to list the lights of per-light layers and to read the
                camera's apertures for adjustPixelAspectRatio (None: the start)
        """
        settings_prim = self.find_settings(settings)
        # Listed once, however many products add per-light layers (each walk is a whole traversal).
        lights = functools.cache(lambda: self.lights(settings_prim, frame))
        with trapped_usd_diagnostics(self.file):
            time, _ = resolve_time(self.stage, frame)
            return read_recipe(self.stage, self.file, settings_prim, default_camera=lambda: self.first_camera,
                               lights=lights, camera=camera, per_light=per_light, check_colour=check_colour,
                               time=time)

    def lights(self, settings: UsdRender.Settings | None = None, frame: float | None = None) -> list[tuple[str, str, str]]:
        """(name, path, light group) of every light the render sees: the walk's own rule
        (supported types, visible, of a purpose the settings include)."""
        with trapped_usd_diagnostics(self.file):
            time, _ = resolve_time(self.stage, frame)
            context = self._context(time, settings_fields(settings, time)["included_purposes"], Diagnostics())
            found = []
            for prim in walk_stage(context).lights:
                attribute = prim.GetAttribute(_LIGHT_GROUP)
                group = attribute.Get() if attribute and attribute.HasAuthoredValue() else schema.fallback(
                    schema.LIGHT_API, _LIGHT_GROUP)
                found.append((prim.GetName(), str(prim.GetPath()), str(group or "")))
            return found

    def spec(self, frame: float | None, recipe: Recipe, *, camera: str | None = None,
             resolution: tuple[int, int] | None = None, auto_camera: str = AUTO_CAMERA_VIEWS[0]) -> RenderSpec:
        """The frame's render spec: ``recipe``'s camera and resolution (or these overrides),
        pixel aspect ratio and conform policy, the camera read at the frame, and the
        settings' purposes. The automatic camera is framed (``auto_camera``: its view, one of
        request.AUTO_CAMERA_VIEWS) and the default rig aimed from the camera, at the frame."""
        view = recipe.shared_view()
        resolution = tuple(resolution or view.resolution)
        with trapped_usd_diagnostics(self.file):
            time, _ = resolve_time(self.stage, frame)
            settings = self.find_settings(recipe.settings_path) if recipe.settings_path else None
            fields = settings_fields(settings, time)
            camera_path = camera or view.camera
            context = self._context(time, fields["included_purposes"], Diagnostics())
            prim = camera_prim(context, camera_path)
            if camera_path == AUTO_CAMERA_PATH:
                aspect = resolution[0] * view.pixel_aspect_ratio / resolution[1]
                if not frame_auto_camera(self.stage, time, fields["included_purposes"], self.up_axis, aspect,
                                         auto_camera):
                    logger.info("%s: nothing to frame (no geometry): the automatic camera looks to the front",
                                self.file)
                context.xform_cache.Clear()
            render_camera = read_camera(context, prim)
            if self.default_rig:
                aim_default_lights(self.stage, -render_camera.world_from_camera[:3, 2], self.up_axis)
            return RenderSpec(camera=render_camera, resolution=resolution,
                              pixel_aspect_ratio=view.pixel_aspect_ratio,
                              aspect_ratio_conform_policy=view.aspect_ratio_conform_policy,
                              frame=frame, recipe=recipe, **fields)

    def scene(self, spec: RenderSpec, *, subdiv_level: int | None = None) -> SceneData:
        """Everything the tracer needs at ``spec.frame``.

        subdiv_level : one refinement level for every subdivision surface; None: a level per
                       surface from its size through ``spec``'s camera at its resolution
                       (reader.py)
        """
        footprint = PixelFootprint.of_camera(spec.camera, spec.resolution, spec.pixel_aspect_ratio)
        with trapped_usd_diagnostics(self.file):
            time, frame_value = resolve_time(self.stage, spec.frame)
            diagnostics = Diagnostics()
            context = self._context(time, spec.included_purposes, diagnostics)
            context.shutter = Shutter.of(time, spec.camera.shutter, spec.motion_blur)
            return read_scene(context, frame_value, spec.material_binding_purposes, footprint, subdiv_level,
                              self.warnings)

    def _context(self, time: Usd.TimeCode, purposes: tuple[str, ...], diagnostics: Diagnostics) -> ReadContext:
        return ReadContext(stage=self.stage, time=time, meters_per_unit=self.meters_per_unit, up_axis=self.up_axis,
                           xform_cache=UsdGeom.XformCache(time), diagnostics=diagnostics, file=self.file,
                           rendered_purposes=tuple(purposes))


def open_shot(path: str | os.PathLike[str], *, recipe_layers: Sequence[str | os.PathLike[str]] = (),
              variants: Sequence[VariantSelection] = (), strict: bool = False, default_lights: bool = True) -> Shot:
    """Compose the shot once (see :func:`opening.compose_stage`), and give a stage without a
    camera the automatic one and a stage that nothing lights (no supported light, no emissive
    material) the default rig (``default_lights``)."""
    file = os.fspath(path)
    diagnostics = Diagnostics()
    stage = compose_stage(file, diagnostics, recipe_layers=recipe_layers, variants=variants, strict=strict)
    with trapped_usd_diagnostics(file):
        up_axis = "Z" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else "Y"
        first_camera, has_light = _survey(stage)
        if first_camera is None:
            first_camera = define_auto_camera(stage)
            logger.info("%s has no camera: %s frames the stage (--camera picks another)", file, first_camera)
        default_rig = not has_light and default_lights
        if not has_light:
            if default_lights:
                paths = define_default_lights(stage)
                diagnostics.warn(f"{file} has no light and no emissive material: lit by the default rig ({', '.join(paths)}; "
                                 "--no-default-lights keeps it unlit)")
            else:
                diagnostics.warn(f"{file} has no light and no emissive material, and --no-default-lights "
                                 "was given: the image will be black")
    return Shot(stage=stage, file=file, recipe_layers=tuple(os.fspath(layer) for layer in recipe_layers),
                warnings=diagnostics.finish(), first_camera=first_camera, up_axis=up_axis,
                meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)), default_rig=default_rig)


def open_request(request: RenderRequest) -> Shot:
    """:func:`open_shot` with what a render request says."""
    return open_shot(request.stage, recipe_layers=request.recipe_layers, variants=request.variants,
                     strict=request.strict, default_lights=request.default_lights)


def _survey(stage: Usd.Stage) -> tuple[str | None, bool]:
    """(the first camera's path or None, whether anything lights the stage: a supported
    visible light or an emissive UsdPreviewSurface), in one traversal."""
    first_camera, has_light = None, False
    for prim in stage.Traverse(Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)):
        if is_ours(prim.GetPath()):
            continue
        if first_camera is None and prim.IsA(UsdGeom.Camera):
            first_camera = str(prim.GetPath())
        elif not has_light and is_supported_light(prim):
            has_light = UsdGeom.Imageable(prim).ComputeVisibility() != UsdGeom.Tokens.invisible
        elif not has_light and prim.IsA(UsdShade.Shader):
            has_light = _emits(UsdShade.Shader(prim))
        if first_camera is not None and has_light:
            break
    return first_camera, has_light


def _emits(shader: UsdShade.Shader) -> bool:
    """Whether a UsdPreviewSurface has a non-black or textured emissiveColor."""
    if shader.GetIdAttr().Get() != "UsdPreviewSurface":
        return False
    emission = shader.GetInput("emissiveColor")
    if not emission:
        return False
    if emission.HasConnectedSource():
        return True
    value = emission.Get()
    return value is not None and any(float(component) > 0.0 for component in value)


def load_stage(path: str | os.PathLike[str], *, frame: float | None = None, camera: str | None = None,
               settings: str | None = None, request: RenderRequest | None = None) -> tuple[SceneData, RenderSpec]:
    """Open a stage and read one frame: (SceneData, RenderSpec). A convenience for scripts and
    tests; ``render`` and jobs open the shot once and read each frame from it.

    frame    : time code; None → the stage's startTimeCode if authored, else the earliest
               time sample (SceneData.frame is then NaN)
    camera   : camera prim path, overriding the recipe's
    settings : RenderSettings prim path, instead of the one rule's choice
    request  : the rest (recipe layers, variants, resolution, automatic camera view, subdiv
               level, default lights, strict);
               its stage, camera and settings are replaced by the arguments above
    """
    request = dataclasses.replace(request, stage=path) if request else RenderRequest(stage=path)
    shot = open_request(request)
    recipe = shot.recipe(settings=settings, camera=camera, frame=frame, check_colour=False)
    spec = shot.spec(frame, recipe, camera=camera, resolution=request.resolution, auto_camera=request.auto_camera)
    return shot.scene(spec, subdiv_level=request.subdiv_level), spec
