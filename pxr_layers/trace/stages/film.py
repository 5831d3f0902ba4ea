"""Stage 9: the film of a batch — every contribution summed into its pixel, in order."""

from __future__ import annotations

import numpy as np

from ...compiled import kernel
from .observer import Observer
from .queues import PathQueue, ShadowQueue, Splats, SurfaceQueue


class BatchFilm(Observer):
    """Pixel sums of the contiguous pixel range [first_pixel, first_pixel + pixel_count).

    rgb (k, 3) float64 sums of contributions (not yet divided by spp); alpha (k,) float64
    count of camera rays that reach geometry they do not pass through (a cut-out or a
    passed-through part of a partly present surface covers nothing). Contributions are added in the order the
    stages make them, so a batch always sums the same way."""

    def __init__(self, first_pixel: int, pixel_count: int):
        self.first_pixel = first_pixel
        self.rgb = np.zeros((pixel_count, 3))
        self.alpha = np.zeros(pixel_count)

    def escaped(self, queue: PathQueue, splats: Splats) -> None:
        _add_kernel(queue.pixel, splats.lane, splats.rgb, self.first_pixel, self.rgb)

    def emitted(self, queue: PathQueue, splats: Splats) -> None:
        _add_kernel(queue.pixel, splats.lane, splats.rgb, self.first_pixel, self.rgb)

    def lit(self, queue: PathQueue, surfaces: SurfaceQueue, shadows: ShadowQueue) -> None:
        """The contributions of visible light samples, every lobe's."""
        _add_lobes_kernel(queue.pixel, shadows.lane, shadows.radiance, shadows.visible, self.first_pixel, self.rgb)

    def add_coverage(self, queue: PathQueue, hit: np.ndarray) -> None:
        _coverage_kernel(queue.pixel, hit, self.first_pixel, self.alpha)


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
