"""USD → plain scene data: the only package of pxr_layers that imports ``pxr``.

``open_shot(path, recipe_layers=, variants=)`` composes a shot once; from it come the
recipe (``shot.recipe()``), a frame's flattened render spec (``shot.spec(frame, recipe)``)
and a frame's scene (``shot.scene(spec, subdiv_level=)``). ``load_stage(path, frame=,
camera=, settings=)`` does all three for one frame. See :mod:`pxr_layers.scene` for the
units and conventions of everything it produces.

Modules, in the order a read uses them:

* ``opening``       compose the stage, its recipe layers and variants; composition errors
* ``defaults``      the automatic camera and the default light rig of bare stages
* ``shot``          the composed shot: settings, recipe, render spec, scene
* ``recipe_reader`` UsdRender settings → the Recipe; ``schema`` the pxr-layers USD schema
* ``render_spec``   what the settings say beyond the recipe, and the camera
* ``draw_modes``    models drawn as cards (UsdGeomModelAPI) authored as card meshes
* ``walk``          find gprims (instances and point instancers expanded) and lights
* ``surfaces``      triangulate UsdGeom.Mesh (``subdivision`` refines subdivision surfaces);
                    ``implicit`` tessellate Sphere, Cube, ...; ``skinning`` poses UsdSkel meshes
* ``placement``     put a triangulated surface in the world (metres, normals, degenerates)
* ``materials``     binding and UsdPreviewSurface; ``textures`` decode images with OIIO
* ``lights``        UsdLux with intensity, exposure, colour and normalize folded in
* ``diagnostics``   warnings, grouped per kind and naming the prims
* ``values``        attribute values of their schema's type, or a StageError naming them
"""

from ..interrupts import raise_recorded, recorded

# USD's module loader (Tf.PreparePythonModule) turns a KeyboardInterrupt raised while it loads
# its libraries into a printed warning and goes on: a Ctrl-C in those seconds would be lost and
# the command would run on. The signal is held while this package loads USD, and raised after.
with recorded() as _received:
    from .schema import register as _register_schema

    _register_schema()  # before any stage is opened: USD ignores schemas registered later

    from .shot import Shot, load_stage, open_request, open_shot  # (after the registration)
raise_recorded(_received)


def load_recipe(path, settings=None, *, recipe_layers=(), camera=None, per_light=None, check_colour=True):
    """The recipe of a shot file with ``recipe_layers`` composed over it (see Shot.recipe)."""
    return open_shot(path, recipe_layers=recipe_layers).recipe(settings=settings, camera=camera,
                                                               per_light=per_light, check_colour=check_colour)


__all__ = ["Shot", "load_recipe", "load_stage", "open_request", "open_shot"]
