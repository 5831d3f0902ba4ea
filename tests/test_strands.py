"""BasisCurves and Points (Embree's curve and sphere geometry) against what they must cover
and how they must shade.

Black strands in front of a glowing backdrop take from it exactly the area they cover:
straight curves of width w and length L, n·w·L, and spheres of diameter w, n·π(w/2)², over
the view's area at their distance (all of them in one plane parallel to the film, near the
axis, where the perspective scales lengths by one factor). A point's sphere under a uniform
sky shades like a tessellated UsdGeom.Sphere of its radius.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pxr_layers.errors import StageError
from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.extract import extract
from pxr_layers.paths.reader import PathIndex
from pxr_layers.request import RenderRequest
from pxr_layers.stage import load_stage

from camera_scenes import APERTURE, BLACK, FOCAL, GLOW, beauty, centimetre_stage, quad

RESOLUTION = 96
DISTANCE = 100.0  # cm from the camera to the strands
VIEW = APERTURE / FOCAL * DISTANCE  # cm across the view at the strands' distance


def stage(tmp_path, strands: str, name: str, light: str = "backdrop") -> str:
    """A centimetre stage: `strands` (prims bound to /World/black or not) 100 cm down −Z,
    before a glowing backdrop 200 cm away, or under a uniform sky (light="sky")."""
    lighting = (quad("backdrop", 400, 400, 2 * DISTANCE) if light == "backdrop"
                else 'def DomeLight "sky"\n    {\n        float inputs:intensity = 1\n    }')
    return centimetre_stage(tmp_path / f"{name}.usda", f"""{GLOW}{BLACK}
    {lighting}
    {strands}""")


def curves(name: str, kind: str, basis: str, wrap: str, counts: list[int], points: list[tuple], widths: str,
           black: bool = True) -> str:
    listed = ", ".join(f"({x}, {y}, {-DISTANCE})" for x, y in points)
    binding = ('(prepend apiSchemas = ["MaterialBindingAPI"])', "rel material:binding = </World/black>") if black \
        else ("", "")
    return f"""def BasisCurves "{name}" {binding[0]}
    {{
        uniform token type = "{kind}"
        uniform token basis = "{basis}"
        uniform token wrap = "{wrap}"
        int[] curveVertexCounts = {counts}
        point3f[] points = [{listed}]
        {widths}
        {binding[1]}
    }}"""


def occluded(path, spp: int = 64) -> float:
    """The fraction of the view the strands take from the backdrop (max_depth 0: what the
    camera sees directly)."""
    return float(np.mean(1.0 - beauty(path, RESOLUTION, spp)))


LENGTH, WIDTH = 40.0, 1.0  # cm
HEIGHTS = (-10.0, 0.0, 10.0)


@pytest.mark.parametrize("shape", ["linear", "bezier", "catmullRom-pinned", "bspline-periodic-ring"])
def test_straight_curves_cover_n_w_l(tmp_path, shape):
    half = LENGTH / 2
    if shape == "linear":
        prim = curves("hair", "linear", "bezier", "nonperiodic", [2] * 3,
                      [p for y in HEIGHTS for p in ((-half, y), (half, y))], f"float[] widths = [{WIDTH}]")
        expected = len(HEIGHTS) * WIDTH * LENGTH
    elif shape == "bezier":  # collinear control points: a straight curve from the first to the last
        prim = curves("hair", "cubic", "bezier", "nonperiodic", [4] * 3,
                      [p for y in HEIGHTS for p in ((-half, y), (-5, y), (7, y), (half, y))],
                      f"float[] widths = [{WIDTH}] (interpolation = \"constant\")")
        expected = len(HEIGHTS) * WIDTH * LENGTH
    elif shape == "catmullRom-pinned":  # pinned: through its end points
        prim = curves("hair", "cubic", "catmullRom", "pinned", [5] * 3,
                      [p for y in HEIGHTS for p in ((-half, y), (-10, y), (0, y), (10, y), (half, y))],
                      f"float[] widths = [{', '.join([str(WIDTH)] * 15)}] (interpolation = \"vertex\")")
        expected = len(HEIGHTS) * WIDTH * LENGTH
    else:  # a periodic B-spline of 8 points on a circle: a closed ring near radius R
        angles = np.linspace(0, 2 * np.pi, 8, endpoint=False)
        radius = 15.0  # the control polygon's
        prim = curves("hair", "cubic", "bspline", "periodic", [8],
                      [(radius * np.cos(a), radius * np.sin(a)) for a in angles], f"float[] widths = [{WIDTH}]")
        # a uniform cubic B-spline on a regular octagon is nearly a circle of radius R·(2 + cos(π/4))/3
        ring = radius * (2 + np.cos(np.pi / 4)) / 3
        expected = 2 * np.pi * ring * WIDTH
    fraction = occluded(stage(tmp_path, prim, shape))
    assert fraction == pytest.approx(expected / VIEW ** 2, rel=0.03)


@pytest.mark.parametrize("facing, expected", [("(0, 0, 1)", WIDTH * 4 * LENGTH), ("(0, 1, 0)", 0.0)])
@pytest.mark.parametrize("kind", ["linear", "catmullRom"])
def test_curves_with_normals_are_flat_ribbons_facing_them(tmp_path, facing, expected, kind):
    """A ribbon 4 cm wide facing the camera covers w·L; turned edge-on (its normal across the
    view), next to nothing."""
    half = LENGTH / 2
    points = [(-half, 0), (half, 0)] if kind == "linear" else [(-half, 0), (-10, 0), (10, 0), (half, 0)]
    prim = curves("ribbon", "linear" if kind == "linear" else "cubic", "catmullRom", "pinned", [len(points)], points,
                  f"float[] widths = [{4 * WIDTH}]\n        normal3f[] normals = [{facing}] (interpolation = \"constant\")")
    fraction = occluded(stage(tmp_path, prim, f"ribbon_{kind}_{facing[4]}"))
    assert fraction == pytest.approx(expected / VIEW ** 2, abs=0.02 * 4 * WIDTH * LENGTH / VIEW ** 2)


def test_point_instanced_curves_are_a_copy_per_instance(tmp_path):
    """A tuft (one straight curve) instanced three times covers three times its w·L, each copy
    an object of its instance's path."""
    prim = f"""def PointInstancer "tufts"
    {{
        rel prototypes = </World/tufts/Prototypes/tuft>
        int[] protoIndices = [0, 0, 0]
        point3f[] positions = [(0, -10, {-DISTANCE}), (0, 0, {-DISTANCE}), (0, 10, {-DISTANCE})]
        def Scope "Prototypes"
        {{
            {curves("tuft", "linear", "bezier", "nonperiodic", [2], [(-LENGTH / 2, 0), (LENGTH / 2, 0)],
                    f"float[] widths = [{WIDTH}]").replace(str(-DISTANCE), "0")}
        }}
    }}"""
    path = stage(tmp_path, prim, "tufts")
    scene, _ = load_stage(path)
    assert [strands.path for strands in scene.strands] == [f"/World/tufts/instance_{n}/tuft" for n in range(3)]
    assert occluded(path) == pytest.approx(3 * WIDTH * LENGTH / VIEW ** 2, rel=0.03)


