"""Hostile stages (issue 18): what the stage reader is given that no image can be made of.

The rule (stage/reader.py, walk.py): a value that is wrong wherever it is read (a camera's
lens, an implicit shape's size, an attribute of another type than its schema's, a broken
topology) is an error: exit 1, one line naming the file, the prim and the attribute. Data
that goes bad by being computed (NaN or infinite transforms, instance arrays and mesh
points; geometry placed out of float32's reach) skips its prim, or its instances, with one
warning line naming them and the attribute; so do a size of 0 and faces of fewer than 3
vertices, which describe nothing rather than something wrong. A light's image is read with
its NaN, infinite and negative texels as 0, with one warning naming the file and how many.
Each case renders an 8 × 8 frame at 1 spp through the command line, in this process.
"""

from __future__ import annotations

import contextlib
import logging
import warnings

import numpy as np
import OpenEXR
import OpenImageIO as oiio
import pytest
from test_cli import ball_lit_by, bad_sky

from pxr_layers.cli.main import main
from pxr_layers.stage.diagnostics import Diagnostics
from pxr_layers.stage.placement import MAX_WORLD_COORDINATE
from pxr_layers.stage.textures import MAX_LIGHT_TEXEL, TextureLibrary
from pxr_layers.trace import texture_cache
from pxr_layers.trace.texture_cache import resident_textures

TINY = ["--spp", "1", "--resolution", "8", "8", "--quiet", "--no-previews", "--no-index"]
SUN = '    def DistantLight "sun"\n    {\n    }\n'


@contextlib.contextmanager
def own_logging():
    """The root logger as a fresh process has it (no handlers), so that main's basicConfig
    writes its warning lines to the (captured) sys.stderr; restored afterwards."""
    root = logging.getLogger()
    handlers, level, showwarning = root.handlers[:], root.level, warnings.showwarning
    root.handlers = []
    try:
        yield
    finally:
        root.handlers, warnings.showwarning = handlers, showwarning
        root.setLevel(level)


def render(capsys, tmp_path, text: str, name: str = "shot.usda") -> tuple[int, list[str], np.ndarray | None]:
    """`pxr-layers render` of the stage `text`: (exit code, stderr lines, RGBA pixels or None)."""
    shot = tmp_path / name
    if text:
        shot.write_text(text)
    capsys.readouterr()
    with own_logging():
        code = main(["render", str(shot), "-o", str(tmp_path / "out"), *TINY])
    stderr = capsys.readouterr().err
    assert "Traceback" not in stderr and "internal error" not in stderr, stderr
    written = tmp_path / "out" / f"{shot.stem}.exr"
    pixels = OpenEXR.File(str(written)).channels()["RGBA"].pixels if written.exists() else None
    return code, stderr.strip().splitlines(), pixels


def stage(extra: str = "", camera: str = "") -> str:
    """The camera and ball of test_cli.ball_lit_by under a distant light, with `camera`
    authored on the camera and the prims `extra` beside them (USD text)."""
    text = ball_lit_by(SUN + extra)
    return text.replace('def Camera "cam"\n    {\n', f'def Camera "cam"\n    {{\n        {camera}\n', 1)


def prim(type_name: str, body: str, name: str = "bad") -> str:
    return f'    def {type_name} "{name}"\n    {{\n        {body}\n    }}\n'


QUAD = {
    "points": "point3f[] points = [(-1, -1, -2), (1, -1, -2), (1, 1, -2), (-1, 1, -2)]",
    "counts": "int[] faceVertexCounts = [4]",
    "indices": "int[] faceVertexIndices = [0, 1, 2, 3]",
}


def mesh(**authored: str) -> str:
    """A quad Mesh /World/bad behind the ball, with some of its attributes replaced."""
    return prim("Mesh", "\n        ".join({**QUAD, **authored}.values()))


def instancer(arrays: str, count: int = 3) -> str:
    """A PointInstancer /World/bad of `count` small cubes, with `arrays` authored on it."""
    return f'''    def PointInstancer "bad"
    {{
        rel prototypes = </World/bad/protos/cube>
        int[] protoIndices = {[0] * count}
        {arrays}
        def Scope "protos"
        {{
            def Cube "cube"
            {{
                double size = 0.2
            }}
        }}
    }}
'''


def positions(count: int = 3) -> str:
    return f"point3f[] positions = {[(n - 1, 1.5, 0) for n in range(count)]}"


# --- errors: one line naming the file, the prim and the attribute ---------------------------

