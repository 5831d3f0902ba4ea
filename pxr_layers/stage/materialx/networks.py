"""Reading MaterialX networks: documents, UsdShade networks copied into documents, and the
walk that resolves a node's inputs through connections, interface bindings and nodedef graphs.

usd-core has no usdMtlx plugin, so a reference to a .mtlx document does not compose and the
binding target under it does not exist. :meth:`Documents.referenced` finds the prim whose
reference (or payload) named the document and maps the target onto usdMtlx's naming
(``<surfacematerial name="X">`` at ``/MaterialX/Materials/X``); :meth:`Documents.surface`
reads that material with the MaterialX library itself (``import MaterialX``). A flattened
network (:class:`UsdNetwork`) is copied into an in-memory MaterialX document, node for node,
so both forms go through one evaluator.

Evaluation. :class:`Evaluator` turns every node output into a :class:`ShaderNode` tree
(shader_nodes.py). A category with a hand-written translation (``handlers``: nodes.py's) is
translated by it; any other node whose nodedef is implemented by a NodeGraph (UsdUVTexture,
UsdPrimvarReader, UsdTransform2d, place2d, most of stdlib) is expanded with its inputs bound
to the graph's interface, as MaterialX's code generators do. Anything else is noted once per
category and gives its output's default.

Values: a number that is not finite is a StageError naming where it is authored (the USD
attribute of a UsdShade network, or the node input and the file of a document), as
values.checked does for every other input; what the surface computes from them is checked
by materials.check_fields.
"""

from __future__ import annotations

import math
import os
import threading
from typing import Callable

import MaterialX as mx
from pxr import Sdf, Usd, UsdShade

from pxr_layers.errors import StageError
from pxr_layers.inputs import input_problem
from pxr_layers.shader_nodes import ShaderNode, broadcast, constant

from ..context import ReadContext
from ..defaults import DEFAULT_UV_SET
from ..textures import anchored_asset_path
from ..values import checked_all

MAX_DEPTH = 128
"""Nested node evaluations before a graph counts as runaway (cyclic). Each level costs a
handful of Python frames, so this stays well inside Python's recursion limit."""

COMPONENTS = {"float": 1, "integer": 1, "boolean": 1, "vector2": 2, "color3": 3, "vector3": 3,
              "color4": 4, "vector4": 4}
"""Components of each MaterialX value type."""

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


class Frame:
    """One level of graph expansion: how ``interfacename`` inputs of its nodes bind.

    bind(name) → (port, frame) to evaluate instead, a ready ShaderNode, or None (unbound).
    """

    def __init__(self, bind: Callable[[str], object] | None) -> None:
        self.bind = bind
        self.cache: dict[tuple[str, str], ShaderNode] = {}


def parse_value(text: str, type_name: str) -> tuple[float, ...] | None:
    """A MaterialX value string as floats (booleans 1/0); None when it is not numeric."""
    text = text.strip()
    if type_name == "boolean":
        return (1.0 if text.lower() == "true" else 0.0,)
    try:
        return tuple(float(part) for part in text.replace(",", " ").split())
    except ValueError:
        return None


class Evaluator:
    """Evaluates one material's node outputs into ShaderNode trees (``handlers`` translate
    the categories written by hand)."""

    def __init__(self, reader, material_path: str, handlers: dict[str, Callable]) -> None:
        self.reader = reader  # the MaterialXReader: its context, library and textures
        self.material_path = material_path
        self.handlers = handlers  # category -> handler(evaluator, element, out_type, output, frame)
        self.uv_primvars: list[str] = []
        self.primvars: list[str] = []
        self._active: set[tuple[int, str, str]] = set()
        self._depth = 0
        self._compound_frames: dict[tuple[str, int], Frame] = {}

    # ---- diagnostics ------------------------------------------------------------------
    def note(self, kind: str, template: str, where: str = "") -> None:
        label = f"{self.material_path} ({where})" if where else self.material_path
        self.reader.context.diagnostics.note(kind, template, label)

    # ---- ports ------------------------------------------------------------------------
    def follow(self, port, frame: Frame):
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

    def _compound_frame(self, graph: mx.NodeGraph, outer: Frame) -> Frame:
        key = (graph.getNamePath(), id(outer))
        frame = self._compound_frames.get(key)
        if frame is None:
            def bind(name, graph=graph, outer=outer):
                port = graph.getInput(name)
                return (port, outer) if port is not None else None
            frame = self._compound_frames[key] = Frame(bind)
        return frame

    def port_value(self, port, frame: Frame, type_name: str) -> ShaderNode | None:
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
        values = parse_value(value_port.getValueString(), value_port.getType() or type_name)
        if values and not all(math.isfinite(value) for value in values):  # values.checked's rule, for a document
            node = value_port.getParent()
            where = f"{node.getName()}.{value_port.getName()}" if node is not None else value_port.getName()
            raise StageError(f"MaterialX input {where} is {value_port.getValueString()!r}: it must be finite "
                             f"(used by {self.material_path})", file=value_port.getActiveSourceUri() or None)
        return constant(*values) if values else None

    def port_string(self, port, frame: Frame):
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

    def input(self, element, name: str, frame: Frame) -> ShaderNode:
        """Input ``name`` of a node: connected, authored or the nodedef's default; 0 if none."""
        port = element.getInput(name)
        value = self.port_value(port, frame, port.getType()) if port is not None else None
        if value is None:
            nodedef = element.getNodeDef()
            default = nodedef.getActiveInput(name) if nodedef is not None else None
            if default is not None:
                value = self.port_value(default, frame, default.getType())
        return value if value is not None else constant(0.0)

    def input_type(self, element, name: str) -> str:
        port = self.input_port(element, name)
        return port.getType() if port is not None else "float"

    def arg(self, element, name: str, frame: Frame, out_type: str) -> ShaderNode:
        """An input broadcast to ``out_type`` when it is a scalar feeding a wider output."""
        value = self.input(element, name, frame)
        if COMPONENTS.get(self.input_type(element, name), 1) == 1 and COMPONENTS.get(out_type, 1) > 1:
            return broadcast(value)
        return value

    def string(self, element, name: str, frame: Frame) -> tuple[str, object]:
        port = self.input_port(element, name)
        return self.port_string(port, frame) if port is not None else ("", None)

    def integer(self, element, name: str, frame: Frame, default: int = 0) -> int:
        value = self.input(element, name, frame)
        if not value.is_constant:
            self.note("mtlx-varying-integer", "MaterialX integer inputs that vary over the surface used "
                      f"{default} on: {{prims}}", f"{element.getName()}.{name}")
            return default
        return int(round(value.values[0]))

    # ---- nodes ------------------------------------------------------------------------
    def node_output(self, element: mx.Node, output_name: str, frame: Frame) -> ShaderNode:
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

    def _evaluate(self, element: mx.Node, output_name: str, frame: Frame) -> ShaderNode:
        category = element.getCategory()
        nodedef = element.getNodeDef()
        if nodedef is None:
            return self._unsupported(element, category, None, output_name, frame)
        outputs = nodedef.getActiveOutputs()
        output = nodedef.getActiveOutput(output_name) if output_name else None
        if output is None and outputs:
            output = outputs[0]
        out_type = output.getType() if output is not None else element.getType()
        handler = self.handlers.get(category)
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

            expanded = self.port_value(graph_output, Frame(bind), out_type)
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
            values = parse_value(default, output.getType()) if default else None
            if values:
                return constant(*values)
            default_input = output.getAttribute("defaultinput")
            if default_input:
                return self.input(element, default_input, frame)
        return constant(0.0)


