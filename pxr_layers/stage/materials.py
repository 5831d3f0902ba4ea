"""Material binding, UsdPreviewSurface networks and MaterialX looks → scene.Material.

A UsdPreviewSurface on the universal render context (``outputs:surface``) is read here: its
inputs follow connections through NodeGraphs and interface inputs
(``GetValueProducingAttributes``) into shader_nodes trees — UsdUVTexture (scale, bias,
fallback, wrap modes, colour space, ``<UDIM>`` tiles), UsdTransform2d, and
UsdPrimvarReader_float/float2/float3/float4/int into any input. MaterialX looks, bound
through UsdShade prims with MaterialX ids or referenced as ``.mtlx`` documents, are read by
the materialx package (materialx/). Anything else renders with the default material, after one note.

Values (values.checked, one rule): every number a network authors (an input's value, a
UsdUVTexture's scale, bias and fallback, a transform's, a primvar reader's fallback; in
MaterialX, every value of a node or a document) must be finite, else a StageError names the
file, the shader (or MaterialX node) and the input: a NaN diffuseColor or a metallic of inf
would make NaN pixels, where no layer can hold them. Then each Material field within its
range (FIELD_RANGES: a reflectance at most MAX_REFLECTANCE, an emission at most
values.MAX_RADIANCE), checked on what the network computes (:func:`check_fields`, for
UsdPreviewSurface and MaterialX alike), so that a base_color of 1e30 is an error naming it
rather than pixels of 1e30. Below 0, the tracer reads diffuse and transmission colours and
weights as 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from pxr import Sdf, Usd, UsdGeom, UsdShade

from pxr_layers import shader_nodes as nodes
from pxr_layers.scene import DEFAULT_MATERIAL_PATH, Material
from pxr_layers.shader_nodes import ShaderNode

from . import values
from .context import ReadContext
from .defaults import DEFAULT_UV_SET
from .materialx import PREVIEW_INPUTS, MaterialXReader, is_flat_normal
from .textures import UDIM, TextureLibrary, anchored_asset_path
from .values import MAX_RADIANCE, checked_all

InputKind = Literal["color", "scalar", "float", "bool", "normal"]  # PREVIEW_INPUTS' kinds


# UsdPreviewSurface inputs the tracer has no use for. Occlusion is baked ambient occlusion,
# which a path tracer computes itself: it is ignored silently. Displacement gets one note.
_NOTED_PREVIEW_INPUTS = ("displacement",)

MAX_REFLECTANCE = 10.0
"""The largest constant reflectance (diffuse, specular or transmission colour) a material may
have. Above 1 a surface reflects more light than it receives; a little above is a stylised
look some assets use, but 10 times is a mistake: a colour authored in 0–255 instead of 0–1,
or a unit slip, which each bounce would multiply into fireflies and overflow."""

FIELD_RANGES: dict[str, tuple[float | None, float | None]] = {
    "diffuse_color": (None, MAX_REFLECTANCE),
    "specular_color": (None, MAX_REFLECTANCE),
    "transmission_color": (None, MAX_REFLECTANCE),
    "emissive_color": (None, MAX_RADIANCE),
}
"""(least, most) of the scene.Material fields whose constant values have a range beyond being
finite (None: no bound); every other number needs only be finite (the tracer clamps weights
and roughness to [0, 1] and the ior to its least)."""
_FIELD_NAMES = {spec.field: spec.usd_name for spec in PREVIEW_INPUTS}  # for messages

_OUTPUT_CHANNELS = {"rgb": (0, 1, 2), "r": (0,), "g": (1,), "b": (2,), "a": (3,)}
_WRAP_TOKENS = ("black", "clamp", "repeat", "mirror")


@dataclass(frozen=True)
class ResolvedMaterial:
    """A material's index in SceneData.materials, the uv primvar its textures read (the
    mesh's ``texcoord``) and the other primvars its primvar readers read."""

    index: int
    uv_primvar: str | None
    primvars: tuple[str, ...] = ()


@dataclass(frozen=True)
class DocumentMaterial:
    """A binding target composed from a ``.mtlx`` document (usd-core cannot compose it)."""

    path: str  # the binding target's prim path
    document: str  # absolute .mtlx path
    name: str  # the document's surfacematerial


