"""Notes on valid expressions that probably do not say what was meant.

The path notation writes one reflection-diffuse event as ``RD``; in an expression (as in
OSL) ``RD`` is two events, an R then a D, and one such event is ``<RD>``. Both spellings
meet in the same command line, so the slip is easy to make and silent: it only shows as
"no match".
"""

from __future__ import annotations

from itertools import pairwise

from ..errors import LpeSyntaxError
from ..paths.events import NO_SCATTERING_LETTER, SCATTERING_TYPES
from .lexer import Kind, tokenize


def hints(query: str) -> list[str]:
    """One note per likely slip; empty for a query that reads as meant (or that does not parse)."""
    try:
        tokens = tokenize(query)
    except LpeSyntaxError:  # the parser reports syntax errors; hints are only for valid queries
        return []
    notes = []
    enclosed = 0  # inside <...> letters are slots of one event; inside [...] alternatives
    for first, second in pairwise(tokens):
        if first.kind in (Kind.OPEN_GROUP, Kind.OPEN_SET, Kind.OPEN_NEGATED_SET):
            enclosed += 1
        elif first.kind in (Kind.CLOSE_GROUP, Kind.CLOSE_SET):
            enclosed -= 1
        adjacent = second.position == first.position + 1
        slip = first.kind is Kind.TYPE and second.kind is Kind.SCATTER and first.value in SCATTERING_TYPES
        if slip and adjacent and not enclosed:
            scatter = second.value or NO_SCATTERING_LETTER
            pair = first.value + scatter
            notes.append(
                f"'{pair}' at {first.position} is two events ({first.value}, then {scatter}); "
                f"one {pair} event is written <{pair}>"
            )
    return notes
