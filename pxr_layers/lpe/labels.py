"""Help for label typos: the known names closest to a quoted label of an expression, and
the one check that every quoted label of a set of layers names something.

A label that names nothing makes a layer silently empty (or a negated set exclude nothing),
so :func:`unknown_labels` warns of each, with the closest names of the kind the label's
slot can carry (a label of an ``L`` event is looked up among the lights, one of an ``R``,
``T``, ``V`` or ``O`` event among objects, materials and lobes). Every command that cuts
layers calls it: ``extract`` (and so ``render``'s delivery), the inspector, ``lpe match``.
"""

from __future__ import annotations

import difflib
import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from ..paths.events import EVENT_TYPES, LOBE_NAMES
from . import nodes
from .events import is_glob, label_matches

log = logging.getLogger(__name__)

SIMILARITY_CUTOFF = 0.6
"""difflib ratio below which a name is not worth suggesting."""

CLOSEST_SHOWN = 3
"""Close names a warning suggests at most."""

LISTED_WHEN_FEW = 6
"""When no known name is close, a kind with at most this many names lists them all (a scene
with two lights: "its lights are 'key', 'fill'"); a longer list would drown the warning."""

LIGHT, OBJECT, MATERIAL, LOBE, LABEL = "light", "object", "material", "lobe", "label"
"""The kinds of names events carry. LABEL: a name of unknown kind (paths typed on the
command line carry bare labels), which a slot of any kind accepts."""

KINDS_OF_TYPE = {"L": (LIGHT,), "R": (OBJECT, MATERIAL, LOBE), "T": (OBJECT, MATERIAL, LOBE),
                 "V": (OBJECT, MATERIAL, LOBE), "O": (OBJECT, MATERIAL), "C": (), "B": ()}
"""The kinds of names an event of each type carries (paths.events.EventVocabulary.event)."""
assert set(KINDS_OF_TYPE) == set(EVENT_TYPES)

_PLURAL = {LIGHT: "lights", OBJECT: "objects", MATERIAL: "materials", LOBE: "lobes", LABEL: "labels"}


def closest_labels(label: str, known, n: int = CLOSEST_SHOWN) -> list[str]:
    """Up to ``n`` names of ``known`` closest to ``label``, best first (difflib ratio).

    Prim paths are long and share prefixes, so a path-like label is also compared by its
    last component: ``'/World/Lights/kye'`` suggests ``/World/Lights/key``.
    """
    known = list(dict.fromkeys(known))
    if not known:
        return []
    text = label.replace("*", "").replace("?", "") if is_glob(label) else label
    scored = {}
    for name in known:
        score = difflib.SequenceMatcher(None, text, name).ratio()
        if "/" in text and "/" in name:
            score = max(score, difflib.SequenceMatcher(None, text.rsplit("/", 1)[-1], name.rsplit("/", 1)[-1]).ratio())
        if score >= SIMILARITY_CUTOFF:
            scored[name] = score
    return sorted(scored, key=lambda name: (-scored[name], name))[:n]


@dataclass(frozen=True)
class KnownNames:
    """The names the events of an index (or of a scene) carry, by kind.

    names : kind (LIGHT, OBJECT, MATERIAL, LOBE, LABEL) → the names of that kind
    """

    names: Mapping[str, frozenset[str]]

    @classmethod
    def of_events(cls, events: Iterable) -> KnownNames:
        """From events (paths.events.Event of an index, or lpe.Event of typed paths): a light
        event's labels are lights; a surface event's lobe labels are lobes, its name and the
        path ending in it the object, and its other labels the material. An event without a
        name (a typed path) gives bare LABELs."""
        found: dict[str, set[str]] = {kind: set() for kind in _PLURAL}
        for event in events:
            labels = event.labels
            name = getattr(event, "name", "")
            if not labels:
                continue
            if event.type == "L":
                found[LIGHT].update(labels)
            elif not name:
                found[LABEL].update(labels)
            else:
                lobes = labels & frozenset(LOBE_NAMES)
                own = {label for label in labels if label == name or label.rsplit("/", 1)[-1] == name}
                found[LOBE].update(lobes)
                found[OBJECT].update(own)
                found[MATERIAL].update(labels - lobes - own)
        return cls({kind: frozenset(names) for kind, names in found.items()})

    @classmethod
    def of_labels(cls, labels: Iterable[str]) -> KnownNames:
        """Bare labels, of no known kind."""
        return cls({LABEL: frozenset(labels)})

    def of_kinds(self, kinds: Iterable[str]) -> list[str]:
        """The names of ``kinds`` and the bare labels, sorted."""
        return sorted(set().union(*(self.names.get(kind, frozenset()) for kind in (*kinds, LABEL))))

    def kinds_of(self, label: str) -> list[str]:
        """The kinds of the names ``label`` (a pattern) matches."""
        return [kind for kind in _PLURAL if kind != LABEL
                and any(label_matches(label, name) for name in self.names.get(kind, ()))]


