"""Material textures as kernels read them: MIP pyramids in each file's own precision, the
levels the frame needs, within a memory budget.

Why not OpenImageIO's TextureSystem: its lookups are calls into C++ through Python, one per
shading point, and the tracer's kernels (numba, no Python inside) cannot make them; what
it does that matters here — a bounded cache, MIP levels chosen by the lookup's footprint,
trilinear filtering, 8-bit and half texels kept as stored — is a few arrays and a few
lines of kernel code. So the cache reads files through OpenImageIO (texture_files.py: a
``maketx`` .tx or tiled EXR at the level it holds, any other file averaged down from its
finest level a band of rows at a time) and hands kernels flat arrays.

What is in memory
-----------------
Pools, one per stored type: ``u8`` (8-bit files), ``u16`` (16-bit files and half floats, as
their bits), ``f32`` (float files, and images already decoded: lights' tools, tests). Each
level of each resident texture is one block of a pool, row-major (h, w, c), row 0 the top
of the image, the file's channels (at most 4). ``levels`` (L, 7) int64 rows: OFFSET,
WIDTH, HEIGHT, CHANNELS (the columns textures.footprint reads of an atlas row), POOL,
COLOUR_LUT and ALPHA_LUT: where in ``luts`` (float32) the stored value's linear value is
looked up (−1 for the f32 pool, already linear). The LUTs: 8-bit and 16-bit unsigned
values as v / (2^n − 1), raw and through the sRGB EOTF; half floats' bit patterns, raw and
through the EOTF, NaN and infinities as 0. Alpha (the 2nd channel of grey + alpha, the 4th
of RGBA) is always raw. ``info`` (x, 5) int64 per texture: FIRST_ROW (its finest resident
level's row; the coarser ones follow), RESIDENT (levels held, 0: none), FINEST (the level
number of the first held: 0 is the file's full size), BASE_WIDTH and BASE_HEIGHT (level 0's).

A pyramid is built as ``maketx`` builds one: each level the 2 × 2 box average of the one
above (its stored values: 8-bit sRGB is averaged before it is decoded; an odd last row or
column is averaged with what is left), sizes halved and rounded up, down to 1 × 1.

Which levels
------------
The caller says, per texture, the finest level to hold (None: none); ``resident_textures``
holds it and every coarser one. The finest level holds at most MAX_TEXTURE_TEXELS, and all
of them together at most the budget (``--texture-memory``, the job key
``render.texture_memory``; default DEFAULT_TEXTURE_MEMORY of the machine's memory): past it
the texture whose finest level is largest is held one level coarser, again until the rest
fits, with a warning naming each texture so reduced. A file that cannot be read is a
warning and its fallback value.

Kernels read ``wanted`` (x,) int32 too: the finest level a lookup asked for, written where
smaller (shading._texture_value). trace/render.prepare traces a visibility pre-pass with
nothing resident, and holds what it asked for.

The pyramids of the last frame are kept in the process (by file identity and level): the
frames of a shot read the same files one after another.
"""

from __future__ import annotations

import logging
import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..cores import available_cores
from ..request import DEFAULT_TEXTURE_MEMORY, MAX_DEFAULT_TEXTURE_MIB
from ..scene import FLOAT, TextureImage
from ..texture_files import (
    MAX_TEXTURE_TEXELS,
    as_stored,
    block_means,
    file_identity,
    level_count,
    level_size,
    linear,
    read_level,
    repaired,
    srgb_to_linear,
)

log = logging.getLogger(__name__)

POOL_U8, POOL_U16, POOL_F32 = range(3)
OFFSET, WIDTH, HEIGHT, CHANNELS, POOL, COLOUR_LUT, ALPHA_LUT = range(7)  # columns of ``levels``
FIRST_ROW, RESIDENT, FINEST, BASE_WIDTH, BASE_HEIGHT = range(5)  # columns of ``info``
NOT_WANTED = np.iinfo(np.int32).max
"""``wanted`` of a texture no lookup asked for."""
ANY_LEVEL = NOT_WANTED - 1
"""``wanted`` of a texture only lookups without a footprint asked for (any level serves them)."""
_MIB = 1 << 20
_POOLS = {"uint8": POOL_U8, "uint16": POOL_U16, "half": POOL_U16, "float": POOL_F32}
_ITEM_BYTES = {"uint8": 1, "uint16": 2, "half": 2, "float": 4}


