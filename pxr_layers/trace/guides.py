"""The denoiser's guides: each pixel's albedo and normal, as Intel Open Image Denoise wants
them (layers/denoise.py).

Every camera sample contributes the albedo and the world-space shading normal of the first
vertex where its path scatters off a lobe that is not singular: a perfect mirror or smooth
glass (and a cut-out) is looked through, to what follows it, as OIDN's documentation asks
of its auxiliary images. The albedo is the reflectance of the non-singular lobes there,
toward the viewer (bsdf.py: the diffuse lobe's weight, the specular and coat lobes' Fresnel
at the view angle; hair.py: the fibre's lobes' tint·A_p), in [0, 1]. A sample that scatters
off no such vertex and meets no emitter contributes 0.
Per pixel, the guides are the mean over its samples: anti-aliased like the beauty, with the
same camera samples.
"""

from __future__ import annotations

import numpy as np

from ..compiled import kernel
from ..paths.events import SCATTER_SINGULAR
from . import bsdf
from .stages.observer import Observer
from .stages.queues import PathQueue, Splats, SurfaceQueue
from .stages.scatter import Scattering

GUIDE_CHANNELS = 6
"""Albedo r, g, b, then normal x, y, z."""


class DenoiseGuides(Observer):
    """Per-pixel sums of the guides over a batch's paths: sums (k, GUIDE_CHANNELS) float64,
    pixels [first_pixel, first_pixel + k); paths [first_path, first_path + paths) of `spp`
    samples a pixel."""

    def __init__(self, first_pixel: int, pixel_count: int, first_path: int, paths: int, spp: int):
        self.first_pixel, self.first_path, self.spp = first_pixel, first_path, spp
        self.sums = np.zeros((pixel_count, GUIDE_CHANNELS))
        self.guided = np.zeros(paths, bool)

    def escaped(self, queue: PathQueue, splats: Splats) -> None:
        self.emitted(queue, splats)

    def emitted(self, queue: PathQueue, splats: Splats) -> None:
        _emitter_guide_kernel(queue.pixel, queue.sample, queue.direction, splats.lane, splats.rgb, self.first_pixel,
                              self.first_path, self.spp, self.guided, self.sums)

    def scattered(self, queue: PathQueue, surfaces: SurfaceQueue, scattering: Scattering, step: int) -> None:
        _guide_kernel(queue.pixel, queue.sample, scattering.scattered, scattering.scatter, surfaces.lobes,
                      surfaces.wo, surfaces.frame, self.first_pixel, self.first_path, self.spp, self.guided, self.sums)


@kernel
def _guide_kernel(pixel, sample, scattered, scatter, lobes, wo, frame, first_pixel, first_path, spp, guided, sums):
    for lane in range(len(pixel)):
        path = pixel[lane] * spp + sample[lane] - first_path
        if guided[path] or not scattered[lane] or scatter[lane] == SCATTER_SINGULAR:
            continue
        guided[path] = True
        r, g, b = bsdf.albedo(lobes[lane], wo[lane, 2])
        where = pixel[lane] - first_pixel
        sums[where, 0] += min(max(r, 0.0), 1.0)
        sums[where, 1] += min(max(g, 0.0), 1.0)
        sums[where, 2] += min(max(b, 0.0), 1.0)
        for axis in range(3):
            sums[where, 3 + axis] += frame[lane, 2, axis]


@kernel
def _emitter_guide_kernel(pixel, sample, direction, lane, rgb, first_pixel, first_path, spp, guided, sums):
    for entry in range(len(lane)):
        path_lane = lane[entry]
        path = pixel[path_lane] * spp + sample[path_lane] - first_path
        brightest = max(rgb[entry, 0], rgb[entry, 1], rgb[entry, 2])
        if guided[path] or not brightest > 0:
            continue
        guided[path] = True
        where = pixel[path_lane] - first_pixel
        for channel in range(3):
            sums[where, channel] += max(rgb[entry, channel], 0.0) / brightest
            sums[where, 3 + channel] -= direction[path_lane, channel]
