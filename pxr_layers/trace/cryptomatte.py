"""The coverage Cryptomatte ranks: per pixel, the share of its camera samples whose first
visible hit has each name (a prim path, a material path, a model root).

Each sample's camera ray is the beauty's own (stages.camera_rays with the same frame key,
pixel and sample, so the same jittered film position), and the film's filter is the
beauty's: a box over the pixel, every sample weighing 1/spp. What counts as the first
visible hit is what the beauty's alpha counts (Integrator.trace): the first surface or
light shape the ray reaches and does not pass through. Lights hidden from the camera are
crossed (stages.intersect), and so are cut-outs, with the same presence choice per sample
as the integrator's (stages.surface with the frame key, step and spp), so a pixel's
coverages sum to its alpha exactly (k/spp both).

A light shape seen directly is named by its light's prim path in CryptoObject and
CryptoMaterial (it has no material), and in CryptoAsset, as any object, by the asset root of
that path (``asset_paths``: ``/World`` for Cornell's ``/World/Lights/ceilingLight``). The result is one :class:`Coverage` per type: plain arrays, ranked by
pxr_layers.layers.cryptomatte.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..errors import RenderSettingsError
from ..recipe.model import CRYPTOMATTE_SOURCES
from .integrator import Integrator
from .render import batch_pixels
from .stages.camera import camera_rays
from .stages.intersect import intersect
from .stages.queues import MAX_PASS_THROUGH, T_INFINITY
from .stages.surface import surface

log = logging.getLogger(__name__)

BATCH_PATHS = 1 << 16  # camera rays per batch (whole pixels), as the beauty's batches


@dataclass(frozen=True)
class Coverage:
    """The coverage of one Cryptomatte type over the image.

    names  : the type's names (every object's, material's or model's the frame has)
    pixel  : (k,) int64 pixel index y·w + x, ascending
    name   : (k,) int32 index into names; one entry per (pixel, name) covered
    weight : (k,) float32 the share of the pixel's samples (1/spp each)
    """

    names: tuple[str, ...]
    pixel: np.ndarray
    name: np.ndarray
    weight: np.ndarray


def render_coverage(integrator: Integrator, sources: Iterable[str], *, asset_paths: Sequence[str] | None = None,
                    threads: int | None = None) -> dict[str, Coverage]:
    """The Coverage of each of ``sources`` (CRYPTOMATTE_SOURCES) for the frame `integrator`
    was prepared for, from the beauty's camera samples (integrator.settings.spp per pixel).

    asset_paths : (objects,) CryptoAsset's name of each object, in World.object_paths order
                  (layers.cryptomatte.asset_roots); needed for CryptoAsset only.
    Batches run on `threads` threads (default: one per CPU); the result does not depend on it.
    Raises RenderSettingsError for an unknown source or CryptoAsset without asset_paths.
    """
    wanted = tuple(dict.fromkeys(sources))
    unknown = [source for source in wanted if source not in CRYPTOMATTE_SOURCES]
    if unknown:
        raise RenderSettingsError(f"unknown Cryptomatte source {', '.join(map(repr, unknown))}: known ones are "
                                  f"{', '.join(CRYPTOMATTE_SOURCES)}")
    if not wanted:
        return {}
    subject, tables = _name_tables(integrator, wanted, asset_paths)
    spp = integrator.settings.spp
    pixels = integrator.width * integrator.height
    step = batch_pixels(spp, BATCH_PATHS)
    starts = range(0, pixels, step)

    def run(first: int):
        triangle = _first_visible(integrator, first * spp, min(first + step, pixels) * spp)
        # one histogram of (pixel, subject), then each type's names from those few entries
        pixel, subjects, counts = _pixel_counts(triangle, first, spp, subject, int(subject.max(initial=-1)) + 1)
        return [_regrouped(pixel, table[subjects], counts, len(names)) for names, table in tables.values()]

    workers = min(threads or os.cpu_count() or 1, len(starts))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        batches = list(pool.map(run, starts))
    out = {}
    for slot, (source, (names, _)) in enumerate(tables.items()):
        pieces = [batch[slot] for batch in batches]
        pixel = np.concatenate([piece[0] for piece in pieces])
        name = np.concatenate([piece[1] for piece in pieces])
        counts = np.concatenate([piece[2] for piece in pieces])
        out[source] = Coverage(names, pixel, name, (counts / np.float64(spp)).astype(np.float32))
    log.debug("Cryptomatte coverage %s: %d×%d at %d spp", ", ".join(wanted), integrator.width, integrator.height,
              spp)
    return out


def _name_tables(integrator: Integrator, sources: Sequence[str], asset_paths: Sequence[str] | None
                 ) -> tuple[np.ndarray, dict[str, tuple[tuple[str, ...], np.ndarray]]]:
    """((t,) int32 the subject of each triangle: its distinct (object, material) pair,
    {source → (its names, sorted, (subjects,) int32 the name of each subject)})."""
    world, vocabulary = integrator.world, integrator.vocabulary
    obj = np.asarray(world.triangle_object, np.int64)
    material = np.where(world.triangle_light >= 0, -1, world.triangle_material).astype(np.int64)
    pairs, subject = np.unique(obj * (len(vocabulary.material_paths) + 1) + material + 1, return_inverse=True)
    pair_object = pairs // (len(vocabulary.material_paths) + 1)
    pair_material = pairs % (len(vocabulary.material_paths) + 1) - 1  # −1: a light shape
    tables = {}
    for source in sources:
        if source == "CryptoObject":
            labels = np.asarray(world.object_paths, str)[pair_object]
        elif source == "CryptoMaterial":  # a light shape is named by its light
            labels = np.where(pair_material >= 0, np.asarray(vocabulary.material_paths + ("",), str)[pair_material],
                              np.asarray(world.object_paths, str)[pair_object])
        else:
            if asset_paths is None or len(asset_paths) != len(world.object_paths):
                raise RenderSettingsError("CryptoAsset needs the asset root of every object")
            labels = np.asarray(tuple(asset_paths), str)[pair_object]
        names, name_of_subject = np.unique(labels, return_inverse=True)
        tables[source] = (tuple(str(name) for name in names), name_of_subject.astype(np.int32).reshape(-1))
    return subject.astype(np.int32).reshape(-1), tables


def _first_visible(integrator: Integrator, first_path: int, stop_path: int) -> np.ndarray:
    """(n,) int32 the triangle each camera path [first_path, stop_path) sees first and does
    not pass through (−1: nothing), as Integrator.trace's coverage counts it."""
    settings, geometry = integrator.settings, integrator.geometry
    queue = camera_rays(integrator.camera, integrator.key, (integrator.width, integrator.height), settings.spp,
                        first_path, stop_path)
    seen = np.full(len(queue), -1, np.int32)
    lanes = np.arange(len(queue))
    see_through = integrator.materials.see_through
    for step in range(settings.max_depth + MAX_PASS_THROUGH + 1):  # the integrator's bound on a path's steps
        hits = intersect(integrator.caster, queue, geometry.triangle_light, integrator.hidden_lights,
                         integrator.epsilon)
        if not see_through:  # without see-through materials the first hit is it (−1 for a miss)
            seen[lanes] = hits.triangle
            break
        hit = np.flatnonzero(hits.triangle >= 0)
        queue, hits, lanes = queue.take(hit), hits.take(hit), lanes[hit]
        if not len(queue):
            break
        surfaces = surface(queue, hits, np.take(geometry.triangle_light, hits.triangle) < 0, step, geometry,
                           integrator.materials.arrays, integrator.curvature[:0], settings.max_depth,
                           integrator.key, settings.spp)
        stops = ~surfaces.cut  # lights (not alive) are never cut
        seen[lanes[stops]] = hits.triangle[stops]
        crossing = np.flatnonzero(surfaces.cut)
        queue, lanes = queue.take(crossing), lanes[crossing]
        if not len(queue):
            break
        # straight on from just behind the surface, as stages.scatter sends a cut-out path
        queue.origin = surfaces.position[crossing] - surfaces.facing[crossing] * np.float32(integrator.epsilon)
        queue.t_max = np.full(len(queue), T_INFINITY, np.float32)
    return seen


