"""Where a stack of layers counts energy twice, and where it counts none.

Layers of one stack are summed in the compositor. When two of them claim the same paths
(``C<RD>.*`` and ``C.*<L.'key'>`` both take the diffuse light of the key), their sum
counts that light twice, silently; paths no layer claims are missing from the sum. This
module measures both from the path index, per record: a record belongs to a layer when its
class matches the layer's expression and its own covariance passes the layer's conditions,
decided by the extraction engine itself (``extract.plan_layers`` and ``keyed_chunks``: one
pass over the chunks, on the same threads, no matcher of its own).

Energies are Rec.709 luminance summed over the image, as ``previews.energy_shares`` counts
a layer's share, and are given as shares of the beauty's energy:

* ``pairs[(a, b)]``: the energy both ``a`` and ``b`` claim (pairs claiming nothing in
  common are left out);
* ``double_counted``: what the stack's sum counts more than once, Σ over records of
  (layers claiming it − 1) for the records claimed twice or more: the stack's sum is the
  beauty plus this, less ``remainder``;
* ``remainder``: the energy no layer claims.

The fixes (exclusive versions and a remainder layer, which partition the beauty exactly)
are expressions of the extended LPE syntax: ``lpe.exclusive``, ``lpe.remainder``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np

from ..colour import REC709_LUMINANCE
from ..paths.reader import PathIndex
from .accumulate import distinct
from .extract import default_threads, keyed_chunks, plan_layers
from .previews import image_energy

log = logging.getLogger(__name__)

NEGLIGIBLE_SHARE = 1e-9
"""Shares smaller than this (float64 rounding of sums of the same records) are reported as 0."""


@dataclass(frozen=True)
class Overlaps:
    """pairs : {(a, b): share} for the pairs of layers (a before b in the stack) that claim
    energy in common, shares of the beauty's energy; double_counted, remainder : shares
    (module docstring); claimed : the share some layer claims; beauty_energy : the summed
    luminance the shares are of; seconds : wall time; warnings : unknown labels."""

    pairs: dict[tuple[str, str], float]
    double_counted: float
    remainder: float
    claimed: float
    beauty_energy: float
    seconds: float
    warnings: tuple[str, ...] = ()


def overlaps(index: PathIndex, expressions: dict[str, str], beauty: np.ndarray | None = None, *,
             threads: int | None = None) -> Overlaps:
    """The overlaps of the layers ``expressions`` (name → extended LPE, in stack order).

    beauty : (h, w, 3+) linear image whose energy the shares are of (the render's beauty);
        None: the energy of every record of the index, which then reads every class
        (the index is built so that its records sum to the beauty).
    threads : as ``extract`` (None: ``default_threads()``).
    """
    start = time.perf_counter()
    threads = threads or default_threads()
    plan = plan_layers(index, expressions)
    layers = len(plan.names)
    weights = np.asarray(REC709_LUMINANCE, np.float64)
    spp = index.manifest["spp"]
    pair_sums = np.zeros((layers, layers))  # [a, b]: luminance of the records a and b both claim
    claimed = double = every = 0.0
    for chunk, key, unkeyed in keyed_chunks(index, plan, threads, every_class=beauty is None):
        luminance = chunk.rgb.astype(np.float64) @ weights
        if beauty is None:  # else the beauty's own energy is the total
            every += float(luminance.sum())
        if unkeyed:  # conditional layers past the key's bits (over 60 of them): per record
            members = plan.members(key)
            for row, matching in unkeyed:
                members[matching, row] = True
            energy = luminance
        else:  # per distinct key: a chunk holds few
            keys, which = distinct(key)
            members = plan.members(keys)
            energy = np.bincount(which, weights=luminance, minlength=len(keys))
        counts = members.sum(axis=1)
        claimed += float(energy[counts > 0].sum())
        double += float((energy * np.maximum(counts - 1, 0)).sum())
        shared = members[counts > 1]
        if len(shared):
            pair_sums += (shared.T * energy[counts > 1]) @ shared
    total = image_energy(beauty) if beauty is not None else every / spp
    claimed, double = claimed / spp, double / spp

    def share(value: float) -> float:
        # float64 sums of the same records in another order differ in their last bits: a
        # remainder of -2e-15 is none
        fraction = value / total if total > 0 else 0.0
        return 0.0 if abs(fraction) < NEGLIGIBLE_SHARE else float(fraction)

    pairs = {(plan.names[a], plan.names[b]): share(pair_sums[a, b] / spp)
             for a in range(layers) for b in range(a + 1, layers) if pair_sums[a, b] > 0}
    seconds = time.perf_counter() - start
    log.info("overlaps of %d layers: %d overlapping pairs, %.4g double counted, %.4g unclaimed (%.2f s)", layers,
             len(pairs), share(double), share(total - claimed), seconds)
    return Overlaps(pairs, share(double), share(total - claimed), share(claimed), total, seconds,
                    tuple(plan.warnings))
