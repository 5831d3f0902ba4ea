"""Material binding and UsdPreviewSurface networks → scene.Material.

Only the universal render context is read (``outputs:surface``): that is where USD puts
the portable UsdPreviewSurface, while ``outputs:mtlx:surface`` and friends need a MaterialX
or renderer-specific shading system this tracer does not have. Inputs follow connections
through NodeGraphs and interface inputs (``GetValueProducingAttributes``); an input driven
by a UsdUVTexture becomes a scene.TextureInput.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

from pxr import Sdf, Usd, UsdGeom, UsdShade

from pxr_layers.scene import DEFAULT_MATERIAL_PATH, Material, TextureInput

from .context import ReadContext
from .textures import TextureLibrary, anchored_asset_path

InputKind = Literal["color", "scalar", "float", "bool"]


@dataclass(frozen=True)
class _PreviewInput:
    """A UsdPreviewSurface input, the Material field it fills and its spec fallback.

    kind : "color"/"scalar" may be textured; "float"/"bool" are constants in scene.Material.
    """

    usd_name: str
    field: str
    kind: InputKind


# Fallbacks come from scene.Material's defaults, which are the UsdPreviewSurface spec's.
_PREVIEW_INPUTS = (
    _PreviewInput("diffuseColor", "diffuse_color", "color"),
    _PreviewInput("emissiveColor", "emissive_color", "color"),
    _PreviewInput("roughness", "roughness", "scalar"),
    _PreviewInput("metallic", "metallic", "scalar"),
    _PreviewInput("specularColor", "specular_color", "color"),
    _PreviewInput("useSpecularWorkflow", "use_specular_workflow", "bool"),
    _PreviewInput("ior", "ior", "float"),
    _PreviewInput("opacity", "opacity", "scalar"),
    _PreviewInput("opacityThreshold", "opacity_threshold", "float"),
    _PreviewInput("clearcoat", "clearcoat", "scalar"),
    _PreviewInput("clearcoatRoughness", "clearcoat_roughness", "scalar"),
)
# UsdPreviewSurface inputs the tracer has no use for; connecting them gets one warning.
_IGNORED_PREVIEW_INPUTS = ("normal", "displacement", "occlusion")

_OUTPUT_CHANNELS = {"rgb": (0, 1, 2), "r": (0,), "g": (1,), "b": (2,), "a": (3,)}
_WRAP_TOKENS = ("black", "clamp", "repeat", "mirror")
_DEFAULT_UV_PRIMVAR = "st"


@dataclass(frozen=True)
class ResolvedMaterial:
    """A material's index in SceneData.materials and the uv primvar its textures read."""

    index: int
    uv_primvar: str | None


