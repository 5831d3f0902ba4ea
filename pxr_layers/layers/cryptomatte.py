"""Cryptomatte (Psyop's specification 1.1): ids of names, ranked per pixel, with a manifest.

A Cryptomatte type (a layer ``NAME``: ``CryptoObject``, ``CryptoMaterial``, ``CryptoAsset``)
gives every name (a prim path, a material path, a model root's path) an id, the 32-bit
MurmurHash3_x86_32 (seed 0) of its UTF-8 bytes read as a float32 whose exponent is kept off
0 and 255 (no denormals, inf or NaN): bit 23 is flipped where the exponent is 0 or 255,
which clamps it to [1, 254] as the specification's code does. Each pixel keeps its ``depth``
ids of largest coverage (coverage: the pixel filter's share of the pixel's camera samples
whose first visible hit has that name), highest first, as the parts

    NAME00.R, .G, .B, .A = id rank 0, coverage rank 0, id rank 1, coverage rank 1
    NAME01.R, ...         = ranks 2 and 3, ...

(float32; an empty rank has id 0 and coverage 0). The manifest maps each name to the 8 hex
digits of its id's float bits, ``{"/World/floor": "7d36650d", ...}``. The header attributes of
a type are keyed by the first 7 of those digits of its type name's id (``CryptoObject`` →
``3ae39a5``; the specification suggests a hash of the type name without fixing one, and the
``d593dd7`` its example files under CryptoObject is the key of ``uCryptoAsset``) as

    cryptomatte/<key>/name       = NAME
    cryptomatte/<key>/hash       = MurmurHash3_32
    cryptomatte/<key>/conversion = uint32_to_float32
    cryptomatte/<key>/manifest   = the manifest as JSON

The encoder lives here, and the one decoder the inspector's masks need (:func:`coverage`:
the matte of a list of names, as a compositor keys it; :func:`names_at`: what a click picks);
the tests decode with their own implementation of the specification.
"""

from __future__ import annotations

import json
import logging
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

log = logging.getLogger(__name__)

HASH = "MurmurHash3_32"
CONVERSION = "uint32_to_float32"
ATTRIBUTE_PREFIX = "cryptomatte/"
_MASK = 0xFFFFFFFF


def murmurhash3_32(data: bytes, seed: int = 0) -> int:
    """MurmurHash3_x86_32 of ``data`` (Austin Appleby's reference), as an unsigned 32-bit int."""
    c1, c2 = 0xCC9E2D51, 0x1B873593
    h = seed & _MASK
    blocks = len(data) // 4
    for (k,) in struct.iter_unpack("<I", data[:4 * blocks]):
        h ^= _mix(k, c1, c2)
        h = _rotate(h, 13)
        h = (h * 5 + 0xE6546B64) & _MASK
    tail = data[4 * blocks:]
    if tail:
        h ^= _mix(int.from_bytes(tail, "little"), c1, c2)
    h ^= len(data)
    h ^= h >> 16
    h = (h * 0x85EBCA6B) & _MASK
    h ^= h >> 13
    h = (h * 0xC2B2AE35) & _MASK
    return h ^ (h >> 16)


def _mix(k: int, c1: int, c2: int) -> int:
    return (_rotate((k * c1) & _MASK, 15) * c2) & _MASK


def _rotate(value: int, bits: int) -> int:
    return ((value << bits) | (value >> (32 - bits))) & _MASK


def id_bits(name: str) -> int:
    """The float bits of ``name``'s id: its hash with the exponent moved off 0 and 255."""
    bits = murmurhash3_32(name.encode("utf-8"))
    exponent = (bits >> 23) & 0xFF
    return bits ^ (1 << 23) if exponent in (0, 0xFF) else bits


def name_id(name: str) -> np.float32:
    """``name``'s id as the float32 the pixels hold."""
    return np.uint32(id_bits(name)).view(np.float32)


def id_hex(name: str) -> str:
    """The manifest's value for ``name``: 8 lower-case hex digits of its id's bits."""
    return f"{id_bits(name):08x}"


def type_key(type_name: str) -> str:
    """The 7-hex-digit key of a type's header attributes (as the Nuke gizmo derives it)."""
    return id_hex(type_name)[:7]


