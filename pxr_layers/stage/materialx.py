"""MaterialX looks as shader-node trees: .mtlx documents referenced from USD, and UsdShade
networks of MaterialX nodes (``info:id = "ND_…"``), read into scene.Material fields.

usd-core has no usdMtlx plugin, so a reference to a .mtlx document does not compose and the
binding target under it does not exist. :meth:`MaterialXReader.referenced` finds the prim
whose reference (or payload) named the document and maps the target onto usdMtlx's naming
(``<surfacematerial name="X">`` at ``/MaterialX/Materials/X``); :meth:`from_document` reads
that material with the MaterialX library itself (``import MaterialX``). A flattened network
(:meth:`from_usd`) is copied into an in-memory MaterialX document, node for node, so both
forms go through one evaluator.

Evaluation. Every node output becomes a :class:`ShaderNode` tree (shader_nodes.py). The
nodes below are written by hand; any other node whose nodedef is implemented by a NodeGraph
(UsdUVTexture, UsdPrimvarReader, UsdTransform2d, place2d, most of stdlib) is expanded with
its inputs bound to the graph's interface, as MaterialX's code generators do. Anything else
is noted once per category and gives its output's default.

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
import threading
from dataclasses import dataclass
from typing import Callable

import MaterialX as mx
from pxr import Ar, Sdf, Usd, UsdShade

from pxr_layers.scene import Material
from pxr_layers.shader_nodes import ShaderNode, broadcast, constant, field_value, node, swizzle

from .context import ReadContext
from .defaults import DEFAULT_UV_SET
from .textures import UDIM, TextureLibrary, anchored_asset_path

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


MAX_DEPTH = 128
"""Nested node evaluations before a graph counts as runaway (cyclic). Each level costs a
handful of Python frames, so this stays well inside Python's recursion limit."""

_COMPONENTS = {"float": 1, "integer": 1, "boolean": 1, "vector2": 2, "color3": 3, "vector3": 3,
               "color4": 4, "vector4": 4}
_WRAP = {"periodic": "repeat", "clamp": "clamp", "mirror": "mirror", "constant": "black"}
_SURFACES = {"standard_surface", "open_pbr_surface", "gltf_pbr", "UsdPreviewSurface"}
_CHANNEL_LETTERS = {"x": 0, "y": 1, "z": 2, "w": 3, "r": 0, "g": 1, "b": 2, "a": 3, "0": -1, "1": -2}

_library_lock = threading.Lock()
_library_document: mx.Document | None = None


def standard_library() -> mx.Document:
    """MaterialX's standard data libraries (nodedefs, implementation graphs, translations),
    loaded once per process and shared read-only."""
    global _library_document
    with _library_lock:
        if _library_document is None:
            library = mx.createDocument()
            mx.loadLibraries(mx.getDefaultDataLibraryFolders(), mx.getDefaultDataSearchPath(), library)
            _library_document = library
        return _library_document


@dataclass(frozen=True)
class MaterialXLook:
    """What a MaterialX material becomes: scene.Material keyword fields, and primvars."""

    fields: dict[str, object]  # Material field name -> value (tuple/float/bool/ShaderNode)
    uv_primvars: tuple[str, ...]  # texcoord primvar names read (usually ("st",))
    primvars: tuple[str, ...]  # other primvars read (geompropvalue, geomcolor, texcoord N > 0)


class _Frame:
    """One level of graph expansion: how ``interfacename`` inputs of its nodes bind.

    bind(name) → (port, frame) to evaluate instead, a ready ShaderNode, or None (unbound).
    """

    def __init__(self, bind: Callable[[str], object] | None) -> None:
        self.bind = bind
        self.cache: dict[tuple[str, str], ShaderNode] = {}


