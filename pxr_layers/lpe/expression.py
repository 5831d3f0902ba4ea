"""The public entry points: compile one expression, or a recipe's layers into one automaton."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from ..errors import LpeError, LpeSyntaxError
from . import conditions as cond
from . import nodes
from .automaton import LayerAutomaton
from .events import Event
from .outcomes import ALWAYS, Outcome
from .parser import parse
from .paths import PathText, parse_path

EXPRESSION_LAYER = "expression"
"""The name of the single layer of a compiled :class:`Expression`."""


class Expression:
    """One compiled Light Path Expression.

    text : the query as given; tree : its expression tree; canonical : its canonical text
    automaton : a one-layer :class:`LayerAutomaton`
    """

    def __init__(self, text: str):
        self.text = text
        self.tree = parse(text)
        self.canonical = nodes.canonical(self.tree)
        self.automaton = LayerAutomaton({EXPRESSION_LAYER: self.tree})

    def __repr__(self) -> str:
        return f"Expression({self.canonical!r})"

    @property
    def has_conditions(self) -> bool:
        return nodes.has_conditions(self.tree)

    @property
    def state_count(self) -> int:
        return self.automaton.state_count

    @property
    def transition_count(self) -> int:
        return self.automaton.transition_count

    def outcome(self, events: Sequence[Event]) -> Outcome:
        """Never, always, or conditional (with a vectorised ``mask``) for one path class."""
        return self.automaton.match(events)[EXPRESSION_LAYER]

    def matches(self, path: str | PathText | Sequence[Event], norms_row=None, sigma_row=None) -> bool:
        """Whether a whole path matches.

        path : the textual notation (its quantities, ``RD{C=0,T=3.2,R=0}``, feed the
            conditions), a parsed :class:`PathText`, or a sequence of :class:`Event`
        norms_row, sigma_row : (N, 3) and (N, 10) values of events 1..N, for a sequence of
            events (or to override the text's)

        Covariance values are needed only when the answer depends on them; then missing
        ones raise LpeError naming the event and the quantity.
        """
        if isinstance(path, str):
            parsed = parse_path(path)
        elif isinstance(path, PathText):
            parsed = path
        else:
            parsed = PathText(tuple(path), ())
        outcome = self.outcome(parsed.events)
        if outcome.kind != "conditional":
            return outcome is ALWAYS
        if norms_row is not None:
            norms = _as_records(norms_row, 3)
            sigma = None if sigma_row is None else _as_records(sigma_row, cond.SIGMA_ENTRY_COUNT)
        elif parsed.has_values:
            _check_given(outcome, parsed)
            norms, sigma = parsed.norms(), parsed.sigma()
        else:
            atoms = ", ".join(f"{cond.canonical(c)} at event {i} ({parsed.events[i]})" for i, c in outcome.atoms)
            raise LpeError(
                f"the match depends on covariance ({atoms}) but the path gives none; "
                "write the values after the event, e.g. RD'floor'{C=0, T=3.2, R=0}"
            )
        return bool(outcome.mask(norms, sigma)[0])


def _as_records(row, width: int) -> np.ndarray:
    """(N, width) values of one path → (1, N, width) float32 records."""
    array = np.asarray(row, dtype=np.float32)
    if array.ndim != 2 or array.shape[1] != width:
        raise LpeError(f"expected a (N, {width}) array of per-event values, got shape {array.shape}")
    return array[None]


def _check_given(outcome, parsed: PathText) -> None:
    """Every quantity the deciding conditions read must be in the path text."""
    for index, condition in outcome.atoms:
        if index == 0 or index >= len(parsed.events):
            continue  # the outcome's own mask() explains these
        for quantity in sorted(cond.quantities(condition), key=str):
            if quantity not in parsed.values[index]:
                raise LpeError(
                    f"the path gives no {quantity} for event {index} ({parsed.events[index]}), "
                    f"which {cond.canonical(condition)} reads"
                )


def compile(expression: str) -> Expression:
    """Parse and compile one expression. Raises LpeSyntaxError with a caret under the fault."""
    return Expression(expression)


def compile_layers(layers: Mapping[str, str]) -> LayerAutomaton:
    """Compile every layer of a recipe (name → expression) into one automaton.

    A syntax error names the layer: ``layer 'key': ...`` with the caret under its query.
    """
    if not layers:
        raise LpeError("no layers to compile")
    trees = {}
    for name, text in layers.items():
        try:
            trees[name] = parse(text)
        except LpeSyntaxError as error:
            raise LpeSyntaxError(f"layer {name!r}: {error.message}", error.query, error.position) from None
    return LayerAutomaton(trees)
