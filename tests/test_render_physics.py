"""The tracer against physics: furnaces, analytic direct lighting, equivalent emitters.

Every scene is a real USD stage written to tmp_path and read by the stage reader, so these
tests cover stage → tracer end to end. Tolerances are stated per test: they bound Monte
Carlo noise at the sample counts used (relative standard errors measured well below them).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.jobs.frame import render_frame
from pxr_layers.request import RenderRequest
from pxr_layers.stage import load_stage
from pxr_layers.trace import TraceSettings

from tracing import trace_image


def preview_surface(name: str, **inputs: str) -> str:
    """A UsdPreviewSurface Material prim under /World/Looks; inputs as 'type = value'."""
    lines = "".join(f"                {kind} inputs:{key} = {value}\n" for key, (kind, value) in inputs.items())
    return f"""
        def Material "{name}"
        {{
            token outputs:surface.connect = </World/Looks/{name}/Surface.outputs:surface>
            def Shader "Surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
{lines}                token outputs:surface
            }}
        }}
"""


def lambert(name: str, r: float, e: float) -> str:
    """A pure Lambertian (no specular lobe) of albedo r, emitting e."""
    return preview_surface(
        name,
        diffuseColor=("color3f", f"({r}, {r}, {r})"),
        emissiveColor=("color3f", f"({e}, {e}, {e})"),
        useSpecularWorkflow=("int", "1"),
        specularColor=("color3f", "(0, 0, 0)"),
    )


def camera_prim(focal_length: float, aperture: float, translate=(0, 0, 0), rotate=(0, 0, 0)) -> str:
    """A square-aperture perspective camera /World/Camera looking down its local −Z."""
    return f"""
    def Camera "Camera"
    {{
        float focalLength = {focal_length}
        float horizontalAperture = {aperture}
        float verticalAperture = {aperture}
        float2 clippingRange = (0.01, 1000)
        double3 xformOp:translate = {tuple(translate)}
        float3 xformOp:rotateXYZ = {tuple(rotate)}
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
"""


def stage_text(body: str, looks: str = "", camera: str = "") -> str:
    camera = camera or camera_prim(50, 10, translate=(0, 3, 0), rotate=(-90, 0, 0))
    header = '#usda 1.0\n(\n    upAxis = "Y"\n    metersPerUnit = 1\n    defaultPrim = "World"\n)\n'
    return header + f'def Xform "World"\n{{\n    def Scope "Looks"\n    {{\n{looks}\n    }}\n{body}\n{camera}\n}}\n'


FLOOR = """
    def Mesh "floor" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-50, 0, 50), (50, 0, 50), (50, 0, -50), (-50, 0, -50)]
        rel material:binding = </World/Looks/grey>
    }
"""


def write(tmp_path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return path


def mean_rgb(path, spp=16, max_depth=8, resolution=(16, 16), **options):
    """The mean pixel of the stage's beauty and render_frame's result (no index, its
    product written beside the stage); options: more RenderRequest fields."""
    request = RenderRequest(stage=path, resolution=resolution, spp=spp, max_depth=max_depth, norm_bounces=0,
                            keep_index=False, previews=False, **options)
    result = render_frame(request, output=path.parent)
    return result.rgba[..., :3].reshape(-1, 3).mean(axis=0), result


@pytest.mark.parametrize("max_depth", [0, 1, 3])
def test_furnace_closed_sphere_converges_to_geometric_series(tmp_path, max_depth):
    """Inside a closed emissive sphere of albedo a, radiance is Le · Σ_{j ≤ depth} a^j."""
    albedo = 0.5
    looks = lambert("glow", albedo, 1.0)
    body = """
    def Sphere "shell" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        double radius = 10
        rel material:binding = </World/Looks/glow>
    }
