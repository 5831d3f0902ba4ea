"""Observers of the integrator's stages (stages/observer.py) that watch paths: the path
index's recorder and the first-bounce covariance pictures.

``PathRecorder`` owns the event vocabulary's ids, the prefix tree of path classes
(``paths/trie.py``, compiled) and the per-event covariance norms (``EventNorms``): a path
carries its class as one trie node and its norms as one row linked to its previous
event's, both kept in the PathQueue's ``node`` and ``row`` columns. With Σ asked for, each
row also keeps its vertex's world-space data and each record its light end (sigma.py),
recorded beside the kernels' own rows (the kernels are the same either way).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..paths import events
from ..paths import format as fmt
from ..paths.events import EventVocabulary
from ..paths.trie import ClassTrie, class_sequences
from ..paths.trie import child as trie_child
from ..scene import FLOAT
from .bounce_norms import lobe_reflectance, reflectance
from ..compiled import inline, kernel
from .stages.observer import Observer
from .stages.queues import PathQueue, ShadowQueue, Splats, SurfaceQueue
from .stages.scatter import Scattering
from .sigma import (EmitterTable, SigmaInputs, SigmaLightEnds, SigmaVertices, emitter_hit_distance, record_sigma,
                    shadow_distance)
from . import bsdf
from . import sigma as sigma_rows


@dataclass
class Contributions:
    """Every contribution of a batch, in the order the tracer made them.

    pixel  : (r,) int64; sample : (r,) int32; rgb : (r, 3) float32 (what the film adds)
    path_class : (r,) int64 index into ``class_nodes``
    norms  : (r, N, 3) float16 C, T, R of events 1..N after the camera (0 past the end),
             as the index stores them
    class_nodes : (k,) int64 each class's node in the batch's trie, whose nodes are
             trie_parent, trie_event (m,) int64 (node 0 the camera; a parent's number is
             below its children's): plain arrays, so a writer merges them without
             building the event sequences of classes it already knows
    sigma  : (r, N, 10) float32 or None (without ``TraceSettings.record_sigma``): for
             events 1..N after the camera (the slots of ``norms``), the upper triangle
             xx xy xu xv yy yu yv uu uv vv of the covariance Σ of the light LEAVING the
             event's vertex toward the eye (after the inverse projection, before the
             travel), in the amplitude convention of ``pxr_layers.covariance``:
             cycles²/m² (x, y), cycles²/rad² (u, v), cycles²/(m·rad) mixed; zeros past the
             path's last event and for pass-through and light events. Frame: ẑ = toward
             the eye; x̂ ⟂ the plane of (ẑ, shading normal), a tangent direction not
             foreshortened by the view; ŷ = ẑ × x̂ in that plane (the axis 1/|cos θo|
             stretches); its sign is irrelevant to Σ. Head-on (ẑ ∥ normal) x̂ is the
             arriving frame's. Each record is its own chain from its light end; emitter
             and lobe models in trace/sigma.py
    """

    pixel: np.ndarray
    sample: np.ndarray
    rgb: np.ndarray
    path_class: np.ndarray
    norms: np.ndarray
    class_nodes: np.ndarray
    trie_parent: np.ndarray
    trie_event: np.ndarray
    sigma: np.ndarray | None = None

    @property
    def sequences(self) -> list[tuple[int, ...]]:
        """Each class's event ids after the camera (paths/events.py)."""
        return class_sequences(self.trie_parent, self.trie_event, self.class_nodes)


