"""The UsdLux reference integrator (usdlux_reference.py) against closed forms.

Smooth cases must agree to ~1e-9 (the quadrature is spectrally accurate there; attributes
are float32, so exact values are computed from what the prim holds); cases whose integrand
jumps (a shadow's edge) state their own tolerance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux

import usdlux_reference as ref

UP = np.array([[0.0, 0.0, 1.0]])
ORIGIN = np.zeros((1, 3))


def new_stage(meters_per_unit: float = 1.0) -> Usd.Stage:
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageMetersPerUnit(stage, meters_per_unit)
    return stage


def place(light, translate=(0.0, 0.0, 0.0), rotate=(0.0, 0.0, 0.0), scale=None):
    xform = UsdGeom.Xformable(light)
    xform.AddTranslateOp().Set(Gf.Vec3d(*translate))
    xform.AddRotateXYZOp().Set(Gf.Vec3f(*rotate))
    if scale is not None:
        xform.AddScaleOp().Set(Gf.Vec3f(*scale))
    return light


def f32(value: float) -> float:
    """What a float attribute holds."""
    return float(np.float32(value))


def E(light, points=ORIGIN, normals=UP, **kwargs) -> np.ndarray:
    return ref.irradiance(ref.read_light(light.GetPrim()), points, normals, **kwargs)


def rect_form_factor(x: float, y: float) -> float:
    """Differential area to a parallel x × y rectangle (units of its height) with a corner
    above it."""
    a, b = math.hypot(1, x), math.hypot(1, y)
    return (x / a * math.atan(y / a) + y / b * math.atan(x / b)) / (2 * math.pi)


def lambert_contour(contour: np.ndarray, point: np.ndarray, normal: np.ndarray) -> float:
    """E / L of a Lambertian emitter bounded by the closed polyline ``contour`` (k, 3), by
    Lambert's contour formula: ½ Σ γᵢ n·nᵢ over its edges (an independent method: a line
    integral, not an area one)."""
    r = contour - point
    following = np.roll(r, -1, axis=0)
    cross = np.cross(r, following)
    angle = np.arctan2(np.linalg.norm(cross, axis=1), np.einsum("ij,ij->i", r, following))
    unit = cross / np.linalg.norm(cross, axis=1, keepdims=True)
    return 0.5 * abs(float(angle @ (unit @ normal)))


# -- shapes ---------------------------------------------------------------------------------


@pytest.mark.parametrize("meters_per_unit", [1.0, 0.01])
def test_disk_on_its_axis(meters_per_unit):
    stage = new_stage(meters_per_unit)
    disk = place(UsdLux.DiskLight.Define(stage, "/disk"), translate=(0, 0, 150), scale=(2, 2, 2))
    disk.CreateRadiusAttr(40.0)
    disk.CreateIntensityAttr(3.0)
    # the disk faces down (−Z) onto the origin, 1.5 m (or units) away with radius 0.8
    r, h = 80.0, 150.0
    expected = math.pi * 3.0 * r * r / (r * r + h * h)
    points = ORIGIN * meters_per_unit
    assert E(disk, points) == pytest.approx(np.full((1, 3), expected), rel=1e-12)


def test_rect_on_the_axis_of_its_centre():
    stage = new_stage()
    rect = place(UsdLux.RectLight.Define(stage, "/rect"), translate=(0.3, -0.2, 1.7), rotate=(0, 0, 30))
    rect.CreateWidthAttr(2.0)
    rect.CreateHeightAttr(0.7)
    point = np.array([[0.3, -0.2, 0.0]])
    expected = 4 * math.pi * rect_form_factor(1.0 / 1.7, f32(0.35) / 1.7)
    assert E(rect, point)[0] == pytest.approx(np.full(3, expected), rel=1e-9)


def test_rect_and_disk_emit_from_their_minus_z_side_only():
    stage = new_stage()
    rect = place(UsdLux.RectLight.Define(stage, "/rect"), translate=(0, 0, -1))  # emits away, to −Z
    disk = place(UsdLux.DiskLight.Define(stage, "/disk"), translate=(0, 0, 1), rotate=(180, 0, 0))
    assert E(rect, normals=-UP).max() == 0.0
    assert E(disk).max() == 0.0


def test_sphere_fully_visible_off_axis():
    stage = new_stage()
    sphere = place(UsdLux.SphereLight.Define(stage, "/sphere"), translate=(0.8, 0.4, 1.5), scale=(1.5, 1.5, 1.5))
    sphere.CreateRadiusAttr(0.2)
    sphere.CreateIntensityAttr(2.0)
    r, centre = 1.5 * f32(0.2), np.array([0.8, 0.4, 1.5])
    d = np.linalg.norm(centre)
    expected = math.pi * 2.0 * (r / d) ** 2 * centre[2] / d
    assert E(sphere)[0] == pytest.approx(np.full(3, expected), rel=1e-9)


def test_cylinder_side_against_lamberts_contour_integral():
    stage = new_stage()
    cylinder = place(UsdLux.CylinderLight.Define(stage, "/cylinder"), translate=(0.2, 0.1, 1.0), rotate=(0, 0, 25))
    cylinder.CreateRadiusAttr(0.125)
    cylinder.CreateLengthAttr(1.5)
    light = ref.read_light(cylinder.GetPrim())
    # The band it shows the origin: azimuths φ0 ± acos(r/ρ) about its axis (local X), whose
    # outline is the two visible end arcs joined by the two tangent generators.
    local = np.linalg.solve(light.linear, -light.origin)
    rho, phi0 = math.hypot(local[1], local[2]), math.atan2(local[2], local[1])
    phi = np.linspace(phi0 - math.acos(light.radius / rho), phi0 + math.acos(light.radius / rho), 20001)
    ends = [np.stack([np.full_like(phi, x), light.radius * np.cos(phi), light.radius * np.sin(phi)], axis=-1)
            for x in (light.length / 2, -light.length / 2)]
    contour = light.origin + np.concatenate([ends[0], ends[1][::-1]]) @ light.linear.T
    expected = lambert_contour(contour, ORIGIN[0], UP[0])
    assert ref.irradiance(light, ORIGIN, UP)[0] == pytest.approx(np.full(3, expected), rel=1e-8)


def test_point_inside_a_sphere_or_cylinder_receives_nothing():
    stage = new_stage()
    sphere = UsdLux.SphereLight.Define(stage, "/sphere")
    cylinder = UsdLux.CylinderLight.Define(stage, "/cylinder")
    inside = np.array([[0.1, 0.1, 0.1]])
    assert E(sphere, inside).max() == 0.0
    assert E(cylinder, inside).max() == 0.0


@pytest.mark.parametrize("angle", [0.0, 1.0, 40.0, 170.0])
def test_distant_light_facing_and_tilted(angle):
    stage = new_stage()
    distant = place(UsdLux.DistantLight.Define(stage, "/sun"), rotate=(-30, 0, 0))  # arrives from +Z tilted 30°
    distant.CreateAngleAttr(angle)
    distant.CreateIntensityAttr(2.0)
    theta_max = math.radians(f32(angle)) / 2
    facing = 2.0 if angle == 0 else math.pi * 2.0 * math.sin(theta_max) ** 2
    toward = np.array([[0.0, math.sin(math.radians(30)), math.cos(math.radians(30))]])
    assert E(distant, normals=toward)[0] == pytest.approx(np.full(3, facing), rel=1e-12)
    if angle < 120:  # the whole cone is above the horizon of the z-up plane
        assert E(distant)[0] == pytest.approx(np.full(3, facing * math.cos(math.radians(30))), rel=1e-12)


# -- emission -------------------------------------------------------------------------------


def test_intensity_exposure_colour_and_diffuse_multiply():
    stage = new_stage()
    disk = place(UsdLux.DiskLight.Define(stage, "/disk"), translate=(0, 0, 1))
    plain = E(disk)
    disk.CreateIntensityAttr(3.0)
    disk.CreateExposureAttr(-1.5)
    disk.CreateColorAttr(Gf.Vec3f(0.25, 0.5, 1.0))
    disk.CreateDiffuseAttr(0.75)
    disk.CreateSpecularAttr(0.1)  # no effect on a Lambertian receiver
    scale = 3.0 * 2.0**-1.5 * 0.75 * np.array([0.25, 0.5, 1.0])
    assert E(disk) == pytest.approx(plain * scale, rel=1e-12)


def test_colour_temperature_is_the_planckian_locus_of_unit_rec709_luminance():
    luminance = np.array([0.2126, 0.7152, 0.0722])
    for kelvin in (2000.0, 6500.0, 11000.0):
        assert ref.blackbody(kelvin) @ luminance == pytest.approx(1.0, abs=2e-4)
    warm, cool = ref.blackbody(2000.0), ref.blackbody(11000.0)
    assert warm[0] > warm[1] > warm[2] and cool[2] > cool[1] > cool[0]
    stage = new_stage()
    disk = place(UsdLux.DiskLight.Define(stage, "/disk"), translate=(0, 0, 1))
    plain = E(disk)
    disk.CreateEnableColorTemperatureAttr(True)
    disk.CreateColorTemperatureAttr(2000.0)
    assert E(disk) == pytest.approx(plain * warm, rel=1e-12)


@pytest.mark.parametrize("kind", ["rect", "disk", "sphere", "cylinder"])
def test_normalize_divides_by_the_world_area_so_power_is_kept(kind):
    stage = new_stage(0.5)  # the area is in stage units
    schema = {"rect": UsdLux.RectLight, "disk": UsdLux.DiskLight, "sphere": UsdLux.SphereLight,
              "cylinder": UsdLux.CylinderLight}[kind]
    small = place(schema.Define(stage, "/small"), translate=(0, 0, 400), scale=(1.0, 1.0, 1.0))
    large = place(schema.Define(stage, "/large"), translate=(0, 0, 400), scale=(2.0, 2.0, 2.0))
    for light in (small, large):
        light.CreateNormalizeAttr(True)
    read = ref.read_light(large.GetPrim())
    unit_area = {"rect": 1.0, "disk": math.pi * 0.25, "sphere": math.pi, "cylinder": math.pi}[kind]
    assert read.area == pytest.approx(4 * unit_area * 0.25, rel=1e-12)  # ×2 scale, 0.5 m units
    far = np.array([[0.0, 0.0, 0.0]])
    # Same power: the same irradiance far away (to O(r/d) for a cylinder, whose near side is nearer).
    assert E(large, far) == pytest.approx(E(small, far), rel=2e-3)
    large.CreateNormalizeAttr(False)
    assert E(large, far) == pytest.approx(E(small, far) * 4 * unit_area, rel=2e-3)


def test_normalized_ellipsoid_uses_the_spheroids_area():
    stage = new_stage()
    sphere = place(UsdLux.SphereLight.Define(stage, "/sphere"), scale=(1.0, 1.0, 3.0))
    sphere.CreateRadiusAttr(1.0)
    a, c = 1.0, 3.0  # prolate spheroid
    e = math.sqrt(1 - a * a / (c * c))
    assert ref.read_light(sphere.GetPrim()).area == pytest.approx(2 * math.pi * a * a * (1 + c / (a * e) * math.asin(e)),
                                                                  rel=1e-10)


@pytest.mark.parametrize("angle", [0.0, 20.0, 90.0, 179.0])
def test_normalized_distant_light_gives_its_intensity_facing_it(angle):
    stage = new_stage()
    distant = UsdLux.DistantLight.Define(stage, "/sun")
    distant.CreateAngleAttr(angle)
    distant.CreateIntensityAttr(4.0)
    distant.CreateNormalizeAttr(True)
    assert E(distant)[0] == pytest.approx(np.full(3, 4.0), rel=1e-12)


# -- shaping --------------------------------------------------------------------------------


def tiny_sphere(stage, path="/spot", radius=0.001, **shaping):
    """A 1 mm sphere light at the origin with ShapingAPI: seen from 1 m, one direction."""
    light = UsdLux.SphereLight.Define(stage, path)
    light.CreateRadiusAttr(radius)
    api = UsdLux.ShapingAPI.Apply(light.GetPrim())
    api.CreateShapingConeAngleAttr(shaping.get("cone", 180.0))
    api.CreateShapingConeSoftnessAttr(shaping.get("softness", 0.0))
    api.CreateShapingFocusAttr(shaping.get("focus", 0.0))
    api.CreateShapingFocusTintAttr(Gf.Vec3f(*shaping.get("tint", (0.0, 0.0, 0.0))))
    return light


def off_axis(theta_degrees: float):
    """A point 1 m from the origin at θ from −Z, facing the origin."""
    theta = math.radians(theta_degrees)
    point = np.array([[math.sin(theta), 0.0, -math.cos(theta)]])
    return point, -point


def test_hard_cone_cuts_exactly_at_its_angle():
    stage = new_stage()
    spot = tiny_sphere(stage, cone=30.0)
    free = tiny_sphere(stage, "/free")
    for theta in (0.0, 29.9):
        assert E(spot, *off_axis(theta)) == pytest.approx(E(free, *off_axis(theta)), rel=1e-12)
    assert E(spot, *off_axis(30.1)).max() == 0.0


def test_soft_cone_follows_the_smoothstep():
    stage = new_stage()
    spot = tiny_sphere(stage, cone=40.0, softness=0.5)  # ramp from 20° to 40°
    free = tiny_sphere(stage, "/free")
    x = 0.25  # 25°
    assert E(spot, *off_axis(25.0)) == pytest.approx(E(free, *off_axis(25.0)) * (1 - x * x * (3 - 2 * x)), rel=1e-4)
    assert E(spot, *off_axis(19.0)) == pytest.approx(E(free, *off_axis(19.0)), rel=1e-12)


def test_softness_is_clamped_to_one():
    stage = new_stage()
    over = tiny_sphere(stage, cone=40.0, softness=3.0)
    one = tiny_sphere(stage, "/one", cone=40.0, softness=1.0)
    assert E(over, *off_axis(17.0)) == pytest.approx(E(one, *off_axis(17.0)), rel=1e-12)


def test_focus_with_and_without_tint():
    stage = new_stage()
    tint = np.array([0.2, 0.5, 1.0])
    focus = tiny_sphere(stage, focus=3.0, tint=tuple(tint))
    free = tiny_sphere(stage, "/free")
    cos3 = math.cos(math.radians(50.0)) ** 3
    expected = E(free, *off_axis(50.0)) * (tint + cos3 * (1 - tint))
    assert E(focus, *off_axis(50.0)) == pytest.approx(expected, rel=2e-5)  # the 1 mm sphere spans ±0.06°


def test_a_hard_cone_narrower_than_a_large_light_is_integrated_over_its_directions():
    """A 4 × 4 rect 1 m above the point, cone 10°: the point receives what a cone of
    directions within 10° of +Z brings, E = π L sin²10° (the cone's footprint on the rect,
    a 0.35 m disc, is inside it)."""
    stage = new_stage()
    rect = place(UsdLux.RectLight.Define(stage, "/rect"), translate=(0, 0, 1))
    rect.CreateWidthAttr(4.0)
    rect.CreateHeightAttr(4.0)
    UsdLux.ShapingAPI.Apply(rect.GetPrim()).CreateShapingConeAngleAttr(10.0)
    expected = math.pi * math.sin(math.radians(10.0)) ** 2
    assert E(rect)[0] == pytest.approx(np.full(3, expected), rel=1e-9)


def test_a_hard_cone_cutting_a_disk_gives_the_lens_it_leaves():
    """A disk of radius 1, 1 m above, cone 30°, seen from 0.8 m off its axis: the light that
    arrives is the lens where the disk and the cone's footprint (a circle of radius tan 30°
    above the point) overlap: Lambert's contour integral of that lens."""
    stage = new_stage()
    disk = place(UsdLux.DiskLight.Define(stage, "/disk"), translate=(0, 0, 1))
    disk.CreateRadiusAttr(1.0)
    UsdLux.ShapingAPI.Apply(disk.GetPrim()).CreateShapingConeAngleAttr(30.0)
    point = np.array([[0.8, 0.0, 0.0]])
    angles = np.linspace(0, 2 * np.pi, 40000, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    footprint = math.tan(math.radians(30.0))
    rim = circle[np.linalg.norm(circle - [0.8, 0.0], axis=1) <= footprint]  # of the disk, inside the footprint
    arc = [0.8, 0.0] + footprint * circle
    arc = arc[np.linalg.norm(arc, axis=1) <= 1.0]  # of the footprint, on the disk
    lens = np.concatenate([rim, arc])
    centre = lens.mean(axis=0)
    lens = lens[np.argsort(np.arctan2(lens[:, 1] - centre[1], lens[:, 0] - centre[0]))]  # convex: by angle
    expected = lambert_contour(np.c_[lens, np.ones(len(lens))], point[0], UP[0])
    assert E(disk, point)[0] == pytest.approx(np.full(3, expected), rel=3e-4)  # kinks in azimuth: ~1e-4


def lm63(vertical, horizontal, candela) -> str:
    """A minimal LM-63-2002 type C file (degrees; candela rows per horizontal angle)."""
    numbers = [1, -1, 1, len(vertical), len(horizontal), 1, 2, 0, 0, 0, 1, 1, 0,
               *vertical, *horizontal, *np.asarray(candela, float).ravel()]
    return "IESNA:LM-63-2002\n[TEST] usdlux reference\nTILT=NONE\n" + " ".join(f"{n:g}" for n in numbers) + "\n"


def test_ies_power_is_the_mean_intensity():
    vertical, horizontal = np.radians([0.0, 45.0, 90.0, 180.0]), np.radians([0.0, 360.0])
    constant = np.full((2, 4), 7.0)
    assert ref.ies_power(vertical, horizontal, constant) == pytest.approx(7.0, rel=1e-12)
    hemisphere = np.radians([0.0, 30.0, 90.0])
    assert ref.ies_power(hemisphere, horizontal, np.full((2, 3), 5.0)) == pytest.approx(5.0, rel=1e-12)
    # I = θ/π (linear in θ, exact for the bilinear table): its mean over the sphere is 1/2
    linear = np.radians([0.0, 180.0])
    assert ref.ies_power(linear, horizontal, np.array([[0.0, 1.0], [0.0, 1.0]])) == pytest.approx(0.5, rel=1e-12)


def test_ies_profile_angle_scale_normalize_and_azimuth(tmp_path):
    # vertical 0–90° only (0 below the horizon); horizontal: 0–180° bilateral, brighter at 0°
    vertical, horizontal = [0.0, 30.0, 60.0, 90.0], [0.0, 90.0, 180.0]
    candela = np.array([[100.0, 80.0, 40.0, 0.0], [50.0, 40.0, 20.0, 0.0], [10.0, 8.0, 4.0, 0.0]])
    (tmp_path / "test.ies").write_text(lm63(vertical, horizontal, candela))
    stage = Usd.Stage.CreateNew(str(tmp_path / "ies.usda"))
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    spot = tiny_sphere(stage, radius=1e-6)  # its directions span ±6e-5° (the table has kinks)
    free = tiny_sphere(stage, "/free", radius=1e-6)
    spot.GetPrim().CreateAttribute("inputs:shaping:ies:file", Sdf.ValueTypeNames.Asset).Set("test.ies")
    api = UsdLux.ShapingAPI(spot.GetPrim())

    def ratio(theta, azimuth=0.0):
        """Emission at θ from −Z toward local azimuth ``azimuth`` (degrees) over no IES."""
        t, a = math.radians(theta), math.radians(azimuth)
        point = np.array([[math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), -math.cos(t)]])
        return float(E(spot, point, -point)[0, 0] / E(free, point, -point)[0, 0])

    # φ is the azimuth of the direction toward the light (hdEmbree): emitting toward local
    # +X is φ = 180°, toward −X φ = 0°, toward ±Y φ = 270° / 90°.
    assert ratio(45.0, 180.0) == pytest.approx(60.0, rel=1e-4)  # (80 + 40) / 2 at 0°
    assert ratio(45.0, 0.0) == pytest.approx(6.0, rel=1e-4)  # at 180°
    assert ratio(45.0, 90.0) == pytest.approx(30.0, rel=1e-4)  # at 270° = 90° mirrored
    assert ratio(120.0, 180.0) == 0.0  # outside the profile's vertical range
    api.CreateShapingIesAngleScaleAttr(0.5)  # θ_ies = 2 θ
    assert ratio(15.0, 180.0) == pytest.approx(80.0, rel=1e-4)
    api.GetShapingIesAngleScaleAttr().Set(-0.5)  # θ_ies = (θ − π) / 0.5 + π, clamped to [0, π]
    assert ratio(125.0, 180.0) == pytest.approx(80.0 / 3, rel=1e-4)  # → 70°
    assert ratio(20.0, 180.0) == pytest.approx(100.0, rel=1e-4)  # → −140°, clamped to 0°
    api.GetShapingIesAngleScaleAttr().Set(0.0)
    api.CreateShapingIesNormalizeAttr(True)
    power = ref.read_light(spot.GetPrim()).shaping.ies.power
    assert ratio(45.0, 180.0) == pytest.approx(60.0 / power, rel=1e-4)


