"""A node of the hierarchy over path space: what it keeps of each attribute, its LPE, its name.

A node is a conjunction, one term per attribute it was split on: an attribute either equals
one value (the split's chosen side) or avoids a set of values (the other side, which grows
as it is split again), and the bounce count lies in a range. Each split turns a node into
two complementary nodes, so the leaves of any tree of splits partition path space; their
expressions are built to be complementary too (``<L.'key'>`` / ``<L.[^'key']>|[OB]``,
``@(|S_C| != 0)`` / ``@(|S_C| = 0)``), which :mod:`.partition` checks with the automaton.

A value of None (a first-bounce attribute of a path without bounces, a surface without a
material) avoids every set and equals nothing: such paths go with the "avoids" side.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..paths.events import SCATTER_SINGULAR, SCATTERING_NAMES, SCATTERING_TYPES, SCATTERINGS
from .atoms import ATTRIBUTES, COVARIANCE, FIRST_BOUNCE

ALL_DEPTHS = frozenset({0, 1, 2})
NORM_NAMES = {"curved": "|S_C|", "textured": "|S_T|", "shiny": "|S_R|"}
COVARIANCE_WORDS = {"curved": ("curved", "flat"), "textured": ("textured", "plain"), "shiny": ("shiny", "matte")}
"""Covariance attribute → the names of its sides (norm not 0, norm 0)."""
SCATTER_WORDS = {**dict(zip(SCATTERINGS, SCATTERING_NAMES)), SCATTERINGS[SCATTER_SINGULAR]: "specular"}
"""Scattering letter → layer-name word: a perfect mirror is "specular" to an artist."""
TYPE_WORDS = dict(zip(SCATTERING_TYPES, ("", "transmitted", "volume"), strict=True))
"""Bounce type letter → layer-name word; reflection, the common case, goes unsaid."""
DEPTH_WORDS = {frozenset({0}): "emission", frozenset({1}): "direct", frozenset({2}): "indirect",
               frozenset({0, 1}): "direct", frozenset({1, 2}): "bounced"}
REST = "rest"
"""The name of a layer that no split names (the whole of path space, or what a split left)."""


@dataclass(frozen=True)
class Node:
    """include : attribute → the value it equals; exclude : attribute → values it avoids;
    depths : the bounce counts (0, 1, 2 = more) it holds."""

    include: tuple[tuple[str, str], ...] = ()
    exclude: tuple[tuple[str, frozenset], ...] = ()
    depths: frozenset = field(default=ALL_DEPTHS)

    def split(self, attribute: str, value) -> tuple[Node, Node]:
        """(the side where `attribute` equals `value`, the side where it does not); for
        "depth", `value` is a threshold: (depth ≤ value, depth > value)."""
        if attribute == "depth":
            return (Node(self.include, self.exclude, frozenset(d for d in self.depths if d <= value)),
                    Node(self.include, self.exclude, frozenset(d for d in self.depths if d > value)))
        excluded = dict(self.exclude)
        avoided = excluded.pop(attribute, frozenset())
        equal = Node(_sorted({**dict(self.include), attribute: value}), _sorted(excluded), self.depths)
        excluded[attribute] = avoided | {value}
        return equal, Node(self.include, _sorted(excluded), self.depths)

    @property
    def terms(self) -> int:
        """How many terms the node's expression tests: the LPE length penalty counts these."""
        return len(self.include) + sum(len(values) for _, values in self.exclude) + (self.depths != ALL_DEPTHS)

    def expression(self, labels: dict[str, str]) -> str:
        """The node's LPE. labels : value → the label its events carry (prim paths)."""
        if not self.include and not self.exclude and self.depths == ALL_DEPTHS:
            return "C.*"
        include, exclude = dict(self.include), dict(self.exclude)
        end = _end(include.get("light"), exclude.get("light", frozenset()), labels)
        alternatives = []
        first_bounce_equal = any(attribute in FIRST_BOUNCE for attribute in include)
        if 0 in self.depths and not first_bounce_equal:
            alternatives.append("C" + end)
        bounced = sorted(self.depths - {0})
        if bounced:
            middle = {(1,): "", (2,): ".+", (1, 2): ".*"}[tuple(bounced)]
            alternatives.append("C" + _first(include, exclude, labels) + middle + end)
        return "|".join(alternatives)

    def name(self, present: list[dict], names: dict[str, str]) -> str:
        """A readable identifier from the node's terms: ``key_on_floor_diffuse_direct``.
        present : the attribute values of the atoms the node holds that carry light; an
        attribute it avoids values of is named when they leave one value present."""
        include, exclude = dict(self.include), dict(self.exclude)
        parts = []
        for attribute in ATTRIBUTES:
            if attribute == "depth":
                # "bounced" says nothing a first-bounce value it equals does not already say
                implied = self.depths == frozenset({1, 2}) and any(name in FIRST_BOUNCE for name in include)
                if self.depths != ALL_DEPTHS and not implied:
                    parts.append(DEPTH_WORDS[self.depths])
                continue
            if attribute in include:
                value = include[attribute]
            elif attribute in exclude:
                if attribute in COVARIANCE:
                    parts.append(COVARIANCE_WORDS[attribute][1])
                    continue
                left = {atom[attribute] for atom in present}
                if len(left) != 1 or None in left:
                    continue
                value = left.pop()
            else:
                continue
            parts.append(_word(attribute, value, names))
        words = [part for part in parts if part]
        if not words:
            return REST
        text = re.sub(r"[^A-Za-z0-9_]+", "_", "_".join(dict.fromkeys(words))).strip("_")
        return text if re.match(r"[A-Za-z_]", text) else "layer_" + text


