"""Material inputs as tables for kernels, and their per-lane evaluation.

``MaterialTable`` turns SceneData.materials into arrays, one row per material plus a last
row that index −1 (the light shapes) reads and never shades:

* ``constants`` (m + 1, MATERIAL_FIELDS) float32: every input's constant value (columns
  below; HAS_NORMAL is 1 where a normal map drives NORMAL).
* Each material's ShaderNode trees (shader_nodes.py) compiled into one **program**, shared
  subtrees computed once: ``program`` (k, 8) int32 instructions (op, out, a, b, c, d,
  parameter offset, extra) over a register file of 4-vectors, ``parameters`` (p,) float32,
  ``program_range`` (m + 1, 2) int64 [start, end) per material, and ``stores`` (s, 3)
  int32 (column, register, width) in ``store_range`` (m + 1, 2): where the results go.
  Sources: ``texcoord`` reads the mesh's st; ``primvar`` (b = column of
  GeometryArrays.corner_primvars, c = width, its presence column after it; parameters =
  fallback); ``texture`` (a = uv register, b, c = wrap codes s, t, d = tile count, extra =
  first row of ``tiles`` (x, 2) int64 (tile, texture), parameters = fallback, then at
  UV_SCALE the texture units a unit of st spans at most, which scales its footprint).
* The textures' resident MIP levels (texture_cache.py), looked up trilinearly with the
  lookup's footprint (``_texture_value``).

``REGISTERS`` bounds a material's distinct nodes.
"""

from __future__ import annotations

import logging
import math
from typing import NamedTuple

import numpy as np

from .. import shader_nodes
from ..compiled import inline, kernel
from ..scene import Material, SceneData
from ..shader_nodes import ShaderNode
from . import texture_cache, textures
from .texture_cache import resident_textures

# Columns of a material row.
DIFFUSE, EMISSIVE, SPECULAR = 0, 3, 6  # 3 columns each
ROUGHNESS, METALLIC, OPACITY, CLEARCOAT, CLEARCOAT_ROUGHNESS = 9, 10, 11, 12, 13
IOR, OPACITY_THRESHOLD, USE_SPECULAR_WORKFLOW = 14, 15, 16
NORMAL = 17  # 3 columns: tangent space
TRANSMISSION, TRANSMISSION_COLOR = 20, 21  # 1 and 3 columns
THIN_WALLED, HAS_NORMAL = 24, 25
NORMAL_UV = 26  # 4 columns: ∂(s, t)/∂(u, v) row-major, of the uv the normal map is looked up at
HAIR = 30  # 1: a chiang_hair_bsdf (hair.py reads the columns below and IOR), 0: UsdPreviewSurface
HAIR_TINT = 31  # 9 columns: tint_R, tint_TT, tint_TRT
HAIR_ROUGHNESS = 40  # 6 columns: roughness_R, roughness_TT, roughness_TRT (v, s each)
HAIR_CUTICLE = 46
HAIR_ABSORPTION = 47  # 3 columns: absorption_coefficient σa
MATERIAL_FIELDS = 50
# Material fields a tree may drive: (field, first column, width).
_INPUTS = (("diffuse_color", DIFFUSE, 3), ("emissive_color", EMISSIVE, 3), ("specular_color", SPECULAR, 3),
           ("roughness", ROUGHNESS, 1), ("metallic", METALLIC, 1), ("opacity", OPACITY, 1),
           ("clearcoat", CLEARCOAT, 1), ("clearcoat_roughness", CLEARCOAT_ROUGHNESS, 1), ("normal", NORMAL, 3),
           ("transmission", TRANSMISSION, 1), ("transmission_color", TRANSMISSION_COLOR, 3),
           ("hair_tint_r", HAIR_TINT, 3), ("hair_tint_tt", HAIR_TINT + 3, 3), ("hair_tint_trt", HAIR_TINT + 6, 3),
           ("hair_absorption", HAIR_ABSORPTION, 3))
REGISTERS = 256
UV_SCALE = 4  # the parameter of a texture instruction after its fallback (see the module docstring)
log = logging.getLogger(__name__)
_INSTRUCTION = 8


