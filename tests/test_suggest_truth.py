"""Known-truth tests of `pxr-layers suggest` (issue 40): stages built here whose right
answer is known by construction (tests/truth_stages.py), the adjusted Rand index of the
per-pixel dominant suggested layer against it, and the layers summing to the beauty."""

from __future__ import annotations

import numpy as np


def adjusted_rand_index(labels: np.ndarray, truth: np.ndarray) -> float:
    """Hubert & Arabie's (1985) adjusted Rand index of two labellings of the same items
    (1: the same partition, ~0: as good as chance). Two trivial labellings (one cluster
    each, or all singletons on both sides) are 1 if equal as partitions, else 0."""
    _, a = np.unique(np.asarray(labels).reshape(-1), return_inverse=True)
    _, b = np.unique(np.asarray(truth).reshape(-1), return_inverse=True)
    table = np.zeros((a.max() + 1, b.max() + 1))
    np.add.at(table, (a.reshape(-1), b.reshape(-1)), 1)

    def pairs(counts: np.ndarray) -> float:
        return float((counts * (counts - 1) / 2).sum())

    index, rows, columns, total = pairs(table), pairs(table.sum(1)), pairs(table.sum(0)), pairs(np.array([a.size]))
    expected = rows * columns / total
    maximum = (rows + columns) / 2
    if maximum == expected:
        return 1.0 if index == maximum else 0.0
    return (index - expected) / (maximum - expected)
