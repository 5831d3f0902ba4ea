"""A node of the hierarchy over path space: what it keeps of each attribute, its LPE, its name.

A node is a conjunction, one term per attribute it was split on: an attribute either equals
one value (the split's chosen side) or avoids a set of values (the other side, which grows
as it is split again), and the bounce count lies in a range. Each split turns a node into
two complementary nodes, so the leaves of any tree of splits partition path space; their
expressions are built to be complementary too (``<L.'key'>`` / ``<L.[^'key']>|[OB]``,
``@(|S_C| != 0)`` / ``@(|S_C| = 0)``), which :mod:`.partition` checks with the automaton.

A light group is a set of lights: its side ends at one of them (``<L.['/a''/b']>``, every
light the manifests put in the group, Atoms.members), the other side at any other emitter
(``(<L.[^'/a''/b']>|O|B)``); a light split within a group lists what is left of it.

A value of None (a first-bounce attribute of a path without bounces, a surface without a
material) avoids every set and equals nothing: such paths go with the "avoids" side.

Whole-path touches ("touches": any event of the path carries an object, material or asset)
are sets, not one value: a node requires some tokens (``touched``) and avoids others. Its
expression is then an exact set difference (docs/lpe.md): ``P - (C[^'X']* | C.*'Z'.*)``,
P the expression of its other terms, ``C[^'X']*`` the paths none of whose events carries
X (so subtracting it requires X) and ``C.*'Z'.*`` those that touch Z.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from ..paths.events import SCATTER_SINGULAR, SCATTERING_NAMES, SCATTERING_TYPES, SCATTERINGS
from .atoms import ATTRIBUTES, COVARIANCE, FIRST_BOUNCE

TOUCHES = "touches"
NAMING = frozenset({"group", "light", "object", "material", TOUCHES})
"""Attributes whose values are things an artist names and changes (a light group, a light,
an object, a material)."""
EMITTERS = frozenset({"group", "light"})
"""Attributes that pin whose light a node holds: a cut by bounce of one of them is nameable."""
BOUNCE_CUTS = frozenset({"scatter", "type", *COVARIANCE})
"""Attributes (with depth) that cut a named thing's light by how it bounced."""

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
LISTED_AT_MOST = 3
"""A node that avoids some lights (objects, materials) is named after those it is left with
when they are this many or fewer: "fill_sky"."""


