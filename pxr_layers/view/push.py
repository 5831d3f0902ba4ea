"""Which graded layers of the inspector's stack are grades of whole lights, and so can be
pushed back into the shot as light edits (stage/light_overrides.py writes them).

A layer is a light edit when the set of path classes its expression takes is exactly the
set of classes that end at one light (its prim, by the prim path its light events carry),
or at every light of one ``pxrLayers:lightGroup``, with no covariance condition splitting a
class's records: then ``grade · layer`` is what the light itself renders with its radiance
times the grade (direct views of the light, ``C<L.'key'>``, are among its classes: a light
edit changes them too). The expression is compiled and run over the index's classes by the
LPE engine (``layers.extract.class_matches``), so ``C.*<L.'key'>``, the recipe's per-light
layers, ``C.*<L.'/World/Lights/key'>`` and ``C<L.'key'>|C.+<L.'key'>`` all qualify, and
``C<RD>.*<L.'key'>`` does not (it is only part of key's paths).

Every other entry stays a compositing grade, with one line saying why: solo (a viewing
state), a mask (a light lights every object), covariance conditions, paths of several
lights, of emissive objects or of the background, part of a light's paths (which part),
an entry whose light another entry pushes too (their grades add up in the composite,
``(g1 + g2 − 1)·layer``, which is not one light edit: keep one of them).
"""

from __future__ import annotations

import functools
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from ..errors import LpeError
from ..layers.extract import class_matches
from ..layers.nuke import LayerGrade
from ..paths.events import SCATTERING_NAMES, SCATTERING_TYPE_NAMES, SCATTERING_TYPES, SCATTERINGS
from ..paths.reader import PathIndex

_TYPE_NAMES = dict(zip(SCATTERING_TYPES, SCATTERING_TYPE_NAMES, strict=True))


@dataclass(frozen=True)
class PushEntry:
    """One stack entry: its shown name, its expression (None: unknown) and its grade."""

    name: str
    expression: str | None
    grade: LayerGrade

    @property
    def masked(self) -> bool:
        return self.grade.mask is not None


@dataclass(frozen=True)
class LightEdit:
    """A layer pushed as a light edit. lights : the prim paths it edits; light : the light's
    name (or its group's) as shown."""

    layer: str
    light: str
    lights: tuple[str, ...]
    grade: LayerGrade

    def description(self) -> dict:
        grade = self.grade
        return {"layer": self.layer, "light": self.light, "lights": list(self.lights),
                "edits": {"stops": grade.stops, "tint": list(grade.tint), "kelvin": grade.kelvin, "mute": grade.mute,
                          "multiply": list(grade.multiply)}}


@dataclass(frozen=True)
class CompositingGrade:
    layer: str
    why: str

    def description(self) -> dict:
        return {"layer": self.layer, "why": self.why}


@dataclass(frozen=True)
class PushPlan:
    pushed: tuple[LightEdit, ...]
    compositing: tuple[CompositingGrade, ...]
    notes: tuple[str, ...] = field(default=())

    def description(self) -> dict:
        return {"pushed": [edit.description() for edit in self.pushed],
                "compositing": [grade.description() for grade in self.compositing], "notes": list(self.notes)}


def light_path(event) -> str:
    """The prim path a light event carries (its label that is a path); its name without one."""
    paths = sorted(label for label in event.labels if label.startswith("/"))
    return paths[0] if paths else event.name


@functools.lru_cache(maxsize=8)
def light_classes(index: PathIndex) -> dict[str, frozenset[int]]:
    """prim path → the ids of the classes that end at that light (an index's classes do not
    change: computed once per index)."""
    found: dict[str, set[int]] = defaultdict(set)
    for path_class in index.classes:
        end = index.events[path_class.event_ids[-1]]
        if end.type == "L":
            found[light_path(end)].add(path_class.id)
    return {path: frozenset(ids) for path, ids in found.items()}


def classify(index: PathIndex, entries: Sequence[PushEntry], groups: Mapping[str, str] | None = None) -> PushPlan:
    """Each entry a LightEdit or a CompositingGrade (module docstring).

    groups : prim path → pxrLayers:lightGroup ("" none) of the stage's lights; None: no
             groups known (a layer of several lights is then never one light)
    """
    by_light = light_classes(index)
    names = {path: index.events[index.classes[min(ids)].event_ids[-1]].name or path for path, ids in by_light.items()}
    groups = groups or {}
    members: dict[str, set[str]] = defaultdict(set)
    for path, group in groups.items():
        if group:
            members[group].add(path)
    pushed: list[LightEdit] = []
    compositing: list[CompositingGrade] = []
    matched: dict[str, frozenset[int]] = {}
    for entry in entries:
        result = _classify(index, entry, by_light, names, groups, members, matched)
        (pushed if isinstance(result, LightEdit) else compositing).append(result)
    pushed, refused = _conflicts(pushed)
    compositing += refused
    notes = _overlaps(pushed, compositing, matched, by_light)
    if pushed and index.manifest.get("clamp_indirect"):
        notes.append(f"the render clamped indirect light (--clamp-indirect {index.manifest['clamp_indirect']:g}): a "
                     "pushed light's clamped paths clip at another level, so the re-render differs there")
    order = {entry.name: k for k, entry in enumerate(entries)}
    compositing.sort(key=lambda grade: order[grade.layer])
    return PushPlan(tuple(pushed), tuple(compositing), tuple(notes))