def _parse(text: str, type_name: str) -> tuple[float, ...] | None:
    """A MaterialX value string as floats (booleans 1/0); None when it is not numeric."""
    text = text.strip()
    if type_name == "boolean":
        return (1.0 if text.lower() == "true" else 0.0,)
    try:
        return tuple(float(part) for part in text.replace(",", " ").split())
    except ValueError:
        return None


class _Evaluator:
    """Evaluates one material's node outputs into ShaderNode trees."""

    def __init__(self, reader: MaterialXReader, material_path: str) -> None:
        self.reader = reader
        self.material_path = material_path
        self.uv_primvars: list[str] = []
        self.primvars: list[str] = []
        self._active: set[tuple[int, str, str]] = set()
        self._depth = 0
        self._compound_frames: dict[tuple[str, int], _Frame] = {}

    # ---- diagnostics ------------------------------------------------------------------
    def note(self, kind: str, template: str, where: str = "") -> None:
        label = f"{self.material_path} ({where})" if where else self.material_path
        self.reader.context.diagnostics.note(kind, template, label)

    # ---- ports ------------------------------------------------------------------------
    def follow(self, port, frame: _Frame):
        """Where ``port``'s value comes from: ("node", node, output, frame), ("value", port),
        ("ready", ShaderNode) or None (nothing authored)."""
        for _ in range(MAX_DEPTH):
            interface = port.getInterfaceName()
            if interface:
                bound = frame.bind(interface) if frame.bind else None
                if bound is None:
                    return None
                if isinstance(bound, ShaderNode):
                    return ("ready", bound)
                port, frame = bound
                continue
            node_name = port.getNodeName()
            if node_name:
                parent = port.getParent()
                if isinstance(port, mx.Output) and isinstance(parent, (mx.NodeGraph, mx.Document)):
                    graph = parent
                else:
                    graph = parent.getParent()
                upstream = graph.getNode(node_name) if graph is not None else None
                if upstream is None:
                    self.note("mtlx-dangling", "MaterialX inputs connected to missing nodes read their "
                              "defaults on: {prims}", node_name)
                    return None
                return ("node", upstream, port.getOutputString(), frame)
            graph_name = port.getNodeGraphString()
            if graph_name:
                graph = port.getDocument().getNodeGraph(graph_name)
                if graph is None:
                    return None
                output = graph.getOutput(port.getOutputString()) if port.getOutputString() else None
                if output is None:
                    outputs = graph.getOutputs()
                    if not outputs:
                        return None
                    output = outputs[0]
                frame = self._compound_frame(graph, frame)
                port = output
                continue
            geomprop = port.getDefaultGeomPropString() if isinstance(port, mx.Input) else ""
            if port.getValueString() or geomprop:
                return ("value", port)
            return None
        self.note("mtlx-recursion", "MaterialX graphs nested too deeply (cyclic?) read defaults on: {prims}")
        return None

    def _compound_frame(self, graph: mx.NodeGraph, outer: _Frame) -> _Frame:
        key = (graph.getNamePath(), id(outer))
        frame = self._compound_frames.get(key)
        if frame is None:
            def bind(name, graph=graph, outer=outer):
                port = graph.getInput(name)
                return (port, outer) if port is not None else None
            frame = self._compound_frames[key] = _Frame(bind)
        return frame

    def port_value(self, port, frame: _Frame, type_name: str) -> ShaderNode | None:
        source = self.follow(port, frame)
        if source is None:
            return None
        if source[0] == "ready":
            return source[1]
        if source[0] == "node":
            _, upstream, output, upstream_frame = source
            return self.node_output(upstream, output, upstream_frame)
        value_port = source[1]
        geomprop = value_port.getDefaultGeomPropString() if isinstance(value_port, mx.Input) else ""
        if not value_port.getValueString() and geomprop:
            return self._geomprop(geomprop)
        values = _parse(value_port.getValueString(), value_port.getType() or type_name)
        return constant(*values) if values else None

    def port_string(self, port, frame: _Frame):
        """(value string, the port that authored it) following interface bindings; ("", None)."""
        source = self.follow(port, frame)
        if source is None or source[0] != "value":
            return "", None
        return source[1].getValueString(), source[1]

    def _geomprop(self, name: str) -> ShaderNode:
        if name == "UV0":
            return self.uv(DEFAULT_UV_SET)
        vector = {"Nworld": (0, 0, 1), "Nobject": (0, 0, 1), "Tworld": (1, 0, 0), "Tobject": (1, 0, 0),
                  "Bworld": (0, 1, 0), "Bobject": (0, 1, 0)}.get(name, (0, 0, 0))
        return constant(*vector)

    def uv(self, name: str) -> ShaderNode:
        """The mesh's texcoord when ``name`` is the material's (first) uv set, else a primvar."""
        if not self.uv_primvars or self.uv_primvars[0] == name:
            if not self.uv_primvars:
                self.uv_primvars.append(name)
            return ShaderNode("texcoord")
        return self.primvar(name, (0.0, 0.0, 0.0, 0.0))

    def primvar(self, name: str, fallback: tuple[float, ...]) -> ShaderNode:
        if name not in self.primvars:
            self.primvars.append(name)
        return ShaderNode("primvar", values=tuple(fallback), name=name)

    # ---- node inputs ------------------------------------------------------------------
    def input_port(self, element, name: str):
        """The node's authored input ``name``, or its nodedef's (which holds the default)."""
        port = element.getInput(name)
        if port is not None:
            return port
        nodedef = element.getNodeDef() if isinstance(element, mx.Node) else None
        return nodedef.getActiveInput(name) if nodedef is not None else None

    def input(self, element, name: str, frame: _Frame) -> ShaderNode:
        """Input ``name`` of a node: connected, authored or the nodedef's default; 0 if none."""
        port = element.getInput(name)
        value = self.port_value(port, frame, port.getType()) if port is not None else None
        if value is None:
            nodedef = element.getNodeDef()
            default = nodedef.getActiveInput(name) if nodedef is not None else None
            if default is not None:
                value = self.port_value(default, frame, default.getType())
        return value if value is not None else constant(0.0)

    def _input_type(self, element, name: str) -> str:
        port = self.input_port(element, name)
        return port.getType() if port is not None else "float"

    def arg(self, element, name: str, frame: _Frame, out_type: str) -> ShaderNode:
        """An input broadcast to ``out_type`` when it is a scalar feeding a wider output."""
        value = self.input(element, name, frame)
        if _COMPONENTS.get(self._input_type(element, name), 1) == 1 and _COMPONENTS.get(out_type, 1) > 1:
            return broadcast(value)
        return value

    def string(self, element, name: str, frame: _Frame) -> tuple[str, object]:
        port = self.input_port(element, name)
        return self.port_string(port, frame) if port is not None else ("", None)

    def integer(self, element, name: str, frame: _Frame, default: int = 0) -> int:
        value = self.input(element, name, frame)
        if not value.is_constant:
            self.note("mtlx-varying-integer", "MaterialX integer inputs that vary over the surface used "
                      f"{default} on: {{prims}}", f"{element.getName()}.{name}")
            return default
        return int(round(value.values[0]))

    # ---- nodes ------------------------------------------------------------------------
    def node_output(self, element: mx.Node, output_name: str, frame: _Frame) -> ShaderNode:
        key = (element.getNamePath(), output_name)
        cached = frame.cache.get(key)
        if cached is not None:
            return cached
        active_key = (id(frame), key[0], output_name)
        if active_key in self._active or self._depth >= MAX_DEPTH:
            self.note("mtlx-recursion", "MaterialX graphs nested too deeply or cyclic read 0 at the "
                      "repeat on: {prims}", element.getName())
            return constant(0.0)
        self._active.add(active_key)
        self._depth += 1
        try:
            result = self._evaluate(element, output_name, frame)
        finally:
            self._depth -= 1
            self._active.discard(active_key)
        frame.cache[key] = result
        return result

    def _evaluate(self, element: mx.Node, output_name: str, frame: _Frame) -> ShaderNode:
        category = element.getCategory()
        nodedef = element.getNodeDef()
        if nodedef is None:
            return self._unsupported(element, category, None, output_name, frame)
        outputs = nodedef.getActiveOutputs()
        output = nodedef.getActiveOutput(output_name) if output_name else None
        if output is None and outputs:
            output = outputs[0]
        out_type = output.getType() if output is not None else element.getType()
        handler = _HANDLERS.get(category)
        if handler is not None:
            return handler(self, element, out_type, output.getName() if output is not None else "", frame)
        implementation = nodedef.getImplementation()
        if isinstance(implementation, mx.NodeGraph):
            graph_output = implementation.getOutput(output.getName()) if output is not None else None
            if graph_output is None:
                return self._unsupported(element, category, output, output_name, frame)

            def bind(name, element=element, frame=frame):
                port = self.input_port(element, name)
                return (port, frame) if port is not None else None

            expanded = self.port_value(graph_output, _Frame(bind), out_type)
            return expanded if expanded is not None else constant(0.0)
        return self._unsupported(element, category, output, output_name, frame)

    def _unsupported(self, element, category, output, output_name, frame) -> ShaderNode:
        self.reader.context.diagnostics.note(
            f"unsupported-node-{category}",
            f"MaterialX nodes '{category}' are not supported; their inputs' defaults were used on: {{prims}}",
            f"{self.material_path} ({element.getName()})",
        )
        if output is not None:
            default = output.getAttribute("default")
            values = _parse(default, output.getType()) if default else None
            if values:
                return constant(*values)
            default_input = output.getAttribute("defaultinput")
            if default_input:
                return self.input(element, default_input, frame)
        return constant(0.0)


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
    def handler(ev: _Evaluator, element, out_type, output, frame):
        return _op(op, ev.arg(element, "in1", frame, out_type), ev.arg(element, "in2", frame, out_type),
                   _COMPONENTS.get(out_type, 4))
    return handler


