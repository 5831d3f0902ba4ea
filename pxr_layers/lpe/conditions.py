"""Covariance conditions: the extension of LPEs to the covariance of each bounce.

A condition follows an event of an expression and restricts it to bounces whose stored
covariance quantities pass a test, as in Desrichard & Vanderhaeghe (JFIG 2018):
``D C(‖Σ_C‖ = 0) T(‖Σ_T‖ > 6) R(‖Σ_R‖ > 2)``.

Quantities, per event (see COVARIANCE.md, "What the index stores per bounce"):

- ``|S_C|`` curvature norm, max |k_i|, 1/m (0 on locally planar geometry);
- ``|S_T|`` texture norm, sqrt(λmax) of the texture operator, cycles/m;
- ``|S_R|`` reflectance norm, sqrt(λmax) of the BSDF operator, cycles/rad (diffuse: 0);
- ``Sij`` (1 <= i, j <= 4) entry of the 4×4 covariance Σ over (x, y, u, v); symmetric,
  so ``S21`` is ``S12``. Only where the index keeps the whole Σ.

Comparisons ``= != < <= > >=`` and ``>>`` ("much greater": ``a >> b`` is
``a > MUCH_GREATER_FACTOR * b``), combined with ``and`` / ``or`` and parentheses.
Values are compared in float32, the precision of the index.

Written forms (all give the same tree):

- the paper's: ``C(‖Σ_C‖ = 0)``, ``T(|S_T| > 6)``: the letter names the operator read
  inside; several in a row are and-ed;
- ``Σ(Σ11 >> Σ22)`` / ``S(S11 >> S22)`` for matrix entries;
- the canonical form ``@(|S_C| = 0 and |S_T| > 6)``: ``@`` is not an OSL character, so it
  can never be read as an event.

C, T, R and S are also event letters: ``C(R)`` stays "camera, then R". A letter followed
by ``(`` opens a condition only when what follows the parenthesis starts a condition
(a bar, Σ, S with a subscript or digits, a number): never valid OSL.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..errors import LpeError, LpeSyntaxError
from .limits import LARGEST_NUMBER, MAX_NESTING, MAX_TOKENS

MUCH_GREATER_FACTOR = 10.0
"""``a >> b`` means ``a > MUCH_GREATER_FACTOR * b``: one order of magnitude."""

NORM_COLUMNS = {"C": 0, "T": 1, "R": 2}
"""Column of each operator's norm in the index's ``norms`` array (r, N, 3)."""

SIGMA_AXES = "xyuv"
SIGMA_ENTRY_COUNT = 10
"""Σ is stored as its upper triangle in row-major order: xx xy xu xv yy yu yv uu uv vv."""

CONDITION_PREFIXES = ("C", "T", "R", "S", "Σ", "@")
"""Characters that may open a condition when followed by ``(`` and a condition."""


def sigma_column(row: int, column: int) -> int:
    """Index (0..9) of Σ[row, column] (1-based, symmetric) in the stored upper triangle."""
    row, column = min(row, column), max(row, column)
    # Entries before row `row` in the upper triangle of a 4×4: 4 + 3 + ... for each full row.
    preceding = sum(4 - r for r in range(row - 1))
    return preceding + (column - row)


# --- the tree --------------------------------------------------------------------------


@dataclass(frozen=True)
class Norm:
    """‖Σ_op‖ of one operator: op is 'C' (curvature), 'T' (texture) or 'R' (reflectance)."""

    operator: str

    def __str__(self) -> str:
        return f"|S_{self.operator}|"


@dataclass(frozen=True)
class Entry:
    """Σ[row, column] of the bounce's 4×4 covariance, 1-based, stored with row <= column."""

    row: int
    column: int

    def __post_init__(self):
        if self.row > self.column:
            row, column = self.column, self.row
            object.__setattr__(self, "row", row)
            object.__setattr__(self, "column", column)

    def __str__(self) -> str:
        return f"S{self.row}{self.column}"


@dataclass(frozen=True)
class Number:
    value: float

    def __str__(self) -> str:
        text = repr(float(self.value))
        return text.removesuffix(".0")


Operand = Norm | Entry | Number


def _much_greater(left, right):
    # 10·b past the float32 range is ±inf, which compares as the exact product would: no
    # finite value exceeds +inf and every one exceeds -inf, so the overflow is harmless.
    with np.errstate(over="ignore"):
        return np.greater(left, MUCH_GREATER_FACTOR * right)


COMPARATORS = {
    "=": np.equal,
    "!=": np.not_equal,
    "<": np.less,
    "<=": np.less_equal,
    ">": np.greater,
    ">=": np.greater_equal,
    ">>": _much_greater,
}
"""Canonical spelling of each comparison → its vectorised test."""

COMPARATOR_SPELLINGS = {"==": "=", "≠": "!=", "≤": "<=", "≥": ">=", "≫": ">>"}
"""Other accepted spellings (Unicode, C-like) → canonical."""


@dataclass(frozen=True)
class Comparison:
    left: Operand
    comparator: str
    right: Operand

    def __str__(self) -> str:
        return f"{self.left} {self.comparator} {self.right}"


@dataclass(frozen=True)
class AllOf:
    """Conjunction (``and``); build with :func:`all_of` so that nesting is flattened."""

    terms: tuple

    def __str__(self) -> str:
        return " and ".join(f"({term})" if isinstance(term, AnyOf) else str(term) for term in self.terms)


@dataclass(frozen=True)
class AnyOf:
    """Disjunction (``or``); build with :func:`any_of` so that nesting is flattened."""

    terms: tuple

    def __str__(self) -> str:
        return " or ".join(str(term) for term in self.terms)


Condition = Comparison | AllOf | AnyOf


def flattened(kind: type, field: str, items):
    """The n-ary node ``kind(tuple)`` over `items`, with the items of nested `kind` nodes (their
    `field`) spliced in, and a single item on its own: the same meaning always gives the same
    tree (conditions here, expression trees in nodes.py)."""
    flat = []
    for item in items:
        flat.extend(getattr(item, field) if isinstance(item, kind) else [item])
    return flat[0] if len(flat) == 1 else kind(tuple(flat))


def all_of(terms) -> Condition:
    """The conjunction of conditions, flattened."""
    return flattened(AllOf, "terms", terms)


def any_of(terms) -> Condition:
    """The disjunction of conditions, flattened."""
    return flattened(AnyOf, "terms", terms)


def canonical(condition: Condition) -> str:
    """The canonical spelling, attached right after its event: ``@(|S_C| = 0 and |S_T| > 6)``."""
    return f"@({condition})"


def quantities(condition: Condition) -> set[Norm | Entry]:
    """Every stored quantity the condition reads."""
    if isinstance(condition, Comparison):
        return {side for side in (condition.left, condition.right) if not isinstance(side, Number)}
    return set().union(*(quantities(term) for term in condition.terms))


def reads_sigma(condition: Condition) -> bool:
    """Whether the condition needs the whole Σ (an entry), not only the norms."""
    return any(isinstance(quantity, Entry) for quantity in quantities(condition))


# --- evaluation ------------------------------------------------------------------------


def evaluate(condition: Condition, norms: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
    """Test the condition on one event of many records.

    norms : (r, 3) float32, |S_C| (1/m), |S_T| (cycles/m), |S_R| (cycles/rad) of the event
    sigma : (r, 10) float32 upper triangle of Σ (xx xy xu xv yy yu yv uu uv vv), or None
    returns : (r,) bool
    """
    if isinstance(condition, Comparison):
        left = _values(condition.left, norms, sigma)
        right = _values(condition.right, norms, sigma)
        return np.asarray(COMPARATORS[condition.comparator](left, right), dtype=bool)
    results = [evaluate(term, norms, sigma) for term in condition.terms]
    combine = np.logical_and if isinstance(condition, AllOf) else np.logical_or
    return combine.reduce(results)


def _values(operand: Operand, norms: np.ndarray, sigma: np.ndarray | None):
    if isinstance(operand, Number):
        # A Python float is a "weak" scalar for numpy: the comparison happens in float32,
        # so `|S_T| = 3.2` matches a norm stored as float32(3.2).
        return operand.value
    if isinstance(operand, Norm):
        return norms[:, NORM_COLUMNS[operand.operator]]
    if sigma is None:
        raise LpeError(f"the condition reads the covariance entry {operand} but no Σ was given")
    return sigma[:, sigma_column(operand.row, operand.column)]


# --- parsing ---------------------------------------------------------------------------

_CONDITION_START = re.compile(r"[|‖Σ]|S_?\d|S_[CTR]|[-+]?\.?\d")
_TOKEN = re.compile(
    r"""(?P<space>\s+)
    |(?P<quantity>[SΣ]_?(?:[A-Za-z]\b|\d+))
    |(?P<number>[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)
    |(?P<comparator>>>|≫|>=|≥|<=|≤|!=|≠|==|=|<|>)
    |(?P<bar>‖|\|\||\|)
    |(?P<word>[A-Za-z_]\w*)
    |(?P<paren>[()])
    """,
    re.VERBOSE,
)


def condition_opens_at(query: str, position: int) -> int | None:
    """If a condition starts at ``position`` (a prefix then ``(``), the position of the ``(``.

    The decision only looks at what follows the parenthesis: a bar, Σ, ``S`` with a
    subscript or digits, or a number, none of which can start an OSL expression.
    """
    if query[position] not in CONDITION_PREFIXES:
        return None
    cursor = _skip_space(query, position + 1)
    if cursor >= len(query) or query[cursor] != "(":
        return None
    opening = cursor
    # Parentheses may nest before the first comparison: C((|S_C| = 0 or ...) and ...).
    while cursor < len(query) and (query[cursor] == "(" or query[cursor].isspace()):
        cursor += 1
    if _CONDITION_START.match(query, cursor):
        return opening
    if query[position] == "@":
        return opening  # '@' is never OSL: always a condition, even a malformed one
    return None


def _skip_space(text: str, position: int) -> int:
    while position < len(text) and text[position].isspace():
        position += 1
    return position


@dataclass(frozen=True)
class _Token:
    kind: str
    text: str
    position: int


class ConditionParser:
    """Parses one parenthesised condition out of a query, from its ``(`` to the matching ``)``.

    Positions in errors are offsets into the whole query, so the caret lands right.
    """

    def __init__(self, query: str, prefix_position: int, opening: int, max_tokens: int = MAX_TOKENS):
        self.query = query
        self.prefix_position = prefix_position
        self.prefix = query[prefix_position]
        self.cursor = self.opening = opening
        self._peeked: _Token | None = None
        self.depth = 0  # parentheses open inside the condition's own
        self.tokens_left = max_tokens  # of the expression's MAX_TOKENS

    def parse(self) -> tuple[Condition, int]:
        """Returns the condition and the position just after its closing parenthesis."""
        opening = self._expect("(", "a condition starts with '('")
        condition = self._disjunction()
        self._expect(")", f"expected 'and', 'or' or ')' to close the condition opened at position {opening.position}")
        self._check_prefix(condition)
        return condition, self.cursor

    # Grammar: disjunction := conjunction ('or' conjunction)*
    #          conjunction := primary ('and' primary)*
    #          primary     := '(' disjunction ')' | operand comparator operand
    def _disjunction(self) -> Condition:
        terms = [self._conjunction()]
        while self._peek().kind == "word" and self._peek().text == "or":
            self._next()
            terms.append(self._conjunction())
        return any_of(terms)

    def _conjunction(self) -> Condition:
        terms = [self._primary()]
        while self._peek().kind == "word" and self._peek().text == "and":
            self._next()
            terms.append(self._primary())
        return all_of(terms)

    def _primary(self) -> Condition:
        if self._peek().text == "(":
            opening = self._next()
            if self.depth == MAX_NESTING:
                raise self._error(f"parentheses nest more than {MAX_NESTING} deep here", opening.position)
            self.depth += 1
            inner = self._disjunction()
            self._expect(")", f"expected 'and', 'or' or ')' to close the '(' at position {opening.position}")
            self.depth -= 1
            return inner
        left_token = self._peek()
        left = self._operand()
        token = self._next()
        if token.kind != "comparator":
            raise self._error("expected a comparison (= != < <= > >= >>)", token.position)
        comparator = COMPARATOR_SPELLINGS.get(token.text, token.text)
        right = self._operand()
        if isinstance(left, Number) and isinstance(right, Number):
            raise self._error("a comparison needs a stored quantity (|S_C|, |S_T|, |S_R| or Sij)", left_token.position)
        follower = self._peek()
        if follower.kind == "comparator":
            raise self._error("chained comparisons are not supported; join two with 'and'", follower.position)
        return Comparison(left, comparator, right)

    def _operand(self) -> Operand:
        token = self._next()
        if token.kind == "number":
            return Number(number_value(token.text, lambda message: self._error(message, token.position)))
        if token.kind == "bar":
            inner = self._next()
            if inner.kind != "quantity":
                raise self._error("expected S_C, S_T or S_R between the norm bars", inner.position)
            quantity = self._quantity(inner)
            if not isinstance(quantity, Norm):
                raise self._error(f"entries are compared as they are: write {quantity} without bars", inner.position)
            closing = self._next()
            if closing.kind != "bar" or closing.text != token.text:
                raise self._error(f"expected {token.text} to close the norm", closing.position)
            return quantity
        if token.kind == "quantity":
            quantity = self._quantity(token)
            if isinstance(quantity, Norm):
                raise self._error(
                    f"the norm of Σ_{quantity.operator} is written |S_{quantity.operator}| (with bars)", token.position
                )
            return quantity
        if token.kind == "end":
            raise self._error("the condition ends early: expected a quantity or a number", token.position)
        raise self._error("expected |S_C|, |S_T|, |S_R|, an entry like S11, or a number", token.position)

    def _quantity(self, token: _Token) -> Norm | Entry:
        subscript = token.text[1:].lstrip("_")
        if subscript in NORM_COLUMNS:
            return Norm(subscript)
        if len(subscript) == 2 and subscript.isdigit() and all("1" <= digit <= "4" for digit in subscript):
            return Entry(int(subscript[0]), int(subscript[1]))
        raise self._error(
            f"unknown quantity {token.text!r}: norms are S_C, S_T, S_R; entries S11 to S44 "
            f"(1-based over {', '.join(SIGMA_AXES)})",
            token.position,
        )

    def _check_prefix(self, condition: Condition) -> None:
        """``C(...)`` reads |S_C| only (and so on): a mismatch is almost surely a typo."""
        if self.prefix not in NORM_COLUMNS:
            return
        for quantity in sorted(quantities(condition), key=str):
            if quantity != Norm(self.prefix):
                raise self._error(
                    f"{self.prefix}(...) conditions read |S_{self.prefix}| only, not {quantity}; "
                    "use @(...) to combine quantities",
                    self.prefix_position,
                )

    # --- tokens ------------------------------------------------------------------------

    def _peek(self) -> _Token:
        if self._peeked is None:
            self._peeked = self._scan()
        return self._peeked

    def _next(self) -> _Token:
        token = self._peek()
        self._peeked = None
        return token

    def _expect(self, text: str, message: str) -> _Token:
        token = self._next()
        if token.text != text:
            raise self._error(message, token.position)
        return token

    def _scan(self) -> _Token:
        self.cursor = _skip_space(self.query, self.cursor)
        if self.cursor >= len(self.query):
            return _Token("end", "", len(self.query))
        match = _TOKEN.match(self.query, self.cursor)
        if match is None:
            raise self._error(f"unexpected character {self.query[self.cursor]!r} in a condition", self.cursor)
        self.tokens_left -= 1
        if self.tokens_left < 0:
            raise self._error(too_many_tokens(), self.cursor)
        position, self.cursor = self.cursor, match.end()
        kind = match.lastgroup
        if kind == "word" and match.group() not in ("and", "or"):
            raise self._error(f"unknown word {match.group()!r} in a condition: expected 'and', 'or', a quantity, or "
                              f"')' to close the condition opened at position {self.opening}", position)
        return _Token(kind, match.group(), position)

    def _error(self, message: str, position: int) -> LpeSyntaxError:
        return LpeSyntaxError(message, self.query, position)


def number_value(text: str, error) -> float:
    """The value of a number's text, or ``error(message)`` raised if its magnitude passes
    LARGEST_NUMBER (including what reads as infinity, such as ``1e999``)."""
    value = float(text)
    if abs(value) > LARGEST_NUMBER:
        shown = text if len(text) <= 24 else f"{text[:20]}…"
        raise error(f"{shown} is out of range: values are float32, at most ±{LARGEST_NUMBER:.8g}")
    return value


def too_many_tokens() -> str:
    return (f"the expression passes {MAX_TOKENS} tokens here (MAX_TOKENS, see docs/lpe.md): write long runs "
            "of events as repetitions, and long lists of labels as globs")


def parse_condition(query: str, prefix_position: int, opening: int,
                    max_tokens: int = MAX_TOKENS) -> tuple[Condition, int, int]:
    """Parse the condition whose prefix is at ``prefix_position`` and ``(`` at ``opening``;
    an LpeSyntaxError past its ``max_tokens`` (what the expression has left of MAX_TOKENS).

    Returns the condition tree, the position just after its closing parenthesis and the
    number of tokens it read.
    """
    parser = ConditionParser(query, prefix_position, opening, max_tokens)
    condition, position_after = parser.parse()
    return condition, position_after, max_tokens - parser.tokens_left
