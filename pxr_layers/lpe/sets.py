"""Exclusive and remainder layers: expressions that make a stack sum to the beauty exactly.

Layers of a stack may claim the same paths (their sum then counts that light twice) or
leave some unclaimed. With the set difference of the extended syntax (``A - B``: the paths
``A`` matches and ``B`` does not, decided per record; docs/lpe.md, "Set difference"):

* the **exclusive** version of a layer is its expression less every layer before it in
  the stack: ``L3 - (L1|L2)``;
* the **remainder** of a stack is the beauty less all of its layers: ``C.* - (L1|L2|L3)``.

A stack of exclusive versions (the first layer as it is) plus the remainder is a partition
of the records, so it sums to the beauty (``layers.overlaps`` measures the overlaps).

Layers of the stack that are themselves differences are taken as they are when exact: a
stack ``L1, L2 - L1, L3 - (L1|L2)`` claims what ``L1|L2|L3`` does (each subtracts only
layers before it), so its remainder is ``C.* - (L1|L2|L3)``. A difference that subtracts
anything else cannot be subtracted in turn (the syntax has one difference, at the top), and
is an LpeError naming it.
"""

from __future__ import annotations

from collections.abc import Sequence

from ..errors import LpeError
from . import nodes
from .parser import parse
from .passes import BEAUTY


def exclusive(expression: str, before: Sequence[str]) -> str:
    """The canonical expression of ``expression`` less every record of the layers ``before``
    (their expressions, in stack order); ``expression`` itself when ``before`` is empty."""
    tree = parse(expression)
    claimed = _claimed(before)
    if not claimed:
        return nodes.canonical(tree)
    if isinstance(tree, nodes.Difference):
        return nodes.canonical(nodes.Difference(tree.positive, nodes.union([*_alternatives(tree.negative), *claimed])))
    return nodes.canonical(nodes.Difference(tree, nodes.union(claimed)))


def remainder(expressions: Sequence[str], beauty: str = BEAUTY) -> str:
    """The canonical expression of the records of ``beauty`` that no layer of
    ``expressions`` (a stack, in order) claims."""
    return exclusive(beauty, expressions)


def _claimed(expressions: Sequence[str]) -> list:
    """Alternatives (trees) whose union is every record the layers claim (module docstring)."""
    claimed: list = []
    for number, text in enumerate(expressions):
        tree = parse(text)
        if isinstance(tree, nodes.Difference):
            taken = _alternatives(tree.negative)
            if not all(alternative in claimed for alternative in taken):
                raise LpeError(f"layer {number + 1} of the stack ({nodes.canonical(tree)}) subtracts paths that no "
                               "layer before it claims: a set difference cannot be subtracted in turn; subtract "
                               "its first part and what it subtracts separately")
            tree = tree.positive
        claimed.extend(alternative for alternative in _alternatives(tree) if alternative not in claimed)
    return claimed


def _alternatives(tree) -> list:
    return list(tree.alternatives) if isinstance(tree, nodes.Union) else [tree]
