"""Cut layers out of a path index with Light Path Expressions, without rendering again.

The fast path never matches records one by one. The recipe's expressions are compiled
into one automaton; it runs once over each distinct event sequence of the index (its
path classes), which says per layer: never, always, or depending on the covariance
norms of given events. Only the classes some layer can match are read from disk
(chunks of other classes are skipped), covariance conditions are evaluated only on the
records of conditional classes, and every layer is accumulated per pixel in float64 in
the same pass (``accumulate.LayerSums``). Images are divided by spp like the beauty, and
returned as float32.

Threads: the chunks are read, checked and decoded on ``threads`` threads
(``PathIndex.records``: file reads, CRC-32, zstd and numpy's loops release the GIL) while
this thread computes each chunk's layer keys and adds its records, in chunk order. Decoding
is some 90 % of the work of a layer without conditions, so it is what is spread; the sums
stay in one order (chunk, then record), which makes the images byte-identical whatever the
thread count. Memory: the output's float64 sums plus a few chunks per thread in flight.

The matching is ``plan_layers`` (what the automata say of every class) and
``keyed_chunks`` (each decoded record's set of layers, as an int64 key): ``extract`` adds
the records to their layers' images, ``overlaps`` (layers/overlaps.py) sums the energy
that several layers, or none, claim, from the same keys.

``extract_reference`` is the slow, obvious version (every record matched on its own by
the tree-walking reference matcher) that the fast one is tested against.
"""

from __future__ import annotations

import contextlib
import contextvars
import logging
from dataclasses import dataclass

import numpy as np

from .. import lpe
from ..errors import PathIndexError
from ..lpe.automaton import DEAD
from ..lpe.labels import KnownNames, unknown_labels
from ..paths.events import path_text
from ..paths.reader import PathIndex
from ..progress import Progress
from .accumulate import LayerSums, distinct


log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Extraction:
    """layers : name → (h, w, 3) float32 linear images (same scale as the beauty)
    records_read : records of the classes some layer can use (only those are decoded);
    classes_matched : those classes
    warnings : one line per quoted label that names nothing in the index (logged too:
    lpe.labels.unknown_labels), for callers that show them elsewhere (the inspector)
    """

    layers: dict[str, np.ndarray]
    records_read: int
    classes_matched: int
    warnings: tuple[str, ...] = ()


_THREADS: contextvars.ContextVar[int | None] = contextvars.ContextVar("extraction_threads", default=None)


@contextlib.contextmanager
def extraction_threads(threads: int | None):
    """Within it, ``extract`` reads with `threads` threads unless told otherwise (None: all
    cores): how ``pxr-layers extract --threads`` reaches the extractions ``deliver`` runs."""
    token = _THREADS.set(threads)
    try:
        yield
    finally:
        _THREADS.reset(token)


def default_threads() -> int:
    """Threads ``extract`` reads with when not told: ``extraction_threads``'s, else every
    core this process may use."""
    from ..cores import available_cores

    return _THREADS.get() or available_cores()


def extract(index: PathIndex, expressions: dict[str, str], *, show_progress: bool = False,
            threads: int | None = None) -> Extraction:
    """Every layer of `expressions` (name → extended LPE) from `index`, in one pass.

    threads: how many threads read and decode the chunks (None: ``default_threads()``);
    the images are the same, byte for byte, whatever it is (module docstring).

    An index holding NaN or infinite light (from a render that went wrong: ``render`` itself
    refuses to keep one) is refused, naming a path class that carries it: no layer of it
    could be trusted to sum to anything.
    """
    threads = threads or default_threads()
    plan = plan_layers(index, expressions)
    width, height = index.manifest["resolution"]
    accumulator = LayerSums(plan.plain_sets, plan.keyed, width * height)
    progress = Progress(plan.records_read, "extract", enabled=show_progress)
    for chunk, key, unkeyed in keyed_chunks(index, plan, threads):
        for row, matching in unkeyed:
            accumulator.add_to_layer(row, chunk.pixel[matching], chunk.rgb[matching])
        accumulator.add(key, chunk.pixel, chunk.rgb)
        progress.advance(len(chunk.class_id))
    images = dict(zip(plan.names, accumulator.images(height, width, index.manifest["spp"])))
    log.info("extracted %d layers from %d of %d records (%d of %d classes)", len(plan.names), plan.records_read,
             index.record_count, len(plan.wanted), index.class_count)
    return Extraction(images, plan.records_read, len(plan.wanted), tuple(plan.warnings))


