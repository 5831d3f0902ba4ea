"""Many named expressions → one automaton over whole events.

1. Thompson's construction turns each layer's tree into an NFA fragment whose edges are
   labelled by event patterns ("guards"); one start state joins all layers, and each
   layer's end state is marked with its name.
2. The DFA reads one symbol per event. A symbol is the bit mask of the guards the event
   satisfies, so the DFA never needs label names: a label that matches no quoted label
   of the recipe sets no bit (the "any other label" edge), and a guard with a covariance
   condition is satisfied only under an assumption on that condition (see ``match``).
3. Subset construction builds DFA states as sets of NFA states. When the event alphabet
   is small enough to enumerate (every type × scattering × subset of the recipe's labels ×
   truth of its conditions), the complete DFA is built and minimised (Moore's partition
   refinement); a state lists the layers it accepts.

Why not always build it complete: an event may carry any subset of the labels the recipe
names, and the DFA must tell every subset apart when each one feeds different layers. A
per-light split over n light groups has 2**n such subsets. Past the budget below, states are
built on demand from the path classes actually met (the technique of RE2's lazy DFA), which
stays linear in the index's size and gives the same answers.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field

import numpy as np

from ..errors import LpeError
from ..paths.events import ALL_SCATTERINGS, EVENT_TYPES
from . import conditions as cond
from . import nodes
from .events import Event, PatternTable
from .labels import KnownNames, unknown_labels
from .limits import MAX_DFA_STATES, MAX_NFA_STATES
from .outcomes import (
    ALWAYS,
    NEVER,
    Conditional,
    Outcome,
    check_available,
    checked_arrays,
    reduce_table,
)

log = logging.getLogger(__name__)

DEAD = -1
"""The state after a mismatch: nothing can match any more."""

MAX_ENUMERATED_EVENTS = 8192
"""Most events (type × scattering × label subset × truths of the conditions tested on it)
enumerated to build the complete DFA; past this the DFA is built on demand."""

MAX_COMPLETE_WORK = 50_000
"""Most steps taken to build the complete DFA: one per symbol looked at in each DFA state,
and one per NFA state visited in each (DFA state, symbol) pair explored. Past this the DFA
is built on demand; it keeps the complete build, its minimisation (which takes a few steps
per state and symbol) and ``pxr-layers lpe check`` well under a second."""

MAX_ATOMS_PER_CLASS = 16
"""Most (condition, event) pairs a path class's truth table may depend on (it has 2**atoms
rows); past this the class's records run through the DFA one event at a time instead
(:class:`PerRecord`)."""


# --- NFA -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Subtracted:
    """The NFA state ending the subtracted part of layer ``layer``'s set difference."""

    layer: str


@dataclass
class Nfa:
    """Thompson NFA over events.

    guards : distinct event patterns labelling the edges
    edges : per state, (guard index, target state) pairs
    epsilon : per state, targets reached without reading an event
    accepting : per state, the layer it ends (a name; ``Subtracted(name)`` for the end of
        what a set difference ``A - B`` takes away from layer ``name``), or None
    """

    guards: list[nodes.EventPattern]
    edges: list[list[tuple[int, int]]]
    epsilon: list[list[int]]
    accepting: list[str | Subtracted | None]
    start: int
    _closures: dict[int, frozenset[int]] = field(default_factory=dict, repr=False)

    @property
    def state_count(self) -> int:
        return len(self.edges)

    def layers_ended(self, nfa_set) -> frozenset[str]:
        """The layers a DFA state made of these NFA states accepts: those whose expression
        ends here, less those of a set difference whose subtracted part ends here too."""
        ended = {self.accepting[state] for state in nfa_set if self.accepting[state] is not None}
        return frozenset(layer for layer in ended if isinstance(layer, str) and Subtracted(layer) not in ended)

    def closure(self, states) -> frozenset[int]:
        """The states reachable through epsilon edges (including the given ones) that read an
        event or end a layer: the others (epsilon-only states) can neither step nor accept,
        so DFA states that differ only by them are the same state, and are built once."""
        return frozenset().union(*(self._closure_of(state) for state in states))

    def _closure_of(self, state: int) -> frozenset[int]:
        # Computed once per state and only for states reached (the subset construction asks
        # for the same closures over and over; precomputing them all is quadratic in memory
        # for long chains of optional copies).
        found = self._closures.get(state)
        if found is not None:
            return found
        seen = {state}
        stack = [state]
        while stack:
            for target in self.epsilon[stack.pop()]:
                if target not in seen:
                    seen.add(target)
                    stack.append(target)
        found = self._closures[state] = frozenset(
            reached for reached in seen if self.edges[reached] or self.accepting[reached] is not None
        )
        return found


