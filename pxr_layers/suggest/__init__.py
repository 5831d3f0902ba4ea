"""Layers found automatically: path space clustered into "light touches" (docs/suggest.md).

A hierarchy of splits over path space (by light, bounce count, the first bounce's object,
material, type, scattering and covariance bins, and what the whole path touches: any
bounce's object, material or asset) and a search for the K leaves that best serve an
artist under a stated objective (separated in the picture, nameable; K by its elbow when
not given); every leaf is an LPE with a name and a one-line explanation, and the K layers
partition the beauty of every frame they were chosen for.

    suggestion = suggest([PathIndex("shot.0001.pxlidx"), ...], k=6)
    suggestion.layers      # name → LPE, largest share first
    suggestion.shares      # name → share of the beauty
    suggestion.objective   # the objective's value

Modules: ``atoms`` (one read of each index: light per atom and tile), ``layers`` (a node's
terms, LPE and name), ``search`` (the objective, greedy and beam search), ``partition``
(the automaton's check that the layers partition the paths), ``suggestion`` (``suggest``).
"""

from .partition import SuggestError, check_partition
from .search import MAX_ELBOW_K, STRATEGIES
from .suggestion import DEFAULT_K, Suggestion, suggest

__all__ = ["DEFAULT_K", "MAX_ELBOW_K", "STRATEGIES", "SuggestError", "Suggestion", "check_partition", "suggest"]