@dataclass(frozen=True)
class Node:
    """include : attribute → the value it equals; exclude : attribute → values it avoids;
    depths : the bounce counts (0, 1, 2 = more) it holds."""

    include: tuple[tuple[str, str], ...] = ()
    exclude: tuple[tuple[str, frozenset], ...] = ()
    depths: frozenset = field(default=ALL_DEPTHS)
    touched: frozenset = frozenset()
    """Touch tokens the node's paths all carry at some event (exclude["touches"]: none of them)."""

    def split(self, attribute: str, value) -> tuple[Node, Node]:
        """(the side where `attribute` equals `value`, the side where it does not); for
        "depth", `value` is a threshold: (depth ≤ value, depth > value); for "touches", a
        token: (the paths that touch it, those that do not)."""
        if attribute == "depth":
            return (Node(self.include, self.exclude, frozenset(d for d in self.depths if d <= value), self.touched),
                    Node(self.include, self.exclude, frozenset(d for d in self.depths if d > value), self.touched))
        excluded = dict(self.exclude)
        avoided = excluded.pop(attribute, frozenset())
        if attribute == TOUCHES:
            equal = Node(self.include, self.exclude, self.depths, self.touched | {value})
        else:
            included = _sorted({**dict(self.include), attribute: value})
            equal = Node(included, _sorted(excluded), self.depths, self.touched)
        excluded[attribute] = avoided | {value}
        return equal, Node(self.include, _sorted(excluded), self.depths, self.touched)

    def pinned(self, attribute: str, value) -> Node:
        """The node with `attribute` equal to `value` in place of the values it avoids: the
        "avoids" side of a split whose paths, in every index, all carry that one value (the
        other of two light groups), so that its expression names it (``<L.['/a''/b']>``)."""
        excluded = dict(self.exclude)
        excluded.pop(attribute, None)
        return Node(_sorted({**dict(self.include), attribute: value}), _sorted(excluded), self.depths, self.touched)

    @property
    def terms(self) -> int:
        """How many terms the node's expression tests: the LPE length penalty counts these."""
        return (len(self.include) + sum(len(values) for _, values in self.exclude) + (self.depths != ALL_DEPTHS)
                + len(self.touched))

    def expression(self, labels: dict[str, str], members: dict[str, tuple[str, ...]] | None = None) -> str:
        """The node's LPE. labels : value → the label its events carry (prim paths);
        members : group value → its light values (Atoms.members; needed for a group term)."""
        positive = Node(self.include, tuple(item for item in self.exclude if item[0] != TOUCHES),
                        self.depths)._plain_expression(labels, members or {})
        avoided = dict(self.exclude).get(TOUCHES, frozenset())
        subtracted = [f"C[^{_label_list([token], labels)}]*" for token in sorted(self.touched)]
        subtracted += [f"C.*{_label_list([token], labels)}.*" for token in sorted(avoided)]
        if not subtracted:
            return positive
        return f"{positive} - " + (subtracted[0] if len(subtracted) == 1 else "(" + "|".join(subtracted) + ")")

    def _plain_expression(self, labels: dict[str, str], members: dict[str, tuple[str, ...]]) -> str:
        """The expression of every term but the touches: a plain LPE (no difference)."""
        if not self.include and not self.exclude and self.depths == ALL_DEPTHS:
            return "C.*"
        include, exclude = dict(self.include), dict(self.exclude)
        end = _end(include, exclude, labels, members)
        alternatives = []
        first_bounce_equal = any(attribute in FIRST_BOUNCE for attribute in include)
        if 0 in self.depths and not first_bounce_equal:
            alternatives.append("C" + end)
        bounced = sorted(self.depths - {0})
        if bounced:
            middle = {(1,): "", (2,): ".+", (1, 2): ".*"}[tuple(bounced)]
            alternatives.append("C" + _first(include, exclude, labels) + middle + end)
        return "|".join(alternatives)

    def named_terms(self, present: list[dict]) -> dict[str, object]:
        """The terms that name something an artist can change: attribute → value for the
        light group, light, the first bounce's object and material it equals or is left with one value of
        among `present` (whether the node tests it or the stage has only one: "lamp"), or a
        tuple of the LISTED_AT_MOST values it is left with when it avoids some ("fill",
        "sky"); and "touches" → the tokens it requires. Empty: it names nothing."""
        include, exclude = dict(self.include), dict(self.exclude)
        found: dict[str, object] = {}
        for attribute in ("group", "light", "object", "material"):
            if attribute in include:
                found[attribute] = include[attribute]
                continue
            if attribute == "light" and "group" in found and "light" not in exclude:
                continue  # the group names whose light it is; its lights are not terms
            left = sorted({atom.get(attribute) for atom in present}, key=str)  # no "group": none
            if None in left or not left:
                continue
            if len(left) == 1 and (attribute in exclude or attribute == "light"):
                found[attribute] = left[0]
            elif attribute in exclude and len(left) <= LISTED_AT_MOST:
                found[attribute] = tuple(left)
        if self.touched:
            found[TOUCHES] = tuple(sorted(self.touched))
        return found

    def nameable(self, single: frozenset | set) -> bool:
        """Whether an artist can name what the node holds (docs/suggest.md, "Names"): it has a
        term on a light, an object, a material or a touch, and it cuts by bounce count, lobe
        or covariance only when it also pins one light ("the red light's indirect light",
        not "the indirect light on white"; a light group counts as a light). single : the
        attributes among group, light, object, material whose lit atoms in the node hold one
        value (present or not in its terms)."""
        terms = {attribute for attribute, _ in (*self.include, *self.exclude)}
        if not terms and not self.touched and self.depths == ALL_DEPTHS:
            return True  # the whole of path space: the beauty
        if not (terms & NAMING or self.touched):
            return False
        cuts = self.depths != ALL_DEPTHS or bool(terms & BOUNCE_CUTS)
        return not cuts or bool(EMITTERS & set(dict(self.include))) or bool(EMITTERS & terms & set(single))

    def name(self, present: list[dict], names: dict[str, str]) -> str:
        """A readable identifier from the node's terms: ``key_on_floor_diffuse_direct``,
        ``lamp_via_mirror``. present : the attribute values of the atoms the node holds that
        carry light; an attribute it avoids values of is named when they leave one value present."""
        include, exclude = dict(self.include), dict(self.exclude)
        named = self.named_terms(present)
        parts = []
        for attribute in ATTRIBUTES:
            if attribute == TOUCHES:
                parts += [f"via_{names.get(token, token)}" for token in named.get(TOUCHES, ())]
                avoided = sorted(exclude.get(TOUCHES, ()))
                if len(avoided) == 1:
                    parts.append(f"without_{names.get(avoided[0], avoided[0])}")
                continue
            if attribute == "depth":
                # "bounced" says nothing a first-bounce value it equals does not already say
                implied = self.depths == frozenset({1, 2}) and any(name in FIRST_BOUNCE for name in include)
                if self.depths != ALL_DEPTHS and not implied:
                    parts.append(DEPTH_WORDS[self.depths])
                continue
            if attribute in named and isinstance(named[attribute], tuple):
                parts.append("_".join(_word(attribute, value, names) for value in named[attribute]))
                continue
            if attribute in named:
                value = named[attribute]
            elif attribute in include:
                value = include[attribute]
            elif attribute in exclude and attribute in COVARIANCE:
                parts.append(COVARIANCE_WORDS[attribute][1])
                continue
            else:
                continue
            parts.append(_word(attribute, value, names))
        words = [part for part in parts if part]
        if not words:
            return REST
        text = re.sub(r"[^A-Za-z0-9_]+", "_", "_".join(dict.fromkeys(words))).strip("_")
        return text if re.match(r"[A-Za-z_]", text) else "layer_" + text

    def explain(self, present: list[dict], names: dict[str, str]) -> str:
        """One line an artist reads: "the red light's direct diffuse light on the shelf",
        "the lamp light's light on the wall by way of the mirror"."""
        include, exclude = dict(self.include), dict(self.exclude)
        named = self.named_terms(present)

        def called(value) -> str:
            return names.get(value, str(value))

        def listed(values) -> str:
            values = [called(value) for value in values]
            return values[0] if len(values) == 1 else ", ".join(values[:-1]) + " and " + values[-1]

        light = named.get("light")
        group = named.get("group")
        if group is not None and light is None:
            groups = group if isinstance(group, tuple) else (group,)
            whose = f"the {listed(groups)} groups'" if len(groups) > 1 else f"the {listed(groups)} group's"
            if "light" in exclude:
                whose += f", but {listed(sorted(exclude['light']))}'s,"
        elif isinstance(light, tuple):
            whose = f"the {listed(light)} lights'"
        elif light == "B":
            whose = "the background's"
        elif light is not None:
            whose = f"{called(light)}'s" if str(light).startswith("O:") else f"the {called(light)} light's"
        elif "light" in exclude or "group" in exclude:
            avoided = [*(f"the {called(value)} group" for value in sorted(exclude.get("group", ()))),
                       *sorted(exclude.get("light", ()))]
            whose = f"every light's but {listed(avoided)}'s"
        else:
            whose = "every light's"
        kind = {frozenset({0}): "", frozenset({1}): "direct", frozenset({2}): "indirect",
                frozenset({0, 1}): "direct and directly seen"}.get(self.depths, "")
        lobe = []
        if "type" in include and TYPE_WORDS[include["type"]]:
            lobe.append(TYPE_WORDS[include["type"]])
        if "scatter" in include:
            lobe.append(SCATTER_WORDS[include["scatter"]])
        elif "scatter" in exclude:
            lobe.append("non-" + "/".join(SCATTER_WORDS[value] for value in sorted(exclude["scatter"])))
        words = " ".join(word for word in (kind, *lobe) if word)
        if self.depths == frozenset({0}):
            text = f"{whose} emitter seen directly"
        else:
            text = f"{whose} {words + ' ' if words else ''}light"
        objects = named.get("object")
        if objects is not None:
            text += f" on the {listed(objects if isinstance(objects, tuple) else (objects,))}"
        elif "object" in exclude:
            text += f" on anything but the {listed(sorted(exclude['object']))}"
        materials = named.get("material")
        if materials is not None:
            text += f" ({listed(materials if isinstance(materials, tuple) else (materials,))} material)"
        elif "material" in exclude:
            text += f" (any material but {listed(sorted(exclude['material']))})"
        covariance = [COVARIANCE_WORDS[attribute][0 if attribute in include else 1]
                      for attribute in COVARIANCE if attribute in include or attribute in exclude]
        if covariance:
            text += " where the first bounce is " + ", ".join(covariance)
        if self.touched:
            text += f" by way of the {listed(sorted(self.touched))}"
        avoided = sorted(exclude.get(TOUCHES, ()))
        if avoided:
            text += f", never touching the {listed(avoided)}"
        return text


def _word(attribute: str, value, names: dict[str, str]) -> str:
    if attribute in EMITTERS:
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


def _end(include: dict, exclude: dict, labels: dict[str, str], members: dict[str, tuple[str, ...]]) -> str:
    """The emitter event of a node's light and group terms: ``<L.'/World/Lights/key'>``,
    ``B``, a group's lights ``<L.['/a''/b']>`` (less the lights it avoids); or what avoids
    lights and groups: ``(<L.[^'/World/Lights/key']>|O|B)``, ``[LOB]``."""
    equal = include.get("light")
    avoided = set(exclude.get("light", frozenset()))
    if equal is not None:
        return "B" if equal == "B" else f"<{equal[0]}.'{labels[equal]}'>"
    if "group" in include:
        left = [light for light in members[include["group"]] if light not in avoided]
        return f"<L.{_label_list(left, labels)}>" if len(left) == 1 else f"<L.[{_label_list(left, labels)}]>"
    for group in exclude.get("group", ()):
        avoided.update(members[group])
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
