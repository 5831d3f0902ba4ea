"""Observers of the integrator's stages: the path index's recorder and the first-bounce
covariance pictures.

The integrator hands every observer each stage's results (``escaped``, ``emitted``, ``lit``,
``scattered``); an observer that is not there costs nothing, and the integrator has no
branch on what is recorded.

``PathRecorder`` owns the event vocabulary's ids, the prefix tree of path classes
(``ClassTrie``, compiled) and the per-event covariance norms (``EventNorms``): a path
carries its class as one trie node and its norms as one row linked to its previous
event's, both kept in the PathQueue's ``node`` and ``row`` columns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..paths import events
from ..paths.events import EventVocabulary
from ..scene import FLOAT
from . import bsdf
from .bounce_norms import lobe_reflectance
from .compiled import inline, kernel
from .stages.queues import PathQueue, ShadowQueue, Splats, SurfaceQueue
from .stages.scatter import Scattering


@dataclass
class Contributions:
    """Every contribution of a batch, in the order the tracer made them.

    pixel  : (r,) int64; sample : (r,) int32; rgb : (r, 3) float32 (what the film adds)
    path_class : (r,) int64 index into ``sequences``
    norms  : (r, N, 3) float32 C, T, R of events 1..N after the camera (0 past the end)
    sequences : the batch's path classes, each its event ids after the camera (paths/events.py)
    """

    pixel: np.ndarray
    sample: np.ndarray
    rgb: np.ndarray
    path_class: np.ndarray
    norms: np.ndarray
    sequences: list[tuple[int, ...]]


class Observer:
    """Does nothing with any stage's results; subclasses pick what they watch."""

    def wants_norms(self, step: int) -> bool:
        """Whether the surfaces of bounce `step` need their covariance norms C and T."""
        return False

    def escaped(self, queue: PathQueue, splats: Splats) -> None:
        pass

    def emitted(self, queue: PathQueue, splats: Splats) -> None:
        pass

    def lit(self, queue: PathQueue, surfaces: SurfaceQueue, shadows: ShadowQueue) -> None:
        """Light samples, with their visibility (called before ``scattered`` at the same vertex)."""

    def scattered(self, queue: PathQueue, surfaces: SurfaceQueue, scattering: Scattering, step: int) -> None:
        pass