def manifest(names: Sequence[str]) -> dict[str, str]:
    """name → id_hex(name), in the order given."""
    return {name: id_hex(name) for name in names}


COLLISIONS_NAMED = 5
"""Groups of names sharing an id a warning lists at most (then how many more)."""


def collisions(type_manifest: Mapping[str, str]) -> list[tuple[str, ...]]:
    """The groups of names of a manifest (name → id_hex) that share one id, in the
    manifest's order. 32-bit hashes collide by chance (even odds among some 77 000 names,
    by the birthday bound), and the exponent fix gives two hashes one id when they differ
    only in bit 23 and one's exponent is 0 (or 255), the other's 1 (or 254)."""
    by_id: dict[str, list[str]] = {}
    for name, hex_id in type_manifest.items():
        by_id.setdefault(hex_id, []).append(name)
    return [tuple(names) for names in by_id.values() if len(names) > 1]


def warn_of_collisions(type_name: str, type_manifest: Mapping[str, str]) -> str | None:
    """One warning line (logged and returned) naming the names of ``type_name`` that share
    an id: a compositor's matte of one picks the others too. None when every id is unique."""
    groups = collisions(type_manifest)
    if not groups:
        return None
    shown = "; ".join(" and ".join(map(repr, names)) + f" (id {type_manifest[names[0]]})"
                      for names in groups[:COLLISIONS_NAMED])
    more = f"; and {len(groups) - COLLISIONS_NAMED} more" if len(groups) > COLLISIONS_NAMED else ""
    message = (f"{type_name}: names share a Cryptomatte id, so a matte of one picks the other too: "
               f"{shown}{more} (rename one of each)")
    log.warning(message)
    return message


def header_attributes(type_name: str, type_manifest: Mapping[str, str]) -> dict[str, str]:
    """The ``cryptomatte/<key>/...`` header attributes of one type (on its parts and part 0)."""
    prefix = f"{ATTRIBUTE_PREFIX}{type_key(type_name)}/"
    return {prefix + "name": type_name, prefix + "hash": HASH, prefix + "conversion": CONVERSION,
            prefix + "manifest": json.dumps(dict(type_manifest), separators=(",", ":"))}


@dataclass(frozen=True)
class Cryptomatte:
    """One Cryptomatte type of a frame, ranked.

    ids      : (h, w, depth) float32, rank r's id in [..., r]; 0 where the rank is empty
    coverage : (h, w, depth) float32, its coverage (0..1; a pixel's sum is its alpha when no
               more than ``depth`` names cover it)
    manifest : name → id_hex, every name the type knows (also those no pixel ranks)
    """

    ids: np.ndarray
    coverage: np.ndarray
    manifest: dict[str, str]

    @property
    def depth(self) -> int:
        return self.ids.shape[2]

    @cached_property
    def names_by_id(self) -> dict[str, str]:
        """id_hex → the manifest's first name of it (once: a click picks by it)."""
        return {hex_id: name for name, hex_id in reversed(self.manifest.items())}

    def part_pixels(self, part: int) -> np.ndarray:
        """Part ``part`` (``NAME{part:02d}``) as (h, w, 4) float32: id, coverage of ranks 2·part, 2·part + 1."""
        height, width, depth = self.ids.shape
        pixels = np.zeros((height, width, 4), np.float32)
        for slot, rank in enumerate((2 * part, 2 * part + 1)):
            if rank < depth:
                pixels[..., 2 * slot] = self.ids[..., rank]
                pixels[..., 2 * slot + 1] = self.coverage[..., rank]
        return pixels

    @classmethod
    def from_parts(cls, parts: Sequence[np.ndarray], type_manifest: Mapping[str, str]) -> Cryptomatte:
        """The Cryptomatte whose parts (each (h, w, 4), in order) :meth:`part_pixels` gave."""
        stacked = np.concatenate([np.asarray(part, np.float32) for part in parts], axis=2)
        return cls(np.ascontiguousarray(stacked[..., 0::2]), np.ascontiguousarray(stacked[..., 1::2]),
                   dict(type_manifest))