def _unary(op: str):
    def handler(ev: _Evaluator, element, out_type, output, frame):
        return node(op, ev.input(element, "in", frame))
    return handler


def _constant_node(ev, element, out_type, output, frame):
    return ev.input(element, "value", frame)


def _dot(ev, element, out_type, output, frame):
    return ev.input(element, "in", frame)


def _mix(ev, element, out_type, output, frame):
    background, foreground = ev.input(element, "bg", frame), ev.input(element, "fg", frame)
    amount = ev.arg(element, "mix", frame, out_type)
    width = _COMPONENTS.get(out_type, 4)
    if _is(amount, 0.0, width):
        return background
    if _is(amount, 1.0, width):
        return foreground
    return node("mix", background, foreground, amount)


def _clamp(ev, element, out_type, output, frame):
    return node("clamp", ev.input(element, "in", frame), ev.arg(element, "low", frame, out_type),
                ev.arg(element, "high", frame, out_type))


def _dotproduct(ev, element, out_type, output, frame):
    width = _COMPONENTS.get(ev._input_type(element, "in1"), 3)
    return node("dotproduct", ev.input(element, "in1", frame), ev.input(element, "in2", frame), values=(width,))


def _swizzle(ev, element, out_type, output, frame):
    channels, _ = ev.string(element, "channels", frame)
    source = ev.input(element, "in", frame)
    if _COMPONENTS.get(ev._input_type(element, "in"), 1) == 1:
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
        width = _COMPONENTS.get(ev._input_type(element, name), 1)
        components.extend(value if width == 1 else swizzle(value, (k,)) for k in range(width))
    return node("combine", *components[:4])


