"""Tokens of a Light Path Expression.

Whitespace between tokens is ignored (OSL accepts none; the paper's notation has spaces).
A covariance condition (``C(|S_C| = 0)``, ``@(...)``) is read whole by
:mod:`.conditions` and comes out as one CONDITION token carrying its tree.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from enum import Enum, auto

from ..errors import LpeSyntaxError
from ..paths.events import EVENT_TYPES, NO_SCATTERING, NO_SCATTERING_LETTER, SCATTERINGS
from . import conditions
from .limits import MAX_QUERY_LENGTH, MAX_REPETITION, MAX_TOKENS


class Kind(Enum):
    TYPE = auto()  # C R T V L O B
    SCATTER = auto()  # D G S s, and x for none
    DOT = auto()
    LABEL = auto()  # 'name'
    OPEN_GROUP = auto()  # <
    CLOSE_GROUP = auto()  # >
    OPEN_SET = auto()  # [
    OPEN_NEGATED_SET = auto()  # [^
    CLOSE_SET = auto()  # ]
    OPEN_PAREN = auto()
    CLOSE_PAREN = auto()
    BAR = auto()  # |
    MINUS = auto()  # - set difference, top level only (our extension)
    STAR = auto()
    PLUS = auto()
    QUESTION = auto()
    RANGE = auto()  # {n} {n,} {n,m}
    CONDITION = auto()
    END = auto()


@dataclass(frozen=True)
class Token:
    """kind; value: the letter, the label text, (min, max) of a range, or a condition tree;
    position: offset of the token's first character in the query."""

    kind: Kind
    value: object
    position: int


_PUNCTUATION = {
    ".": Kind.DOT,
    "<": Kind.OPEN_GROUP,
    ">": Kind.CLOSE_GROUP,
    "]": Kind.CLOSE_SET,
    "(": Kind.OPEN_PAREN,
    ")": Kind.CLOSE_PAREN,
    "|": Kind.BAR,
    "-": Kind.MINUS,
    "*": Kind.STAR,
    "+": Kind.PLUS,
    "?": Kind.QUESTION,
}


def tokenize(query: str) -> list[Token]:
    """All tokens of the query, ending with one END token. Raises LpeSyntaxError."""
    if len(query) > MAX_QUERY_LENGTH:
        message = f"the expression has {len(query)} characters, more than {MAX_QUERY_LENGTH} (MAX_QUERY_LENGTH)"
        raise LpeSyntaxError(message, query, MAX_QUERY_LENGTH)
    tokens: list[Token] = []
    condition_tokens = 0  # read inside conditions, which count towards MAX_TOKENS too
    position = 0
    while position < len(query):
        char = query[position]
        if char.isspace():
            position += 1
            continue
        if len(tokens) + condition_tokens >= MAX_TOKENS:
            raise LpeSyntaxError(conditions.too_many_tokens(), query, position)
        opening = conditions.condition_opens_at(query, position)
        if opening is not None:
            left = MAX_TOKENS - len(tokens) - condition_tokens
            condition, position_after, read = conditions.parse_condition(query, position, opening, left)
            tokens.append(Token(Kind.CONDITION, condition, position))
            condition_tokens += read - 1  # the condition itself is one of the tokens
            position = position_after
        elif char in EVENT_TYPES:
            tokens.append(Token(Kind.TYPE, char, position))
            position += 1
        elif char in SCATTERINGS:
            tokens.append(Token(Kind.SCATTER, char, position))
            position += 1
        elif char == NO_SCATTERING_LETTER:
            tokens.append(Token(Kind.SCATTER, NO_SCATTERING, position))
            position += 1
        elif char == "'":
            label, position_after = _read_label(query, position)
            tokens.append(Token(Kind.LABEL, label, position))
            position = position_after
        elif char == "[":
            if query.startswith("^", position + 1):
                tokens.append(Token(Kind.OPEN_NEGATED_SET, None, position))
                position += 2
            else:
                tokens.append(Token(Kind.OPEN_SET, None, position))
                position += 1
        elif char == "{":
            bounds, position_after = _read_range(query, position)
            tokens.append(Token(Kind.RANGE, bounds, position))
            position = position_after
        elif char in _PUNCTUATION:
            tokens.append(Token(_PUNCTUATION[char], char, position))
            position += 1
        else:
            raise LpeSyntaxError(_unexpected(query, position), query, position)
    tokens.append(Token(Kind.END, None, len(query)))
    return tokens


def _read_label(query: str, opening: int) -> tuple[str, int]:
    closing = query.find("'", opening + 1)
    if closing < 0:
        raise LpeSyntaxError(f"expected ' to close the label opened at position {opening} (labels cannot contain "
                             "quotes)", query, len(query))
    label = query[opening + 1 : closing]
    if not label:
        raise LpeSyntaxError("empty label ''", query, opening)
    return label, closing + 1


_RANGE = re.compile(r"\{\s*([0-9]+)\s*(?:(,)\s*([0-9]*)\s*)?\}")


def _read_range(query: str, opening: int) -> tuple[tuple[int, int | None], int]:
    found = _RANGE.match(query, opening)
    if found is None:
        raise LpeSyntaxError("bad repetition: expected {n}, {n,} or {n,m} with whole numbers", query, opening)
    low, comma, high = found.groups()
    # Leading zeros go first, and bounds longer than the limit's digits are refused unread:
    # Python's int() refuses a few thousand digits.
    low, high = low.lstrip("0") or "0", high and (high.lstrip("0") or "0")
    if any(len(bound) > len(str(MAX_REPETITION)) for bound in (low, high or "")):
        raise LpeSyntaxError(f"repetition bounds above {MAX_REPETITION} are not supported", query, opening)
    minimum = int(low)
    maximum = minimum if not comma else (int(high) if high else None)
    if maximum is not None and maximum < minimum:
        message = f"bad repetition: {{{minimum},{maximum}}} has its maximum below its minimum"
        raise LpeSyntaxError(message, query, opening)
    if max(minimum, maximum or 0) > MAX_REPETITION:
        raise LpeSyntaxError(f"repetition bounds above {MAX_REPETITION} are not supported", query, opening)
    return (minimum, maximum), found.end()


def _unexpected(query: str, position: int) -> str:
    char = query[position]
    if char == "@":
        return "'@' opens a condition and must be followed by '(': @(|S_C| = 0)"
    if char == "^":
        return "'^' is only allowed right after '[' (as in [^RT])"
    if char in "Σ‖":
        return f"{char!r} belongs in a condition, which follows an event: D C(‖Σ_C‖ = 0)"
    if char.isalpha():
        return (
            f"unknown letter {char!r}: event types are {' '.join(EVENT_TYPES)}, scatterings "
            f"{' '.join(SCATTERINGS)} (case matters), x for none, labels are quoted: 'name'"
        )
    if char == '"':
        return "labels are quoted with single quotes: 'name'"
    return f"unexpected character {char!r}"