def nfa_state_count(node: nodes.Node, known: dict | None = None) -> int:
    """The number of states :class:`_NfaBuilder` makes for a tree, without building them.

    2 per event, 1 per sequence, 2 per alternation and per repetition, and a repetition
    ``{m,n}`` holds n copies of what it repeats (``{m,}``: m + 1, the last one looping).
    known : id(node) → (node, count) of nodes counted already (the node is kept so that its
        id is not reused); callers that count a tree as it grows pass the same dict.
    """
    if known is None:
        known = {}
    found = known.get(id(node))
    if found is not None:
        return found[1]
    if isinstance(node, nodes.EventPattern):
        count = 2
    elif isinstance(node, nodes.Difference):
        count = nfa_state_count(node.positive, known) + nfa_state_count(node.negative, known)
    elif isinstance(node, nodes.Concat):
        count = 1 + sum(nfa_state_count(item, known) for item in node.items)
    elif isinstance(node, nodes.Union):
        count = 2 + sum(nfa_state_count(alternative, known) for alternative in node.alternatives)
    elif isinstance(node, nodes.Repeat):
        copies = node.minimum + 1 if node.maximum is None else node.maximum
        count = 2 + copies * nfa_state_count(node.body, known)
    else:
        raise TypeError(f"not an expression node: {node!r}")
    known[id(node)] = (node, count)
    return count


class _NfaBuilder:
    def __init__(self):
        self.edges: list[list[tuple[int, int]]] = []
        self.epsilon: list[list[int]] = []
        self.accepting: list[str | None] = []
        self.guard_index: dict[nodes.EventPattern, int] = {}

    def state(self) -> int:
        self.edges.append([])
        self.epsilon.append([])
        self.accepting.append(None)
        return len(self.edges) - 1

    def fragment(self, node: nodes.Node) -> tuple[int, int]:
        """Thompson fragment of a tree: (entry state, exit state)."""
        if isinstance(node, nodes.EventPattern):
            entry, exit_ = self.state(), self.state()
            guard = self.guard_index.setdefault(node, len(self.guard_index))
            self.edges[entry].append((guard, exit_))
            return entry, exit_
        if isinstance(node, nodes.Concat):
            entry = current = self.state()
            for item in node.items:
                item_entry, item_exit = self.fragment(item)
                self.epsilon[current].append(item_entry)
                current = item_exit
            return entry, current
        if isinstance(node, nodes.Union):
            entry, exit_ = self.state(), self.state()
            for alternative in node.alternatives:
                alternative_entry, alternative_exit = self.fragment(alternative)
                self.epsilon[entry].append(alternative_entry)
                self.epsilon[alternative_exit].append(exit_)
            return entry, exit_
        if isinstance(node, nodes.Repeat):
            return self._repeat(node)
        raise TypeError(f"not an expression node: {node!r}")

    def _repeat(self, node: nodes.Repeat) -> tuple[int, int]:
        entry = current = self.state()
        for _ in range(node.minimum):  # the required copies, in sequence
            copy_entry, copy_exit = self.fragment(node.body)
            self.epsilon[current].append(copy_entry)
            current = copy_exit
        if node.maximum is None:  # then a Kleene loop
            loop = self.state()
            self.epsilon[current].append(loop)
            body_entry, body_exit = self.fragment(node.body)
            self.epsilon[loop].append(body_entry)
            self.epsilon[body_exit].append(loop)
            return entry, loop
        exit_ = self.state()  # or up to (maximum - minimum) optional copies
        for _ in range(node.maximum - node.minimum):
            self.epsilon[current].append(exit_)
            copy_entry, copy_exit = self.fragment(node.body)
            self.epsilon[current].append(copy_entry)
            current = copy_exit
        self.epsilon[current].append(exit_)
        return entry, exit_