class PathRecorder(Observer):
    """Keeps every contribution of one batch with its path class and event norms; each
    stage's results are recorded by one compiled kernel."""

    def __init__(self, vocabulary: EventVocabulary, triangle_subject: np.ndarray, slots: int, paths: int,
                 sigma: SigmaInputs | None = None):
        self.triangle_subject = triangle_subject  # (t,) int64 surface subject of each triangle
        self.subject_count = vocabulary.subject_count
        self.light_offset = len(vocabulary.surface_objects)  # light L's subject: light_offset + L
        self.slots = slots
        # Sized for a batch of `paths` paths (about 1.5 records and 4 events per path): they
        # grow when a batch needs more.
        self.classes = ClassTrie(paths)
        self.norms = EventNorms(4 * paths)
        self.records = RecordBuffer(2 * paths)
        # Σ (sigma.py): only with norms to hang its rows on; nothing allocated otherwise
        self.sigma = sigma if slots > 0 else None
        if self.sigma is not None:
            self.vertices = SigmaVertices(4 * paths)
            self.light_ends = SigmaLightEnds(2 * paths)

    def wants_norms(self, step: int) -> bool:
        return self.slots > 0

    def escaped(self, queue: PathQueue, splats: Splats) -> None:
        self.emitted(queue, splats)

    def emitted(self, queue: PathQueue, splats: Splats) -> None:
        trie, records = self.classes.reserve(len(splats)), self.records.reserve(len(splats))
        first_record = self.records.count
        self.classes.size, self.records.count = _record_emitted(
            splats.lane, splats.light, splats.triangle, splats.rgb, queue.pixel, queue.sample, queue.node, queue.row,
            self.triangle_subject, self.subject_count, self.light_offset, *trie, *records)
        if self.sigma is not None and len(splats):  # a record per splat, in order
            lane = splats.lane
            direction = queue.direction[lane]
            distance = emitter_hit_distance(self.sigma.world, splats.triangle, queue.origin[lane], direction,
                                            queue.travelled[lane] - queue.vertex_travelled[lane])
            self.light_ends.add(first_record, splats.light, splats.triangle, -direction, distance)

    def lit(self, queue: PathQueue, surfaces: SurfaceQueue, shadows: ShadowQueue) -> None:
        most = 3 * len(shadows)  # a record (and two classes) per glossy lobe
        trie, records = self.classes.reserve(2 * most), self.records.reserve(most)
        norms = self.norms.reserve(most)
        first_row, first_record = self.norms.size, self.records.count
        self.classes.size, self.norms.size, self.records.count = _record_lit(
            shadows.lane, shadows.light, shadows.triangle, shadows.radiance, shadows.visible, surfaces.triangle,
            surfaces.lobes, surfaces.curvature, surfaces.texture, queue.pixel, queue.sample, queue.node, queue.row,
            self.triangle_subject, self.subject_count, self.light_offset, self.slots > 0, *trie, *norms, *records)
        if self.sigma is not None and self.records.count > first_record:
            # _record_lit's order: visible entries, then their lobes with light; a row per record
            entry, _ = np.nonzero(shadows.visible[:, None] & (shadows.radiance != 0).any(axis=2))
            lanes = shadows.lane[entry]
            self.vertices.add(first_row, lanes, queue.travelled, surfaces, sigma_rows.REFLECT, self.sigma.ray_cone)
            self.light_ends.add(first_record, shadows.light[entry], shadows.triangle[entry],
                                -shadows.direction[entry], shadow_distance(shadows.t_max[entry]))

    def scattered(self, queue: PathQueue, surfaces: SurfaceQueue, scattering: Scattering, step: int) -> None:
        """Append this vertex's event to every continuing path: its sampled lobe, or a
        straight pass (no operator, norms 0) for cut-outs."""
        trie, norms = self.classes.reserve(len(queue)), self.norms.reserve(len(queue))
        first_row = self.norms.size
        self.classes.size, self.norms.size = _record_scattered(
            scattering.scattered, surfaces.cut, scattering.lobe, scattering.scatter, scattering.transmit,
            surfaces.triangle, surfaces.lobes, surfaces.curvature, surfaces.texture, queue.node, queue.row,
            self.triangle_subject, self.subject_count, self.slots > 0, *trie, *norms)
        if self.sigma is not None and self.norms.size > first_row:  # a row per passing or scattered lane
            passes = surfaces.cut
            lanes = np.flatnonzero(passes | scattering.scattered)
            kind = np.where(passes[lanes], sigma_rows.PASS,
                            np.where(scattering.transmit[lanes], sigma_rows.TRANSMIT, sigma_rows.REFLECT))
            self.vertices.add(first_row, lanes, queue.travelled, surfaces, kind, self.sigma.ray_cone)

    def result(self) -> Contributions:
        """The batch's contributions; norms already as the index stores them (float16)."""
        pixel, sample, rgb, node, row = self.records.arrays()
        trie = self.classes
        # np.unique(node, return_inverse=True), compiled (it would hold the GIL to sort)
        class_of_node = np.empty(trie.size, np.int64)
        path_class = np.empty(len(node), np.int64)
        classes = _dense_classes(node, class_of_node, path_class)
        nodes = np.flatnonzero(class_of_node >= 0)[:classes]
        norms = self.norms.first_events(row, self.slots)
        sigma = None
        if self.sigma is not None:
            sigma = record_sigma(self.sigma, EmitterTable(self.sigma.world, self.sigma.lights), row,
                                 self.norms.parent[:self.norms.size], self.norms.values[:self.norms.size, 2],
                                 self.vertices, self.light_ends.first(self.records.count), self.slots)
        return Contributions(pixel, sample, rgb, path_class, norms, nodes, trie.parent[:trie.size].copy(),
                             trie.event[:trie.size].copy(), sigma)


_event_id = inline(events.event_id)


@inline
def _surface_event(triangle_subject, subject_count, event_type, scatter, lobe, triangle):
    return _event_id(event_type, scatter, lobe, triangle_subject[triangle], subject_count)