def _convert(ev, element, out_type, output, frame):
    source = ev.input(element, "in", frame)
    width_in = _COMPONENTS.get(ev._input_type(element, "in"), 1)
    width_out = _COMPONENTS.get(out_type, 1)
    if width_in == 1:
        return swizzle(source, (0,) * width_out)
    if width_out <= width_in:
        return swizzle(source, tuple(range(width_out)))
    pad = (-2,) if width_out == 4 and out_type in ("color4", "vector4") else (-1,)
    return swizzle(source, tuple(range(width_in)) + pad * (width_out - width_in))


def _conditional(op: str):
    def handler(ev: _Evaluator, element, out_type, output, frame):
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


def normalmap_tangent(ev: _Evaluator, element, frame: _Frame) -> ShaderNode:
    """A normalmap node's tangent-space normal: (in·2 − 1) with x, y times ``scale``."""
    decoded = node("subtract", node("multiply", ev.input(element, "in", frame), constant(2.0, 2.0, 2.0, 0.0)),
                   constant(1.0, 1.0, 1.0, 0.0))
    scale = ev.input(element, "scale", frame)
    if _COMPONENTS.get(ev._input_type(element, "scale"), 1) == 1:
        factor = node("combine", scale, scale, constant(1.0))
    else:
        factor = node("combine", swizzle(scale, (0,)), swizzle(scale, (1,)), constant(1.0))
    return _op("multiply", decoded, factor, 3)