def build_nfa(layers: dict[str, nodes.Node]) -> Nfa:
    """One NFA for every layer: a shared start state, one accepting state per layer."""
    builder = _NfaBuilder()
    start = builder.state()
    for name, tree in layers.items():
        # A set difference A - B runs both parts side by side from the start; a DFA state
        # then knows whether each ended (Nfa.layers_ended), for each record's own covariance.
        parts = [(tree.positive, name), (tree.negative, Subtracted(name))] if isinstance(tree, nodes.Difference) \
            else [(tree, name)]
        for part, ends in parts:
            entry, exit_ = builder.fragment(part)
            builder.epsilon[start].append(entry)
            builder.accepting[exit_] = ends
    guards = sorted(builder.guard_index, key=builder.guard_index.get)
    return Nfa(guards, builder.edges, builder.epsilon, builder.accepting, start)


# --- the event alphabet ----------------------------------------------------------------


class Alphabet:
    """Turns events into DFA symbols: the bit mask of the guards an event satisfies.

    Guards with a condition are satisfied only if the condition holds on the event's
    covariance, which a path class does not know: :meth:`classify` returns the bits that
    hold outright and, apart, the (bit, condition) pairs that hold if their condition does.
    The three slots are tested apart (one mask per type, per scattering, per set of carried
    patterns) and the masks and-ed: that keeps enumerating every symbol cheap.
    """

    def __init__(self, guards: list[nodes.EventPattern]):
        self.patterns = PatternTable(
            pattern for guard in guards for term in guard.labels for pattern in term.patterns
        )
        self.conditions: list[cond.Condition] = list(
            dict.fromkeys(guard.condition for guard in guards if guard.condition is not None)
        )
        condition_index = {condition: i for i, condition in enumerate(self.conditions)}
        self._label_terms = [
            tuple((self.patterns.mask_of(term.patterns), term.negated) for term in guard.labels) for guard in guards
        ]
        self._condition_of_bit = {
            bit: condition_index[guard.condition] for bit, guard in enumerate(guards) if guard.condition is not None
        }
        self._conditioned = sum(1 << bit for bit in self._condition_of_bit)
        self._type_masks = {
            event_type: _guard_mask(guards, lambda guard, t=event_type: guard.types is None or t in guard.types)
            for event_type in EVENT_TYPES
        }
        self._scatter_masks = {
            scatter: _guard_mask(guards, lambda guard, s=scatter: guard.scatters is None or s in guard.scatters)
            for scatter in ALL_SCATTERINGS
        }
        self._label_masks: dict[int, int] = {}
        self._cache: dict[Event, tuple[int, tuple[tuple[int, int], ...]]] = {}

    def label_mask(self, carried: int) -> int:
        """Guards whose label terms all hold for an event carrying the patterns ``carried``."""
        mask = self._label_masks.get(carried)
        if mask is None:
            mask = 0
            for bit, terms in enumerate(self._label_terms):
                if all(bool(carried & pattern_mask) != negated for pattern_mask, negated in terms):
                    mask |= 1 << bit
            self._label_masks[carried] = mask
        return mask

    def classify(self, event: Event) -> tuple[int, tuple[tuple[int, int], ...]]:
        """(bits of guards satisfied outright, ((bit, condition index), ...) satisfied if the condition holds)."""
        found = self._cache.get(event)
        if found is None:
            satisfied = (
                self._type_masks[event.type]
                & self._scatter_masks[event.scatter]
                & self.label_mask(self.patterns.carried(event.labels))
            )
            found = self._cache[event] = self._split(satisfied)
        return found

    def _split(self, satisfied: int) -> tuple[int, tuple[tuple[int, int], ...]]:
        conditioned = satisfied & self._conditioned
        conditional = tuple(
            (1 << bit, condition) for bit, condition in self._condition_of_bit.items() if conditioned >> bit & 1
        )
        return satisfied & ~self._conditioned, conditional

    @staticmethod
    def symbol(outright: int, conditional, holding) -> int:
        """The symbol of an event when exactly the conditions in ``holding`` hold."""
        symbol = outright
        for bit, condition in conditional:
            if condition in holding:
                symbol |= bit
        return symbol

    def every_symbol(self, limit: int = MAX_ENUMERATED_EVENTS) -> list[int] | None:
        """Every symbol any event can produce, or None if that means enumerating more than ``limit``.

        The events enumerated are every type × scattering × subset of the recipe's labels ×
        truth of the conditions that event is tested on (slot masks deduplicated first).
        """
        if 2 ** len(self.patterns) > limit:
            return None
        slot_masks = {
            self._type_masks[event_type] & self._scatter_masks[scatter]
            for event_type, scatter in itertools.product(EVENT_TYPES, ALL_SCATTERINGS)
        }
        label_masks = self._every_label_mask()
        symbols = set()
        enumerated = 0
        for slots, labels in itertools.product(slot_masks, label_masks):
            outright, conditional = self._split(slots & labels)
            involved = sorted({condition for _, condition in conditional})
            enumerated += 2 ** len(involved)
            if enumerated > limit:
                return None
            for holding in _subsets(involved):
                symbols.add(self.symbol(outright, conditional, holding))
        return sorted(symbols)

    def _every_label_mask(self) -> set[int]:
        """:meth:`label_mask` of every subset of the patterns (at most 2**13 of them), in
        numpy: guards × subsets tests in Python would take seconds for a long expression."""
        carried = np.arange(2 ** len(self.patterns), dtype=np.int64)
        holds = np.ones((carried.size, max(len(self._label_terms), 1)), dtype=bool)
        for bit, terms in enumerate(self._label_terms):
            for pattern_mask, negated in terms:
                holds[:, bit] &= ((carried & pattern_mask) != 0) != negated
        rows = np.unique(np.packbits(holds, axis=1, bitorder="little"), axis=0)
        return {int.from_bytes(row.tobytes(), "little") & ((1 << len(self._label_terms)) - 1) for row in rows}