@inline
def _emitter_event(triangle_subject, subject_count, light_offset, light, triangle):
    """L for a light (or its shape), O for an emissive surface's triangle."""
    if light >= 0:
        return _event_id(events.LIGHT, events.NO_SCATTER, events.NO_LOBE, light_offset + light, subject_count)
    return _surface_event(triangle_subject, subject_count, events.OBJECT, events.NO_SCATTER, events.NO_LOBE, triangle)


@inline
def _add_record(r_pixel, r_sample, r_rgb, r_node, r_row, count, pixel, sample, r, g, b, node, row):
    r_pixel[count], r_sample[count], r_node[count], r_row[count] = pixel, sample, node, row
    r_rgb[count, 0], r_rgb[count, 1], r_rgb[count, 2] = r, g, b
    return count + 1


@inline
def _add_norms(n_parent, n_values, n_size, parent, curvature, texture, reflectance_norm):
    n_parent[n_size] = parent
    n_values[n_size, 0], n_values[n_size, 1], n_values[n_size, 2] = curvature, texture, reflectance_norm
    return n_size + 1


@kernel
def _dense_classes(node, class_of_node, path_class):
    """Number the trie nodes that records use 0, 1, ... in node order (class_of_node, −1
    for the others) and give each record its number (path_class); returns the count."""
    class_of_node[:] = -1
    for record in range(len(node)):
        class_of_node[node[record]] = 0
    classes = 0
    for trie_node in range(len(class_of_node)):
        if class_of_node[trie_node] == 0:
            class_of_node[trie_node] = classes
            classes += 1
    for record in range(len(node)):
        path_class[record] = class_of_node[node[record]]
    return classes


@kernel
def _record_emitted(lane, light, triangle, rgb, pixel, sample, node, row, triangle_subject, subject_count,
                    light_offset, keys, children, parent, event, size, r_pixel, r_sample, r_rgb, r_node, r_row, count):
    for entry in range(len(lane)):
        path = lane[entry]
        event_id = _emitter_event(triangle_subject, subject_count, light_offset, light[entry], triangle[entry])
        child, size = trie_child(keys, children, parent, event, size, node[path], event_id)
        count = _add_record(r_pixel, r_sample, r_rgb, r_node, r_row, count, pixel[path], sample[path], rgb[entry, 0],
                            rgb[entry, 1], rgb[entry, 2], child, row[path])
    return size, count


@kernel
def _record_lit(lane, light, triangle, radiance, visible, surface_triangle, lobes, curvature, texture, pixel, sample,
                node, row, triangle_subject, subject_count, light_offset, with_norms, keys, children, parent, event,
                size, n_parent, n_values, n_size, r_pixel, r_sample, r_rgb, r_node, r_row, count):
    for entry in range(len(lane)):
        if not visible[entry]:
            continue
        path = lane[entry]
        light_event = _emitter_event(triangle_subject, subject_count, light_offset, light[entry], triangle[entry])
        for slot in range(3):  # the glossy lobes
            r, g, b = radiance[entry, slot, 0], radiance[entry, slot, 1], radiance[entry, slot, 2]
            if r == 0 and g == 0 and b == 0:
                continue
            lobe = bsdf.slot_lobe(lobes[path], slot)
            surface_event = _surface_event(triangle_subject, subject_count, events.LOBE_TYPE[lobe],
                                           events.LOBE_SCATTER[lobe], lobe, surface_triangle[path])
            child, size = trie_child(keys, children, parent, event, size, node[path], surface_event)
            child, size = trie_child(keys, children, parent, event, size, child, light_event)
            norms_row = row[path]
            if with_norms:
                norms_row = n_size
                n_size = _add_norms(n_parent, n_values, n_size, row[path], curvature[path], texture[path],
                                    reflectance(lobes, path, lobe))
            count = _add_record(r_pixel, r_sample, r_rgb, r_node, r_row, count, pixel[path], sample[path], r, g, b,
                                child, norms_row)
    return size, n_size, count


@kernel
def _record_scattered(scattered, cut, lobe, scatter, transmit, triangle, lobes, curvature, texture, node, row,
                      triangle_subject, subject_count, with_norms, keys, children, parent, event, size, n_parent,
                      n_values, n_size):
    for path in range(len(node)):
        passes = cut[path]
        if not (passes or scattered[path]):
            continue
        event_type = events.TRANSMIT if passes or transmit[path] else events.REFLECT
        path_lobe = events.NO_LOBE if passes else np.int64(lobe[path])
        event_id = _surface_event(triangle_subject, subject_count, event_type, scatter[path], path_lobe,
                                  triangle[path])
        node[path], size = trie_child(keys, children, parent, event, size, node[path], event_id)
        if with_norms:
            if passes:
                n_size = _add_norms(n_parent, n_values, n_size, row[path], 0.0, 0.0, 0.0)
            else:
                n_size = _add_norms(n_parent, n_values, n_size, row[path], curvature[path], texture[path],
                                    reflectance(lobes, path, lobe[path]))
            row[path] = n_size - 1
    return size, n_size


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


