"""Direct irradiance from one UsdLux light by quadrature: the reference the tracer's lights
are checked against (tests/test_usdlux_reference.py validates it against closed forms).

    light = read_light(prim, time)                       # straight from the prim, with pxr only
    E = irradiance(light, points, normals, occluders)    # (n, 3) RGB

It shares nothing with pxr_layers but the IES file parser (``pxr_layers.stage.ies``): the
light is read from the prim with the pxr API, every formula comes from the UsdLux schema
documentation (``pxr/pluginfo/usdLux/resources/usdLux/schema.usda``), and where that
leaves a choice, hdEmbree's (the UsdLux reference renderer's) is taken.

Units. Positions are world metres (the stage's metersPerUnit applied to the light's whole
world transform, scale included). E is irradiance in the UsdLux unit: a Lambertian surface
of albedo ρ shows radiance ρ·E/π; a light of intensity 1 has radiance 1 (nit), linear
Rec.709. ``normalize`` divides by the world area in stage units² (UsdLux's "world-space
surface area"; a change of metersPerUnit alone leaves the image unchanged).

Emission L(point on the light, emission direction e), e a world unit vector:

    L = intensity · 2^exposure · color · blackbody(colorTemperature) · diffuse / sizeFactor
        · focus(θ) · cone(θ) · ies(θ_ies, φ)        (the last three with ShapingAPI only)

* blackbody: ``Gf.Color.SetFromPlanckianLocus(K, 1)`` in linear Rec.709, divided by its
  Rec.709 luminance (as hdEmbree); 1 unless enableColorTemperature.
* diffuse: E is what a Lambertian surface receives, so the diffuse multiplier applies
  (specular does not).
* sizeFactor (normalize): the world area for rect, disk, sphere and cylinder; for distant
  π·sin²θmax (θmax ≤ π/2) or π·(2 − sin²θmax), θmax = clamp(angle/2, 0, π), 1 if θmax = 0.
* θ is the angle between e and the light's primary axis, its −Z axis in world space (for
  every light type); focus: lerp(|cos θ|^focus, focusTint, 1) when focus > 0; cone:
  1 − smoothstep(θ; cone·(1 − softness), cone), softness clamped to [0, 1], and with no
  ramp θ ≤ cone gives 1, beyond 0.
* ies: the profile's candela, bilinear in (φ, θ_ies) over its table and 0 outside its
  vertical range, divided by its power (its mean intensity over the sphere, or over the
  hemisphere when its vertical angles span at most π/2 + 0.1, as hdEmbree) when
  ies:normalize. With w = −e in the light's local frame (the direction toward the light):
  θ_light = acos(w_z) (0 along the emission axis −Z), φ = atan2(w_y, w_x); θ_ies is
  θ_light / angleScale (angleScale > 0), (θ_light − π) / −angleScale + π (< 0), θ_light
  (0), clamped to [0, π].

Shapes, integrated over their exact surface (never a tessellation), one-sided along their
normal (−Z for rect and disk, outward for sphere and cylinder), with N = ``order``:

* rect (width × height in local XY): N × N Gauss–Legendre;
* disk: N Gauss–Legendre nodes in radius × 2N trapezoid nodes in azimuth;
* sphere (an ellipsoid under scale): over the cap visible from each point (found in the
  local frame, where the affine map keeps tangency), N Gauss–Legendre in cos × 2N
  trapezoid in azimuth around the point's direction;
* cylinder (radius, length along local X, no caps): over the band of azimuths visible from
  each point, N × N Gauss–Legendre (length × azimuth);
* distant: directions in the cone of half-angle θmax around the light's world +Z (light
  arrives from +Z: it emits along −Z), N Gauss–Legendre in cos × 2N trapezoid in azimuth;
  a delta direction when angle = 0 (E = L·cos);
* treatAsPoint / treatAsLine: the sphere collapsed to its centre with intensity
  L·area/4 (its mean projected area: the sphere's own far field, exact for a whole
  visible sphere), the cylinder to its axis with 2·r·L·sinψ per unit length (ψ the angle
  to the axis, r its mean world radius: a thin cylinder's emission); N Gauss nodes along it.

The world area is the same quadrature over the whole surface (exact for rect and disk, to
~1e-12 for ellipsoids). Area weights follow Nanson's rule, dA_world = |det M|·|M⁻ᵀ n|·dA.

Where a cone (ShapingAPI) cuts the light as seen from a point, or lets through less than
the light subtends, the point is integrated over the cone's directions instead (the
emission direction of a ray toward the light depends on the ray only): along each of 2N
azimuths about the cone's axis, the arc of directions that reach the (convex) shape is found
by a scan and bisection and integrated by N Gauss–Legendre nodes in cos, so the cone's
edge and the light's outline are the ends of the domain. What is left, where the
integrand still drops to 0 over part of the domain (a shadow's edge, the receiver's
horizon) and those cone points, is integrated again at order ``refine`` · N: the error
there is ~1/(refine · N) of the point's value at worst (~1e-4 typical); elsewhere ~1e-10.

Shadows: segments from each point to each node against ``Quad`` occluders (double-sided
parallelograms); ``Light.casts_shadow`` and ``Light.illuminates`` read the light's
shadowLink and lightLink collections.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

# The file parser (importing pxr_layers.stage registers pxr-layers' USD schema: before any stage opens).
from pxr_layers.stage.ies import read_ies as parse_ies_file

DEFAULT_ORDER = 16
CHUNK = 1 << 20
"""Point × node pairs evaluated at once (memory: a few dozen arrays of this many doubles)."""
_FAR = 1.0e7
"""Metres: the length of shadow segments toward a distant light."""
_EPSILON = 1.0e-7
"""Fraction of a shadow segment at either end that cannot be blocked (the ends are on surfaces)."""


@dataclass(frozen=True)
class Quad:
    """A double-sided occluding parallelogram: centre + a·edge_u + b·edge_v, |a|, |b| ≤ 1/2
    (metres). path: the prim it stands for, checked against the light's shadowLink."""

    centre: np.ndarray
    edge_u: np.ndarray
    edge_v: np.ndarray
    path: str | None = None

    @property
    def normal(self) -> np.ndarray:
        normal = np.cross(self.edge_u, self.edge_v)
        return normal / np.linalg.norm(normal)

    def intersect(self, origins: np.ndarray, rays: np.ndarray) -> np.ndarray:
        """(n, m) parameter t > 0 where origins (n, 3) + t · rays (n or 1, m, 3) cross the
        quad, inf where they miss it."""
        # rows: the plane's normal, then the edges scaled so that a, b = (x − centre)·row
        basis = np.stack([self.normal, self.edge_u / (self.edge_u @ self.edge_u),
                          self.edge_v / (self.edge_v @ self.edge_v)])
        start = (origins - self.centre) @ basis.T  # (n, 3)
        along = rays @ basis.T  # (n or 1, m, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -start[:, None, 0] / along[..., 0]
            a = start[:, None, 1] + t * along[..., 1]
            b = start[:, None, 2] + t * along[..., 2]
        return np.where((t > 0) & (np.abs(a) <= 0.5) & (np.abs(b) <= 0.5), t, np.inf)


