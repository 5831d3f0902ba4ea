"""Material inputs as expression trees of shading nodes: plain data from stage/ to trace/.

A material input that is not a constant is a :class:`ShaderNode` tree, evaluated at every
shading point. ``stage/`` builds the trees from UsdPreviewSurface networks (UsdUVTexture,
UsdTransform2d, UsdPrimvarReader_*) and from MaterialX node graphs; ``trace/shading.py``
compiles each material's trees into one short program and interprets it per lane.

Every value is a 4-vector of float32: a float uses component 0, a vector2 0–1, a colour or
vector3 0–2. Trees are built already broadcast (a float multiplying a colour is swizzled to
(x, x, x) first), so every operation below is componentwise on four components unless it
says otherwise. The operations (``OPS``, the one alphabet):

=============  ===========================================================================
constant       ``values`` (4)
texcoord       the mesh's texture coordinates (s, t, 0, 1): the uv primvar its material reads
primvar        primvar ``name`` per shading point (interpolated), components past its width
               and meshes without it from ``values`` (4), the fallback
texture        bilinear lookup of the image ``tiles`` at ``inputs[0]`` (s, t); ``tiles`` is
               ((0, texture),) for a plain image or ((tile, texture), ...) for UDIM tiles
               (tile = 1001 + ⌊s⌋ + 10·⌊t⌋, looked up at the fractional s, t). ``wrap`` is
               (s, t). Texels read as RGBA (grey is rgb, a missing alpha 1); a missing UDIM
               tile gives ``values`` (4), the fallback
add, subtract, multiply, min, max          a ∘ b
divide         a / b, 0 where b = 0
power          aᵇ for a > 0; for a ≤ 0, 1 where b = 0 and 0 elsewhere (MaterialX leaves it undefined)
modulo         a − b·⌊a/b⌋ (MaterialX's), 0 where b = 0
absval, floor, ceil, sqrt (of max(a, 0)), sin, cos                     f(a) (floor, ceil: ±inf, NaN kept)
mix            inputs (bg, fg, m): bg + (fg − bg)·m
clamp          inputs (in, low, high)
dotproduct     Σ a·b over the first ``values[0]`` components, in every component
normalize      a / |a| over the first three components, the 4th kept (vector2/3, the normals
               and directions shading uses)
swizzle        component k = a[values[k]], or 0 where values[k] = −1, 1 where it is −2
combine        (inputs[0][0], inputs[1][0], inputs[2][0], inputs[3][0]) (node() pads with 0)
affine2d       (m0·a0 + m1·a1 + m2, m3·a0 + m4·a1 + m5, a2, a3) with m = ``values`` (6)
ifgreater, ifgreatereq, ifequal            inputs (v1, v2, in1, in2): in1 if v1[0] ∘ v2[0] else in2
=============  ===========================================================================

:func:`node` folds an operation on constants into a constant, with :func:`apply` — the
same function the trace kernels run — so a graph of constants costs nothing per lane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from .compiled import inline

WrapMode = Literal["repeat", "mirror", "clamp", "black"]

# The alphabet, in the order of the codes kernels see; arity = how many inputs.
_ARITY = {
    "constant": 0, "texcoord": 0, "primvar": 0, "texture": 1,
    "add": 2, "subtract": 2, "multiply": 2, "divide": 2, "min": 2, "max": 2, "power": 2, "modulo": 2,
    "absval": 1, "floor": 1, "ceil": 1, "sqrt": 1, "sin": 1, "cos": 1,
    "mix": 3, "clamp": 3, "dotproduct": 2, "normalize": 1, "swizzle": 1, "combine": 4, "affine2d": 1,
    "ifgreater": 4, "ifgreatereq": 4, "ifequal": 4,
}
OPS = tuple(_ARITY)
OP_CODE = {name: code for code, name in enumerate(OPS)}
(CONSTANT, TEXCOORD, PRIMVAR, TEXTURE, ADD, SUBTRACT, MULTIPLY, DIVIDE, MIN, MAX, POWER, MODULO, ABSVAL, FLOOR,
 CEIL, SQRT, SIN, COS, MIX, CLAMP, DOTPRODUCT, NORMALIZE, SWIZZLE, COMBINE, AFFINE2D, IFGREATER, IFGREATEREQ,
 IFEQUAL) = range(len(OPS))
_SOURCES = {"texcoord", "primvar", "texture"}  # ops that read the shading point: never folded
MAX_INPUTS = 4
PARAMETERS = 6  # the most ``values`` an operation takes (affine2d)


@dataclass(frozen=True)
class ShaderNode:
    """One operation of a material input's expression tree (see the module docstring)."""

    op: str
    inputs: tuple[ShaderNode, ...] = ()
    values: tuple[float, ...] = ()
    name: str = ""  # primvar: the primvar's name
    tiles: tuple[tuple[int, int], ...] = ()  # texture: (tile, index into SceneData.textures)
    wrap: tuple[WrapMode, WrapMode] = ("repeat", "repeat")  # texture: (s, t)

    def __post_init__(self) -> None:
        if self.op not in _ARITY:
            raise ValueError(f"unknown shader node operation {self.op!r}")
        if len(self.inputs) != _ARITY[self.op]:
            raise ValueError(f"{self.op} takes {_ARITY[self.op]} inputs, not {len(self.inputs)}")

    @property
    def is_constant(self) -> bool:
        return self.op == "constant"

    def walk(self):
        """This node and every node below it, each once, inputs before the nodes using them."""
        seen: set[int] = set()
        order: list[ShaderNode] = []
        stack: list[tuple[ShaderNode, bool]] = [(self, False)]
        while stack:
            current, expanded = stack.pop()
            if id(current) in seen:
                continue
            if expanded:
                seen.add(id(current))
                order.append(current)
                continue
            stack.append((current, True))
            stack.extend((child, False) for child in reversed(current.inputs))
        return order


