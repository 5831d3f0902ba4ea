"""Path events: what one vertex of a light path was, as one small integer.

A light path is read camera first (LPE convention, ``docs/lpe.md``): C, then one event
per surface the path scattered at or passed through, then the emitter. Each event has a
type, a scattering, the lobe the renderer used, and a subject: the (object, material)
pair of a surface, or a light. Its id packs the four:

    head  = (type · 5 + scatter) · 5 + lobe                    (175 heads)
    event = head · subject_count + subject
    subject ∈ [0, S) surface pairs of ``EventVocabulary``, [S, S + lights) lights

so that the tracer carries a path's history as one integer: its node in a prefix tree
of event ids (``PathClassTrie``), whose nodes are the path classes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..lpe.events import EVENT_TYPES, SCATTERINGS

CAMERA, REFLECT, TRANSMIT, VOLUME, LIGHT, OBJECT, BACKGROUND = range(7)
NO_SCATTER = 4  # the scatter code of events that do not scatter (C, L, O, B); others index SCATTERINGS
LOBE_NAMES = ("diffuse", "specular", "coat", "glass")  # the renderer's lobes (trace/bsdf.py ids)
NO_LOBE = 4
_EVENT_BITS = 32


@dataclass(frozen=True)
class Event:
    """One event, unpacked: LPE letters and the labels it carries."""

    type: str  # one of EVENT_TYPES
    scatter: str  # one of SCATTERINGS, or '' for C, L, O, B
    labels: frozenset[str]
    name: str = ""  # the object's or light's prim name, for display (also among the labels)


@dataclass(frozen=True)
class EventVocabulary:
    """The subjects of one frame's events and their names.

    surface_objects, surface_materials : (S,) the distinct (object, material) pairs of the
        scene's triangles (material −1: none); indices into the name tuples below
    An event carries as labels: for surfaces (R, T, O) the object's prim name and path and
    the bound material's name and path, plus the lobe name ('diffuse', 'specular',
    'coat', 'glass'); for lights (L) the light's prim name and path.
    """

    surface_objects: tuple[int, ...]
    surface_materials: tuple[int, ...]
    object_names: tuple[str, ...]
    object_paths: tuple[str, ...]
    material_names: tuple[str, ...]
    material_paths: tuple[str, ...]
    light_names: tuple[str, ...]
    light_paths: tuple[str, ...]

    @property
    def subject_count(self) -> int:
        return len(self.surface_objects) + len(self.light_names)

    def ids(self, event_type, scatter, lobe, subject) -> np.ndarray:
        """Event ids of (n,) or scalar fields; surface subjects in [0, S), lights offset
        by ``light_subject``."""
        head = (np.asarray(event_type, np.int64) * 5 + np.asarray(scatter, np.int64)) * 5 + np.asarray(lobe, np.int64)
        return head * self.subject_count + np.asarray(subject, np.int64)

    def light_subject(self, light) -> np.ndarray:
        return np.asarray(light, np.int64) + len(self.surface_objects)

    def event(self, event_id: int) -> Event:
        head, subject = divmod(int(event_id), max(self.subject_count, 1))
        event_type, scatter, lobe = head // 25, (head // 5) % 5, head % 5
        labels: set[str] = set()
        name = ""
        if event_type == LIGHT:
            light = subject - len(self.surface_objects)
            name = self.light_names[light]
            labels.update((name, self.light_paths[light]))
        elif event_type in (REFLECT, TRANSMIT, OBJECT):
            obj, material = self.surface_objects[subject], self.surface_materials[subject]
            name = self.object_names[obj]
            labels.update((name, self.object_paths[obj]))
            if material >= 0:
                labels.update((self.material_names[material], self.material_paths[material]))
        if lobe != NO_LOBE:
            labels.add(LOBE_NAMES[lobe])
        return Event(EVENT_TYPES[event_type], "" if scatter == NO_SCATTER else SCATTERINGS[scatter],
                     frozenset(labels), name)


def path_text(events: tuple[Event, ...], all_labels: bool = False) -> str:
    """The textual notation of docs/lpe.md: ``C RD'floor' L'key'``, each event with its
    object or light name, or with every label (sorted) if `all_labels`."""
    def labels(event: Event) -> list[str]:
        return sorted(event.labels) if all_labels or not event.name else [event.name]

    return " ".join(e.type + e.scatter + "".join(f"'{label}'" for label in labels(e)) for e in events)


class PathClassTrie:
    """Prefix tree of event ids: every distinct event sequence (path class) is one node.

    Node 0 is the camera (the empty sequence after C). A path carries its node; ``extend``
    moves many paths one event further at once, with sorted arrays instead of a Python
    dictionary. Node numbers depend only on the sequence of ``extend`` calls, so a batch
    traced the same way numbers its classes the same way.
    """

    def __init__(self) -> None:
        self.parent = np.full(1, -1, np.int64)
        self.event = np.zeros(1, np.int64)
        self._pairs = np.zeros(0, np.int64)  # sorted parent << 32 | event of every edge
        self._children = np.zeros(0, np.int64)  # the child of each pair

    def __len__(self) -> int:
        return len(self.parent)

    def extend(self, node: np.ndarray, event: np.ndarray) -> np.ndarray:
        """Children of node (n,) by event id (n,), created as needed -> (n,) int64."""
        if not len(node):
            return np.zeros(0, np.int64)
        pairs = (np.asarray(node, np.int64) << _EVENT_BITS) | np.asarray(event, np.int64)
        unique, inverse = np.unique(pairs, return_inverse=True)
        position = np.minimum(np.searchsorted(self._pairs, unique), max(len(self._pairs) - 1, 0))
        found = self._pairs[position] == unique if len(self._pairs) else np.zeros(len(unique), bool)
        children = np.empty(len(unique), np.int64)
        children[found] = self._children[position[found]]
        new = unique[~found]
        if len(new):
            ids = np.arange(len(self.parent), len(self.parent) + len(new))
            children[~found] = ids
            self.parent = np.concatenate([self.parent, new >> _EVENT_BITS])
            self.event = np.concatenate([self.event, new & ((1 << _EVENT_BITS) - 1)])
            at = np.searchsorted(self._pairs, new)
            self._pairs = np.insert(self._pairs, at, new)
            self._children = np.insert(self._children, at, ids)
        return children[inverse.reshape(-1)]

    def sequences(self, nodes: np.ndarray) -> list[tuple[int, ...]]:
        """The event ids from the first event after the camera to each of `nodes`."""
        chains = []
        current = np.asarray(nodes, np.int64)
        while (current > 0).any():
            chains.append(np.where(current > 0, self.event[current], -1))
            current = np.where(current > 0, self.parent[np.maximum(current, 0)], 0)
        if not chains:
            return [() for _ in range(len(current))]
        table = np.stack(chains[::-1], axis=1)  # (nodes, depth), left-padded with −1
        return [tuple(event for event in row if event >= 0) for row in table.tolist()]