ERRORS = {
    # the camera
    "focalLength 0": (stage(camera="float focalLength = 0"), "/World/cam", "focalLength is 0"),
    "focalLength NaN": (stage(camera="float focalLength = nan"), "/World/cam", "focalLength is nan"),
    "focalLength inf": (stage(camera="float focalLength = inf"), "/World/cam", "focalLength is inf"),
    "focalLength negative": (stage(camera="float focalLength = -35"), "/World/cam", "focalLength is -35"),
    "focalLength a string": (stage(camera='string focalLength = "50mm"'), "/World/cam",
                             "focalLength is authored as string: it must be a number"),
    "horizontalAperture 0": (stage(camera="float horizontalAperture = 0"), "/World/cam", "horizontalAperture is 0"),
    "horizontalAperture NaN": (stage(camera="float horizontalAperture = nan"), "/World/cam",
                               "horizontalAperture is nan"),
    "verticalAperture negative": (stage(camera="float verticalAperture = -1"), "/World/cam", "verticalAperture is -1"),
    "horizontalApertureOffset NaN": (stage(camera="float horizontalApertureOffset = nan"), "/World/cam",
                                     "horizontalApertureOffset is nan"),
    "clippingRange inverted": (stage(camera="float2 clippingRange = (100, 1)"), "/World/cam",
                               "clippingRange is (100, 1): it must be 0 <= near < far"),
    "clippingRange NaN": (stage(camera="float2 clippingRange = (nan, 100)"), "/World/cam", "clippingRange is (nan, 100)"),
    "clippingRange infinite": (stage(camera="float2 clippingRange = (1, inf)"), "/World/cam", "clippingRange is (1, inf)"),
    "clippingRange a float": (stage(camera="float clippingRange = 1"), "/World/cam",
                              "clippingRange is authored as float: it must be float2"),
    # mesh attributes of another type than the schema's
    "faceVertexCounts string[]": (stage(mesh(counts='string[] faceVertexCounts = ["a"]')), "/World/bad",
                                  "faceVertexCounts is authored as string[]: it must be int[]"),
    "faceVertexCounts string": (stage(mesh(counts='string faceVertexCounts = "4"')), "/World/bad",
                                "faceVertexCounts is authored as string: it must be int[]"),
    "faceVertexCounts float[]": (stage(mesh(counts="float[] faceVertexCounts = [4.5]")), "/World/bad",
                                 "faceVertexCounts is authored as float[]: it must be int[]"),
    "points string[]": (stage(mesh(points='string[] points = ["a"]')), "/World/bad",
                        "points is authored as string[]: it must be point3f[]"),
    "points int3[]": (stage(mesh(points="int3[] points = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]")),
                      "/World/bad", "points is authored as int3[]: it must be point3f[]"),
    "points float[]": (stage(mesh(points="float[] points = [0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0]")), "/World/bad",
                       "points is authored as float[]: it must be point3f[]"),
    "faceVertexIndices float[]": (stage(mesh(indices="float[] faceVertexIndices = [0, 1, 2, 3]")), "/World/bad",
                                  "faceVertexIndices is authored as float[]: it must be int[]"),
    "faceVertexIndices int2[]": (stage(mesh(indices="int2[] faceVertexIndices = [(0, 1), (2, 3)]")), "/World/bad",
                                 "faceVertexIndices is authored as int2[]: it must be int[]"),
    # topology
    "a negative face size": (stage(mesh(counts="int[] faceVertexCounts = [4, -4, 8]",
                                        indices="int[] faceVertexIndices = [0, 1, 2, 3, 0, 1, 2, 3]")),
                             "/World/bad", "faceVertexCounts[1] is -4: a face cannot have a negative number"),
    # implicit sizes no shape has
    "Sphere radius -1": (stage(prim("Sphere", "double radius = -1")), "/World/bad", "radius is -1: a size must be"),
    "Sphere radius NaN": (stage(prim("Sphere", "double radius = nan")), "/World/bad", "radius is nan"),
    "Sphere radius a string": (stage(prim("Sphere", 'string radius = "big"')), "/World/bad",
                               "radius is authored as string: it must be a number"),
    "Cube size -2": (stage(prim("Cube", "double size = -2")), "/World/bad", "size is -2"),
    "Cube size inf": (stage(prim("Cube", "double size = inf")), "/World/bad", "size is inf"),
    "Cylinder height -1": (stage(prim("Cylinder", "double height = -1")), "/World/bad", "height is -1"),
    "Cylinder radius NaN": (stage(prim("Cylinder", "double radius = nan")), "/World/bad", "radius is nan"),
    "Cone radius inf": (stage(prim("Cone", "double radius = inf")), "/World/bad", "radius is inf"),
    "Capsule height NaN": (stage(prim("Capsule", "double height = nan")), "/World/bad", "height is nan"),
    "Capsule radius -1": (stage(prim("Capsule", "double radius = -1")), "/World/bad", "radius is -1"),
    # instancer arrays and transforms of another type than the schema's
    "positions string[]": (stage(instancer('string[] positions = ["a", "b", "c"]')), "/World/bad",
                           "positions is authored as string[]: it must be point3f[]"),
    "protoIndices float[]": (stage(instancer(positions()).replace("int[] protoIndices = [0, 0, 0]",
                                                                  "float[] protoIndices = [0, 0, 0]")),
                             "/World/bad", "protoIndices is authored as float[]: it must be int[]"),
    "orientations float4[]": (stage(instancer(positions() + "\n        float4[] orientations = "
                                              "[(1, 0, 0, 0), (1, 0, 0, 0), (1, 0, 0, 0)]")),
                              "/World/bad", "orientations is authored as float4[]: it must be quath[]"),
    "xformOp:translate a string": (stage(prim("Cube", 'string xformOp:translate = "x"\n'
                                                      '        uniform token[] xformOpOrder = ["xformOp:translate"]')),
                                   "/World/bad", "its transform cannot be computed: Invalid combination of opType"),
}