def _guard_mask(guards, accepts) -> int:
    return sum(1 << bit for bit, guard in enumerate(guards) if accepts(guard))


def _subsets(items):
    return itertools.chain.from_iterable(itertools.combinations(items, size) for size in range(len(items) + 1))


# --- DFA -------------------------------------------------------------------------------


class Dfa:
    """Deterministic automaton over event symbols; ``accepts[state]`` lists the layers it ends.

    A state only looks at the guards on the NFA edges leaving it (``relevant[state]``, a
    guard mask): its transitions are keyed by the symbol and-ed with that mask, so the many
    symbols a state cannot tell apart share one entry.

    Built on demand from the NFA (``complete`` False: a missing transition is computed when
    first needed), or complete and minimised (``complete`` True: a missing transition leads
    to DEAD).
    """

    def __init__(self, nfa: Nfa):
        self.nfa = nfa
        self.complete = False
        self.accepts: list[frozenset[str]] = []
        self.relevant: list[int] = []
        self.transitions: list[dict[int, int]] = []
        self._nfa_sets: list[frozenset[int]] = []
        self._ids: dict[frozenset[int], int] = {}
        self.start = self._state(nfa.closure([nfa.start]))

    @classmethod
    def from_tables(
        cls, nfa: Nfa, start: int, accepts: list, relevant: list[int], transitions: list[dict[int, int]]
    ) -> Dfa:
        """A complete DFA given by its tables (a missing transition leads to DEAD)."""
        dfa = cls.__new__(cls)
        dfa.nfa, dfa.complete, dfa.start = nfa, True, start
        dfa.accepts, dfa.relevant, dfa.transitions = accepts, relevant, transitions
        dfa._nfa_sets, dfa._ids = [], {}
        return dfa

    @property
    def state_count(self) -> int:
        return len(self.accepts)

    @property
    def transition_count(self) -> int:
        """Arrows of the state diagram: distinct (source, target) pairs, DEAD left out.

        Each arrow stands for every symbol that takes that step ("any other symbol" edges
        are one arrow, not one per symbol).
        """
        return sum(len({target for target in row.values() if target != DEAD}) for row in self.transitions)

    def _state(self, nfa_set: frozenset[int]) -> int:
        if not nfa_set:
            return DEAD
        found = self._ids.get(nfa_set)
        if found is not None:
            return found
        if len(self._nfa_sets) >= MAX_DFA_STATES:
            raise LpeError(self._too_many_states())
        self._ids[nfa_set] = len(self._nfa_sets)
        self._nfa_sets.append(nfa_set)
        self.transitions.append({})
        self.accepts.append(self.nfa.layers_ended(nfa_set))
        self.relevant.append(sum({1 << guard for s in nfa_set for guard, _ in self.nfa.edges[s]}))
        return len(self._nfa_sets) - 1

    def _too_many_states(self) -> str:
        layers = list(dict.fromkeys(layer for layer in self.nfa.accepting if isinstance(layer, str)))
        which = f"layer {layers[0]!r}" if len(layers) == 1 else f"these {len(layers)} layers"
        return (
            f"the automaton of {which} needs more than {MAX_DFA_STATES} states (MAX_DFA_STATES, see "
            "docs/lpe.md) for the paths matched: a repetition after a loop, as in .*R.{12}, makes it "
            "remember every one of the last events; anchor such expressions or repeat fewer times"
        )

    def step(self, state: int, symbol: int) -> int:
        if state == DEAD:
            return DEAD
        key = symbol & self.relevant[state]
        row = self.transitions[state]
        target = row.get(key)
        if target is None:
            if self.complete:
                return DEAD
            target = row[key] = self._successor(state, key)
        return target

    def _successor(self, state: int, symbol: int) -> int:
        reached = [
            target
            for nfa_state in self._nfa_sets[state]
            for guard, target in self.nfa.edges[nfa_state]
            if symbol >> guard & 1
        ]
        return self._state(self.nfa.closure(reached))

    def expand(self, symbols: list[int], max_work: int = MAX_COMPLETE_WORK) -> bool:
        """Build every state reachable on ``symbols``; False if that takes more than ``max_work``
        steps (see MAX_COMPLETE_WORK) or builds more than MAX_DFA_STATES states."""
        work = 0
        frontier = [self.start]
        visited = {self.start}
        while frontier:
            state = frontier.pop()
            work += len(symbols)
            for key in {symbol & self.relevant[state] for symbol in symbols}:
                work += 1 + len(self._nfa_sets[state])
                if work > max_work or self.state_count >= MAX_DFA_STATES:
                    return False
                target = self.step(state, key)
                if target != DEAD and target not in visited:
                    visited.add(target)
                    frontier.append(target)
        return True

    def minimised(self, symbols: list[int]) -> Dfa:
        """Moore's partition refinement over a fully expanded DFA; a complete, minimal copy.

        States are first split by the layers they accept, then by the blocks their
        successors fall in, until no block splits. DEAD takes part as a state of its own,
        so states from which no layer can be reached merge into it and vanish. Symbols that
        every state treats alike are refined as one.
        """
        count = self.state_count
        dead = count  # DEAD's row in the tables below
        representatives = _distinguishable_symbols(symbols, set(self.relevant))
        columns = {tuple(self._row_target(state, symbol, dead) for state in range(count)) for symbol in representatives}
        successors = np.array([*zip(*columns), [dead] * len(columns)], dtype=np.int64).reshape(count + 1, len(columns))
        block = np.array(_renumber([*self.accepts, frozenset()]), dtype=np.int64)
        while True:
            refined = _refined_blocks(block, successors)
            if refined.max() == block.max():  # blocks are numbered 0..k-1: no block split
                break
            block = refined
        block = block.tolist()

        dead_block = block[dead]
        representative: dict[int, int] = {}  # block → its first state
        for state, b in enumerate(block[:count]):
            if b != dead_block:
                representative.setdefault(b, state)
        live_blocks = list(representative)
        new_id = {b: i for i, b in enumerate(live_blocks)}
        new_id[dead_block] = DEAD
        transitions = []
        for b in live_blocks:
            # Equivalent states step alike: the representative's row speaks for its block.
            merged = {key: DEAD if target == DEAD else new_id[block[target]]
                      for key, target in self.transitions[representative[b]].items()}
            transitions.append({key: target for key, target in merged.items() if target != DEAD})
        return Dfa.from_tables(
            self.nfa,
            new_id[block[self.start]],
            [self.accepts[representative[b]] for b in live_blocks],
            [self.relevant[representative[b]] for b in live_blocks],
            transitions,
        )

    def _row_target(self, state: int, symbol: int, dead: int) -> int:
        target = self.transitions[state][symbol & self.relevant[state]]
        return dead if target == DEAD else target


