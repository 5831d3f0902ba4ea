"""Translating MaterialX nodes: node outputs into ShaderNode trees (shader_nodes.py), and
surface shaders into scene.Material fields. networks.py walks the graphs and calls the
``HANDLERS`` below for the categories written by hand:

    image, tiledimage (uv transform folded into one affine2d), texcoord (index 0: the mesh's
    texcoord; index N: primvar "stN"), geompropvalue (vector2: a uv set, else a primvar),
    geomcolor (primvar displayColor), constant, dot (pass-through), add, subtract, multiply,
    divide, min, max, power, modulo, absval, floor, ceil, sqrt, sin, cos, mix, clamp,
    dotproduct, normalize, swizzle (1.38), extract, separate2/3/4, combine2/3/4, convert,
    ifgreater, ifgreatereq, ifequal, rotate2d (degrees, about the origin), normalmap
    (its tangent-space value, see below).

Image colour spaces: ``srgb_texture`` → sRGB, ``lin_rec709``/``raw``/none → raw, anything
else raw with a note; only colour-typed images (color3/color4) are colour-managed, as in
MaterialX. Address modes periodic/clamp/mirror/constant → repeat/clamp/mirror/black.

Surface shaders (standard_surface and OpenPBR through MaterialX's own translation graphs,
gltf_pbr by hand, MaterialX's UsdPreviewSurface 1:1) become Material fields as docs/materials.md
tabulates parameter by parameter. Fields are stored as plain tuples/floats whenever they fold
to constants.

Primvars: texcoord index 0, and the first vector2 geompropvalue, read the mesh's texcoord
(``uv_primvars``, "st" for texcoord); other indices ("st1", …) and other geompropvalues and
geomcolor ("displayColor") are primvar nodes (``primvars``).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Callable

import MaterialX as mx
from pxr import Ar

from pxr_layers.scene import Material
from pxr_layers.shader_nodes import ShaderNode, broadcast, constant, field_value, node, swizzle

from ..defaults import DEFAULT_UV_SET
from ..textures import UDIM
from .networks import COMPONENTS, Evaluator, Frame, texture_path


@dataclass(frozen=True)
class PreviewInput:
    """A UsdPreviewSurface input, the Material field it fills and its kind: "color",
    "scalar" and "normal" may vary over the surface; "float" and "bool" are constants."""

    usd_name: str
    field: str
    kind: str


# Fallbacks come from scene.Material's defaults, which are the UsdPreviewSurface spec's.
PREVIEW_INPUTS = (
    PreviewInput("diffuseColor", "diffuse_color", "color"),
    PreviewInput("emissiveColor", "emissive_color", "color"),
    PreviewInput("roughness", "roughness", "scalar"),
    PreviewInput("metallic", "metallic", "scalar"),
    PreviewInput("specularColor", "specular_color", "color"),
    PreviewInput("useSpecularWorkflow", "use_specular_workflow", "bool"),
    PreviewInput("ior", "ior", "float"),
    PreviewInput("opacity", "opacity", "scalar"),
    PreviewInput("opacityThreshold", "opacity_threshold", "float"),
    PreviewInput("clearcoat", "clearcoat", "scalar"),
    PreviewInput("clearcoatRoughness", "clearcoat_roughness", "scalar"),
    PreviewInput("normal", "normal", "normal"),
)


def is_flat_normal(value: ShaderNode) -> bool:
    """Whether a tangent-space normal is the constant (0, 0, 1): no perturbation."""
    return value.is_constant and value.values[:3] == (0.0, 0.0, 1.0)


_WRAP = {"periodic": "repeat", "clamp": "clamp", "mirror": "mirror", "constant": "black"}
SURFACES = {"standard_surface", "open_pbr_surface", "gltf_pbr", "UsdPreviewSurface", "surface"}
HAIR_BSDF = "chiang_hair_bsdf"
_CHANNEL_LETTERS = {"x": 0, "y": 1, "z": 2, "w": 3, "r": 0, "g": 1, "b": 2, "a": 3, "0": -1, "1": -2}


@dataclass(frozen=True)
class MaterialXLook:
    """What a MaterialX material becomes: scene.Material keyword fields, and primvars."""

    fields: dict[str, object]  # Material field name -> value (tuple/float/bool/ShaderNode)
    uv_primvars: tuple[str, ...]  # texcoord primvar names read (usually ("st",))
    primvars: tuple[str, ...]  # other primvars read (geompropvalue, geomcolor, texcoord N > 0)


# ---- hand-written nodes ---------------------------------------------------------------
def _is(value: ShaderNode, number: float, width: int) -> bool:
    return value.is_constant and all(component == number for component in value.values[:width])


def _op(op: str, a: ShaderNode, b: ShaderNode, width: int) -> ShaderNode:
    """node(op, a, b) without the identities translation graphs are full of (× 1, + 0, ÷ 1):
    components past ``width`` (the output type's) are unused, so they need not survive."""
    if op == "multiply" and _is(b, 1.0, width) or op in ("add", "subtract") and _is(b, 0.0, width) \
            or op == "divide" and _is(b, 1.0, width):
        return a
    if op == "multiply" and _is(a, 1.0, width) or op == "add" and _is(a, 0.0, width):
        return b
    return node(op, a, b)


def _binary(op: str):
    def handler(ev: Evaluator, element, out_type, output, frame):
        return _op(op, ev.arg(element, "in1", frame, out_type), ev.arg(element, "in2", frame, out_type),
                   COMPONENTS.get(out_type, 4))
    return handler


def _unary(op: str):
    def handler(ev: Evaluator, element, out_type, output, frame):
        return node(op, ev.input(element, "in", frame))
    return handler


def _constant_node(ev, element, out_type, output, frame):
    return ev.input(element, "value", frame)


def _dot(ev, element, out_type, output, frame):
    return ev.input(element, "in", frame)


def _mix(ev, element, out_type, output, frame):
    background, foreground = ev.input(element, "bg", frame), ev.input(element, "fg", frame)
    amount = ev.arg(element, "mix", frame, out_type)
    width = COMPONENTS.get(out_type, 4)
    if _is(amount, 0.0, width):
        return background
    if _is(amount, 1.0, width):
        return foreground
    return node("mix", background, foreground, amount)


def _clamp(ev, element, out_type, output, frame):
    return node("clamp", ev.input(element, "in", frame), ev.arg(element, "low", frame, out_type),
                ev.arg(element, "high", frame, out_type))


def _dotproduct(ev, element, out_type, output, frame):
    width = COMPONENTS.get(ev.input_type(element, "in1"), 3)
    return node("dotproduct", ev.input(element, "in1", frame), ev.input(element, "in2", frame), values=(width,))


def _swizzle(ev, element, out_type, output, frame):
    channels, _ = ev.string(element, "channels", frame)
    source = ev.input(element, "in", frame)
    if COMPONENTS.get(ev.input_type(element, "in"), 1) == 1:
        return broadcast(source)
    return swizzle(source, tuple(_CHANNEL_LETTERS.get(letter, -1) for letter in channels))


def _extract(ev, element, out_type, output, frame):
    return swizzle(ev.input(element, "in", frame), (ev.integer(element, "index", frame),))


def _separate(ev, element, out_type, output, frame):
    channel = _CHANNEL_LETTERS.get(output[-1:], 0) if output.startswith("out") else 0
    return swizzle(ev.input(element, "in", frame), (channel,))


def _combine(ev, element, out_type, output, frame):
    components: list[ShaderNode] = []
    for index in range(1, 5):
        name = f"in{index}"
        if ev.input_port(element, name) is None:
            break
        value = ev.input(element, name, frame)
        width = COMPONENTS.get(ev.input_type(element, name), 1)
        components.extend(value if width == 1 else swizzle(value, (k,)) for k in range(width))
    return node("combine", *components[:4])


def _convert(ev, element, out_type, output, frame):
    source = ev.input(element, "in", frame)
    width_in = COMPONENTS.get(ev.input_type(element, "in"), 1)
    width_out = COMPONENTS.get(out_type, 1)
    if width_in == 1:
        return swizzle(source, (0,) * width_out)
    if width_out <= width_in:
        return swizzle(source, tuple(range(width_out)))
    pad = (-2,) if width_out == 4 and out_type in ("color4", "vector4") else (-1,)
    return swizzle(source, tuple(range(width_in)) + pad * (width_out - width_in))


def _conditional(op: str):
    def handler(ev: Evaluator, element, out_type, output, frame):
        if ev.input_port(element, "in1") is None:  # boolean-valued variants
            yes, no = constant(1.0), constant(0.0)
        else:
            yes, no = ev.input(element, "in1", frame), ev.input(element, "in2", frame)
        return node(op, ev.input(element, "value1", frame), ev.input(element, "value2", frame), yes, no)
    return handler


def _rotate2d(ev, element, out_type, output, frame):
    source = ev.input(element, "in", frame)
    amount = ev.input(element, "amount", frame)
    if amount.is_constant:
        radians = math.radians(amount.values[0])
        sa, ca = math.sin(radians), math.cos(radians)
        return node("affine2d", source, values=(ca, sa, 0.0, -sa, ca, 0.0))
    radians = node("multiply", amount, constant(math.pi / 180.0))
    sa, ca = broadcast(node("sin", radians)), broadcast(node("cos", radians))
    x, y = swizzle(source, (0, 0)), swizzle(source, (1, 1))
    rotated_x = node("add", node("multiply", ca, x), node("multiply", sa, y))
    rotated_y = node("subtract", node("multiply", ca, y), node("multiply", sa, x))
    return node("combine", rotated_x, rotated_y)


def _texcoord(ev, element, out_type, output, frame):
    index = ev.integer(element, "index", frame)
    return ev.uv(DEFAULT_UV_SET) if index == 0 else ev.primvar(f"{DEFAULT_UV_SET}{index}", (0.0, 0.0, 0.0, 0.0))


def _geompropvalue(ev, element, out_type, output, frame):
    name, _ = ev.string(element, "geomprop", frame)
    default = ev.input(element, "default", frame)
    if not name:
        return default
    if out_type == "vector2":
        return ev.uv(name)
    fallback = default.values if default.is_constant else (0.0, 0.0, 0.0, 0.0)
    return ev.primvar(name, fallback)


def _geomcolor(ev, element, out_type, output, frame):
    return ev.primvar("displayColor", (1.0, 1.0, 1.0, 1.0))


def normalmap_tangent(ev: Evaluator, element, frame: Frame) -> ShaderNode:
    """A normalmap node's tangent-space normal: (in·2 − 1) with x, y times ``scale``."""
    decoded = node("subtract", node("multiply", ev.input(element, "in", frame), constant(2.0, 2.0, 2.0, 0.0)),
                   constant(1.0, 1.0, 1.0, 0.0))
    scale = ev.input(element, "scale", frame)
    if COMPONENTS.get(ev.input_type(element, "scale"), 1) == 1:
        factor = node("combine", scale, scale, constant(1.0))
    else:
        factor = node("combine", swizzle(scale, (0,)), swizzle(scale, (1,)), constant(1.0))
    return _op("multiply", decoded, factor, 3)


def _normalmap(ev, element, out_type, output, frame):
    return normalmap_tangent(ev, element, frame)


def _image(ev: Evaluator, element, out_type, output, frame, uv: ShaderNode | None = None):
    default = ev.input(element, "default", frame)
    filename, port = ev.string(element, "file", frame)
    if not filename or port is None:
        return default
    if uv is None:
        uv = ev.input(element, "texcoord", frame)
    color_space = "raw"
    if out_type in ("color3", "color4"):  # MaterialX colour-manages colour-typed images only
        space = port.getActiveColorSpace() if isinstance(port, mx.Input) else ""
        if space == "srgb_texture":
            color_space = "sRGB"
        elif space not in ("", "lin_rec709", "raw"):
            ev.note(f"mtlx-color-space-{space}", f"MaterialX textures in colour space '{space}' were read "
                    "as raw (not converted) on: {prims}", element.getName())
    path = texture_path(filename, port)
    tiles = []
    if UDIM not in path and not os.path.isfile(path) and not Ar.IsPackageRelativePath(path):  # (a member is no file)
        ev.reader.context.diagnostics.warn(f"texture file not found: {path} (MaterialX image {ev.material_path} "
                                           f"{element.getName()}); using its default value", once_key=f"texture:{path}")
    else:
        user = f"{ev.material_path} ({element.getName()})"
        tiles = [(tile, loaded.index) for tile, loaded in ev.reader.textures.load_tiles(path, color_space, user)]
    if not tiles:
        return default
    wrap = tuple(_WRAP.get(ev.string(element, name, frame)[0] or "periodic", "repeat")
                 for name in ("uaddressmode", "vaddressmode"))
    fallback = default.values if default.is_constant else (0.0, 0.0, 0.0, 0.0)
    lookup = ShaderNode("texture", (uv,), values=tuple(float(v) for v in fallback), tiles=tuple(tiles), wrap=wrap)
    return swizzle(lookup, tuple(range(COMPONENTS.get(out_type, 3))))


def _tiledimage(ev, element, out_type, output, frame):
    if not ev.string(element, "file", frame)[0]:
        return ev.input(element, "default", frame)
    uv = ev.input(element, "texcoord", frame)
    tiling, offset, image_size, tile_size = (ev.input(element, name, frame) for name in (
        "uvtiling", "uvoffset", "realworldimagesize", "realworldtilesize"))
    if all(value.is_constant for value in (tiling, offset, image_size, tile_size)):
        matrix = []
        for axis in (0, 1):
            ratio = tile_size.values[axis] / image_size.values[axis] if image_size.values[axis] else 0.0
            scale, shift = tiling.values[axis] * ratio, -offset.values[axis] * ratio
            matrix.append((scale, 0.0, shift) if axis == 0 else (0.0, scale, shift))
        values = matrix[0] + matrix[1]
        if values != (1.0, 0.0, 0.0, 0.0, 1.0, 0.0):
            uv = node("affine2d", uv, values=values)
    else:
        uv = node("multiply", node("divide", node("subtract", node("multiply", uv, tiling), offset), image_size),
                  tile_size)
    return _image(ev, element, out_type, output, frame, uv=uv)


def _constant_inputs(ev: Evaluator, element, frame: Frame, names: tuple[str, ...]) -> list[tuple[float, ...]]:
    """Each input's constant value; one that varies over the surface reads its nodedef's
    default, after a note (the hair helpers are evaluated once per material)."""
    values = []
    for name in names:
        value = ev.input(element, name, frame)
        if not value.is_constant:
            ev.note(f"mtlx-varying-{element.getCategory()}", f"MaterialX '{element.getCategory()}' inputs that vary "
                    "over the surface are not supported; their defaults were used on: {prims}",
                    f"{element.getName()}.{name}")
            default = element.getNodeDef().getActiveInput(name)
            value = ev.port_value(default, Frame(None), default.getType()) or constant(0.0)
        values.append(value.values)
    return values


def _hair_roughness(ev, element, out_type, output, frame):
    """chiang_hair_roughness: MaterialX's (v, s) pairs of each lobe (Chiang et al. 2016, eq. 7
    and its azimuthal fit; TT and TRT scale v by scale²)."""
    longitudinal, azimuthal, scale_tt, scale_trt = (
        value[0] for value in _constant_inputs(ev, element, frame, ("longitudinal", "azimuthal", "scale_TT",
                                                                     "scale_TRT")))
    lr, ar = min(max(longitudinal, 0.001), 1.0), min(max(azimuthal, 0.001), 1.0)
    v = (0.726 * lr + 0.812 * lr ** 2 + 3.7 * lr ** 20) ** 2
    s = 0.265 * ar + 1.194 * ar ** 2 + 5.372 * ar ** 22
    scale = {"roughness_R": 1.0, "roughness_TT": scale_tt, "roughness_TRT": scale_trt}.get(output, 1.0)
    return constant(v * scale * scale, s)


def _hair_absorption_from_color(ev, element, out_type, output, frame):
    """chiang_hair_absorption_from_color: σa = (ln c / β(βn))², Chiang et al. 2016, eq. 9."""
    color, (beta, *_) = _constant_inputs(ev, element, frame, ("color", "azimuthal_roughness"))
    fit = (5.969 - 0.215 * beta + 2.532 * beta ** 2 - 10.73 * beta ** 3 + 5.574 * beta ** 4
           + 0.245 * beta ** 5)
    return constant(*((math.log(min(max(c, 0.001), 1.0)) / fit) ** 2 for c in color[:3]))


def _hair_absorption_from_melanin(ev, element, out_type, output, frame):
    """deon_hair_absorption_from_melanin: σa from melanin concentration and redness (d'Eon
    et al. 2011; MaterialX's pigment colours, exp(−σ) of theirs)."""
    (concentration, *_), (redness, *_), eumelanin, pheomelanin = _constant_inputs(
        ev, element, frame, ("melanin_concentration", "melanin_redness", "eumelanin_color", "pheomelanin_color"))
    melanin = -math.log(max(1.0 - concentration, 0.0001))
    return constant(*(max(melanin * (1.0 - redness) * -math.log(max(e, 1e-6))
                          + melanin * redness * -math.log(max(p, 1e-6)), 0.0)
                      for e, p in zip(eumelanin[:3], pheomelanin[:3])))


HANDLERS: dict[str, Callable] = {
    "constant": _constant_node, "dot": _dot, "mix": _mix, "clamp": _clamp, "dotproduct": _dotproduct,
    "swizzle": _swizzle, "extract": _extract, "separate2": _separate, "separate3": _separate,
    "separate4": _separate, "combine2": _combine, "combine3": _combine, "combine4": _combine,
    "convert": _convert, "ifgreater": _conditional("ifgreater"), "ifgreatereq": _conditional("ifgreatereq"),
    "ifequal": _conditional("ifequal"), "rotate2d": _rotate2d, "texcoord": _texcoord,
    "geompropvalue": _geompropvalue, "geomcolor": _geomcolor, "normalmap": _normalmap, "image": _image,
    "tiledimage": _tiledimage, "normalize": _unary("normalize"), "chiang_hair_roughness": _hair_roughness,
    "chiang_hair_absorption_from_color": _hair_absorption_from_color,
    "deon_hair_absorption_from_melanin": _hair_absorption_from_melanin,
}
"""Category → handler(evaluator, element, out_type, output name, frame) -> ShaderNode."""
for _name in ("add", "subtract", "multiply", "divide", "min", "max", "power", "modulo"):
    HANDLERS[_name] = _binary(_name)
for _name in ("absval", "floor", "ceil", "sqrt", "sin", "cos"):
    HANDLERS[_name] = _unary(_name)


# ---- surface shaders ------------------------------------------------------------------
def look(evaluator: Evaluator, surface: mx.Node, frame: Frame) -> MaterialXLook | None:
    """The look of a surface shader node (a supported category: SURFACES); None, after a
    note, for any other."""
    library = evaluator.reader.library
    category = surface.getCategory()
    if category == "standard_surface":
        fields = _standard_surface(evaluator, lambda name: evaluator.input(surface, name, frame))
        fields["normal"] = _normal(evaluator, surface, "normal", frame)
    elif category == "open_pbr_surface":
        translation = library.getNodeDef("ND_open_pbr_surface_to_standard_surface").getImplementation()

        def bind(name):
            port = evaluator.input_port(surface, name)
            return (port, frame) if port is not None else None

        translated = Frame(bind)

        def get(name):
            output = translation.getOutput(f"{name}_out")
            value = evaluator.port_value(output, translated, output.getType()) if output is not None else None
            if value is None:  # standard_surface's own default
                default = library.getNodeDef("ND_standard_surface_surfaceshader").getActiveInput(name)
                value = evaluator.port_value(default, frame, default.getType()) if default is not None else None
            return value if value is not None else constant(0.0)

        fields = _standard_surface(evaluator, get)
        fields["normal"] = _normal(evaluator, surface, "geometry_normal", frame)
    elif category == "gltf_pbr":
        fields = _gltf(evaluator, surface, frame)
    elif category == "UsdPreviewSurface":
        fields = _preview(evaluator, surface, frame)
    elif category == "surface" and _bsdf_node(evaluator, surface, frame) is not None:
        bsdf, bsdf_frame = _bsdf_node(evaluator, surface, frame)
        fields = _hair(evaluator, bsdf, bsdf_frame)
        fields["opacity"] = field_value(evaluator.input(surface, "opacity", frame), 1)
    else:
        evaluator.reader.context.diagnostics.note(
            f"unsupported-node-{category}",
            f"MaterialX nodes '{category}' are not supported; their inputs' defaults were used on: {{prims}}",
            f"{evaluator.material_path} ({surface.getName()})")
        return None
    return MaterialXLook(fields, tuple(evaluator.uv_primvars), tuple(evaluator.primvars))


def _standard_surface(ev: Evaluator, get: Callable[[str], ShaderNode]) -> dict[str, object]:
    translation = ev.reader.library.getNodeDef("ND_standard_surface_to_UsdPreviewSurface").getImplementation()
    frame = Frame(lambda name: get(name))

    def out(name: str) -> ShaderNode:
        value = ev.port_value(translation.getOutput(name), frame, "float")
        return value if value is not None else constant(0.0)

    return {
        "diffuse_color": field_value(out("diffuseColor_out"), 3),
        "emissive_color": field_value(out("emissiveColor_out"), 3),
        "metallic": field_value(out("metallic_out"), 1),
        "roughness": field_value(out("roughness_out"), 1),
        "clearcoat": field_value(out("clearcoat_out"), 1),
        "clearcoat_roughness": field_value(out("clearcoatRoughness_out"), 1),
        "opacity": field_value(out("opacity_out"), 1),
        "ior": _uniform(ev, out("ior_out"), "ior", 1.5),
        "transmission": field_value(get("transmission"), 1),
        "transmission_color": field_value(get("transmission_color"), 3),
        "thin_walled": bool(_uniform(ev, get("thin_walled"), "thin_walled", 0.0)),
    }


def _gltf(ev: Evaluator, surface, frame) -> dict[str, object]:
    def get(name):
        return ev.input(surface, name, frame)

    base = get("base_color")
    emissive = node("multiply", get("emissive"), broadcast(get("emissive_strength")))
    transmission = get("transmission")
    fields = {
        "diffuse_color": field_value(base, 3),
        "metallic": field_value(get("metallic"), 1),
        "roughness": field_value(get("roughness"), 1),
        "emissive_color": field_value(emissive, 3),
        "clearcoat": field_value(get("clearcoat"), 1),
        "clearcoat_roughness": field_value(get("clearcoat_roughness"), 1),
        "transmission": field_value(transmission, 1),
        "ior": _uniform(ev, get("ior"), "ior", 1.5),
        "normal": _normal(ev, surface, "normal", frame),
    }
    if not (transmission.is_constant and transmission.values[0] == 0.0):
        fields["transmission_color"] = field_value(base, 3)
        fields["thin_walled"] = _uniform(ev, get("thickness"), "thickness", 0.0) == 0.0
    mode = ev.integer(surface, "alpha_mode", frame)
    if mode == 0:
        fields["opacity"] = 1.0
    else:
        fields["opacity"] = field_value(get("alpha"), 1)
        fields["opacity_threshold"] = (_uniform(ev, get("alpha_cutoff"), "alpha_cutoff", 0.5)
                                       if mode == 1 else 0.0)
    return fields


def _preview(ev: Evaluator, surface, frame) -> dict[str, object]:
    fields: dict[str, object] = {}
    for spec in PREVIEW_INPUTS:
        value = ev.input(surface, spec.usd_name, frame)
        if spec.kind == "color":
            fields[spec.field] = field_value(value, 3)
        elif spec.kind == "scalar":
            fields[spec.field] = field_value(value, 1)
        elif spec.kind == "normal":
            fields[spec.field] = None if is_flat_normal(value) else value
        else:
            default = getattr(Material, spec.field)
            uniform = _uniform(ev, value, spec.usd_name, float(default))
            fields[spec.field] = bool(uniform) if spec.kind == "bool" else uniform
    return fields


def _bsdf_node(ev: Evaluator, surface, frame: Frame):
    """(node, frame) of the chiang_hair_bsdf a ``surface`` node's bsdf input is connected to;
    None for any other BSDF (the one BSDF node read alone: other BSDF graphs are noted as
    unsupported by the caller)."""
    port = surface.getInput("bsdf")
    source = ev.follow(port, frame) if port is not None else None
    if source is None or source[0] != "node" or source[1].getCategory() != HAIR_BSDF:
        return None
    return source[1], source[3]


def _hair(ev: Evaluator, bsdf, frame: Frame) -> dict[str, object]:
    """Material fields of a chiang_hair_bsdf node (scene.Material.hair; trace/hair.py).
    Tints and absorption may vary (textures, primvars); ior, roughness and cuticle_angle are
    one value per material; normal and curve_direction are the fibre's own."""
    def get(name):
        return ev.input(bsdf, name, frame)

    def pair(name: str) -> tuple[float, float]:
        value = get(name)
        if value.is_constant:
            return value.values[0], value.values[1]
        default = getattr(Material, f"hair_{name.lower()}")
        ev.note(f"mtlx-varying-{name}", f"MaterialX chiang_hair_bsdf '{name}' inputs that vary over the surface "
                f"are not supported; {default} was used on: {{prims}}")
        return default

    for name in ("normal", "curve_direction"):
        port = bsdf.getInput(name)
        if port is not None and ev.follow(port, frame) is not None:
            ev.note("mtlx-hair-frame", "chiang_hair_bsdf 'normal' and 'curve_direction' inputs were ignored (a "
                    "fibre's own normal and tangent are used) on: {prims}", name)
    return {
        "hair": True,
        "hair_tint_r": field_value(get("tint_R"), 3),
        "hair_tint_tt": field_value(get("tint_TT"), 3),
        "hair_tint_trt": field_value(get("tint_TRT"), 3),
        "hair_roughness_r": pair("roughness_R"),
        "hair_roughness_tt": pair("roughness_TT"),
        "hair_roughness_trt": pair("roughness_TRT"),
        "hair_cuticle_angle": _uniform(ev, get("cuticle_angle"), "cuticle_angle", 0.5),
        "hair_absorption": field_value(get("absorption_coefficient"), 3),
        "ior": _uniform(ev, get("ior"), "ior", 1.55),
    }


def _uniform(ev: Evaluator, value: ShaderNode, name: str, default: float) -> float:
    """A field the tracer takes as one number: the constant, or ``default`` with a note."""
    if value.is_constant:
        return value.values[0]
    ev.note(f"mtlx-varying-{name}", f"MaterialX '{name}' inputs that vary over the surface are not "
            f"supported; {default} was used on: {{prims}}")
    return default


def _normal(ev: Evaluator, surface, name: str, frame) -> ShaderNode | None:
    """Material.normal from a surface's world-space normal input: a normalmap's
    tangent-space value; None when unconnected (anything else is noted and ignored)."""
    port = surface.getInput(name)
    source = ev.follow(port, frame) if port is not None else None
    while source is not None and source[0] == "node" and source[1].getCategory() == "dot":
        inner = source[1].getInput("in")
        source = ev.follow(inner, source[3]) if inner is not None else None
    if source is None:
        return None
    if source[0] == "node" and source[1].getCategory() == "normalmap":
        tangent = normalmap_tangent(ev, source[1], source[3])
        return None if is_flat_normal(tangent) else tangent
    ev.note("mtlx-normal", "MaterialX surface normals not made by a normalmap node were ignored on: {prims}",
            name)
    return None
