"""Path events: what one vertex of a light path was, packed into one int64 key.

A light path is read camera first (LPE convention, ``docs/lpe.md``): C, then one event
per surface the path scattered at or passed through, then the emitter. Each event has a
type, a scattering, the lobe the renderer used, and a subject: the object and material
of a surface, or the light. The key packs all four so that the tracer can carry a path's
history as one integer (its node in a prefix tree of keys, ``PathClassTrie``).

    key = (((type · 5 + scatter) · 5 + lobe) << 40) | subject
    subject = object << 20 | (material + 1)      for surface events (R, T, O)
    subject = light                              for L events

The labels an event carries (names a query can use) come from ``EventVocabulary``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EVENT_TYPES = "CRTVLOB"
CAMERA, REFLECT, TRANSMIT, VOLUME, LIGHT, OBJECT, BACKGROUND = range(7)
SCATTER_NAMES = "DGSs"  # + NO_SCATTER for events that do not scatter (C, L, O, B)
NO_SCATTER = 4
LOBE_NAMES = ("diffuse", "specular", "coat", "glass")  # the renderer's lobes (trace/bsdf.py ids)
NO_LOBE = 4

_SUBJECT_BITS = 40
_MATERIAL_BITS = 20
_SUBJECT_MASK = (1 << _SUBJECT_BITS) - 1
_MATERIAL_MASK = (1 << _MATERIAL_BITS) - 1


def event_keys(event_type, scatter, lobe, subject) -> np.ndarray:
    """Pack (n,) or scalar fields into (n,) int64 keys."""
    head = (np.asarray(event_type, np.int64) * 5 + np.asarray(scatter, np.int64)) * 5 + np.asarray(lobe, np.int64)
    return (head << _SUBJECT_BITS) | np.asarray(subject, np.int64)


def surface_subject(obj, material) -> np.ndarray:
    """Subject of a surface event: object index (n,) and material index (n,), -1 = none."""
    return (np.asarray(obj, np.int64) << _MATERIAL_BITS) | (np.asarray(material, np.int64) + 1)


@dataclass(frozen=True)
class Event:
    """One event, unpacked: LPE letters and the labels it carries."""

    type: str  # one of EVENT_TYPES
    scatter: str  # one of SCATTER_NAMES, or '' for C, L, O, B
    labels: frozenset[str]


@dataclass(frozen=True)
class EventVocabulary:
    """Names of the scene's objects, materials and lights, to turn keys into events.

    An event carries as labels: for surfaces (R, T, O) the object's prim name and path and
    the bound material's name and path, plus the lobe name ('diffuse', 'specular',
    'coat', 'glass'); for lights (L) the light's prim name and path.
    """

    object_names: tuple[str, ...]
    object_paths: tuple[str, ...]
    material_names: tuple[str, ...]
    material_paths: tuple[str, ...]
    light_names: tuple[str, ...]
    light_paths: tuple[str, ...]

    def event(self, key: int) -> Event:
        head, subject = int(key) >> _SUBJECT_BITS, int(key) & _SUBJECT_MASK
        lobe = head % 5
        scatter = (head // 5) % 5
        event_type = head // 25
        labels: set[str] = set()
        if event_type == LIGHT:
            labels.update((self.light_names[subject], self.light_paths[subject]))
        elif event_type in (REFLECT, TRANSMIT, OBJECT):
            obj, material = subject >> _MATERIAL_BITS, (subject & _MATERIAL_MASK) - 1
            labels.update((self.object_names[obj], self.object_paths[obj]))
            if material >= 0:
                labels.update((self.material_names[material], self.material_paths[material]))
        if lobe != NO_LOBE:
            labels.add(LOBE_NAMES[lobe])
        return Event(EVENT_TYPES[event_type], "" if scatter == NO_SCATTER else SCATTER_NAMES[scatter],
                     frozenset(labels))


def path_text(events: tuple[Event, ...]) -> str:
    """The textual notation of docs/lpe.md: ``C RD'floor' L'key'`` (labels sorted)."""
    return " ".join(e.type + e.scatter + "".join(f"'{label}'" for label in sorted(e.labels)) for e in events)


class PathClassTrie:
    """Prefix tree of event keys: every distinct event sequence (path class) is one node.

    Node 0 is the camera event. A path carries its node; ``extend`` moves many paths one
    event further at once. Node numbers depend only on the order of ``extend`` calls, so
    a batch traced the same way numbers its classes the same way.
    """

    def __init__(self) -> None:
        self.parent: list[int] = [-1]
        self.key: list[int] = [event_keys(CAMERA, NO_SCATTER, NO_LOBE, 0).item()]
        self._children: dict[tuple[int, int], int] = {}

    def __len__(self) -> int:
        return len(self.parent)

    def extend(self, node: np.ndarray, key: np.ndarray) -> np.ndarray:
        """Children of node (n,) by key (n,) int64, created as needed -> (n,) int64."""
        if not len(node):
            return np.zeros(0, np.int64)
        node = np.asarray(node, np.int64)
        key = np.asarray(key, np.int64)
        order = np.lexsort((key, node))
        sorted_node, sorted_key = node[order], key[order]
        first = np.ones(len(order), bool)
        first[1:] = (sorted_node[1:] != sorted_node[:-1]) | (sorted_key[1:] != sorted_key[:-1])
        children = np.empty(int(first.sum()), np.int64)
        for index, pair in enumerate(zip(sorted_node[first].tolist(), sorted_key[first].tolist())):
            child = self._children.get(pair)
            if child is None:
                child = len(self.parent)
                self._children[pair] = child
                self.parent.append(pair[0])
                self.key.append(pair[1])
            children[index] = child
        result = np.empty(len(order), np.int64)
        result[order] = children[np.cumsum(first) - 1]
        return result

    def sequence(self, node: int) -> tuple[int, ...]:
        """The event keys from the camera to `node`, camera first."""
        keys = []
        while node >= 0:
            keys.append(self.key[node])
            node = self.parent[node]
        return tuple(reversed(keys))