def test_ies_power_agrees_with_the_parsers_midpoint_rule(shared_data):
    """The parser's power (hdEmbree's patch-centre sum) and the exact mean of the bilinear
    table differ by the midpoint rule's error only."""
    from pxr_layers.stage.ies import read_ies

    path = shared_data / "luxtest" / "bega_omni002_4777lm.ies"
    profile, _ = read_ies(str(path))
    assert ref.read_ies(path).power == pytest.approx(profile.power, rel=5e-3)


# -- point, line, occluders, links, hits ------------------------------------------------


def test_treat_as_point_is_the_spheres_own_far_field():
    stage = new_stage()
    sphere = place(UsdLux.SphereLight.Define(stage, "/sphere"), translate=(0.5, 0.0, 2.0))
    sphere.CreateRadiusAttr(0.25)
    area = E(sphere)
    sphere.CreateTreatAsPointAttr(True)
    assert E(sphere) == pytest.approx(area, rel=1e-9)  # exact while the whole sphere is visible


def test_treat_as_line_is_a_thin_cylinder():
    stage = new_stage()
    cylinder = place(UsdLux.CylinderLight.Define(stage, "/cylinder"), translate=(0.3, 0.0, 1.0), rotate=(0, 0, 20))
    cylinder.CreateRadiusAttr(0.001)
    cylinder.CreateLengthAttr(2.0)
    thin = E(cylinder)
    cylinder.CreateTreatAsLineAttr(True)
    assert E(cylinder) == pytest.approx(thin, rel=2e-3)


