"""Random expressions and paths for property tests (seeded numpy generators only).

The trees are built with the constructors of :mod:`.nodes`, so they are in the normal form
the parser produces, and their canonical text must parse back to them. They stay small, so
that their automata build in milliseconds.
"""

from __future__ import annotations

import numpy as np

from ..paths.events import ALL_SCATTERINGS, EVENT_TYPES
from . import conditions as cond
from . import nodes
from .events import Event, label_matches

LABEL_POOL = ("key", "fill", "floor", "/World/Lights/key", "/World/Lights/rim", "chrome")
"""Labels carried by random events: a few names, two prim paths under one scope."""

PATTERN_POOL = ("key", "fill", "floor", "/World/Lights/*", "k*", "nowhere")
"""Quoted labels of random expressions: names, globs, and one that nothing carries."""

NORM_VALUES = (0.0, 1.0, 2.5, 6.0, 30.0)
"""Values of random norms and thresholds: few, so that equality tests sometimes hold."""

REPETITIONS = ((0, None), (1, None), (0, 1), (2, 2), (1, 3), (2, None), (0, 0))


def _pick(rng: np.random.Generator, items):
    return items[int(rng.integers(len(items)))]


def _subset(rng: np.random.Generator, universe, max_size: int) -> frozenset:
    size = int(rng.integers(1, max_size + 1))
    return frozenset(rng.choice(list(universe), size=size, replace=False).tolist())


def random_condition(rng: np.random.Generator, with_entries: bool = False) -> cond.Condition:
    """A comparison, or an and/or of two, on the norms (and Σ entries if ``with_entries``)."""

    def comparison():
        if with_entries and rng.random() < 0.3:
            left = cond.Entry(int(rng.integers(1, 5)), int(rng.integers(1, 5)))
            right = _pick(rng, [cond.Number(_pick(rng, NORM_VALUES)), cond.Entry(int(rng.integers(1, 5)), 2)])
        else:
            left = cond.Norm(_pick(rng, "CTR"))
            right = cond.Number(_pick(rng, NORM_VALUES))
        return cond.Comparison(left, _pick(rng, tuple(cond.COMPARATORS)), right)

    roll = rng.random()
    if roll < 0.6:
        return comparison()
    combine = cond.all_of if roll < 0.8 else cond.any_of
    return combine([comparison(), comparison()])


def random_event_pattern(rng: np.random.Generator, condition_rate: float = 0.0, with_entries: bool = False):
    """One event pattern. A pattern with a condition never matches the camera type C, so that
    conditions are never tested on the camera event of a path that starts with C."""
    types = scatters = None
    if rng.random() < 0.6:
        types = nodes.SymbolSet(_subset(rng, EVENT_TYPES, 3), negated=bool(rng.random() < 0.3))
    if rng.random() < 0.4:
        scatters = nodes.SymbolSet(_subset(rng, ALL_SCATTERINGS, 2), negated=bool(rng.random() < 0.3))
    labels = []
    for _ in range(int(rng.choice([0, 0, 1, 1, 2]))):
        patterns = tuple(sorted(_subset(rng, PATTERN_POOL, 2)))
        labels.append(nodes.LabelTerm(patterns, negated=bool(rng.random() < 0.3)))
    if rng.random() < 0.05:
        labels.append(nodes.LabelTerm((nodes.ANY_LABEL,)))
    condition = None
    if rng.random() < condition_rate:
        condition = random_condition(rng, with_entries)
        if types is None:
            types = nodes.SymbolSet(frozenset("C"), negated=True)
        elif types.negated:
            types = nodes.SymbolSet(types.symbols | {"C"}, negated=True)
        else:
            types = nodes.SymbolSet(types.symbols - {"C"} or frozenset("R"))
    return nodes.EventPattern(types, scatters, tuple(labels), condition)


def random_tree(rng: np.random.Generator, depth: int = 3, condition_rate: float = 0.0, with_entries: bool = False):
    """A random expression tree of at most ``depth`` levels of operators."""
    if depth == 0 or rng.random() < 0.3:
        return random_event_pattern(rng, condition_rate, with_entries)
    kind = _pick(rng, ("concat", "concat", "union", "repeat"))
    if kind == "repeat":
        minimum, maximum = _pick(rng, REPETITIONS)
        return nodes.repeat(random_tree(rng, depth - 1, condition_rate, with_entries), minimum, maximum)
    children = [random_tree(rng, depth - 1, condition_rate, with_entries) for _ in range(int(rng.integers(2, 4)))]
    return nodes.concat(children) if kind == "concat" else nodes.union(children)