@dataclass(frozen=True, eq=False)
class LayerPlan:
    """What the automata say of every class of an index, for the layers ``names``: the plan
    ``keyed_chunks`` follows to give each record the set of layers it feeds.

    always : (layers, classes) bool, the class feeds the layer whatever the covariance
    group_of : (layers, classes) int64, the conditional group of (layer, class), −1 for none
    groups : the groups' outcomes (their ``mask`` says which records of the group match)
    conditional_rows : the layers with a conditional class; the first ``len(keyed)`` are
        bits of the record's key, the others are given apart (``keyed_chunks``)
    plain_sets : (S, layers) bool, the distinct columns of ``always``; class_set : (classes,)
        int64, each class's set id shifted past the keyed bits
    wanted : ids of the classes some layer can match (only those are decoded);
    records_read : their records; warnings : unknown_labels's
    """

    names: list[str]
    always: np.ndarray
    group_of: np.ndarray
    groups: list
    conditional_rows: list[int]
    keyed: list[int]
    plain_sets: np.ndarray
    class_set: np.ndarray
    wanted: np.ndarray
    records_read: int
    warnings: list[str]

    def members(self, key: np.ndarray) -> np.ndarray:
        """(k, layers) bool: the layers records of each key (k,) int64 feed (without the
        unkeyed conditional layers, which ``keyed_chunks`` gives apart)."""
        rows = self.plain_sets[key >> len(self.keyed)].copy()
        for bit, row in enumerate(self.keyed):
            rows[:, row] |= (key >> bit & 1).astype(bool)
        return rows


def plan_layers(index: PathIndex, expressions: dict[str, str]) -> LayerPlan:
    """Match every class of ``index`` against the layers ``expressions`` (name → extended
    LPE) once: the plan of ``extract`` (and ``overlaps``). Refuses an index holding NaN or
    infinite light, and warns of labels that name nothing (``warn_unknown_labels``)."""
    broken = np.flatnonzero(~index.finite_class)
    if len(broken):
        raise PathIndexError(f"{len(broken)} path classes carry NaN or infinite light (the first: "
                             f"{path_text(index.classes[broken[0]].events)}); the render that wrote it went wrong",
                             file=str(index.shown_as))
    automata = _automata(expressions)
    warnings = warn_unknown_labels(automata, index)
    names = list(expressions)
    class_count = index.class_count
    always = np.zeros((len(names), class_count), bool)
    # Conditional classes whose outcomes are the same function of the same atoms share one
    # group: its mask is evaluated once per chunk over all their records.
    group_of = np.full((len(names), class_count), -1, np.int64)
    groups: list[lpe.Outcome] = []
    signatures: dict[tuple, int] = {}
    group_of_outcome: dict[tuple[int, int], int] = {}  # (row, id): classes share outcome objects
    rows = {name: row for row, name in enumerate(names)}
    conditional_outcomes = []
    for automaton in automata:
        accepting, conditional_classes = _class_outcomes(automaton, index)
        for layers, class_ids in accepting.items():
            for layer in layers:
                always[rows[layer], class_ids] = True
        conditional_outcomes.append(conditional_classes)
    for class_id, outcomes in (item for classes in conditional_outcomes for item in classes):
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
    # A record's layers: its class's "always" layers (one of a few distinct sets) plus, per
    # conditional layer, one bit from its covariance. Both go into one int64 key per record;
    # conditional layers past the key's 63 bits are given apart.
    plain_sets, class_set = _distinct_rows(always.T)
    keyed = conditional_rows[:63 - max(1, len(plain_sets)).bit_length()]
    class_set = class_set << len(keyed)
    records_read = int(index.class_records()[wanted].sum())
    return LayerPlan(names, always, group_of, groups, conditional_rows, keyed, plain_sets, class_set, wanted,
                     records_read, warnings)


