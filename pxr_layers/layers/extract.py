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
from ..lpe.automaton import DEAD
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
    automata = _automata(expressions)
    for automaton in automata:
        warn_unknown_labels(automaton, index)
    names = list(expressions)
    class_count = len(index.classes)
    always = np.zeros((len(names), class_count), bool)
    # Conditional classes whose outcomes are the same function of the same atoms share one
    # group: its mask is evaluated once per chunk over all their records.
    group_of = np.full((len(names), class_count), -1, np.int64)
    groups: list[lpe.Outcome] = []
    signatures: dict[tuple, int] = {}
    group_of_outcome: dict[tuple[int, int], int] = {}  # (row, id): classes share outcome objects
    rows = {name: row for row, name in enumerate(names)}
    every_class_outcomes = (item for automaton in automata for item in _class_outcomes(automaton, index))
    for class_id, outcomes in every_class_outcomes:
        for layer, outcome in outcomes.items():
            row = rows[layer]
            if outcome.kind == "always":
                always[row, class_id] = True
            elif outcome.kind == "conditional":
                group = group_of_outcome.get((row, id(outcome)))
                if group is None:
                    signature = (row, outcome.atoms, outcome.table.tobytes()) \
                        if isinstance(outcome, lpe.Conditional) else (row, id(outcome))  # PerRecord: its own
                    group = group_of_outcome[row, id(outcome)] = signatures.setdefault(signature, len(groups))
                    if group == len(groups):
                        groups.append(outcome)
                group_of[row, class_id] = group
    conditional_rows = np.flatnonzero((group_of >= 0).any(axis=1)).tolist()
    wanted = np.flatnonzero(always.any(axis=0) | (group_of >= 0).any(axis=0))
    width, height = index.manifest["resolution"]
    accumulator = _Accumulator(len(names), width * height)
    records_read = 0
    progress = Progress(sum(index.classes[c].records for c in wanted.tolist()), "extract", enabled=show_progress)
    for chunk in index.records(wanted.tolist(), norms=bool(groups)):
        records_read += len(chunk.class_id)
        selected = always[:, chunk.class_id]  # (layers, r)
        for row in conditional_rows:
            # The chunk's records of each group of the layer, from one sort by group.
            chunk_groups = group_of[row, chunk.class_id]
            records = np.flatnonzero(chunk_groups >= 0)
            records = records[np.argsort(chunk_groups[records], kind="stable")]
            sorted_groups = chunk_groups[records]
            starts = np.flatnonzero(np.diff(sorted_groups, prepend=-1))
            for start, stop in zip(starts.tolist(), [*starts[1:].tolist(), len(records)]):
                members = records[start:stop]
                selected[row, members] = groups[sorted_groups[start]].mask(chunk.norms[members])
        accumulator.add(selected, chunk.pixel, chunk.rgb)
        progress.advance(len(chunk.class_id))
    sums = accumulator.sums()
    log.info("extracted %d layers from %d of %d records (%d of %d classes)", len(names), records_read,
             index.record_count, len(wanted), class_count)
    return Extraction(_images(sums, names, index), records_read, len(wanted))


def _automata(expressions: dict[str, str]) -> list[lpe.LayerAutomaton]:
    """One automaton for the layers without covariance conditions, one per layer with.

    A class is matched against every combination of the conditions its events carry, and
    in a shared automaton those are the conditions of all its layers (2**k combinations
    per event): matching each conditional layer on its own keeps k small.
    """
    alone = {name: lpe.compile_layers({name: text}) for name, text in expressions.items()}
    conditional = [automaton for automaton in alone.values() if automaton.has_conditions]
    plain = {name: text for name, text in expressions.items() if not alone[name].has_conditions}
    return ([lpe.compile_layers(plain)] if plain else []) + conditional