"""
    camera = camera_prim(20, 20)
    path = write(tmp_path, "furnace.usda", stage_text(body, looks, camera))
    rgb, _ = mean_rgb(path, spp=16, max_depth=max_depth)
    expected = sum(albedo**j for j in range(max_depth + 1))
    np.testing.assert_allclose(rgb, expected, rtol=0.01)


@pytest.mark.parametrize("elevation", [90, 60, 30])
def test_diffuse_plane_under_delta_distant_light(tmp_path, elevation):
    """L = ρ/π · E · cos θ for a Lambertian plane lit by a distant light of angle 0."""
    looks = lambert("grey", 0.6, 0)
    body = FLOOR + f"""
    def DistantLight "sun"
    {{
        float inputs:angle = 0
        float inputs:intensity = 3
        float3 xformOp:rotateXYZ = ({elevation - 180}, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }}
"""
    path = write(tmp_path, "sun.usda", stage_text(body, looks))
    rgb, _ = mean_rgb(path, spp=1, max_depth=1)
    expected = 0.6 / math.pi * 3.0 * math.sin(math.radians(elevation))
    np.testing.assert_allclose(rgb, expected, rtol=1e-5)


def test_normalized_distant_light_with_a_cone_gives_its_intensity_as_irradiance(tmp_path):
    """A normalized distant light's intensity is the irradiance it gives a facing surface;
    light sampling and BSDF sampling of its cone are combined by MIS."""
    looks = lambert("grey", 0.5, 0)
    body = FLOOR + """
    def DistantLight "sun"
    {
        float inputs:angle = 20
        float inputs:intensity = 2
        bool inputs:normalize = 1
        float3 xformOp:rotateXYZ = (-120, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
    }
"""
    path = write(tmp_path, "cone.usda", stage_text(body, looks))
    rgb, _ = mean_rgb(path, spp=64, max_depth=1)
    # A uniform cone whose axis is 30° from the normal and which stays above the horizon:
    # E = L · π sin²(θmax) · cos θ, and normalize makes L · π sin²(θmax) = intensity.
    expected = 0.5 / math.pi * 2.0 * math.cos(math.radians(30))
    np.testing.assert_allclose(rgb, expected, rtol=0.01)


def test_uniform_dome_on_a_diffuse_plane(tmp_path):
    """A uniform dome of radiance Lc gives E = π·Lc on an unoccluded plane: L = ρ·Lc."""
    looks = lambert("grey", 0.5, 0)
    body = FLOOR + """
    def DomeLight "sky"
    {
        float inputs:intensity = 0.8
        color3f inputs:color = (1, 0.5, 0.25)
    }
"""
    path = write(tmp_path, "dome.usda", stage_text(body, looks))
    rgb, _ = mean_rgb(path, spp=64, max_depth=1)
    # The 100 m floor seen from 3 m hides a little of the lower hemisphere: nothing, since
    # the floor faces up. Directions below the horizon are the floor's own back.
    np.testing.assert_allclose(rgb, 0.5 * 0.8 * np.array([1, 0.5, 0.25]), rtol=0.01)


def grey_card_stage(camera: str = "") -> str:
    """A 2 × 2 m Lambertian card of albedo 0.18 facing +Z, and nothing that lights it."""
    header = '#usda 1.0\n(\n    upAxis = "Y"\n    metersPerUnit = 1\n    defaultPrim = "World"\n)\n'
    card = """
    def Mesh "card" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
        rel material:binding = </World/Looks/grey>
    }
"""
    return header + f'def Xform "World"\n{{\n    def Scope "Looks"\n    {{\n{lambert("grey", 0.18, 0)}\n    }}\n{card}\n{camera}\n}}\n'


# The default rig on a surface facing the camera (stage/defaults.DEFAULT_RIG): a distant
# light at azimuth a, elevation e from the view axis meets it at cos e · cos a; the rim,
# behind, not at all; the 0.3 dome gives ρ · 0.3 over the open hemisphere.
DEFAULT_RIG_ON_A_FACING_CARD = (0.18 / math.pi * (5.0 * math.cos(math.radians(35)) * math.cos(math.radians(45))
                                                  + 1.25 * math.cos(math.radians(10)) * math.cos(math.radians(60)))
                                + 0.18 * 0.3)


def test_a_grey_card_under_the_default_rig_and_automatic_camera_is_mid_grey(tmp_path):
    """No camera, no light: the automatic camera looks at the card from the front and fills
    the frame with it; the normalised key and fill give their irradiance, as documented."""
    path = write(tmp_path, "card.usda", grey_card_stage())
    _, result = mean_rgb(path, spp=64, max_depth=1, resolution=(24, 16))
    centre = result.rgba[4:12, 8:16, :3].reshape(-1, 3).mean(axis=0)
    np.testing.assert_allclose(centre, DEFAULT_RIG_ON_A_FACING_CARD, rtol=0.01)
    assert 0.24 < DEFAULT_RIG_ON_A_FACING_CARD < 0.27  # mid grey in an sRGB preview
    # The card (2 × 2 m, square) binds the frame's height: about 1/AUTO_CAMERA_MARGIN of it.
    card_rows = np.flatnonzero(np.abs(result.rgba[:, 12, 0] - 0.3) > 0.02)
    assert 12 <= len(card_rows) <= 15


def test_the_default_rig_turns_with_the_users_camera(tmp_path):
    """A camera on the +X side looking down −X at a card turned to face it sees the same
    grey; the key comes from the camera's upper left on a sphere."""
    side_camera = camera_prim(35, 20, translate=(4, 0, 0), rotate=(0, 90, 0))
    turned = grey_card_stage(side_camera).replace(
        "(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)", "(0, -1, 1), (0, -1, -1), (0, 1, -1), (0, 1, 1)")
    _, result = mean_rgb(write(tmp_path, "side.usda", turned), spp=64, max_depth=1)
    np.testing.assert_allclose(result.rgba[4:12, 4:12, :3].reshape(-1, 3).mean(axis=0),
                               DEFAULT_RIG_ON_A_FACING_CARD, rtol=0.01)

    sphere = grey_card_stage(side_camera).replace(
        'def Mesh "card"', 'def Sphere "card"').replace(
        "int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]\n", "").replace(
        "point3f[] points = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]", "double radius = 0.5")
    _, result = mean_rgb(write(tmp_path, "sphere.usda", sphere), spp=16, max_depth=1, resolution=(32, 32))
    luminance, on_sphere = result.rgba[..., :3].mean(axis=2), result.rgba[..., 3] > 0.99
    centre_row, centre_column = (indices.mean() for indices in np.nonzero(on_sphere))
    rows, columns = np.ogrid[:32, :32]
    upper_left = luminance[on_sphere & (rows < centre_row) & (columns < centre_column)].mean()
    lower_right = luminance[on_sphere & (rows > centre_row) & (columns > centre_column)].mean()
    assert upper_left > 2.0 * lower_right


def test_a_coarse_subdivision_cage_is_framed_by_the_surface_that_renders(tmp_path):
    """A Catmull-Clark cube's limit surface is smaller than its cage: framed by the cage's
    box, the rendered ball spanned 57 % of the frame; framed by the limit surface's, more,
    and nothing is cut at the frame's edge. (A round subject framed by its box's eight
    corners spans less than the box's 1/AUTO_CAMERA_MARGIN: its silhouette lies deeper.)"""
    cube = grey_card_stage().replace(
        "int[] faceVertexCounts = [4]\n        int[] faceVertexIndices = [0, 1, 2, 3]",
        "int[] faceVertexCounts = [4, 4, 4, 4, 4, 4]\n"
        "        int[] faceVertexIndices = [0, 1, 3, 2, 2, 3, 5, 4, 4, 5, 7, 6, 6, 7, 1, 0, 1, 7, 5, 3, 6, 0, 2, 4]").replace(
        "(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)",
        "(-1, -1, 1), (1, -1, 1), (-1, 1, 1), (1, 1, 1), (-1, 1, -1), (1, 1, -1), (-1, -1, -1), (1, -1, -1)")
    _, result = mean_rgb(write(tmp_path, "cube.usda", cube), spp=1, max_depth=1, resolution=(64, 64))
    covered = result.rgba[..., 3] > 0.5
    rows = np.flatnonzero(covered.any(axis=1))
    assert 0.6 <= (rows[-1] - rows[0] + 1) / 64 <= 0.87
    assert not (covered[[0, -1]].any() or covered[:, [0, -1]].any())


RECT_LIGHT = """
    def RectLight "panel"
    {{
        float inputs:width = 1
        float inputs:height = 2
        float inputs:intensity = {intensity}
        float inputs:exposure = {exposure}
        bool inputs:normalize = {normalize}
        double3 xformOp:translate = (0.3, 1.5, 0.2)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
    }}
"""

EMISSIVE_QUAD = """
    def Mesh "panel" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-0.2, 1.5, -0.8), (0.8, 1.5, -0.8), (0.8, 1.5, 1.2), (-0.2, 1.5, 1.2)]
        rel material:binding = </World/Looks/glow>
    }
"""


LOW_CAMERA = camera_prim(10, 20, translate=(0, 1, 0), rotate=(-90, 0, 0))


def test_rect_light_and_equivalent_emissive_quad_give_the_same_image(tmp_path):
    """A one-sided RectLight and a two-sided emissive quad in its place light the floor the
    same; the camera sits below the panel, where both emit."""
    looks = lambert("grey", 0.5, 0) + lambert("glow", 0, 4.0)
    rect = write(tmp_path, "rect.usda",
                 stage_text(FLOOR + RECT_LIGHT.format(intensity=4.0, exposure=0, normalize=0), looks, LOW_CAMERA))
    quad = write(tmp_path, "quad.usda", stage_text(FLOOR + EMISSIVE_QUAD, looks, LOW_CAMERA))
    rect_rgb, rect_result = mean_rgb(rect, spp=32, max_depth=2, resolution=(24, 24))
    quad_rgb, quad_result = mean_rgb(quad, spp=32, max_depth=2, resolution=(24, 24))
    np.testing.assert_allclose(rect_rgb, quad_rgb, rtol=0.02)
    # Also pixel by pixel on a 4×4-pixel block average (noise per block well under 5 %).
    blocks = lambda rgba: rgba[..., 0].reshape(6, 4, 6, 4).mean(axis=(1, 3))
    np.testing.assert_allclose(blocks(rect_result.rgba), blocks(quad_result.rgba), rtol=0.08)


def test_normalize_divides_by_area_and_exposure_doubles(tmp_path):
    """UsdLux: normalize divides radiance by the light's area (1 × 2 here); each stop of
    exposure doubles it. Single light, same samples: the images match to float rounding."""
    looks = lambert("grey", 0.5, 0)
    images = {}
    for name, intensity, exposure, normalize in [
        ("plain", 2.0, 0, 0), ("normalized", 4.0, 0, 1), ("exposed", 1.0, 1, 0)
    ]:
        path = write(tmp_path, f"{name}.usda",
                     stage_text(FLOOR + RECT_LIGHT.format(intensity=intensity, exposure=exposure,
                                                          normalize=normalize), looks))
        images[name] = mean_rgb(path, spp=4, max_depth=2)[1].rgba
    np.testing.assert_allclose(images["normalized"], images["plain"], rtol=1e-5)
    np.testing.assert_allclose(images["exposed"], images["plain"], rtol=1e-5)


def test_same_inputs_give_identical_bytes_whatever_threads_and_batches(tmp_path):
    looks = lambert("grey", 0.5, 0)
    path = write(tmp_path, "rect.usda", stage_text(FLOOR + RECT_LIGHT.format(intensity=4, exposure=0, normalize=0), looks))
    scene, spec = load_stage(path)
    settings = TraceSettings(spp=8, max_depth=4, seed=7)
    one = trace_image(scene, spec, settings, resolution=(20, 12), threads=1, batch_paths=64).rgba
    two = trace_image(scene, spec, settings, resolution=(20, 12), threads=2, batch_paths=1000).rgba
    assert one.tobytes() == two.tobytes()
    other_seed = trace_image(scene, spec, TraceSettings(spp=8, max_depth=4, seed=8), resolution=(20, 12)).rgba
    assert other_seed.tobytes() != one.tobytes()
    # and the entry users use, in one batch, gives those bytes too
    framed = mean_rgb(path, spp=8, max_depth=4, resolution=(20, 12), seed=7)[1].rgba
    assert framed.tobytes() == one.tobytes()


def ggx_albedo_by_quadrature(alpha: float, cos_o: float) -> float:
    """∫ f_GGX(wo, wi) cos θi dωi for F = 1 by midpoint quadrature over the hemisphere,
    written out independently of the tracer's sampling code (isotropic GGX, separable
    Smith shadowing)."""
    theta = (np.arange(1500) + 0.5) / 1500 * (np.pi / 2)
    phi = (np.arange(1500) + 0.5) / 1500 * (2 * np.pi)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    wi = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])
    wo = np.array([np.sqrt(1 - cos_o**2), 0.0, cos_o])[:, None, None]
    half = wi + wo
    half /= np.linalg.norm(half, axis=0)
    a2 = alpha**2
    d = a2 / (np.pi * (half[2] ** 2 * (a2 - 1) + 1) ** 2)

    def g1(c):
        return 2 * c / (c + np.sqrt(a2 + (1 - a2) * c * c))

    f = d * g1(cos_o) * g1(wi[2]) / (4 * cos_o * wi[2])
    d_omega = np.sin(t) * (np.pi / 2 / 1500) * (2 * np.pi / 1500)
    return float(np.sum(f * wi[2] * d_omega))


