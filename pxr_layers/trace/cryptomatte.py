"""The coverage Cryptomatte ranks: per pixel, the share of its camera samples whose first
visible hit has each name (a prim path, a material path, a model root).

The beauty's own samples are counted while it is traced (TraceSettings.first_hits: the
film counts the samples alpha counts by the surface subject they reach, FirstHits), so
there is no second pass over the camera rays, and the film's filter is the beauty's: a box
over the pixel, every sample weighing 1/spp. What counts as the first visible hit is what
the beauty's alpha counts (Integrator.trace): the first surface or light shape the ray
reaches and does not pass through (hidden lights and cut-outs are crossed), so a pixel's
coverages sum to its alpha exactly (k/spp both).

Here each type names the subjects (:func:`coverage_names`, from the frame's world) and the
counts become its :class:`Coverage` (:func:`coverage`). A light shape seen directly is named
by its light's prim path in CryptoObject and CryptoMaterial (it has no material), and in
CryptoAsset, as any object, by the asset root of that path (``asset_paths``: ``/World`` for
Cornell's ``/World/Lights/ceilingLight``). Plain arrays, ranked by pxr_layers.layers.cryptomatte.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import RenderSettingsError
from ..recipe.model import CRYPTOMATTE_SOURCES
from .integrator import Integrator
from .stages.film import FirstHits


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


@dataclass(frozen=True)
class CoverageNames:
    """How one Cryptomatte type names the tracer's surface subjects.

    names      : the type's names, sorted
    of_subject : (subjects,) int32 the name of each surface subject (EventVocabulary's)
    """

    names: tuple[str, ...]
    of_subject: np.ndarray


def coverage_names(integrator: Integrator, sources: Iterable[str], *, asset_paths: Sequence[str] | None = None
                   ) -> dict[str, CoverageNames]:
    """The CoverageNames of each of ``sources`` (CRYPTOMATTE_SOURCES) for the frame
    ``integrator`` was prepared for.

    asset_paths : (objects,) CryptoAsset's name of each object, in World.object_paths order
                  (layers.cryptomatte.asset_roots); needed for CryptoAsset only.
    Raises RenderSettingsError for an unknown source or CryptoAsset without asset_paths.
    """
    wanted = tuple(dict.fromkeys(sources))
    unknown = [source for source in wanted if source not in CRYPTOMATTE_SOURCES]
    if unknown:
        raise RenderSettingsError(f"unknown Cryptomatte source {', '.join(map(repr, unknown))}: known ones are "
                                  f"{', '.join(CRYPTOMATTE_SOURCES)}")
    world, vocabulary = integrator.world, integrator.vocabulary
    subject_object = np.asarray(vocabulary.surface_objects, np.int64)
    subject_material = np.asarray(vocabulary.surface_materials, np.int64)  # −1: a light shape (World)
    object_paths = np.asarray(world.object_paths, str)
    out = {}
    for source in wanted:
        if source == "CryptoObject":
            labels = object_paths[subject_object]
        elif source == "CryptoMaterial":  # a light shape is named by its light
            material_paths = np.asarray(vocabulary.material_paths + ("",), str)
            labels = np.where(subject_material < 0, object_paths[subject_object],
                              material_paths[np.maximum(subject_material, 0)])
        else:
            if asset_paths is None or len(asset_paths) != len(world.object_paths):
                raise RenderSettingsError("CryptoAsset needs the asset root of every object")
            labels = np.asarray(tuple(asset_paths), str)[subject_object]
        names, of_subject = np.unique(labels, return_inverse=True)
        out[source] = CoverageNames(tuple(str(name) for name in names), of_subject.astype(np.int32).reshape(-1))
    return out


def coverage(names: CoverageNames, hits: FirstHits, spp: int) -> Coverage:
    """One type's Coverage from the frame's FirstHits: the (pixel, subject) counts summed
    where several subjects share a name (an object of two materials in CryptoObject, ...)."""
    count = len(names.names)
    keys, inverse = np.unique(hits.pixel * count + names.of_subject[hits.subject], return_inverse=True)
    samples = np.bincount(inverse.reshape(-1), hits.samples, minlength=len(keys))
    return Coverage(names.names, keys // count, (keys % count).astype(np.int32), (samples / np.float64(spp)).astype(np.float32))
