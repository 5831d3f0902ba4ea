"""Path space cut into atoms: the finest pieces any split of the hierarchy can tell apart.

Every split of :mod:`.search` looks at a path through a few attributes only (ATTRIBUTES):
the light group of the emitter it ends at (``pxrLayers:lightGroup``, from the index
manifest's ``light_groups``), the emitter, how many bounces it has (none, one, more), the first bounce's
type, scattering, object, material and covariance bins (curvature, texture, reflectance
zero or not), and what the **whole path touches**: every object, material and asset (the
Cryptomatte asset: the object's model root, from the manifest's ``model_paths``) that any of
its events carries, at any bounce. An index without those manifest keys (rendered before
they were recorded) has no groups and no assets.
An **atom** is one combination of these values; a path class is one atom, except that the
covariance bins are per record. One read of each index sums every atom's
light per image tile: the tile maps the objective compares (docs/suggest.md).

Values are strings that mean the same in every frame of a shot (prim paths, letters), so
the atoms of several indexes are merged by value, and each atom's maps of every frame are
kept side by side (a shot's frames are separate tiles, not added together).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..paths.events import Event, event_paths
from ..paths.reader import PathIndex
from ..layers.cryptomatte import asset_roots
from ..layers.previews import LUMINANCE_WEIGHTS as LUMINANCE
from .partition import SuggestError

log = logging.getLogger(__name__)

ATTRIBUTES = ("group", "light", "depth", "object", "material", "scatter", "type", "curved", "textured", "shiny",
              "touches")
"""What an atom is made of, in the order splits are preferred when they score the same.
group: the emitter's light group ("group:<name>"; None for a light of no group, an
emissive object, the background); light: the emitter ("L:<light path>", "O:<object path>", "B"); depth: 0 (seen directly),
1 (direct: one bounce), 2 (indirect: more); then the first bounce's type (R, T, V),
scattering (D, G, S, s), object path, material path (None: no material), and "1" where its |S_C|,
|S_T|, |S_R| is not 0, "0" where it is. First-bounce values are None on a path without
bounces. touches: the sorted tuple of TOUCH tokens ("object:<path>", "material:<path>",
"asset:<path>") of every event of the path but the camera, at any bounce (an emissive
object it ends at included); a split on it is "touches X or not"."""
FIRST_BOUNCE = ATTRIBUTES[3:-1]
TOUCH_KINDS = ("object", "material", "asset")
"""What a path can touch, as token prefixes: a token is "<kind>:<prim path>"."""
COVARIANCE = {"curved": 0, "textured": 1, "shiny": 2}
"""Covariance attribute → its column of the index's norms (C, T, R)."""
TILES = 16
"""Tiles along each side of the image: the maps are TILES × TILES × RGB per frame."""
COVARIANCE_BITS = 1 << len(COVARIANCE)


@dataclass(frozen=True)
class Atoms:
    """The atoms of one or more indexes.

    keys  : (a,) tuples of ATTRIBUTES values, sorted (so the same input gives the same order)
    maps  : (a, f) float64: each atom's light per frame, tile and channel, every frame
            scaled so that its beauty's luminance sums to 1 (f = frames · TILES² · 3)
    names : value → display name (a light's or object's prim name, a material's); touch
            tokens too
    labels: value → the label an LPE tests for it (the prim path; an asset's: a glob of it
            and what is under it, "/World/shelf*")
    covariance : whether the indexes keep first-bounce norms (covariance splits possible)
    frames : the frames' descriptions, in feature order
    members : group value → the light values ("L:<path>") of the group, sorted: every light
              the indexes' manifests put in it, seen in a path or not (an LPE of the group
              lists them all, so it is exact)
    """

    keys: tuple[tuple, ...]
    maps: np.ndarray
    names: dict[str, str]
    labels: dict[str, str]
    covariance: bool
    frames: tuple[str, ...]
    members: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def values(self, attribute: str) -> list:
        column = ATTRIBUTES.index(attribute)
        return [key[column] for key in self.keys]

    def mattes(self) -> np.ndarray:
        """(a,) int64: each atom's ID matte, numbered in order of first appearance. What an
        ID matte (Cryptomatte) of the beauty tells apart is what the camera ray hits first:
        the first bounce's object, or for a path without bounces the emitter it sees."""
        light, depth, first = (ATTRIBUTES.index(name) for name in ("light", "depth", "object"))
        numbers: dict[tuple, int] = {}
        return np.array([numbers.setdefault(("object", key[first]) if key[depth] > 0 else ("emitter", key[light]),
                                            len(numbers)) for key in self.keys], np.int64)


@dataclass(frozen=True)
class _FrameAtoms:
    sums: dict[tuple, np.ndarray]  # atom key → (TILES², 3) float64 rgb, scaled
    names: dict[str, str]
    labels: dict[str, str]