def _pixel_counts(triangle: np.ndarray, first_pixel: int, spp: int, table: np.ndarray, names: int
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pixel (k,) int64, name (k,) int32, samples (k,) int64) of a batch's covered samples,
    pixels ascending. triangle: (pixels · spp,) as _first_visible gives it; table: (t,) the
    label of each triangle, of ``names`` labels."""
    covered = np.flatnonzero(triangle >= 0)
    keys = (covered // spp) * names + np.take(table, triangle[covered])
    bins = (len(triangle) // spp) * names
    if bins <= 4 * len(triangle):  # a histogram of every (pixel, name): linear, no sort
        histogram = np.bincount(keys, minlength=bins)
        unique = np.flatnonzero(histogram)
        counts = histogram[unique]
    else:  # too many names for one: sort the keys
        unique, counts = np.unique(keys, return_counts=True)
    return first_pixel + unique // names, (unique % names).astype(np.int32), counts


def _regrouped(pixel: np.ndarray, name: np.ndarray, counts: np.ndarray, names: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (pixel, name) entries summed where several subjects share a name (an object of two
    materials in CryptoObject, ...), pixels ascending."""
    keys, inverse = np.unique(pixel * names + name, return_inverse=True)
    return keys // names, (keys % names).astype(np.int32), np.bincount(inverse.reshape(-1), counts).astype(np.int64)