def rank(names: Sequence[str], pixel: np.ndarray, name: np.ndarray, weight: np.ndarray,
         resolution: tuple[int, int], depth: int, type_name: str = "Cryptomatte") -> Cryptomatte:
    """Rank the coverage of one type into a Cryptomatte of ``depth`` ranks; names whose
    ids collide are warned of (:func:`warn_of_collisions`, ``type_name`` naming the type).

    names  : the type's names (the manifest, in this order)
    pixel  : (k,) int64 pixel index y·w + x; name : (k,) int index into ``names``;
    weight : (k,) float32 coverage of that name in that pixel, at most one entry per pair
    resolution : (w, h)

    Ranks run by coverage, highest first; equal coverages by id bits, so the order never
    depends on the input's.
    """
    width, height = resolution
    ids = np.zeros((height * width, depth), np.float32)
    coverage = np.zeros((height * width, depth), np.float32)
    table = manifest(names)
    warn_of_collisions(type_name, table)
    if len(pixel) and depth:
        bits = np.array([int(table[n], 16) for n in names], np.uint32)
        order = np.lexsort((bits[name], -np.asarray(weight, np.float64), pixel))
        pixel, name, weight = pixel[order], name[order], np.asarray(weight, np.float32)[order]
        first = np.flatnonzero(np.r_[True, pixel[1:] != pixel[:-1]])
        ranks = np.arange(len(pixel)) - np.repeat(first, np.diff(np.r_[first, len(pixel)]))
        kept = ranks < depth
        ids[pixel[kept], ranks[kept]] = bits[name[kept]].view(np.float32)
        coverage[pixel[kept], ranks[kept]] = weight[kept]
    return Cryptomatte(ids.reshape(height, width, depth), coverage.reshape(height, width, depth), table)


def asset_roots(object_paths: Sequence[str], model_paths: Sequence[str]) -> tuple[str, ...]:
    """CryptoAsset's name of each object: the nearest of ``model_paths`` (the stage's
    models, stage.recipe_reader.model_prim_paths) that is the object's path or above it,
    else the object's top-level prim (``/World`` for ``/World/Geometry/floor``)."""
    models = set(model_paths)
    roots = []
    for path in object_paths:
        parts = path.split("/")  # "/a/b" → "", "a", "b"
        ancestors = ("/".join(parts[:end]) for end in range(len(parts), 1, -1))
        roots.append(next((p for p in ancestors if p in models), "/".join(parts[:2]) or path))
    return tuple(roots)


def coverage(cryptomatte: Cryptomatte, names: Sequence[str]) -> np.ndarray:
    """The matte of ``names``: (h, w) float32, at each pixel the sum of the coverages of the
    ranks whose id is one of the names' ids (the specification's keying, as the Nuke gizmo
    and Blender's compositor key a matte list), ranks summed in order in float32, clipped to
    [0, 1]. Ids come from the names (:func:`name_id`), not the manifest, as the
    specification asks of decoders; a name no pixel ranks has coverage 0 everywhere."""
    wanted = np.array([id_bits(name) for name in names], np.uint32)
    ranks = cryptomatte.ids.view(np.uint32)
    total = np.zeros(cryptomatte.ids.shape[:2], np.float32)
    for slot in range(cryptomatte.depth):
        hit = np.isin(ranks[..., slot], wanted) & (ranks[..., slot] != 0)
        total += np.where(hit, cryptomatte.coverage[..., slot], np.float32(0.0))
    return np.clip(total, np.float32(0.0), np.float32(1.0))


def names_at(cryptomatte: Cryptomatte, x: int, y: int) -> list[tuple[str, float]]:
    """The names ranked at pixel (x, y) (x from the left, y from the top) with their
    coverage, highest first: what a click on the pixel picks. Empty ranks are left out; an
    id the manifest does not name is given as its 8 hex digits."""
    by_id = cryptomatte.names_by_id
    picked = []
    for slot in range(cryptomatte.depth):
        bits = int(cryptomatte.ids[y, x, slot:slot + 1].view(np.uint32)[0])
        weight = float(cryptomatte.coverage[y, x, slot])
        if bits and weight > 0.0:
            picked.append((by_id.get(f"{bits:08x}", f"{bits:08x}"), weight))
    return picked