def test_points_cover_n_pi_w2_over_4(tmp_path):
    centres = [(-8, -8), (8, -8), (0, 0), (-8, 8), (8, 8)]
    listed = ", ".join(f"({x}, {y}, {-DISTANCE})" for x, y in centres)
    prim = f"""def Points "dots" (prepend apiSchemas = ["MaterialBindingAPI"])
    {{
        point3f[] points = [{listed}]
        float[] widths = [4, 4, 4, 4, 4] (interpolation = "vertex")
        rel material:binding = </World/black>
    }}"""
    # a sphere's silhouette subtends asin(r / d): a disc of radius d·tan(asin(r / d)) in its plane
    radius = DISTANCE * np.tan(np.arcsin(2.0 / DISTANCE))
    fraction = occluded(stage(tmp_path, prim, "dots"))
    assert fraction == pytest.approx(len(centres) * np.pi * radius ** 2 / VIEW ** 2, rel=0.03)


def test_a_point_shades_like_a_tessellated_sphere_under_a_sky(tmp_path):
    point = 'def Points "ball"\n    {\n        point3f[] points = [(0, 0, -100)]\n        float[] widths = [40]\n    }'
    sphere = ('def Sphere "ball"\n    {\n        double radius = 20\n        double3 xformOp:translate = (0, 0, -100)\n'
              '        uniform token[] xformOpOrder = ["xformOp:translate"]\n    }')
    images = []
    for name, prim in (("point", point), ("sphere", sphere)):
        request = RenderRequest(stage=stage(tmp_path, prim, name, light="sky"), resolution=(64, 64), spp=64,
                                max_depth=4, keep_index=False, previews=False, default_lights=False)
        images.append(render_frame(request, output=tmp_path).rgba.astype(np.float64))
    point_image, sphere_image = images
    inside = (point_image[..., 3] > 0.999) & (sphere_image[..., 3] > 0.999)
    assert point_image[..., 3].sum() == pytest.approx(sphere_image[..., 3].sum(), rel=0.01)  # silhouettes
    np.testing.assert_allclose(point_image[inside, :3].mean(axis=0), sphere_image[inside, :3].mean(axis=0), rtol=0.02)


