"""Covariance tracing: the 4×4 frequency covariance Σ of the local light field around a ray.

The path index stores, per bounce, how much curvature (C), texture (T) and reflectance
(R) frequency content the light picked up; these operators compute it. The source model
is Belcour et al. 2013 ("5D Covariance Tracing", TOG 32(3)) without time and aperture,
as summarised in the design notes (shared/design/COVARIANCE.md). Every convention is stated here,
once; the modules refer back to this docstring.

Local light field
-----------------
Around a central ray with unit direction ẑ (the direction light PROPAGATES) and two unit
axes x̂, ŷ perpendicular to it, l(x, y, u, v) is the radiance of the nearby ray that
crosses the plane ⟂ ẑ at x·x̂ + y·ŷ with direction ∝ ẑ + u·x̂ + v·ŷ.

* Coordinates are ordered (x, y, u, v): index 0 = x, 1 = y, 2 = u, 3 = v.
* x, y: spatial offsets in metres. u, v: angular offsets in radians (tilt of the
  propagation direction toward x̂, ŷ; first order, so tilt = slope = angle).
* Travelling a distance d along ẑ maps (x, u) to (x + d·u, u).

Σ: second moments of the AMPLITUDE spectrum
-------------------------------------------
Σ (4×4, symmetric positive semi-definite) is the second-moment matrix of |l̂(ξ)|, the
magnitude of the Fourier transform of l taken as a density:
``Σ = ∫ ξ ξᵀ |l̂(ξ)| dξ / ∫ |l̂(ξ)| dξ``, with ξ = (ξx, ξy, ξu, ξv) in cycles per metre
(spatial) and cycles per radian (angular). Units of Σ: cycles²/m² in the spatial block,
cycles²/rad² in the angular block, cycles²/(m·rad) across.

* A primal Gaussian of covariance V has Σ = V⁻¹ / (4π²).
* The power spectrum |l̂|² of the same Gaussian has half this covariance: thresholds
  written for a power-spectrum Σ must be doubled to be used here.
* The amplitude convention makes multiplication in the primal exact: the spectrum of a
  product is the convolution of the spectra, and second moments of a convolution of
  zero-mean non-negative densities add. Texture, occlusion and windows therefore add
  to Σ (exactly for Gaussians and for the cosine textures of the tests).
* Convolution in the primal (the BRDF's angular blur) multiplies spectra, i.e. adds
  precisions; it is applied in the Woodbury form so a singular Σ is fine.

Geometric events are changes of primal coordinates p_old = A·p_new and act on Σ as the
congruence Σ_new = Aᵀ Σ_old A (always written with full 4×4 matrices).

Frames and signs at a surface vertex
------------------------------------
1. ``rotate(angle)`` expresses Σ in the frame turned by ``angle`` about ẑ: the new axes
   are x̂' = cos·x̂ + sin·ŷ, ŷ' = −sin·x̂ + cos·ŷ. The CALLER picks the angle that puts
   ŷ' in the plane of incidence (``plane_of_incidence_angle``); ``project`` and
   ``inverse_project`` assume it has been done.
2. ``project(cos θi)``: the tangent axes are t̂x = x̂' and t̂y = the tangent direction ŷ'
   projects onto; the surface offset along t̂y is y / |cos θi|.
3. Surface operators (curvature, texture, cosine, BRDF) work in (t̂x, t̂y). The arriving
   field is first re-expressed with the angles of ω_i = −ẑ (``reverse``), the direction
   that points back toward the light, which is the convention the curvature sign and the
   mirror symmetry below assume.
4. Curvature K (2×2, 1/m) is the second fundamental form in (t̂x, t̂y) with the normal on
   the side the light arrives from: the surface is h(s) = ½ sᵀ K s along that normal.
   K positive definite is a bowl facing the light (concave, focusing): a mirror with
   K = k·I focuses a distant source at 1/(2k). ``curvature(+K)`` before the BRDF turns
   angles into angles relative to the local normal, ``curvature(−K)`` after turns them
   back; in between, ``mirror`` (S = diag(1, 1, −1, −1)) is the reflection about the
   local normal and the BRDF blurs the outgoing angles.
5. ``inverse_project(cos θo)`` after rotating (t̂x, t̂y) so that t̂y' is in the plane of
   ω_o: the outgoing frame is x̂o = t̂x', ŷo ⟂ ω_o in that plane on the side of t̂y',
   ẑ = ω_o. Offsets on both sides are measured along the shared tangent axes, so the
   outgoing frame is the mirror image of the incoming one (a flat mirror is then the
   identity on Σ). Rotation angles are always taken in the frame's own axes, so the
   change of handedness never matters; a caller that keeps right-handed frames negates
   x and u (conjugation by diag(−1, 1, −1, 1)) after each reflection.

COVARIANCE.md lists the vertex without step 3 (``reverse``). Without it a flat mirror
would turn a diverging beam into a converging one (the chain would disagree with the
brute-force light field of tests/test_covariance_bruteforce.py by 75 % or more); with
it the doc's order, +K/−K signs and validation numbers all hold. See ``chain.scatter``.

Units of the operator parameters (per-lane arrays (n,) unless noted; scalars broadcast)
------------------------------------------------------------------------------------
* travel distance d: metres (negative travels backwards).
* rotation angle: radians, about the ray (or the normal), sense as in 1. above.
* cos θ (project, inverse_project, cosine): cosine between the ray and the surface
  normal, sign ignored; ``eps`` clamps grazing angles.
* principal curvatures k1, k2: 1/m; ``angle``: radians from t̂x to the first principal
  direction. ``sign`` is +1 before the BRDF, −1 after.
* BRDF bandwidths b_u, b_v: the lobe's amplitude-spectrum variance in cycles²/rad², in
  the tangent frame (a lobe of angular std w has b = 1/(4π²w²)). b = 0 is diffuse
  (angular content killed), b = inf a perfect mirror (Σ unchanged).
* texture block T, occlusion block O: (n, 2, 2) cycles²/m² in the tangent frame.
* emitter extent s: metres (std of a Gaussian emitter); distant emitter: radians.
* lens focal length: metres (inf = no lens). Sensor pixel size: metres per pixel.

Norms stored in the path index (amplitude convention, see ``operators``):
R = √λmax(B) in cycles/rad, T = √λmax(T) in cycles/m, C = max|k_i| in 1/m, and
optionally the 10 unique entries of Σ (``pack_upper``).
"""