def _distinguishable_symbols(symbols: list[int], masks: set[int]) -> list[int]:
    """One symbol per class of symbols that every state sees alike (equal under each state's
    relevant-guard mask); states sharing a mask are handled once."""
    classes = [symbols]
    for mask in masks:
        refined = []
        for members in classes:
            groups: dict[int, list[int]] = {}
            for symbol in members:
                groups.setdefault(symbol & mask, []).append(symbol)
            refined.extend(groups.values())
        classes = refined
    return [members[0] for members in classes]


def _refined_blocks(block: np.ndarray, successors: np.ndarray) -> np.ndarray:
    """One round of Moore's refinement: states stay together when their block and the blocks
    of all their successors agree.

    block : (n,) int64 block of each state, numbered 0..k-1; successors : (n, columns) int64
    returns : (n,) int64 blocks numbered 0..k'-1
    """
    # The signature (block, successor blocks...) is folded into one int64 column by column,
    # renumbering after each: key < n and block < n, so key * n + block < n**2 never overflows.
    key = block
    for column in successors.T:
        key = np.unique(key * len(block) + block[column], return_inverse=True)[1].reshape(-1)
    return key


def _renumber(keys) -> list[int]:
    """Number equal keys alike, in order of first appearance."""
    numbers: dict = {}
    return [numbers.setdefault(key, len(numbers)) for key in keys]