class MaterialArrays(NamedTuple):
    """What kernels read of the materials (see the module docstring)."""

    constants: np.ndarray
    program: np.ndarray
    parameters: np.ndarray
    program_range: np.ndarray
    stores: np.ndarray
    store_range: np.ndarray
    tiles: np.ndarray
    texel_u8: np.ndarray
    texel_u16: np.ndarray
    texel_f32: np.ndarray
    texture_levels: np.ndarray
    texture_info: np.ndarray
    texture_luts: np.ndarray
    texture_wanted: np.ndarray


class MaterialTable:
    """Every material's inputs as arrays, for kernels (``arrays``).

    primvar_columns : GeometryArrays' primvar columns, name → (offset, width); a primvar
                      no mesh carries reads its fallback.
    finest          : SceneData.textures index → the finest MIP level to hold (None or
                      absent: none, its lookups read the fallback); default: every texture
                      from level 0 (texture_cache.resident_textures)
    texture_memory  : the textures' budget, MiB (default: texture_cache's)
    """

    def __init__(self, scene: SceneData, primvar_columns: dict[str, tuple[int, int]] | None = None,
                 finest: dict[int, int | None] | None = None, texture_memory: int | None = None):
        materials = scene.materials or (Material(name="default", path="<default>"),)
        compiler = _Compiler(scene, primvar_columns or {})
        rows = len(materials) + 1
        constants = np.zeros((rows, MATERIAL_FIELDS), np.float32)
        program_range = np.zeros((rows, 2), np.int64)
        store_range = np.zeros((rows, 2), np.int64)
        emissive = np.zeros(len(materials), bool)
        for index, material in enumerate(materials):
            program_range[index, 0], store_range[index, 0] = len(compiler.program), len(compiler.stores)
            trees = {}
            for name, column, width in _INPUTS:
                value = getattr(material, name)
                if isinstance(value, ShaderNode):
                    trees[column, width] = value
                elif value is not None:
                    constants[index, column:column + width] = value
            compiler.material(material.path, trees)
            program_range[index, 1], store_range[index, 1] = len(compiler.program), len(compiler.stores)
            constants[index, IOR] = material.ior
            constants[index, OPACITY_THRESHOLD] = material.opacity_threshold
            constants[index, USE_SPECULAR_WORKFLOW] = float(material.use_specular_workflow)
            constants[index, THIN_WALLED] = float(material.thin_walled)
            constants[index, HAS_NORMAL] = float(isinstance(material.normal, ShaderNode))
            constants[index, NORMAL_UV:NORMAL_UV + 4] = normal_uv_frame(material)
            constants[index, HAIR] = float(material.hair)
            constants[index, HAIR_ROUGHNESS:HAIR_ROUGHNESS + 6] = (
                *material.hair_roughness_r, *material.hair_roughness_tt, *material.hair_roughness_trt)
            constants[index, HAIR_CUTICLE] = material.hair_cuticle_angle
            emissive[index] = material.emits
        program_range[-1] = store_range[-1] = len(compiler.program), len(compiler.stores)
        constants[-1, OPACITY] = 1.0  # light shapes block shadow rays
        # Whether any material lets light through (presence below 1 somewhere).
        self.see_through = any(isinstance(material.opacity, ShaderNode) or material.opacity < 1
                               for material in materials)
        self.texture_rows = compiler.atlas  # SceneData.textures index → the kernels' texture row
        images = [scene.textures[texture] for texture in compiler.atlas]
        self.resident = resident_textures(
            images, None if finest is None else [finest.get(texture) for texture in compiler.atlas], texture_memory)
        self.arrays = MaterialArrays(
            constants=constants, program=np.array(compiler.program, np.int32).reshape(-1, _INSTRUCTION),
            parameters=np.array(compiler.parameters + [0.0], np.float32), program_range=program_range,
            stores=np.array(compiler.stores, np.int32).reshape(-1, 3), store_range=store_range,
            tiles=np.array(compiler.tiles, np.int64).reshape(-1, 2), texel_u8=self.resident.u8,
            texel_u16=self.resident.u16, texel_f32=self.resident.f32, texture_levels=self.resident.levels,
            texture_info=self.resident.info, texture_luts=self.resident.luts, texture_wanted=self.resident.wanted)
        self.emissive = emissive  # (materials,) bool, without the light-shape row
        self._images = images
        self._reported: set[int] = set()

    def report_unresident(self) -> None:
        """Warn, once per texture, about those lookups asked for that held no level (they
        read the fallback value): seen by the frame, missed by the visibility pre-pass."""
        wanted, resident = self.arrays.texture_wanted, self.arrays.texture_info[:, texture_cache.RESIDENT]
        for row in np.flatnonzero((wanted != texture_cache.NOT_WANTED) & (resident == 0)).tolist():
            if row not in self._reported:
                self._reported.add(row)
                image = self._images[row]
                log.warning("texture %s%s: looked up where the visibility pre-pass did not see it; its fallback "
                            "value was used there", image.path, texture_cache.used_by(image))


