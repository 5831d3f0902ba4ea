"""The per-vertex covariance chain, light to eye, batched over n paths.

A camera-first path tracer stores the per-vertex data (``VertexParams``) while it
walks and runs this chain from the light end; each next-event connection and each
emitter hit is its own chain.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from . import operators as ops
from .vertex import VertexParams

logger = logging.getLogger(__name__)


def scatter(sigma: np.ndarray, vertex: VertexParams) -> np.ndarray:
    """Σ arriving at a vertex -> Σ arriving at the next one. (n, 4, 4) -> (n, 4, 4).

    The order of COVARIANCE.md ("Per-vertex order"), with one added step (2):

    1. rotate(rotation_in), then projection onto the tangent plane (cos_in);
    2. reverse: angles of ω_i instead of the propagation direction. COVARIANCE.md omits
       it; without it the +K / symmetry pair below is only right when the arriving Σ
       has no space-angle correlation (the first bounce off a distant light), and a flat
       mirror would focus a diverging beam. Equivalently (S C(K) S = C(−K)) the vertex
       is projection → curvature(−K) → texture → cosine → BRDF → curvature(−K) → ...;
    3. curvature(+K), texture, cosine, mirror symmetry, BRDF(b), curvature(−K);
    4. rotate(rotation_out), inverse projection toward ω_o (cos_out), travel(distance).

    "cosine" is the incident cos θ factor of the rendering equation, an angular window
    (``operators.cosine``); it is skipped on perfect-mirror lanes (b = inf on both
    axes), where the mirror BRDF's 1/cos cancels it.

    The curvature operators foreshorten the angle change across the plane of incidence
    (the x, u axes) by cos θ_i: a normal tilted by δ across the plane turns the reflected
    ray by 2·cos θ·δ (in the plane, by 2δ), so a mirror focuses with 2k·cos θ sagittally.
    The source model (COVARIANCE.md) leaves it out, which at 40° incidence on a curved
    mirror is 27 % off the sampled light field (tests/test_covariance_path.py).
    """
    sagittal = np.abs(vertex.cos_in)
    sigma = ops.rotate(sigma, vertex.rotation_in)
    sigma = ops.project(sigma, vertex.cos_in)
    sigma = ops.reverse(sigma)
    sigma = ops.curvature(sigma, vertex.k1, vertex.k2, sign=+1.0, angle=vertex.curvature_angle,
                          sagittal_scale=sagittal)
    sigma = ops.texture(sigma, vertex.texture)
    perfect_mirror = np.isinf(vertex.bandwidth_u) & np.isinf(vertex.bandwidth_v)
    sigma = np.where(np.asarray(perfect_mirror)[..., None, None], sigma, ops.cosine(sigma, vertex.cos_in))
    sigma = ops.mirror(sigma)
    sigma = ops.brdf(sigma, vertex.bandwidth_u, vertex.bandwidth_v)
    sigma = ops.curvature(sigma, vertex.k1, vertex.k2, sign=-1.0, angle=vertex.curvature_angle,
                          sagittal_scale=sagittal)
    sigma = ops.rotate(sigma, vertex.rotation_out)
    sigma = ops.inverse_project(sigma, vertex.cos_out)
    return ops.travel(sigma, vertex.distance)


def chain(emitted: np.ndarray, distance_from_light, vertices: Sequence[VertexParams]) -> np.ndarray:
    """Σ reaching the eye for n paths: travel from the light, then ``scatter`` per vertex.

    emitted : (n, 4, 4) Σ leaving the light (``emitter`` / ``distant_emitter``, in the
    light ray's frame); distance_from_light : (n,) metres to the first vertex;
    vertices : light-to-eye order, each ending with the travel to the next vertex.
    Returns (n, 4, 4) at the end of the last vertex's travel.
    """
    sigma = ops.travel(emitted, distance_from_light)
    for vertex in vertices:
        sigma = scatter(sigma, vertex)
    logger.debug("covariance chain: %d paths, %d vertices", len(sigma), len(vertices))
    return sigma