def default_texture_memory_mib() -> int:
    """The texture budget when none is given, MiB: DEFAULT_TEXTURE_MEMORY of the physical
    memory, at most MAX_DEFAULT_TEXTURE_MIB, at least 256."""
    try:
        total = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):  # not on every platform
        return 1024
    return int(max(256, min(MAX_DEFAULT_TEXTURE_MIB, total * DEFAULT_TEXTURE_MEMORY / _MIB)))


def _build_luts() -> tuple[np.ndarray, dict[tuple[str, str], int]]:
    """(the LUTs concatenated, float32; (stored type, colour space) → offset)."""
    # float32 arithmetic, as OpenImageIO's conversion and the stage reader's EOTF: the same bits
    unorm8 = np.arange(256, dtype=FLOAT) * FLOAT(1 / 255)
    unorm16 = np.arange(65536, dtype=FLOAT) * FLOAT(1 / 65535)
    half = np.arange(65536, dtype=np.uint16).view(np.float16).astype(FLOAT)
    half[~np.isfinite(half)] = 0.0
    tables, offsets, offset = [], {}, 0
    for stored, values in (("uint8", unorm8), ("uint16", unorm16), ("half", half)):
        for color_space in ("raw", "sRGB"):
            offsets[stored, color_space] = offset
            tables.append(values if color_space == "raw" else srgb_to_linear(values))
            offset += len(values)
    return np.concatenate(tables).astype(FLOAT), offsets


LUTS, _LUT_OFFSETS = _build_luts()
LUTS.flags.writeable = False


@dataclass(frozen=True)
class ResidentTextures:
    """The arrays kernels read (module docstring); ``wanted`` is written by lookups."""

    u8: np.ndarray
    u16: np.ndarray
    f32: np.ndarray
    levels: np.ndarray
    info: np.ndarray
    luts: np.ndarray
    wanted: np.ndarray

    def finest_linear(self, texture: int) -> np.ndarray | None:
        """(h, w, c) float32 linear values of `texture`'s finest resident level, None when
        nothing is resident."""
        if self.info[texture, RESIDENT] == 0:
            return None
        row = self.levels[self.info[texture, FIRST_ROW]]
        size = row[WIDTH] * row[HEIGHT] * row[CHANNELS]
        pool = (self.u8, self.u16, self.f32)[row[POOL]]
        stored = pool[row[OFFSET]:row[OFFSET] + size].reshape(row[HEIGHT], row[WIDTH], row[CHANNELS])
        if row[POOL] == POOL_F32:
            return stored
        colour = 3 if row[CHANNELS] >= 3 else 1
        linear = np.empty(stored.shape, FLOAT)
        linear[..., :colour] = self.luts[row[COLOUR_LUT] + stored[..., :colour].astype(np.int64)]
        linear[..., colour:] = self.luts[row[ALPHA_LUT] + stored[..., colour:].astype(np.int64)]
        return linear


def decoded(image: TextureImage) -> np.ndarray:
    """(h, w, c) float32 linear values of `image` at full size, as lookups read its level 0
    (its pixels when the stage reader decoded it)."""
    if image.pixels is not None:
        return image.pixels
    linear = resident_textures([image], [0], budget_mib=np.iinfo(np.int32).max).finest_linear(0)
    if linear is None:
        raise OSError(f"cannot read texture {image.path}")
    return linear


def pyramid_bytes(image: TextureImage, finest: int) -> int:
    """Bytes of `image`'s levels from `finest` down to 1 × 1."""
    width, height, channels, stored = _shape(image)
    total = 0
    for level in range(finest, level_count(width, height)):
        w, h = level_size(width, height, level)
        total += w * h * channels * _ITEM_BYTES[stored]
    return total


def _shape(image: TextureImage) -> tuple[int, int, int, str]:
    """(width, height, channels held, stored type) of level 0."""
    if image.pixels is not None:
        height, width, channels = image.pixels.shape
        return width, height, min(channels, 4), "float"
    header = image.header
    return header.width, header.height, min(header.channels, 4), header.stored


