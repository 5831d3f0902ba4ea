"""Choosing K leaves of the hierarchy: the objective, and two ways to search for its best.

The objective of a partition into layers l (docs/suggest.md, "The objective")::

    J = Σ_l ‖x_l − s_l·b‖₁ / ‖b‖₁                                  what a grade of the beauty cannot do
        + UNMATTED_WEIGHT · Σ_l Σ_m ‖min(x_lm, b_m − x_lm)‖₁ / ‖b‖₁   what an ID matte cannot do
        − TERM_WEIGHT · Σ_l terms_l                                   long expressions

x_l : the layer's rgb per frame and tile (atoms.Atoms.maps summed over its atoms), b the
beauty's, s_l = ‖x_l‖₁ / ‖b‖₁ its share; x_lm, b_m the same under the ID matte m (the
atoms whose camera ray first hits m: Atoms.mattes); terms_l the number of terms of its
expression. The first sum is the light each layer puts where a proportional slice of the
beauty would not; the second, the light it separates *within* the pixels of one matte:
x_lm's distance to the nearest all-or-nothing cut of b_m, which is 0 for a layer made of
whole objects (a Cryptomatte gives that already) and large for a light, a lobe or a
bounce count that shares its pixels with others. Neither decreases when a layer is split.

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

UNMATTED_WEIGHT = 3.0
"""Calibrated (docs/suggest.md): from 1.25 the showcase's first split is by light; above
3.25 the known-answer stage splits its glossy box into lobes before its lights apart."""
TERM_WEIGHT = 0.002
BEAM_WIDTH = 6
STRATEGIES = ("beam", "greedy")
"""The first is the default: the better of the two on the known-answer tests (docs/suggest.md)."""


@dataclass(frozen=True)
class Leaf:
    """A node and what it holds. atoms : (n,) int64 rows of Atoms; rgb : (f,) its light;
    energy : its luminance summed over frames and tiles; isolated, unmatted : its terms of
    the first two sums."""

    node: Node
    atoms: np.ndarray
    rgb: np.ndarray
    energy: float
    isolated: float
    unmatted: float


@dataclass(frozen=True)
class Partition:
    """Leaves in the order they were made; splits : (attribute, value) of each split, in order."""

    leaves: tuple[Leaf, ...]
    objective: float
    splits: tuple[tuple[str, object], ...]


class Searcher:
    """The objective over one set of atoms, with each leaf's candidate splits cached."""

    def __init__(self, atoms: Atoms, *, unmatted_weight: float = UNMATTED_WEIGHT, term_weight: float = TERM_WEIGHT):
        self.atoms = atoms
        self.beauty = atoms.maps.sum(axis=0)
        self.total = float(self.beauty.sum()) or 1.0
        self.energy_total = float(luminance(self.beauty).sum()) or 1.0
        self.mattes = atoms.mattes()
        self.matte_beauty = self._by_matte(np.arange(len(atoms.keys)))[1]  # (m, f): the beauty under each matte
        self.unmatted_weight, self.term_weight = unmatted_weight, term_weight
        self.columns = {attribute: np.array(atoms.values(attribute), dtype=object) for attribute in ATTRIBUTES}
        self._candidates: dict[Node, list[tuple[tuple[str, object], Leaf, Leaf]]] = {}

    def leaf(self, node: Node, rows: np.ndarray) -> Leaf:
        present, by_matte = self._by_matte(rows)
        rgb = by_matte.sum(axis=0)
        share = rgb.sum() / self.total
        beauty = self.matte_beauty[present]
        # clipped: rounding can leave the beauty a hair below a leaf that holds all of it
        unmatted = np.minimum(by_matte, beauty - by_matte).clip(min=0).sum() / self.total
        isolated = np.abs(rgb - share * self.beauty).sum() / self.total
        return Leaf(node, rows, rgb, float(luminance(rgb).sum()), float(isolated), float(unmatted))

    def _by_matte(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(p,) the mattes the atoms `rows` fall under, ascending; (p, f) their light under each.
        A sum per run of one matte (np.add.reduceat), not a product with a one-hot matrix:
        BLAS threads make products this small slower, not faster, on a busy machine."""
        rows = rows[np.argsort(self.mattes[rows], kind="stable")]
        mattes = self.mattes[rows]
        starts = np.flatnonzero(np.r_[True, mattes[1:] != mattes[:-1]])
        return mattes[starts], np.add.reduceat(self.atoms.maps[rows], starts, axis=0)

    def root(self) -> Partition:
        leaf = self.leaf(Node(), np.arange(len(self.atoms.keys)))
        return Partition((leaf,), self.objective((leaf,)), ())

    def objective(self, leaves: tuple[Leaf, ...]) -> float:
        return sum(self._value(leaf) for leaf in leaves)

    def _value(self, leaf: Leaf) -> float:
        """A leaf's part of J: J is a sum over the leaves."""
        return leaf.isolated + self.unmatted_weight * leaf.unmatted - self.term_weight * leaf.node.terms

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
                if first.energy > 0 and second.energy > 0:
                    found.append(((attribute, value), first, second))
        self._candidates[leaf.node] = found
        return found

    def gain(self, parent: Leaf, first: Leaf, second: Leaf) -> float:
        """J after replacing `parent` by `first` and `second`, minus J before."""
        return self._value(first) + self._value(second) - self._value(parent)

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
                        value = state.objective + self.gain(leaf, first, second)
                        grown.append((value, order, Partition(leaves, value, state.splits + (split,))))
                        order += 1
            if not grown:
                break
            grown.sort(key=lambda item: (-item[0], item[1]))
            beam = [partition for _, _, partition in grown[:width]]
        best = beam[0]
        log.info("%s search: %d layers, objective %.4f", strategy, len(best.leaves), best.objective)
        return best