def random_event(rng: np.random.Generator) -> Event:
    labels = frozenset(label for label in LABEL_POOL if rng.random() < 0.2)
    return Event(_pick(rng, EVENT_TYPES), _pick(rng, ALL_SCATTERINGS), labels)


def random_path(rng: np.random.Generator, max_length: int = 6, start_with_camera: bool = True) -> tuple[Event, ...]:
    """A random event sequence; with ``start_with_camera`` its first event is a bare C."""
    length = int(rng.integers(0 if not start_with_camera else 1, max_length + 1))
    events = [random_event(rng) for _ in range(length)]
    if start_with_camera and events:
        events[0] = Event("C")
    return tuple(events)


def random_values(rng: np.random.Generator, records: int, events: int) -> tuple[np.ndarray, np.ndarray]:
    """(records, events, 3) norms and (records, events, 10) Σ entries, float32, from NORM_VALUES (Σ also negative)."""
    norms = rng.choice(NORM_VALUES, size=(records, events, 3)).astype(np.float32)
    sigma = (rng.choice(NORM_VALUES, size=(records, events, cond.SIGMA_ENTRY_COUNT))
             * rng.choice([-1.0, 1.0], size=(records, events, cond.SIGMA_ENTRY_COUNT))).astype(np.float32)
    return norms, sigma


LABELS_FOR_GLOBS = (*LABEL_POOL, "kx", "/World/Lights/fill", "other")
"""Candidate labels when an event must carry a label matching a glob."""


def sample_event(rng: np.random.Generator, pattern: nodes.EventPattern) -> Event | None:
    """A random event the pattern's type, scattering and labels accept (its condition
    aside), or None if the random choices could not satisfy it."""
    types = [t for t in EVENT_TYPES if pattern.types is None or t in pattern.types]
    scatters = [s for s in ALL_SCATTERINGS if pattern.scatters is None or s in pattern.scatters]
    if not types or not scatters:
        return None
    labels = {label for label in LABEL_POOL if rng.random() < 0.15}
    for term in pattern.labels:
        matching = [label for label in LABELS_FOR_GLOBS if any(label_matches(p, label) for p in term.patterns)]
        if term.negated:
            labels -= set(matching)
        elif matching:
            labels.add(_pick(rng, matching))
    event = Event(_pick(rng, types), _pick(rng, scatters), frozenset(labels))
    return event if pattern.matches_event(event) else None


def sample_path(rng: np.random.Generator, tree, max_repeats: int = 2) -> tuple[Event, ...] | None:
    """A random path the tree accepts (conditions aside), or None if sampling failed."""
    if isinstance(tree, nodes.EventPattern):
        event = sample_event(rng, tree)
        return None if event is None else (event,)
    if isinstance(tree, nodes.Union):
        return sample_path(rng, _pick(rng, tree.alternatives), max_repeats)
    if isinstance(tree, nodes.Concat):
        parts = [sample_path(rng, item, max_repeats) for item in tree.items]
        return None if any(part is None for part in parts) else sum(parts, ())
    most = tree.maximum if tree.maximum is not None else tree.minimum + max_repeats
    count = int(rng.integers(tree.minimum, most + 1))
    parts = [sample_path(rng, tree.body, max_repeats) for _ in range(count)]
    return None if any(part is None for part in parts) else sum(parts, ())


def mutate_path(rng: np.random.Generator, path: tuple[Event, ...]) -> tuple[Event, ...]:
    """The path with one event replaced, dropped or inserted (the camera event kept first)."""
    events = list(path)
    position = int(rng.integers(1, len(events) + 1)) if events else 0
    roll = rng.random()
    if roll < 0.4 and position < len(events):
        events[position] = random_event(rng)
    elif roll < 0.7 and position < len(events):
        del events[position]
    else:
        events.insert(position, random_event(rng))
    return tuple(events)
