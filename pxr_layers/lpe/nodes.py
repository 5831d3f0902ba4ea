"""The expression tree of a Light Path Expression and its canonical spelling.

Leaves are :class:`EventPattern` (one event: type set, scattering set, label terms and an
optional covariance condition); inner nodes are :class:`Concat`, :class:`Union` and
:class:`Repeat`. Build inner nodes with :func:`concat`, :func:`union` and :func:`repeat`:
they flatten nesting, so that two spellings of the same structure give equal trees (the
canonical form parses back to the very tree it was printed from).

The canonical form (:func:`canonical`) is plain OSL whenever the expression uses no
extension (no ``?`` is printed: ``{0,1}`` is OSL), with two safety rules for OSL's quirks:
an alternative of several items is parenthesised (OSL's ``|`` binds only its two neighbours)
and a form that would start with ``(`` is wrapped in one more pair (OSL drops whatever
follows a leading parenthesised group).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..paths.events import ALL_SCATTERINGS, EVENT_TYPES, NO_SCATTERING, NO_SCATTERING_LETTER, SCATTERINGS
from . import conditions as cond
from .events import Event, label_matches

ANY_LABEL = "*"
"""The pattern of a ``.`` in a label slot of ``<...>``: "carries at least one label"."""

TYPE_ORDER = EVENT_TYPES
SCATTER_ORDER = (*SCATTERINGS, NO_SCATTERING)
_EVERY_TYPE = frozenset(EVENT_TYPES)
_EVERY_SCATTERING = frozenset(ALL_SCATTERINGS)


@dataclass(frozen=True)
class SymbolSet:
    """A set of letters of one slot (types or scatterings), possibly negated (``[^...]``)."""

    symbols: frozenset[str]
    negated: bool = False

    def __contains__(self, symbol: str) -> bool:
        return (symbol in self.symbols) != self.negated


@dataclass(frozen=True)
class LabelTerm:
    """One label slot: the event carries a label matching one of ``patterns``
    (negated: it carries no label matching any of them). Patterns may be fnmatch globs."""

    patterns: tuple[str, ...]
    negated: bool = False

    def matches(self, labels: frozenset[str]) -> bool:
        found = any(label_matches(pattern, label) for pattern in self.patterns for label in labels)
        return found != self.negated


@dataclass(frozen=True)
class EventPattern:
    """One event of an expression: every given slot must match. ``None`` slots are wildcards.

    condition : a covariance condition the matched event's stored quantities must pass.
    """

    types: SymbolSet | None = None
    scatters: SymbolSet | None = None
    labels: tuple[LabelTerm, ...] = ()
    condition: cond.Condition | None = None

    def __post_init__(self):
        # A positive set naming every letter is a wildcard: normalise so that equal
        # meanings give equal trees.
        if self.types is not None and not self.types.negated and self.types.symbols >= _EVERY_TYPE:
            object.__setattr__(self, "types", None)
        if self.scatters is not None and not self.scatters.negated and self.scatters.symbols >= _EVERY_SCATTERING:
            object.__setattr__(self, "scatters", None)

    def matches_event(self, event: Event) -> bool:
        """Type, scattering and labels match (the condition is not looked at)."""
        return (
            (self.types is None or event.type in self.types)
            and (self.scatters is None or event.scatter in self.scatters)
            and all(term.matches(event.labels) for term in self.labels)
        )

    def with_condition(self, condition: cond.Condition) -> EventPattern:
        combined = condition if self.condition is None else cond.all_of([self.condition, condition])
        return EventPattern(self.types, self.scatters, self.labels, combined)


@dataclass(frozen=True)
class Concat:
    items: tuple


@dataclass(frozen=True)
class Union:
    alternatives: tuple


@dataclass(frozen=True)
class Repeat:
    """``body`` repeated between ``minimum`` and ``maximum`` times (None: unbounded)."""

    body: object
    minimum: int
    maximum: int | None


@dataclass(frozen=True)
class Difference:
    """``positive - negative``: the paths ``positive`` matches and ``negative`` does not.

    Our extension (OSL has no set difference); only at the top of a layer's expression, so
    ``negative`` and ``positive`` hold no Difference. Conditions on either side are read
    with each record's own covariance: a record belongs when it matches ``positive`` and
    not ``negative`` (see docs/lpe.md, "Set difference").
    """

    positive: object
    negative: object


Node = EventPattern | Concat | Union | Repeat | Difference


def concat(items) -> Node:
    return cond.flattened(Concat, "items", items)


def union(alternatives) -> Node:
    return cond.flattened(Union, "alternatives", alternatives)


def repeat(body: Node, minimum: int, maximum: int | None) -> Node:
    if minimum == 1 and maximum == 1:
        return body
    return Repeat(body, minimum, maximum)


def walk(node: Node):
    """Every node of the tree, parents before children."""
    yield node
    if isinstance(node, Difference):
        yield from walk(node.positive)
        yield from walk(node.negative)
        return
    children = {Concat: "items", Union: "alternatives"}.get(type(node))
    if children:
        for child in getattr(node, children):
            yield from walk(child)
    elif isinstance(node, Repeat):
        yield from walk(node.body)


def event_patterns(node: Node) -> list[EventPattern]:
    return [item for item in walk(node) if isinstance(item, EventPattern)]


def label_patterns(node: Node) -> list[str]:
    """Every quoted label of the tree, in order of appearance, without repeats."""
    found = (pattern for event in event_patterns(node) for term in event.labels for pattern in term.patterns)
    return list(dict.fromkeys(found))


def has_conditions(node: Node) -> bool:
    return any(event.condition is not None for event in event_patterns(node))


# --- canonical spelling ----------------------------------------------------------------


def canonical(node: Node) -> str:
    """The canonical text of a tree; parsing it gives the same tree back."""
    if isinstance(node, Difference):
        negative = node.negative
        subtracted = event_text(negative) if isinstance(negative, EventPattern) else f"({_alternation_text(negative)})"
        return f"{canonical(node.positive)}-{subtracted}"
    text = _alternation_text(node)
    return f"({text})" if text.startswith("(") else text


def _alternation_text(node: Node) -> str:
    if isinstance(node, Union):
        return "|".join(_alternative_text(alternative) for alternative in node.alternatives)
    return _sequence_text(node)


def _alternative_text(node: Node) -> str:
    # OSL's '|' takes one item on each side, so a multi-item alternative needs parentheses.
    return f"({_sequence_text(node)})" if isinstance(node, Concat) else _sequence_text(node)


def _sequence_text(node: Node) -> str:
    if isinstance(node, Concat):
        return "".join(_postfix_text(item) for item in node.items)
    return _postfix_text(node)


def _postfix_text(node: Node) -> str:
    if isinstance(node, EventPattern):
        return event_text(node)
    if isinstance(node, Repeat):
        body = event_text(node.body) if isinstance(node.body, EventPattern) else f"({_alternation_text(node.body)})"
        return body + _repetition_text(node.minimum, node.maximum)
    return f"({_alternation_text(node)})"


def _repetition_text(minimum: int, maximum: int | None) -> str:
    if maximum is None:
        return {0: "*", 1: "+"}.get(minimum, f"{{{minimum},}}")
    return f"{{{minimum}}}" if minimum == maximum else f"{{{minimum},{maximum}}}"


def event_text(event: EventPattern) -> str:
    text = _event_body_text(event)
    return text + cond.canonical(event.condition) if event.condition is not None else text


def _event_body_text(event: EventPattern) -> str:
    given = [event.types is not None, event.scatters is not None, bool(event.labels)]
    if not any(given):
        return "."
    if given == [True, False, False]:
        return _set_text(event.types, TYPE_ORDER)
    if given == [False, True, False]:
        return _set_text(event.scatters, SCATTER_ORDER)
    if given == [False, False, True] and len(event.labels) == 1:
        return _label_term_text(event.labels[0])
    type_slot = "." if event.types is None else _set_text(event.types, TYPE_ORDER)
    scatter_slot = "." if event.scatters is None else _set_text(event.scatters, SCATTER_ORDER)
    return f"<{type_slot}{scatter_slot}{''.join(_label_term_text(term) for term in event.labels)}>"


def _letter(symbol: str) -> str:
    return NO_SCATTERING_LETTER if symbol == NO_SCATTERING else symbol


def _set_text(symbols: SymbolSet, order) -> str:
    letters = "".join(_letter(symbol) for symbol in order if symbol in symbols.symbols)
    if symbols.negated:
        return f"[^{letters}]"
    return letters if len(letters) == 1 else f"[{letters}]"


def _label_term_text(term: LabelTerm) -> str:
    quoted = "".join(f"'{pattern}'" for pattern in term.patterns)
    if term.negated:
        return f"[^{quoted}]"
    return quoted if len(term.patterns) == 1 else f"[{quoted}]"
