"""What a pixel or a region is made of: the path classes of its records, grouped, with the
distribution of each bounce's covariance norms, and LPEs that select them.

Plain functions over a :class:`~pxr_layers.paths.reader.PathIndex`; the server turns their
results into JSON. Chunks are cut by class, so every chunk holds pixels all over the image:
a selection's records are found by a pass over the sums of every chunk, then a read of the
chunks it found them in (:func:`select`).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from ..layers.previews import LUMINANCE_WEIGHTS as LUMINANCE
from ..paths.events import SCATTERING_TYPES, Event, path_text
from ..paths.reader import PathClass, PathIndex

TOP_CLASSES = 50
"""Classes listed for a selection, by share."""
NORM_OCTAVES = (-32, 32)
"""The norm histograms' range, as powers of 2 (2^-32 to 2^32: norms of real scenes lie well
inside), one bin an octave, values outside counted in the first and last bins, 0 on its own.
A merged index keeps norms by octave (paths.format.NormBins): these bins hold exactly its values."""
NORM_QUANTITIES = ("C", "T", "R")
ASPECTS = ("light", "first_object", "first_material", "first_scattering", "scattering", "bounces")
"""What :func:`generalise` can keep of the classes it is given."""


@dataclass(frozen=True)
class ClassInfo:
    """One path class as the inspector shows it.

    path : the path notation (``C RD'redWall' L'ceilingLight'``); lpe : an expression that
    matches it (its events' types, scatterings and names); light : the name of its last
    event (light, emissive object; "" for the background); first_object, first_material :
    of its first bounce ("" when it has none, or no material); scattering : the bounces'
    scattering letters, camera first (``"D G"``); bounces : R/T/V events
    """

    id: int
    path: str
    lpe: str
    light: str
    end_type: str
    first_type: str
    first_object: str
    first_material: str
    scattering: str
    bounces: int


def describe(path_class: PathClass, paths: Sequence[tuple[str, str]]) -> ClassInfo:
    """paths : paths.events.event_paths of the index's event table."""
    events = path_class.events
    middle = [(event, event_id) for event, event_id in zip(events[1:-1], path_class.event_ids[1:-1])
              if event.type in SCATTERING_TYPES]
    first, first_id = middle[0] if middle else (None, None)
    end = events[-1]
    return ClassInfo(
        id=path_class.id, path=path_text(events), lpe="".join(_event_lpe(event) for event in events),
        light=end.name, end_type=end.type, first_type=first.type if first else "",
        first_object=first.name if first else "",
        first_material=paths[first_id][1].rsplit("/", 1)[-1] if first else "",
        scattering=" ".join(event.scatter for event, _ in middle), bounces=len(middle))


def _event_lpe(event: Event) -> str:
    """``<RD'redWall'>``, ``<L.'key'>``, ``B``: one event, by type, scattering and name."""
    if event.type == "C" or (event.type == "B" and not event.name):
        return event.type
    name = f"'{event.name}'" if event.name else ""
    return f"<{event.type}{event.scatter or '.'}{name}>"


@dataclass(frozen=True)
class Selection:
    """The records of a pixel rectangle. class_id : (r,) int64; rgb : (r, 3) float64 summed
    film contributions; norms : (r, N, 3) float32 per bounce C, T, R; pixels : its pixel count."""

    class_id: np.ndarray
    rgb: np.ndarray
    norms: np.ndarray
    pixels: int


def select(index: PathIndex, x0: int, y0: int, x1: int, y1: int, *, threads: int = 1) -> Selection:
    """The records of pixels x0 ≤ x < x1, y0 ≤ y < y1 (image coordinates, top row 0),
    clipped to the image.

    Two passes: the pixels of every chunk find the chunks with records in the rectangle and
    their classes (no light nor covariance decoded), then only those chunks are read, and in
    them only the runs of those classes. A chunk
    holds a run of a class's records in pixel order, so a click's records lie in a few.
    """
    width, height = index.manifest["resolution"]
    x0, x1 = max(0, x0), min(width, x1)
    y0, y1 = max(0, y0), min(height, y1)
    pixels = max(0, x1 - x0) * max(0, y1 - y0)
    empty = Selection(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, index.norm_slots, 3), np.float32), pixels)
    if not pixels:
        return empty

    first, span = y0 * width + x0, (y1 - 1) * width + x1 - (y0 * width + x0)

    def inside(pixel: np.ndarray) -> np.ndarray:
        """(r,) bool: in the rectangle. pixel: (r,) int64. The rows' range first, in one
        comparison (below it, pixel − first wraps to a huge unsigned value): a click tests
        every record of the index, the columns only those few in range."""
        hit = (pixel - first).view(np.uint64) < np.uint64(span)
        if x1 - x0 < width and hit.any():
            at = np.flatnonzero(hit)
            column = pixel[at] % width
            hit[at[(column < x0) | (column >= x1)]] = False
        return hit

    present: set[int] = set()
    hit_chunks = []
    for number, chunk in enumerate(index.records(norms=False, light=False, threads=threads)):  # every chunk's pixels
        hit = inside(chunk.pixel)
        if hit.any():
            present.update(np.unique(chunk.class_id[hit]).tolist())
            hit_chunks.append(number)
    if not present:
        return empty
    kept = []
    for chunk in index.records(sorted(present), threads=threads, chunks=hit_chunks):
        hit = inside(chunk.pixel)
        kept.append((chunk.class_id[hit], chunk.rgb[hit], chunk.norms[hit]))
    return Selection(np.concatenate([k[0] for k in kept]), np.concatenate([k[1] for k in kept]).astype(np.float64),
                     np.concatenate([k[2] for k in kept]), pixels)


