"""Chi-squared goodness-of-fit tests of every light type's sampling against its pdf (after
Mitsuba 3's and pbrt-v4's chi2 tests).

Each test draws SAMPLES light samples with a fixed seed through the real sampling kernel
(light_kernels.sample) from a shading point, bins them, and computes each bin's expected
count as SAMPLES × the pdf kernel integrated over the bin; bins expecting fewer than
MIN_EXPECTED samples are pooled, and the test passes when the p-value of Pearson's
statistic exceeds SIGNIFICANCE. The pdf is the one MIS uses (light_kernels.emitter_pdf
for what a ray hits, dome_pdf and cone_pdf for what escapes). Two parameterisations:

* lights sampled by area (rect, disk, cylinder, ellipsoids, emissive surfaces): the light's
  own, each triangle cut into k² equal sub-triangles; the solid-angle pdf at a
  sub-triangle's centre times |cos| / distance² is the area density, constant over a
  triangle, so the integral is exact. A (cos θ, φ) grid would need the pdf's 1/|cos| spikes
  on the grazing facets of closed shapes integrated, which a sub-grid cannot do reliably.
* the others (spheres by solid angle, distant cones, domes, a mixture of sources): a
  (cos θ, φ) grid about an axis, the pdf integrated on a sub-grid of each bin (midpoint
  rule, refined where the pdf varies and next to its support).

Delta lights (points, delta distant lights) have no density: the chi² test covers their
selection among the sources (source_cdf) and a line's samples along its segment, and an
exact check their one direction. The scenes are plain SceneData, no USD.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import pytest

from pxr_layers.compiled import kernel, scratch
from pxr_layers.scene import IesProfile, Light, LightShaping, Material, Mesh, SceneData, TextureImage
from pxr_layers.trace import light_kernels, shading
from pxr_layers.trace.embree import RayCaster
from pxr_layers.trace.light_kernels.table import DISTANT, POINT
from pxr_layers.trace.lights import LightSampler
from pxr_layers.trace.shading import MaterialTable
from pxr_layers.trace.stages.next_event import SHADOW_SPAN
from pxr_layers.trace.world import GeometryArrays, World, build_world, geometry_arrays

log = logging.getLogger(__name__)

SAMPLES = 100_000
ROWS, COLUMNS = 20, 40  # the (cos θ, φ) grid
SUBDIVISIONS = 12  # per bin and axis, for the pdf's integral (midpoint rule)
REFINED_SUBDIVISIONS = 64  # in bins where the pdf varies (edges, grazing triangles' 1/cos)
UNEVEN = 1.1  # a bin's pdf varies when its largest sub-cell value exceeds its smallest by this
MIN_EXPECTED = 5.0
SIGNIFICANCE = 0.01
SEED = 1  # over seeds 1–20, 3 of the 240 fits below fell under 1 %: as many as chance makes
SHADING_POINT = np.array([0.4, 0.0, -0.3])  # metres: off every light's axis
AREA_CELLS = 600  # sub-triangles an area-sampled light is cut into, about
HEIGHT = 2.0  # the lights hang this high above the origin, emitting down


# -- the chi² distribution's survival function (no scipy in the venv)

def chi2_survival(statistic: float, dof: int) -> float:
    """P(X > statistic) for X ~ χ²(dof): the regularized upper incomplete gamma function
    Q(dof/2, statistic/2), by its series below a + 1 and Legendre's continued fraction
    (modified Lentz) above (Numerical Recipes' gammq)."""
    a, x = dof / 2.0, statistic / 2.0
    if x <= 0:
        return 1.0
    log_prefix = a * math.log(x) - x - math.lgamma(a)
    if x < a + 1:
        term = total = 1.0 / a
        for n in range(1, 1000):
            term *= x / (a + n)
            total += term
            if abs(term) < abs(total) * 1e-15:
                break
        return max(0.0, 1.0 - total * math.exp(log_prefix))
    tiny = 1e-300
    b = x + 1.0 - a
    c, d = 1.0 / tiny, 1.0 / b
    fraction = d
    for n in range(1, 1000):
        an = -n * (n - a)
        b += 2.0
        d = an * d + b
        d = tiny if abs(d) < tiny else d
        c = b + an / c
        c = tiny if abs(c) < tiny else c
        d = 1.0 / d
        fraction *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return math.exp(log_prefix) * fraction


@pytest.mark.parametrize("statistic, dof, expected", [
    (3.841458820694124, 1, 0.05),  # the textbook critical values
    (6.634896601021214, 1, 0.01),
    (18.307038053275146, 10, 0.05),
    (124.34211340400407, 100, 0.05),
    (4.0, 2, math.exp(-2.0)),  # χ²(2) is exponential: Q = e^(−x/2)
    (0.5, 2, math.exp(-0.25)),
    (1.0, 3, 0.8012519569012008),  # erfc(1/√2) + √(2/π) e^(−1/2)
])
def test_chi2_survival_matches_known_values(statistic, dof, expected):
    assert chi2_survival(statistic, dof) == pytest.approx(expected, rel=1e-9)


def pearson_p_value(observed: np.ndarray, expected: np.ndarray) -> tuple[float, int]:
    """(p-value, degrees of freedom) of Pearson's χ² for bin counts `observed` against
    `expected`, after pooling the bins that expect fewer than MIN_EXPECTED samples (lowest
    first, as Mitsuba's test does). Bins a sampler reaches where the pdf says nothing can
    go (expected 0) are pooled too, so their samples weigh in the statistic."""
    order = np.argsort(expected, kind="stable")
    cells_observed, cells_expected = [], []
    pool_observed = pool_expected = 0.0
    for seen, wanted in zip(observed[order], expected[order]):
        if wanted >= MIN_EXPECTED:
            cells_observed.append(seen)
            cells_expected.append(wanted)
            continue
        pool_observed, pool_expected = pool_observed + seen, pool_expected + wanted
        if pool_expected >= MIN_EXPECTED:
            cells_observed.append(pool_observed)
            cells_expected.append(pool_expected)
            pool_observed = pool_expected = 0.0
    if pool_observed or pool_expected:  # the rest, too little for a cell: into the smallest cell
        if cells_expected and pool_expected < MIN_EXPECTED:
            smallest = int(np.argmin(cells_expected))
            cells_observed[smallest] += pool_observed
            cells_expected[smallest] += pool_expected
        else:
            cells_observed.append(pool_observed)
            cells_expected.append(max(pool_expected, 1e-300))
    seen, wanted = np.array(cells_observed), np.array(cells_expected)
    statistic = float(((seen - wanted) ** 2 / wanted).sum())
    dof = len(seen) - 1
    return chi2_survival(statistic, dof), dof


# -- scenes

def world_from(translate=(0.0, HEIGHT, 0.0), rotate_x=-90.0, scale=(1.0, 1.0, 1.0)) -> np.ndarray:
    """(4, 4) translate · rotateX · scale; rotateX −90° turns the light's −Z down."""
    c, s = math.cos(math.radians(rotate_x)), math.sin(math.radians(rotate_x))
    matrix = np.eye(4)
    matrix[:3, :3] = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ np.diag(scale)
    matrix[:3, 3] = translate
    return matrix


def light(kind: str, name: str | None = None, **fields) -> Light:
    name = name or kind
    fields.setdefault("world_from_light", world_from())
    fields.setdefault("radiance", np.ones(3))
    return Light(name, f"/{name}", kind, **fields)


def ies_profile() -> IesProfile:
    """A lopsided profile: bright straight down, dim sideways, brighter at φ = 90° than 270°."""
    vertical = np.radians([0.0, 30.0, 60.0, 90.0, 120.0, 180.0])
    horizontal = np.radians([0.0, 90.0, 180.0, 270.0, 360.0])
    candela = np.outer([1.0, 2.5, 1.0, 0.4, 1.0], [10.0, 8.0, 4.0, 1.0, 0.2, 0.1])
    return IesProfile("lopsided.ies", vertical, horizontal, candela, power=3.0)


def box(name: str, center, half, material: int) -> Mesh:
    """An axis-aligned box's 12 outward triangles."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
    points = (np.asarray(center) + corners * np.asarray(half)).astype(np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    triangles = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], np.int32)
    return Mesh(name, f"/{name}", points, triangles, None, None, None, np.full(len(triangles), material, np.int32))


def quad(name: str, corners, material: int) -> Mesh:
    points = np.asarray(corners, np.float32)
    triangles = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return Mesh(name, f"/{name}", points, triangles, None, None, None, np.full(2, material, np.int32))


def gradient_image(height: int, width: int, seed: int) -> np.ndarray:
    """(height, width, 3) float32: a smooth ramp with a hot spot and random texels."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    hot = 40.0 * np.exp(-((x - 0.3) ** 2 + (y - 0.35) ** 2) / 0.01)
    base = 0.2 + x + 0.5 * y + hot + rng.uniform(0, 0.5, (height, width))
    return np.stack([base, 0.5 * base, 0.25 * base + 0.1], axis=-1).astype(np.float32)


@dataclass
class Frame:
    """A scene's tracer tables, as a render builds them."""

    scene: SceneData
    world: World
    geometry: GeometryArrays
    materials: MaterialTable
    sampler: LightSampler
    caster: RayCaster

    @classmethod
    def of(cls, lights=(), meshes=(), materials=(), images=()) -> Frame:
        scene = SceneData("chi2", 0.0, tuple(meshes), tuple(materials), tuple(lights),
                          tuple(TextureImage(f"image{i}.exr", image) for i, image in enumerate(images)))
        world = build_world(scene)
        geometry = geometry_arrays(world)
        table = MaterialTable(scene, world.primvar_columns)
        return cls(scene, world, geometry, table, LightSampler(scene, world, table, geometry), RayCaster(world))

    @property
    def lights(self) -> light_kernels.LightArrays:
        return self.sampler.arrays


# -- drawing samples and integrating pdfs through the kernels

@kernel
def _draw_kernel(lights, geometry, materials, point, uniforms, registers, inputs, radiance, direction_out,
                 distance_out, radiance_out, pdf_out, light_out, triangle_out):
    for k in range(len(uniforms)):
        dx, dy, dz, distance, r, g, b, pdf, light, triangle = light_kernels.sample(
            lights, geometry, materials, 0, point[0], point[1], point[2], uniforms[k, 0], uniforms[k, 1],
            uniforms[k, 2], uniforms[k, 3], registers, inputs, radiance)
        direction_out[k, 0], direction_out[k, 1], direction_out[k, 2] = dx, dy, dz
        radiance_out[k, 0], radiance_out[k, 1], radiance_out[k, 2] = r, g, b
        distance_out[k], pdf_out[k], light_out[k], triangle_out[k] = distance, pdf, light, triangle


@dataclass
class Draws:
    """Light samples from a point: direction (n, 3) unit, distance (n,) metres, radiance (n, 3)
    (irradiance over the probability for delta lights), pdf (n,) 1/sr, light (n,) and
    triangle (n,) indices."""

    direction: np.ndarray
    distance: np.ndarray
    radiance: np.ndarray
    pdf: np.ndarray
    light: np.ndarray
    triangle: np.ndarray


def draw(frame: Frame, point=SHADING_POINT, count=SAMPLES, seed=SEED) -> Draws:
    uniforms = np.random.default_rng(seed).random((count, 4))
    out = Draws(np.empty((count, 3)), np.empty(count), np.empty((count, 3)), np.empty(count),
                np.empty(count, np.int64), np.empty(count, np.int64))
    _draw_kernel(frame.lights, frame.geometry, frame.materials.arrays, np.asarray(point, np.float64), uniforms,
                 scratch(shading.REGISTERS, 4), scratch(shading.MATERIAL_FIELDS), scratch(3), out.direction,
                 out.distance, out.radiance, out.pdf, out.light, out.triangle)
    return out


@kernel
def _hit_pdf_kernel(lights, geometry, direction, triangle, bary_u, bary_v, distance, out):
    """out += the emitter density of each hit (triangle −1: none)."""
    normal = geometry.geometric_normal
    for k in range(len(triangle)):
        tri = triangle[k]
        if tri < 0:
            continue
        dx, dy, dz = direction[k, 0], direction[k, 1], direction[k, 2]
        cos_light = -(normal[tri, 0] * dx + normal[tri, 1] * dy + normal[tri, 2] * dz)
        out[k] += light_kernels.emitter_pdf(lights, geometry, 0, tri, bary_u[k], bary_v[k], dx, dy, dz, distance[k],
                                            cos_light)


@kernel
def _sky_pdf_kernel(lights, direction, out):
    """out += the densities the escaped stage gives domes and distant cones."""
    for k in range(len(direction)):
        x, y, z = direction[k, 0], direction[k, 1], direction[k, 2]
        for dome in range(len(lights.dome_light)):
            out[k] += lights.dome_probability[0, dome] * light_kernels.dome_pdf(lights, dome, x, y, z)
        for item in range(len(lights.distant_light)):
            cos_max = lights.distant_cos_max[item]
            axis = lights.distant_direction[item]
            if cos_max < 1.0 and x * axis[0] + y * axis[1] + z * axis[2] >= cos_max:
                out[k] += light_kernels.cone_pdf(lights.distant_probability[0, item], cos_max)


def direction_pdf(frame: Frame, directions: np.ndarray, point=SHADING_POINT) -> np.ndarray:
    """Light sampling's density (n,) 1/sr of unit `directions` (n, 3) from `point`: the
    skies' plus the emitter density at the ray's first hit, as MIS takes them."""
    out = np.zeros(len(directions))
    _sky_pdf_kernel(frame.lights, directions, out)
    origin = np.tile(np.asarray(point, np.float32), (len(directions), 1))
    triangle, _, u, v, t = frame.caster.intersect(origin, directions, np.full(len(directions), np.inf, np.float32))
    _hit_pdf_kernel(frame.lights, frame.geometry, directions, triangle.astype(np.int64), u.astype(np.float64),
                    v.astype(np.float64), t.astype(np.float64), out)
    return out


@dataclass
class Grid:
    """ROWS × COLUMNS bins over the cap cos θ ≥ z_min about unit `axis` (θ from it, φ about it)."""

    axis: np.ndarray
    z_min: float

    def __post_init__(self):
        self.axis = np.asarray(self.axis, np.float64) / np.linalg.norm(self.axis)
        helper = np.array([1.0, 0.0, 0.0]) if abs(self.axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        self.tangent = np.cross(self.axis, helper)
        self.tangent /= np.linalg.norm(self.tangent)
        self.bitangent = np.cross(self.axis, self.tangent)

    def bins(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(bin index (n,) row-major, inside (n,) bool) of unit directions (n, 3)."""
        z = directions @ self.axis
        phi = np.arctan2(directions @ self.bitangent, directions @ self.tangent) % (2 * np.pi)
        row = np.clip(((z - self.z_min) / (1 - self.z_min) * ROWS).astype(np.int64), 0, ROWS - 1)
        column = np.clip((phi / (2 * np.pi) * COLUMNS).astype(np.int64), 0, COLUMNS - 1)
        return row * COLUMNS + column, z >= self.z_min

    def sub_directions(self, bins: np.ndarray, subdivisions: int) -> tuple[np.ndarray, float]:
        """(directions (len(bins)·subdivisions², 3) at the centres of the sub-cells of
        `bins` (row-major indices), bin-major; the sub-cells' solid angle, sr)."""
        z_step, phi_step = (1 - self.z_min) / (ROWS * subdivisions), 2 * np.pi / (COLUMNS * subdivisions)
        within = (np.arange(subdivisions) + 0.5)
        z = self.z_min + ((bins // COLUMNS)[:, None, None] * subdivisions + within[None, :, None]) * z_step
        phi = ((bins % COLUMNS)[:, None, None] * subdivisions + within[None, None, :]) * phi_step
        z, phi = (np.broadcast_to(a, (len(bins), subdivisions, subdivisions)).reshape(-1) for a in (z, phi))
        radius = np.sqrt(np.maximum(1 - z * z, 0))
        directions = (radius[:, None] * (np.cos(phi)[:, None] * self.tangent + np.sin(phi)[:, None] * self.bitangent)
                      + z[:, None] * self.axis)
        return directions, z_step * phi_step

    def integrals(self, pdf) -> np.ndarray:
        """∫ pdf dω (ROWS·COLUMNS,) over each bin, for pdf(directions (n, 3)) -> (n,): the
        midpoint rule on a SUBDIVISIONS² sub-grid, REFINED_SUBDIVISIONS² where it varies."""
        bins = np.arange(ROWS * COLUMNS)
        directions, solid_angle = self.sub_directions(bins, SUBDIVISIONS)
        values = pdf(directions).reshape(len(bins), -1)
        out = values.sum(axis=1) * solid_angle
        # refine where the pdf varies, and next to its support: a sliver of it can fall
        # between the coarse sub-cells' centres
        varies = values.max(axis=1) > UNEVEN * values.min(axis=1)
        support = (values.max(axis=1) > 0).reshape(ROWS, COLUMNS)
        near = support.copy()
        for axis in (0, 1):
            for shift in (-1, 1):
                near |= np.roll(support, shift, axis=axis) if axis == 1 else _shifted_rows(support, shift)
        uneven = np.flatnonzero(varies | (near.reshape(-1) & ~support.reshape(-1)))
        if len(uneven):
            directions, solid_angle = self.sub_directions(uneven, REFINED_SUBDIVISIONS)
            out[uneven] = pdf(directions).reshape(len(uneven), -1).sum(axis=1) * solid_angle
        return out


def _shifted_rows(table: np.ndarray, shift: int) -> np.ndarray:
    """`table` (rows, columns) moved `shift` rows down (no wrap: rows are cos θ bands)."""
    out = np.zeros_like(table)
    if shift > 0:
        out[shift:] = table[:-shift]
    else:
        out[:shift] = table[-shift:]
    return out


def direction_fit(frame: Frame, grid: Grid) -> tuple[float, float, int]:
    """(p-value, ∫ pdf over the grid's cap, degrees of freedom) of the frame's light
    sampling from SHADING_POINT against its direction_pdf, on `grid`. Every sample must
    have a density and fall inside the cap."""
    draws = draw(frame)
    assert (draws.pdf > 0).all() and np.isfinite(draws.pdf).all()
    index, inside = grid.bins(draws.direction)
    assert inside.all(), f"{(~inside).sum()} samples outside the cap"
    observed = np.bincount(index, minlength=ROWS * COLUMNS).astype(np.float64)
    expected = grid.integrals(lambda directions: direction_pdf(frame, directions))
    p_value, dof = pearson_p_value(observed, expected * len(draws.pdf))
    return p_value, float(expected.sum()), dof


def barycentrics(corners: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(u, v) (n,) of `points` (n, 3) on triangles with `corners` (n, 3 corners, 3):
    p = (1 − u − v) c0 + u c1 + v c2, by least squares in the triangle's plane."""
    e1, e2, w = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0], points - corners[:, 0]
    a, b, c = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
    d, e = (e1 * w).sum(1), (e2 * w).sum(1)
    determinant = a * c - b * b
    return (c * d - b * e) / determinant, (a * e - b * d) / determinant


def sub_triangle(rank: np.ndarray, u: np.ndarray, v: np.ndarray, k: int) -> np.ndarray:
    """The cell (n,) of barycentrics (u, v) among k² equal sub-triangles of their
    triangle's `rank` (n,): ((rank · k + i) · k + j) · 2 + upper, for the k × k cells of
    (u, v) and the upper half of a cell (fractions summing to 1 or more)."""
    i = np.clip(np.floor(u * k), 0, k - 1).astype(np.int64)
    j = np.clip(np.floor(v * k), 0, k - 1).astype(np.int64)
    upper = (u * k - i) + (v * k - j) >= 1
    return ((rank * k + i) * k + j) * 2 + upper


def area_fit(frame: Frame) -> tuple[float, float, int]:
    """(p-value, total probability, degrees of freedom) of the frame's area sampling from
    SHADING_POINT, binned on its triangles cut into k² equal sub-triangles each, against
    the pdf kernel turned back to area density at the sub-triangles' centres."""
    lights = frame.lights
    emitters = lights.emitter_triangles.astype(np.int64)
    rank = np.full(frame.world.triangle_count, -1, np.int64)
    rank[emitters] = np.arange(len(emitters))
    k = max(1, round(math.sqrt(AREA_CELLS / len(emitters))))
    corners = frame.geometry.corner_positions.astype(np.float64)  # (t, 3 corners, 3)

    draws = draw(frame)
    assert (draws.pdf > 0).all() and np.isfinite(draws.pdf).all()
    assert (rank[draws.triangle] >= 0).all()
    points = SHADING_POINT + draws.direction * draws.distance[:, None]
    u, v = barycentrics(corners[draws.triangle], points)
    observed = np.bincount(sub_triangle(rank[draws.triangle], u, v, k), minlength=len(emitters) * k * k * 2)

    # every sub-triangle's centre: lower halves at (i + ⅓, j + ⅓) / k, upper at (i + ⅔, j + ⅔) / k
    i, j = (a.reshape(-1) for a in np.meshgrid(np.arange(k), np.arange(k), indexing="ij"))
    lower, upper = i + j <= k - 1, i + j <= k - 2
    centre_u = np.concatenate([(i[lower] + 1 / 3) / k, (i[upper] + 2 / 3) / k])
    centre_v = np.concatenate([(j[lower] + 1 / 3) / k, (j[upper] + 2 / 3) / k])
    triangle = np.repeat(emitters, len(centre_u))
    centre_u, centre_v = np.tile(centre_u, len(emitters)), np.tile(centre_v, len(emitters))
    c = corners[triangle]
    centre = (1 - centre_u - centre_v)[:, None] * c[:, 0] + centre_u[:, None] * c[:, 1] + centre_v[:, None] * c[:, 2]
    toward = centre - SHADING_POINT
    distance = np.linalg.norm(toward, axis=1)
    direction = toward / distance[:, None]
    density = np.zeros(len(triangle))
    _hit_pdf_kernel(lights, frame.geometry, direction, triangle, centre_u, centre_v, distance, density)
    cos_light = np.einsum("ki,ki->k", direction, frame.geometry.geometric_normal[triangle].astype(np.float64))
    # solid angle → area: |cos| / distance²; each sub-triangle has 1/k² of its triangle's area
    probability = density * np.abs(cos_light) / distance**2 * frame.geometry.area[triangle] / k**2
    expected = np.bincount(sub_triangle(rank[triangle], centre_u, centre_v, k), weights=probability,
                           minlength=len(observed))
    p_value, dof = pearson_p_value(observed.astype(np.float64), expected * len(draws.pdf))
    return p_value, float(expected.sum()), dof


def cap_about(frame: Frame, point=SHADING_POINT, margin=1.05) -> Grid:
    """The grid about the direction from `point` toward the centre of the world's triangles,
    wide enough (× margin) for all of them."""
    vertices = frame.world.vertices.astype(np.float64) - np.asarray(point)
    axis = vertices.mean(axis=0)
    axis /= np.linalg.norm(axis)
    cosines = vertices @ axis / np.linalg.norm(vertices, axis=1)
    widest = min(math.acos(np.clip(cosines.min(), -1, 1)) * margin, math.pi)
    return Grid(axis, math.cos(widest))


def assert_fits(fit: tuple[float, float, int], integral_tolerance: float) -> None:
    """A (p-value, ∫ pdf, degrees of freedom) fit passes: the pdf integrates to 1, and
    enough cells give a p-value above SIGNIFICANCE."""
    p_value, integral, dof = fit
    assert integral == pytest.approx(1.0, abs=integral_tolerance), "the pdf does not integrate to 1"
    assert dof > 100, "too few cells for a meaningful test"
    assert_p_value(p_value, dof)


def assert_p_value(p_value: float, dof: int) -> None:
    log.info("chi2 p-value %.4f (%d degrees of freedom)", p_value, dof)
    assert p_value > SIGNIFICANCE, f"χ² p-value {p_value:.3g} ({dof} degrees of freedom)"


# -- lights sampled by area: area lights, ellipsoids, emissive surfaces

SPOT = LightShaping(cone_angle=50.0, cone_softness=0.3, ies=ies_profile())
SQUASHED = world_from(scale=(1.0, 0.5, 1.6))  # a sphere light's ellipsoid: too far from round for its cone
AREA_CASES = {
    "rect": dict(kind="rect", width=1.0, height=0.6),
    "rect with a colour map": dict(kind="rect", width=1.0, height=0.6, texture=0),
    "disk": dict(kind="disk", radius=0.4),
    "spot (disk with a cone and an IES profile)": dict(kind="disk", radius=0.4, shaping=SPOT),
    "cylinder": dict(kind="cylinder", radius=0.2, length=1.0, world_from_light=world_from(rotate_x=-60.0)),
    "ellipsoid": dict(kind="sphere", radius=0.3, world_from_light=SQUASHED),
    "ellipsoid with an IES profile": dict(kind="sphere", radius=0.3, shaping=SPOT, world_from_light=SQUASHED),
    # found by light sampling alone, so it must cover the whole shape, not the inner cone
    "sphere with a restricted shadow link": dict(kind="sphere", radius=0.3, shadow_link=()),
}


@pytest.mark.parametrize("case", AREA_CASES)
def test_area_light_sampling_fits_its_pdf(case):
    fields = AREA_CASES[case]
    frame = Frame.of([light(**fields)], images=[gradient_image(8, 8, seed=1)] if "texture" in fields else [])
    assert frame.lights.light_sphere[0] == -1, "sampled by area"
    assert_fits(area_fit(frame), integral_tolerance=1e-6)


def test_emissive_surfaces_sampling_fits_its_pdf():
    """Two-sided emissive meshes of different radiance (a box and a tilted quad): their
    triangles are picked by power, both faces of each."""
    materials = [Material("bright", "/bright", emissive_color=(4.0, 3.0, 2.0)),
                 Material("dim", "/dim", emissive_color=(0.5, 0.5, 0.5))]
    meshes = [box("box", (0.2, HEIGHT, 0.1), (0.3, 0.2, 0.25), 0),
              quad("panel", [(-0.8, 1.5, -0.2), (-0.3, 1.7, -0.2), (-0.3, 2.1, 0.4), (-0.8, 1.9, 0.4)], 1)]
    frame = Frame.of(meshes=meshes, materials=materials)
    assert len(frame.lights.emitter_triangles) == 14
    assert_fits(area_fit(frame), integral_tolerance=1e-6)


# -- sphere lights by solid angle

@pytest.mark.parametrize("shaping", [None, SPOT], ids=["plain", "with an IES profile"])
def test_sphere_light_sampling_fits_its_solid_angle_pdf(shaping):
    """A uniform cone toward the sphere: on a grid whose cap is the cone, every bin expects
    the same count."""
    frame = Frame.of([light("sphere", radius=0.3, shaping=shaping)])
    arrays = frame.lights
    assert arrays.light_sphere[0] == 0
    toward = arrays.sphere_center[0] - SHADING_POINT
    distance = np.linalg.norm(toward)
    cone = Grid(toward, math.sqrt(1 - (arrays.sphere_inner_radius[0] / distance) ** 2))
    assert_fits(direction_fit(frame, cone), integral_tolerance=1e-3)


def test_sphere_samples_reach_the_spheres_front_and_no_shadow_ray_hits_its_own_shape():
    """What keeps solid-angle sampling and BSDF hits on one emitter: every sampled direction
    meets the tessellated sphere on a triangle facing the point, and the sample's point lies
    beyond none of it (the shadow ray ends before the shape)."""
    frame = Frame.of([light("sphere", radius=0.3)])
    draws = draw(frame, count=20_000)
    origins = np.tile(SHADING_POINT.astype(np.float32), (len(draws.pdf), 1))
    direction = draws.direction.astype(np.float32)
    triangle, _, _, _, t = frame.caster.intersect(origins, direction, np.full(len(draws.pdf), np.inf, np.float32))
    assert (triangle >= 0).all()
    facing = np.einsum("ki,ik->k", draws.direction, frame.world.geometric_normal[:, triangle])
    assert (facing < 0).all()
    assert (draws.distance * SHADOW_SPAN < t).all()
    assert not frame.caster.occluded(origins, direction, (draws.distance * SHADOW_SPAN).astype(np.float32)).any()


def test_no_sphere_sample_from_inside_and_no_density_there():
    """From inside the sphere (an outward emitter sends nothing there) light sampling gives
    no sample and BSDF rays hitting it get density 0 (MIS weight 1)."""
    frame = Frame.of([light("sphere", radius=0.3)])
    inside = np.array([0.05, HEIGHT - 0.1, 0.0])
    draws = draw(frame, point=inside, count=1000)
    assert (draws.pdf == 0).all()
    directions = np.random.default_rng(3).normal(size=(1000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    assert (direction_pdf(frame, directions, point=inside) == 0).all()


# -- skies: distant cones, domes; and a mixture of sources

def test_distant_cone_sampling_fits_its_pdf():
    frame = Frame.of([light("distant", angle=12.0, world_from_light=world_from(rotate_x=-70.0))])
    axis = frame.lights.distant_direction[0]
    assert_fits(direction_fit(frame, Grid(axis, frame.lights.distant_cos_max[0])), integral_tolerance=1e-3)


@pytest.mark.parametrize("channels", [0, 3, 1], ids=["constant", "textured", "grey texture"])
def test_dome_sampling_fits_its_pdf(channels):
    tilted = world_from(translate=(0, 0, 0), rotate_x=25.0)
    images = [gradient_image(32, 64, seed=2)[..., :channels]] if channels else []
    frame = Frame.of([light("dome", world_from_light=tilted, texture=0 if channels else None)], images=images)
    assert_fits(direction_fit(frame, Grid((0.0, 1.0, 0.0), -1.0)), integral_tolerance=1e-3)


def test_a_mixture_of_sources_fits_the_sum_of_their_pdfs():
    """Source selection and each source's sampling together: a rect, a sphere, a distant
    cone and a textured dome, over the whole sphere of directions."""
    lights = [light("rect", width=1.0, height=0.6, world_from_light=world_from(translate=(-1.0, HEIGHT, 0.0))),
              light("sphere", radius=0.3, world_from_light=world_from(translate=(1.2, HEIGHT, 0.5))),
              light("distant", angle=20.0, world_from_light=world_from(rotate_x=-50.0), radiance=np.full(3, 0.3)),
              light("dome", world_from_light=world_from(translate=(0, 0, 0), rotate_x=0.0), texture=0,
                    radiance=np.full(3, 0.02))]
    frame = Frame.of(lights, images=[gradient_image(32, 64, seed=4)])
    probability = np.diff(frame.lights.source_cdf[0], prepend=0.0)
    assert len(probability) == 4 and probability.min() > 0.03
    assert_fits(direction_fit(frame, Grid((0.0, 1.0, 0.0), -1.0)), integral_tolerance=1e-3)


# -- delta lights: selection, a line's samples along it, a point's one direction

def test_source_selection_fits_the_source_probabilities():
    """Points (one dimmed by an IES profile), a line, a delta distant light and a rect: the
    light each sample picked against the source probabilities."""
    dim = LightShaping(ies=IesProfile("flat.ies", np.radians([0.0, 180.0]), np.radians([0.0, 360.0]),
                                      np.full((2, 2), 0.2), 0.2))
    lights = [light("point", "bright", radius=0.05, world_from_light=world_from(translate=(-1, HEIGHT, 0))),
              light("point", "dim", radius=0.05, shaping=dim, world_from_light=world_from(translate=(1, HEIGHT, 0))),
              light("line", radius=0.02, length=1.5, world_from_light=world_from(translate=(0, HEIGHT, 1))),
              light("distant", angle=0.0, radiance=np.full(3, 0.05)),
              light("rect", width=0.5, height=0.5, world_from_light=world_from(translate=(0, HEIGHT, -1)))]
    frame = Frame.of(lights)
    arrays = frame.lights
    probability = np.diff(arrays.source_cdf[0], prepend=0.0)
    kind, item = arrays.source_kind, arrays.source_item
    tables = {POINT: arrays.point_light, DISTANT: arrays.distant_light}
    source_light = np.array([tables[k][i] if k in tables else 4 for k, i in zip(kind, item)])  # AREA: the rect
    expected = np.zeros(len(lights))
    np.add.at(expected, source_light, probability * SAMPLES)
    observed = np.bincount(draw(frame).light, minlength=len(lights)).astype(np.float64)
    assert expected.min() > 100
    assert_p_value(*pearson_p_value(observed, expected))


def test_line_samples_fit_a_uniform_density_along_the_segment():
    """A line light samples its segment uniformly: the samples' positions along it, in 50
    bins, against 1/50 each."""
    line = light("line", radius=0.02, length=1.5, world_from_light=world_from(rotate_x=-60.0))
    frame = Frame.of([line])
    draws = draw(frame)
    center, segment = frame.lights.point_center[0], frame.lights.point_segment[0]
    position = SHADING_POINT + draws.direction * draws.distance[:, None]
    along = (position - center) @ segment / (segment @ segment) + 0.5
    assert np.allclose(np.linalg.norm(np.cross(position - center, segment), axis=1), 0, atol=1e-9)
    observed = np.bincount(np.clip((along * 50).astype(int), 0, 49), minlength=50).astype(np.float64)
    assert np.isinf(draws.pdf).all()
    assert_p_value(*pearson_p_value(observed, np.full(50, SAMPLES / 50)))


def test_point_and_delta_distant_lights_give_their_one_direction():
    """Delta lights have no density to test: every sample is their direction, with pdf inf
    and the irradiance at normal incidence (L·π r² / d² for a point, L for a distant light)."""
    center = np.array([0.5, 1.5, 0.0])
    point = light("point", radius=0.05, radiance=np.full(3, 2.0), world_from_light=world_from(translate=center))
    frame = Frame.of([point])
    draws = draw(frame, count=100)
    toward = center - SHADING_POINT
    distance = np.linalg.norm(toward)
    np.testing.assert_allclose(draws.direction, np.tile(toward / distance, (100, 1)), atol=1e-12)
    np.testing.assert_allclose(draws.radiance, 2.0 * math.pi * 0.05**2 / distance**2, rtol=1e-12)
    assert np.isinf(draws.pdf).all()

    sun = Frame.of([light("distant", angle=0.0, radiance=np.full(3, 3.0), world_from_light=world_from(rotate_x=-60.0))])
    draws = draw(sun, count=100)
    np.testing.assert_allclose(draws.direction, np.tile(sun.lights.distant_direction[0], (100, 1)), atol=1e-12)
    np.testing.assert_allclose(draws.radiance, 3.0, rtol=1e-6)
    assert np.isinf(draws.pdf).all()
