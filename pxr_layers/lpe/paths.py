"""The textual path notation, for tests and the command line.

Events are separated by spaces (or simply follow each other); each is its type letter,
its scattering letter (R, T and V events only), its quoted labels, and optionally the
covariance quantities stored for it in braces::

    C RD'floor' RG'chrome' L'key'
    C Ts RD'wall' O'lamp'
    C RD'floor'{C=0, T=3.2, R=0} L'key'
    C RG{C=0, T=0, R=5, S11=4, S22=0.1} L

Quantities: ``C``, ``T``, ``R`` (the norms |S_C|, |S_T|, |S_R|) and ``S11`` ... ``S44``
(entries of Σ, symmetric; ``Σ11`` also accepted). The camera event (the first) has none.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from ..errors import LpeSyntaxError
from ..paths.events import EVENT_TYPES, NON_SCATTERING_TYPES, SCATTERINGS
from . import conditions as cond
from .events import Event

FLOAT = np.float32

_KEY = re.compile(r"(?:\|?[SΣ]_)?([CTR])\|?|[SΣ]_?([1-4])([1-4])")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


@dataclass(frozen=True)
class PathText:
    """A parsed path: its events and the covariance quantities the text gives per event.

    values : per event, {Norm or Entry: value}; empty dicts where none were given
    """

    events: tuple[Event, ...]
    values: tuple[dict, ...] = field(default=())

    @property
    def has_values(self) -> bool:
        return any(self.values)

    def norms(self) -> np.ndarray:
        """(1, N, 3) float32 |S_C|, |S_T|, |S_R| of events 1..N; NaN where not given."""
        norms = np.full((1, max(len(self.events) - 1, 0), 3), np.nan, dtype=FLOAT)
        for index, values in enumerate(self.values[1:], start=1):
            for quantity, value in values.items():
                if isinstance(quantity, cond.Norm):
                    norms[0, index - 1, cond.NORM_COLUMNS[quantity.operator]] = value
        return norms

    def sigma(self) -> np.ndarray | None:
        """(1, N, 10) float32 upper triangles of Σ for events 1..N (NaN where not given),
        or None when the text gives no entry at all."""
        if not any(isinstance(quantity, cond.Entry) for values in self.values for quantity in values):
            return None
        sigma = np.full((1, max(len(self.events) - 1, 0), cond.SIGMA_ENTRY_COUNT), np.nan, dtype=FLOAT)
        for index, values in enumerate(self.values[1:], start=1):
            for quantity, value in values.items():
                if isinstance(quantity, cond.Entry):
                    sigma[0, index - 1, cond.sigma_column(quantity.row, quantity.column)] = value
        return sigma

    def __str__(self) -> str:
        return format_path(self.events, self.values)


def parse_path(text: str) -> PathText:
    """Parse the path notation. Raises LpeSyntaxError with a caret under the fault."""
    return _PathParser(text).parse()


def format_path(events, values=None) -> str:
    """The notation of a sequence of events (and optionally their quantities)."""
    parts = []
    for index, event in enumerate(events):
        text = str(event)
        given = values[index] if values else None
        if given:
            ordered = sorted(given.items(), key=lambda item: str(item[0]))
            text += "{" + ", ".join(f"{_key_text(quantity)}={cond.Number(value)}" for quantity, value in ordered) + "}"
        parts.append(text)
    return " ".join(parts)


def _key_text(quantity) -> str:
    return quantity.operator if isinstance(quantity, cond.Norm) else str(quantity)


class _PathParser:
    def __init__(self, text: str):
        self.text = text
        self.position = 0

    def error(self, message: str, position: int | None = None) -> LpeSyntaxError:
        return LpeSyntaxError(message, self.text, self.position if position is None else position)

    def peek(self) -> str:
        return self.text[self.position] if self.position < len(self.text) else ""

    def skip_space(self) -> None:
        while self.peek().isspace():
            self.position += 1

    def parse(self) -> PathText:
        events, values = [], []
        self.skip_space()
        if not self.peek():
            raise self.error("empty path")
        while self.peek():
            event, given = self.event(is_first=not events)
            events.append(event)
            values.append(given)
            self.skip_space()
        return PathText(tuple(events), tuple(values))

    def event(self, is_first: bool) -> tuple[Event, dict]:
        event_type = self.peek()
        if event_type not in EVENT_TYPES:
            raise self.error(f"expected an event type ({' '.join(EVENT_TYPES)}), got {event_type!r}")
        self.position += 1
        scatter = ""
        if self.peek() in SCATTERINGS and self.peek():
            if event_type in NON_SCATTERING_TYPES:
                raise self.error(f"{event_type} events have no scattering letter")
            scatter = self.peek()
            self.position += 1
        elif event_type not in NON_SCATTERING_TYPES:
            raise self.error(f"{event_type} events need a scattering letter ({' '.join(SCATTERINGS)})")
        labels = []
        self.skip_space()
        while self.peek() == "'":
            closing = self.text.find("'", self.position + 1)
            if closing < 0:
                raise self.error("label not closed: missing '")
            if closing == self.position + 1:
                raise self.error("empty label ''")
            labels.append(self.text[self.position + 1 : closing])
            self.position = closing + 1
            self.skip_space()
        given = {}
        if self.peek() == "{":
            if is_first:
                raise self.error("the camera event (the first) has no covariance")
            given = self.quantities()
        return Event(event_type, scatter, frozenset(labels)), given

    def quantities(self) -> dict:
        opening = self.position
        self.position += 1
        given = {}
        while True:
            self.skip_space()
            if self.peek() == "}":
                self.position += 1
                return given
            if not self.peek():
                raise self.error("missing '}'", opening)
            key_position = self.position
            key = _KEY.match(self.text, self.position)
            if key is None:
                raise self.error("expected C, T, R (norms) or S11..S44 (entries of Σ)")
            quantity = cond.Norm(key.group(1)) if key.group(1) else cond.Entry(int(key.group(2)), int(key.group(3)))
            self.position = key.end()
            self.skip_space()
            if self.peek() != "=":
                raise self.error("expected '=' and a value")
            self.position += 1
            self.skip_space()
            number = _NUMBER.match(self.text, self.position)
            if number is None:
                raise self.error("expected a number")
            if quantity in given:
                raise self.error(f"{_key_text(quantity)} is given twice", key_position)
            given[quantity] = cond.number_value(number.group(), self.error)
            self.position = number.end()
            self.skip_space()
            if self.peek() == ",":
                self.position += 1
