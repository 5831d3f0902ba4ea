"""Recursive-descent parser: query text → expression tree (:mod:`.nodes`).

Grammar (standard regular-expression precedence: repetition, then concatenation, then
alternation; see docs/lpe.md for the EBNF and every difference from OSL)::

    query       = alternation { "-" alternation } END    (set difference: our extension)
    expression  = alternation
    alternation = sequence { "|" sequence }
    sequence    = postfix { postfix }
    postfix     = atom { condition } [ repetition ]
    atom        = event | "(" alternation ")" | "[" postfix { postfix } "]"
    event       = TYPE | SCATTER | "." | LABEL | "[^" symbol { symbol } "]"
                | "<" { slot } ">"
    slot        = TYPE | SCATTER | "." | LABEL | "[" symbol { symbol } "]" | "[^" symbol { symbol } "]"
"""

from __future__ import annotations

from ..errors import LpeSyntaxError
from ..paths.events import NO_SCATTERING_LETTER
from . import nodes
from .automaton import nfa_state_count
from .lexer import Kind, Token, tokenize
from .limits import MAX_NESTING, MAX_NFA_STATES
from .nodes import ANY_LABEL, EventPattern, LabelTerm, SymbolSet

_EVENT_STARTS = {Kind.TYPE, Kind.SCATTER, Kind.DOT, Kind.LABEL, Kind.OPEN_GROUP, Kind.OPEN_NEGATED_SET}
_ATOM_STARTS = _EVENT_STARTS | {Kind.OPEN_PAREN, Kind.OPEN_SET}
_REPETITIONS = {Kind.STAR: (0, None), Kind.PLUS: (1, None), Kind.QUESTION: (0, 1)}
_SLOT_NAMES = ("event type", "scattering")


def parse(query: str) -> nodes.Node:
    """Parse a Light Path Expression. Raises LpeSyntaxError whose message starts with the
    position of the fault ("position 13: expected '>' ...") and says what was expected."""
    try:
        return _Parser(query).parse()
    except LpeSyntaxError as error:
        raise LpeSyntaxError(f"position {error.position}: {error.message}", error.query, error.position) from None