def fit_levels(images: Sequence[TextureImage], finest: Sequence[int | None], budget_mib: int) -> list[int | None]:
    """The finest level to hold of each image: at least the one asked for (None: none), at most
    MAX_TEXTURE_TEXELS texels, and all the pyramids within `budget_mib` (the texture whose
    finest level frees most is lowered first), with a warning for each image held coarser
    than asked."""
    chosen = list(finest)
    reasons: dict[int, str] = {}
    for index, (image, level) in enumerate(zip(images, finest)):
        if level is None:
            continue
        chosen[index] = level = min(level, _last_level(image))
        while _texels(image, level) > MAX_TEXTURE_TEXELS:
            level += 1
            reasons[index] = f"more than the {MAX_TEXTURE_TEXELS:,} texels a texture may hold"
        chosen[index] = level
    sizes = {index: pyramid_bytes(images[index], level) for index, level in enumerate(chosen) if level is not None}
    total = sum(sizes.values())
    while total > budget_mib * _MIB:
        freed = {index: sizes[index] - pyramid_bytes(images[index], chosen[index] + 1)
                 for index in sizes if chosen[index] < _last_level(images[index])}
        if not freed:
            break  # every texture at 1 × 1: the budget is as small as it can be
        lowered = max(freed, key=freed.__getitem__)
        chosen[lowered] += 1
        sizes[lowered] -= freed[lowered]
        total -= freed[lowered]
        reasons[lowered] = f"the frame's textures pass the {budget_mib} MiB texture memory budget (--texture-memory)"
    for index, reason in sorted(reasons.items()):
        image = images[index]
        width, height, _, _ = _shape(image)
        held, asked = level_size(width, height, chosen[index]), level_size(width, height, finest[index])
        log.warning("texture %s%s: held at %d×%d texels, not the %d×%d the frame asks for: %s", image.path,
                    used_by(image), *held, *asked, reason)
    return chosen


def used_by(image: TextureImage) -> str:
    """The words ' (used by PRIM)' of a warning about `image`, when the stage reader named the prim."""
    return f" (used by {image.user})" if image.user else ""


def _last_level(image: TextureImage) -> int:
    width, height, _, _ = _shape(image)
    return level_count(width, height) - 1


def _texels(image: TextureImage, level: int) -> int:
    width, height, _, _ = _shape(image)
    w, h = level_size(width, height, level)
    return w * h


_LAST: dict[tuple, tuple[list[np.ndarray], int]] = {}  # the last frame's _pyramid results, by _pyramid_key
_LAST_LOCK = threading.Lock()


def _pyramid_key(image: TextureImage, finest: int) -> tuple | None:
    """What tells a lazy image's pyramid apart: the file's identity, colour space and level."""
    identity = file_identity(image.path)
    return None if identity is None else (*identity, image.color_space, finest)


def _pyramid(image: TextureImage, finest: int) -> tuple[list[np.ndarray], int]:
    """`image`'s levels from `finest` to 1 × 1, (h, w, c) arrays of its stored type (float32
    linear for the f32 pool), and how many texels of the first were NaN or infinite (read
    as 0); OSError when its file cannot be read."""
    fixed = 0
    if image.pixels is not None:
        top = np.asarray(image.pixels[..., :4], FLOAT)
        for _ in range(finest):
            top = block_means(top, 2)
        stored = "float"
    else:
        header, top = read_level(image.path, finest, image.header.stored)
        stored = image.header.stored
        if (header.width, header.height, header.stored) != (image.header.width, image.header.height, stored):
            raise OSError("the file changed since the stage was read")
        if stored == "half":
            top = np.array(top)
            fixed = repaired(top)
        elif stored == "float":  # held linear
            top = linear(top, image.color_space)
            fixed = repaired(top)
    levels = [top]
    while levels[-1].shape[0] > 1 or levels[-1].shape[1] > 1:
        levels.append(as_stored(block_means(levels[-1], 2), stored))
    for level in levels:
        level.flags.writeable = False
    return levels, fixed