def _normalmap(ev, element, out_type, output, frame):
    return normalmap_tangent(ev, element, frame)


def _image(ev: _Evaluator, element, out_type, output, frame, uv: ShaderNode | None = None):
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
    path = ev.reader.texture_path(filename, port)
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
    return swizzle(lookup, tuple(range(_COMPONENTS.get(out_type, 3))))


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


_HANDLERS: dict[str, Callable] = {
    "constant": _constant_node, "dot": _dot, "mix": _mix, "clamp": _clamp, "dotproduct": _dotproduct,
    "swizzle": _swizzle, "extract": _extract, "separate2": _separate, "separate3": _separate,
    "separate4": _separate, "combine2": _combine, "combine3": _combine, "combine4": _combine,
    "convert": _convert, "ifgreater": _conditional("ifgreater"), "ifgreatereq": _conditional("ifgreatereq"),
    "ifequal": _conditional("ifequal"), "rotate2d": _rotate2d, "texcoord": _texcoord,
    "geompropvalue": _geompropvalue, "geomcolor": _geomcolor, "normalmap": _normalmap, "image": _image,
    "tiledimage": _tiledimage, "normalize": _unary("normalize"),
}
for _name in ("add", "subtract", "multiply", "divide", "min", "max", "power", "modulo"):
    _HANDLERS[_name] = _binary(_name)
for _name in ("absval", "floor", "ceil", "sqrt", "sin", "cos"):
    _HANDLERS[_name] = _unary(_name)