class _Parser:
    def __init__(self, query: str):
        self.query = query
        self.tokens = tokenize(query)
        self.index = 0
        self.depth = 0  # groups and sets open at the current token
        self.sizes: dict = {}  # nfa_state_count's memo, shared as the tree grows
        self.single_events: dict[tuple[Kind, object], EventPattern] = {}  # one object per letter, label or '.'

    @property
    def token(self) -> Token:
        return self.tokens[self.index]

    def advance(self) -> Token:
        token = self.tokens[self.index]
        self.index += 1
        return token

    def error(self, message: str, position: int | None = None) -> LpeSyntaxError:
        return LpeSyntaxError(message, self.query, self.token.position if position is None else position)

    def parse(self) -> nodes.Node:
        if self.token.kind is Kind.END:
            raise self.error("empty expression")
        first = self.token.position
        tree = self.alternation()
        negatives, positions = [], []
        while self.token.kind is Kind.MINUS:
            self.advance()
            if self.token.kind not in _ATOM_STARTS:
                raise self.error("expected an expression after '-' (set difference: A - B)")
            positions.append(self.token.position)
            negatives.append(self.alternation())
        if negatives:
            # A - B - C is A - (B|C): one regular expression for everything subtracted.
            tree = self.checked_size(nodes.Difference(tree, nodes.union(negatives)), [tree, *negatives],
                                     [first, *positions], "part")
        if self.token.kind is Kind.CLOSE_PAREN:
            raise self.error("unexpected ')': no '(' is open")
        if self.token.kind is not Kind.END:
            raise self.error(self._unexpected_here())
        return tree

    def alternation(self) -> nodes.Node:
        positions = [self.token.position]
        alternatives = [self.sequence()]
        while self.token.kind is Kind.BAR:
            self.advance()
            positions.append(self.token.position)
            alternatives.append(self.sequence())
        return self.checked_size(nodes.union(alternatives), alternatives, positions, "alternative")

    def sequence(self) -> nodes.Node:
        if self.token.kind not in _ATOM_STARTS:
            raise self.error(self._unexpected_here())
        items, positions = [], []
        while self.token.kind in _ATOM_STARTS:
            positions.append(self.token.position)
            items.append(self.postfix())
        return self.checked_size(nodes.concat(items), items, positions, "item")

    def checked_size(self, node: nodes.Node, parts: list, positions: list[int], part_name: str) -> nodes.Node:
        """``node``, made of ``parts`` (which start at ``positions``), unless its NFA passes
        MAX_NFA_STATES: then a syntax error at the part that takes it past."""
        if nfa_state_count(node, self.sizes) <= MAX_NFA_STATES:
            return node
        running = 0
        for part, position in zip(parts, positions):
            # Caret at the part where the running count passes the limit (or at the last part:
            # flattening a group into the enclosing sequence saves a state, so the count of
            # the parts taken whole is within a state or two of the node's own).
            running += nfa_state_count(part, self.sizes)
            if running > MAX_NFA_STATES:
                break
        raise self.error(
            f"the expression is too large at this {part_name}: its automaton would have more than "
            f"{MAX_NFA_STATES} states (MAX_NFA_STATES, see docs/lpe.md); split it into several layers",
            position,
        )

    def postfix(self) -> nodes.Node:
        atom = self.atom()
        while self.token.kind is Kind.CONDITION:
            if not isinstance(atom, EventPattern):
                raise self.error(
                    "a condition follows one event (a letter, '.', a label, <...> or a set of letters); "
                    "put it inside the group, after the event it is about"
                )
            atom = atom.with_condition(self.advance().value)
        if self.token.kind in _REPETITIONS or self.token.kind is Kind.RANGE:
            token = self.advance()
            minimum, maximum = token.value if token.kind is Kind.RANGE else _REPETITIONS[token.kind]
            body_size = nfa_state_count(atom, self.sizes)
            atom = nodes.repeat(atom, minimum, maximum)
            size = nfa_state_count(atom, self.sizes)
            if size > MAX_NFA_STATES:
                copies = minimum + 1 if maximum is None else maximum
                raise self.error(
                    f"this repetition makes the expression too large: {copies} copies of {body_size} "
                    f"automaton states are {size}, more than the {MAX_NFA_STATES} an expression may have "
                    "(MAX_NFA_STATES, see docs/lpe.md); repeat fewer times, or repeat a shorter expression",
                    token.position,
                )
            if self.token.kind in _REPETITIONS or self.token.kind is Kind.RANGE:
                raise self.error("two repetitions in a row: use parentheses, e.g. (R*){2}")
            if self.token.kind is Kind.CONDITION:
                raise self.error("a condition follows an event, not a repetition: write D@(...)* rather than D*@(...)")
        return atom

    def atom(self) -> nodes.Node:
        token = self.token
        if token.kind in (Kind.OPEN_PAREN, Kind.OPEN_SET):
            if self.depth == MAX_NESTING:
                raise self.error(f"groups and sets nest more than {MAX_NESTING} deep here")
            self.depth += 1
            try:
                return self._group(token)
            finally:
                self.depth -= 1
        return self.event()

    def _group(self, token: Token) -> nodes.Node:
        """``(...)`` or ``[...]`` starting at `token`."""
        if token.kind is Kind.OPEN_PAREN:
            self.advance()
            if self.token.kind is Kind.CLOSE_PAREN:
                raise self.error(f"expected an expression inside the '(' at position {token.position}: "
                                 "empty parentheses")
            inner = self.alternation()
            if self.token.kind is Kind.END:
                raise self.error(f"expected ')' to close the '(' at position {token.position}")
            if self.token.kind is not Kind.CLOSE_PAREN:
                raise self.error(f"expected ')' to close the '(' at position {token.position}: "
                                 f"{self._unexpected_here()}")
            self.advance()
            return inner
        return self.alternative_set()

    def alternative_set(self) -> nodes.Node:
        """``[...]`` outside ``<...>``: any one of its items (OSL's "or list")."""
        opening = self.advance()
        items, positions = [], []
        while self.token.kind is not Kind.CLOSE_SET:
            if self.token.kind is Kind.END:
                raise self.error(f"expected ']' to close the '[' at position {opening.position}")
            if self.token.kind not in _ATOM_STARTS:
                raise self.error(f"expected an item or ']' to close the '[' at position {opening.position}: "
                                 f"{self._unexpected_here()}")
            positions.append(self.token.position)
            items.append(self.postfix())
        self.advance()
        if not items:
            raise self.error(f"expected an item inside the '[' at position {opening.position}: empty set []",
                             opening.position)
        return _fold_letter_set(items) or self.checked_size(nodes.union(items), items, positions, "item")

    def event(self) -> EventPattern:
        token = self.token
        if token.kind is Kind.OPEN_GROUP:
            return self.group()
        if token.kind is Kind.OPEN_NEGATED_SET:
            kind, symbols = self.symbol_list()
            return _event_with_slot(kind, SymbolSet(frozenset(symbols), negated=True), symbols)
        self.advance()
        found = self.single_events.get((token.kind, token.value))
        if found is None:
            # Trees are immutable, so equal events share one object: long runs of letters
            # (``[RRRR...]``) then cost one dictionary look-up each.
            found = self.single_events[token.kind, token.value] = self.single_event(token)
        return found

    def single_event(self, token: Token) -> EventPattern:
        if token.kind is Kind.TYPE:
            return EventPattern(types=SymbolSet(frozenset([token.value])))
        if token.kind is Kind.SCATTER:
            return EventPattern(scatters=SymbolSet(frozenset([token.value])))
        if token.kind is Kind.LABEL:
            return EventPattern(labels=(LabelTerm((token.value,)),))
        if token.kind is Kind.DOT:
            return EventPattern()
        raise self.error(self._unexpected_here(), token.position)  # unreachable: callers check starts

    def group(self) -> EventPattern:
        """``<type scattering 'label'...>``: slots by position, missing ones are wildcards."""
        opening = self.advance()
        types = scatters = None
        labels: list[LabelTerm] = []
        slot = 0
        while self.token.kind is not Kind.CLOSE_GROUP:
            token = self.token
            if token.kind is Kind.END:
                raise self.error(f"expected '>' to close the event '<' opened at position {opening.position}")
            problem = _GROUP_PROBLEMS.get(token.kind)
            if problem:
                position = token.position
                if token.kind in _REPETITIONS and self.tokens[self.index - 1].kind is Kind.DOT:
                    # <RD'wall'.*L: the '>' was meant before the '.*'
                    position = self.tokens[self.index - 1].position
                raise self.error(f"expected '>' to close the event '<' opened at position {opening.position}: "
                                 f"{problem}", position)
            if token.kind is Kind.DOT:
                self.advance()
                if slot >= 2:
                    labels.append(LabelTerm((ANY_LABEL,)))
            else:
                kind, symbols, negated = self.slot_symbols()
                expected = (Kind.TYPE, Kind.SCATTER, Kind.LABEL)[min(slot, 2)]
                if kind is not expected:
                    raise self.error(_slot_mismatch(slot, kind, symbols), token.position)
                if kind is Kind.LABEL:
                    labels.append(LabelTerm(tuple(dict.fromkeys(symbols)), negated))
                elif slot == 0:
                    types = SymbolSet(frozenset(symbols), negated)
                else:
                    scatters = SymbolSet(frozenset(symbols), negated)
            slot += 1
        self.advance()
        return EventPattern(types, scatters, tuple(labels))

    def slot_symbols(self) -> tuple[Kind, list[str], bool]:
        """One slot of a group: a letter, a label, or a [..] / [^..] list of one kind."""
        token = self.token
        if token.kind in (Kind.OPEN_SET, Kind.OPEN_NEGATED_SET):
            kind, symbols = self.symbol_list()
            return kind, symbols, token.kind is Kind.OPEN_NEGATED_SET
        self.advance()
        return token.kind, [token.value], False

    def symbol_list(self) -> tuple[Kind, list[str]]:
        """``[...]`` or ``[^...]`` of plain symbols, all of one kind (letters of one slot, or labels)."""
        opening = self.advance()
        kind = None
        symbols = []
        while self.token.kind is not Kind.CLOSE_SET:
            token = self.token
            if token.kind is Kind.END:
                raise self.error(f"expected ']' to close the '[' at position {opening.position}")
            if token.kind not in (Kind.TYPE, Kind.SCATTER, Kind.LABEL):
                raise self.error(f"expected an event letter, a quoted label or ']' to close the '[' at position "
                                 f"{opening.position}: only letters or labels can be listed here")
            if kind is not None and token.kind is not kind:
                raise self.error(
                    f"this list mixes {_KIND_NAMES[kind]} and {_KIND_NAMES[token.kind]}; "
                    "one list holds symbols of one slot (write <[RT][DG]> for both)"
                )
            kind = token.kind
            symbols.append(self.advance().value)
        self.advance()
        if not symbols:
            raise self.error(f"expected a letter or a label inside the '[' at position {opening.position}: "
                             "empty list", opening.position)
        return kind, symbols

    def _unexpected_here(self) -> str:
        token = self.token
        if token.kind is Kind.END:
            return "the expression ends early: expected an event"
        if token.kind is Kind.BAR:
            return ("expected an event before '|': an alternative cannot be empty ('|' needs an expression on both "
                    "sides)")
        if token.kind is Kind.MINUS:
            return ("unexpected '-': a set difference takes whole expressions on both sides, at the top level only "
                    "(A - B, A - (B|C); not (A - B), A|-B or -A)")
        if token.kind in _REPETITIONS or token.kind is Kind.RANGE:
            return "expected an event: a repetition must follow an event or a group"
        if token.kind is Kind.CONDITION:
            return "expected an event: a condition must follow an event"
        if token.kind is Kind.CLOSE_GROUP:
            return "unexpected '>' without a matching '<' (expected an event)"
        if token.kind is Kind.CLOSE_SET:
            return "unexpected ']' without a matching '[' (expected an event)"
        if token.kind is Kind.CLOSE_PAREN:
            return ("unexpected ')' without a matching '('" if self._paren_depth() == 0
                    else "expected an event before ')': an alternative cannot be empty")
        return "unexpected token"

    def _paren_depth(self) -> int:
        depth = 0
        for token in self.tokens[: self.index]:
            depth += {Kind.OPEN_PAREN: 1, Kind.CLOSE_PAREN: -1}.get(token.kind, 0)
        return depth