def test_occluders_block_and_shadow_links_unblock():
    stage = new_stage()
    rect = place(UsdLux.RectLight.Define(stage, "/rect"), translate=(0, 0, 1))
    rect.CreateWidthAttr(1.0)
    rect.CreateHeightAttr(1.0)
    whole = ref.Quad(np.array([0.0, 0.0, 0.5]), np.array([2.0, 0, 0]), np.array([0, 2.0, 0]), path="/blocker")
    half = ref.Quad(np.array([0.5, 0.0, 0.5]), np.array([1.0, 0, 0]), np.array([0, 2.0, 0]))  # covers x > 0
    light = ref.read_light(rect.GetPrim())
    plain = ref.irradiance(light, ORIGIN, UP)
    assert ref.irradiance(light, ORIGIN, UP, [whole]).max() == 0.0
    assert ref.irradiance(light, ORIGIN, UP, [half]) == pytest.approx(plain / 2, rel=1e-9)  # by symmetry
    links = UsdLux.LightAPI(rect.GetPrim()).GetShadowLinkCollectionAPI()
    links.CreateExcludesRel().AddTarget("/blocker")
    assert E(rect, occluders=[whole]) == pytest.approx(plain, rel=1e-12)


def test_light_link_excludes_a_receiver():
    stage = new_stage()
    disk = place(UsdLux.DiskLight.Define(stage, "/disk"), translate=(0, 0, 1))
    UsdLux.LightAPI(disk.GetPrim()).GetLightLinkCollectionAPI().CreateExcludesRel().AddTarget("/World/floor")
    assert E(disk, receiver="/World/floor").max() == 0.0
    assert E(disk, receiver="/World/wall").max() > 0.0