class MaterialLibrary:
    """Converts each bound USD material once and hands out indices into ``materials``."""

    def __init__(
        self, context: ReadContext, textures: TextureLibrary, binding_purposes: tuple[str, ...]
    ) -> None:
        self.materials: list[Material] = []
        self._context = context
        self._textures = textures
        self._materialx = MaterialXReader(context, textures)
        self._purposes = binding_purposes
        # Material prim path → converted material, or None when it has no supported surface.
        self._by_path: dict[str, ResolvedMaterial | None] = {}
        self._defaults: dict[tuple[float, float, float] | None, int] = {}

    def emit(self, triangle_material: np.ndarray) -> bool:
        """Whether any of the materials (indices into ``materials``) sends light of its own."""
        return any(self.materials[index].emits for index in np.unique(triangle_material).tolist())

    def bound_material(self, prim: Usd.Prim) -> UsdShade.Material | DocumentMaterial | None:
        """The material bound to ``prim`` for the first binding purpose that has one."""
        binding = UsdShade.MaterialBindingAPI(prim)
        dangling = None
        for purpose in self._purposes:
            material, relationship = binding.ComputeBoundMaterial(purpose)
            if material:
                return material
            if relationship and relationship.GetTargets():
                dangling = relationship
        if dangling is None:
            return None
        target = dangling.GetTargets()[0]
        referenced = self._materialx.referenced(target)
        if referenced is not None:
            return DocumentMaterial(str(target), *referenced)
        # A binding whose target is missing or not a Material (e.g. it lives in a reference
        # that failed to load): the artist expects a look, not grey.
        self._context.diagnostics.note(
            "dangling-binding",
            "material bindings to missing or non-Material prims (default material used): {prims}",
            f"{prim.GetPath()} -> {target}",
        )
        return None

    def resolve(
        self,
        material: UsdShade.Material | DocumentMaterial | None,
        display_color: tuple[float, float, float] | None,
    ) -> ResolvedMaterial:
        """Index of ``material``; the default material (tinted by ``display_color``) when it is
        None or has no surface this tracer reads."""
        if material is not None:
            path = material.path if isinstance(material, DocumentMaterial) else str(material.GetPath())
            if path not in self._by_path:
                self._by_path[path] = self._convert(material, path)
            resolved = self._by_path[path]
            if resolved is not None:
                return resolved
        return ResolvedMaterial(self._default_index(display_color), None)

    def _default_index(self, display_color: tuple[float, float, float] | None) -> int:
        # All defaults share name and path so a query on "default" finds every one of them;
        # only their diffuse colour differs.
        if display_color not in self._defaults:
            self._defaults[display_color] = len(self.materials)
            material = Material(name="default", path=DEFAULT_MATERIAL_PATH)
            if display_color is not None:
                material = replace(material, diffuse_color=display_color)
            self.materials.append(material)
        return self._defaults[display_color]

    def _convert(self, material: UsdShade.Material | DocumentMaterial, path: str) -> ResolvedMaterial | None:
        if isinstance(material, DocumentMaterial):
            look = self._materialx.from_document(material.document, material.name, path)
            name = path.rsplit("/", 1)[-1]
            file = material.document
        else:
            name = material.GetPrim().GetName()
            shader, _, _ = material.ComputeSurfaceSource(UsdShade.Tokens.universalRenderContext)
            if shader and shader.GetShaderId() == "UsdPreviewSurface":
                fields, uv_primvars, primvars = self._preview_surface(shader, path)
                check_fields(fields, file=self._context.file, prim=str(shader.GetPath()), prefix="inputs:")
                return self._add(name, path, fields, uv_primvars, primvars)
            look = self._materialx.from_usd(material)
            file = self._context.file
            if look is None:
                self._context.diagnostics.note(
                    "unsupported-material",
                    "materials without a UsdPreviewSurface or MaterialX surface (renderer-specific, "
                    "...) rendered with the default material: {prims}",
                    path,
                )
        if look is None:
            return None
        check_fields(look.fields, file=file, prim=path, prefix="its MaterialX surface's ")
        return self._add(name, path, look.fields, list(look.uv_primvars), look.primvars)

    def _add(self, name: str, path: str, fields: dict, uv_primvars: list[str],
             primvars: tuple[str, ...]) -> ResolvedMaterial:
        unique_uvs = list(dict.fromkeys(uv_primvars))
        if len(unique_uvs) > 1:
            self._context.diagnostics.note(
                "several-uv-sets-material",
                "materials whose textures read several uv sets as texture coordinates (the first is used "
                "for all): {prims}",
                f"{path} ({', '.join(unique_uvs)})",
            )
        index = len(self.materials)
        self.materials.append(Material(name=name, path=path, **fields))
        return ResolvedMaterial(index, unique_uvs[0] if unique_uvs else None, tuple(dict.fromkeys(primvars)))

    def _preview_surface(self, shader: UsdShade.Shader, material_path: str):
        network = _Network(self._context, self._textures, material_path)
        fields: dict[str, object] = {}
        for spec in PREVIEW_INPUTS:
            value = network.input_value(shader, spec.usd_name, spec.kind)
            if value is not None:
                fields[spec.field] = value
        for name in _NOTED_PREVIEW_INPUTS:
            shader_input = shader.GetInput(name)
            if shader_input and shader_input.HasConnectedSource():
                self._context.diagnostics.note(
                    f"ignored-input-{name}",
                    f"UsdPreviewSurface '{name}' connections are not supported and were ignored on: {{prims}}",
                    str(shader.GetPath()),
                )
        return fields, network.uv_primvars, tuple(network.primvars)