def constant(*values: float) -> ShaderNode:
    """A constant 4-vector; fewer values are padded with 0."""
    padded = tuple(float(value) for value in values[:4])
    return ShaderNode("constant", values=padded + (0.0,) * (4 - len(padded)))


def node(op: str, *inputs: ShaderNode, values: tuple[float, ...] = ()) -> ShaderNode:
    """The operation `op` on `inputs`, folded into a constant when every input is one; a
    combine of fewer than four inputs gets constant 0 for the rest."""
    if op == "combine":
        inputs = inputs + (constant(),) * (MAX_INPUTS - len(inputs))
    built = ShaderNode(op, tuple(inputs), tuple(float(value) for value in values))
    if op in _SOURCES or not all(child.is_constant for child in inputs):
        return built
    registers = np.zeros((MAX_INPUTS + 1, 4), np.float32)
    for row, child in enumerate(inputs):
        registers[row] = child.values
    parameters = np.zeros(PARAMETERS, np.float32)
    parameters[:len(built.values)] = built.values
    apply.py_func(OP_CODE[op], registers, MAX_INPUTS, 0, 1, 2, 3, parameters, 0)
    return ShaderNode("constant", values=tuple(float(value) for value in registers[MAX_INPUTS]))


def field_value(tree: ShaderNode, width: int):
    """What a scene.Material field of `width` (1 scalar, 3 colour) holds for `tree`: its
    constant value (a float, or a 3-tuple) when it folded to one, else the tree (whose
    first `width` components are read)."""
    if not tree.is_constant:
        return tree
    return tuple(tree.values[:3]) if width == 3 else tree.values[0]


def swizzle(source: ShaderNode, channels: tuple[int, ...]) -> ShaderNode:
    """Components `channels` of `source` (−1: 0, −2: 1), padded with 0."""
    padded = tuple(channels[:4]) + (-1,) * (4 - len(channels[:4]))
    if padded == (0, 1, 2, 3):
        return source
    return node("swizzle", source, values=padded)


def broadcast(source: ShaderNode) -> ShaderNode:
    """A float (component 0) in every component."""
    return swizzle(source, (0, 0, 0, 0))