def _class_outcomes(automaton: lpe.LayerAutomaton, index: PathIndex):
    """(class id, {layer: outcome}) for every class of the index, from the automaton.

    Classes share their first events, and an index has few distinct events: a class
    whose events carry no condition walks the DFA through a memo of (state, event id)
    transitions; the others go through ``automaton.match``.
    """
    symbols = [automaton.alphabet.classify(event) for event in index.events]
    transitions: dict[tuple[int, int], int] = {}
    dfa = automaton.dfa
    conditional = {event for event, (_, conditions) in enumerate(symbols) if conditions}
    deferred = []
    for path_class in index.classes:
        if conditional and not conditional.isdisjoint(path_class.event_ids):
            deferred.append(path_class)
            continue
        state = dfa.start
        for event in path_class.event_ids:
            key = (state, event)
            if key not in transitions:
                transitions[key] = dfa.step(state, symbols[event][0])
            state = transitions[key]
            if state == DEAD:
                break
        accepted = () if state == DEAD else dfa.accepts[state]
        yield path_class.id, {layer: lpe.ALWAYS for layer in accepted}
    # Conditional classes in event order: each shares the walk along its common prefix
    # with the one before (classes are the leaves and nodes of one prefix tree).
    deferred.sort(key=lambda path_class: tuple(path_class.event_ids))
    walks = [automaton.start_walk()]  # walks[k]: after the first k events of `previous`
    previous: tuple = ()
    for path_class in deferred:
        ids = tuple(path_class.event_ids)
        shared = 0
        while shared < min(len(ids), len(previous)) and ids[shared] == previous[shared]:
            shared += 1
        del walks[shared + 1:]
        for position in range(shared, len(ids)):
            walks.append(automaton.advance(walks[-1], position, symbols[ids[position]]))
        previous = ids
        classified = [symbols[event] for event in ids]
        yield path_class.id, automaton.outcomes(walks[len(ids)], path_class.events, classified)


class _Accumulator:
    """Per-pixel float64 sums of many layers from records that each feed a set of layers.

    Records are grouped by the set of layers they feed (few distinct sets: the standard
    passes partition the records), so one bincount per colour channel serves every layer.
    """

    MAX_SETS = 64  # beyond this many distinct sets in a chunk, one bincount per layer

    def __init__(self, layers: int, pixels: int):
        self.layers, self.pixels = layers, pixels
        self._by_set: dict[bytes, np.ndarray] = {}
        self._per_layer = np.zeros((layers, 3, pixels))

    def add(self, selected: np.ndarray, pixel: np.ndarray, rgb: np.ndarray) -> None:
        """selected (layers, r) bool; pixel (r,); rgb (r, 3)."""
        feeding = selected.any(axis=0)
        if not feeding.any():
            return
        selected, pixel, rgb = selected[:, feeding], pixel[feeding], rgb[feeding]
        if self.layers <= 63:
            bits = (np.left_shift(1, np.arange(self.layers, dtype=np.int64))[:, None] * selected).sum(axis=0)
            _, first, which = np.unique(bits, return_index=True, return_inverse=True)
            sets = selected[:, first]
        if self.layers > 63 or sets.shape[1] > self.MAX_SETS:
            for layer in range(self.layers):
                chosen = selected[layer]
                for channel in range(3):
                    self._per_layer[layer, channel] += np.bincount(pixel[chosen], weights=rgb[chosen, channel],
                                                                   minlength=self.pixels)
            return
        key = which.reshape(-1) * self.pixels + pixel
        size = sets.shape[1] * self.pixels
        channels = [np.bincount(key, weights=rgb[:, c], minlength=size).reshape(sets.shape[1], self.pixels)
                    for c in range(3)]
        for number in range(sets.shape[1]):
            members = sets[:, number]
            image = np.stack([channel[number] for channel in channels])
            signature = members.tobytes()
            if signature in self._by_set:
                self._by_set[signature] += image
            else:
                self._by_set[signature] = image

    def sums(self) -> np.ndarray:
        """(layers, 3, pixels) float64."""
        total = self._per_layer.copy()
        for signature, image in self._by_set.items():
            total[np.frombuffer(signature, bool)] += image
        return total


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
