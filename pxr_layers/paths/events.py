"""Path events: what one vertex of a light path was, as one small integer.

A light path is read camera first (LPE convention, ``docs/lpe.md``): C, then one event
per surface the path scattered at or passed through, then the emitter. Each event has a
type, a scattering, the lobe the renderer used, and a subject: the (object, material)
pair of a surface, or a light. Its id packs the four:

    head  = (type · 5 + scatter) · 5 + lobe                    (175 heads)
    event = head · subject_count + subject
    subject ∈ [0, S) surface pairs of ``EventVocabulary``, [S, S + lights) lights

so that the tracer carries a path's history as one integer: its node in a prefix tree
of event ids (``trace/recorder.py``'s ``ClassTrie``), whose nodes are the path classes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..lpe.events import EVENT_TYPES, SCATTERINGS

CAMERA, REFLECT, TRANSMIT, VOLUME, LIGHT, OBJECT, BACKGROUND = range(7)
NO_SCATTER = 4  # the scatter code of events that do not scatter (C, L, O, B); others index SCATTERINGS
LOBE_NAMES = ("diffuse", "specular", "coat", "glass")  # the renderer's lobes (trace/bsdf.py ids)
NO_LOBE = 4


def event_id(event_type, scatter, lobe, subject, subject_count):
    """The id of one event (the packing above); plain arithmetic, so that numpy arrays and
    the tracer's compiled kernels (scalars) share it."""
    return ((event_type * 5 + scatter) * 5 + lobe) * subject_count + subject


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
        return event_id(np.asarray(event_type, np.int64), np.asarray(scatter, np.int64), np.asarray(lobe, np.int64),
                        np.asarray(subject, np.int64), self.subject_count)

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


def event_paths(events: Sequence[Event]) -> list[tuple[str, str]]:
    """(own path, material path) of each event of an index's event table: the prim path of
    the object or light it names, and the bound material's path ("" without one, and for
    lights, C and B).

    An event carries its object's name and path and its material's name and path
    (EventVocabulary.event) without saying which path is which: a material's path is the one
    events of several names carry, or else the path whose last element is not the event's name.
    """
    carriers: dict[str, set[str]] = {}
    for event in events:
        for label in event.labels:
            if label.startswith("/"):
                carriers.setdefault(label, set()).add(event.name)
    shared = {label for label, names in carriers.items() if len(names) > 1}
    paths_of = []
    for event in events:
        paths = sorted(label for label in event.labels if label.startswith("/"))
        own = [path for path in paths if path.rsplit("/", 1)[-1] == event.name and path not in shared] or \
            [path for path in paths if path.rsplit("/", 1)[-1] == event.name] or paths
        own_path = own[0] if own else ""
        material = "" if event.type in ("L", "C", "B") else next((path for path in paths if path != own_path), "")
        paths_of.append((own_path, material))
    return paths_of