@inline  # into trace/shading.material_inputs, which is compiled once and called
def apply(op, registers, out, a, b, c, d, parameters, offset):
    """registers[out] ← operation `op` (a code of OPS, not a source) of registers a, b, c, d,
    with its ``values`` at parameters[offset:]."""
    ra, rb, rc, rd, ro = registers[a], registers[b], registers[c], registers[d], registers[out]
    if op == TEXCOORD or op == PRIMVAR or op == TEXTURE:
        return
    if op == CONSTANT:
        for k in range(4):
            ro[k] = parameters[offset + k]
    elif op == ADD:
        for k in range(4):
            ro[k] = ra[k] + rb[k]
    elif op == SUBTRACT:
        for k in range(4):
            ro[k] = ra[k] - rb[k]
    elif op == MULTIPLY:
        for k in range(4):
            ro[k] = ra[k] * rb[k]
    elif op == DIVIDE:
        for k in range(4):
            ro[k] = ra[k] / rb[k] if rb[k] != 0 else 0.0
    elif op == MIN:
        for k in range(4):
            ro[k] = min(ra[k], rb[k])
    elif op == MAX:
        for k in range(4):
            ro[k] = max(ra[k], rb[k])
    elif op == POWER:
        for k in range(4):
            ro[k] = ra[k] ** rb[k] if ra[k] > 0 else (1.0 if rb[k] == 0 else 0.0)
    elif op == MODULO:
        for k in range(4):
            quotient = ra[k] / rb[k] if rb[k] != 0 else 0.0
            ro[k] = ra[k] - rb[k] * math.floor(quotient) if math.isfinite(quotient) and rb[k] != 0 else 0.0
    elif op == ABSVAL:
        for k in range(4):
            ro[k] = abs(ra[k])
    elif op == FLOOR:
        for k in range(4):
            ro[k] = math.floor(ra[k]) if math.isfinite(ra[k]) else ra[k]
    elif op == CEIL:
        for k in range(4):
            ro[k] = math.ceil(ra[k]) if math.isfinite(ra[k]) else ra[k]
    elif op == SQRT:
        for k in range(4):
            ro[k] = math.sqrt(max(ra[k], 0.0))
    elif op == SIN:
        for k in range(4):
            ro[k] = math.sin(ra[k])
    elif op == COS:
        for k in range(4):
            ro[k] = math.cos(ra[k])
    elif op == MIX:
        for k in range(4):
            ro[k] = ra[k] + (rb[k] - ra[k]) * rc[k]
    elif op == CLAMP:
        for k in range(4):
            ro[k] = min(max(ra[k], rb[k]), rc[k])
    elif op == DOTPRODUCT:
        total = 0.0
        for k in range(int(parameters[offset])):
            total += ra[k] * rb[k]
        for k in range(4):
            ro[k] = total
    elif op == NORMALIZE:
        length = math.sqrt(ra[0] * ra[0] + ra[1] * ra[1] + ra[2] * ra[2])
        scale = 1.0 / length if length > 0 else 0.0
        w = ra[3]
        for k in range(3):
            ro[k] = ra[k] * scale
        ro[3] = w
    elif op == SWIZZLE:
        x, y, z, w = ra[0], ra[1], ra[2], ra[3]
        for k in range(4):
            channel = int(parameters[offset + k])
            if channel == -1:
                ro[k] = 0.0
            elif channel == -2:
                ro[k] = 1.0
            else:
                ro[k] = x if channel == 0 else (y if channel == 1 else (z if channel == 2 else w))
    elif op == COMBINE:
        x, y, z, w = ra[0], rb[0], rc[0], rd[0]
        ro[0], ro[1], ro[2], ro[3] = x, y, z, w
    elif op == AFFINE2D:
        x, y = ra[0], ra[1]
        ro[0] = parameters[offset] * x + parameters[offset + 1] * y + parameters[offset + 2]
        ro[1] = parameters[offset + 3] * x + parameters[offset + 4] * y + parameters[offset + 5]
        ro[2], ro[3] = ra[2], ra[3]
    else:
        if op == IFGREATER:
            chosen = ra[0] > rb[0]
        elif op == IFGREATEREQ:
            chosen = ra[0] >= rb[0]
        else:
            chosen = ra[0] == rb[0]
        source = rc if chosen else rd
        x, y, z, w = source[0], source[1], source[2], source[3]
        ro[0], ro[1], ro[2], ro[3] = x, y, z, w
