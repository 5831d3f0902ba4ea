"""Per-pixel float64 sums of many layers, from records keyed by the set of layers they feed.

Why this shape (measured on a 1920×1080, 64 spp showcase index, 18.8 M merged records,
6.2 M of them in the classes of a new layer ``C<RD>.*<L.'key'>``): an accumulator that ran
one ``bincount`` over (key, pixel) per chunk did O(pixels) work per chunk whatever the
chunk held, and then added whole images per key: 2.0 s of a 2.9 s extraction. Here each
chunk's records are added where they go, ``np.add.at`` on each channel's (layers · pixels,)
float64 sums: O(records), some 7 ns a record and channel, in numpy alone (a compiled loop
was faster, but importing numba costs `pxr-layers extract` a fifth of a second; queueing
the records for one ``bincount`` was as fast, with 300 MB more memory at 1080p).

Each record carries a slot; a slot names the layers its records feed (CSR: ``offsets`` and
``layers``), so a record feeding three layers is added three times and no image per
distinct key is kept: memory is the output's, (layers, pixels, 3) float64 as three channel
arrays, however many distinct layer sets the records fall into.

Determinism: every image is the sum of its records in the order they are given (chunk
order, then record order within a chunk), one addition at a time in float64. The callers
give chunks in file order whatever the number of threads that decoded them, so the images
are byte-identical for any thread count.
"""

from __future__ import annotations

import numpy as np

from ..paths.format import run_rows


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
        self._layers, self._pixels = plain_sets.shape[1], pixels
        self._channels = [np.zeros(self._layers * pixels) for _ in range(3)]  # r, g, b: (layers · pixels,) sums
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
        pixel = np.asarray(pixel, np.int64)
        if len(pixel) and (pixel.min() < 0 or pixel.max() >= self._pixels or not 0 <= layer < self._layers):
            raise AssertionError("records outside the image or their layer sets")
        self._add_at(layer * self._pixels + pixel, rgb)

    def images(self, height: int, width: int, spp: int) -> list[np.ndarray]:
        """Each layer's sums / spp as an (height, width, 3) float32 image (pixels = height ·
        width), rounded once from float64 (no (layers, pixels, 3) copy of the sums)."""
        images = []
        for layer in range(self._layers):
            image = np.empty((height, width, 3), np.float32)
            for channel, sums in enumerate(self._channels):
                np.divide(sums[layer * self._pixels:(layer + 1) * self._pixels].reshape(height, width), spp,
                          out=image[..., channel])
            images.append(image)
        return images

    def _add(self, pixel, rgb, slot, offsets, layers) -> None:
        """Add each record to every layer of its slot (offsets (S + 1,), layers (E,): CSR)."""
        pixels = self._pixels
        pixel, slot = np.asarray(pixel, np.int64), np.asarray(slot, np.int64)
        if len(pixel) and (pixel.min() < 0 or pixel.max() >= pixels or slot.min() < 0
                           or slot.max() >= len(offsets) - 1):
            raise AssertionError("records outside the image or their layer sets")
        counts = np.diff(offsets)
        if (counts <= 1).all():  # the common case: each slot feeds one layer, or none
            layer = np.full(len(counts), -1, np.int64)
            layer[counts == 1] = layers[offsets[:-1][counts == 1]]
            record_layer = np.take(layer, slot)
            if (counts == 0).any() and (record_layer < 0).any():
                keep = record_layer >= 0
                pixel, rgb, record_layer = pixel[keep], rgb[keep], record_layer[keep]
            self._add_at(pixel if not layer.any() else record_layer * pixels + pixel, rgb)
            return
        first, count = np.take(offsets, slot), np.take(counts, slot)
        record = np.repeat(np.arange(len(pixel)), count)
        entry = run_rows(first, count)
        self._add_at(layers[entry] * pixels + pixel[record], rgb[record])

    def _add_at(self, place: np.ndarray, rgb: np.ndarray) -> None:
        """Add rgb (r, 3) to the sums at place (r,) (layer · pixels + pixel), in order."""
        for channel, sums in enumerate(self._channels):
            np.add.at(sums, place, rgb[:, channel].astype(np.float64))  # float64 values: numpy's fast path


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