@dataclass(frozen=True)
class Ies:
    """An IES profile's table (radians; candela (H, V), horizontal 0..2π unfolded) and the
    divisor of ies:normalize, computed here."""

    vertical: np.ndarray
    horizontal: np.ndarray
    candela: np.ndarray
    power: float

    def sample(self, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
        """Candela at (θ, φ) radians, bilinear; 0 outside the vertical range."""
        h, v = self.horizontal, self.vertical
        i = np.clip(np.searchsorted(h, phi, side="right") - 1, 0, len(h) - 2)
        j = np.clip(np.searchsorted(v, theta, side="right") - 1, 0, len(v) - 2)
        fh = np.clip((phi - h[i]) / (h[i + 1] - h[i]), 0.0, 1.0)
        fv = np.clip((theta - v[j]) / (v[j + 1] - v[j]), 0.0, 1.0)
        low = self.candela[i, j] * (1 - fv) + self.candela[i, j + 1] * fv
        high = self.candela[i + 1, j] * (1 - fv) + self.candela[i + 1, j + 1] * fv
        inside = (theta >= v[0]) & (theta <= v[-1])
        return np.where(inside, low * (1 - fh) + high * fh, 0.0)


def ies_power(vertical: np.ndarray, horizontal: np.ndarray, candela: np.ndarray) -> float:
    """The mean of the bilinear interpolant of ``candela`` over the sphere (the hemisphere
    when the vertical angles span at most π/2 + 0.1): exact cell by cell."""
    # Over φ a bilinear cell integrates to Δφ times the mean of its two φ-edges; over θ,
    # ∫ (a + b (θ − θ0)) sin θ dθ in closed form.
    edge = 0.5 * (candela[1:] + candela[:-1]) * np.diff(horizontal)[:, None]  # (H-1, V): ∫ dφ
    per_theta = edge.sum(axis=0)  # (V,)
    t0, t1 = vertical[:-1], vertical[1:]
    width = t1 - t0
    a, slope = per_theta[:-1], (per_theta[1:] - per_theta[:-1]) / width
    integral = a * (np.cos(t0) - np.cos(t1)) + slope * (np.sin(t1) - np.sin(t0) - width * np.cos(t1))
    hemisphere = vertical[-1] - vertical[0] <= math.pi / 2 + 0.1
    return float(integral.sum() / ((2.0 if hemisphere else 4.0) * math.pi))


def read_ies(path: str | Path) -> Ies:
    """The IES file at a resolved path: parsed by pxr_layers.stage.ies, its power computed here."""
    profile, _ = parse_ies_file(str(path))
    vertical, horizontal, candela = (np.asarray(a, float) for a in (profile.vertical, profile.horizontal,
                                                                      profile.candela))
    return Ies(vertical, horizontal, candela, ies_power(vertical, horizontal, candela))


@dataclass(frozen=True)
class Shaping:
    cone_angle: float  # degrees
    cone_softness: float  # clamped to [0, 1]
    focus: float
    focus_tint: np.ndarray  # (3,)
    ies: Ies | None
    ies_angle_scale: float
    ies_normalize: bool


@dataclass(frozen=True)
class Light:
    """One UsdLux light at one time (see the module docstring for the semantics).

    kind      : rect, disk, sphere, cylinder, distant, point (treatAsPoint), line (treatAsLine)
    linear    : (3, 3) world_from_light's linear part, metres per local unit (column vectors)
    origin    : (3,) metres
    rgb       : (3,) radiance before shaping: intensity · 2^exposure · colour · blackbody ·
                diffuse / sizeFactor
    area      : world surface area in metres² (0 for distant)
    """

    path: str
    kind: str
    linear: np.ndarray
    origin: np.ndarray
    width: float
    height: float
    radius: float
    length: float
    angle: float
    rgb: np.ndarray
    area: float
    shaping: Shaping | None
    light_link: Usd.CollectionMembershipQuery
    shadow_link: Usd.CollectionMembershipQuery

    @property
    def axis(self) -> np.ndarray:
        """The primary axis: local −Z in world space, unit."""
        axis = -self.linear[:, 2]
        return axis / np.linalg.norm(axis)

    def illuminates(self, path: str | None) -> bool:
        return path is None or self.light_link.IsPathIncluded(Sdf.Path(path))

    def casts_shadow(self, path: str | None) -> bool:
        return path is None or self.shadow_link.IsPathIncluded(Sdf.Path(path))

    def radiance(self, emission: np.ndarray) -> np.ndarray:
        """(..., 3) RGB radiance along world unit emission directions (..., 3)."""
        out = np.broadcast_to(self.rgb, emission.shape).copy()
        if self.shaping is not None:
            out *= _shaping(self, emission)
        return out


def blackbody(kelvin: float) -> np.ndarray:
    """UsdLux colour temperature as linear Rec.709 RGB of Rec.709 luminance 1 (hdEmbree's)."""
    rec709 = Gf.ColorSpace(Gf.ColorSpaceNames.LinearRec709)
    xyz = Gf.ColorSpace(Gf.ColorSpaceNames.CIEXYZ)
    luminance = np.array([Gf.Color(Gf.Color(axis, rec709), xyz).GetRGB()[1]
                          for axis in (Gf.Vec3f(1, 0, 0), Gf.Vec3f(0, 1, 0), Gf.Vec3f(0, 0, 1))])
    color = Gf.Color(rec709)
    color.SetFromPlanckianLocus(float(kelvin), 1.0)
    rgb = np.array(color.GetRGB(), float)
    return rgb / float(rgb @ luminance)


def read_light(prim: Usd.Prim, time: Usd.TimeCode | float = Usd.TimeCode.Default()) -> Light:
    """The light ``prim`` at ``time``, from its attributes (schema fallbacks included)."""
    time = Usd.TimeCode(time)

    def get(name, default=None):
        attribute = prim.GetAttribute(name)
        value = attribute.Get(time) if attribute else None
        return default if value is None else value

    kinds = {UsdLux.RectLight: "rect", UsdLux.DiskLight: "disk", UsdLux.SphereLight: "sphere",
             UsdLux.CylinderLight: "cylinder", UsdLux.DistantLight: "distant"}
    kind = next((name for schema, name in kinds.items() if prim.IsA(schema)), None)
    if kind is None:
        raise ValueError(f"{prim.GetPath()}: not a rect, disk, sphere, cylinder or distant light")
    if kind == "sphere" and get("treatAsPoint", False):
        kind = "point"
    if kind == "cylinder" and get("treatAsLine", False):
        kind = "line"
    meters = UsdGeom.GetStageMetersPerUnit(prim.GetStage())
    matrix = np.array(UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(time), float).T * meters
    light = Light(path=str(prim.GetPath()), kind=kind, linear=matrix[:3, :3], origin=matrix[:3, 3],
                  width=float(get("inputs:width", 1.0)), height=float(get("inputs:height", 1.0)),
                  radius=float(get("inputs:radius", 0.5)), length=float(get("inputs:length", 1.0)),
                  angle=float(get("inputs:angle", 0.53)), rgb=np.ones(3), area=0.0, shaping=None,
                  light_link=UsdLux.LightAPI(prim).GetLightLinkCollectionAPI().ComputeMembershipQuery(),
                  shadow_link=UsdLux.LightAPI(prim).GetShadowLinkCollectionAPI().ComputeMembershipQuery())
    area = 0.0 if kind == "distant" else _world_area(light)
    rgb = (float(get("inputs:intensity", 1.0)) * 2.0 ** float(get("inputs:exposure", 0.0))
           * np.array(get("inputs:color", Gf.Vec3f(1, 1, 1)), float) * float(get("inputs:diffuse", 1.0)))
    if get("inputs:enableColorTemperature", False):
        rgb = rgb * blackbody(get("inputs:colorTemperature", 6500.0))
    if get("inputs:normalize", False):
        rgb = rgb / (_distant_size_factor(light.angle) if kind == "distant" else area / meters**2)
    shaping = None
    if prim.HasAPI(UsdLux.ShapingAPI):
        ies_file = get("inputs:shaping:ies:file")
        ies_path = ies_file.resolvedPath if ies_file is not None else ""
        if ies_file is not None and ies_file.path and not ies_path:
            raise FileNotFoundError(f"{prim.GetPath()}: IES profile {ies_file.path} not found")
        shaping = Shaping(
            cone_angle=float(get("inputs:shaping:cone:angle")),
            cone_softness=min(max(float(get("inputs:shaping:cone:softness")), 0.0), 1.0),
            focus=float(get("inputs:shaping:focus")),
            focus_tint=np.array(get("inputs:shaping:focusTint"), float),
            ies=read_ies(ies_path) if ies_path else None,
            ies_angle_scale=float(get("inputs:shaping:ies:angleScale")),
            ies_normalize=bool(get("inputs:shaping:ies:normalize")))
        if shaping.focus <= 0 and shaping.ies is None and shaping.cone_angle * (1 - shaping.cone_softness) >= 180:
            shaping = None  # changes nothing (and costs nothing then)
    return dataclasses.replace(light, rgb=rgb, area=area, shaping=shaping)


def _distant_size_factor(angle_degrees: float) -> float:
    theta_max = min(max(math.radians(angle_degrees) / 2, 0.0), math.pi)
    if theta_max == 0.0:
        return 1.0
    sin2 = math.sin(theta_max) ** 2
    return math.pi * sin2 if theta_max <= math.pi / 2 else math.pi * (2.0 - sin2)


def _smoothstep(t: np.ndarray, start: float, stop: float) -> np.ndarray:
    if stop <= start:
        return np.where(t <= start, 0.0, 1.0)
    x = np.clip((t - start) / (stop - start), 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _shaping(light: Light, emission: np.ndarray) -> np.ndarray:
    """(..., 3) focus × cone × IES weights of emission directions (..., 3)."""
    shaping = light.shaping
    cos_theta = np.clip(emission @ light.axis, -1.0, 1.0)
    weight = np.ones(emission.shape)
    if shaping.focus > 0:
        factor = np.abs(cos_theta)[..., None] ** shaping.focus
        weight *= shaping.focus_tint + factor * (1.0 - shaping.focus_tint)
    cutoff = math.radians(shaping.cone_angle)
    weight *= (1.0 - _smoothstep(np.arccos(cos_theta), cutoff * (1.0 - shaping.cone_softness), cutoff))[..., None]
    if shaping.ies is not None:
        toward = -np.linalg.solve(light.linear, emission.reshape(-1, 3).T).T  # local, toward the light
        toward /= np.linalg.norm(toward, axis=1, keepdims=True)
        theta = np.arccos(np.clip(toward[:, 2], -1.0, 1.0))
        phi = np.mod(np.arctan2(toward[:, 1], toward[:, 0]), 2 * math.pi)
        scale = shaping.ies_angle_scale
        if scale > 0:
            theta = theta / scale
        elif scale < 0:
            theta = (theta - math.pi) / -scale + math.pi
        candela = shaping.ies.sample(np.clip(theta, 0.0, math.pi), phi)
        if shaping.ies_normalize:
            candela = candela / shaping.ies.power
        weight *= candela.reshape(emission.shape[:-1])[..., None]
    return weight


# -- quadrature nodes ------------------------------------------------------------------------


def _gauss(order: int, low, high):
    """Gauss–Legendre nodes and weights on [low, high] (arrays broadcast: (..., order))."""
    x, w = np.polynomial.legendre.leggauss(order)
    low, high = np.asarray(low, float)[..., None], np.asarray(high, float)[..., None]
    half = 0.5 * (high - low)
    return low + half * (x + 1.0), half * w


def _periodic(count: int):
    """Trapezoid nodes and weights of [0, 2π) (spectrally accurate for periodic integrands)."""
    phi = (np.arange(count) + 0.5) * (2 * math.pi / count)
    return phi, np.full(count, 2 * math.pi / count)


def _to_world(light: Light, local_points, local_normals, local_weights):
    """World positions, unit normals and area weights (Nanson: |det M|·|M⁻ᵀ n|·dA)."""
    inverse = np.linalg.inv(light.linear)
    normals = local_normals @ inverse  # rows: (M⁻ᵀ n)ᵀ
    stretch = np.linalg.norm(normals, axis=-1)
    weights = abs(np.linalg.det(light.linear)) * stretch * local_weights
    return light.origin + local_points @ light.linear.T, normals / stretch[..., None], weights


def _planar_nodes(light: Light, order: int):
    """(1, m, 3) points, normals, (1, m) weights of a rect or disk (emitting along −Z)."""
    if light.kind == "rect":
        u, wu = _gauss(order, -light.width / 2, light.width / 2)
        v, wv = _gauss(order, -light.height / 2, light.height / 2)
        x, y = np.meshgrid(u, v, indexing="ij")
        weights = np.outer(wu, wv)
    else:
        r, wr = _gauss(order, 0.0, light.radius)
        phi, wphi = _periodic(2 * order)
        x, y = np.outer(r, np.cos(phi)), np.outer(r, np.sin(phi))
        weights = np.outer(wr * r, wphi)
    points = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=-1)
    normals = np.broadcast_to([0.0, 0.0, -1.0], points.shape)
    return tuple(a[None] for a in _to_world(light, points, normals, weights.ravel()))


def _frame(axis: np.ndarray):
    """Two unit vectors completing each unit axis (n, 3) to an orthonormal frame."""
    helper = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    first = np.cross(axis, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    return first, np.cross(axis, first)


def _cap(axis: np.ndarray, cos_low, order: int):
    """Unit vectors (n, m, 3) of the caps {cos ∠(v, axis) ≥ cos_low} about unit axes (n, 3),
    and their solid angles (n, m): N Gauss–Legendre nodes in cos × 2N trapezoid azimuths."""
    mu, wmu = _gauss(order, cos_low, 1.0)  # (n, N)
    phi, wphi = _periodic(2 * order)
    first, second = _frame(axis)
    ring = np.cos(phi)[:, None] * first[:, None, :] + np.sin(phi)[:, None] * second[:, None, :]  # (n, 2N, 3)
    sin_mu = np.sqrt(np.clip(1.0 - mu * mu, 0.0, None))
    vectors = mu[:, :, None, None] * axis[:, None, None, :] + sin_mu[:, :, None, None] * ring[:, None, :, :]
    return vectors.reshape(len(axis), -1, 3), (wmu[:, :, None] * wphi).reshape(len(axis), -1)


def _cap_nodes(light: Light, axis: np.ndarray, cos_alpha: np.ndarray, order: int):
    """(n, m, ...) nodes of the caps {cos ∠(q, axis) ≥ cos α} of the light's sphere, in world."""
    normals, solid_angles = _cap(axis, cos_alpha, order)
    return _to_world(light, light.radius * normals, normals, light.radius**2 * solid_angles)


def _band_nodes(light: Light, centre: np.ndarray, half_width: np.ndarray, order: int):
    """(n, m, ...) nodes of the cylinder's side over azimuths centre ± half_width (about X)."""
    x, wx = _gauss(order, -light.length / 2, light.length / 2)
    phi, wphi = _gauss(order, centre - half_width, centre + half_width)  # (n, N)
    n = len(centre)
    cos, sin = np.cos(phi)[:, None, :], np.sin(phi)[:, None, :]
    normals = np.stack(np.broadcast_arrays(np.zeros((n, order, order)), cos, sin), axis=-1)
    points = normals * light.radius
    points[..., 0] = x[:, None]
    weights = light.radius * wx[None, :, None] * wphi[:, None, :]
    return _to_world(light, points.reshape(n, -1, 3), normals.reshape(n, -1, 3), weights.reshape(n, -1))


def _visible_nodes(light: Light, points: np.ndarray, order: int):
    """Nodes of the part of a sphere or cylinder that faces each point (none when inside)."""
    local = (points - light.origin) @ np.linalg.inv(light.linear).T
    if light.kind == "sphere":
        distance = np.linalg.norm(local, axis=1)
        outside = distance > light.radius
        axis = np.where(outside[:, None], local / np.where(outside, distance, 1.0)[:, None], [[0.0, 0.0, 1.0]])
        nodes = _cap_nodes(light, axis, np.where(outside, light.radius / np.where(outside, distance, 1.0), 1.0), order)
    else:
        distance = np.hypot(local[:, 1], local[:, 2])
        outside = distance > light.radius
        half = np.arccos(np.clip(light.radius / np.where(outside, distance, 1.0), -1.0, 1.0))
        nodes = _band_nodes(light, np.arctan2(local[:, 2], local[:, 1]), np.where(outside, half, 0.0), order)
    return nodes


def _world_area(light: Light, order: int = 96) -> float:
    """World surface area in metres² (rect, disk: exact; sphere, cylinder: quadrature)."""
    if light.kind in ("rect", "disk"):
        return float(_planar_nodes(light, 2)[2].sum())
    if light.kind in ("sphere", "point"):
        return float(_cap_nodes(light, np.array([[0.0, 0.0, 1.0]]), np.array([-1.0]), order)[2].sum())
    return float(_band_nodes(light, np.zeros(1), np.full(1, math.pi), order)[2].sum())


# -- irradiance -----------------------------------------------------------------------------


def _unblocked(points: np.ndarray, segments: np.ndarray, occluders) -> np.ndarray:
    """(n, m) 1 where the segment from each point (n, 3) along segments (n or 1, m, 3) is clear."""
    clear = np.ones((len(points), segments.shape[1]))
    for quad in occluders:
        t = quad.intersect(points, segments)
        clear[(t > _EPSILON) & (t < 1.0 - _EPSILON)] = 0.0
    return clear


def hit(light: Light, origins: np.ndarray, directions: np.ndarray, front_only: bool = True) -> np.ndarray:
    """(n, m) parameter t of rays origins (n, 3) + t · directions (n or 1, m, 3) where they
    meet the light's shape, inf where they miss it (always for point and line lights, which
    have none). front_only: only hits on its emitting side (seen from the origin)."""
    if light.kind in ("point", "line", "distant"):
        return np.full((len(origins), directions.shape[1]), np.inf)
    inverse = np.linalg.inv(light.linear)
    o = ((origins - light.origin) @ inverse.T)[:, None, :]  # local; t is the same in both frames
    d = np.broadcast_to(directions @ inverse.T, (len(origins), *directions.shape[1:]))
    with np.errstate(divide="ignore", invalid="ignore"):
        if light.kind in ("rect", "disk"):
            t = -o[..., 2] / d[..., 2]
            x, y = o[..., 0] + t * d[..., 0], o[..., 1] + t * d[..., 1]
            inside = ((np.abs(x) <= light.width / 2) & (np.abs(y) <= light.height / 2) if light.kind == "rect"
                      else x * x + y * y <= light.radius**2)
            inside &= (t > 0) & ((o[..., 2] < 0) if front_only else True)  # it emits from local −Z
            return np.where(inside, t, np.inf)
        axes = slice(0, 3) if light.kind == "sphere" else slice(1, 3)  # a cylinder's circle is in YZ
        a = np.einsum("nmk,nmk->nm", d[..., axes], d[..., axes])
        b = np.einsum("nmk,nmk->nm", o[..., axes], d[..., axes])
        c = np.einsum("nmk,nmk->nm", o[..., axes], o[..., axes]) - light.radius**2
        root = np.sqrt(b * b - a * c)
        t = np.full(a.shape, np.inf)
        # the far root is the inside of the surface, which emits nothing: front_only skips it
        for candidate in ((-b - root) / a,) if front_only else ((-b + root) / a, (-b - root) / a):
            valid = candidate > 0
            if light.kind == "cylinder":
                valid &= np.abs(o[..., 0] + candidate * d[..., 0]) <= light.length / 2
            t = np.where(valid, candidate, t)  # the near root last: it wins where both are valid
    return t


def _emitters(light: Light, points: np.ndarray, order: int):
    """(n or 1, m, 3) nodes, their unit normals (None for point and line) and (n or 1, m)
    weights: area for surfaces, intensity per radiance for a point, per unit length for a line."""
    if light.kind in ("rect", "disk"):
        return _planar_nodes(light, order)
    if light.kind in ("sphere", "cylinder"):
        return _visible_nodes(light, points, order)
    if light.kind == "point":
        return light.origin[None, None, :], None, np.full((1, 1), light.area / 4)
    direction = light.linear[:, 0]
    x, wx = _gauss(order, -light.length / 2, light.length / 2)
    mean_radius = light.area / (2 * math.pi * light.length * np.linalg.norm(direction))
    return (light.origin + np.outer(x, direction))[None], None, (2 * mean_radius * np.linalg.norm(direction) * wx)[None]


def _over_area(light: Light, points, normals, occluders, order: int):
    """By quadrature over the light's surface: (n, 3) irradiance, (n,) the solid angle the
    light subtends (0 for point and line), (n,) jumps of visibility (shadows, the horizon)
    and (n,) jumps of emission (a cone's edge)."""
    nodes, node_normals, weights = _emitters(light, points, order)
    segments = nodes - points[:, None, :]
    distance2 = np.einsum("nmk,nmk->nm", segments, segments)
    toward = segments / np.sqrt(distance2)[..., None]
    if light.kind == "point":
        projection = np.ones(1)
    elif light.kind == "line":  # sin ψ, ψ the angle to the axis
        along = light.linear[:, 0] / np.linalg.norm(light.linear[:, 0])
        projection = np.sqrt(np.clip(1.0 - (toward @ along) ** 2, 0.0, None))
    else:
        projection = np.clip(-np.einsum("nmk,nmk->nm", node_normals, toward), 0.0, None)
    solid = np.broadcast_to(projection * weights / distance2, distance2.shape)
    cos_surface = np.clip(np.einsum("nk,nmk->nm", normals, toward), 0.0, None)
    geometry = cos_surface * _unblocked(points, segments, occluders)
    radiance = light.radiance(-toward)
    solid_angle = np.zeros(len(points)) if node_normals is None else solid.sum(axis=1)
    return (np.einsum("nm,nmk->nk", geometry * solid, radiance), solid_angle, _jumps(solid, geometry == 0),
            _jumps(solid, radiance.max(axis=-1) == 0))


def _jumps(solid: np.ndarray, dark: np.ndarray) -> np.ndarray:
    """(n,) whether the integrand is 0 over part of the light only (a shadow, the horizon, a
    cone's edge): where fixed-order quadrature is least accurate."""
    facing = solid > 0
    return (facing & dark).any(axis=1) & (facing & ~dark).any(axis=1)


def _over_cone(light: Light, points, normals, occluders, order: int, cutoff: float, scan: int = 64):
    """(n, 3) irradiance over the directions within ``cutoff`` of the light's +Z (the
    emission cone, seen from the receiver) that reach its shape. The set of
    directions that hit a convex shape is convex, so along each of 2N azimuths about the
    axis it is one arc: found by a scan of ``scan`` directions and bisection, then
    integrated by N Gauss–Legendre nodes in cos. The light's outline and the cone's edge are
    the ends of the domain, not jumps inside it."""
    axis = -light.axis
    phi, wphi = _periodic(2 * order)
    first, second = (vector[0] for vector in _frame(axis[None]))
    ring = np.cos(phi)[:, None] * first + np.sin(phi)[:, None] * second  # (2N, 3)
    n = len(points)

    def directions(mu):  # (n, 2N, k) cosines → (n, 2N·k, 3)
        sin = np.sqrt(np.clip(1.0 - mu * mu, 0.0, None))
        return (mu[..., None] * axis + sin[..., None] * ring[None, :, None, :]).reshape(n, -1, 3)

    def reaches(mu):
        return np.isfinite(hit(light, points, directions(mu))).reshape(mu.shape)

    low = math.cos(cutoff)
    grid = np.linspace(low, 1.0, scan)
    inside = reaches(np.broadcast_to(grid, (n, 2 * order, scan)))
    seen = inside.any(axis=-1)
    first_in = inside.argmax(axis=-1)
    last_in = scan - 1 - inside[..., ::-1].argmax(axis=-1)
    ends = []
    for hit_at, miss_at, edge in ((first_in, first_in - 1, low), (last_in, last_in + 1, 1.0)):
        at_edge = (miss_at < 0) | (miss_at >= scan)
        inner, outer = grid[hit_at], grid[np.clip(miss_at, 0, scan - 1)]
        for _ in range(40):  # to ~1e-12 of the cone's cos range
            middle = 0.5 * (inner + outer)
            reached = reaches(middle[..., None])[..., 0]
            inner, outer = np.where(reached, middle, inner), np.where(reached, outer, middle)
        ends.append(np.where(at_edge, edge, inner))
    mu, wmu = _gauss(order, ends[0], ends[1])  # (n, 2N, N)
    toward = directions(mu)
    t = hit(light, points, toward)
    reached = np.isfinite(t)
    solid = np.where(reached, (wmu * wphi[None, :, None] * seen[..., None]).reshape(n, -1), 0.0)
    segments = np.where(reached, t, 0.0)[..., None] * toward
    geometry = np.clip(np.einsum("nk,nmk->nm", normals, toward), 0.0, None) * _unblocked(points, segments, occluders)
    return np.einsum("nm,nmk->nk", geometry * solid, light.radiance(-toward))


def _chunk(light: Light, points: np.ndarray, normals: np.ndarray, occluders, order: int):
    """(n, 3) irradiance and (n,) whether the integrand jumps (see _jumps)."""
    if light.kind == "distant":
        theta_max = min(max(math.radians(light.angle) / 2, 0.0), math.pi)
        if theta_max == 0.0:  # a delta: E = L · cos
            directions, solid_angles = -light.axis[None], np.ones(1)
        else:
            directions, solid_angles = (a[0] for a in _cap(-light.axis[None], np.array([math.cos(theta_max)]), order))
        geometry = np.clip(normals @ directions.T, 0.0, None) * _unblocked(points, directions[None] * _FAR, occluders)
        solid = np.broadcast_to(solid_angles, geometry.shape)
        return (geometry * solid) @ light.radiance(-directions), _jumps(solid, geometry == 0)
    irradiance_, solid_angle, jumps, cut = _over_area(light, points, normals, occluders, order)
    cutoff = math.radians(light.shaping.cone_angle) if light.shaping is not None else math.pi
    if cutoff < math.pi and light.kind in ("rect", "disk", "sphere", "cylinder"):
        # Where the cone's edge cuts the light, or the cone lets through less than the
        # light subtends: integrate over the cone's directions instead.
        cone = cut | (2 * math.pi * (1 - math.cos(cutoff)) < solid_angle)
        if cone.any():
            irradiance_[cone] = _over_cone(light, points[cone], normals[cone], occluders, order, cutoff)
            jumps |= cone  # the arcs' ends have kinks in azimuth: refined too
    return irradiance_, jumps


def irradiance(light: Light, points, normals, occluders=(), *, receiver: str | None = None,
               order: int = DEFAULT_ORDER, refine: int = 4) -> np.ndarray:
    """(n, 3) RGB irradiance at world points (n, 3) metres with normals (n, 3) (made unit).

    occluders : Quads that block the light (those outside its shadowLink are skipped)
    receiver  : the prim the points are on: 0 if the light's lightLink excludes it
    order     : N, the quadrature order (see the module docstring)
    refine    : points whose integrand jumps (penumbrae, horizons, cone edges) are integrated
                again at order refine · N
    """
    points = np.asarray(points, float).reshape(-1, 3)
    normals = np.asarray(normals, float).reshape(-1, 3)
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    out = np.zeros((len(points), 3))
    if not light.illuminates(receiver) or len(points) == 0:
        return out
    blockers = [quad for quad in occluders if light.casts_shadow(quad.path)]
    jumps = _integrate(light, points, normals, blockers, order, out)
    if refine > 1 and jumps.any():
        again = np.zeros((int(jumps.sum()), 3))
        _integrate(light, points[jumps], normals[jumps], blockers, order * refine, again)
        out[jumps] = again
    return out


def _integrate(light: Light, points, normals, occluders, order: int, out: np.ndarray) -> np.ndarray:
    """Fill out (n, 3) chunk by chunk; returns (n,) whether each point's integrand jumps."""
    per_point = {"rect": order * order, "disk": 2 * order * order, "sphere": 2 * order * order,
                 "cylinder": order * order, "distant": 2 * order * order, "point": 1, "line": order}[light.kind]
    step = max(1, CHUNK // per_point)
    jumps = np.zeros(len(points), bool)
    for start in range(0, len(points), step):
        stop = start + step
        out[start:stop], jumps[start:stop] = _chunk(light, points[start:stop], normals[start:stop], occluders, order)
    return jumps