_KIND_NAMES = {Kind.TYPE: "event types", Kind.SCATTER: "scatterings", Kind.LABEL: "labels"}

_GROUP_PROBLEMS = {
    Kind.OPEN_GROUP: "no <...> inside <...>",
    Kind.MINUS: "no '-' inside <...>: a set difference takes whole expressions, A - B",
    Kind.OPEN_PAREN: "no (...) inside <...>: list alternatives of one slot with [...]",
    Kind.BAR: "no '|' inside <...>: list alternatives of one slot with [...]",
    Kind.STAR: "repetitions are not allowed inside <...>",
    Kind.PLUS: "repetitions are not allowed inside <...>",
    Kind.QUESTION: "repetitions are not allowed inside <...>",
    Kind.RANGE: "repetitions are not allowed inside <...>",
    Kind.CONDITION: "a condition goes after the closing '>': <RD>@(...)",
    Kind.CLOSE_SET: "']' without a matching '['",
    Kind.CLOSE_PAREN: "')' inside <...>",
}


def _slot_mismatch(slot: int, kind: Kind, symbols: list[str]) -> str:
    shown = symbols[0] if kind is not Kind.LABEL else f"'{symbols[0]}'"
    if kind is Kind.LABEL:
        return f"labels come after the type and scattering slots: <..{shown}>, <R.{shown}>"
    if slot >= 2:
        return f"{shown} is not a label: after the type and scattering slots come quoted labels only"
    where = _SLOT_NAMES[slot]
    if kind is Kind.SCATTER:
        letter = shown or NO_SCATTERING_LETTER
        return f"{letter} is a scattering but this slot is the {where}: write <.{letter}> (slots are positional)"
    return f"{shown} is an event type but this slot is the {where}: write <{shown}.> (slots are positional)"