def _classify(index, entry: PushEntry, by_light, names, groups, members, matched) -> LightEdit | CompositingGrade:
    def stays(why: str) -> CompositingGrade:
        return CompositingGrade(entry.name, why)

    grade = entry.grade
    if grade.solo:
        return stays("solo is a viewing state (only soloed layers are shown), not a look of the lights")
    if entry.masked:
        return stays("masked to objects (a Cryptomatte mask): a light edit lights every object it reaches")
    if not entry.expression:
        return stays("has no expression: which paths it holds is unknown")
    try:
        match = class_matches(index, {entry.name: entry.expression})[entry.name]
    except LpeError as error:
        return stays(f"its expression does not compile: {str(error).splitlines()[0]}")
    if match.conditional:
        return stays(f"has covariance conditions: they keep some records of a path class and not others "
                     f"({len(match.conditional)} classes)")
    taken = match.always
    matched[entry.name] = taken
    if not taken:
        return stays("matches no path of this render")
    ends: dict[str, set[str]] = defaultdict(set)
    for class_id in taken:
        end = index.events[index.classes[class_id].event_ids[-1]]
        ends[end.type].add(light_path(end) if end.type == "L" else end.name)
    others = []
    if ends.get("O"):
        others.append(f"emissive objects ({_listed(ends['O'])}: their emission is their material's, not a light's)")
    if ends.get("B"):
        others.append("the background")
    if others:
        return stays(f"holds paths that end at {' and '.join(others)}: no light edit changes them")
    lights = ends["L"]
    label = names.get(next(iter(lights)), next(iter(lights)))
    if len(lights) > 1:
        group = {groups.get(path, "") for path in lights}
        name = next(iter(group))
        seen = {path for path in members.get(name, ()) if path in by_light}
        if len(group) == 1 and name and lights == seen:
            lights, label = members[name], name
        else:
            return stays(f"matches paths of {len(lights)} lights ({_listed(names.get(p, p) for p in lights)}), "
                         "not one light or one light group")
    whole = frozenset().union(*(by_light.get(path, frozenset()) for path in lights))
    if taken != whole:
        return stays(f"only part of {label}'s paths: {_part(index, taken)}, not {_part(index, whole - taken)} "
                     f"({len(taken)} of its {len(whole)} path classes)")
    return LightEdit(entry.name, label, tuple(sorted(lights)), grade)


def _part(index: PathIndex, classes) -> str:
    """What some classes of one light are, by the first event after the camera and the
    number of bounces: "its diffuse reflection bounces (direct only)", "the light seen directly"."""
    firsts, bounces = set(), set()
    for class_id in classes:
        events = index.classes[class_id].events
        first = events[1]
        if first.type in ("L", "O", "B"):
            firsts.add("the light seen directly")
            continue
        scattering = SCATTERING_NAMES[SCATTERINGS.index(first.scatter)] if first.scatter in SCATTERINGS else ""
        firsts.add(f"its {scattering} {_TYPE_NAMES.get(first.type, first.type)} bounces".replace("  ", " "))
        bounces.add(len(events) - 2)
    depth = ""
    if bounces and "the light seen directly" not in firsts:
        depth = " (direct only)" if max(bounces) == 1 else " (indirect only)" if min(bounces) > 1 else ""
    return " and ".join(sorted(firsts)) + depth


def _conflicts(pushed: list[LightEdit]) -> tuple[list[LightEdit], list[CompositingGrade]]:
    """Entries that push to a light another entry pushes to too stay compositing grades."""
    owners: dict[str, list[str]] = defaultdict(list)
    for edit in pushed:
        for path in edit.lights:
            owners[path].append(edit.layer)
    kept, refused = [], []
    for edit in pushed:
        sharing = sorted({layer for path in edit.lights for layer in owners[path]} - {edit.layer})
        if sharing:
            refused.append(CompositingGrade(edit.layer, f"{edit.light} is pushed by {_listed(sharing)} too: two grades "
                                            "of one light's paths add up in the composite ((g1 + g2 − 1)·layer), "
                                            "not one light edit; keep one of them"))
        else:
            kept.append(edit)
    return kept, refused


def _overlaps(pushed, compositing, matched, by_light) -> list[str]:
    """Compositing grades whose paths include a pushed light's: on the pushed render those
    paths already carry the light edit, and the compositing grade applies on top of it."""
    notes = []
    for grade in compositing:
        taken = matched.get(grade.layer)
        if not taken:
            continue
        shared = [edit.light for edit in pushed
                  if any(taken & by_light.get(path, frozenset()) for path in edit.lights)]
        if shared:
            notes.append(f"{grade.layer} holds paths of pushed lights ({_listed(shared)}): on the pushed render its "
                         "grade applies on top of their light edits")
    return notes


def _listed(names) -> str:
    names = sorted(names)
    return ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")
