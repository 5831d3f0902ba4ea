"""``load_stage``: one USD stage at one time code → SceneData + RenderSpec."""

from __future__ import annotations

import logging
import os

import numpy as np
from pxr import Tf, Usd, UsdGeom, UsdShade

from pxr_layers.errors import StageError
from pxr_layers.scene import Material, Mesh, RenderSpec, SceneData, TextureInput

from .context import ReadContext
from .diagnostics import Diagnostics
from .implicit import tessellate
from .lights import read_light
from .materials import MaterialLibrary, ResolvedMaterial, display_color
from .opening import open_stage, resolve_time, tf_error_summary
from .placement import place_surface
from .render_spec import read_render_spec
from .surfaces import LocalSurface, read_mesh
from .textures import TextureLibrary
from .walk import GprimPlacement, walk_stage

logger = logging.getLogger(__name__)

_DEFAULT_UV_PRIMVAR = "st"


def load_stage(
    path: str | os.PathLike[str],
    *,
    frame: float | None = None,
    camera: str | None = None,
    settings: str | None = None,
) -> tuple[SceneData, RenderSpec]:
    """Read a USD stage into plain scene data and a render spec.

    frame    : time code to read everything at; None → the stage's startTimeCode if
               authored, else the earliest time sample (SceneData.frame is then NaN)
    camera   : prim path of the camera, overriding the render settings' camera
    settings : prim path of the RenderSettings to use, instead of the stage's default
               (``renderSettingsPrimPath``) settings

    Raises StageError (naming the file, and the prim when there is one) for a missing,
    unreadable or non-composing file, a missing camera or settings prim, and bad geometry
    (NaN points, broken topology). Everything the tracer cannot honour but can render
    around is a warning, logged and kept in SceneData.warnings.
    """
    file = os.fspath(path)
    diagnostics = Diagnostics()
    stage = open_stage(file, diagnostics)
    with Tf.DiagnosticTrap() as trap:
        try:
            return _read_stage(stage, file, frame, camera, settings, diagnostics)
        except Tf.ErrorException as error:
            message = f"USD failed while reading: {tf_error_summary(error)}"
            raise StageError(message, file=file) from None
        finally:
            # USD's Tf warnings (e.g. an instancer without prototypes) duplicate what the
            # reader reports itself; keep them for debugging only.
            for warning in trap.GetWarnings():
                logger.debug("USD: %s", warning.commentary)
            trap.Clear()


def _read_stage(
    stage: Usd.Stage,
    file: str,
    frame: float | None,
    camera: str | None,
    settings: str | None,
    diagnostics: Diagnostics,
) -> tuple[SceneData, RenderSpec]:
    time, frame_value = resolve_time(stage, frame)
    up_axis = "Z" if UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z else "Y"
    context = ReadContext(
        stage=stage,
        time=time,
        meters_per_unit=float(UsdGeom.GetStageMetersPerUnit(stage)),
        up_axis=up_axis,
        xform_cache=UsdGeom.XformCache(time),
        diagnostics=diagnostics,
        file=file,
    )
    render_spec, context.rendered_purposes = read_render_spec(context, camera, settings)
    textures = TextureLibrary(diagnostics)
    materials = MaterialLibrary(context, textures, render_spec.material_binding_purposes)
    contents = walk_stage(context)

    builder = _MeshBuilder(context, materials)
    meshes = [mesh for placement in contents.gprims if (mesh := builder.build(placement))]
    lights = [read_light(context, prim, textures) for prim in contents.lights]
    if not lights and not any(_is_emissive(material) for material in materials.materials):
        diagnostics.warn(
            f"{file} has no lights and no emissive material: the image will be black"
        )
    logger.info(
        "%s: %d meshes, %d triangles, %d materials, %d lights, %d textures",
        file,
        len(meshes),
        sum(len(mesh.triangles) for mesh in meshes),
        len(materials.materials),
        len(lights),
        len(textures.images),
    )
    textures.remember()  # the next frame's read takes them as they are
    scene = SceneData(
        stage_path=os.path.abspath(file),
        frame=frame_value,
        meshes=tuple(meshes),
        materials=tuple(materials.materials),
        lights=tuple(lights),
        textures=tuple(textures.images),
        meters_per_unit=context.meters_per_unit,
        up_axis=up_axis,
        warnings=diagnostics.finish(),
    )
    return scene, render_spec


class _MeshBuilder:
    """Builds scene.Mesh objects, triangulating each prototype gprim only once."""

    def __init__(self, context: ReadContext, materials: MaterialLibrary) -> None:
        self._context = context
        self._materials = materials
        # (prototype prim path, uv primvar) → surface: native instances and point-instanced
        # copies of one gprim share its triangulation.
        self._surfaces: dict[tuple[str, str], LocalSurface] = {}

    def build(self, placement: GprimPlacement) -> Mesh | None:
        context = self._context
        prim = placement.prim
        color = display_color(prim, context.time)
        mesh_material = self._materials.resolve(self._materials.bound_material(prim), color)
        subset_materials = self._subset_materials(prim, color)
        uv_primvar = next(
            (
                resolved.uv_primvar
                for resolved in [mesh_material, *(m for _, m in subset_materials)]
                if resolved.uv_primvar
            ),
            _DEFAULT_UV_PRIMVAR,
        )
        surface = self._surface(prim, uv_primvar)

        face_material = np.full(surface.face_count, mesh_material.index, dtype=np.int64)
        # Reversed so that, where subsets overlap, the first subset listed wins.
        for faces, resolved in reversed(subset_materials):
            faces = faces[(faces >= 0) & (faces < surface.face_count)]
            face_material[faces] = resolved.index
        triangle_material = face_material[surface.triangle_face]
        return place_surface(
            surface,
            placement.world_from_local,
            context.meters_per_unit,
            triangle_material,
            placement.name,
            placement.path,
            context.diagnostics,
            instance=placement.instance,
        )

    def _subset_materials(
        self, prim: Usd.Prim, color: tuple[float, float, float] | None
    ) -> list[tuple[np.ndarray, ResolvedMaterial]]:
        if not prim.IsA(UsdGeom.Mesh):
            return []
        subsets = []
        for subset in UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets():
            if subset.GetElementTypeAttr().Get() != UsdGeom.Tokens.face:
                continue
            faces = np.asarray(subset.GetIndicesAttr().Get(self._context.time) or [], np.int64)
            material = self._materials.bound_material(subset.GetPrim())
            subsets.append((faces, self._materials.resolve(material, color)))
        return subsets

    def _surface(self, prim: Usd.Prim, uv_primvar: str) -> LocalSurface:
        source = prim.GetPrimInPrototype() if prim.IsInstanceProxy() else prim
        key = (str(source.GetPath()), uv_primvar)
        if key not in self._surfaces:
            context = self._context
            if prim.IsA(UsdGeom.Mesh):
                surface = read_mesh(
                    prim, context.time, uv_primvar, context.diagnostics, context.file
                )
            else:
                surface = tessellate(prim, context.time)
            self._surfaces[key] = surface
        return self._surfaces[key]


def _is_emissive(material: Material) -> bool:
    emissive = material.emissive_color
    return isinstance(emissive, TextureInput) or any(component > 0.0 for component in emissive)