def summary(selection: Selection, infos: Sequence[ClassInfo]) -> dict:
    """The inspector's view of a selection (JSON-able): classes by share, groups, norms.

    Shares are of the selection's summed Rec.709 luminance; ``rgb`` and ``energy`` are per
    pixel, on the beauty's scale only up to the index's spp (the caller divides).
    """
    ids, inverse = np.unique(selection.class_id, return_inverse=True)
    luminance = selection.rgb @ LUMINANCE
    class_energy = np.bincount(inverse, weights=luminance, minlength=len(ids))
    class_records = np.bincount(inverse, minlength=len(ids))
    class_rgb = np.stack([np.bincount(inverse, weights=selection.rgb[:, c], minlength=len(ids)) for c in range(3)], -1)
    total = float(class_energy.sum())

    def share(energy: float) -> float:
        return energy / total if total > 0 else 0.0

    order = np.argsort(-class_energy, kind="stable")
    classes = [
        {"id": int(ids[k]), "path": infos[ids[k]].path, "lpe": infos[ids[k]].lpe, "share": share(class_energy[k]),
         "records": int(class_records[k]), "rgb": class_rgb[k].tolist(), "light": infos[ids[k]].light,
         "first_object": infos[ids[k]].first_object, "first_material": infos[ids[k]].first_material,
         "scattering": infos[ids[k]].scattering, "bounces": infos[ids[k]].bounces}
        for k in order[:TOP_CLASSES]]
    groups = {}
    for aspect in ("light", "first_object", "first_material", "scattering"):
        energy: dict[str, float] = defaultdict(float)
        records: dict[str, int] = defaultdict(int)
        members: dict[str, list[int]] = defaultdict(list)
        for k, class_id in enumerate(ids.tolist()):
            key = getattr(infos[class_id], aspect)
            energy[key] += class_energy[k]
            records[key] += int(class_records[k])
            members[key].append(class_id)
        groups[aspect] = [
            {"key": key, "share": share(energy[key]), "records": records[key],
             "lpe": generalise([infos[i] for i in members[key]], [aspect])}
            for key in sorted(energy, key=lambda key: -energy[key])]
    return {"records": int(len(selection.class_id)), "energy_total": total, "rgb_total": class_rgb.sum(0).tolist(),
            "classes": classes, "groups": groups, "norms": norm_histograms(selection, infos, luminance)}