def test_strands_are_objects_the_index_names(tmp_path):
    """Paths that reach the camera off the curves are the layer named by the curves' name."""
    prim = curves("hair", "linear", "bezier", "nonperiodic", [2], [(-20, 0), (20, 0)], "float[] widths = [3]",
                  black=False)
    request = RenderRequest(stage=stage(tmp_path, prim, "named", light="sky"), resolution=(48, 48), spp=8,
                            max_depth=2, previews=False, default_lights=False)
    result = render_frame(request, output=tmp_path)
    hair = extract(PathIndex(result.index_path), {"hair": "C<R.'hair'>.*"}).layers["hair"].astype(np.float64)
    assert hair.sum() > 0
    rows = np.flatnonzero(hair[..., 0].sum(axis=1) > 0)
    assert rows.min() >= 20 and rows.max() <= 27  # the curve's band of rows, around the middle
    assert np.all(hair <= result.rgba[..., :3] + 1e-6)  # a part of the beauty


@pytest.mark.parametrize("prim, radius", [
    ('def Points "ball"\n    {\n        point3f[] points = [(0, 0, -100)]\n        float[] widths = [40]\n    }', 0.2),
    (curves("ball", "linear", "bezier", "nonperiodic", [2], [(-20, 0), (20, 0)], "float[] widths = [8]", black=False),
     0.04),
])
def test_strand_hits_carry_the_curvature_of_their_sphere_or_tube(tmp_path, prim, radius):
    """The index's curvature norm C at a point's sphere, or a curve's tube, is 1/r: every path
    that starts on it meets the condition that C lies in 1/r's octave, between the powers of
    two around it (thresholds a merged index answers exactly: paths/format.py)."""
    request = RenderRequest(stage=stage(tmp_path, prim, "curvature", light="sky"), resolution=(32, 32), spp=4,
                            max_depth=1, previews=False, default_lights=False)
    index = PathIndex(render_frame(request, output=tmp_path).index_path)
    low, high = 2.0 ** math.floor(math.log2(0.9 / radius)), 2.0 ** math.ceil(math.log2(1.1 / radius))
    assert high == 2 * low  # 1/r ± 10 % inside one octave
    layers = extract(index, {"all": "C<R.'ball'>.*",
                             "curved": f"C<R.'ball'>C(|S_C| > {low:g} and |S_C| < {high:g}).*"}).layers
    assert layers["all"].sum() > 0
    np.testing.assert_allclose(layers["curved"], layers["all"], rtol=1e-6)


@pytest.mark.parametrize("attributes, message", [
    ('int[] curveVertexCounts = [3]\n        point3f[] points = [(0, 0, 0), (1, 0, 0)]',
     "curveVertexCounts add up to 3 vertices but points has 2"),
    ('int[] curveVertexCounts = [2]\n        point3f[] points = [(0, 0, 0), (1, 0, 0)]\n        float[] widths = [-1]',
     "widths holds -1"),
    ('uniform token type = "cubic"\n        uniform token basis = "hermite"\n        int[] curveVertexCounts = [4]\n'
     '        point3f[] points = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0)]', "basis is 'hermite'"),
    ('uniform token type = "cubic"\n        uniform token basis = "bezier"\n        int[] curveVertexCounts = [5]\n'
     '        point3f[] points = [(0, 0, 0), (1, 0, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0)]', "a bezier curve needs 3k"),
])
def test_malformed_curves_are_refused_naming_the_prim(tmp_path, attributes, message):
    prim = f'def BasisCurves "bad"\n    {{\n        {attributes}\n    }}'
    with pytest.raises(StageError, match=message) as error:
        load_stage(stage(tmp_path, prim, "bad"))
    assert "/World/bad" in str(error.value)
