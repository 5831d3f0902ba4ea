"""The tracer's lights against closed forms: ShapingAPI (cone, softness, focus, focusTint),
IES profiles, point and line lights, light and shadow linking, camera visibility, textured
rect lights, the diffuse/specular multipliers, and shadow rays at grazing angles.

The stages are real USD written to tmp_path; the light controls under test are set on the
plain scene.Light the reader produced (dataclasses.replace), so these tests check the tracer
against the formulas, apart from how the reader gets them from USD (test_stage_lights.py).
Every expectation is computed here from the UsdLux formulas, at pixel centres, for a white
Lambertian floor (a pixel shows E / π) lit directly (max depth 1).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from pxr_layers import lpe
from pxr_layers.layers.extract import extract
from pxr_layers.paths.reader import PathIndex
from pxr_layers.paths.writer import PathIndexWriter
from pxr_layers.scene import IesProfile, LightShaping, TextureImage
from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings

from test_render_physics import camera_prim, lambert, preview_surface, stage_text, write
from tracing import trace_image

HEIGHT = 1.0  # the light above the floor, metres
CAMERA_HEIGHT = 4.0
HALF_VIEW = 2.0  # the floor seen spans ±HALF_VIEW in x and z
RESOLUTION = 48


def floor(name="floor", x0=-10.0, x1=10.0, look="white") -> str:
    return f"""
    def Mesh "{name}" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [({x0}, 0, 10), ({x1}, 0, 10), ({x1}, 0, -10), ({x0}, 0, -10)]
        rel material:binding = </World/Looks/{look}>
    }}