class _Compiler:
    """Appends materials' trees to one program (see the module docstring)."""

    def __init__(self, scene: SceneData, primvar_columns: dict[str, tuple[int, int]]):
        self.program: list[list[int]] = []
        self.parameters: list[float] = []
        self.stores: list[list[int]] = []
        self.tiles: list[list[int]] = []
        self.atlas: dict[int, int] = {}  # SceneData.textures index → texture row
        self._scene = scene
        self._primvar_columns = primvar_columns

    def material(self, path: str, trees: dict[tuple[int, int], ShaderNode]) -> None:
        registers: dict[ShaderNode, int] = {}  # equal subtrees share one register
        for (column, width), tree in trees.items():
            for current in tree.walk():
                if current not in registers:
                    if len(registers) == REGISTERS:
                        raise ValueError(f"material {path}: its shading networks have more than {REGISTERS} "
                                         "distinct nodes")
                    registers[current] = len(registers)
                    self._instruction(current, registers)
            self.stores.append([column, registers[tree], width])

    def _parameters(self, values: tuple[float, ...]) -> int:
        offset = len(self.parameters)
        self.parameters.extend(values)
        self.parameters.extend([0.0] * (shader_nodes.PARAMETERS - len(values)))
        return offset

    def _instruction(self, current: ShaderNode, registers: dict[ShaderNode, int]) -> None:
        inputs = [registers[child] for child in current.inputs]
        inputs += [registers[current]] * (shader_nodes.MAX_INPUTS - len(inputs))  # unused: any valid register
        row = [shader_nodes.OP_CODE[current.op], registers[current], *inputs, self._parameters(current.values), 0]
        if current.op == "primvar":
            offset, width = self._primvar_columns.get(current.name, (-1, 0))
            row[3], row[4] = offset, width
        elif current.op == "texture":
            row[3], row[4] = textures.wrap_code(current.wrap[0]), textures.wrap_code(current.wrap[1])
            row[5], row[7] = len(current.tiles), len(self.tiles)
            self.parameters[row[6] + UV_SCALE] = _uv_scale(current.inputs[0])
            for tile, texture in current.tiles:
                self.tiles.append([tile, self.atlas.setdefault(texture, len(self.atlas))])
        self.program.append(row)


def diffuse_texture(material: Material):
    """(SceneData.textures index, affine2d (6,) of its uv or None) of the first texture
    driving diffuse_color through a texcoord, for the covariance T operator; None when
    none does."""
    tree = material.diffuse_color
    if not isinstance(tree, ShaderNode):
        return None
    for current in tree.walk():
        if current.op == "texture" and len(current.tiles) == 1:
            transform = _uv_transform(current.inputs[0])
            if transform is not None:
                return current.tiles[0][1], transform
    return None


def normal_uv_frame(material: Material) -> np.ndarray:
    """∂(s, t)/∂(u, v) (4,) row-major, the inverse of the linear part of the uv transform
    through which the first texture of the normal map reads the mesh's st: the tangent
    frame of the normal map is ∂P/∂(u, v) = ∂P/∂(s, t) · that. Identity when there is no
    such transform (or it is singular)."""
    identity = np.array([1.0, 0.0, 0.0, 1.0])
    if not isinstance(material.normal, ShaderNode):
        return identity
    for current in material.normal.walk():
        if current.op == "texture":
            transform = _uv_transform(current.inputs[0])
            if transform is None:
                return identity
            linear = np.array([transform[0:2], transform[3:5]])
            if abs(np.linalg.det(linear)) < 1e-12:
                return identity
            return np.linalg.inv(linear).reshape(-1)
    return identity