class EventNorms:
    """C, T, R of every event of a batch's paths, as rows linked to the path's previous
    event: a path keeps one row number instead of N norms, and a record's N slots are
    gathered once, when the batch ends."""

    def __init__(self, capacity: int = 1024) -> None:
        self.parent = np.empty(capacity, np.int64)
        self.values = np.empty((capacity, 3), FLOAT)
        self.size = 0

    def reserve(self, extra: int) -> tuple:
        """Room for `extra` more rows; the arrays a kernel's ``_add_norms`` takes, and size."""
        if self.size + extra > len(self.parent):
            capacity = max(self.size + extra, 2 * len(self.parent))
            self.parent = _grown(self.parent, capacity)
            self.values = _grown(self.values, capacity)
        return self.parent, self.values, self.size

    def first_events(self, rows: np.ndarray, slots: int) -> np.ndarray:
        """(r, slots, 3) float16 norms of events 1..slots of the paths ending at `rows`
        (zeros past a path's last event), as the index stores them (paths/format.py
        ``stored_norms``: saturated at the largest float16)."""
        out = np.zeros((len(rows), slots, 3), np.uint16)
        if slots:
            _first_events_kernel(self.parent, self.values.view(np.uint32), rows, out)
        return out.view(fmt.NORM_DTYPE)


class RecordBuffer:
    """The records of a batch: pixel, sample, rgb (float32 × 3), class node, norms row."""

    def __init__(self, capacity: int = 1024) -> None:
        self.pixel = np.empty(capacity, np.int64)
        self.sample = np.empty(capacity, np.int32)
        self.rgb = np.empty((capacity, 3), FLOAT)
        self.node = np.empty(capacity, np.int64)
        self.row = np.empty(capacity, np.int64)
        self.count = 0

    def reserve(self, extra: int) -> tuple:
        """Room for `extra` more records; the arrays a kernel's ``_add_record`` takes, and
        the count."""
        if self.count + extra > len(self.pixel):
            capacity = max(self.count + extra, 2 * len(self.pixel))
            for name in ("pixel", "sample", "rgb", "node", "row"):
                setattr(self, name, _grown(getattr(self, name), capacity))
        return self.pixel, self.sample, self.rgb, self.node, self.row, self.count

    def arrays(self) -> tuple[np.ndarray, ...]:
        return tuple(getattr(self, name)[:self.count] for name in ("pixel", "sample", "rgb", "node", "row"))


def _grown(array: np.ndarray, capacity: int) -> np.ndarray:
    grown = np.empty((capacity,) + array.shape[1:], array.dtype)
    grown[:len(array)] = array
    return grown


@kernel
def _first_events_kernel(parent, value_bits, rows, out):
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
                for norm in range(3):
                    out[record, position, norm] = _half_bits(value_bits[row, norm])
            position -= 1
            row = parent[row]


_F16_MAX_BITS = 0x7BFF


@inline
def _half_bits(bits):
    """The float16 bits of the float32 whose bits are `bits` (uint32), rounded to nearest
    even and saturated at the largest float16 (±65504), as ``stored_norms`` stores norms;
    NaN stays NaN. (numpy's float16 cast costs more than the whole gather.)"""
    bits = np.int64(bits)
    sign = (bits >> 16) & 0x8000
    exponent = (bits >> 23) & 0xFF
    mantissa = bits & 0x7FFFFF
    if exponent == 0xFF:
        return np.uint16(sign | (0x7E00 if mantissa else _F16_MAX_BITS))
    half_exponent = exponent - 127 + 15
    if half_exponent >= 31:
        return np.uint16(sign | _F16_MAX_BITS)
    if half_exponent <= 0:  # a float16 subnormal, or zero
        if half_exponent < -10:
            return np.uint16(sign)
        mantissa |= 0x800000
        shift = 14 - half_exponent
        half = mantissa >> shift
        remainder = mantissa & ((1 << shift) - 1)
        halfway = 1 << (shift - 1)
        if remainder > halfway or (remainder == halfway and half & 1):
            half += 1
        return np.uint16(sign | half)
    half = (half_exponent << 10) | (mantissa >> 13)
    remainder = mantissa & 0x1FFF
    if remainder > 0x1000 or (remainder == 0x1000 and half & 1):
        half += 1  # may carry into the exponent: still the right rounding
    return np.uint16(sign | min(half, _F16_MAX_BITS))
