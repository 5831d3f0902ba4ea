"""Stage 9: the film of a batch — every contribution summed into its pixel, in order."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...compiled import kernel
from .observer import Observer
from .queues import PathQueue, ShadowQueue, Splats, SurfaceQueue


@dataclass(frozen=True)
class FirstHits:
    """How many camera samples of each pixel first see each surface subject (the tracer's
    (object, material) pairs, EventVocabulary.surface_objects): the samples alpha counts, by
    what they reach. One entry per (pixel, subject) seen, pixels ascending.

    pixel (k,) int64 y·w + x; subject (k,) int32; samples (k,) int64
    """

    pixel: np.ndarray
    subject: np.ndarray
    samples: np.ndarray

    @staticmethod
    def concatenate(parts: list[FirstHits]) -> FirstHits:
        """The FirstHits of disjoint pixel ranges, in pixel order."""
        return FirstHits(*(np.concatenate([getattr(part, name) for part in parts]) if parts else np.zeros(0, dtype)
                           for name, dtype in (("pixel", np.int64), ("subject", np.int32), ("samples", np.int64))))


class BatchFilm(Observer):
    """Pixel sums of the contiguous pixel range [first_pixel, first_pixel + pixel_count).

    rgb (k, 3) float64 sums of contributions (not yet divided by spp); alpha (k,) float64
    count of camera rays that reach geometry they do not pass through (a cut-out or a
    passed-through part of a partly present surface covers nothing). Contributions are added in the order the
    stages make them, so a batch always sums the same way. With ``subjects`` ((t,) the
    surface subject of each triangle, and how many there are), the samples alpha counts are
    counted by subject too (:meth:`first_hits`)."""

    def __init__(self, first_pixel: int, pixel_count: int, subjects: tuple[np.ndarray, int] | None = None):
        self.first_pixel = first_pixel
        self.rgb = np.zeros((pixel_count, 3))
        self.alpha = np.zeros(pixel_count)
        self._subjects = subjects
        self._seen: list[np.ndarray] = []  # per call, (pixel − first_pixel) · subjects + subject

    def escaped(self, queue: PathQueue, splats: Splats) -> None:
        _add_kernel(queue.pixel, splats.lane, splats.rgb, self.first_pixel, self.rgb)

    def emitted(self, queue: PathQueue, splats: Splats) -> None:
        _add_kernel(queue.pixel, splats.lane, splats.rgb, self.first_pixel, self.rgb)

    def lit(self, queue: PathQueue, surfaces: SurfaceQueue, shadows: ShadowQueue) -> None:
        """The contributions of visible light samples, every lobe's."""
        _add_lobes_kernel(queue.pixel, shadows.lane, shadows.radiance, shadows.visible, self.first_pixel, self.rgb)

    def add_coverage(self, queue: PathQueue, hit: np.ndarray, triangle: np.ndarray) -> None:
        """Count the lanes ``hit`` (n,) bool selects: camera rays stopped by ``triangle`` (n,) int32."""
        _coverage_kernel(queue.pixel, hit, self.first_pixel, self.alpha)
        if self._subjects is not None:
            table, count = self._subjects
            lanes = np.flatnonzero(hit)
            self._seen.append((queue.pixel[lanes] - self.first_pixel) * count + np.take(table, triangle[lanes]))

    def first_hits(self) -> FirstHits | None:
        """The samples counted so far, by (pixel, subject); None without ``subjects``."""
        if self._subjects is None:
            return None
        count = self._subjects[1]
        keys = np.concatenate(self._seen) if self._seen else np.zeros(0, np.int64)
        bins = len(self.alpha) * count
        if bins <= 4 * len(keys) + 4096:  # a histogram of every (pixel, subject): linear, no sort
            histogram = np.bincount(keys, minlength=bins)
            unique = np.flatnonzero(histogram)
            samples = histogram[unique]
        else:  # too many subjects for one: sort the keys
            unique, samples = np.unique(keys, return_counts=True)
        return FirstHits(self.first_pixel + unique // count, (unique % count).astype(np.int32), samples.astype(np.int64))


@kernel
def _add_kernel(pixel, lane, rgb, first_pixel, sums):
    for entry in range(len(lane)):
        where = pixel[lane[entry]] - first_pixel
        for channel in range(3):
            sums[where, channel] += rgb[entry, channel]


@kernel
def _add_lobes_kernel(pixel, lane, radiance, visible, first_pixel, sums):
    for entry in range(len(lane)):
        if not visible[entry]:
            continue
        where = pixel[lane[entry]] - first_pixel
        for lobe in range(3):
            for channel in range(3):
                sums[where, channel] += radiance[entry, lobe, channel]


@kernel
def _coverage_kernel(pixel, hit, first_pixel, alpha):
    for lane in range(len(pixel)):
        if hit[lane]:
            alpha[pixel[lane] - first_pixel] += 1.0