@pytest.mark.parametrize("case", sorted(ERRORS))
def test_a_value_no_image_can_be_made_of_is_one_line_naming_file_prim_and_attribute(tmp_path, capsys, case):
    text, prim_path, said = ERRORS[case]
    code, lines, pixels = render(capsys, tmp_path, text)
    assert code == 1 and pixels is None
    (line,) = lines
    assert line.startswith(f"pxr-layers: error: {tmp_path / 'shot.usda'}, prim {prim_path}: ") and said in line, line
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


# --- warnings: the prim (or instances) skipped, one line naming them; a finite image --------

WARNINGS = {
    "Sphere radius 0": (stage(prim("Sphere", "double radius = 0")), "sizes make no surface skipped: /World/bad (radius is 0)"),
    "Cube size 0": (stage(prim("Cube", "double size = 0")), "/World/bad (size is 0)"),
    "NaN translate": (stage(prim("Cube", "double3 xformOp:translate = (nan, 0, 0)\n"
                                         '        uniform token[] xformOpOrder = ["xformOp:translate"]')),
                      "NaN or infinite transforms skipped (the xformOp at fault in brackets): /World/bad (xformOp:translate)"),
    "infinite scale": (stage(prim("Sphere", "float3 xformOp:scale = (1, inf, 1)\n"
                                            '        uniform token[] xformOpOrder = ["xformOp:scale"]')),
                       "/World/bad (xformOp:scale)"),
    "NaN on an ancestor": (stage('    def Xform "group"\n    {\n'
                                 "        double3 xformOp:translate = (0, nan, 0)\n"
                                 '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
                                 + prim("Cube", "double size = 0.5").replace("\n    ", "\n        ") + "    }\n"),
                           "/World/group/bad (/World/group.xformOp:translate)"),
    "NaN mesh points": (stage(mesh(points="point3f[] points = [(nan, -1, -2), (1, -1, -2), (1, 1, -2), (-1, 1, -2)]")),
                        "meshes with NaN or infinite points skipped: /World/bad (1 of 4 points)"),
    "infinite mesh points": (stage(mesh(points="point3f[] points = [(-1, -1, -2), (1, -inf, -2), (1, 1, -2), (inf, 1, -2)]")),
                             "/World/bad (2 of 4 points)"),
    "faces of 0 and 2 vertices": (stage(mesh(counts="int[] faceVertexCounts = [4, 0, 2]",
                                             indices="int[] faceVertexIndices = [0, 1, 2, 3, 0, 1]")),
                                  "faces of fewer than 3 vertices left out (they have no surface): "
                                  "/World/bad (2 faces, the first faceVertexCounts[1] = 0)"),
    "a NaN instance position": (stage(instancer(positions().replace("(1, 1.5, 0)", "(nan, 1.5, 0)"))),
                                "dropped 1 point instances with unusable data from: /World/bad "
                                "(1 of 3 instances: 1 with NaN or infinite positions)"),
    "an infinite instance orientation": (stage(instancer(positions() + "\n        quath[] orientations = "
                                                         "[(1, 0, 0, 0), (inf, 0, 0, 0), (1, 0, 0, 0)]")),
                                         "(1 of 3 instances: 1 with NaN or infinite orientations)"),
    "NaN instance scales": (stage(instancer(positions() + "\n        float3[] scales = "
                                            "[(1, 1, 1), (nan, 1, 1), (1, 1, -inf)]")),
                            "(2 of 3 instances: 2 with NaN or infinite scales)"),
    "ragged arrays and an infinite scale": (stage(instancer(positions() + "\n        float3[] scales = "
                                                           "[(1, 1, 1), (inf, 1, 1)]")),
                                            "(2 of 3 instances: 1 past the 2 scales, 1 with NaN or infinite scales)"),
    "every instance NaN": (stage(instancer("point3f[] positions = [(nan, 0, 0), (0, nan, 0), (0, 0, nan)]")),
                           "PointInstancers none of whose instances has usable data skipped: /World/bad "
                           "(3 of 3 instances: 3 with NaN or infinite positions)"),
    "placed out of reach": (stage(prim("Cube", "double3 xformOp:scale = (1e12, 1e12, 1e12)\n"
                                               "        double3 xformOp:translate = (0, 0, -10)\n"
                                               '        uniform token[] xformOpOrder = ["xformOp:scale", '
                                               '"xformOp:translate"]')),
                            f"gprims placed beyond {MAX_WORLD_COORDINATE:g} m from the origin (or whose placed points "
                            "overflow) skipped: /World/bad"),
    "a radius that overflows": (stage(prim("Sphere", "double radius = 1e300")), "skipped: /World/bad"),
}