def keyed_chunks(index: PathIndex, plan: LayerPlan, threads: int, *, every_class: bool = False):
    """Each chunk of the classes ``plan`` wants (every class: all of them), in file order,
    with its records' layers: yields (chunk, key, unkeyed), key (r,) int64 as
    ``LayerSums`` reads it (``plan.members(key)``: the layers), unkeyed [(layer row,
    (m,) ids of the chunk's records that also feed it)] for conditional layers past the key.

    threads: how many threads read and decode the chunks (``PathIndex.records``); the
    chunks and keys are the same whatever it is.
    """
    # Only the runs of wanted classes are decoded (PathIndex.records): a chunk's other
    # records cost their share of its decompression only.
    selected = None if every_class or len(plan.wanted) == index.class_count else plan.wanted.tolist()
    groups, group_of = plan.groups, plan.group_of
    for chunk in index.records(selected, norms=bool(groups), threads=threads):
        key = plan.class_set[chunk.class_id]
        unkeyed = []
        for bit, row in enumerate(plan.conditional_rows):
            # The chunk's records of each group of the layer, from one sort by group.
            chunk_groups = group_of[row, chunk.class_id]
            records = np.flatnonzero(chunk_groups >= 0)
            records = records[np.argsort(chunk_groups[records], kind="stable")]
            sorted_groups = chunk_groups[records]
            starts = np.flatnonzero(np.diff(sorted_groups, prepend=-1))
            norms = np.take(chunk.norms, records, axis=0)  # take: 3x faster than [records] on (r, N, 3)
            sigma = None if chunk.sigma is None else np.take(chunk.sigma, records, axis=0)
            matching = np.concatenate([np.zeros(0, np.int64)] + [
                records[start:stop][groups[sorted_groups[start]].mask(
                    norms[start:stop], None if sigma is None else sigma[start:stop])]
                for start, stop in zip(starts.tolist(), [*starts[1:].tolist(), len(records)])])
            if bit < len(plan.keyed):
                key[matching] |= 1 << bit
            else:
                unkeyed.append((row, matching))
        yield chunk, key, unkeyed


@dataclass(frozen=True)
class ClassMatch:
    """Which path classes of an index an expression takes. always : the ids of the classes
    all of whose records it takes; conditional : of those whose records its covariance
    conditions split (some records in, some out); every other class it never takes."""

    always: frozenset[int]
    conditional: frozenset[int]


def class_matches(index: PathIndex, expressions: dict[str, str]) -> dict[str, ClassMatch]:
    """name → the classes of `index` each expression matches, by the automaton ``extract``
    runs (no record is read). Raises LpeError for an expression that does not compile."""
    always: dict[str, set[int]] = {name: set() for name in expressions}
    conditional: dict[str, set[int]] = {name: set() for name in expressions}
    for automaton in _automata(expressions):
        accepting, conditional_classes = _class_outcomes(automaton, index)
        for layers, class_ids in accepting.items():
            for layer in layers:
                always[layer].update(class_ids.tolist())
        for class_id, outcomes in conditional_classes:
            for layer, outcome in outcomes.items():
                if outcome.kind == "always":
                    always[layer].add(class_id)
                elif outcome.kind == "conditional":
                    conditional[layer].add(class_id)
    return {name: ClassMatch(frozenset(always[name]), frozenset(conditional[name])) for name in expressions}


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
    """What the automaton says of every class of the index.

    Returns ({accepted layers: (k,) ids of the classes whose events carry no condition and
    that those layers match}, an iterator of (class id, {layer: outcome}) for the classes
    whose events carry conditions).
    """
    symbols = [automaton.alphabet.classify(event) for event in index.events]
    conditional = [event for event, (_, conditions) in enumerate(symbols) if conditions]
    events = index.event_matrix(-1)  # (classes, longest): built from arrays, no PathClass needed
    carries = np.isin(events, conditional).any(axis=1) if conditional else np.zeros(len(events), bool)
    deferred = [index.classes[class_id] for class_id in np.flatnonzero(carries).tolist()]
    plain = np.flatnonzero(~carries)
    return _plain_walk(automaton.dfa, [outright for outright, _ in symbols], events[plain], plain), \
        _conditional_walks(automaton, symbols, deferred)