class MaterialXReader:
    """MaterialX looks of one stage read: documents read once, library shared."""

    def __init__(self, context: ReadContext, textures: TextureLibrary) -> None:
        self.context = context
        self.textures = textures
        self.library = standard_library()
        self._documents: dict[str, mx.Document | None] = {}

    # ---- the interface ---------------------------------------------------------------
    def from_usd(self, material: UsdShade.Material) -> MaterialXLook | None:
        """A UsdShade.Material whose surface (outputs:mtlx:surface first, then outputs:surface) is a
        Shader with a MaterialX info:id; None when it has none (the caller falls back)."""
        for name in ("mtlx:surface", "surface"):
            output = material.GetOutput(name)
            if not output:
                continue
            attributes = output.GetValueProducingAttributes()
            if not attributes or not UsdShade.Output.IsOutput(attributes[0]):
                continue
            shader = UsdShade.Shader(attributes[0].GetPrim())
            shader_id = shader.GetShaderId() if shader else None
            nodedef = self.library.getNodeDef(shader_id) if shader_id else None
            if nodedef is None:
                continue
            if nodedef.getNodeString() not in _SURFACES:
                self.context.diagnostics.note(
                    f"unsupported-node-{nodedef.getNodeString()}",
                    f"MaterialX nodes '{nodedef.getNodeString()}' are not supported; their inputs' defaults "
                    "were used on: {prims}", f"{material.GetPath()} ({shader.GetPath().name})")
                return None
            document = mx.createDocument()
            document.setDataLibrary(self.library)
            surface = _UsdNetwork(self, document).node(shader)
            return self._look(surface, str(material.GetPath()))
        return None

    def referenced(self, target: Sdf.Path) -> tuple[str, str] | None:
        """For a binding target that does not exist on the stage: (absolute .mtlx path, material name)
        when it lies under a prim that references (or payloads) a .mtlx document; else None."""
        stage = self.context.stage
        target = Sdf.Path(target)
        prim = None
        ancestor = target.GetParentPath()
        while ancestor != Sdf.Path.absoluteRootPath and not ancestor.isEmpty:
            candidate = stage.GetPrimAtPath(ancestor)
            if candidate and candidate.IsValid():
                prim = candidate
                break
            ancestor = ancestor.GetParentPath()
        candidates: list[tuple[str, str]] = []
        while prim is not None and prim.IsValid() and not prim.IsPseudoRoot():
            relative = target.MakeRelativePath(prim.GetPath())
            for spec in prim.GetPrimStack():
                for items in (spec.referenceList.GetAddedOrExplicitItems(),
                              spec.payloadList.GetAddedOrExplicitItems()):
                    for item in items:
                        if not item.assetPath.lower().endswith(".mtlx"):
                            continue
                        root = item.primPath if not item.primPath.isEmpty else Sdf.Path("/MaterialX")
                        mapped = root.AppendPath(relative)
                        if mapped.GetParentPath() == Sdf.Path("/MaterialX/Materials"):
                            candidates.append((spec.layer.ComputeAbsolutePath(item.assetPath), mapped.name))
            if candidates:
                break
            prim = prim.GetParent()
        for path, name in candidates:
            document = self._document(path, str(target))
            if document is not None and _surface_material(document, name) is not None:
                return path, name
        return candidates[0] if candidates else None

    def from_document(self, mtlx_path: str, material_name: str, user_path: str) -> MaterialXLook | None:
        """The surfacematerial `material_name` of the document (documents read once per reader);
        None (after a diagnostics warning naming the file) when unreadable or absent."""
        document = self._document(mtlx_path, user_path)
        if document is None:
            return None
        material = _surface_material(document, material_name)
        if material is None:
            self.context.diagnostics.warn(
                f"MaterialX document {mtlx_path} has no material '{material_name}' (bound on {user_path}); "
                "using the default material", once_key=f"mtlx-material:{mtlx_path}:{material_name}")
            return None
        label = f"{user_path} ({mtlx_path}:{material_name})"
        evaluator = _Evaluator(self, label)
        port = material.getInput("surfaceshader")
        source = evaluator.follow(port, _Frame(None)) if port is not None else None
        if source is None or source[0] != "node":
            self.context.diagnostics.warn(
                f"MaterialX material '{material_name}' of {mtlx_path} has no surface shader (bound on "
                f"{user_path}); using the default material", once_key=f"mtlx-surface:{mtlx_path}:{material_name}")
            return None
        return self._look(source[1], label, evaluator, source[3])

    # ---- helpers ------------------------------------------------------------------------
    def _document(self, path: str, user_path: str) -> mx.Document | None:
        if path in self._documents:
            return self._documents[path]
        document = mx.createDocument()
        try:
            mx.readFromXmlFile(document, path)
        except Exception as error:  # MaterialX raises its own exception types (file, parse)
            self.context.diagnostics.warn(
                f"cannot read MaterialX document {path} (used by {user_path}): {error}; "
                "its materials use the default material", once_key=f"mtlx-document:{path}")
            document = None
        else:
            document.setDataLibrary(self.library)
        self._documents[path] = document
        return document

    def texture_path(self, filename: str, port) -> str:
        """An image filename resolved like MaterialX: fileprefix, then the document's folder."""
        if os.path.isabs(filename) or port is None or not isinstance(port, mx.Input):
            return filename
        resolved = port.getResolvedValueString()
        source = port.getActiveSourceUri()
        folder = os.path.dirname(source) if source else ""
        prefixed = os.path.normpath(os.path.join(folder, resolved))
        if not os.path.exists(prefixed):
            plain = os.path.normpath(os.path.join(folder, filename))
            if os.path.exists(plain):  # a prefix repeated in the value (seen in the wild)
                return plain
        return prefixed

    def _look(self, surface: mx.Node, label: str, evaluator: _Evaluator | None = None,
              frame: _Frame | None = None) -> MaterialXLook | None:
        evaluator = evaluator or _Evaluator(self, label)
        frame = frame or _Frame(None)
        category = surface.getCategory()
        if category == "standard_surface":
            fields = self._standard_surface(evaluator, lambda name: evaluator.input(surface, name, frame))
            fields["normal"] = self._normal(evaluator, surface, "normal", frame)
        elif category == "open_pbr_surface":
            translation = self.library.getNodeDef("ND_open_pbr_surface_to_standard_surface").getImplementation()

            def bind(name):
                port = evaluator.input_port(surface, name)
                return (port, frame) if port is not None else None

            translated = _Frame(bind)

            def get(name):
                output = translation.getOutput(f"{name}_out")
                value = evaluator.port_value(output, translated, output.getType()) if output is not None else None
                if value is None:  # standard_surface's own default
                    default = self.library.getNodeDef("ND_standard_surface_surfaceshader").getActiveInput(name)
                    value = evaluator.port_value(default, frame, default.getType()) if default is not None else None
                return value if value is not None else constant(0.0)

            fields = self._standard_surface(evaluator, get)
            fields["normal"] = self._normal(evaluator, surface, "geometry_normal", frame)
        elif category == "gltf_pbr":
            fields = self._gltf(evaluator, surface, frame)
        elif category == "UsdPreviewSurface":
            fields = self._preview(evaluator, surface, frame)
        else:
            self.context.diagnostics.note(
                f"unsupported-node-{category}",
                f"MaterialX nodes '{category}' are not supported; their inputs' defaults were used on: {{prims}}",
                f"{label} ({surface.getName()})")
            return None
        return MaterialXLook(fields, tuple(evaluator.uv_primvars), tuple(evaluator.primvars))

    def _standard_surface(self, ev: _Evaluator, get: Callable[[str], ShaderNode]) -> dict[str, object]:
        translation = self.library.getNodeDef("ND_standard_surface_to_UsdPreviewSurface").getImplementation()
        frame = _Frame(lambda name: get(name))

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
            "ior": self._uniform(ev, out("ior_out"), "ior", 1.5),
            "transmission": field_value(get("transmission"), 1),
            "transmission_color": field_value(get("transmission_color"), 3),
            "thin_walled": bool(self._uniform(ev, get("thin_walled"), "thin_walled", 0.0)),
        }

    def _gltf(self, ev: _Evaluator, surface, frame) -> dict[str, object]:
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
            "ior": self._uniform(ev, get("ior"), "ior", 1.5),
            "normal": self._normal(ev, surface, "normal", frame),
        }
        if not (transmission.is_constant and transmission.values[0] == 0.0):
            fields["transmission_color"] = field_value(base, 3)
            fields["thin_walled"] = self._uniform(ev, get("thickness"), "thickness", 0.0) == 0.0
        mode = ev.integer(surface, "alpha_mode", frame)
        if mode == 0:
            fields["opacity"] = 1.0
        else:
            fields["opacity"] = field_value(get("alpha"), 1)
            fields["opacity_threshold"] = (self._uniform(ev, get("alpha_cutoff"), "alpha_cutoff", 0.5)
                                           if mode == 1 else 0.0)
        return fields

    def _preview(self, ev: _Evaluator, surface, frame) -> dict[str, object]:
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
                uniform = self._uniform(ev, value, spec.usd_name, float(default))
                fields[spec.field] = bool(uniform) if spec.kind == "bool" else uniform
        return fields

    def _uniform(self, ev: _Evaluator, value: ShaderNode, name: str, default: float) -> float:
        """A field the tracer takes as one number: the constant, or ``default`` with a note."""
        if value.is_constant:
            return value.values[0]
        ev.note(f"mtlx-varying-{name}", f"MaterialX '{name}' inputs that vary over the surface are not "
                f"supported; {default} was used on: {{prims}}")
        return default

    def _normal(self, ev: _Evaluator, surface, name: str, frame) -> ShaderNode | None:
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