@pytest.mark.parametrize("case", sorted(WARNINGS))
def test_computed_data_gone_bad_skips_its_prim_with_one_line_naming_it(tmp_path, capsys, case):
    text, said = WARNINGS[case]
    code, lines, pixels = render(capsys, tmp_path, text)
    assert code == 0
    (line,) = lines
    assert line.startswith("pxr-layers: WARNING: ") and said in line, line
    assert np.isfinite(pixels).all() and pixels[..., :3].min() >= 0.0
    assert pixels[..., 3].max() == 1.0  # the ball still renders


@pytest.mark.parametrize("texel", [float("nan"), float("inf"), -5.0, 1e38])
def test_a_dome_image_of_texels_no_light_has_is_read_sanitised_with_one_warning(tmp_path, capsys, texel):
    bad_sky(tmp_path, texel)  # sky.usda: the ball under a dome whose image holds `texel` in half its texels
    code, lines, pixels = render(capsys, tmp_path, "", name="sky.usda")
    assert code == 0
    (line,) = lines
    assert line.startswith(f"pxr-layers: WARNING: texture {tmp_path / 'sky.exr'} (used by /World/sky): 16 of 32 "
                           "texels are NaN, infinite or negative (read as 0)"), line
    assert np.isfinite(pixels).all() and pixels[..., :3].min() >= 0.0
    assert pixels[..., :3].max() > 0.5  # the dome still lights the ball and fills the background
    if texel == 1e38:
        assert f"or above {MAX_LIGHT_TEXEL:g} (read as that)" in line and pixels.max() <= MAX_LIGHT_TEXEL


def test_material_textures_lose_only_their_non_finite_texels_and_every_read_says_so(tmp_path, caplog):
    """NaN and infinities are 0 in every texture; negative texels stay in a material's (a
    normal map's, a displacement's) but not in a light's; a later frame that takes the
    remembered images (the stage reader's for lights, the texture cache's for materials)
    warns again, as each frame's warnings are its own."""
    path = str(tmp_path / "signed.exr")
    image = oiio.ImageOutput.create(path)
    image.open(path, oiio.ImageSpec(4, 1, 1, "float"))
    image.write_image(np.array([[[np.nan], [-2.0], [0.5], [np.inf]]], np.float32))
    image.close()
    for _ in range(2):
        caplog.clear()
        diagnostics = Diagnostics()
        library = TextureLibrary(diagnostics)
        material = library.load(path, "raw", "/World/look/normals")
        light = library.load(path, "raw", "/World/sky", light=True)
        library.remember()
        resident = resident_textures([library.images[material.index]])
        assert resident.finest_linear(0)[0, :, 0].tolist() == [0.0, -2.0, 0.5, 0.0]
        assert library.images[light.index].pixels[0, :, 0].tolist() == [0.0, 0.0, 0.5, 0.0]
        (light_warning,) = diagnostics.finish()
        assert light_warning.startswith(f"texture {path} (used by /World/sky): 3 of 4 texels are NaN, infinite or negative")
        assert [record.getMessage() for record in caplog.records if record.name == texture_cache.__name__] == [
            f"texture {path} (used by /World/look/normals): 2 of 4 texels are NaN or infinite (read as 0)"]