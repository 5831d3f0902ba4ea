"""Check with the LPE automaton that suggested layers partition an index's paths.

Every path class must be matched by exactly one layer; a class that some layer matches
only under covariance conditions must be matched by exactly one layer for every record.
The suggested expressions test covariance on the first bounce only, and only against 0
(``= 0`` / ``!= 0``, complementary for any float, NaN included), so the records of a class
can differ in 2³ ways only: each is checked, which covers every record there is.

Classes are checked once per distinct sequence of automaton symbols: the automaton's
answer depends on nothing else, and a scene's tens of thousands of classes have a few
hundred such sequences.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping

import numpy as np

from .. import lpe
from ..errors import PxrLayersError
from ..paths.events import path_text
from ..paths.reader import PathIndex


class SuggestError(PxrLayersError):
    """Suggested layers that do not partition an index (a bug, or labels the index makes
    ambiguous), or a suggestion asked of nothing."""

    def __init__(self, message: str, *, file: str | None = None):
        super().__init__(f"{file}: {message}" if file else message)
        self.file = file


def first_bounce_combinations(norm_slots: int) -> np.ndarray:
    """(8, N, 3) float32 norms: every zero / non-zero combination of event 1's C, T, R."""
    norms = np.zeros((8, max(norm_slots, 1), 3), np.float32)
    for row, bits in enumerate(itertools.product((0.0, 1.0), repeat=3)):
        norms[row, 0] = bits
    return norms


def check_partition(index: PathIndex, expressions: Mapping[str, str]) -> int:
    """Raise SuggestError naming the first class of `index` that no layer, or more than
    one, matches (for some record); returns how many distinct symbol sequences were checked."""
    automaton = lpe.compile_layers(dict(expressions))
    symbol_of: dict = {}
    event_symbol = np.array([symbol_of.setdefault(automaton.alphabet.classify(event), len(symbol_of))
                             for event in index.events] + [-1], np.int64)  # the last: padding
    combinations = first_bounce_combinations(index.norm_slots)
    representatives = _distinct_sequences(index, event_symbol)
    for class_id in representatives.tolist():
        path_class = index.classes[class_id]
        matches = np.zeros(len(combinations), np.int64)
        for outcome in automaton.match(path_class.events).values():
            if outcome.kind == "always":
                matches += 1
            elif outcome.kind == "conditional":
                matches += outcome.mask(combinations)
        if not (matches == 1).all():
            how = "no layer" if matches.min() == 0 else f"{int(matches.max())} layers"
            raise SuggestError(f"the class {path_text(path_class.events)} is matched by {how} "
                               f"(layers: {', '.join(expressions)})", file=str(index.shown_as))
    return len(representatives)


def same_layer(index: PathIndex, expression: str, other: str) -> bool:
    """Whether two expressions cut the same layer from `index`: they match the same path
    classes, and a class's records under the same first-bounce covariance combinations (the
    2³ zero / non-zero C, T, R that suggested layers test; conditions on later bounces are
    taken at these combinations too). Decided once per distinct sequence of the automaton's
    symbols, as check_partition is, so whatever their text."""
    automaton = lpe.compile_layers({"first": expression, "other": other})
    symbol_of: dict = {}
    event_symbol = np.array([symbol_of.setdefault(automaton.alphabet.classify(event), len(symbol_of))
                             for event in index.events] + [-1], np.int64)
    combinations = first_bounce_combinations(index.norm_slots)
    for class_id in _distinct_sequences(index, event_symbol).tolist():
        masks = {name: np.zeros(len(combinations), bool) for name in ("first", "other")}
        for name, outcome in automaton.match(index.classes[class_id].events).items():
            if outcome.kind == "always":
                masks[name][:] = True
            elif outcome.kind == "conditional":
                masks[name] |= np.asarray(outcome.mask(combinations), bool)
        if not (masks["first"] == masks["other"]).all():
            return False
    return True


def _distinct_sequences(index: PathIndex, event_symbol: np.ndarray) -> np.ndarray:
    """(s,) ids of one class per distinct sequence of symbols (event_symbol: event id →
    symbol, its last entry the padding), the first of each in class order."""
    if not index.classes:
        return np.zeros(0, np.int64)
    padded = index.event_matrix(len(event_symbol) - 1)
    _, first = np.unique(event_symbol[padded], axis=0, return_index=True)
    return np.sort(first)
