"""Path events and label patterns: what an expression is matched against.

A light path is a sequence of events read camera first. Each event is a
(type, scattering, labels) triple, in the alphabet of ``paths/events.py``:

- type: one of ``EVENT_TYPES`` (camera, reflection, transmission, volume, light, emissive
  object, background);
- scattering: one of ``SCATTERINGS`` (diffuse, glossy, singular, straight), or ``''`` for
  events that do not scatter (camera, light, emissive object, background);
- labels: any number of names (prim name and path, material, light group, lobe name).
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field

from ..paths.events import ALL_SCATTERINGS, EVENT_TYPES, NO_SCATTERING, SCATTERINGS

GLOB_CHARACTERS = frozenset("*?[")


@dataclass(frozen=True)
class Event:
    """One event of a light path.

    type : one letter of ``EVENT_TYPES``
    scatter : one letter of ``SCATTERINGS``, or ``''`` (C, L, O, B)
    labels : every name the event carries; an expression's label matches when any of
        them matches. Any iterable is accepted and stored as a frozenset.
    """

    type: str
    scatter: str = NO_SCATTERING
    labels: frozenset[str] = field(default_factory=frozenset)

    def __post_init__(self):
        if len(self.type) != 1 or self.type not in EVENT_TYPES:
            raise ValueError(f"event type must be one of {' '.join(EVENT_TYPES)}, got {self.type!r}")
        if self.scatter not in ALL_SCATTERINGS:
            raise ValueError(f"scattering must be one of {' '.join(SCATTERINGS)} or '', got {self.scatter!r}")
        if not isinstance(self.labels, frozenset):
            object.__setattr__(self, "labels", frozenset(self.labels))

    def __str__(self) -> str:
        """The event in the textual path notation, labels sorted: ``RD'floor'``."""
        return self.type + self.scatter + "".join(f"'{label}'" for label in sorted(self.labels))


def is_glob(pattern: str) -> bool:
    """Whether a quoted label is a glob pattern (fnmatch: ``*``, ``?``, ``[...]``)."""
    return not GLOB_CHARACTERS.isdisjoint(pattern)


def label_matches(pattern: str, label: str) -> bool:
    """Whether one label matches one quoted label of an expression.

    Plain names compare for equality; names holding ``*``, ``?`` or ``[`` are fnmatch
    globs, case-sensitive, and ``*`` crosses ``/`` (``'/World/Lights/*'`` matches
    ``/World/Lights/rig/key`` too).
    """
    return fnmatch.fnmatchcase(label, pattern) if is_glob(pattern) else label == pattern


class PatternTable:
    """Numbers every quoted label of a set of expressions and tells which ones an event carries.

    The automaton never sees label names: only the bit mask of the patterns an event's
    labels match. A label that matches no pattern sets no bit, which is how "any other
    label" is represented without knowing the scene's names in advance.
    """

    def __init__(self, patterns):
        self.patterns: tuple[str, ...] = tuple(dict.fromkeys(patterns))
        self.index = {pattern: bit for bit, pattern in enumerate(self.patterns)}
        self._label_masks: dict[str, int] = {}

    def __len__(self) -> int:
        return len(self.patterns)

    def mask_of(self, patterns) -> int:
        """Bit mask of the given patterns (each must be in the table)."""
        mask = 0
        for pattern in patterns:
            mask |= 1 << self.index[pattern]
        return mask

    def label_mask(self, label: str) -> int:
        """Bit mask of the patterns one label matches (cached: labels repeat a lot)."""
        mask = self._label_masks.get(label)
        if mask is None:
            mask = 0
            for bit, pattern in enumerate(self.patterns):
                if label_matches(pattern, label):
                    mask |= 1 << bit
            self._label_masks[label] = mask
        return mask

    def carried(self, labels) -> int:
        """Bit mask of the patterns an event carries: the union over its labels."""
        mask = 0
        for label in labels:
            mask |= self.label_mask(label)
        return mask
