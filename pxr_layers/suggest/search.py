"""Choosing K leaves of the hierarchy: the objective, and two ways to search for its best.

The objective of a partition into layers l (docs/suggest.md, "The objective")::

    J = Σ_l ‖x_l − s_l·b‖₁ / ‖b‖₁                                  what a grade of the beauty cannot do
        + UNMATTED_WEIGHT · Σ_l Σ_m ‖min(x_lm, b_m − x_lm)‖₁ / ‖b‖₁   what an ID matte cannot do
        − NAMELESS_WEIGHT · Σ_{l not nameable} s_l                    what no one can name
        − TERM_WEIGHT · Σ_l terms_l − TOUCH_TERM_WEIGHT · Σ_l touch terms_l   long expressions

x_l : the layer's rgb per frame and tile (atoms.Atoms.maps summed over its atoms), b the
beauty's, s_l = ‖x_l‖₁ / ‖b‖₁ its share; x_lm, b_m the same under the ID matte m (the
atoms whose camera ray first hits m: Atoms.mattes); terms_l the number of terms of its
expression. The first sum is the light each layer puts where a proportional slice of the
beauty would not; the second, the light it separates *within* the pixels of one matte:
x_lm's distance to the nearest all-or-nothing cut of b_m, which is 0 for a layer made of
whole objects (a Cryptomatte gives that already) and large for a light, a lobe or a
bounce count that shares its pixels with others. Neither decreases when a layer is split.
The third takes the share of a layer that names no light, object, material or touch, or
cuts by bounce, lobe or covariance without naming one light (Node.nameable).

Without K, ``elbow`` chooses it from J of the best partition into 1, 2, … layers.

Strategies: ``greedy`` takes, K − 1 times, the split of one leaf that raises J most;
``beam`` keeps the BEAM_WIDTH best partitions at each step (greedy is beam of width 1).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .atoms import ATTRIBUTES, COVARIANCE, Atoms, luminance
from .layers import TOUCHES, Node

log = logging.getLogger(__name__)

NAMELESS_WEIGHT = 1.0
"""Per unit of share of a layer that names no light, object, material or touch (docs/suggest.md)."""
ELBOW_FLAT = 0.02
"""J(2) − J(1) at or under which no split is worth making: the elbow rule suggests one layer."""
ELBOW_FRACTION = 0.2
"""A split gaining less than this fraction of the first split's gain is past the elbow."""
MAX_ELBOW_K = 8
"""The largest K the elbow rule looks at when -k is left out."""
UNMATTED_WEIGHT = 1.5
"""Calibrated (docs/suggest.md): from 1.25 the showcase's first split is by light; above
3.25 the known-answer stage splits its glossy box into lobes before its lights apart."""
TERM_WEIGHT = 0.002
TOUCH_TERM_WEIGHT = 0.02
"""More per whole-path touch term (on top of TERM_WEIGHT): a set difference over whole paths
is harder to read than a term on the emitter or the first bounce, so where a light and the
walls it alone lights cut the same paths (within the noise), the light is chosen."""
RUNS_SUMMED_ONE_BY_ONE = 64
"""Up to this many mattes in a leaf, its per-matte sums are taken one matte at a time."""
BEAM_WIDTH = 6
STRATEGIES = ("beam", "greedy")
"""The first is the default: the better of the two on the known-answer tests (docs/suggest.md)."""


@dataclass(frozen=True)
class Leaf:
    """A node and what it holds. atoms : (n,) int64 rows of Atoms; rgb : (f,) its light;
    energy : its luminance summed over frames and tiles; isolated, unmatted : its terms of
    the first two sums; nameable : Node.nameable of its node and atoms, the third sum
    counting its share when not; mattes : (p,) the ID mattes its atoms fall under,
    ascending; by_matte : (p, f) its light under each. Its atoms are kept in matte order,
    so that one side of a split is a sum per run."""

    node: Node
    atoms: np.ndarray
    rgb: np.ndarray
    energy: float
    isolated: float
    unmatted: float
    nameable: bool
    mattes: np.ndarray
    by_matte: np.ndarray


@dataclass(frozen=True)
class Partition:
    """Leaves in the order they were made; splits : (attribute, value) of each split, in order."""

    leaves: tuple[Leaf, ...]
    objective: float
    splits: tuple[tuple[str, object], ...]


