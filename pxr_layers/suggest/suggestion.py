"""``suggest``: K light layers for one or more indexes (a shot's frames), as named LPEs."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .. import lpe
from ..paths.reader import PathIndex
from .atoms import ATTRIBUTES, gather
from .partition import SuggestError, check_partition, same_layer
from .search import (MAX_ELBOW_K, NAMELESS_WEIGHT, STRATEGIES, TERM_WEIGHT, UNMATTED_WEIGHT, Leaf, Searcher,
                     elbow)

log = logging.getLogger(__name__)

DEFAULT_K = None
"""No K: the elbow rule chooses it (search.elbow)."""


@dataclass(frozen=True)
class Suggestion:
    """K layers that partition the beauty of every index they were suggested for.

    layers    : name → extended LPE, largest share first (ties by name); the layers offered
    explanations : name → one line an artist reads ("the red light's direct light on ball")
    shares    : name → the layer's share of the beauty's luminance, averaged over the frames
    objective : J of the partition (docs/suggest.md), the search's score
    objectives: J of the best partition into 1, 2, … layers the search found (what the elbow
                rule chose K from, when K was not given)
    chosen_k  : "given" (K asked for) or "elbow" (K chosen by the elbow rule)
    already   : name → the expression of the stack (``exclude``) that a suggested layer
                equals as a set of path classes: not offered again (not in ``layers``)
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
    explanations: dict[str, str] = field(default_factory=dict)
    objectives: tuple[float, ...] = ()
    chosen_k: str = "given"
    already: dict[str, str] = field(default_factory=dict)


def suggest(indexes: Sequence[PathIndex], k: int | None = None, *, strategy: str = STRATEGIES[0],
            threads: int = 2, unmatted_weight: float = UNMATTED_WEIGHT, term_weight: float = TERM_WEIGHT,
            nameless_weight: float = NAMELESS_WEIGHT, exclude: Sequence[str] = ()) -> Suggestion:
    """The K layers (fewer when path space cannot be split further) that maximise the
    objective over every index at once, checked to partition each index's paths. The one
    search behind ``pxr-layers suggest``, the inspector's /api/suggest and ``suggest`` in jobs.

    indexes : the frames of one shot (any order: the result does not depend on it)
    k       : how many layers; None: the elbow of the objective over 1 … MAX_ELBOW_K layers
    threads : threads reading each index's chunks
    exclude : expressions of layers already in a stack; a suggested layer that matches the
              same path classes (records, per first-bounce covariance bin) as one of them in
              every index is not offered again (Suggestion.already)
    Raises SuggestError for no index or k < 1, or when the layers fail the partition check.
    """
    if not indexes:
        raise SuggestError("no path index to suggest layers for")
    if k is not None and k < 1:
        raise SuggestError(f"asked for {k} layers: at least 1")
    for expression in exclude:  # a mistake in the stack's expressions costs nothing
        lpe.compile_layers({"exclude": expression})
    started = time.perf_counter()
    atoms = gather(indexes, threads=threads)
    gathered = time.perf_counter()
    searcher = Searcher(atoms, unmatted_weight=unmatted_weight, term_weight=term_weight,
                        nameless_weight=nameless_weight)
    bests = searcher.search_each(k or MAX_ELBOW_K, strategy)
    objectives = tuple(best.objective for best in bests)
    best = bests[-1] if k else bests[elbow(list(objectives)) - 1]
    searched = time.perf_counter()
    named = _named(best.leaves, atoms, searcher)
    shares = {name: float(leaf.energy / searcher.energy_total) for name, (leaf, _) in named.items()}
    order = sorted(named, key=lambda name: (-shares[name], name))
    layers = {name: named[name][0].node.expression(atoms.labels, atoms.members) for name in order}
    checked = tuple(check_partition(index, layers) for index in indexes)
    already = _already(indexes, layers, exclude)
    log.info("suggested %d layers in %.2f s (read %.2f s, search %.2f s, check %.2f s)", len(layers),
             time.perf_counter() - started, gathered - started, searched - gathered, time.perf_counter() - searched)
    offered = [name for name in order if name not in already]
    return Suggestion({name: layers[name] for name in offered}, {name: shares[name] for name in offered},
                      best.objective, strategy,
                      tuple(f"{attribute} {'<=' if attribute == 'depth' else '='} {value}"
                            for attribute, value in best.splits),
                      atoms.frames, checked, {name: named[name][1] for name in offered}, objectives,
                      "given" if k else "elbow", already)


def _already(indexes: Sequence[PathIndex], layers: dict[str, str], exclude: Sequence[str]) -> dict[str, str]:
    """name → the first expression of `exclude` that cuts the same layer from every index
    (partition.same_layer)."""
    if not exclude:
        return {}
    found: dict[str, str] = {}
    for name, expression in layers.items():
        for other in exclude:
            if all(same_layer(index, expression, other) for index in indexes):
                found[name] = other
                break
    return found


def _named(leaves: tuple[Leaf, ...], atoms, searcher: Searcher) -> dict[str, tuple[Leaf, str]]:
    """Each leaf and its one-line explanation under its readable name, a second leaf of one
    name numbered (``_2``)."""
    named: dict[str, tuple[Leaf, str]] = {}
    energy = np.asarray([float(row.sum()) for row in searcher.atoms.maps])
    for leaf in leaves:
        present = [dict(zip(ATTRIBUTES, atoms.keys[row])) for row in leaf.atoms.tolist() if energy[row] > 0]
        name = base = leaf.node.name(present, atoms.names)
        number = 2
        while name in named or name == "rgba":
            name, number = f"{base}_{number}", number + 1
        named[name] = (leaf, leaf.node.explain(present, atoms.names))
    return named