@pytest.mark.parametrize("roughness", [0.5, 0.3])
def test_white_metal_under_a_uniform_dome_reflects_the_ggx_albedo(tmp_path, roughness):
    """A white metal plane (F = 1) under a uniform dome of radiance 1, seen at 60° from its
    normal: radiance = the GGX directional albedo, combining light and BSDF sampling."""
    looks = preview_surface(
        "metal",
        diffuseColor=("color3f", "(1, 1, 1)"),
        metallic=("float", "1"),
        roughness=("float", str(roughness)),
    )
    body = FLOOR.replace("/World/Looks/grey", "/World/Looks/metal") + """
    def DomeLight "sky"
    {
        float inputs:intensity = 1
    }
"""
    camera = camera_prim(500, 10, translate=(0, 2, 3.4641016), rotate=(-30, 0, 0))
    path = write(tmp_path, "metal.usda", stage_text(body, looks, camera))
    rgb, _ = mean_rgb(path, spp=64, max_depth=1)
    expected = ggx_albedo_by_quadrature(roughness**2, math.cos(math.radians(60)))
    assert 0.8 < expected < 1.0
    np.testing.assert_allclose(rgb, expected, rtol=0.01)


def test_textured_dome_follows_the_openexr_lat_long_orientation(tmp_path):
    """A lat-long dome bright only where longitude ∈ (−π/2, π/2), i.e. on the +Z side
    (OpenEXR convention: longitude 0 is +Z), lights a plane facing +Z fully (L = ρ) and
    one facing −Z not at all."""
    import OpenImageIO as oiio

    width, height = 64, 32
    pixels = np.zeros((height, width, 3), np.float32)
    pixels[:, width // 4: 3 * width // 4] = 1.0
    image = oiio.ImageBuf(oiio.ImageSpec(width, height, 3, oiio.FLOAT))
    image.set_pixels(oiio.ROI(), pixels)
    assert image.write(str(tmp_path / "half.exr"))

    looks = lambert("grey", 0.5, 0)
    results = {}
    for facing, rotate in (("front", 0), ("back", 180)):
        body = f"""
    def Mesh "wall" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        int[] faceVertexCounts = [4]
        int[] faceVertexIndices = [0, 1, 2, 3]
        point3f[] points = [(-50, -50, 0), (50, -50, 0), (50, 50, 0), (-50, 50, 0)]
        float3 xformOp:rotateXYZ = (0, {rotate}, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
        rel material:binding = </World/Looks/grey>
    }}
    def DomeLight "sky"
    {{
        asset inputs:texture:file = @./half.exr@
    }}
"""
        camera = camera_prim(50, 10, translate=(0, 0, 3 if rotate == 0 else -3), rotate=(0, rotate, 0))
        path = write(tmp_path, f"{facing}.usda", stage_text(body, looks, camera))
        results[facing] = mean_rgb(path, spp=32, max_depth=1)[0]
    np.testing.assert_allclose(results["front"], 0.5, rtol=0.02)
    np.testing.assert_allclose(results["back"], 0.0, atol=0.01)


GLASS_BALL_IN_UNIFORM_DOME = """
    def Sphere "ball" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        double radius = 1
        rel material:binding = </World/Looks/glass>
    }
    def DomeLight "sky"
    {
        float inputs:intensity = 1
    }
"""


@pytest.mark.parametrize("threshold, max_depth", [(0.0, 12), (0.5, 0)])
def test_transparent_and_cut_out_spheres_vanish_in_a_uniform_dome(tmp_path, threshold, max_depth):
    """A sphere of opacity 0 is not there: without a threshold every path passes straight
    through it (presence 0), and a cut-out (opacity below opacityThreshold) is crossed
    straight too. Neither is a bounce, so even max_depth 0 sees the dome's radiance through
    it, and a compositor sees through it as well: alpha 0. (Refraction is MaterialX's
    transmission: tests/test_looks.py.)"""
    looks = preview_surface(
        "glass",
        opacity=("float", "0"),
        opacityThreshold=("float", str(threshold)),
        ior=("float", "1.5"),
    )
    body = GLASS_BALL_IN_UNIFORM_DOME
    camera = camera_prim(50, 20, translate=(0, 0, 4))
    path = write(tmp_path, "glass.usda", stage_text(body, looks, camera))
    rgb, result = mean_rgb(path, spp=16, max_depth=max_depth)
    assert result.rgba[8, 8, 3] == 0.0  # the sphere, in the centre of the frame, covers nothing
    np.testing.assert_allclose(rgb, 1.0, rtol=0.01)


def test_event_subjects_are_the_distinct_object_material_pairs_in_order():
    """The vocabulary's surface subjects: np.unique of the (object, material) rows, computed
    through one key per pair (materials may be -1: no material)."""
    from pxr_layers.trace.render import _distinct_pairs

    rng = np.random.default_rng(0)
    objects, materials = rng.integers(0, 50, 20000), rng.integers(-1, 30, 20000)
    expected, expected_inverse = np.unique(np.stack([objects, materials], 1), axis=0, return_inverse=True)
    pairs, inverse = _distinct_pairs(objects, materials)
    assert np.array_equal(pairs, expected) and np.array_equal(inverse, expected_inverse.reshape(-1))
