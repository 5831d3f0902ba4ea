"""``suggest``: K light layers for one or more indexes (a shot's frames), as named LPEs."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..paths.reader import PathIndex
from .atoms import ATTRIBUTES, gather
from .partition import SuggestError, check_partition
from .search import STRATEGIES, TERM_WEIGHT, UNMATTED_WEIGHT, Leaf, Searcher

log = logging.getLogger(__name__)

DEFAULT_K = 6


@dataclass(frozen=True)
class Suggestion:
    """K layers that partition the beauty of every index they were suggested for.

    layers    : name → extended LPE, largest share first (ties by name)
    shares    : name → the layer's share of the beauty's luminance, averaged over the frames
    objective : J of the partition (docs/suggest.md), the search's score
    strategy  : the search that chose it ("beam" or "greedy")
    splits    : the splits taken, in order, as "attribute = value"
    frames    : the indexes, in the order their tiles were laid out (by frame, then path)
    checked   : distinct automaton symbol sequences checked per index (partition.check_partition)
    """

    layers: dict[str, str]
    shares: dict[str, float]
    objective: float
    strategy: str
    splits: tuple[str, ...]
    frames: tuple[str, ...]
    checked: tuple[int, ...]


def suggest(indexes: Sequence[PathIndex], k: int = DEFAULT_K, *, strategy: str = STRATEGIES[0],
            threads: int = 2, unmatted_weight: float = UNMATTED_WEIGHT, term_weight: float = TERM_WEIGHT) -> Suggestion:
    """The K layers (fewer when path space cannot be split further) that maximise the
    objective over every index at once, checked to partition each index's paths.

    indexes : the frames of one shot (any order: the result does not depend on it)
    threads : threads reading each index's chunks
    Raises SuggestError for no index or k < 1, or when the layers fail the partition check.
    """
    if not indexes:
        raise SuggestError("no path index to suggest layers for")
    if k < 1:
        raise SuggestError(f"asked for {k} layers: at least 1")
    started = time.perf_counter()
    atoms = gather(indexes, threads=threads)
    gathered = time.perf_counter()
    searcher = Searcher(atoms, unmatted_weight=unmatted_weight, term_weight=term_weight)
    best = searcher.search(k, strategy)
    searched = time.perf_counter()
    named = _named(best.leaves, atoms, searcher)
    shares = {name: float(leaf.energy / searcher.energy_total) for name, leaf in named.items()}
    order = sorted(named, key=lambda name: (-shares[name], name))
    layers = {name: named[name].node.expression(atoms.labels) for name in order}
    checked = tuple(check_partition(index, layers) for index in indexes)
    log.info("suggested %d layers in %.2f s (read %.2f s, search %.2f s, check %.2f s)", len(layers),
             time.perf_counter() - started, gathered - started, searched - gathered, time.perf_counter() - searched)
    return Suggestion(layers, {name: shares[name] for name in order}, best.objective, strategy,
                      tuple(f"{attribute} {'<=' if attribute == 'depth' else '='} {value}"
                            for attribute, value in best.splits),
                      atoms.frames, checked)


def _named(leaves: tuple[Leaf, ...], atoms, searcher: Searcher) -> dict[str, Leaf]:
    """Each leaf under its readable name, a second leaf of one name numbered (``_2``)."""
    named: dict[str, Leaf] = {}
    energy = np.asarray([float(row.sum()) for row in searcher.atoms.maps])
    for leaf in leaves:
        present = [dict(zip(ATTRIBUTES, atoms.keys[row])) for row in leaf.atoms.tolist() if energy[row] > 0]
        name = base = leaf.node.name(present, atoms.names)
        number = 2
        while name in named or name == "rgba":
            name, number = f"{base}_{number}", number + 1
        named[name] = leaf
    return named