def _event_with_slot(kind: Kind, symbols: SymbolSet, raw: list[str]) -> EventPattern:
    if kind is Kind.TYPE:
        return EventPattern(types=symbols)
    if kind is Kind.SCATTER:
        return EventPattern(scatters=symbols)
    return EventPattern(labels=(LabelTerm(tuple(dict.fromkeys(raw)), symbols.negated),))


def _fold_letter_set(items) -> EventPattern | None:
    """``[RT]``, ``[DG]``, ``['a' 'b']``: a set of single-slot events is one event with a set.

    Folding keeps one event, so a condition can follow the set: ``[RT]@(...)``.
    """
    if not all(isinstance(item, EventPattern) and item.condition is None for item in items):
        return None
    if all(_constrains_only(item, "types") and not item.types.negated for item in items):
        return EventPattern(types=SymbolSet(frozenset().union(*(item.types.symbols for item in items))))
    if all(_constrains_only(item, "scatters") and not item.scatters.negated for item in items):
        return EventPattern(scatters=SymbolSet(frozenset().union(*(item.scatters.symbols for item in items))))
    single_positive_label = all(
        _constrains_only(item, "labels") and len(item.labels) == 1 and not item.labels[0].negated for item in items
    )
    if single_positive_label:
        patterns = tuple(dict.fromkeys(pattern for item in items for pattern in item.labels[0].patterns))
        return EventPattern(labels=(LabelTerm(patterns),))
    return None


def _constrains_only(event: EventPattern, slot: str) -> bool:
    """Whether the event's only constraint is on ``slot`` ('types', 'scatters' or 'labels')."""
    given = {"types": event.types is not None, "scatters": event.scatters is not None, "labels": bool(event.labels)}
    return given[slot] and sum(given.values()) == 1