def _uv_scale(uv: ShaderNode) -> float:
    """How many texture units a unit of the mesh's st spans, at most, along any direction, for
    a texture looked up at `uv`: the largest singular value of its affine map from st (1 when
    uv is not an affine map of st: a primvar, a computed uv)."""
    transform = _uv_transform(uv)
    if transform is None:
        return 1.0
    return float(np.linalg.norm(np.reshape(transform, (2, 3))[:, :2], 2))


def _uv_transform(uv: ShaderNode):
    """The affine map (6,) from the mesh's st to `uv`, or None when uv is not one."""
    matrix = np.eye(3)
    while uv.op == "affine2d":
        step = np.array([uv.values[0:3], uv.values[3:6], (0.0, 0.0, 1.0)])
        matrix = matrix @ step
        uv = uv.inputs[0]
    if uv.op != "texcoord":
        return None
    return tuple(matrix[:2].reshape(-1))


# -- per-lane functions of kernels

@inline
def _texture_value(materials, row, registers, out, footprint):
    """registers[out] ← the texture instruction `row`'s lookup, `footprint` (st units) wide:
    trilinear between the two resident MIP levels whose texels are nearest that size (the
    finest resident level for a footprint of 0 or one finer than it); the fallback where
    no level is resident. Records the level asked for in ``texture_wanted`` (ANY_LEVEL
    without a footprint)."""
    program, ro = materials.program, registers[out]
    s, t = registers[program[row, 2], 0], registers[program[row, 2], 1]
    count, first = program[row, 5], program[row, 7]
    texture = -1
    if count == 1 and materials.tiles[first, 0] == 0:
        texture = materials.tiles[first, 1]
    elif math.isfinite(s) and math.isfinite(t):
        column, line = math.floor(s), math.floor(t)
        if 0 <= column < 10 and line >= 0:  # UDIM rows are ten tiles wide: no st aliases another tile
            tile = 1001 + column + 10 * line
            for k in range(count):
                if materials.tiles[first + k, 0] == tile:
                    texture = materials.tiles[first + k, 1]
        s, t = s - column, t - line
    info = materials.texture_info
    level = 0.0
    if texture >= 0:
        texels = (footprint * materials.parameters[program[row, 6] + UV_SCALE]
                  * max(info[texture, texture_cache.BASE_WIDTH], info[texture, texture_cache.BASE_HEIGHT]))
        level = math.log2(texels) if 1.0 < texels < 1e30 else 0.0  # NaN fails both tests too
        asked = np.int32(level) if footprint > 0.0 else np.int32(texture_cache.ANY_LEVEL)
        if asked < materials.texture_wanted[texture]:
            materials.texture_wanted[texture] = asked
    if texture < 0 or info[texture, texture_cache.RESIDENT] == 0:
        offset = program[row, 6]
        for k in range(4):
            ro[k] = materials.parameters[offset + k]
        return
    resident = info[texture, texture_cache.RESIDENT]
    level = min(max(level - info[texture, texture_cache.FINEST], 0.0), resident - 1.0)
    lower = int(level)
    fraction = level - lower
    top = info[texture, texture_cache.FIRST_ROW] + lower
    channels = materials.texture_levels[top, textures.CHANNELS]
    i00, i10, i01, i11, fx, fy = textures.footprint(materials.texture_levels, top, s, t, program[row, 3],
                                                    program[row, 4])
    for k in range(channels):  # each stored channel once, then expanded to RGBA in place
        ro[k] = _blend_stored(materials, top, i00, i10, i01, i11, fx, fy, k)
    if fraction > 0.0 and lower + 1 < resident:
        i00, i10, i01, i11, fx, fy = textures.footprint(materials.texture_levels, top + 1, s, t, program[row, 3],
                                                        program[row, 4])
        for k in range(channels):
            ro[k] += fraction * (_blend_stored(materials, top + 1, i00, i10, i01, i11, fx, fy, k) - ro[k])
    for k in range(3, -1, -1):  # descending: the channel a component reads is never above it
        stored = textures.rgba_channel(channels, k)
        ro[k] = 1.0 if stored < 0 else ro[stored]