def _plain_walk(dfa, symbols: list[int], events: np.ndarray, ids: np.ndarray) -> dict[frozenset, np.ndarray]:
    """{accepted layers: class ids} for classes without conditions, given as the (k, longest)
    rows of their event ids padded with −1 and their (k,) ids: all walk the DFA together,
    one event position at a time; each distinct (state, event) pair is stepped once (an
    index has few distinct events and the DFA few states)."""
    if not len(ids):
        return {}
    state = np.full(len(ids), dfa.start, np.int64)
    event_count = len(symbols)
    for position in range(events.shape[1]):
        moving = (events[:, position] >= 0) & (state != DEAD)
        if not moving.any():
            break
        pairs, which = distinct(state[moving] * event_count + events[moving, position])
        targets = np.array([dfa.step(pair // event_count, symbols[pair % event_count]) for pair in pairs.tolist()],
                           np.int64)
        state[moving] = targets[which]
    accepting: dict[frozenset, list] = {}
    for final in np.unique(state).tolist():
        if final != DEAD and dfa.accepts[final]:
            accepting.setdefault(dfa.accepts[final], []).append(ids[state == final])
    return {layers: np.concatenate(parts) for layers, parts in accepting.items()}


def _conditional_walks(automaton: lpe.LayerAutomaton, symbols: list, deferred: list):
    """(class id, {layer: outcome}) for classes whose events carry conditions."""
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


def _distinct_rows(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(matrix, axis=0, return_inverse=True)`` for a (n, k) bool matrix, on its
    rows packed into bytes (sorting packed rows is far faster than sorting by columns)."""
    if matrix.shape[1] == 0:  # no columns: every row is the one empty row
        return matrix[:1], np.zeros(len(matrix), np.int64)
    packed = np.ascontiguousarray(np.packbits(matrix, axis=1))
    rows = packed.view(np.dtype((np.void, packed.shape[1]))).reshape(-1)
    _, first, which = np.unique(rows, return_index=True, return_inverse=True)
    return matrix[first], which.reshape(-1).astype(np.int64)


def extract_reference(index: PathIndex, expressions: dict[str, str]) -> dict[str, np.ndarray]:
    """The same layers, matching every record on its own with ``lpe.reference_match``."""
    trees = {name: lpe.parse(expression) for name, expression in expressions.items()}
    width, height = index.manifest["resolution"]
    sums = np.zeros((len(trees), width * height, 3))
    class_events = [path_class.events for path_class in index.classes]
    for chunk in index.records():
        for record in range(len(chunk.class_id)):
            events = class_events[chunk.class_id[record]]
            for layer, tree in enumerate(trees.values()):
                sigma = None if chunk.sigma is None else chunk.sigma[record]
                if lpe.reference_match(tree, events, chunk.norms[record], sigma):
                    sums[layer, chunk.pixel[record]] += chunk.rgb[record]
    return _images(sums, list(trees), index)


def warn_unknown_labels(automata: list[lpe.LayerAutomaton], index: PathIndex) -> list[str]:
    """A label that names nothing in the index is a warning (logged, and returned) naming
    its layers and the closest names of its kind (lpe.labels.unknown_labels): the layer
    would be silently empty, or a negated label exclude nothing."""
    trees = {layer: tree for automaton in automata for layer, tree in automaton.trees.items()}
    return unknown_labels(trees, KnownNames.of_events(index.events), str(index.shown_as))


def _images(sums: np.ndarray, names: list[str], index: PathIndex) -> dict[str, np.ndarray]:
    """name → (h, w, 3) float32 images of (layers, pixels, 3) float64 sums, / spp."""
    width, height = index.manifest["resolution"]
    spp = index.manifest["spp"]
    return {name: (sums[layer] / spp).astype(np.float32).reshape(height, width, 3)
            for layer, name in enumerate(names)}
