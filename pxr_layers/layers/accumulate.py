"""Per-pixel float64 sums of many layers, from records keyed by the set of layers they feed.

Why this shape (measured on a 1920×1080, 64 spp showcase index, 17.6 M merged records,
6.2 M of them in the classes of a new layer ``C<RD>.*<L.'key'>``): the earlier accumulator
ran one ``bincount`` over (key, pixel) per chunk, i.e. O(pixels) work per chunk whatever
the chunk held, and then added whole images per key: 2.0 s of the 2.9 s extraction, where
decoding the chunks took 0.45 s. Here each record is added where it goes, by one compiled
loop (``_add_records``): about 2 ns a record, O(records), not O(chunks × pixels).

Each record carries a slot; a slot names the layers its records feed (CSR: ``offsets`` and
``layers``), so a record feeding three layers is added to three images and no image per
distinct key is kept: memory is the output's, (layers, pixels, 3) float64, however many
distinct layer sets the records fall into.

Determinism: every image is the sum of its records in the order they are given (chunk
order, then record order within a chunk), one addition at a time in float64. The callers
give chunks in file order whatever the number of threads that decoded them, so the images
are byte-identical for any thread count. (The sum runs on the consumer's thread while the
reading threads decode the next chunks: at 2 ns a record against some 25 ns to read,
check and decode one, it is not what limits the speed; splitting it among threads by pixel
ranges would keep it deterministic too, should it ever be.)
"""

from __future__ import annotations

import numpy as np

from ..compiled import kernel


@kernel
def _add_records(pixel, rgb, slot, offsets, layers, sums):
    """Add each record's rgb to the pixel of every layer of its slot.

    pixel (r,) int64, rgb (r, 3) float32, slot (r,) int64 into offsets;
    offsets (S + 1,) int64 and layers (E,) int64: slot s feeds layers[offsets[s]:offsets[s + 1]];
    sums (L, P, 3) float64, added to in place. Returns the records whose pixel or slot is
    out of range (skipped: the kernel checks no bounds, and a caller's mistake must not
    write outside `sums`); 0 from every caller that is right.
    """
    pixels = sums.shape[1]
    slots = offsets.shape[0] - 1
    skipped = 0
    for record in range(pixel.shape[0]):
        at = pixel[record]
        group = slot[record]
        if at < 0 or at >= pixels or group < 0 or group >= slots:
            skipped += 1
            continue
        red = np.float64(rgb[record, 0])
        green = np.float64(rgb[record, 1])
        blue = np.float64(rgb[record, 2])
        for entry in range(offsets[group], offsets[group + 1]):
            layer = layers[entry]
            sums[layer, at, 0] += red
            sums[layer, at, 1] += green
            sums[layer, at, 2] += blue
    return skipped


class LayerSums:
    """(layers, pixels, 3) float64 sums, added to one chunk of records at a time.

    ``plain_sets`` (S, layers) bool: the layers a class always feeds, as one of S distinct
    sets; a record's key is its set id << C | C bits, bit j meaning that the record also
    feeds ``conditional_rows[j]`` (its covariance passed that layer's conditions).
    """

    MAX_SETS = 64
    """Beyond this many distinct keys in a chunk (many conditional layers: keys can then be
    nearly one per record), records are selected layer by layer from their key's bits
    instead of through a table of every distinct key's layers."""
    MAX_REMEMBERED = 4096
    """Distinct keys whose layers are remembered between chunks (bounds that table)."""

    def __init__(self, plain_sets: np.ndarray, conditional_rows: list[int], pixels: int):
        self.plain_sets, self.conditional_rows = plain_sets, conditional_rows
        self.sums = np.zeros((plain_sets.shape[1], pixels, 3))
        self._members: dict[int, np.ndarray] = {}  # key → (k,) int64 layer rows
        # Keys without conditional bits are the plain set ids: their CSR, built once.
        self._plain_offsets, self._plain_layers = _csr([np.flatnonzero(row) for row in plain_sets])

    def members(self, key: int) -> np.ndarray:
        """(k,) int64: the layers records of ``key`` feed."""
        found = self._members.get(key)
        if found is None:
            if len(self._members) >= self.MAX_REMEMBERED:
                self._members.clear()
            rows = self.plain_sets[key >> len(self.conditional_rows)].copy()
            for bit, row in enumerate(self.conditional_rows):
                rows[row] |= bool(key >> bit & 1)
            found = self._members[key] = np.flatnonzero(rows)
        return found

    def add(self, key: np.ndarray, pixel: np.ndarray, rgb: np.ndarray) -> None:
        """key (r,) int64 (class docstring); pixel (r,) int64; rgb (r, 3) float32."""
        if not self.conditional_rows:  # the key is the plain set id
            self._add(pixel, rgb, key, self._plain_offsets, self._plain_layers)
            return
        keys, which = distinct(key)
        if len(keys) <= self.MAX_SETS:
            offsets, layers = _csr([self.members(value) for value in keys.tolist()])
            self._add(pixel, rgb, which, offsets, layers)
            return
        plain = self.plain_sets[key >> len(self.conditional_rows)]  # (r, layers)
        for bit, row in enumerate(self.conditional_rows):
            plain[:, row] |= (key >> bit & 1).astype(bool)
        for layer in np.flatnonzero(plain.any(axis=0)).tolist():
            chosen = plain[:, layer]
            self.add_to_layer(layer, pixel[chosen], rgb[chosen])

    def add_to_layer(self, layer: int, pixel: np.ndarray, rgb: np.ndarray) -> None:
        """Records (pixel (r,), rgb (r, 3)) that feed ``layer``, whatever their key says."""
        self._add(pixel, rgb, np.zeros(len(pixel), np.int64), np.array([0, 1], np.int64),
                  np.array([layer], np.int64))

    def _add(self, pixel, rgb, slot, offsets, layers) -> None:
        skipped = _add_records(np.ascontiguousarray(pixel, np.int64), np.ascontiguousarray(rgb, np.float32),
                               np.ascontiguousarray(slot, np.int64), offsets, layers, self.sums)
        if skipped:
            raise AssertionError(f"{skipped} records outside the image or their layer sets")


def _csr(members: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(offsets (S + 1,), layers (E,)) int64 of S lists of layer rows."""
    offsets = np.zeros(len(members) + 1, np.int64)
    offsets[1:] = np.cumsum([len(rows) for rows in members])
    layers = np.concatenate([np.zeros(0, np.int64), *members]).astype(np.int64)
    return offsets, layers


def distinct(key: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sorted distinct values, index of each value among them), as ``np.unique`` with
    ``return_inverse``; by counting instead of sorting when the values are small."""
    top = int(key.max(initial=0))
    if top >= 1 << 20 or key.min(initial=0) < 0:
        keys, which = np.unique(key, return_inverse=True)
        return keys, which.reshape(-1)
    present = np.bincount(key, minlength=top + 1) > 0
    number = np.cumsum(present) - 1
    return np.flatnonzero(present), number[key]
