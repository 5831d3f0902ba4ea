"""The prefix tree of a path index's classes, compiled: every distinct event sequence (path
class, paths/events.py) is one node, a path carries its class as one node number.

The tracer's recorder extends one trie per batch (``child`` in its kernels); the index
writer merges each batch's trie into its own (``ClassTrie.merge``), so a class's event
sequence is built once, when it first appears.
"""

from __future__ import annotations

import numpy as np

from ..compiled import inline, kernel

_EVENT_BITS = 32  # an edge's key: parent << 32 | event
_HASH = np.uint64(0x9E3779B97F4A7C15)


class ClassTrie:
    """Prefix tree of event ids: every distinct event sequence (path class) is one node.

    Node 0 is the camera (the empty sequence after C). Kernels move paths one event further
    through an open-addressing table of (parent, event) edges (``child``). New nodes are
    numbered in the order lanes first ask for them, so a batch traced the same way numbers
    its classes the same way.
    """

    def __init__(self, capacity: int = 64) -> None:
        self.parent = np.full(capacity, -1, np.int64)
        self.event = np.zeros(capacity, np.int64)
        self.size = 1
        slots = 1 << max(8, int(2 * capacity - 1).bit_length())  # a power of two ≥ 2 × capacity
        self._keys = np.full(slots, -1, np.int64)  # parent << 32 | event, −1 = empty
        self._children = np.zeros(slots, np.int64)

    def __len__(self) -> int:
        return self.size

    def reserve(self, extra: int) -> tuple:
        """Room for `extra` more nodes; the arrays a kernel's ``child`` takes, and size."""
        needed = self.size + extra
        if needed > len(self.parent):
            capacity = max(needed, 2 * len(self.parent))
            self.parent = np.concatenate([self.parent, np.full(capacity - len(self.parent), -1, np.int64)])
            self.event = np.concatenate([self.event, np.zeros(capacity - len(self.event), np.int64)])
        if 2 * needed > len(self._keys):  # load factor at most one half
            capacity = len(self._keys)
            while capacity < 2 * needed:
                capacity *= 2
            self._keys, self._children = _rehashed(self._keys, self._children, capacity)
        return self._keys, self._children, self.parent, self.event, self.size

    def merge(self, parent: np.ndarray, event: np.ndarray) -> np.ndarray:
        """This trie's nodes (m,) int64 for every node of another trie given by its parent and
        event arrays (m,) (parents numbered below children), created as needed."""
        trie = self.reserve(len(parent))
        out = np.empty(len(parent), np.int64)
        self.size = _merge_kernel(*trie, parent, event, out)
        return out

    def sequences(self, nodes: np.ndarray) -> list[tuple[int, ...]]:
        """The event ids from the first event after the camera to each of `nodes`."""
        return class_sequences(self.parent, self.event, nodes)


def class_sequences(parent: np.ndarray, event: np.ndarray, nodes: np.ndarray) -> list[tuple[int, ...]]:
    """The event ids from the first event after the camera to each of `nodes` of the trie
    (parent, event)."""
    return [tuple(e for e in row if e >= 0) for row in class_events(parent, event, nodes).tolist()]


def class_events(parent: np.ndarray, event: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """(n, longest) int64: the event ids after the camera of each of `nodes` of the trie
    (parent, event), first to last, then −1 (:func:`class_sequences` as one array)."""
    upward, current = [], np.asarray(nodes, np.int64)
    while (current > 0).any():  # one level of all chains at a time, from the last event up
        upward.append(np.where(current > 0, event[current], -1))
        current = np.where(current > 0, parent[np.maximum(current, 0)], 0)
    if not upward:
        return np.full((len(current), 0), -1, np.int64)
    last_first = np.stack(upward, axis=1)
    lengths = (last_first >= 0).sum(axis=1)
    position = lengths[:, None] - 1 - np.arange(last_first.shape[1])  # column c holds the (length - 1 - c)-th up
    return np.where(position >= 0, np.take_along_axis(last_first, np.maximum(position, 0), axis=1), -1)


@kernel
def _merge_kernel(keys, children, parent, event, size, other_parent, other_event, out):
    out[0] = 0
    for node in range(1, len(other_parent)):
        out[node], size = child(keys, children, parent, event, size, out[other_parent[node]], other_event[node])
    return size


@inline
def _slot(key, mask):
    """Fibonacci hashing: the high bits of key · 2⁶⁴/φ (44 of them, for tables of any size)."""
    return np.int64((np.uint64(key) * _HASH) >> np.uint64(20)) & mask


def _rehashed(keys: np.ndarray, children: np.ndarray, capacity: int) -> tuple[np.ndarray, np.ndarray]:
    new_keys, new_children = np.full(capacity, -1, np.int64), np.zeros(capacity, np.int64)
    _rehash_kernel(keys, children, new_keys, new_children)
    return new_keys, new_children


@kernel
def _rehash_kernel(keys, children, new_keys, new_children):
    mask = len(new_keys) - 1
    for old in range(len(keys)):
        key = keys[old]
        if key == -1:
            continue
        slot = _slot(key, mask)
        while new_keys[slot] != -1:
            slot = (slot + 1) & mask
        new_keys[slot], new_children[slot] = key, children[old]


@inline
def child(keys, children, parent, event, size, node, event_id):
    """The trie child of `node` by `event_id`, created if new: (child, new size)."""
    key = (node << _EVENT_BITS) | event_id
    mask = len(keys) - 1
    slot = _slot(key, mask)
    while True:
        found = keys[slot]
        if found == key:
            return children[slot], size
        if found == -1:
            keys[slot], children[slot] = key, size
            parent[size], event[size] = node, event_id
            return size, size + 1
        slot = (slot + 1) & mask