def _surface_material(document: mx.Document, name: str) -> mx.Node | None:
    element = document.getNode(name)
    return element if element is not None and element.getCategory() == "surfacematerial" else None


class _UsdNetwork:
    """A UsdShade network of MaterialX shaders copied into a MaterialX document."""

    def __init__(self, reader: MaterialXReader, document: mx.Document) -> None:
        self.reader = reader
        self.document = document
        self.time = reader.context.time
        self._nodes: dict[Sdf.Path, mx.Node | None] = {}

    def node(self, shader: UsdShade.Shader) -> mx.Node | None:
        path = shader.GetPath()
        if path in self._nodes:
            return self._nodes[path]
        self._nodes[path] = None  # a cycle stops here
        shader_id = shader.GetShaderId()
        nodedef = self.reader.library.getNodeDef(shader_id) if shader_id else None
        if nodedef is None:
            self.reader.context.diagnostics.note(
                f"unsupported-node-{shader_id}",
                f"MaterialX nodes '{shader_id}' are not supported; their inputs' defaults were used on: {{prims}}",
                str(path))
            return None
        name = self.document.createValidChildName(mx.createValidName(str(path).strip("/").replace("/", "_")))
        element = self.document.addNodeInstance(nodedef, name)
        self._nodes[path] = element
        for usd_input in shader.GetInputs():
            input_name = usd_input.GetBaseName()
            definition = nodedef.getActiveInput(input_name)
            if definition is None:
                continue
            type_name = definition.getType()
            for attribute in usd_input.GetValueProducingAttributes():
                if UsdShade.Output.IsOutput(attribute):
                    upstream = self.node(UsdShade.Shader(attribute.GetPrim()))
                    if upstream is None:
                        break
                    port = element.addInput(input_name, type_name)
                    port.setNodeName(upstream.getName())
                    upstream_def = upstream.getNodeDef()
                    if upstream_def is not None and len(upstream_def.getActiveOutputs()) > 1:
                        port.setOutputString(attribute.GetBaseName())
                else:
                    text = self._value_string(attribute, type_name)
                    if text is None:
                        break
                    port = element.addInput(input_name, type_name)
                    port.setValueString(text)
                    if attribute.HasColorSpace():
                        port.setColorSpace(attribute.GetColorSpace())
                break
        return element

    def _value_string(self, attribute: Usd.Attribute, type_name: str) -> str | None:
        value = attribute.Get(self.time)
        if value is None:
            return None
        if isinstance(value, Sdf.AssetPath):
            return value.resolvedPath or (anchored_asset_path(attribute, value, self.time) if value.path else "")
        if type_name == "boolean":
            return "true" if value else "false"
        if isinstance(value, (bool, int)) and type_name == "integer":
            return str(int(value))
        if isinstance(value, (int, float)):
            return repr(float(value))
        if isinstance(value, str):
            return value
        try:
            return ", ".join(repr(float(component)) for component in value)
        except TypeError:
            return str(value)