def gather(indexes: Sequence[PathIndex], *, threads: int = 1) -> Atoms:
    """The atoms of every index, in a fixed order whatever the order of `indexes`
    (sorted by frame, then path)."""
    ordered = sorted(indexes, key=_frame_order)
    covariance = all(index.norm_slots >= 1 for index in ordered)
    group_of = light_groups(ordered)
    members: dict[str, list[str]] = {}
    for light, group in group_of.items():
        members.setdefault(group, []).append(light)
    frames = [_frame_atoms(index, covariance, threads, group_of) for index in ordered]
    keys = sorted({key for frame in frames for key in frame.sums}, key=_sortable)
    row = {key: number for number, key in enumerate(keys)}
    width = TILES * TILES * 3
    maps = np.zeros((len(keys), width * len(frames)))
    names, labels = {}, {}
    for number, frame in enumerate(frames):
        for key, tile_rgb in frame.sums.items():
            maps[row[key], number * width:(number + 1) * width] = tile_rgb.reshape(-1)
        names.update(frame.names)
        labels.update(frame.labels)
    for group, lights in members.items():
        names[group] = group.split(":", 1)[1]
        for light in lights:
            names.setdefault(light, light.rsplit("/", 1)[-1])
            labels.setdefault(light, light.split(":", 1)[1])
    return Atoms(tuple(keys), maps, names, labels, covariance, tuple(_frame_order(index)[2] for index in ordered),
                 {group: tuple(sorted(lights)) for group, lights in sorted(members.items())})


def light_groups(indexes: Sequence[PathIndex]) -> dict[str, str]:
    """Light value ("L:<prim path>") → group value ("group:<name>") of every light the
    indexes' manifests (``light_groups``) put in a group; {} for indexes that record none.
    Raises SuggestError when two indexes put one light in different groups."""
    found: dict[str, tuple[str, PathIndex]] = {}
    for index in indexes:
        for path, group in (index.manifest.get("light_groups") or {}).items():
            light, value = f"L:{path}", f"group:{group}"
            if light in found and found[light][0] != value:
                raise SuggestError(f"light {path} is in group {found[light][0][6:]!r} in {found[light][1].path.name} "
                                   f"and {group!r} in {index.path.name}: suggest frames of one shot")
            found.setdefault(light, (value, index))
    return {light: value for light, (value, _) in sorted(found.items())}


def _frame_order(index: PathIndex) -> tuple:
    frame = index.manifest.get("frame", "default")
    number = float(frame) if frame != "default" else float("-inf")
    return number, str(index.path), f"{index.path.name} (frame {frame})"


def _sortable(key: tuple) -> tuple:
    """None first, then values as strings: keys mix None, ints and strings."""
    return tuple(("", "") if value is None else ("~", str(value)) for value in key)