class Searcher:
    """The objective over one set of atoms, with each leaf's candidate splits cached."""

    def __init__(self, atoms: Atoms, *, unmatted_weight: float = UNMATTED_WEIGHT, term_weight: float = TERM_WEIGHT,
                 nameless_weight: float = NAMELESS_WEIGHT):
        self.atoms = atoms
        self.beauty = atoms.maps.sum(axis=0)
        self.total = float(self.beauty.sum()) or 1.0
        self.energy_total = float(luminance(self.beauty).sum()) or 1.0
        self.mattes = atoms.mattes()
        # (m, f): the beauty under each matte
        self.matte_beauty = self._by_matte(np.argsort(self.mattes, kind="stable"))[1]
        self.unmatted_weight, self.term_weight = unmatted_weight, term_weight
        self.nameless_weight = nameless_weight
        self.columns = {attribute: _object_column(atoms.values(attribute)) for attribute in ATTRIBUTES}
        self.lit = luminance(atoms.maps).sum(axis=1) > 0  # (a,) atoms that carry light
        # (a,) int64 code of each atom's light group, light, object, material: what a leaf is left with
        self.codes = {attribute: np.unique(np.array([str(value) for value in self.columns[attribute]]),
                                           return_inverse=True)[1].reshape(-1)
                      for attribute in ("group", "light", "object", "material")}
        self.tokens = sorted({token for touched in self.columns[TOUCHES] for token in touched})
        token_column = {token: column for column, token in enumerate(self.tokens)}
        self.touch_matrix = np.zeros((len(atoms.keys), len(self.tokens)), bool)  # (a, tokens): atom touches token
        for row, touched in enumerate(self.columns[TOUCHES]):
            self.touch_matrix[row, [token_column[token] for token in touched]] = True
        self._candidates: dict[Node, list[tuple[tuple[str, object], Leaf, Leaf]]] = {}

    def leaf(self, node: Node, rows: np.ndarray) -> Leaf:
        """The leaf of `node` holding the atoms `rows` (in any order)."""
        rows = rows[np.argsort(self.mattes[rows], kind="stable")]
        mattes, by_matte = self._by_matte(rows)
        return self._leaf(node, rows, mattes, by_matte)

    def _leaf(self, node: Node, rows: np.ndarray, mattes: np.ndarray, by_matte: np.ndarray) -> Leaf:
        rgb = by_matte.sum(axis=0)
        share = rgb.sum() / self.total
        beauty = self.matte_beauty[mattes]
        # clipped: rounding can leave the beauty a hair below a leaf that holds all of it
        unmatted = np.minimum(by_matte, beauty - by_matte).clip(min=0).sum() / self.total
        isolated = np.abs(rgb - share * self.beauty).sum() / self.total
        return Leaf(node, rows, rgb, float(luminance(rgb).sum()), float(isolated), float(unmatted),
                    self._nameable(node, rows), mattes, by_matte)

    def _sides(self, parent: Leaf, equal: np.ndarray, attribute: str, value) -> tuple[Leaf, Leaf]:
        """The two leaves of splitting `parent` where `equal` ((n,) bool over its atoms) holds:
        the smaller side summed per matte, the larger one the parent's sums less it."""
        node_equal, node_other = parent.node.split(attribute, value)
        if attribute == "group":
            left = set(self.columns["group"][parent.atoms[~equal]].tolist())
            if len(left) == 1 and None not in left:  # every path of the other side ends at one other group
                node_other = node_other.pinned("group", left.pop())
        small = equal if equal.sum() * 2 <= len(equal) else ~equal
        small_rows, large_rows = parent.atoms[small], parent.atoms[~small]
        small_mattes, small_sums = self._by_matte(small_rows)
        large_mattes = np.unique(self.mattes[large_rows])
        large_sums = parent.by_matte[np.searchsorted(parent.mattes, large_mattes)].copy()
        shared = np.isin(small_mattes, large_mattes)
        large_sums[np.searchsorted(large_mattes, small_mattes[shared])] -= small_sums[shared]
        small_leaf = self._leaf(node_equal if small is equal else node_other, small_rows, small_mattes, small_sums)
        large_leaf = self._leaf(node_other if small is equal else node_equal, large_rows, large_mattes, large_sums)
        return (small_leaf, large_leaf) if small is equal else (large_leaf, small_leaf)

    def _nameable(self, node: Node, rows: np.ndarray) -> bool:
        """Node.nameable, the attributes its lit atoms hold one value of found on codes."""
        lit = rows[self.lit[rows]]
        single = {attribute for attribute, codes in self.codes.items()
                  if len(lit) and (codes[lit] == codes[lit[0]]).all() and self.columns[attribute][lit[0]] is not None}
        return node.nameable(single)

    def _by_matte(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(p,) the mattes the atoms `rows` (in matte order) fall under, ascending; (p, f)
        their light under each. A sum per run of one matte: ndarray.sum per run when there
        are few runs (three times np.add.reduceat's speed along rows), reduceat when there
        are many; not a product with a one-hot matrix, which BLAS threads make slower, not
        faster, on a busy machine."""
        mattes = self.mattes[rows]
        starts = np.flatnonzero(np.r_[True, mattes[1:] != mattes[:-1]])
        light = self.atoms.maps[rows]
        if len(starts) > RUNS_SUMMED_ONE_BY_ONE:
            return mattes[starts], np.add.reduceat(light, starts, axis=0)
        ends = [*starts[1:].tolist(), len(rows)]
        return mattes[starts], np.array([light[start:end].sum(axis=0) for start, end in zip(starts.tolist(), ends)])

    def root(self) -> Partition:
        leaf = self.leaf(Node(), np.arange(len(self.atoms.keys)))
        return Partition((leaf,), self.objective((leaf,)), ())

    def objective(self, leaves: tuple[Leaf, ...]) -> float:
        return sum(self._value(leaf) for leaf in leaves)

    def _value(self, leaf: Leaf) -> float:
        """A leaf's part of J: J is a sum over the leaves."""
        nameless = 0.0 if leaf.nameable else leaf.energy / self.energy_total
        touch_terms = len(leaf.node.touched) + len(dict(leaf.node.exclude).get(TOUCHES, ()))
        return (leaf.isolated + self.unmatted_weight * leaf.unmatted - self.term_weight * leaf.node.terms
                - TOUCH_TERM_WEIGHT * touch_terms - self.nameless_weight * nameless)

    def candidates(self, leaf: Leaf) -> list[tuple[tuple[str, object], Leaf, Leaf]]:
        """Every split of `leaf` whose sides both carry light: ((attribute, value), equal
        side, other side), attributes in ATTRIBUTES order, values sorted. A group or light
        split that cuts the leaf's atoms as a group split before it did (a group of one
        light, the other of two groups) is left out: the group's is the one kept."""
        cached = self._candidates.get(leaf.node)
        if cached is not None:
            return cached
        found = []
        group_cuts: set[bytes] = set()  # the atoms group splits cut off, and what they leave
        include = dict(leaf.node.include)
        for attribute in ATTRIBUTES:
            if attribute in include or (attribute in COVARIANCE and not self.atoms.covariance):
                continue
            column = self.columns[attribute][leaf.atoms]
            if attribute == TOUCHES:
                held = self.touch_matrix[leaf.atoms]
                avoided = dict(leaf.node.exclude).get(TOUCHES, frozenset())
                any_held = held.any(axis=0)
                kept = [(number, token) for number, token in enumerate(self.tokens)
                        if any_held[number] and token not in leaf.node.touched and token not in avoided]
                values = [token for _, token in kept]
                sides = [held[:, number] for number, _ in kept]
            elif attribute == "depth":
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
                if attribute in ("group", "light"):
                    if equal.tobytes() in group_cuts:
                        continue
                    if attribute == "group":
                        group_cuts.update((equal.tobytes(), (~equal).tobytes()))
                first, second = self._sides(leaf, equal, attribute, value)
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
        return self.search_each(k, strategy, width)[-1]

    def search_each(self, k: int, strategy: str, width: int = BEAM_WIDTH) -> list[Partition]:
        """The best partition the strategy finds into 1, 2, …, `k` leaves (one search: the
        best of the beam after each step), shorter when no split is left."""
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown strategy {strategy!r} (known: {', '.join(STRATEGIES)})")
        beam = [self.root()]
        bests = [beam[0]]
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
            bests.append(beam[0])
        log.info("%s search: %d layers, objective %.4f", strategy, len(bests[-1].leaves), bests[-1].objective)
        return bests


def elbow(objectives: list[float]) -> int:
    """The number of layers (1-based) at the elbow of J(1), J(2), …: the first K whose next
    split gains less than ELBOW_FRACTION of what the first split gained (J(2) − J(1)), the
    last K when none does; 1 when the first split gains ELBOW_FLAT or less (nothing worth
    splitting). The first split is the measure of what a split can do on this stage."""
    values = np.asarray(objectives, float)
    if len(values) < 2 or values[1] - values[0] <= ELBOW_FLAT:
        return 1
    gains = np.diff(values)
    small = np.flatnonzero(gains[1:] < ELBOW_FRACTION * gains[0])
    return int(small[0]) + 2 if len(small) else len(values)


def _object_column(values: list) -> np.ndarray:
    """values as a (a,) object array, tuples (touches) kept whole."""
    column = np.empty(len(values), dtype=object)
    column[:] = values
    return column
