"""Cut layers out of a path index with Light Path Expressions, without rendering again.

The fast path never matches records one by one. The recipe's expressions are compiled
into one automaton; it runs once over each distinct event sequence of the index (its
path classes), which says per layer: never, always, or depending on the covariance
norms of given events. Only the classes some layer can match are read from disk
(chunks of other classes are skipped), covariance conditions are evaluated only on the
records of conditional classes, and every layer is accumulated per pixel in float64 in
the same pass. Images are divided by spp like the beauty, and returned as float32.

``extract_reference`` is the slow, obvious version (every record matched on its own by
the tree-walking reference matcher) that the fast one is tested against.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from .. import lpe
from ..paths.reader import PathIndex
from ..progress import Progress

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Extraction:
    """layers : name → (h, w, 3) float32 linear images (same scale as the beauty)
    records_read : records decoded from disk; classes_matched : classes some layer can use
    """

    layers: dict[str, np.ndarray]
    records_read: int
    classes_matched: int


def extract(index: PathIndex, expressions: dict[str, str], *, show_progress: bool = False) -> Extraction:
    """Every layer of `expressions` (name → extended LPE) from `index`, in one pass."""
    automaton = lpe.compile_layers(expressions)
    warn_unknown_labels(automaton, index)
    names = list(expressions)
    class_count = len(index.classes)
    always = np.zeros((len(names), class_count), bool)
    conditional: dict[int, list[tuple[int, lpe.Outcome]]] = {}
    for path_class in index.classes:
        for layer, outcome in automaton.match(path_class.events).items():
            if outcome.kind == "always":
                always[names.index(layer), path_class.id] = True
            elif outcome.kind == "conditional":
                conditional.setdefault(path_class.id, []).append((names.index(layer), outcome))
    wanted = np.flatnonzero(always.any(axis=0)).tolist() + list(conditional)
    width, height = index.manifest["resolution"]
    pixels = width * height
    sums = np.zeros((len(names), 3, pixels))
    records_read = 0
    total = sum(index.classes[c].records for c in wanted)
    progress = Progress(total, "extract", enabled=show_progress)
    for chunk in index.records(wanted, norms=bool(conditional)):
        records_read += len(chunk.class_id)
        selected = always[:, chunk.class_id]  # (layers, r)
        for class_id in np.intersect1d(np.unique(chunk.class_id), list(conditional)).tolist():
            rows = np.flatnonzero(chunk.class_id == class_id)
            for layer, outcome in conditional[class_id]:
                selected[layer, rows] = outcome.mask(chunk.norms[rows])
        for layer in range(len(names)):
            chosen = selected[layer]
            if not chosen.any():
                continue
            where = chunk.pixel[chosen]
            for channel in range(3):
                sums[layer, channel] += np.bincount(where, weights=chunk.rgb[chosen, channel], minlength=pixels)
        progress.advance(len(chunk.class_id))
    log.info("extracted %d layers from %d of %d records (%d of %d classes)", len(names), records_read,
             index.record_count, len(wanted), class_count)
    return Extraction(_images(sums, names, index), records_read, len(wanted))


def extract_reference(index: PathIndex, expressions: dict[str, str]) -> dict[str, np.ndarray]:
    """The same layers, matching every record on its own with ``lpe.reference_match``."""
    trees = {name: lpe.parse(expression) for name, expression in expressions.items()}
    width, height = index.manifest["resolution"]
    sums = np.zeros((len(trees), 3, width * height))
    for chunk in index.records():
        for record in range(len(chunk.class_id)):
            events = index.classes[chunk.class_id[record]].events
            for layer, tree in enumerate(trees.values()):
                if lpe.reference_match(tree, events, chunk.norms[record]):
                    sums[layer, :, chunk.pixel[record]] += chunk.rgb[record]
    return _images(sums, list(trees), index)


def warn_unknown_labels(automaton: lpe.LayerAutomaton, index: PathIndex) -> None:
    """A label that names nothing in the index is a warning listing the closest names."""
    table = automaton.alphabet.patterns
    matched = 0
    for label in index.labels:
        matched |= table.label_mask(label)
    for bit, pattern in enumerate(table.patterns):
        if not matched >> bit & 1:
            closest = lpe.closest_labels(pattern, index.labels)
            log.warning("label '%s' names nothing in %s; closest: %s", pattern, index.path,
                        ", ".join(f"'{name}'" for name in closest) or "none")


def _images(sums: np.ndarray, names: list[str], index: PathIndex) -> dict[str, np.ndarray]:
    width, height = index.manifest["resolution"]
    spp = index.manifest["spp"]
    return {name: (sums[layer] / spp).T.reshape(height, width, 3).astype(np.float32)
            for layer, name in enumerate(names)}