def unknown_labels(trees: Mapping[str, nodes.Node], known: KnownNames, where: str = "") -> list[str]:
    """One warning (logged, and returned) per quoted label of the layers ``trees`` (name →
    expression tree) that matches none of the ``known`` names its slots can carry; each
    names the layers using the label, the kind looked for, and the closest names of that
    kind (or all of them when there are few, LISTED_WHEN_FEW), or the kind it has instead
    (``'floor'`` in an ``L`` slot is an object, not a light). ``where``: what the names
    are of ("cornell.pxlidx"), for the message.

    A negated label (``[^'flor']``) that names nothing is warned of too: it excludes nothing.
    The ``.`` label slot (any label) names everything.
    """
    slots = _label_slots(trees)
    return [warning.message for warning in _unknown(slots, known, where, log_them=True)]


@dataclass(frozen=True)
class UnknownLabel:
    """A quoted label that names nothing: ``label`` (as written), ``layers`` using it, the
    ``kinds`` its slots carry, the ``nearest`` names of those kinds (the closest, or all of
    them when there are few: LISTED_WHEN_FEW), and the warning's ``message``."""

    label: str
    layers: tuple[str, ...]
    kinds: tuple[str, ...]
    nearest: tuple[str, ...]
    message: str


def _label_slots(trees: Mapping[str, nodes.Node]) -> dict[tuple[str, tuple[str, ...]], list[str]]:
    """(label, kinds its slot carries) → the layers using it, for every quoted label."""
    slots: dict[tuple[str, tuple[str, ...]], list[str]] = {}
    for layer, tree in trees.items():
        for event in nodes.event_patterns(tree):
            types = EVENT_TYPES if event.types is None else [kind for kind in EVENT_TYPES if kind in event.types]
            carried = {kind for event_type in types for kind in KINDS_OF_TYPE[event_type]}
            kinds = tuple(kind for kind in _PLURAL if kind in carried)
            for term in event.labels:
                for pattern in term.patterns:
                    if pattern != nodes.ANY_LABEL:
                        slots.setdefault((pattern, kinds), [])
                        if layer not in slots[pattern, kinds]:
                            slots[pattern, kinds].append(layer)
    return slots


def unknown_label_report(query: str, known: KnownNames, where: str = "") -> list[dict]:
    """The labels of one expression that name nothing, for a page to show while the query is
    typed: ``[{"label", "position", "nearest", "message"}]``, position the offset of the
    label's opening quote in ``query`` (its first use), nearest as in UnknownLabel. Not
    logged (``unknown_labels`` logs when the layer is made). Raises LpeSyntaxError."""
    from .lexer import Kind, tokenize
    from .parser import parse

    slots = _label_slots({"expression": parse(query)})
    first_use: dict[str, int] = {}
    for token in tokenize(query):
        if token.kind is Kind.LABEL:
            first_use.setdefault(token.value, token.position)
    return [{"label": warning.label, "position": first_use.get(warning.label), "nearest": list(warning.nearest),
             "message": warning.message.split(": ", 1)[1]}
            for warning in _unknown(slots, known, where, log_them=False)]


def _unknown(slots: dict, known: KnownNames, where: str, *, log_them: bool) -> list[UnknownLabel]:
    found = []
    for (pattern, kinds), layers in slots.items():
        candidates = known.of_kinds(kinds)
        if any(label_matches(pattern, name) for name in candidates):
            continue
        message = (f"{'layer' if len(layers) == 1 else 'layers'} {', '.join(map(repr, layers))}: label "
                   f"'{pattern}' names no {_either([kind for kind in kinds if known.names.get(kind)]) or 'known label'}"
                   f"{f' in {where}' if where else ''}")
        elsewhere = [kind for kind in known.kinds_of(pattern) if kind not in kinds]
        if elsewhere:
            message += f" (it is {_either([_article(kind) for kind in elsewhere], 'and')})"
        elif pattern in LOBE_NAMES:
            message += " (no path took that lobe)"
        close = closest_labels(pattern, candidates)
        nearest = close or (candidates if 0 < len(candidates) <= LISTED_WHEN_FEW else [])
        if close:
            message += f"; closest: {', '.join(map(repr, close))}"
        elif 0 < len(candidates) <= LISTED_WHEN_FEW:
            message += f"; the {_PLURAL[kinds[0]] if len(kinds) == 1 else 'names'} are {', '.join(map(repr, candidates))}"
        elif candidates:
            message += "; no known name is close"
        if log_them:
            log.warning(message)
        found.append(UnknownLabel(pattern, tuple(layers), kinds, tuple(nearest), message))
    return found


def _either(words: list[str], joint: str = "or") -> str:
    """``a``, ``a or b``, ``a, b or c``."""
    return f"{', '.join(words[:-1])} {joint} {words[-1]}" if len(words) > 1 else "".join(words)


def _article(noun: str) -> str:
    return f"{'an' if noun[0] in 'aeiou' else 'a'} {noun}"
