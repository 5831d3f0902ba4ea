"""A slow, obviously correct matcher straight on the expression tree; the automaton is tested against it.

It computes, for each sub-expression and start position, the set of positions where a
match can end, exactly as the definitions read. No automaton, no alphabet.
"""

from __future__ import annotations

import numpy as np

from ..errors import LpeError
from . import conditions as cond
from . import nodes
from .events import Event
from .parser import parse
from .paths import parse_path


def reference_match(expression, events, norms_row=None, sigma_row=None) -> bool:
    """Whether the whole path matches the whole expression (anchored at both ends).

    expression : query text or tree
    events : sequence of :class:`Event`, or a path in the textual notation
    norms_row : (N, 3) |S_C|, |S_T|, |S_R| of events 1..N of this one path, or None
    sigma_row : (N, 10) upper triangles of Σ of events 1..N, or None

    Raises LpeError when it has to test a condition without the values it reads (even if
    another alternative would decide the match; the automaton only raises when the answer
    depends on it).
    """
    tree = parse(expression) if isinstance(expression, str) else expression
    path = tuple(parse_path(events).events if isinstance(events, str) else events)
    values = _Values(norms_row, sigma_row)
    if isinstance(tree, nodes.Difference):
        return len(path) in _ends(tree.positive, path, 0, values) and len(path) not in _ends(tree.negative, path, 0,
                                                                                              values)
    return len(path) in _ends(tree, path, 0, values)


class _Values:
    def __init__(self, norms_row, sigma_row):
        self.norms = None if norms_row is None else np.asarray(norms_row, dtype=np.float32)
        self.sigma = None if sigma_row is None else np.asarray(sigma_row, dtype=np.float32)

    def holds(self, condition: cond.Condition, index: int) -> bool:
        if index == 0:
            raise LpeError(f"{cond.canonical(condition)} is on the camera event, which has no covariance")
        if self.norms is None:
            raise LpeError(f"{cond.canonical(condition)} needs the norms of event {index}; none were given")
        if index > len(self.norms):
            given = f"events 1..{len(self.norms)}"
            raise LpeError(f"{cond.canonical(condition)} tests event {index}; norms are given for {given}")
        if cond.reads_sigma(condition) and self.sigma is None:
            raise LpeError(f"{cond.canonical(condition)} reads entries of Σ; none were given")
        sigma = None if self.sigma is None else self.sigma[index - 1][None]
        return bool(cond.evaluate(condition, self.norms[index - 1][None], sigma)[0])


def _ends(node: nodes.Node, path: tuple[Event, ...], start: int, values: _Values) -> set[int]:
    """Positions where a match of ``node`` beginning at ``start`` can end."""
    if isinstance(node, nodes.EventPattern):
        matched = start < len(path) and node.matches_event(path[start])
        # The condition is tested only on an event that matches otherwise, as the automaton does.
        if matched and (node.condition is None or values.holds(node.condition, start)):
            return {start + 1}
        return set()
    if isinstance(node, nodes.Concat):
        positions = {start}
        for item in node.items:
            positions = {end for position in positions for end in _ends(item, path, position, values)}
        return positions
    if isinstance(node, nodes.Union):
        return {end for alternative in node.alternatives for end in _ends(alternative, path, start, values)}
    if isinstance(node, nodes.Repeat):
        return _repeat_ends(node, path, start, values)
    raise TypeError(f"not an expression node: {node!r}")


def _repeat_ends(node: nodes.Repeat, path, start: int, values: _Values) -> set[int]:
    current = {start}  # ends after exactly `count` repetitions
    for _ in range(node.minimum):
        current = {end for position in current for end in _ends(node.body, path, position, values)}
    results = set(current)
    if node.maximum is not None:
        for _ in range(node.maximum - node.minimum):
            current = {end for position in current for end in _ends(node.body, path, position, values)}
            results |= current
        return results
    # Unbounded: keep repeating until no new end position appears (positions are finite).
    frontier = set(current)
    while frontier:
        reached = {end for position in frontier for end in _ends(node.body, path, position, values)}
        frontier = reached - results
        results |= frontier
    return results