def _word(attribute: str, value, names: dict[str, str]) -> str:
    if attribute == "light":
        return names.get(value, value)
    if attribute == "object":
        return "on_" + names.get(value, value)
    if attribute == "material":
        return names.get(value, value)
    if attribute == "scatter":
        return SCATTER_WORDS[value]
    if attribute == "type":
        return TYPE_WORDS[value]
    return COVARIANCE_WORDS[attribute][0]


def _sorted(mapping: dict) -> tuple:
    return tuple(sorted(mapping.items(), key=lambda item: ATTRIBUTES.index(item[0])))


def _label_list(values, labels: dict[str, str]) -> str:
    return "".join(f"'{labels[value]}'" for value in sorted(values, key=lambda value: labels[value]))


def _end(equal, avoided: frozenset, labels: dict[str, str]) -> str:
    """The emitter event: ``<L.'/World/Lights/key'>``, ``B``; or what avoids `avoided`:
    ``(<L.[^'/World/Lights/key']>|O|B)``, ``[LOB]``."""
    if equal is not None:
        return "B" if equal == "B" else f"<{equal[0]}.'{labels[equal]}'>"
    parts = []
    for kind in "LO":
        listed = [value for value in avoided if value.startswith(kind + ":")]
        parts.append(f"<{kind}.[^{_label_list(listed, labels)}]>" if listed else kind)
    if "B" not in avoided:
        parts.append("B")
    if all(len(part) == 1 for part in parts):
        return parts[0] if len(parts) == 1 else "[" + "".join(parts) + "]"
    return parts[0] if len(parts) == 1 else "(" + "|".join(parts) + ")"


def _first(include: dict, exclude: dict, labels: dict[str, str]) -> str:
    """The first bounce: ``<RD'/World/Geometry/floor'>@(|S_C| = 0)`` and the like."""
    def letters(attribute: str, alphabet: str, wildcard: str) -> str:
        if attribute in include:
            return include[attribute]
        allowed = [letter for letter in alphabet if letter not in exclude.get(attribute, ())]
        if len(allowed) == len(alphabet):
            return wildcard
        return allowed[0] if len(allowed) == 1 else "[" + "".join(allowed) + "]"

    slots = [letters("type", SCATTERING_TYPES, f"[{SCATTERING_TYPES}]"), letters("scatter", SCATTERINGS, ".")]
    for attribute in ("object", "material"):
        if attribute in include:
            slots.append(f"'{labels[include[attribute]]}'")
        elif attribute in exclude:
            slots.append(f"[^{_label_list(exclude[attribute], labels)}]")
    tests = [f"{NORM_NAMES[attribute]} != 0" if attribute in include else f"{NORM_NAMES[attribute]} = 0"
             for attribute in COVARIANCE if attribute in include or attribute in exclude]
    return "<" + "".join(slots) + ">" + (f"@({' and '.join(tests)})" if tests else "")