def test_hits_on_each_shape():
    stage = new_stage()
    up = np.array([[[0.0, 0.0, 1.0]]])
    shapes = {"rect": UsdLux.RectLight, "disk": UsdLux.DiskLight, "sphere": UsdLux.SphereLight,
              "cylinder": UsdLux.CylinderLight}
    expected = {"rect": 2.0, "disk": 2.0, "sphere": 1.5, "cylinder": 1.5}  # each centred at z = 2
    below, above = np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 4.0]])
    for kind, schema in shapes.items():
        light = ref.read_light(place(schema.Define(stage, f"/{kind}"), translate=(0, 0, 2)).GetPrim())
        assert ref.hit(light, below, up)[0, 0] == pytest.approx(expected[kind])
        if kind in ("rect", "disk"):  # their back emits nothing, but is hit when both sides count
            assert np.isinf(ref.hit(light, above, -up)[0, 0])
            assert ref.hit(light, above, -up, front_only=False)[0, 0] == pytest.approx(2.0)
    inside = ref.read_light(UsdLux.SphereLight.Define(stage, "/inside").GetPrim())
    assert np.isinf(ref.hit(inside, below, up)[0, 0])  # from inside: only its back
    assert ref.hit(inside, below, up, front_only=False)[0, 0] == pytest.approx(0.5)