class _Network:
    """Reads one UsdPreviewSurface's upstream network into shader_nodes trees."""

    def __init__(self, context: ReadContext, textures: TextureLibrary, material_path: str) -> None:
        self._context = context
        self._textures = textures
        self._material_path = material_path
        self.uv_primvars: list[str] = []  # texcoord primvars, in the order textures read them
        self.primvars: list[str] = []  # primvars read by value

    def input_value(self, shader: UsdShade.Shader, input_name: str, kind: InputKind):
        """The Material field value for one input, or None to keep the spec fallback."""
        source = _value_source(shader, input_name, self._context.time)
        if source is None:
            return None
        if not isinstance(source, tuple):
            value = _constant(source, kind)
            if isinstance(value, (tuple, float)):  # numbers: values.checked (bools and normals need not)
                values.checked_all(value if isinstance(value, tuple) else (value,), f"inputs:{input_name}",
                                   file=self._context.file, prim=str(shader.GetPath()))
            return value
        if kind not in ("color", "scalar", "normal"):
            self._unsupported_connection(shader, input_name)
            return None
        tree = self._output(*source)
        if tree is None:
            self._unsupported_connection(shader, input_name)
            return None
        if kind == "normal":
            return None if is_flat_normal(tree) else tree
        return nodes.field_value(tree, 3 if kind == "color" else 1)  # a scalar reads component 0

    def _unsupported_connection(self, shader: UsdShade.Shader, input_name: str) -> None:
        self._context.diagnostics.note(
            "unsupported-connection",
            "UsdPreviewSurface inputs connected to unsupported shaders (or untexturable inputs) "
            "use their fallback value: {prims}",
            f"{shader.GetPath()}.inputs:{input_name}",
        )

    def _output(self, shader: UsdShade.Shader, output_name: str) -> ShaderNode | None:
        """The tree of one shader output (4 components; a scalar output in every component)."""
        shader_id = shader.GetShaderId() or ""
        if shader_id.startswith("UsdUVTexture"):
            return self._texture(shader, output_name)
        if shader_id.startswith("UsdPrimvarReader_"):
            return self._primvar_reader(shader, shader_id)
        if shader_id == "UsdTransform2d":
            return self._transform2d(shader)
        self._context.diagnostics.note(
            f"unsupported-shader-{shader_id or 'unknown'}",
            f"shaders '{shader_id or '(no info:id)'}' are not supported; the inputs they drive use "
            "their fallback on: {prims}",
            f"{self._material_path} ({shader.GetPath().name})",
        )
        return None

    def _vector(self, shader: UsdShade.Shader, name: str, default: tuple[float, ...]) -> tuple[float, ...]:
        value = _value_source(shader, name, self._context.time)
        try:
            components = tuple(float(component) for component in value)
        except TypeError:
            return default
        if len(components) != len(default):
            return default
        return self._finite(shader, name, components)

    def _finite(self, shader: UsdShade.Shader, name: str, numbers: tuple[float, ...]) -> tuple[float, ...]:
        """``numbers`` of the input ``name`` of a shader of the network (values.checked)."""
        return values.checked_all(numbers, f"inputs:{name}", file=self._context.file, prim=str(shader.GetPath()))

    def _primvar_reader(self, reader: UsdShade.Shader, shader_id: str) -> ShaderNode:
        width = {"float": 1, "float2": 2, "float3": 3, "normal": 3, "point": 3, "vector": 3, "float4": 4,
                 "int": 1, "string": 0}.get(shader_id.split("_", 1)[1], 1)
        raw_fallback = _value_source(reader, "fallback", self._context.time)
        try:
            fallback = tuple(float(component) for component in raw_fallback)
        except TypeError:
            fallback = (float(raw_fallback),) if isinstance(raw_fallback, (int, float)) else ()
        fallback = self._finite(reader, "fallback", (fallback + (0.0,) * 4)[:4])
        varname = str(_value_source(reader, "varname", self._context.time) or "")
        if not varname:
            return nodes.constant(*fallback)
        if width == 2 and (not self.uv_primvars or self.uv_primvars[0] == varname):
            self.uv_primvars.append(varname)
            return ShaderNode("texcoord")
        self.primvars.append(varname)
        tree = ShaderNode("primvar", name=varname, values=fallback)
        return nodes.broadcast(tree) if width == 1 else tree

    def _transform2d(self, transform: UsdShade.Shader) -> ShaderNode:
        """UsdPreviewSurface's order: scale, then rotate (degrees, counter-clockwise), then
        translate."""
        upstream = _value_source(transform, "in", self._context.time)
        source = self._output(*upstream) if isinstance(upstream, tuple) else None
        if source is None:
            source = nodes.constant(*self._vector(transform, "in", (0.0, 0.0)))
        sx, sy = self._vector(transform, "scale", (1.0, 1.0))
        tx, ty = self._vector(transform, "translation", (0.0, 0.0))
        rotation = _value_source(transform, "rotation", self._context.time)
        degrees = self._finite(transform, "rotation", (float(rotation),))[0] if isinstance(rotation, (int, float)) else 0.0
        angle = math.radians(degrees)
        cos, sin = math.cos(angle), math.sin(angle)
        return nodes.node("affine2d", source, values=(sx * cos, -sy * sin, tx, sx * sin, sy * cos, ty))

    def _uv(self, texture: UsdShade.Shader) -> ShaderNode:
        upstream = _value_source(texture, "st", self._context.time)
        if isinstance(upstream, tuple):
            tree = self._output(*upstream)
            if tree is not None:
                return tree
        elif upstream is not None:
            return nodes.constant(*self._vector(texture, "st", (0.0, 0.0)))
        # An unconnected st reads the default uv set, as Storm does.
        if not self.uv_primvars:
            self.uv_primvars.append(DEFAULT_UV_SET)
        return ShaderNode("texcoord")

    def _texture(self, texture: UsdShade.Shader, output_name: str) -> ShaderNode:
        diagnostics = self._context.diagnostics
        texture_path = str(texture.GetPath())
        channels = _OUTPUT_CHANNELS.get(output_name, (0, 1, 2))
        scale = self._vector(texture, "scale", (1.0, 1.0, 1.0, 1.0))
        bias = self._vector(texture, "bias", (0.0, 0.0, 0.0, 0.0))
        fallback = self._vector(texture, "fallback", (0.0, 0.0, 0.0, 1.0))
        uv = self._uv(texture)
        tiles: list[tuple[int, int]] = []
        wrap_modes = (None, None)
        file_attribute = _producing_attribute(texture, "file")
        asset = file_attribute.Get(self._context.time) if file_attribute else None
        color_space = str(_value_source(texture, "sourceColorSpace", self._context.time) or "auto")
        if isinstance(asset, Sdf.AssetPath) and asset.path:
            resolved = asset.resolvedPath
            if UDIM in asset.path:
                resolved = anchored_asset_path(file_attribute, asset, self._context.time)
            elif not resolved:
                missing = anchored_asset_path(file_attribute, asset, self._context.time)
                diagnostics.warn(
                    f"texture file not found: {missing} (UsdUVTexture {texture_path}); using its fallback value",
                    once_key=f"texture:{missing}",
                )
            if resolved:
                for tile, loaded in self._textures.load_tiles(resolved, color_space, texture_path):
                    tiles.append((tile, loaded.index))
                    wrap_modes = loaded.wrap_modes
        else:
            diagnostics.note(
                "texture-without-file",
                "UsdUVTexture shaders without inputs:file use their fallback value: {prims}",
                texture_path,
            )
        if tiles:
            wrap = (self._wrap_mode(texture, "wrapS", wrap_modes[0]), self._wrap_mode(texture, "wrapT", wrap_modes[1]))
            # A missing UDIM tile gives the fallback, which stands in for the texel.
            texel = ShaderNode("texture", (uv,), values=fallback, tiles=tuple(tiles), wrap=wrap)
        else:
            texel = nodes.constant(*fallback)
        value = texel
        if any(scale[c] != 1 for c in channels):  # the identities cost a step per shading point
            value = nodes.node("multiply", value, nodes.constant(*scale))
        if any(bias[c] != 0 for c in channels):
            value = nodes.node("add", value, nodes.constant(*bias))
        if len(channels) == 1:
            return nodes.broadcast(nodes.swizzle(value, channels))
        return nodes.swizzle(value, (*channels, -1))

    def _wrap_mode(self, texture: UsdShade.Shader, input_name: str, from_file):
        token = str(_value_source(texture, input_name, self._context.time) or "useMetadata")
        if token in _WRAP_TOKENS:
            return token
        if token != "useMetadata":
            self._context.diagnostics.note(
                "unknown-wrap",
                "unknown UsdUVTexture wrap modes treated as useMetadata on: {prims}",
                str(texture.GetPath()),
            )
        return from_file or "repeat"