def norm_histograms(selection: Selection, infos: Sequence[ClassInfo], weights: np.ndarray) -> dict:
    """Energy-weighted histograms of each kept bounce's C, T, R over the selection: one bin
    an octave over NORM_OCTAVES (``edges``: 2^k), exact zeros apart. A record counts at
    bounce b only if its path has a b-th event after the camera."""
    low, high = NORM_OCTAVES
    edges = [2.0 ** k for k in range(low, high + 1)]
    lengths = np.array([info.bounces + 1 for info in infos], np.int64)  # the bounces and the end event
    events_after_camera = lengths[selection.class_id]
    bounces = []
    for slot in range(selection.norms.shape[1]):
        has_event = events_after_camera > slot
        entry = {"bounce": slot + 1, "zero": {}}
        for q, quantity in enumerate(NORM_QUANTITIES):
            values = selection.norms[has_event, slot, q].astype(np.float64)
            weight = weights[has_event]
            zero = values == 0
            octave = np.clip(np.floor(np.log2(np.where(zero, 1.0, values))), low, high - 1).astype(np.int64) - low
            entry[quantity] = np.bincount(octave[~zero], weights=weight[~zero], minlength=high - low).tolist()
            entry["zero"][quantity] = float(weight[zero].sum())
        bounces.append(entry)
    return {"edges": edges, "bounces": bounces}


def generalise(infos: Iterable[ClassInfo], keep: Iterable[str]) -> str:
    """One LPE matching every class of `infos`, keeping only the aspects in `keep`
    (ASPECTS); nothing kept: the union of their own LPEs.

    Each class becomes ``C <first bounce> <middle> <end>`` where the first bounce keeps its
    type and scattering (first_scattering) and its object/material names (first_object,
    first_material), the middle is every bounce's scattering (scattering), ``.{n-1}``
    (bounces) or ``.*``, and the end keeps its light's name (light) or is any event. Distinct patterns are joined with ``|``, in the
    order of the classes.
    """
    keep = set(keep)
    unknown = keep - set(ASPECTS)
    if unknown:
        raise ValueError(f"cannot keep {', '.join(sorted(unknown))} (aspects: {', '.join(ASPECTS)})")
    patterns: list[str] = []
    for info in infos:
        pattern = info.lpe if not keep else _generalised(info, keep)
        if pattern not in patterns:
            patterns.append(pattern)
    return "|".join(patterns)


def _generalised(info: ClassInfo, keep: set[str]) -> str:
    end = _end_pattern(info, "light" in keep)
    if info.bounces == 0:
        return "C" + end
    labels = "".join(f"'{name}'" for aspect, name in (("first_object", info.first_object),
                                                        ("first_material", info.first_material))
                     if aspect in keep and name)
    scatterings = info.scattering.split(" ")
    if "first_scattering" in keep:
        first = f"<{info.first_type}{scatterings[0]}{labels}>"
    elif "scattering" in keep:
        first = f"<.{scatterings[0]}{labels}>"
    else:
        first = f"<..{labels}>" if labels else "."
    if "scattering" in keep:  # every bounce's scattering, so their number too
        return "C" + first + "".join(f"<.{scattering}>" for scattering in scatterings[1:]) + end
    if "bounces" in keep:
        return "C" + first + (f".{{{info.bounces - 1}}}" if info.bounces > 1 else "") + end
    if first == ".":  # only the light kept: every path to it, a class without bounces too
        return "C.*" + end
    return "C" + first + (".+" if end == "." else ".*" + end)


def _end_pattern(info: ClassInfo, keep_light: bool) -> str:
    if not keep_light:
        return "."
    if info.end_type == "B":
        return "B"
    return f"<{info.end_type}.'{info.light}'>" if info.light else f"<{info.end_type}.>"