def texture_path(filename: str, port) -> str:
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


class Documents:
    """The .mtlx documents of one stage read: each read once, on the shared standard library."""

    def __init__(self, context: ReadContext, library: mx.Document) -> None:
        self.context = context
        self.library = library
        self._documents: dict[str, mx.Document | None] = {}

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
            document = self.document(path, str(target))
            if document is not None and surface_material(document, name) is not None:
                return path, name
        return candidates[0] if candidates else None

    def surface(self, mtlx_path: str, material_name: str, user_path: str, evaluator: Evaluator):
        """(surface shader node, its frame) of the surfacematerial `material_name` of the document;
        None (after a diagnostics warning naming the file) when unreadable or absent."""
        document = self.document(mtlx_path, user_path)
        if document is None:
            return None
        material = surface_material(document, material_name)
        if material is None:
            self.context.diagnostics.warn(
                f"MaterialX document {mtlx_path} has no material '{material_name}' (bound on {user_path}); "
                "using the default material", once_key=f"mtlx-material:{mtlx_path}:{material_name}")
            return None
        port = material.getInput("surfaceshader")
        source = evaluator.follow(port, Frame(None)) if port is not None else None
        if source is None or source[0] != "node":
            self.context.diagnostics.warn(
                f"MaterialX material '{material_name}' of {mtlx_path} has no surface shader (bound on "
                f"{user_path}); using the default material", once_key=f"mtlx-surface:{mtlx_path}:{material_name}")
            return None
        return source[1], source[3]

    def document(self, path: str, user_path: str) -> mx.Document | None:
        if path in self._documents:
            return self._documents[path]
        document = mx.createDocument()
        try:
            problem = input_problem(path, "MaterialX document")  # a FIFO would block the read
            if problem is not None:
                raise OSError(problem)
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


def surface_material(document: mx.Document, name: str) -> mx.Node | None:
    element = document.getNode(name)
    return element if element is not None and element.getCategory() == "surfacematerial" else None


def surface_shader(library: mx.Document, material: UsdShade.Material):
    """(Shader, its nodedef) of a UsdShade.Material whose surface (outputs:mtlx:surface first,
    then outputs:surface) is a Shader with a MaterialX info:id; None when it has none."""
    for name in ("mtlx:surface", "surface"):
        output = material.GetOutput(name)
        if not output:
            continue
        attributes = output.GetValueProducingAttributes()
        if not attributes or not UsdShade.Output.IsOutput(attributes[0]):
            continue
        shader = UsdShade.Shader(attributes[0].GetPrim())
        shader_id = shader.GetShaderId() if shader else None
        nodedef = library.getNodeDef(shader_id) if shader_id else None
        if nodedef is not None:
            return shader, nodedef
    return None


class UsdNetwork:
    """A UsdShade network of MaterialX shaders copied into a MaterialX document."""

    def __init__(self, context: ReadContext, library: mx.Document, document: mx.Document) -> None:
        self.context = context
        self.library = library
        self.document = document
        self.time = context.time
        self._nodes: dict[Sdf.Path, mx.Node | None] = {}

    def node(self, shader: UsdShade.Shader) -> mx.Node | None:
        path = shader.GetPath()
        if path in self._nodes:
            return self._nodes[path]
        self._nodes[path] = None  # a cycle stops here
        shader_id = shader.GetShaderId()
        nodedef = self.library.getNodeDef(shader_id) if shader_id else None
        if nodedef is None:
            self.context.diagnostics.note(
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
        if isinstance(value, str):
            return value
        try:
            numbers = (float(value),) if isinstance(value, (int, float)) else tuple(float(part) for part in value)
        except TypeError:
            return str(value)
        # Checked here, where the USD attribute can be named (values.checked), not in the copy
        numbers = checked_all(numbers, attribute.GetName(), file=self.context.file, prim=str(attribute.GetPrim().GetPath()))
        return ", ".join(repr(number) for number in numbers)