@inline
def _stored_texel(materials, level, index, channel):
    """The linear value of stored `channel` of the texel at flat offset `index` (−1: black)
    of the resident level row `level`: the f32 pool's value, or the LUT's for the stored
    8- or 16-bit value (the colour LUT for colour channels, the raw one for alpha)."""
    if index < 0:
        return 0.0
    levels = materials.texture_levels
    pool = levels[level, texture_cache.POOL]
    if pool == texture_cache.POOL_F32:
        return materials.texel_f32[index + channel]
    colour = channel < (3 if levels[level, textures.CHANNELS] >= 3 else 1)
    lut = levels[level, texture_cache.COLOUR_LUT] if colour else levels[level, texture_cache.ALPHA_LUT]
    if pool == texture_cache.POOL_U8:
        return materials.texture_luts[lut + np.int64(materials.texel_u8[index + channel])]
    return materials.texture_luts[lut + np.int64(materials.texel_u16[index + channel])]


@inline
def _blend_stored(materials, level, i00, i10, i01, i11, fx, fy, channel):
    """One stored channel of a bilinear lookup in the level row `level` (textures.footprint)."""
    top = (_stored_texel(materials, level, i00, channel) * (1 - fx)
           + _stored_texel(materials, level, i10, channel) * fx)
    bottom = (_stored_texel(materials, level, i01, channel) * (1 - fx)
              + _stored_texel(materials, level, i11, channel) * fx)
    return top * (1 - fy) + bottom * fy


@inline
def _primvar_value(materials, row, corner_primvars, triangle, u, v, registers, out):
    """registers[out] ← the primvar instruction `row`'s value at barycentrics (u, v)."""
    program, ro = materials.program, registers[out]
    column, width, offset = program[row, 3], program[row, 4], program[row, 6]
    w = 1.0 - u - v
    present = column >= 0 and (w * corner_primvars[triangle, 0, column + width]
                               + u * corner_primvars[triangle, 1, column + width]
                               + v * corner_primvars[triangle, 2, column + width]) > 0.5
    for k in range(4):
        if present and k < width:
            ro[k] = (w * corner_primvars[triangle, 0, column + k] + u * corner_primvars[triangle, 1, column + k]
                     + v * corner_primvars[triangle, 2, column + k])
        else:
            ro[k] = materials.parameters[offset + k]


@kernel  # called, not inlined: the interpreter is compiled once, not into every kernel that shades
def material_inputs(materials, material, s, t, footprint, corner_primvars, triangle, u, v, registers, out):
    """Every input of `material` at a shading point — texture coordinates (s, t), textures
    looked up `footprint` wide (st units; 0: their finest resident level), barycentrics
    (u, v) of `triangle` — into out (MATERIAL_FIELDS,); registers: (REGISTERS, 4) float32
    scratch."""
    for column in range(MATERIAL_FIELDS):
        out[column] = materials.constants[material, column]
    program = materials.program
    for row in range(materials.program_range[material, 0], materials.program_range[material, 1]):
        op, target = program[row, 0], program[row, 1]
        if op == shader_nodes.TEXCOORD:
            registers[target, 0], registers[target, 1], registers[target, 2], registers[target, 3] = s, t, 0.0, 1.0
        elif op == shader_nodes.TEXTURE:
            _texture_value(materials, row, registers, target, footprint)
        elif op == shader_nodes.PRIMVAR:
            _primvar_value(materials, row, corner_primvars, triangle, u, v, registers, target)
        else:
            shader_nodes.apply(op, registers, target, program[row, 2], program[row, 3], program[row, 4],
                               program[row, 5], materials.parameters, program[row, 6])
    for store in range(materials.store_range[material, 0], materials.store_range[material, 1]):
        column, register, width = materials.stores[store, 0], materials.stores[store, 1], materials.stores[store, 2]
        for k in range(width):
            out[column + k] = registers[register, k]


@inline
def pass_fraction(inputs):
    """The fraction of paths (and of shadow-ray light) that passes through a hit whose
    material inputs are `inputs`: all below opacityThreshold (cut out) and none above it;
    without a threshold, 1 − opacity (presence)."""
    opacity, threshold = inputs[OPACITY], inputs[OPACITY_THRESHOLD]
    if threshold > 0:
        return 1.0 if opacity < threshold else 0.0
    return 1.0 - min(max(opacity, 0.0), 1.0)


