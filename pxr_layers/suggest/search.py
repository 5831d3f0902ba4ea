"""Choosing K leaves of the hierarchy: the objective, and two ways to search for its best.

The objective of a partition into layers l (docs/suggest.md, "The objective")::

    J = Σ_l ‖x_l − s_l·b‖₁ / ‖b‖₁  −  OVERLAP_WEIGHT · Σ_{l<m} Σ_t min(e_l(t), e_m(t)) / Σ_t e(t)
        −  TERM_WEIGHT · Σ_l terms_l

x_l : the layer's rgb per frame and tile (atoms.Atoms.maps summed over its atoms), b the
beauty's, s_l = ‖x_l‖₁ / ‖b‖₁ its share; e_l its luminance per tile; terms_l the number of
terms of its expression. The first sum is the light each layer puts where a proportional
slice of the beauty would not (what regrading it can change that regrading the beauty
cannot): it never decreases when a layer is split. The second penalises layers lighting
the same tiles; the third, long expressions.

Strategies: ``greedy`` takes, K − 1 times, the split of one leaf that raises J most;
``beam`` keeps the BEAM_WIDTH best partitions at each step (greedy is beam of width 1).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .atoms import ATTRIBUTES, COVARIANCE, Atoms, luminance
from .layers import Node

log = logging.getLogger(__name__)

OVERLAP_WEIGHT = 0.25
TERM_WEIGHT = 0.002
BEAM_WIDTH = 6
STRATEGIES = ("beam", "greedy")
"""The first is the default: the better of the two on the known-answer tests (docs/suggest.md)."""


@dataclass(frozen=True)
class Leaf:
    """A node and what it holds. atoms : (n,) int64 rows of Atoms; rgb : (f,) its light;
    energy : (f/3,) its luminance per frame and tile; isolated : its term of the first sum."""

    node: Node
    atoms: np.ndarray
    rgb: np.ndarray
    energy: np.ndarray
    isolated: float


@dataclass(frozen=True)
class Partition:
    """Leaves in the order they were made; splits : (attribute, value) of each split, in order."""

    leaves: tuple[Leaf, ...]
    objective: float
    splits: tuple[tuple[str, object], ...]


class Searcher:
    """The objective over one set of atoms, with each leaf's candidate splits cached."""

    def __init__(self, atoms: Atoms, *, overlap_weight: float = OVERLAP_WEIGHT, term_weight: float = TERM_WEIGHT):
        self.atoms = atoms
        self.beauty = atoms.maps.sum(axis=0)
        self.total = float(self.beauty.sum()) or 1.0
        self.energy_total = float(luminance(self.beauty).sum()) or 1.0
        self.overlap_weight, self.term_weight = overlap_weight, term_weight
        self.columns = {attribute: np.array(atoms.values(attribute), dtype=object) for attribute in ATTRIBUTES}
        self._candidates: dict[Node, list[tuple[tuple[str, object], Leaf, Leaf]]] = {}

    def leaf(self, node: Node, rows: np.ndarray) -> Leaf:
        rgb = self.atoms.maps[rows].sum(axis=0)
        share = rgb.sum() / self.total
        return Leaf(node, rows, rgb, luminance(rgb), float(np.abs(rgb - share * self.beauty).sum() / self.total))

    def root(self) -> Partition:
        leaf = self.leaf(Node(), np.arange(len(self.atoms.keys)))
        return Partition((leaf,), self.objective((leaf,)), ())

    def objective(self, leaves: tuple[Leaf, ...]) -> float:
        energy = np.stack([leaf.energy for leaf in leaves])
        overlap = sum(float(np.minimum(energy[i], energy[i + 1:]).sum()) for i in range(len(leaves) - 1))
        return (sum(leaf.isolated for leaf in leaves) - self.overlap_weight * overlap / self.energy_total
                - self.term_weight * sum(leaf.node.terms for leaf in leaves))

    def candidates(self, leaf: Leaf) -> list[tuple[tuple[str, object], Leaf, Leaf]]:
        """Every split of `leaf` whose sides both carry light: ((attribute, value), equal
        side, other side), attributes in ATTRIBUTES order, values sorted."""
        cached = self._candidates.get(leaf.node)
        if cached is not None:
            return cached
        found = []
        include = dict(leaf.node.include)
        for attribute in ATTRIBUTES:
            if attribute in include or (attribute in COVARIANCE and not self.atoms.covariance):
                continue
            column = self.columns[attribute][leaf.atoms]
            if attribute == "depth":
                values = sorted(leaf.node.depths)[:-1]
                sides = [column <= value for value in values]
            else:
                values = sorted({value for value in column.tolist() if value is not None})
                if attribute in COVARIANCE:
                    values = [value for value in values if value == "1"]
                sides = [column == value for value in values]
            for value, equal in zip(values, sides):
                equal = np.asarray(equal, bool)
                if equal.all() or not equal.any():
                    continue
                node_equal, node_other = leaf.node.split(attribute, value)
                first, second = self.leaf(node_equal, leaf.atoms[equal]), self.leaf(node_other, leaf.atoms[~equal])
                if first.energy.sum() > 0 and second.energy.sum() > 0:
                    found.append(((attribute, value), first, second))
        self._candidates[leaf.node] = found
        return found

    def gain(self, leaves: tuple[Leaf, ...], position: int, first: Leaf, second: Leaf) -> float:
        """J after replacing leaves[position] by `first` and `second`, minus J before."""
        parent = leaves[position]
        others = [leaf.energy for number, leaf in enumerate(leaves) if number != position]
        overlap = float(np.minimum(first.energy, second.energy).sum())
        if others:
            stacked = np.stack(others)
            overlap += float((np.minimum(first.energy, stacked).sum() + np.minimum(second.energy, stacked).sum()
                              - np.minimum(parent.energy, stacked).sum()))
        return (first.isolated + second.isolated - parent.isolated - self.overlap_weight * overlap / self.energy_total
                - self.term_weight * (first.node.terms + second.node.terms - parent.node.terms))

    def search(self, k: int, strategy: str, width: int = BEAM_WIDTH) -> Partition:
        """The best partition into at most `k` leaves the strategy finds (fewer when no
        split is left)."""
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown strategy {strategy!r} (known: {', '.join(STRATEGIES)})")
        beam = [self.root()]
        width = 1 if strategy == "greedy" else width
        for _ in range(k - 1):
            grown: list[tuple[float, int, Partition]] = []
            seen: set[frozenset] = set()
            order = 0
            for state in beam:
                for position, leaf in enumerate(state.leaves):
                    for split, first, second in self.candidates(leaf):
                        leaves = state.leaves[:position] + (first, second) + state.leaves[position + 1:]
                        identity = frozenset(leaf.node for leaf in leaves)
                        if identity in seen:
                            continue
                        seen.add(identity)
                        value = state.objective + self.gain(state.leaves, position, first, second)
                        grown.append((value, order, Partition(leaves, value, state.splits + (split,))))
                        order += 1
            if not grown:
                break
            grown.sort(key=lambda item: (-item[0], item[1]))
            beam = [partition for _, _, partition in grown[:width]]
        best = beam[0]
        log.info("%s search: %d layers, objective %.4f", strategy, len(best.leaves), best.objective)
        return best