class PathRecorder(Observer):
    """Keeps every contribution of one batch with its path class and event norms."""

    def __init__(self, vocabulary: EventVocabulary, triangle_subject: np.ndarray, triangle_light: np.ndarray,
                 slots: int):
        self.vocabulary = vocabulary
        self.triangle_subject = triangle_subject  # (t,) int64 surface subject of each triangle
        self.triangle_light = triangle_light
        self.slots = slots
        self.classes = ClassTrie()
        self.norms = EventNorms()
        self._records: list[tuple[np.ndarray, ...]] = []

    def wants_norms(self, step: int) -> bool:
        return self.slots > 0

    def _surface_event(self, triangle, event_type, scatter, lobe) -> np.ndarray:
        return self.vocabulary.ids(event_type, scatter, lobe, np.take(self.triangle_subject, triangle))

    def _light_event(self, light: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """L for a light (or its shape), O for an emissive surface's triangle."""
        light_event = self.vocabulary.ids(events.LIGHT, events.NO_SCATTER, events.NO_LOBE,
                                          self.vocabulary.light_subject(np.maximum(light, 0)))
        if (light >= 0).all():
            return light_event
        surface = self._surface_event(np.maximum(triangle, 0), events.OBJECT, events.NO_SCATTER, events.NO_LOBE)
        return np.where(light >= 0, light_event, surface)

    def _record(self, queue: PathQueue, lanes: np.ndarray, rgb: np.ndarray, node: np.ndarray, row: np.ndarray):
        self._records.append((queue.pixel[lanes], queue.sample[lanes], rgb.astype(FLOAT, copy=False), node, row))

    def escaped(self, queue: PathQueue, splats: Splats) -> None:
        self.emitted(queue, splats)

    def emitted(self, queue: PathQueue, splats: Splats) -> None:
        if not len(splats):
            return
        node = self.classes.extend(queue.node[splats.lane], self._light_event(splats.light, splats.triangle))
        self._record(queue, splats.lane, splats.rgb, node, queue.row[splats.lane])

    def lit(self, queue: PathQueue, surfaces: SurfaceQueue, shadows: ShadowQueue) -> None:
        shadows = shadows.take(np.flatnonzero(shadows.visible))
        if not len(shadows):
            return
        light_event = self._light_event(shadows.light, shadows.triangle)  # the same for every lobe
        for lobe in bsdf.GLOSSY_LOBES:
            rgb = shadows.radiance[:, lobe]
            active = np.flatnonzero((rgb != 0).any(axis=1))
            if not len(active):
                continue
            lanes = shadows.lane[active]
            scatter = bsdf.SCATTER_DIFFUSE if lobe == bsdf.DIFFUSE else bsdf.SCATTER_GLOSSY
            surface = self._surface_event(surfaces.triangle[lanes], events.REFLECT, scatter, lobe)
            node = self.classes.extend(self.classes.extend(queue.node[lanes], surface), light_event[active])
            row = queue.row[lanes]
            if self.slots:
                reflectance = lobe_reflectance(surfaces.lobes[lanes], np.full(len(lanes), lobe, np.int8))
                row = self.norms.append(row, surfaces.curvature[lanes], surfaces.texture[lanes], reflectance)
            self._record(queue, lanes, rgb[active], node, row)

    def scattered(self, queue: PathQueue, surfaces: SurfaceQueue, scattering: Scattering, step: int) -> None:
        """Append this vertex's event to every continuing path: its sampled lobe, or a
        straight pass (no operator, norms 0) for cut-outs."""
        lanes = np.flatnonzero(scattering.scattered | surfaces.cut)
        if not len(lanes):
            return
        passes = surfaces.cut[lanes]
        lobe = np.where(passes, events.NO_LOBE, scattering.lobe[lanes])
        event_type = np.where(passes | scattering.transmit[lanes], events.TRANSMIT, events.REFLECT)
        event = self._surface_event(surfaces.triangle[lanes], event_type, scattering.scatter[lanes], lobe)
        queue.node[lanes] = self.classes.extend(queue.node[lanes], event)
        if self.slots:
            reflectance = np.where(passes, 0.0, lobe_reflectance(surfaces.lobes[lanes], scattering.lobe[lanes]))
            queue.row[lanes] = self.norms.append(queue.row[lanes], np.where(passes, 0.0, surfaces.curvature[lanes]),
                                                 np.where(passes, 0.0, surfaces.texture[lanes]), reflectance)

    def result(self) -> Contributions:
        slots = self.slots
        if not self._records:
            return Contributions(np.zeros(0, np.int64), np.zeros(0, np.int32), np.zeros((0, 3), FLOAT),
                                 np.zeros(0, np.int64), np.zeros((0, slots, 3), FLOAT), [])
        pixel, sample, rgb, node, row = (np.concatenate(column) for column in zip(*self._records))
        nodes, path_class = np.unique(node, return_inverse=True)
        norms = self.norms.first_events(row, slots)
        return Contributions(pixel, sample, rgb, path_class.reshape(-1), norms, self.classes.sequences(nodes))


class FirstBounceNorms(Observer):
    """Per-pixel sums of the first bounce's C, T, R over the samples whose first event
    scatters (the --debug-covariance pictures): sums (k, 3) float64, count (k,)."""

    def __init__(self, first_pixel: int, pixel_count: int):
        self.first_pixel = first_pixel
        self.sums = np.zeros((pixel_count, 3))
        self.count = np.zeros(pixel_count)

    def wants_norms(self, step: int) -> bool:
        return step == 0

    def scattered(self, queue: PathQueue, surfaces: SurfaceQueue, scattering: Scattering, step: int) -> None:
        if step != 0:
            return
        lanes = np.flatnonzero(scattering.scattered)
        where = queue.pixel[lanes] - self.first_pixel
        reflectance = lobe_reflectance(surfaces.lobes[lanes], scattering.lobe[lanes])
        for norm, values in enumerate((surfaces.curvature[lanes], surfaces.texture[lanes], reflectance)):
            self.sums[:, norm] += np.bincount(where, weights=values, minlength=len(self.count))
        self.count += np.bincount(where, minlength=len(self.count))


class ClassTrie:
    """Prefix tree of event ids: every distinct event sequence (path class) is one node.

    Node 0 is the camera (the empty sequence after C). ``extend`` moves many paths one
    event further at once through a compiled open-addressing table of (parent, event)
    edges. New nodes are numbered in the order lanes first ask for them, so a batch traced
    the same way numbers its classes the same way.
    """

    def __init__(self) -> None:
        self.parent = np.full(64, -1, np.int64)
        self.event = np.zeros(64, np.int64)
        self.size = 1
        self._keys = np.full(256, -1, np.int64)  # parent << 32 | event, −1 = empty
        self._children = np.zeros(256, np.int64)

    def __len__(self) -> int:
        return self.size

    def extend(self, node: np.ndarray, event: np.ndarray) -> np.ndarray:
        """Children of node (n,) by event id (n,), created as needed -> (n,) int64."""
        needed = self.size + len(node)
        if needed > len(self.parent):
            capacity = max(needed, 2 * len(self.parent))
            self.parent = np.concatenate([self.parent, np.full(capacity - len(self.parent), -1, np.int64)])
            self.event = np.concatenate([self.event, np.zeros(capacity - len(self.event), np.int64)])
        if 2 * needed > len(self._keys):
            capacity = len(self._keys)
            while capacity < 2 * needed:
                capacity *= 2
            self._keys, self._children = _rehashed(self._keys, self._children, capacity)
        children = np.empty(len(node), np.int64)
        self.size = _extend_kernel(self._keys, self._children, self.parent, self.event, self.size,
                                   np.asarray(node, np.int64), np.asarray(event, np.int64), children)
        return children

    def sequences(self, nodes: np.ndarray) -> list[tuple[int, ...]]:
        """The event ids from the first event after the camera to each of `nodes`."""
        chains = []
        current = np.asarray(nodes, np.int64)
        while (current > 0).any():  # one level of all chains at a time
            chains.append(np.where(current > 0, self.event[current], -1))
            current = np.where(current > 0, self.parent[np.maximum(current, 0)], 0)
        if not chains:
            return [() for _ in range(len(current))]
        table = np.stack(chains[::-1], axis=1)  # (nodes, depth), left-padded with −1
        return [tuple(event for event in row if event >= 0) for row in table.tolist()]


_EVENT_BITS = 32
_HASH = np.uint64(0x9E3779B97F4A7C15)


@inline
def _slot(key, mask):
    return np.int64((np.uint64(key) * _HASH) >> np.uint64(40)) & mask


@kernel
def _extend_kernel(keys, children, parent, event, size, node, event_in, out):
    mask = len(keys) - 1
    for lane in range(len(node)):
        key = (node[lane] << _EVENT_BITS) | event_in[lane]
        slot = _slot(key, mask)
        while True:
            found = keys[slot]
            if found == key:
                out[lane] = children[slot]
                break
            if found == -1:
                keys[slot] = key
                children[slot] = size
                parent[size], event[size] = node[lane], event_in[lane]
                out[lane] = size
                size += 1
                break
            slot = (slot + 1) & mask
    return size


def _rehashed(keys: np.ndarray, children: np.ndarray, capacity: int) -> tuple[np.ndarray, np.ndarray]:
    new_keys, new_children = np.full(capacity, -1, np.int64), np.zeros(capacity, np.int64)
    _rehash_kernel(keys, children, new_keys, new_children)
    return new_keys, new_children


@kernel
def _rehash_kernel(keys, children, new_keys, new_children):
    mask = len(new_keys) - 1
    for old in range(len(keys)):
        key = keys[old]
        if key == -1:
            continue
        slot = _slot(key, mask)
        while new_keys[slot] != -1:
            slot = (slot + 1) & mask
        new_keys[slot], new_children[slot] = key, children[old]


class EventNorms:
    """C, T, R of every event of a batch's paths, as rows linked to the path's previous
    event: a path keeps one row number instead of N norms, and a record's N slots are
    gathered once, when the batch ends."""

    def __init__(self) -> None:
        self.parent = np.zeros(1024, np.int64)
        self.values = np.zeros((1024, 3), FLOAT)
        self.size = 0

    def append(self, parent: np.ndarray, curvature, texture, reflectance) -> np.ndarray:
        """New rows after `parent` (k,) rows; C, T, R (k,). Returns their ids."""
        count = len(parent)
        if self.size + count > len(self.parent):
            capacity = max(self.size + count, 2 * len(self.parent))
            self.parent = np.resize(self.parent, capacity)
            self.values = np.resize(self.values, (capacity, 3))
        rows = slice(self.size, self.size + count)
        self.parent[rows] = parent
        self.values[rows, 0], self.values[rows, 1], self.values[rows, 2] = curvature, texture, reflectance
        self.size += count
        return np.arange(rows.start, rows.stop, dtype=np.int64)

    def first_events(self, rows: np.ndarray, slots: int) -> np.ndarray:
        """(r, slots, 3) norms of events 1..slots of the paths ending at `rows` (zeros past
        a path's last event)."""
        out = np.zeros((len(rows), slots, 3), FLOAT)
        if slots:
            _first_events_kernel(self.parent, self.values, rows, out)
        return out


@kernel
def _first_events_kernel(parent, values, rows, out):
    slots = out.shape[1]
    for record in range(len(rows)):
        depth = 0
        row = rows[record]
        while row >= 0:
            depth += 1
            row = parent[row]
        row = rows[record]
        position = depth - 1  # the last event's slot
        while row >= 0:
            if position < slots:
                out[record, position, 0] = values[row, 0]
                out[record, position, 1] = values[row, 1]
                out[record, position, 2] = values[row, 2]
            position -= 1
            row = parent[row]
