"""World-space geometry of a light path -> the covariance chain, batched over n lanes.

The tracer knows each vertex in world space (directions, shading normal, curvature,
texture gradients, lobe width); ``chain.scatter`` wants per-vertex ``VertexParams`` whose
angles are measured in ray frames that continue from one vertex to the next. This
module builds those frames and parameters and runs the chain from the light to the eye.
All conventions (local light field, amplitude spectrum, vertex order and signs) are
those of the package docstring; this docstring only adds what the world-space glue
decides.

Vectors are (3, n) component-major float arrays (as in ``pxr_layers.trace``), per-lane
scalars (n,), Σ (n, 4, 4); everything is computed in float64.

Ray frames
----------
Every ray segment carries a frame (x̂, ŷ, ẑ) with ẑ the direction light propagates
(from the light toward the eye). Σ of that segment is expressed in it.

* Frames handed IN and OUT of this module are right-handed: ŷ = ẑ × x̂, so the x̂ axis
  alone (3, n) describes the frame. ``light_frame`` gives a deterministic x̂ for a ray
  when nothing else fixes one (isotropic emitters).
* Inside the chain the frames are the operators' own (package docstring, "Frames and
  signs" 1-5): after each reflection the outgoing frame is the mirror image of the
  incoming one. The module carries that handedness h = ±1 per lane
  (ŷ = h·ẑ × x̂), so the parameters are exactly those ``chain.chain`` expects and the
  chain needs no extra step: the ``params`` of ``PathCovariance.steps`` run through
  ``chain.chain`` reproduce ``at_eye`` up to the final handedness flip below.
* Results are converted back to right-handed frames: where h = −1 the x̂ axis is
  negated and Σ conjugated by diag(−1, 1, −1, 1) (x and u change sign together, which
  commutes with travel). The frame of each returned Σ is therefore fully given by its
  x̂ and the propagation direction ẑ = ``toward_eye`` of the vertex.

At a vertex (ω_i = ``toward_light``, ω_o = ``toward_eye``, n = shading normal):

1. arriving frame (x̂, ŷ, ẑ = −ω_i); ``rotation_in`` = ``plane_of_incidence_angle`` of
   (n·x̂, n·ŷ): x̂' ⟂ the plane of incidence, ŷ' in it with n·ŷ' ≥ 0.
2. tangent axes: t̂x = x̂', t̂y = |cos θi|·ŷ' + (ŷ'·n_i)·ẑ with n_i the normal turned
   toward the light (n_i·ω_i ≥ 0). t̂y is where the ray offset ŷ' lands on the tangent
   plane when slid along ẑ (the meaning ``project`` gives it); unlike normalising the
   tangential part of ŷ' it stays defined at grazing incidence (t̂y = ±ẑ there).
3. curvature: the renderer's k (> 0 where the surface bends away from ``normal``,
   ``trace/curvature.py``) becomes K = −sign(ω_i·n)·k (positive = bowl facing the light);
   ``curvature_angle`` = atan2(d₁·t̂y, d₁·t̂x) for the principal direction d₁.
4. texture: J = ∂(s, t)/∂(t̂x, t̂y) = [[∇s·t̂x, ∇s·t̂y], [∇t·t̂x, ∇t·t̂y]],
   T = Jᵀ T_uv J (``texture_to_tangent``).
5. ``rotation_out`` = ``plane_of_incidence_angle`` of (ω_o·t̂x, ω_o·t̂y);
   x̂o = cos·t̂x + sin·t̂y, and the operators' ŷo = |cos θo|·t̂y' − (t̂y'·ω_o)·n_o
   (n_o: normal turned toward ω_o), the unit vector ⟂ ω_o in the plane of ω_o and n on
   the side of t̂y'. (x̂o, ŷo, ω_o) has the handedness of the arriving frame when ω_o
   leaves on the other side of n than ω_i arrived from (transmission) and the opposite
   one when both are on the same side (reflection).

Degenerate geometry picks a frame instead of failing: at normal incidence the plane of
incidence is undefined and ``plane_of_incidence_angle`` returns 0 (keep x̂); at exact
grazing incidence t̂y = ±ẑ; ``inverse_project`` clamps grazing exits (GRAZING_COS_EPS);
zero-length normals, principal directions or gradients never divide by zero.

Approximations
--------------
* Transmission (``transmit``): the operators have no refraction. The interface is taken
  as flat (K = 0: index-matched, no focusing power) and the angles pass unchanged
  (``reverse`` and ``mirror`` of ``scatter`` cancel when K = 0): the footprint is
  projected with cos θi and inverse-projected with cos θo of the actual directions
  (so a real refraction still compresses or widens the beam along the plane of
  incidence, by cos θo / cos θi), the texture and the BSDF lobe (b = inf for smooth glass) apply as for a
  reflection. Angular magnification by the index ratio (and the power of a curved
  interface) is ignored. A straight pass (ω_o = −ω_i) through any such interface is the
  identity, at every incidence: a zero-distance pass-through vertex can pad paths of
  different lengths.
* Curved mirrors at oblique incidence: ``chain.scatter`` foreshortens the sagittal angle
  change by |cos θi| (a mirror focuses with 2k·cos θ across the plane of incidence, 2k in
  it), so nothing here corrects for it. Against a sampled 4D light field
  (tests/test_covariance_path.py, ``brute_force_error``) two curved mirrors at 40° and 45°
  agree to 0.02 % of ‖Σ‖ (27 % before that fix, commit 5e34cf6), as do the curved mirrors
  at 6°/8° and the flat ones at 40°/45° (0.03 %, 0.02 %).
* Emitters: see ``area_light_covariance``, ``distant_light_covariance``,
  ``dome_covariance``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from . import operators as ops
from .chain import scatter
from .vertex import VertexParams

_FLOAT = np.float64
_TINY = 1e-300
# diag(−1, 1, −1, 1) as a sign pattern on Σ entries: x and u change sign together.
_HANDEDNESS_FLIP = np.outer([-1.0, 1.0, -1.0, 1.0], [-1.0, 1.0, -1.0, 1.0])
# A carried x̂ this close to parallel to the new ray is replaced by light_frame.
_PARALLEL_TOLERANCE = 1e-6


@dataclass(frozen=True)
class SurfaceVertex:
    """World-space data of one scattering vertex for n lanes (float32 or float64).

    toward_light : (3, n) unit ω_i, from the vertex toward its light-side neighbour.
    toward_eye : (3, n) unit ω_o, toward the eye-side neighbour (previous vertex or camera).
    distance_to_eye : (n,) metres to the eye-side neighbour.
    normal : (3, n) shading normal as interpolated, either side (normalised here).
    k1, k2 : (n,) principal curvatures, 1/m; k > 0 where the surface bends AWAY from
        ``normal`` (``trace/curvature.py``: a sphere with outward normals has k = +1/r).
    principal_direction : (3, n) world tangent of k1 (projected on the tangent plane here).
    texture_uv : (n, 2, 2) or (2, 2) texture T block, cycles² per texture unit²
        (``texture_from_patch`` with texel sizes in texture units); zeros if untextured.
    gradient_s, gradient_t : (3, n) world gradients of the texture coordinates, 1/m.
    bandwidth : (n,) isotropic lobe bandwidth b, cycles²/rad² (0 diffuse, inf perfect
        mirror or smooth refraction).
    transmit : (n,) bool, the path crosses the surface here (see the module docstring).

    ``SurfaceVertex.flat`` builds an untextured, flat vertex with defaults.
    """

    toward_light: np.ndarray
    toward_eye: np.ndarray
    distance_to_eye: np.ndarray
    normal: np.ndarray
    k1: np.ndarray
    k2: np.ndarray
    principal_direction: np.ndarray
    texture_uv: np.ndarray
    gradient_s: np.ndarray
    gradient_t: np.ndarray
    bandwidth: np.ndarray
    transmit: np.ndarray

    @classmethod
    def flat(cls, toward_light, toward_eye, distance_to_eye, normal, bandwidth=np.inf, transmit=False, **fields):
        """A vertex with no curvature and no texture unless given in ``fields``."""
        toward_light = np.asarray(toward_light)
        n = toward_light.shape[1]
        zero_vector = np.zeros((3, n))
        defaults = {
            "k1": np.zeros(n),
            "k2": np.zeros(n),
            "principal_direction": zero_vector,
            "texture_uv": np.zeros((2, 2)),
            "gradient_s": zero_vector,
            "gradient_t": zero_vector,
        }
        defaults.update(fields)
        return cls(
            toward_light=toward_light,
            toward_eye=np.asarray(toward_eye),
            distance_to_eye=np.broadcast_to(np.asarray(distance_to_eye, dtype=_FLOAT), (n,)),
            normal=np.asarray(normal),
            bandwidth=np.broadcast_to(np.asarray(bandwidth, dtype=_FLOAT), (n,)),
            transmit=np.broadcast_to(np.asarray(transmit, dtype=bool), (n,)),
            **defaults,
        )


@dataclass(frozen=True)
class VertexStep:
    """The chain parameters of one vertex and the frame the light leaves it in.

    params : VertexParams for ``chain.scatter`` (``distance`` = distance_to_eye).
    x_axis : (3, n) x̂ of the leaving frame, RIGHT-HANDED (ŷ = ω_o × x̂).
    handedness : (n,) +1 where the operators' leaving frame is right-handed, −1 where it
        is the mirror image (Σ out of ``scatter`` must then be conjugated by
        diag(−1, 1, −1, 1) to be expressed in the right-handed frame of ``x_axis``).
    """

    params: VertexParams
    x_axis: np.ndarray
    handedness: np.ndarray


@dataclass(frozen=True)
class PathCovariance:
    """Σ along a path, light to eye, n lanes.

    leaving : per vertex (light-to-eye order), Σ (n, 4, 4) LEAVING the vertex toward the
        eye: after the inverse projection, before the travel to the eye-side neighbour.
    leaving_x_axis : per vertex, (3, n) x̂ of that Σ's right-handed frame, ẑ = toward_eye.
    at_eye : Σ (n, 4, 4) ARRIVING at the eye end (after the last vertex's travel).
    at_eye_x_axis : (3, n) x̂ of at_eye's right-handed frame: leaving_x_axis[-1], or with
        no vertex at all (the eye sees the light) the emitted frame's x̂.
    steps : the per-vertex ``VertexStep`` (parameters, frames, handedness).
    """

    leaving: tuple[np.ndarray, ...]
    leaving_x_axis: tuple[np.ndarray, ...]
    at_eye: np.ndarray
    at_eye_x_axis: np.ndarray
    steps: tuple[VertexStep, ...]


# ------------------------------------------------------------------ small vector helpers


def _vectors(value, n: int | None = None) -> np.ndarray:
    value = np.asarray(value, dtype=_FLOAT)
    if value.ndim == 1 and value.shape == (3,) and n is not None:
        value = np.repeat(value[:, None], n, axis=1)
    if value.ndim != 2 or value.shape[0] != 3:
        raise ValueError(f"expected (3, n) world vectors, got shape {value.shape}")
    return value


def _lanes(value, n: int, name: str) -> np.ndarray:
    value = np.asarray(value, dtype=_FLOAT)
    if value.ndim == 0:
        return np.full(n, float(value))
    if value.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {value.shape}")
    return value


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("in,in->n", a, b)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.sqrt(_dot(vectors, vectors)), _TINY)


def _side(cosine: np.ndarray) -> np.ndarray:
    """+1 / −1 for the side of the normal; exactly tangent counts as +1."""
    return np.where(cosine >= 0.0, 1.0, -1.0)


def light_frame(direction) -> np.ndarray:
    """A deterministic unit x̂ ⟂ direction, (3, n) -> (3, n); it jumps where d_z changes sign.

    The branchless orthonormal basis of Duff et al. 2017 ("Building an orthonormal basis,
    revisited"); with ŷ = ẑ × x̂ the frame is right-handed. Use it for the emitted frame
    of isotropic emitters, whose Σ does not depend on the choice.
    """
    d = _unit(_vectors(direction))
    sign = np.where(d[2] >= 0.0, 1.0, -1.0)
    a = -1.0 / (sign + d[2])
    b = d[0] * d[1] * a
    return np.stack([1.0 + sign * d[0] * d[0] * a, sign * b, -sign * d[0]])


def _orthogonal_axis(x_axis: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """x_axis made unit and ⟂ direction (Gram-Schmidt); light_frame where it is parallel."""
    x = x_axis - _dot(x_axis, direction) * direction
    length = np.sqrt(_dot(x, x))
    parallel = length < _PARALLEL_TOLERANCE
    if parallel.any():
        x = np.where(parallel, light_frame(direction), x)
        length = np.where(parallel, 1.0, length)
    return x / length


# ------------------------------------------------------------------------ the vertex


def vertex_step(vertex: SurfaceVertex, x_axis, handedness=1.0) -> VertexStep:
    """Chain parameters of one vertex, given the frame the light arrives in.

    vertex : the world-space data; x_axis : (3, n) x̂ of the arriving frame (made ⟂ to
    −toward_light here); handedness : (n,) or scalar, +1 if the arriving frame is
    right-handed (ŷ = ẑ × x̂), −1 if it is the mirror image (ŷ = −ẑ × x̂). Vectorised over
    lanes; see the module docstring for every step.

    Note that ``VertexStep.x_axis`` is the right-handed x̂; the frame to pass on to the
    next vertex with the operators' handedness is (``handedness·x_axis``, ``handedness``).
    """
    omega_i = _unit(_vectors(vertex.toward_light))
    n = omega_i.shape[1]
    omega_o = _unit(_vectors(vertex.toward_eye, n))
    normal = _unit(_vectors(vertex.normal, n))
    handedness = _lanes(handedness, n, "handedness")
    transmit = np.broadcast_to(np.asarray(vertex.transmit, dtype=bool), (n,))

    # 1. Arriving frame and the turn into the plane of incidence.
    z_in = -omega_i
    x_in = _orthogonal_axis(_vectors(x_axis, n), z_in)
    y_in = handedness * _cross(z_in, x_in)
    rotation_in = ops.plane_of_incidence_angle(_dot(normal, x_in), _dot(normal, y_in))
    c, s = np.cos(rotation_in), np.sin(rotation_in)
    x_turned = c * x_in + s * y_in
    y_turned = c * y_in - s * x_in

    # 2. Tangent axes (where the ray offsets land on the tangent plane).
    cos_i_signed = _dot(omega_i, normal)
    side_in = _side(cos_i_signed)
    cos_in = np.abs(cos_i_signed)
    tangent_x = x_turned
    tangent_y = _unit(cos_in * y_turned + side_in * _dot(y_turned, normal) * z_in)

    # 3. Curvature with respect to the side the light arrives from (flat when crossing).
    curvature_sign = np.where(transmit, 0.0, -side_in)
    k1 = curvature_sign * _lanes(vertex.k1, n, "k1")
    k2 = curvature_sign * _lanes(vertex.k2, n, "k2")
    principal = _vectors(vertex.principal_direction, n)
    curvature_angle = np.arctan2(_dot(principal, tangent_y), _dot(principal, tangent_x))

    # 4. Texture: J = ∂(s, t)/∂(t̂x, t̂y).
    gradient_s = _vectors(vertex.gradient_s, n)
    gradient_t = _vectors(vertex.gradient_t, n)
    jacobian = np.empty((n, 2, 2))
    jacobian[:, 0, 0] = _dot(gradient_s, tangent_x)
    jacobian[:, 0, 1] = _dot(gradient_s, tangent_y)
    jacobian[:, 1, 0] = _dot(gradient_t, tangent_x)
    jacobian[:, 1, 1] = _dot(gradient_t, tangent_y)
    texture = ops.texture_to_tangent(np.asarray(vertex.texture_uv, dtype=_FLOAT), jacobian)
    texture = np.broadcast_to(texture, (n, 2, 2))

    # 5. Out of the tangent plane toward ω_o.
    rotation_out = ops.plane_of_incidence_angle(_dot(omega_o, tangent_x), _dot(omega_o, tangent_y))
    x_out = _orthogonal_axis(np.cos(rotation_out) * tangent_x + np.sin(rotation_out) * tangent_y, omega_o)
    cos_o_signed = _dot(omega_o, normal)
    reflected = _side(cos_o_signed) == side_in
    handedness_out = np.where(reflected, -handedness, handedness)

    bandwidth = _lanes(vertex.bandwidth, n, "bandwidth")
    params = VertexParams(
        cos_in=cos_in,
        cos_out=np.abs(cos_o_signed),
        bandwidth_u=bandwidth,
        bandwidth_v=bandwidth,
        distance=_lanes(vertex.distance_to_eye, n, "distance_to_eye"),
        rotation_in=rotation_in,
        rotation_out=rotation_out,
        k1=k1,
        k2=k2,
        curvature_angle=curvature_angle,
        texture=texture,
    )
    return VertexStep(params=params, x_axis=handedness_out * x_out, handedness=handedness_out)


def to_right_handed(sigma: np.ndarray, handedness) -> np.ndarray:
    """Σ in the operators' frame -> Σ in the right-handed frame with x̂ negated where handedness < 0."""
    flip = (np.asarray(handedness) < 0.0)[:, None, None]
    return np.where(flip, sigma * _HANDEDNESS_FLIP, sigma)


# ------------------------------------------------------------------------ the path


def path_covariance(
    emitted,
    emitted_x_axis,
    light_direction,
    distance_from_light,
    vertices: Sequence[SurfaceVertex],
) -> PathCovariance:
    """Σ along n paths from the light to the eye.

    emitted : (n, 4, 4) Σ leaving the light, in the right-handed frame with x̂ =
        emitted_x_axis (3, n) and ẑ = light_direction (3, n), the propagation direction
        from the light to the first vertex (for an emitter hit after the last vertex with
        no vertex at all, the direction toward the eye).
    distance_from_light : (n,) metres; inf (distant lights, dome) means no travel, valid
        because their Σ has no spatial block (a purely angular Σ is unchanged by travel).
    vertices : light-to-eye order; vertex k's toward_light should be −(light_direction)
        for k = 0 and −(toward_eye of vertex k−1) after, up to rounding (each arriving
        frame is re-orthogonalised to −toward_light).

    Returns a ``PathCovariance``: Σ LEAVING each vertex toward the eye (after the inverse
    projection, before the travel) with its right-handed x̂, and Σ ARRIVING at the eye
    (after the last travel). Loops over vertices only; every step is vectorised.
    """
    sigma = np.asarray(emitted, dtype=_FLOAT)
    if sigma.ndim != 3 or sigma.shape[1:] != (4, 4):
        raise ValueError(f"emitted must have shape (n, 4, 4), got {sigma.shape}")
    n = len(sigma)
    direction = _unit(_vectors(light_direction, n))
    x_axis = _orthogonal_axis(_vectors(emitted_x_axis, n), direction)
    distance = _lanes(distance_from_light, n, "distance_from_light")
    sigma = ops.travel(sigma, np.where(np.isfinite(distance), distance, 0.0))

    handedness = np.ones(n)
    leaving, axes, steps = [], [], []
    for vertex in vertices:
        step = vertex_step(vertex, x_axis, handedness)
        at_vertex = scatter(sigma, dataclasses.replace(step.params, distance=0.0))
        leaving.append(to_right_handed(at_vertex, step.handedness))
        axes.append(step.x_axis)
        steps.append(step)
        sigma = ops.travel(at_vertex, step.params.distance)
        handedness = step.handedness
        x_axis = handedness * step.x_axis  # the operators' own x̂ for the next vertex
    return PathCovariance(
        leaving=tuple(leaving),
        leaving_x_axis=tuple(axes),
        at_eye=to_right_handed(sigma, handedness),
        at_eye_x_axis=handedness * x_axis,
        steps=tuple(steps),
    )


# ------------------------------------------------------------------------- emitters


def area_light_covariance(area, light_direction, light_normal=None, shape: str = "square"):
    """Σ leaving a diffuse area light toward light_direction, and its frame's x̂.

    The emitter is replaced by a Gaussian with the per-axis variance of a uniform patch of
    the same area: a square of side L has s² = L²/12 = area/12 per axis ("square"; used
    for rect lights of any aspect and for emitting triangles), a disk of radius R has
    s² = R²/4 = area/(4π) ("disk"; disk lights, and sphere lights seen as the disk of
    their silhouette with ``light_normal=None``). Σ = diag(1/(4π²s²), 1/(4π²s²), 0, 0) on
    the light's surface; area ≤ 0 is a point light (``POINT_LIGHT_EXTENT``).

    light_normal (3, n), if given, foreshortens the footprint seen from the ray: the
    frame has x̂ ⟂ the plane of (light_normal, light_direction) and ŷ in it, and Σyy is
    divided by max(cos θe, GRAZING_COS_EPS)² (``inverse_project`` from the light's
    surface). None means the light faces the ray (cos θe = 1), frame ``light_frame``.

    area : (n,) or scalar m²; light_direction : (3, n) from the light toward the first
    vertex. Returns (Σ (n, 4, 4), x̂ (3, n)) for ``path_covariance``.
    """
    direction = _unit(_vectors(light_direction))
    n = direction.shape[1]
    area = _lanes(area, n, "area")
    if shape == "square":
        variance = area / 12.0
    elif shape == "disk":
        variance = area / (4.0 * np.pi)
    else:
        raise ValueError(f"shape must be 'square' or 'disk', got {shape!r}")
    sigma = ops.emitter(np.sqrt(np.maximum(variance, 0.0)))
    if light_normal is None:
        return sigma, light_frame(direction)
    normal = _unit(_vectors(light_normal, n))
    x_axis = _orthogonal_axis(_cross(normal, direction), direction)
    return ops.inverse_project(sigma, _dot(normal, direction)), x_axis


def distant_light_covariance(angular_radius, light_direction):
    """Σ of a distant light whose directions fill a cone of half-angle ``angular_radius``.

    The uniform cone is replaced by a Gaussian of the same per-axis variance, r²/4 (a
    uniform disk of radius r), so α = r/2 in ``distant_emitter``; r ≤ 0 is a delta light
    (``DIRECTIONAL_LIGHT_EXTENT``). UsdLux ``angle`` is the DIAMETER in degrees:
    r = radians(angle)/2. Use distance_from_light = inf. angular_radius : (n,) or scalar
    radians; light_direction : (3, n) propagation direction. Returns (Σ, x̂).
    """
    direction = _unit(_vectors(light_direction))
    radius = _lanes(angular_radius, direction.shape[1], "angular_radius")
    return ops.distant_emitter(np.where(radius > 0.0, radius / 2.0, 0.0)), light_frame(direction)


def dome_covariance(light_direction, angular_variance=0.0):
    """Σ of light from a dome / environment (distance_from_light = inf).

    A uniform environment has no frequency content: Σ = 0 (constant radiance in every
    position and direction); the chain then only picks up what the surfaces add
    (texture, cosine windows). A textured dome can pass the second moment of its map's
    amplitude spectrum around the direction, ``angular_variance`` in cycles²/rad²
    (isotropic; e.g. ``texture_from_patch`` of a patch with texel sizes in radians):
    Σ = diag(0, 0, a, a). light_direction : (3, n). Returns (Σ, x̂).
    """
    direction = _unit(_vectors(light_direction))
    n = direction.shape[1]
    variance = _lanes(angular_variance, n, "angular_variance")
    sigma = np.zeros((n, 4, 4))
    sigma[:, 2, 2] = sigma[:, 3, 3] = variance
    return sigma, light_frame(direction)