def check_fields(fields: dict[str, object], *, file: str | None, prim: str, prefix: str) -> None:
    """StageError naming ``file``, ``prim`` and the input (``prefix`` + its UsdPreviewSurface
    name: "inputs:diffuseColor", "its MaterialX surface's diffuseColor") when a Material
    field's constant is not finite or outside FIELD_RANGES, or a constant inside its
    ShaderNode tree is not finite (a texture's fallback, a folded division by 0)."""
    for field, value in fields.items():
        name = f"{prefix}{_FIELD_NAMES.get(field, field)}"
        if isinstance(value, ShaderNode):
            for node in value.walk():
                values.checked_all(node.values, f"{name} (its {node.op} node)", file=file, prim=prim)
        elif isinstance(value, (tuple, float, int)) and not isinstance(value, bool):
            least, most = FIELD_RANGES.get(field, (None, None))
            values.checked_all(value if isinstance(value, tuple) else (value,), name, file=file, prim=prim,
                               least=least, most=most)


def _value_source(shader: UsdShade.Shader, input_name: str, time: Usd.TimeCode):
    """What drives an input: (shader, output name) for a connection, a plain value, or None
    when nothing is authored."""
    attribute = _producing_attribute(shader, input_name)
    if attribute is None:
        return None
    base_name, attribute_type = UsdShade.Utils.GetBaseNameAndType(attribute.GetName())
    if attribute_type == UsdShade.AttributeType.Output:
        producer = attribute.GetPrim()
        if producer.IsA(UsdShade.Shader):
            return UsdShade.Shader(producer), base_name
        return None
    return attribute.Get(time)