def _frame_atoms(index: PathIndex, covariance: bool, threads: int, group_of: dict[str, str]) -> _FrameAtoms:
    """One read of `index`: every atom's rgb per tile, scaled so the beauty's luminance is 1.
    group_of : light value → its group value (light_groups)."""
    names: dict[str, str] = {}
    labels: dict[str, str] = {}
    event_values = [_event_values(event, paths, names, labels)
                    for event, paths in zip(index.events, event_paths(index.events))]
    # Classes that agree on (first bounce, emitter, depth) are one atom up to the covariance
    # bits: group them once, so that records are keyed with one lookup.
    # Whole paths: each class's touches as a bit mask over the tokens of the index's events.
    tokens, event_bits = _touch_bits(index, event_values, names, labels)
    matrix = index.event_matrix(len(index.events))  # (classes, longest), padded with an id past the events
    lengths = (matrix != len(index.events)).sum(axis=1)  # events, the camera included
    rows = np.arange(len(matrix))
    first_event = np.where(lengths > 2, matrix[:, min(1, matrix.shape[1] - 1)], -1)
    end_event = matrix[rows, np.maximum(lengths - 1, 0)]
    depth = np.minimum(lengths - 2, 2)
    masks = np.bitwise_or.reduce(event_bits[matrix[:, 1:]], axis=1) if matrix.shape[1] > 1 else \
        np.zeros((len(matrix), event_bits.shape[1]), np.uint64)
    keyed = np.column_stack([first_event, end_event, depth, masks.view(np.int64)]) if len(matrix) else \
        np.zeros((0, 3 + event_bits.shape[1]), np.int64)
    groups, class_group = np.unique(keyed, axis=0, return_inverse=True)
    class_group = class_group.reshape(-1)
    group_depth = groups[:, 2]
    width, height = index.manifest["resolution"]
    tiles = TILES * TILES
    pixel_tile = ((np.arange(height) * TILES // height)[:, None] * TILES
                  + (np.arange(width) * TILES // width)[None, :]).reshape(-1)
    bins = len(groups) * COVARIANCE_BITS * tiles
    sums = np.zeros((3, bins))
    for chunk in index.records(norms=covariance, threads=threads):
        group = class_group[chunk.class_id]
        local = group * COVARIANCE_BITS
        if covariance:
            first = chunk.norms[:, 0, :] != 0  # event 1's C, T, R (NaN counts as not 0, as != does)
            bits = first[:, 0] | (first[:, 1] << 1) | (first[:, 2] << 2)
            local += np.where(group_depth[group] > 0, bits, 0)
        key = local * tiles + pixel_tile[chunk.pixel]
        for channel in range(3):
            sums[channel] += np.bincount(key, chunk.rgb[:, channel], bins)
    sums = sums.T.reshape(len(groups), COVARIANCE_BITS, tiles, 3)
    total = float(np.einsum("gbtc,c->", sums, LUMINANCE))
    if total > 0:
        sums /= total
    atoms: dict[tuple, np.ndarray] = {}
    for number, (first, end, depth, *mask) in enumerate(groups.tolist()):
        light = event_values[end]["light"]
        first_values = event_values[first] if depth > 0 else {}
        touched = tuple(sorted(token for bit, token in enumerate(tokens)
                               if (mask[bit // 64] >> (bit % 64)) & 1))
        for bits in range(COVARIANCE_BITS if covariance and depth > 0 else 1):
            values = {"group": group_of.get(light), "light": light, "depth": depth, "touches": touched,
                      **{name: first_values.get(name) for name in FIRST_BOUNCE}}
            for attribute, column in COVARIANCE.items():
                values[attribute] = (str(bits >> column & 1) if covariance else None) if depth > 0 else None
            key = tuple(values[name] for name in ATTRIBUTES)
            tile_rgb = sums[number, bits]
            if key in atoms:
                atoms[key] = atoms[key] + tile_rgb
            else:
                atoms[key] = tile_rgb
    log.debug("%s: %d atoms from %d classes", index.path.name, len(atoms), index.class_count)
    return _FrameAtoms(atoms, names, labels)


def _touch_bits(index: PathIndex, event_values: list[dict], names: dict[str, str],
                labels: dict[str, str]) -> tuple[list[str], np.ndarray]:
    """The touch tokens of the index's events (sorted) and (events + 1, words) uint64: each
    event's tokens as bits (the last row, the padding of event_matrix, none). Records each
    token's display name and LPE label in `names`, `labels`.

    An asset is the model root (manifest ``model_paths``) of an object, when it is neither
    the object itself nor a top-level prim; its label is the glob ``'<root>/*'``, and an event
    carries its token exactly when the LPE's glob matches one of the event's labels (an
    object, a material or a light under the root), so that atoms and expressions agree."""
    model_paths = index.manifest.get("model_paths") or ()
    objects = sorted({values["object"] for values in event_values if values.get("object")})
    roots = sorted({root for own, root in zip(objects, asset_roots(objects, model_paths))
                    if root != own and root.count("/") > 1})  # a top-level prim (/World) tells nothing apart
    event_tokens: list[list[str]] = []
    for event, values in zip(index.events, event_values):
        found = []
        own = values.get("object")
        if own:
            found.append(f"object:{own}")
            names[f"object:{own}"], labels[f"object:{own}"] = names[own], labels[own]
        material = values.get("material")
        if material:
            found.append(f"material:{material}")
            names[f"material:{material}"], labels[f"material:{material}"] = names[material], labels[material]
        for root in roots:
            if any(label.startswith(root + "/") for label in event.labels):
                token = f"asset:{root}"
                found.append(token)
                names[token], labels[token] = root.rsplit("/", 1)[-1], root + "/*"
        event_tokens.append(found)
    tokens = sorted({token for found in event_tokens for token in found})
    bit_of = {token: bit for bit, token in enumerate(tokens)}
    words = max(1, -(-len(tokens) // 64))
    bits = np.zeros((len(event_values) + 1, words), np.uint64)
    for event, found in enumerate(event_tokens):
        for token in found:
            bits[event, bit_of[token] // 64] |= np.uint64(1) << np.uint64(bit_of[token] % 64)
    return tokens, bits


def _event_values(event: Event, paths: tuple[str, str], names: dict[str, str], labels: dict[str, str]) -> dict:
    """The ATTRIBUTES values an event gives as a first bounce ("object", ...) or as the end
    ("light"); records each value's display name and LPE label in `names`, `labels`.
    paths : the event's (own path, material path), paths.events.event_paths."""
    own_path, material = paths
    own_path = own_path or event.name
    if event.type in "LO":
        value = f"{event.type}:{own_path}"
        names[value], labels[value] = event.name or own_path.rsplit("/", 1)[-1], own_path
        if event.type == "L":
            return {"light": value}
        names[own_path], labels[own_path] = names[value], own_path  # an emissive object is touched too
        named_material = _named_material(material, names, labels) if material else None
        return {"light": value, "object": own_path, "material": named_material}
    if event.type == "B":
        names["B"] = "background"
        return {"light": "B"}
    material = _named_material(material, names, labels) if material else None
    names[own_path], labels[own_path] = event.name or own_path.rsplit("/", 1)[-1], own_path
    return {"type": event.type, "scatter": event.scatter, "object": own_path, "material": material}


def _named_material(material: str, names: dict[str, str], labels: dict[str, str]) -> str:
    names[material], labels[material] = material.rsplit("/", 1)[-1], material
    return material


def luminance(maps: np.ndarray) -> np.ndarray:
    """(…, f) rgb features → (…, f / 3) luminance per frame and tile."""
    return maps.reshape(*maps.shape[:-1], -1, 3) @ LUMINANCE
