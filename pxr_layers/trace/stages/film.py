"""Stage 9: the film of a batch — every contribution summed into its pixel, in order — and
the indirect clamp that every contribution passes before any observer sees it, so that the
film and the path index hold the same light."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...compiled import kernel
from .observer import Observer
from .queues import PathQueue, ShadowQueue, Splats, SurfaceQueue

FIRST_INDIRECT_VERTEX = 1
"""A path's scattering vertices are numbered from 0, its first visible hit. Light that
reaches it at vertex 0 (sampled there, or found by the ray scattered there: the two halves of
one MIS estimate) is direct, as is an emitter seen from the camera; from vertex 1 on it is
indirect (Cycles' sample_clamp_indirect draws the same line)."""


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


def clamp_splats(queue: PathQueue, splats: Splats, limit: float) -> None:
    """Clamp `splats` (escaped or emission, ``queue``'s lanes) in place with :func:`_clamp_kernel`.
    Their light reaches the path at its last scattering vertex, number depth − 1 (−1: the
    camera). A `limit` of 0 clamps nothing."""
    if limit > 0:
        _clamp_kernel(splats.rgb[:, None, :], splats.lane, queue.depth, 1, limit)


def clamp_lit(queue: PathQueue, shadows: ShadowQueue, limit: float) -> None:
    """Clamp each lobe's radiance of the light samples `shadows` in place (after their shadow
    rays: what the film would add). Their light reaches the path at its shading point, vertex
    number depth. A `limit` of 0 clamps nothing."""
    if limit > 0:
        _clamp_kernel(shadows.radiance, shadows.lane, queue.depth, 0, limit)


@kernel
def _clamp_kernel(rgb, lane, depth, vertex_offset, limit):
    """rgb (n, k, 3) float32: k contributions of path lane[i] (depth (lanes,) int32), whose
    light reaches it at vertex depth − vertex_offset. Where that vertex is indirect
    (FIRST_INDIRECT_VERTEX on) and a contribution's largest channel is above `limit`, all
    three channels are scaled by limit / largest: the hue is kept and no channel exceeds
    `limit` (up to float32 rounding)."""
    for entry in range(len(lane)):
        if depth[lane[entry]] - vertex_offset < FIRST_INDIRECT_VERTEX:
            continue
        for item in range(rgb.shape[1]):
            largest = max(rgb[entry, item, 0], rgb[entry, item, 1], rgb[entry, item, 2])
            if largest > limit:
                scale = limit / largest
                for channel in range(3):
                    rgb[entry, item, channel] *= scale


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