def _producing_attribute(shader: UsdShade.Shader, input_name: str) -> Usd.Attribute | None:
    """The attribute whose value or connection drives an input, through NodeGraphs and
    interface inputs; None when nothing is authored."""
    shader_input = shader.GetInput(input_name)
    if not shader_input:
        return None
    attributes = shader_input.GetValueProducingAttributes(False)
    return attributes[0] if attributes else None


def _constant(value, kind: InputKind):
    try:
        if kind == "color":
            red, green, blue = (float(component) for component in value)
            return (red, green, blue)
        if kind == "bool":
            return bool(int(value))
        if kind == "normal":
            tree = nodes.constant(*(float(component) for component in value))
            return None if is_flat_normal(tree) else tree
        return float(value)
    except (TypeError, ValueError):
        return None


def display_color(prim: Usd.Prim, time: Usd.TimeCode, file: str | None = None) -> tuple[float, float, float] | None:
    """``primvars:displayColor`` when authored with a single (constant) value; StageError naming
    ``file`` and the prim that authors it when it is not finite or above MAX_REFLECTANCE.

    Constant primvars inherit down namespace, so a colour on a model's root counts.
    """
    primvar = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance("displayColor")
    if not primvar or not primvar.HasAuthoredValue():
        return None
    values = primvar.ComputeFlattened(time)
    if values is None or len(values) == 0:
        return None
    if primvar.GetInterpolation() != UsdGeom.Tokens.constant and len(values) != 1:
        return None
    # The default material's diffuse colour: a reflectance, checked as a material's is.
    red, green, blue = checked_all((float(component) for component in values[0]), primvar.GetAttr().GetName(),
                                   file=file, prim=str(primvar.GetAttr().GetPrim().GetPath()),
                                   most=FIELD_RANGES["diffuse_color"][1])
    return (red, green, blue)