class MaterialLibrary:
    """Converts each bound USD material once and hands out indices into ``materials``."""

    def __init__(
        self, context: ReadContext, textures: TextureLibrary, binding_purposes: tuple[str, ...]
    ) -> None:
        self.materials: list[Material] = []
        self._context = context
        self._textures = textures
        self._purposes = binding_purposes
        # Material prim path → converted material, or None when it has no UsdPreviewSurface.
        self._by_path: dict[str, ResolvedMaterial | None] = {}
        self._defaults: dict[tuple[float, float, float] | None, int] = {}

    def bound_material(self, prim: Usd.Prim) -> UsdShade.Material | None:
        """The material bound to ``prim`` for the first binding purpose that has one."""
        binding = UsdShade.MaterialBindingAPI(prim)
        dangling = None
        for purpose in self._purposes:
            material, relationship = binding.ComputeBoundMaterial(purpose)
            if material:
                return material
            if relationship and relationship.GetTargets():
                dangling = relationship
        if dangling is not None:
            # A binding whose target is missing or not a Material (e.g. it lives in a
            # reference that failed to load): the artist expects a look, not grey.
            self._context.diagnostics.note(
                "dangling-binding",
                "material bindings to missing or non-Material prims (default material "
                "used): {prims}",
                f"{prim.GetPath()} -> {dangling.GetTargets()[0]}",
            )
        return None

    def resolve(
        self,
        material: UsdShade.Material | None,
        display_color: tuple[float, float, float] | None,
    ) -> ResolvedMaterial:
        """Index of ``material``; the default material (tinted by ``display_color``) when it is
        None or has no UsdPreviewSurface."""
        if material is not None:
            path = str(material.GetPath())
            if path not in self._by_path:
                self._by_path[path] = self._convert(material)
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

    def _convert(self, material: UsdShade.Material) -> ResolvedMaterial | None:
        diagnostics = self._context.diagnostics
        material_path = str(material.GetPath())
        shader, _, _ = material.ComputeSurfaceSource(UsdShade.Tokens.universalRenderContext)
        shader_id = shader.GetShaderId() if shader else None
        if shader_id != "UsdPreviewSurface":
            diagnostics.note(
                "unsupported-material",
                "materials without a UsdPreviewSurface on outputs:surface (MaterialX, "
                "renderer-specific, ...) rendered with the default material: {prims}",
                material_path,
            )
            return None

        fields: dict[str, object] = {}
        uv_primvars: list[str] = []
        for spec in _PREVIEW_INPUTS:
            value = self._read_input(shader, spec, uv_primvars)
            if value is not None:
                fields[spec.field] = value
        for name in _IGNORED_PREVIEW_INPUTS:
            shader_input = shader.GetInput(name)
            if shader_input and shader_input.HasConnectedSource():
                diagnostics.note(
                    f"ignored-input-{name}",
                    f"UsdPreviewSurface '{name}' connections are not supported and were "
                    "ignored on: {prims}",
                    str(shader.GetPath()),
                )
        unique_primvars = list(dict.fromkeys(uv_primvars))
        if len(unique_primvars) > 1:
            diagnostics.note(
                "several-uv-sets",
                "materials whose textures read several uv primvars (the first is used for "
                "all): {prims}",
                f"{material_path} ({', '.join(unique_primvars)})",
            )
        index = len(self.materials)
        self.materials.append(
            Material(name=material.GetPrim().GetName(), path=material_path, **fields)
        )
        return ResolvedMaterial(index, unique_primvars[0] if unique_primvars else None)

    def _read_input(self, shader: UsdShade.Shader, spec: _PreviewInput, uv_primvars: list[str]):
        """The Material field value for one input, or None to keep the spec fallback."""
        source = self._value_source(shader, spec.usd_name)
        if source is None:
            return None
        if isinstance(source, tuple):
            source_shader, output_name = source
            if spec.kind in ("color", "scalar") and source_shader.GetShaderId() == "UsdUVTexture":
                return self._texture_input(source_shader, output_name, spec.kind, uv_primvars)
            self._context.diagnostics.note(
                "unsupported-connection",
                "UsdPreviewSurface inputs connected to shaders other than UsdUVTexture "
                "(or untexturable inputs) use their fallback value: {prims}",
                f"{shader.GetPath()}.inputs:{spec.usd_name}",
            )
            return None
        return _constant(source, spec.kind)

    def _value_source(self, shader: UsdShade.Shader, input_name: str):
        """What drives an input: (shader, output name) for a connection, a plain value,
        or None when nothing is authored."""
        attribute = _producing_attribute(shader, input_name)
        if attribute is None:
            return None
        base_name, attribute_type = UsdShade.Utils.GetBaseNameAndType(attribute.GetName())
        if attribute_type == UsdShade.AttributeType.Output:
            producer = attribute.GetPrim()
            if producer.IsA(UsdShade.Shader):
                return UsdShade.Shader(producer), base_name
        return attribute.Get(self._context.time)

    def _texture_input(
        self,
        texture: UsdShade.Shader,
        output_name: str,
        kind: InputKind,
        uv_primvars: list[str],
    ) -> TextureInput | tuple[float, float, float] | float:
        diagnostics = self._context.diagnostics
        texture_path = str(texture.GetPath())
        channels = _OUTPUT_CHANNELS.get(output_name, (0, 1, 2))
        if kind == "color" and len(channels) == 1:
            channels = channels * 3  # a scalar output feeding a colour is grey
        elif kind == "scalar":
            channels = channels[:1]  # a colour output feeding a scalar gives its first channel
        scale = _vector4(self._value_source(texture, "scale"), (1.0, 1.0, 1.0, 1.0))
        bias = _vector4(self._value_source(texture, "bias"), (0.0, 0.0, 0.0, 0.0))
        fallback = _vector4(self._value_source(texture, "fallback"), (0.0, 0.0, 0.0, 1.0))

        uv_primvar = self._uv_primvar(texture)
        if uv_primvar:
            uv_primvars.append(uv_primvar)

        loaded = None
        file_attribute = _producing_attribute(texture, "file")
        asset = file_attribute.Get(self._context.time) if file_attribute else None
        if isinstance(asset, Sdf.AssetPath) and asset.path:
            if "<UDIM>" in asset.path:
                diagnostics.note(
                    "udim",
                    "UDIM textures are not supported; their fallback value is used: {prims}",
                    texture_path,
                )
            elif not asset.resolvedPath:
                missing = anchored_asset_path(file_attribute, asset, self._context.time)
                diagnostics.warn(
                    f"texture file not found: {missing} (UsdUVTexture {texture_path}); "
                    "using its fallback value",
                    once_key=f"texture:{missing}",
                )
            else:
                color_space = self._value_source(texture, "sourceColorSpace") or "auto"
                loaded = self._textures.load(asset.resolvedPath, str(color_space), texture_path)
        else:
            diagnostics.note(
                "texture-without-file",
                "UsdUVTexture shaders without inputs:file use their fallback value: {prims}",
                texture_path,
            )
        if loaded is None:
            # The fallback stands in for the texel, so scale and bias still apply to it.
            values = tuple(fallback[c] * scale[c] + bias[c] for c in channels)
            return values if kind == "color" else values[0]
        wrap_s = self._wrap_mode(texture, "wrapS", loaded.wrap_modes[0])
        wrap_t = self._wrap_mode(texture, "wrapT", loaded.wrap_modes[1])
        return TextureInput(
            texture=loaded.index,
            channels=channels,
            scale=scale,
            bias=bias,
            wrap_s=wrap_s,
            wrap_t=wrap_t,
        )

    def _wrap_mode(self, texture: UsdShade.Shader, input_name: str, from_file):
        token = str(self._value_source(texture, input_name) or "useMetadata")
        if token in _WRAP_TOKENS:
            return token
        if token != "useMetadata":
            self._context.diagnostics.note(
                "unknown-wrap",
                "unknown UsdUVTexture wrap modes treated as useMetadata on: {prims}",
                str(texture.GetPath()),
            )
        return from_file or "repeat"

    def _uv_primvar(self, texture: UsdShade.Shader) -> str | None:
        """The primvar name a UsdUVTexture's ``st`` reads through a UsdPrimvarReader_float2."""
        source = self._value_source(texture, "st")
        if isinstance(source, tuple):
            reader, _ = source
            reader_id = reader.GetShaderId() or ""
            if reader_id == "UsdTransform2d":
                self._context.diagnostics.note(
                    "uv-transform",
                    "UsdTransform2d nodes are not supported; texture coordinates are used "
                    "untransformed on: {prims}",
                    str(reader.GetPath()),
                )
                upstream = self._value_source(reader, "in")
                if not isinstance(upstream, tuple):
                    return _DEFAULT_UV_PRIMVAR
                reader, _ = upstream
                reader_id = reader.GetShaderId() or ""
            if reader_id.startswith("UsdPrimvarReader"):
                varname = self._value_source(reader, "varname")
                if varname:
                    return str(varname)
        return _DEFAULT_UV_PRIMVAR


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
        return float(value)
    except (TypeError, ValueError):
        return None


def _vector4(value, default: tuple[float, float, float, float]):
    try:
        components = tuple(float(component) for component in value)
    except TypeError:
        return default
    return components if len(components) == 4 else default


def display_color(prim: Usd.Prim, time: Usd.TimeCode) -> tuple[float, float, float] | None:
    """``primvars:displayColor`` when authored with a single (constant) value.

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
    red, green, blue = (float(component) for component in values[0])
    return (red, green, blue)