from .chain import chain, scatter
from .operators import (
    DIRECTIONAL_LIGHT_EXTENT,
    GRAZING_COS_EPS,
    PACKED_ENTRY_NAMES,
    POINT_LIGHT_EXTENT,
    SIGMA_DTYPE,
    beckmann_bandwidth,
    brdf,
    cosine,
    curvature,
    curvature_matrix,
    curvature_norm,
    distant_emitter,
    emitter,
    ggx_bandwidth,
    inverse_project,
    lens,
    mirror,
    occlusion,
    occlusion_block,
    pack_upper,
    phong_bandwidth,
    plane_of_incidence_angle,
    project,
    reflectance_norm,
    reverse,
    rotate,
    sensor,
    texture,
    texture_from_patch,
    texture_norm,
    texture_to_tangent,
    travel,
    unpack_upper,
)
from .vertex import VertexParams

__all__ = [
    "DIRECTIONAL_LIGHT_EXTENT",
    "GRAZING_COS_EPS",
    "PACKED_ENTRY_NAMES",
    "POINT_LIGHT_EXTENT",
    "SIGMA_DTYPE",
    "VertexParams",
    "beckmann_bandwidth",
    "brdf",
    "chain",
    "cosine",
    "curvature",
    "curvature_matrix",
    "curvature_norm",
    "distant_emitter",
    "emitter",
    "ggx_bandwidth",
    "inverse_project",
    "lens",
    "mirror",
    "occlusion",
    "occlusion_block",
    "pack_upper",
    "phong_bandwidth",
    "plane_of_incidence_angle",
    "project",
    "reflectance_norm",
    "reverse",
    "rotate",
    "scatter",
    "sensor",
    "texture",
    "texture_from_patch",
    "texture_norm",
    "texture_to_tangent",
    "travel",
    "unpack_upper",
]