# --- the layer automaton ---------------------------------------------------------------


class LayerAutomaton:
    """One automaton for every layer of a recipe.

    layers : the layer names, in the recipe's order
    trees, canonical : each layer's expression tree and canonical text
    state_count, transition_count : size of the DFA (minimal when ``complete``)
    complete : True when the whole DFA was built and minimised at compile time; False when
        its states are built on demand as path classes are matched (large label sets, or a
        subset construction past its budget)
    on_demand_reason : why it is built on demand (None when complete)
    """

    def __init__(self, trees: dict[str, nodes.Node], *, build_complete: bool = True):
        """trees : layer name → expression tree. ``build_complete=False`` skips building
        the complete minimal DFA (states are then always built on demand)."""
        self.layers: tuple[str, ...] = tuple(trees)
        self.trees = dict(trees)
        for name, tree in self.trees.items():  # parsed trees are checked already, built ones not
            size = nfa_state_count(tree)
            if size > MAX_NFA_STATES:
                raise LpeError(f"layer {name!r}: the expression's automaton would have {size} states, more "
                               f"than the {MAX_NFA_STATES} an expression may have (MAX_NFA_STATES, see docs/lpe.md)")
        self.canonical = {name: nodes.canonical(tree) for name, tree in trees.items()}
        self.nfa = build_nfa(self.trees)
        self.alphabet = Alphabet(self.nfa.guards)
        self.dfa, self.on_demand_reason = self._build_dfa(build_complete)
        # Conditional walks are interned: path classes end in few distinct walks, so each
        # step and each end is worked out once (keys hold the ids of interned walks).
        self._walks: dict[tuple, tuple] = {}
        self._steps: dict[tuple, tuple | None] = {}
        self._ends: dict[int, dict[str, Outcome]] = {}

    def _build_dfa(self, build_complete: bool) -> tuple[Dfa, str | None]:
        """The complete minimal DFA and None, or one built on demand and why."""
        symbols = self.alphabet.every_symbol() if build_complete else None
        if not build_complete:
            reason = "asked for"
        elif symbols is None:
            reason = (f"{len(self.alphabet.patterns)} labels and {len(self.alphabet.conditions)} conditions: "
                      f"more than {MAX_ENUMERATED_EVENTS} kinds of events to enumerate")
        else:
            complete = Dfa(self.nfa)
            if complete.expand(symbols):
                return complete.minimised(symbols), None
            reason = f"building it complete takes more than {MAX_COMPLETE_WORK} steps or {MAX_DFA_STATES} states"
        log.debug("LPE automaton for %d layers is built on demand: %s", len(self.layers), reason)
        return Dfa(self.nfa), reason  # a fresh one: its size then tells what matching has needed

    @property
    def complete(self) -> bool:
        return self.dfa.complete

    @property
    def state_count(self) -> int:
        return self.dfa.state_count

    @property
    def transition_count(self) -> int:
        return self.dfa.transition_count

    @property
    def has_conditions(self) -> bool:
        return bool(self.alphabet.conditions)

    def accepting_layers(self, events) -> frozenset[str]:
        """Layers a path matches, for expressions without conditions (else use :meth:`match`)."""
        if self.has_conditions:
            raise LpeError("these expressions have covariance conditions: use match() and the outcomes' masks")
        state = self.dfa.start
        for event in events:
            if state == DEAD:
                break
            state = self.dfa.step(state, self.alphabet.classify(event)[0])
        return frozenset() if state == DEAD else self.dfa.accepts[state]

    def match(self, events) -> dict[str, Outcome]:
        """Match one path class; per layer, its outcome.

        events : the class's event sequence, camera first: :class:`Event`, or any hashable
            objects with ``type``, ``scatter`` and ``labels`` (such as the path index's events)

        Conditions are unknown here. The automaton runs on every combination of the
        conditions that decide a step: an "atom" (event index, condition) is added only
        when, at that event, some current state goes to different states depending on
        that condition. The frontier maps each state to the rows of a truth table over
        the atoms (row ``sum(atom_j << j)``) that lead to it; each layer's final rows say
        never, always, or which records match (:class:`Conditional`, with ``mask``).
        """
        events = tuple(events)
        classified = [self.alphabet.classify(event) for event in events]
        if not any(conditional for _, conditional in classified):
            return self._match_unconditionally(classified)
        walk = self.start_walk()
        for index, symbol in enumerate(classified):
            walk = self.advance(walk, index, symbol)
        return self.outcomes(walk, events, classified)

    def start_walk(self) -> tuple | None:
        """The state of a conditional walk before any event: (atoms, frontier)."""
        return self._interned((), {self.dfa.start: np.ones(1, dtype=bool)})

    def _interned(self, atoms: tuple, frontier: dict[int, np.ndarray]) -> tuple:
        key = (atoms, tuple(sorted((state, rows.tobytes()) for state, rows in frontier.items())))
        walk = self._walks.get(key)
        if walk is None:
            walk = self._walks[key] = (atoms, frontier)
        return walk

    def advance(self, walk: tuple | None, index: int, symbol) -> tuple | None:
        """The walk after event ``index`` (its ``Alphabet.classify`` result); None once the
        class depends on more than MAX_ATOMS_PER_CLASS atoms. Walks are not modified, so
        classes that share a prefix can share the walk up to it (see layers/extract.py)."""
        if walk is None:
            return None
        key = (id(walk), index, symbol)
        if key not in self._steps:
            self._steps[key] = self._advance(walk, index, symbol)
        return self._steps[key]

    def _advance(self, walk: tuple, index: int, symbol) -> tuple | None:
        atoms, frontier = walk
        if not frontier:
            return walk
        outright, conditional = symbol
        involved = sorted({condition for _, condition in conditional})
        options = [frozenset(holding) for holding in _subsets(involved)]
        targets = {
            state: {holding: self.dfa.step(state, self.alphabet.symbol(outright, conditional, holding))
                    for holding in options}
            for state in frontier
        }
        deciding = [
            condition for condition in involved
            if any(row[holding] != row[holding ^ {condition}] for row in targets.values() for holding in options)
        ]
        if len(atoms) + len(deciding) > MAX_ATOMS_PER_CLASS:
            return None  # long paths under `.*` with conditions: a table per class would be too big
        for condition in deciding:
            atoms = (*atoms, (index, condition))
            # A new atom is the highest bit: every existing row splits into two equal halves.
            frontier = {state: np.concatenate([rows, rows]) for state, rows in frontier.items()}
        codes = np.arange(2 ** len(atoms))
        following: dict[int, np.ndarray] = {}
        for holding in map(frozenset, _subsets(deciding)):
            # Conditions that decide nothing at this event are taken as false: same targets.
            selected = np.ones(codes.size, dtype=bool)
            for condition in deciding:
                holds = (codes >> atoms.index((index, condition))) & 1 == 1
                selected &= holds if condition in holding else ~holds
            for state, rows in frontier.items():
                target = targets[state][holding]
                reached = rows & selected
                if target == DEAD or not reached.any():
                    continue
                following[target] = following[target] | reached if target in following else reached
        return self._interned(atoms, following)

    def outcomes(self, walk: tuple | None, events: tuple, classified) -> dict[str, Outcome]:
        """Each layer's outcome at the end of a walk over ``events``.

        Classes that end in the same walk get the same outcome objects; their ``events``
        (for error messages) are those of the first such class.
        """
        if walk is None:
            return {layer: PerRecord(self, layer, events, tuple(classified)) for layer in self.layers}
        found = self._ends.get(id(walk))
        if found is None:
            found = self._ends[id(walk)] = self._outcomes(walk, events)
        return dict(found)

    def _outcomes(self, walk: tuple, events: tuple) -> dict[str, Outcome]:
        atoms, frontier = walk
        outcomes = {}
        for layer in self.layers:
            table = np.zeros(2 ** len(atoms), dtype=bool)
            for state, rows in frontier.items():
                if layer in self.dfa.accepts[state]:
                    table |= rows
            outcomes[layer] = self._outcome(layer, table, list(atoms), events)
        return outcomes

    def _match_unconditionally(self, classified) -> dict[str, Outcome]:
        state = self.dfa.start
        for outright, _ in classified:
            state = self.dfa.step(state, outright)
            if state == DEAD:
                break
        accepted = frozenset() if state == DEAD else self.dfa.accepts[state]
        return {layer: ALWAYS if layer in accepted else NEVER for layer in self.layers}

    def _outcome(self, layer: str, table: np.ndarray, atoms, events) -> Outcome:
        if not table.any():
            return NEVER
        if table.all():
            return ALWAYS
        named = [(index, self.alphabet.conditions[condition]) for index, condition in atoms]
        kept, reduced = reduce_table(named, table)
        return Conditional(tuple(kept), reduced, layer, events)

    def unknown_labels(self, known_labels) -> list[str]:
        """Warnings for quoted labels that match none of ``known_labels`` (bare labels, of no
        known kind; logged too): :func:`pxr_layers.lpe.labels.unknown_labels`."""
        return unknown_labels(self.trees, KnownNames.of_labels(known_labels))