@inline
def interpolate3(corners, triangle, u, v, out):
    """(1 − u − v)·c0 + u·c1 + v·c2 of `triangle`'s corners (t, 3 corners, 3) into out (3,)."""
    w = 1.0 - u - v
    for axis in range(3):
        out[axis] = (w * corners[triangle, 0, axis] + u * corners[triangle, 1, axis]
                     + v * corners[triangle, 2, axis])


@inline
def interpolate_st(corner_uvs, triangle, u, v):
    """Texture coordinates (s, t) at barycentrics (u, v) of `triangle` (corners (t, 3, 2))."""
    w = 1.0 - u - v
    return (w * corner_uvs[triangle, 0, 0] + u * corner_uvs[triangle, 1, 0] + v * corner_uvs[triangle, 2, 0],
            w * corner_uvs[triangle, 0, 1] + u * corner_uvs[triangle, 1, 1] + v * corner_uvs[triangle, 2, 1])


@inline
def shade_point(materials, geometry, triangle, u, v, registers, inputs, footprint):
    """material_inputs of `triangle`'s material at barycentrics (u, v), textures looked up
    `footprint` metres wide (0: their finest resident level); returns (s, t)."""
    s, t = interpolate_st(geometry.corner_uvs, triangle, u, v)
    material_inputs(materials, geometry.triangle_material[triangle], s, t,
                    footprint * st_per_metre(geometry, triangle) if footprint > 0.0 else 0.0,
                    geometry.corner_primvars, triangle, u, v, registers, inputs)
    return s, t


@inline
def triangle_edges(geometry, triangle):
    """`triangle`'s edges from its first corner: (e1, e2) in metres and (ds1, dt1, ds2, dt2)
    in st, as ten scalars."""
    corners, uvs = geometry.corner_positions, geometry.corner_uvs
    return (corners[triangle, 1, 0] - corners[triangle, 0, 0], corners[triangle, 1, 1] - corners[triangle, 0, 1],
            corners[triangle, 1, 2] - corners[triangle, 0, 2], corners[triangle, 2, 0] - corners[triangle, 0, 0],
            corners[triangle, 2, 1] - corners[triangle, 0, 1], corners[triangle, 2, 2] - corners[triangle, 0, 2],
            uvs[triangle, 1, 0] - uvs[triangle, 0, 0], uvs[triangle, 1, 1] - uvs[triangle, 0, 1],
            uvs[triangle, 2, 0] - uvs[triangle, 0, 0], uvs[triangle, 2, 1] - uvs[triangle, 0, 1])


@inline
def st_per_metre(geometry, triangle):
    """How many st units a metre of `triangle` spans: √(its area in st / its area in metres),
    0 where either is 0 (the footprint of a lookup in st, for its MIP level)."""
    e1x, e1y, e1z, e2x, e2y, e2z, ds1, dt1, ds2, dt2 = triangle_edges(geometry, triangle)
    cx, cy, cz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    area = math.sqrt(cx * cx + cy * cy + cz * cz)
    return math.sqrt(abs(ds1 * dt2 - ds2 * dt1) / area) if area > 0.0 else 0.0


def inputs_at(arrays: MaterialArrays, material: int, st: np.ndarray, footprint: float = 0.0) -> np.ndarray:
    """Every input (n, MATERIAL_FIELDS) float32 of `material` at texture coordinates st
    (n, 2), textures looked up `footprint` st units wide (0: their finest resident level), on
    a mesh without primvars (readers give their fallbacks): the shading kernels' own
    evaluation, for checks and tools."""
    st = np.ascontiguousarray(st, np.float32).reshape(-1, 2)
    out = np.empty((len(st), MATERIAL_FIELDS), np.float32)
    _inputs_at_kernel(arrays, material, st, float(footprint), np.zeros((1, 3, 0), np.float32),
                      np.empty((REGISTERS, 4), np.float32), out)
    return out


@kernel
def _inputs_at_kernel(materials, material, st, footprint, corner_primvars, registers, out):
    for lane in range(len(st)):
        material_inputs(materials, material, st[lane, 0], st[lane, 1], footprint, corner_primvars, 0, 0.0, 0.0,
                        registers, out[lane])
