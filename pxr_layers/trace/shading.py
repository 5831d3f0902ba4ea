"""UsdPreviewSurface inputs as tables for kernels, and their per-lane evaluation.

``MaterialTable`` turns SceneData.materials into arrays (one row per material, plus a last
row that index −1, the light shapes, reads and never shades): ``constants`` (m + 1,
MATERIAL_FIELDS) float32 holds every input's constant value, ``slot_input`` (m + 1, SLOTS)
int32 the texture input driving each slot (−1: none), and the texture inputs themselves
are ``input_ints`` (k, 7) int32 (texture, channel count, channels ×3, wrap s, wrap t) and
``input_floats`` (k, 8) float32 (scale ×4, bias ×4), with the textures packed in one atlas
(textures.py). A texture input's value is ``texel[channels] · scale[channels] +
bias[channels]``; a colour driven by one channel repeats it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..scene import Material, SceneData, TextureInput
from . import textures
from ..compiled import inline

# Columns of a material row; the slots (inputs a texture may drive) in the same order.
DIFFUSE, EMISSIVE, SPECULAR = 0, 3, 6  # 3 columns each
ROUGHNESS, METALLIC, OPACITY, CLEARCOAT, CLEARCOAT_ROUGHNESS = 9, 10, 11, 12, 13
IOR, OPACITY_THRESHOLD, USE_SPECULAR_WORKFLOW = 14, 15, 16
MATERIAL_FIELDS = 17
_SLOTS = (("diffuse_color", DIFFUSE, 3), ("emissive_color", EMISSIVE, 3), ("specular_color", SPECULAR, 3),
          ("roughness", ROUGHNESS, 1), ("metallic", METALLIC, 1), ("opacity", OPACITY, 1),
          ("clearcoat", CLEARCOAT, 1), ("clearcoat_roughness", CLEARCOAT_ROUGHNESS, 1))
SLOT_COLUMN = np.array([column for _, column, _ in _SLOTS], np.int64)
SLOT_WIDTH = np.array([width for _, _, width in _SLOTS], np.int64)
SLOTS = len(_SLOTS)
EMISSIVE_SLOT = 1


class MaterialArrays(NamedTuple):
    """What kernels read of the materials (see the module docstring)."""

    constants: np.ndarray
    slot_input: np.ndarray
    textured: np.ndarray  # (m + 1,) bool: some slot is textured
    input_ints: np.ndarray
    input_floats: np.ndarray
    texels: np.ndarray
    texture_info: np.ndarray


class MaterialTable:
    """Every material's inputs as arrays, for kernels (``arrays``)."""

    def __init__(self, scene: SceneData):
        materials = scene.materials or (Material(name="default", path="<default>"),)
        rows = len(materials) + 1
        constants = np.zeros((rows, MATERIAL_FIELDS), np.float32)
        slot_input = np.full((rows, SLOTS), -1, np.int32)
        input_ints: list[list[int]] = []
        input_floats: list[list[float]] = []
        used_textures: dict[int, int] = {}
        for index, material in enumerate(materials):
            for slot, (name, column, width) in enumerate(_SLOTS):
                value = getattr(material, name)
                if isinstance(value, TextureInput):
                    atlas_index = used_textures.setdefault(value.texture, len(used_textures))
                    channels = list(value.channels)[:3]
                    input_ints.append([atlas_index, len(channels), *(channels + [0, 0, 0])[:3],
                                       textures.wrap_code(value.wrap_s), textures.wrap_code(value.wrap_t)])
                    input_floats.append([*value.scale, *value.bias])
                    slot_input[index, slot] = len(input_ints) - 1
                else:
                    constants[index, column:column + width] = value
            constants[index, IOR] = material.ior
            constants[index, OPACITY_THRESHOLD] = material.opacity_threshold
            constants[index, USE_SPECULAR_WORKFLOW] = float(material.use_specular_workflow)
        images = [scene.textures[texture].pixels for texture in used_textures]
        texels, info = textures.pack(images)
        self.arrays = MaterialArrays(
            constants=constants, slot_input=slot_input, textured=(slot_input >= 0).any(axis=1),
            input_ints=np.array(input_ints, np.int32).reshape(-1, 7),
            input_floats=np.array(input_floats, np.float32).reshape(-1, 8), texels=texels, texture_info=info)
        # (materials,) bool, without the light-shape row
        self.emissive = (constants[:-1, EMISSIVE:EMISSIVE + 3].max(axis=1) > 0) | (slot_input[:-1, EMISSIVE_SLOT] >= 0)


@inline
def _input_value(input_ints, input_floats, texels, texture_info, item, s, t, out, column, width):
    """Write texture input `item` at (s, t) into out[column:column + width]."""
    texture, count = input_ints[item, 0], input_ints[item, 1]
    i00, i10, i01, i11, fx, fy = textures.footprint(texture_info, texture, s, t, input_ints[item, 5],
                                                    input_ints[item, 6])
    for k in range(width):
        channel = input_ints[item, 2 + min(k, count - 1)]
        texel = textures.blend(texels, i00, i10, i01, i11, fx, fy, channel)
        out[column + k] = texel * input_floats[item, channel] + input_floats[item, 4 + channel]


@inline
def material_inputs(constants, slot_input, textured, input_ints, input_floats, texels, texture_info, material,
                    s, t, out):
    """Every input of `material` at texture coordinates (s, t) into out (MATERIAL_FIELDS,)."""
    for column in range(MATERIAL_FIELDS):
        out[column] = constants[material, column]
    if textured[material]:
        for slot in range(SLOTS):
            item = slot_input[material, slot]
            if item >= 0:
                _input_value(input_ints, input_floats, texels, texture_info, item, s, t, out, SLOT_COLUMN[slot],
                             SLOT_WIDTH[slot])


@inline
def emission(constants, slot_input, input_ints, input_floats, texels, texture_info, material, s, t, out):
    """emissiveColor of `material` at (s, t) into out (3,)."""
    item = slot_input[material, EMISSIVE_SLOT]
    if item >= 0:
        _input_value(input_ints, input_floats, texels, texture_info, item, s, t, out, 0, 3)
    else:
        out[0], out[1], out[2] = (constants[material, EMISSIVE], constants[material, EMISSIVE + 1],
                                  constants[material, EMISSIVE + 2])


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