"""


def down_camera() -> str:
    # aperture / focal length = 2·HALF_VIEW / CAMERA_HEIGHT
    return camera_prim(10, 10 * 2 * HALF_VIEW / CAMERA_HEIGHT, translate=(0, CAMERA_HEIGHT, 0), rotate=(-90, 0, 0))


def sphere_light(name="bulb", radius=0.05, intensity=100.0, translate=(0, HEIGHT, 0), rotate=(-90, 0, 0)) -> str:
    """A SphereLight whose −Z points down (rotateX −90)."""
    return f"""
    def SphereLight "{name}"
    {{
        float inputs:intensity = {intensity}
        float inputs:radius = {radius}
        double3 xformOp:translate = {tuple(translate)}
        float3 xformOp:rotateXYZ = {tuple(rotate)}
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
"""


def disk_light(name="disk", radius=0.05, intensity=100.0) -> str:
    return f"""
    def DiskLight "{name}"
    {{
        float inputs:intensity = {intensity}
        float inputs:radius = {radius}
        double3 xformOp:translate = (0, {HEIGHT}, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
"""


def load(tmp_path, body: str, camera: str = "", looks: str = ""):
    path = write(tmp_path, "lights.usda", stage_text(body, looks or lambert("white", 1.0, 0.0), camera or down_camera()))
    return load_stage(path)


def with_light(stage, index=0, **changes):
    scene, spec = stage
    lights = list(scene.lights)
    lights[index] = dataclasses.replace(lights[index], **changes)
    return dataclasses.replace(scene, lights=tuple(lights)), spec


def image(stage, spp=16, resolution=(RESOLUTION, RESOLUTION), **settings) -> np.ndarray:
    """The beauty of the (scene, spec), its lights as edited here: the tracer's stages."""
    scene, spec = stage
    settings = TraceSettings(spp=spp, max_depth=settings.pop("max_depth", 1), **settings)
    return trace_image(scene, spec, settings, resolution=resolution).rgba[..., :3].astype(np.float64)


def floor_points(resolution=RESOLUTION, offset=0.5) -> tuple[np.ndarray, np.ndarray]:
    """World x, z (resolution, resolution) of the floor seen by down_camera() at `offset`
    (0–1) across each pixel, the centre by default (image right = +x, image top = −z)."""
    centres = (2 * (np.arange(resolution) + offset) / resolution - 1) * HALF_VIEW
    x, z = np.meshgrid(centres, centres)
    return x, z


def pixel_mean(function, resolution=RESOLUTION, steps=8):
    """The mean of function(x, z) over each pixel's footprint on the floor (steps² points),
    as a render's samples spread over the pixel."""
    total = 0.0
    for i in range(steps):
        for j in range(steps):
            x, _ = floor_points(resolution, (i + 0.5) / steps)
            _, z = floor_points(resolution, (j + 0.5) / steps)
            total = total + function(x, z)
    return total / steps**2


def emission_angles(x, z, height=HEIGHT):
    """θ from the light's −Z (straight down) and distance d from a light at (0, height, 0)."""
    d = np.sqrt(x**2 + z**2 + height**2)
    return np.arccos(height / d), d


def cone_factor(theta, cone_degrees, softness):
    cone = math.radians(cone_degrees)
    start = cone * (1 - softness)
    if cone > start:
        ramp = np.clip((theta - start) / (cone - start), 0, 1)
        return 1 - ramp * ramp * (3 - 2 * ramp)
    return (theta <= cone).astype(float)


def point_pixels(intensity_cd, theta, d, height=HEIGHT):
    """A white Lambertian floor's pixel value under a point of intensity (candela) at θ, d."""
    return intensity_cd * (height / d) / d**2 / math.pi


def assert_close_where(actual, expected, mask, rtol):
    """Pixels of `mask` within rtol of `expected` (plus a quarter of rtol of its maximum,
    for the sampling noise of pixels where it is small), and their mean within rtol / 4."""
    assert mask.sum() > 20
    actual, expected = actual[mask], expected[mask]
    error = np.abs(actual - expected) - 0.25 * rtol * expected.max()
    worst = (error / expected).max()
    assert worst <= rtol, f"worst relative error {worst:.4f} beyond noise"
    assert actual.mean() / expected.mean() == pytest.approx(1.0, abs=rtol / 4)


# -- ShapingAPI on a point light (treatAsPoint): exact direct lighting, no sampling noise


@pytest.mark.parametrize(
    "cone, softness, focus, tint",
    [(30.0, 0.0, 0.0, (0, 0, 0)), (45.0, 0.5, 0.0, (0, 0, 0)), (60.0, 1.0, 0.0, (0, 0, 0)),
     (180.0, 0.0, 2.5, (0, 0, 0)), (60.0, 0.0, 3.0, (1.0, 0.5, 0.0))],
)
def test_cone_softness_and_focus_shape_a_point_light(tmp_path, cone, softness, focus, tint):
    stage = with_light(load(tmp_path, floor() + sphere_light()), kind="point",
                       shaping=LightShaping(cone_angle=cone, cone_softness=softness, focus=focus, focus_tint=tint))
    rgb = image(stage, spp=1024)  # a steep ramp varies across a pixel: its samples' spread is the noise
    x, z = floor_points()
    theta, _ = emission_angles(x, z)
    factor = cone_factor(theta, cone, softness)
    pixel_angle = 2 * HALF_VIEW / RESOLUTION / HEIGHT  # an upper bound of a pixel's span in θ
    # inside the cone, outside it, and (soft) across its ramp; a hard edge's own pixels are mixed
    away = np.abs(theta - math.radians(cone)) > pixel_angle if softness == 0 else np.ones_like(theta, bool)
    for channel in range(3):
        def shaped(x, z, channel=channel):
            theta, d = emission_angles(x, z)
            value = point_pixels(100.0 * math.pi * 0.05**2, theta, d) * cone_factor(theta, cone, softness)
            if focus > 0:
                value = value * (tint[channel] + (1 - tint[channel]) * np.cos(theta) ** focus)
            return value

        expected = pixel_mean(shaped)
        assert_close_where(rgb[..., channel], expected, away & (expected > 0.02 * expected.max()), rtol=0.02)
        outside = theta - math.radians(cone) > pixel_angle  # whole pixels beyond the cone
        if outside.any():
            assert np.all(rgb[..., channel][outside] == 0)


def test_a_hard_cone_cuts_at_its_angle(tmp_path):
    """UsdLux: with softness 0 the light is unaltered up to the cone angle and 0 beyond
    (probed half a degree either side of a 30° cone, one pixel each)."""
    x_edge = HEIGHT * math.tan(math.radians(30.0))
    for offset, lit in ((-0.01, True), (0.01, False)):
        probe = camera_prim(1000, 0.01, translate=(x_edge + offset, 0.5, 0), rotate=(-90, 0, 0))
        stage = with_light(load(tmp_path, floor() + sphere_light(), camera=probe), kind="point",
                           shaping=LightShaping(cone_angle=30.0))
        value = image(stage, spp=4, resolution=(1, 1))[0, 0, 0]
        assert (value > 0) == lit


def test_a_small_disk_light_takes_the_point_limit_of_its_shaping(tmp_path):
    """A cone-shaped disk light (area light: NEE and BSDF hits, MIS) of radius 1 cm at 1 m
    gives the point formula with I = L·π r²·cos θ to within its size's effect."""
    shaping = LightShaping(cone_angle=40.0, cone_softness=0.5)
    stage = with_light(load(tmp_path, floor() + disk_light(radius=0.01, intensity=2500.0)), shaping=shaping,
                       camera_visible=False)
    rgb = image(stage, spp=256)

    def limit(x, z):
        theta, d = emission_angles(x, z)
        return point_pixels(2500.0 * math.pi * 0.01**2 * np.cos(theta), theta, d) * cone_factor(theta, 40.0, 0.5)

    expected = pixel_mean(limit)
    assert_close_where(rgb.mean(axis=-1), expected, expected > 0.05 * expected.max(), rtol=0.03)


# -- IES


def ies_profile(horizontal_degrees=(0, 90, 180, 270, 360)) -> IesProfile:
    """Intensity linear in θ (100 cd down to 20 cd at 90°, 0 beyond) times a factor linear
    between horizontal angles — exactly what bilinear interpolation reproduces."""
    vertical = np.radians(np.linspace(0, 90, 7))
    horizontal = np.radians(np.asarray(horizontal_degrees, float))
    along = 100 - 80 * vertical / (math.pi / 2)
    around = 1 + 0.5 * np.sin(horizontal) ** 2  # 1, 1.5, 1, 1.5, 1 at the five angles
    candela = np.outer(around, along)
    return IesProfile("synthetic.ies", vertical, horizontal, candela, power=50.0)


def ies_expected(theta, phi):
    """ies_profile()'s bilinear value at (θ, φ), from its own definition."""
    along = np.where(theta <= math.pi / 2, 100 - 80 * theta / (math.pi / 2), 0.0)
    quarter = np.mod(phi, math.pi / 2) / (math.pi / 2)  # between two table angles
    sector = np.floor(np.mod(phi, 2 * math.pi) / (math.pi / 2)).astype(int) % 4
    low = np.where(sector % 2 == 0, 1.0, 1.5)
    high = np.where(sector % 2 == 0, 1.5, 1.0)
    return along * (low + (high - low) * quarter)


@pytest.mark.parametrize("angle_scale, normalize", [(0.0, False), (0.5, False), (-0.5, True)])
def test_an_ies_profile_gives_its_intensity_in_every_direction(tmp_path, angle_scale, normalize):
    profile = ies_profile()
    shaping = LightShaping(ies=profile, ies_angle_scale=angle_scale, ies_normalize=normalize)
    # a point of the sphere's power: I = L·π r²; intensity 1/(π r²) makes the IES candela the intensity
    stage = with_light(load(tmp_path, floor() + sphere_light(intensity=1 / (math.pi * 0.05**2))), kind="point",
                       shaping=shaping)
    rgb = image(stage, spp=256)

    def expected_pixels(x, z, with_theta=False):
        theta, d = emission_angles(x, z)
        # the light's local frame: X = world x, Y = world −z, Z = world +y; φ of the direction
        # toward the light (hdEmbree): atan2(−e_y, −e_x) of the emission direction e
        phi = np.arctan2(z / d, -x / d)
        if angle_scale > 0:
            theta_ies = theta / angle_scale
        elif angle_scale < 0:
            theta_ies = (theta - math.pi) / -angle_scale + math.pi
        else:
            theta_ies = theta
        theta_ies = np.clip(theta_ies, 0, math.pi)
        candela = ies_expected(theta_ies, phi) / (profile.power if normalize else 1.0)
        return theta_ies if with_theta else point_pixels(candela, theta, d)

    expected = pixel_mean(expected_pixels)
    smooth = np.abs(expected_pixels(*floor_points(), with_theta=True) - math.pi / 2) > 0.1  # off the cut at 90°
    assert_close_where(rgb[..., 1], expected, smooth & (expected > 0.02 * expected.max()), rtol=0.02)


def test_ies_lights_are_sampled_in_proportion_to_what_they_send(tmp_path):
    """Of two equal bulbs, the one an IES profile dims to a tenth gets about a tenth of the
    light samples' probability (the source powers integrate the profile)."""
    from pxr_layers.trace.lights import LightSampler
    from pxr_layers.trace.render import prepare

    body = floor() + sphere_light("plain", translate=(-1, HEIGHT, 0)) + sphere_light("dim", translate=(1, HEIGHT, 0))
    scene, spec = load(tmp_path, body)
    profile = IesProfile("flat.ies", np.radians([0.0, 180.0]), np.radians([0.0, 360.0]), np.full((2, 2), 0.1), 0.1)
    lights = [dataclasses.replace(light, kind="point") for light in scene.lights]
    lights[1] = dataclasses.replace(lights[1], shaping=LightShaping(ies=profile))
    scene = dataclasses.replace(scene, lights=tuple(lights))
    integrator = prepare(scene, spec, TraceSettings(spp=1, max_depth=1))
    assert isinstance(integrator.lights, LightSampler)
    probability = integrator.lights.arrays.point_probability
    np.testing.assert_allclose(probability[0, 1] / probability[0, 0], 0.1, rtol=1e-3)


# -- point and line lights stand for their shapes


def block_means(image: np.ndarray, block=8) -> np.ndarray:
    height, width = image.shape[:2]
    return image[:height // block * block, :width // block * block].reshape(
        height // block, block, width // block, block, -1).mean(axis=(1, 3))


def test_a_point_light_lights_like_the_small_sphere_it_stands_for(tmp_path):
    """A fully visible sphere lights a point as a point of intensity L·π r² does (exactly,
    for a true sphere): the images agree in total and in 8 × 8 blocks within the sphere
    sampling's noise."""
    stage = with_light(load(tmp_path, floor() + sphere_light(radius=0.02)), camera_visible=False)
    sphere = image(stage, spp=64)
    point = image(with_light(stage, kind="point"), spp=4)
    assert sphere.sum() / point.sum() == pytest.approx(1.0, abs=0.01)
    np.testing.assert_allclose(block_means(sphere), block_means(point), rtol=0.05)


def test_a_line_light_lights_like_the_thin_cylinder_it_stands_for(tmp_path):
    body = floor() + f"""
    def CylinderLight "tube"
    {{
        float inputs:intensity = 50
        float inputs:radius = 0.01
        float inputs:length = 1.5
        double3 xformOp:translate = (0, {HEIGHT}, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
"""
    stage = with_light(load(tmp_path, body), camera_visible=False)
    cylinder = image(stage, spp=256)
    line = image(with_light(stage, kind="line"), spp=64)
    assert cylinder.sum() / line.sum() == pytest.approx(1.0, abs=0.01)
    np.testing.assert_allclose(block_means(cylinder), block_means(line), rtol=0.05)


# -- light and shadow linking


def distant_light(name: str, rotate) -> str:
    return f"""
    def DistantLight "{name}"
    {{
        float inputs:intensity = 2
        float inputs:angle = 0
        float3 xformOp:rotateXYZ = {tuple(rotate)}
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
"""


def linked_stage(tmp_path):
    """Two floor halves (x < 0: "west", x > 0: "east") and two delta distant lights: "sun"
    from straight above (E = 2), "sky" 60° off (E = 2 cos 60° = 1)."""
    body = (floor("west", -10, 0) + floor("east", 0, 10) + distant_light("sun", (-90, 0, 0))
            + distant_light("sky", (-30, 0, 0)))
    return load(tmp_path, body)


def test_each_object_receives_exactly_the_light_linked_to_it(tmp_path):
    scene, spec = linked_stage(tmp_path)
    west, east = (next(i for i, mesh in enumerate(scene.meshes) if mesh.name == name) for name in ("west", "east"))
    lights = {light.name: light for light in scene.lights}
    linked = dataclasses.replace(scene, lights=(dataclasses.replace(lights["sun"], light_link=(west,)),
                                                dataclasses.replace(lights["sky"], light_link=(east,))))
    rgb = image((linked, spec), spp=4).mean(axis=-1)
    x, _ = floor_points()
    inner = np.abs(x) > 0.1
    np.testing.assert_allclose(rgb[(x < 0) & inner], 2 / math.pi, rtol=1e-4)
    np.testing.assert_allclose(rgb[(x > 0) & inner], 1 / math.pi, rtol=1e-4)


def test_per_light_layers_still_sum_to_the_beauty_under_linking(tmp_path):
    scene, spec = linked_stage(tmp_path)
    west = next(i for i, mesh in enumerate(scene.meshes) if mesh.name == "west")
    lights = tuple(dataclasses.replace(light, light_link=(west,)) if light.name == "sky" else light
                   for light in scene.lights)
    scene = dataclasses.replace(scene, lights=lights)
    settings = TraceSettings(spp=4, max_depth=3, record_paths=True, merge_records=True)
    path = tmp_path / "linked.pxlidx"
    writer = PathIndexWriter(path, {"spp": settings.spp, "resolution": [32, 32]}, settings.norm_bounces)
    result = trace_image(scene, spec, settings, resolution=(32, 32))
    for batch in result.batches:
        writer.add(batch.records)
    writer.close(result.vocabulary)
    layers = extract(PathIndex(path), lpe.per_light_passes([light.name for light in scene.lights])).layers
    beauty = result.rgba[..., :3].astype(np.float64)
    total = np.sum([layer.astype(np.float64) for layer in layers.values()], axis=0)
    np.testing.assert_allclose(total, beauty, rtol=1e-5, atol=1e-7)
    x, _ = floor_points(32)
    assert layers["light_sky"][x > 0.1].max() == 0  # the east half never sees the sky light
    # the west half gets it (1/π on average: each sample picks one of its two lights)
    assert layers["light_sky"][x < -0.1].mean() == pytest.approx(1 / math.pi, rel=0.15)


def occluded_stage(tmp_path):
    """A floor under a 1 × 1 m card at 0.5 m, lit by the straight-down sun."""
    card = """
    def Mesh "card" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-0.5, 0.5, 0.5), (0.5, 0.5, 0.5), (0.5, 0.5, -0.5), (-0.5, 0.5, -0.5)]
        rel material:binding = </World/Looks/white>
    }
"""
    camera = camera_prim(10, 10, translate=(0, 0.4, 0), rotate=(-90, 0, 0))  # under the card
    return load(tmp_path, floor() + card + distant_light("sun", (-90, 0, 0)), camera=camera)


def test_geometry_outside_a_lights_shadow_link_casts_no_shadow_from_it(tmp_path):
    scene, spec = occluded_stage(tmp_path)
    floor_index = next(i for i, mesh in enumerate(scene.meshes) if mesh.name == "floor")
    shadowed = image((scene, spec), spp=4, resolution=(8, 8))
    assert shadowed.max() == 0
    unlinked = image(with_light((scene, spec), shadow_link=(floor_index,)), spp=4, resolution=(8, 8))
    np.testing.assert_allclose(unlinked, 2 / math.pi, rtol=1e-4)


def test_an_area_light_with_shadow_links_keeps_its_brightness(tmp_path):
    """Light sampling alone finds a light whose shadow links are restricted: on an
    unoccluded floor it gives the same image as with full MIS, within noise."""
    stage = load(tmp_path, floor() + disk_light(radius=0.3))
    scene, _ = stage
    plain = image(stage, spp=64, max_depth=2)
    restricted = image(with_light(stage, shadow_link=tuple(range(len(scene.meshes)))), spp=64, max_depth=2)
    assert restricted.sum() / plain.sum() == pytest.approx(1.0, abs=0.01)


# -- camera visibility, textures, multipliers


def test_a_light_hidden_from_the_camera_still_lights_the_floor(tmp_path):
    """A big rect light between the camera and the floor, facing down: visible, the camera
    sees its dark back; hidden, the camera sees the floor it lights (and alpha stays)."""
    body = floor() + """
    def RectLight "panel"
    {
        float inputs:intensity = 3
        float inputs:width = 20
        float inputs:height = 20
        double3 xformOp:translate = (0, 2, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }
"""
    stage = load(tmp_path, body)
    seen = image(stage, spp=4, resolution=(8, 8))
    assert seen.max() == 0  # the panel's back
    hidden = image(with_light(stage, camera_visible=False), spp=256, resolution=(8, 8))
    # E under a 20 × 20 m panel 2 m up is nearly π·L (the centre sees 94 % of the hemisphere)
    assert 0.85 * 3 < hidden.mean() < 3


def test_a_dome_hidden_from_the_camera_leaves_a_black_background_and_lights_the_floor(tmp_path):
    body = floor("floor", -0.5, 0.5) + """
    def DomeLight "sky"
    {
        float inputs:intensity = 1
    }
"""
    stage = load(tmp_path, body)
    rgb = image(with_light(stage, camera_visible=False), spp=16, resolution=(16, 16)).mean(axis=-1)
    x, _ = floor_points(16)
    assert rgb[np.abs(x) > 0.6].max() == 0
    assert rgb[np.abs(x) < 0.4].mean() == pytest.approx(1.0, rel=0.05)  # a white floor under a unit dome


def test_a_rect_lights_texture_reads_unmirrored_from_its_lit_side(tmp_path):
    """UsdLux RectLight: the texture's top-left at local (+X, +Y). A camera in front of the
    light (on its −Z side, looking at it) sees the image as it is: red top-left, green
    top-right, blue bottom-left, white bottom-right."""
    body = """
    def RectLight "sign"
    {
        float inputs:intensity = 1
        float inputs:width = 2
        float inputs:height = 2
    }
"""
    # looking along +Z from z = −4: the camera's right is world −X
    camera = camera_prim(50, 10, translate=(0, 0, -4), rotate=(0, 180, 0))
    scene, spec = load(tmp_path, body, camera=camera)
    quadrants = np.array([[[1, 0, 0], [0, 1, 0]], [[0, 0, 1], [1, 1, 1]]], np.float32)  # row 0 = top
    pixels = np.repeat(np.repeat(quadrants, 4, axis=0), 4, axis=1)  # 8 × 8: bilinear stays inside a quadrant
    scene = dataclasses.replace(scene, textures=(*scene.textures, TextureImage("quadrants", pixels)))
    stage = with_light((scene, spec), texture=len(scene.textures) - 1)
    rgb = image(stage, spp=4, resolution=(40, 40))
    # the view spans ±0.4 m of the 2 m light, around its centre where the quadrants meet
    for (row, column), colour in {(5, 5): (1, 0, 0), (5, 34): (0, 1, 0), (34, 5): (0, 0, 1), (34, 34): (1, 1, 1)}.items():
        np.testing.assert_allclose(rgb[row, column], colour, atol=0.02)


def test_the_diffuse_multiplier_scales_the_light_on_a_lambertian_floor(tmp_path):
    stage = load(tmp_path, floor() + distant_light("sun", (-90, 0, 0)))
    plain = image(stage, spp=4, resolution=(8, 8))
    halved = image(with_light(stage, diffuse=0.5, specular=0.0), spp=4, resolution=(8, 8))
    np.testing.assert_allclose(halved, plain * 0.5, rtol=1e-5)


def test_the_specular_multiplier_scales_only_the_glossy_response(tmp_path):
    metal = preview_surface("white", diffuseColor=("color3f", "(1, 1, 1)"), metallic=("float", "1"),
                            roughness=("float", "0.4"))
    stage = load(tmp_path, floor() + disk_light(radius=0.5), looks=metal)
    plain = image(stage, spp=64, resolution=(16, 16), max_depth=2)
    scaled = image(with_light(stage, specular=0.25, diffuse=0.0), spp=64, resolution=(16, 16), max_depth=2)
    assert scaled.sum() / plain.sum() == pytest.approx(0.25, rel=1e-4)


# -- shadow rays at grazing angles


def wall_light_irradiance(point, normal, height, radiance, shape, n=400):
    """E at `point` (normal `normal`) from a one-sided light in the x = 0 plane emitting
    toward −x, centred at (0, height, 0): a 1 × 1 m "rect" or a "disk" of radius 0.5 m, by
    midpoint quadrature over the square that holds it."""
    ys = height + (np.arange(n) + 0.5) / n - 0.5
    zs = (np.arange(n) + 0.5) / n - 0.5
    y, z = np.meshgrid(ys, zs)
    inside = np.ones_like(y, bool) if shape == "rect" else (y - height) ** 2 + z**2 <= 0.25
    offset = np.stack([-point[0] + 0 * y, y - point[1], z - point[2]], axis=-1)
    d2 = (offset**2).sum(-1)
    direction = offset / np.sqrt(d2)[..., None]
    cos_surface = np.clip(direction @ normal, 0, None)
    cos_light = np.clip(direction[..., 0], 0, None)  # the light faces −x, toward the point
    return float((radiance * cos_surface * cos_light / d2 * inside).sum() / n**2)


@pytest.mark.parametrize("shape", ["RectLight", "DiskLight"])
@pytest.mark.parametrize("cos_light", [0.2, 0.05, 0.02])
def test_a_point_lit_edge_on_by_an_area_light_gets_all_of_it(tmp_path, shape, cos_light):
    """A floor point seen from a vertical area light at cos θ (light side) down to 0.02
    receives the quadrature's irradiance within 1 %: no shadow ray may hit the light's own
    triangle before reaching its sample."""
    # the light: centre 0.6 m up in the x = 0 plane, facing −x; the probe s from its plane
    height = 0.6
    s = height * cos_light / math.sqrt(1 - cos_light**2)  # cos θ at the light's centre = s / √(s² + h²)
    size = "float inputs:radius = 0.5" if shape == "DiskLight" else ""
    body = floor() + f"""
    def {shape} "wall"
    {{
        float inputs:intensity = 10
        {size}
        double3 xformOp:translate = (0, {height}, 0)
        float3 xformOp:rotateXYZ = (0, 90, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
"""
    camera = camera_prim(1000, 0.01 * s, translate=(-s, 0.5, 0), rotate=(-90, 0, 0))
    # 2^18 samples over 8 × 8 pixels that all see the probe (the view is 5e-6 s wide): noise 0.6 %
    value = image(load(tmp_path, body, camera=camera), spp=4096, resolution=(8, 8)).mean()
    kind = "disk" if shape == "DiskLight" else "rect"
    expected = wall_light_irradiance(np.array([-s, 0, 0]), np.array([0, 1.0, 0]), height, 10.0, kind) / math.pi
    # the tessellated disk (64 segments) has 0.16 % less area than the circle
    assert value == pytest.approx(expected, rel=0.01)
