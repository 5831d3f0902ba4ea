"""Path events: the event alphabet, and what one vertex of a light path was, as one small integer.

This module is the one home of the event alphabet (``docs/lpe.md``): the type and scattering
letters of the path notation and of expressions (``lpe/`` imports them), the renderer's
lobes and the scattering each lobe gives, and the integer codes the tracer packs into
event ids (``trace/`` imports them). It imports nothing (of the package or beyond the
standard library), so that both the tracer's kernels and the LPE parser can import it.

A light path is read camera first (LPE convention): C, then one event per surface the path
scattered at or passed through, then the emitter. Each event has a type, a scattering, the
lobe the renderer used, and a subject: the (object, material) pair of a surface, or a
light. Its id packs the four:

    head  = (type · 5 + scatter) · 8 + lobe                    (280 heads)
    event = head · subject_count + subject
    subject ∈ [0, S) surface pairs of ``EventVocabulary``, [S, S + lights) lights

so that the tracer carries a path's history as one integer: its node in a prefix tree
of event ids (``trace/recorder.py``'s ``ClassTrie``), whose nodes are the path classes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

# The codes below are plain module-level ints (numba compiles them into the kernels as
# constants); each is the index of its letter or name, so letters and codes cannot drift.

EVENT_TYPES = "CRTVLOB"
"""Camera, Reflection, Transmission, Volume, Light, emissive Object, Background; a type's
code is its index."""
CAMERA, REFLECT, TRANSMIT, VOLUME, LIGHT, OBJECT, BACKGROUND = range(len(EVENT_TYPES))

NON_SCATTERING_TYPES = "CLOB"
"""Event types that carry no scattering letter in the path notation."""
SCATTERING_TYPES = "".join(kind for kind in EVENT_TYPES if kind not in NON_SCATTERING_TYPES)
"""Event types that scatter (the bounces of a path): R, T, V."""
SCATTERING_TYPE_NAMES = ("reflection", "transmission", "volume")
"""The names of SCATTERING_TYPES, in order (what the inspector's query builder shows)."""

SCATTERINGS = "DGSs"
"""Diffuse, Glossy, Singular (perfect mirror or refraction), straight (pass-through); a
scattering's code is its index."""
SCATTERING_NAMES = ("diffuse", "glossy", "singular", "straight")
SCATTER_DIFFUSE, SCATTER_GLOSSY, SCATTER_SINGULAR, SCATTER_STRAIGHT = range(len(SCATTERINGS))

NO_SCATTERING = ""
"""The scattering slot of C, L, O and B events."""
NO_SCATTERING_LETTER = "x"
"""How expressions spell NO_SCATTERING (as OSL does)."""
NO_SCATTER = len(SCATTERINGS)
"""The scatter code of NO_SCATTERING."""
ALL_SCATTERINGS = (NO_SCATTERING, *SCATTERINGS)

LOBE_NAMES = ("diffuse", "specular", "coat", "glass", "R", "TT", "TRT")
"""The renderer's lobes (trace/bsdf.py, trace/hair.py); a lobe's id is its index. Events carry
their lobe's name as a label. R, TT and TRT are the hair lobes (MaterialX chiang_hair_bsdf:
reflection off the fibre, transmission through it, and light reflected inside it, TRT
holding the higher orders too, as chiang_hair_bsdf's tint_TRT does)."""
LOBE_DIFFUSE, LOBE_SPECULAR, LOBE_COAT, LOBE_GLASS, LOBE_HAIR_R, LOBE_HAIR_TT, LOBE_HAIR_TRT = range(len(LOBE_NAMES))
NO_LOBE = len(LOBE_NAMES)
"""The lobe code of events that took no lobe (C, L, O, B, and straight pass-throughs)."""
LOBE_SCATTERINGS = "DGGSGGG"
"""The scattering of each lobe, LOBE_NAMES order. A GGX lobe (specular, coat) narrower
than bsdf.SINGULAR_ALPHA is a perfect mirror and scatters S instead."""
LOBE_SCATTER = tuple(SCATTERINGS.index(letter) for letter in LOBE_SCATTERINGS)
"""LOBE_SCATTERINGS as scatter codes, for the kernels."""
LOBE_TYPES = "RRRRRTR"
"""The event type of a light sample taken through each lobe, LOBE_NAMES order (a sampled
glass direction is R or T by the side it leaves on)."""
LOBE_TYPE = tuple(EVENT_TYPES.index(letter) for letter in LOBE_TYPES)
"""LOBE_TYPES as type codes, for the kernels."""

_SCATTER_CODES = NO_SCATTER + 1
_LOBE_CODES = NO_LOBE + 1


def event_id(event_type, scatter, lobe, subject, subject_count):
    """The id of one event (the packing above); plain arithmetic, so that the tracer's
    compiled kernels inline it (trace/recorder.py)."""
    return ((event_type * _SCATTER_CODES + scatter) * _LOBE_CODES + lobe) * subject_count + subject


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
    the bound material's name and path, plus the lobe name (LOBE_NAMES); for lights (L) the light's prim name and path.
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

    def event(self, event_id: int) -> Event:
        head, subject = divmod(int(event_id), max(self.subject_count, 1))
        event_type, scatter_and_lobe = divmod(head, _SCATTER_CODES * _LOBE_CODES)
        scatter, lobe = divmod(scatter_and_lobe, _LOBE_CODES)
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
        return Event(EVENT_TYPES[event_type], NO_SCATTERING if scatter == NO_SCATTER else SCATTERINGS[scatter],
                     frozenset(labels), name)


def path_text(events: tuple[Event, ...], all_labels: bool = False) -> str:
    """The textual notation of docs/lpe.md: ``C RD'floor' L'key'``, each event with its
    object or light name, or with every label (sorted) if `all_labels`."""
    def labels(event: Event) -> list[str]:
        return sorted(event.labels) if all_labels or not event.name else [event.name]

    return " ".join(e.type + e.scatter + "".join(f"'{label}'" for label in labels(e)) for e in events)


_NO_MATERIAL_TYPES = (EVENT_TYPES[LIGHT], EVENT_TYPES[CAMERA], EVENT_TYPES[BACKGROUND])


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
        material = "" if event.type in _NO_MATERIAL_TYPES else next((path for path in paths if path != own_path), "")
        paths_of.append((own_path, material))
    return paths_of
