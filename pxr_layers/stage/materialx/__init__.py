"""MaterialX looks as shader-node trees: .mtlx documents referenced from USD, and UsdShade
networks of MaterialX nodes (``info:id = "ND_…"``), read into scene.Material fields.

Two jobs, one module each: ``networks`` reads the networks (documents, UsdShade networks
copied into documents, the walk through connections, interface bindings and nodedef
graphs); ``nodes`` translates nodes into ShaderNode trees and surface shaders into Material
fields. :class:`MaterialXReader` puts the two together.
"""

from __future__ import annotations

import MaterialX as mx
from pxr import Sdf, UsdShade

from ..context import ReadContext
from ..textures import TextureLibrary
from .networks import Documents, Evaluator, Frame, UsdNetwork, standard_library, surface_shader
from .nodes import HANDLERS, PREVIEW_INPUTS, SURFACES, MaterialXLook, is_flat_normal, look

__all__ = ["PREVIEW_INPUTS", "MaterialXLook", "MaterialXReader", "is_flat_normal", "standard_library"]


class MaterialXReader:
    """MaterialX looks of one stage read: documents read once, library shared."""

    def __init__(self, context: ReadContext, textures: TextureLibrary) -> None:
        self.context = context
        self.textures = textures
        self.library = standard_library()
        self._documents = Documents(context, self.library)

    def from_usd(self, material: UsdShade.Material) -> MaterialXLook | None:
        """A UsdShade.Material whose surface (outputs:mtlx:surface first, then outputs:surface) is a
        Shader with a MaterialX info:id; None when it has none (the caller falls back)."""
        found = surface_shader(self.library, material)
        if found is None:
            return None
        shader, nodedef = found
        if nodedef.getNodeString() not in SURFACES:
            self.context.diagnostics.note(
                f"unsupported-node-{nodedef.getNodeString()}",
                f"MaterialX nodes '{nodedef.getNodeString()}' are not supported; their inputs' defaults "
                "were used on: {prims}", f"{material.GetPath()} ({shader.GetPath().name})")
            return None
        document = mx.createDocument()
        document.setDataLibrary(self.library)
        surface = UsdNetwork(self.context, self.library, document).node(shader)
        return look(self._evaluator(str(material.GetPath())), surface, Frame(None))

    def referenced(self, target: Sdf.Path) -> tuple[str, str] | None:
        """For a binding target that does not exist on the stage: (absolute .mtlx path, material name)
        when it lies under a prim that references (or payloads) a .mtlx document; else None."""
        return self._documents.referenced(target)

    def from_document(self, mtlx_path: str, material_name: str, user_path: str) -> MaterialXLook | None:
        """The surfacematerial `material_name` of the document (documents read once per reader);
        None (after a diagnostics warning naming the file) when unreadable or absent."""
        evaluator = self._evaluator(f"{user_path} ({mtlx_path}:{material_name})")
        found = self._documents.surface(mtlx_path, material_name, user_path, evaluator)
        return look(evaluator, *found) if found is not None else None

    def _evaluator(self, label: str) -> Evaluator:
        return Evaluator(self, label, HANDLERS)
