"""Help for label typos: the known names closest to a quoted label of an expression."""

from __future__ import annotations

import difflib

from .events import is_glob

SIMILARITY_CUTOFF = 0.6
"""difflib ratio below which a name is not worth suggesting."""


def closest_labels(label: str, known, n: int = 3) -> list[str]:
    """Up to ``n`` names of ``known`` closest to ``label``, best first (difflib ratio).

    Prim paths are long and share prefixes, so a path-like label is also compared by its
    last component: ``'/World/Lights/kye'`` suggests ``/World/Lights/key``.
    """
    known = list(dict.fromkeys(known))
    if not known:
        return []
    text = label.replace("*", "").replace("?", "") if is_glob(label) else label
    scored = {}
    for name in known:
        score = difflib.SequenceMatcher(None, text, name).ratio()
        if "/" in text and "/" in name:
            score = max(score, difflib.SequenceMatcher(None, text.rsplit("/", 1)[-1], name.rsplit("/", 1)[-1]).ratio())
        if score >= SIMILARITY_CUTOFF:
            scored[name] = score
    return sorted(scored, key=lambda name: (-scored[name], name))[:n]