@dataclass(frozen=True, eq=False)
class PerRecord(Outcome):
    """The outcome of a path class with too many atoms for a truth table: its records run
    through the DFA together, one event at a time, each taking the transition its own
    covariance selects. Linear in records × events; same answers as :class:`Conditional`.
    """

    automaton: LayerAutomaton
    layer: str
    events: tuple
    classified: tuple  # per event: Alphabet.classify's (outright bits, conditional bits)

    kind = "conditional"

    @property
    def bounces(self) -> tuple[int, ...]:
        return tuple(index for index, (_, conditional) in enumerate(self.classified) if conditional)

    def __repr__(self) -> str:
        return f"<conditional per record on events {', '.join(map(str, self.bounces))}>"

    def mask(self, norms: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        norms, sigma = checked_arrays(norms, sigma)
        dfa, alphabet = self.automaton.dfa, self.automaton.alphabet
        state = np.full(len(norms), dfa.start, np.int64)
        for index, (outright, conditional) in enumerate(self.classified):
            involved = sorted({condition for _, condition in conditional})
            live = np.unique(state[state != DEAD]).tolist()
            if not live:
                break
            options = [frozenset(holding) for holding in _subsets(involved)]
            code = np.zeros(len(norms), np.int64)
            if involved and any(len({dfa.step(s, alphabet.symbol(outright, conditional, h)) for h in options}) > 1
                                for s in live):
                for bit, condition in enumerate(involved):
                    check_available(self.layer, self.events, index, alphabet.conditions[condition],
                                    norms.shape[1], sigma is not None)
                    row = index - 1
                    values = cond.evaluate(alphabet.conditions[condition], norms[:, row],
                                           None if sigma is None else sigma[:, row])
                    code |= values.astype(np.int64) << bit
            # One transition per distinct (state, conditions holding) pair of the records.
            width = len(involved)
            holding_of = {sum(1 << involved.index(c) for c in holding): holding for holding in options}
            unique, inverse = np.unique((state + 1) << width | code, return_inverse=True)
            targets = np.array([
                dfa.step((pair >> width) - 1, alphabet.symbol(outright, conditional, holding_of[pair & ((1 << width) - 1)]))
                for pair in unique.tolist()
            ], np.int64)
            state = targets[inverse.reshape(-1)]
        final, inverse = np.unique(state, return_inverse=True)
        accepting = np.array([s != DEAD and self.layer in dfa.accepts[s] for s in final.tolist()], bool)
        return accepting[inverse.reshape(-1)]
