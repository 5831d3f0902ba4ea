"""USD → plain scene data: the only package of pxr_layers that imports ``pxr``.

``load_stage(path, frame=, camera=, settings=)`` returns (SceneData, RenderSpec), see
:mod:`pxr_layers.scene` for the units and conventions of everything it produces.

Modules, in the order a read uses them:

* ``opening``     open the stage, composition errors, the time code
* ``render_spec`` UsdRender settings and the camera
* ``walk``        find gprims (instances and point instancers expanded) and lights
* ``surfaces``    triangulate UsdGeom.Mesh; ``implicit`` tessellate Sphere, Cube, ...
* ``placement``   put a triangulated surface in the world (metres, normals, degenerates)
* ``materials``   binding and UsdPreviewSurface; ``textures`` decode images with OIIO
* ``lights``      UsdLux with intensity, exposure, colour and normalize folded in
* ``diagnostics`` warnings, grouped per kind and naming the prims
"""

from pxr_layers.recipe.schema import register as _register_schema

_register_schema()  # before any stage is opened: USD ignores schemas registered later

from .reader import load_stage  # after the schema registration above

__all__ = ["load_stage"]