def resident_textures(images: Sequence[TextureImage], finest: Sequence[int | None] | None = None,
                      budget_mib: int | None = None) -> ResidentTextures:
    """The arrays of `images` holding, for each, its levels from ``finest[i]`` down (None:
    none; default: every image from level 0), within ``budget_mib`` MiB (default
    default_texture_memory_mib()), decoded on every core this process may use. Says, at
    every call (each frame's warnings are its own), which files held NaN or infinite texels."""
    finest = [0] * len(images) if finest is None else list(finest)
    budget_mib = default_texture_memory_mib() if budget_mib is None else budget_mib
    chosen = fit_levels(images, finest, budget_mib)
    work = [index for index, level in enumerate(chosen) if level is not None]
    kept: dict[tuple, tuple[list[np.ndarray], int]] = {}
    with _LAST_LOCK:
        last = dict(_LAST)

    def pyramid(index: int) -> list[np.ndarray] | None:
        image = images[index]
        key = None if image.pixels is not None else _pyramid_key(image, chosen[index])
        try:
            levels, fixed = last[key] if key in last else _pyramid(image, chosen[index])
        except OSError as error:
            log.warning("cannot read texture %s%s: %s; using the fallback value instead", image.path,
                        used_by(image), error)
            return None
        if key is not None:
            kept[key] = levels, fixed
        if fixed:
            log.warning("texture %s%s: %d of %d texels are NaN or infinite (read as 0)", image.path, used_by(image),
                        fixed, levels[0].shape[0] * levels[0].shape[1])
        return levels

    with ThreadPoolExecutor(max(1, min(available_cores(), len(work)))) as pool:
        pyramids = dict(zip(work, pool.map(pyramid, work)))
    resident = _assemble(images, pyramids, chosen)  # the kept levels are views of its pools now
    if any(images[index].pixels is None for index in work):  # a call that held no file keeps the last frame's
        with _LAST_LOCK:
            _LAST.clear()
            _LAST.update(kept)
    return resident


def _assemble(images: Sequence[TextureImage], pyramids: dict[int, list[np.ndarray] | None],
              chosen: list[int | None]) -> ResidentTextures:
    """One block per level in its pool (module docstring). Each pyramid's levels are copied
    in and replaced, in its list, by a view of the pool, one at a time: the pools' pages are
    only touched as they are filled, so memory holds the textures about once, not twice."""
    info = np.zeros((len(images), 5), np.int64)
    rows: list[list[int]] = []
    sizes = [0, 0, 0]
    for index, image in enumerate(images):
        width, height, _, stored = _shape(image)
        info[index, BASE_WIDTH], info[index, BASE_HEIGHT] = width, height
        levels = pyramids.get(index)
        info[index, FIRST_ROW] = len(rows)
        if not levels:
            continue
        info[index, RESIDENT], info[index, FINEST] = len(levels), chosen[index]
        pool = _POOLS[stored]
        color_space = "raw" if image.pixels is not None else image.color_space
        colour_lut = -1 if pool == POOL_F32 else _LUT_OFFSETS[stored, color_space]
        alpha_lut = -1 if pool == POOL_F32 else _LUT_OFFSETS[stored, "raw"]
        for level in levels:
            h, w, c = level.shape
            rows.append([sizes[pool], w, h, c, pool, colour_lut, alpha_lut])
            sizes[pool] += level.size
    pools = [np.empty(max(size, 1), dtype) for size, dtype in zip(sizes, (np.uint8, np.uint16, FLOAT))]
    row = 0
    for index in range(len(images)):
        for number, level in enumerate(pyramids.get(index) or ()):
            offset, pool = rows[row][OFFSET], rows[row][POOL]
            block = pools[pool][offset:offset + level.size]
            block[:] = (level.view(np.uint16) if level.dtype == np.float16 else level).reshape(-1)
            block.flags.writeable = False
            pyramids[index][number] = block.view(level.dtype).reshape(level.shape)
            row += 1
    for array in pools:
        array.flags.writeable = False
    return ResidentTextures(u8=pools[POOL_U8], u16=pools[POOL_U16], f32=pools[POOL_F32],
                            levels=np.array(rows, np.int64).reshape(-1, 7), info=info, luts=LUTS,
                            wanted=np.full(len(images), NOT_WANTED, np.int32))
