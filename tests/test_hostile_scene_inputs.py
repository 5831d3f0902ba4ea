"""Hostile scene inputs (issue 33): what a stage, the files it names and the files a command
is given can hold that no image should be made of, and what each one gets.

* Inputs that are not regular files (inputs.py): a FIFO, a device or a folder given as the
  stage, a recipe layer, a path index, a job file (or its stage), an EXR to ``nuke``: one
  line naming the file, exit 1, at once (a FIFO used to block the command forever). One
  named by the stage (an IES profile, a texture, a MaterialX document) is a warning, as an
  unreadable one is, and the render goes on.
* Numbers that are not numbers or are absurd (values.checked, one rule): NaN, infinite or
  out-of-range light controls, IES profiles, UsdPreviewSurface and MaterialX inputs (USD
  networks and .mtlx documents) are one line naming the file, the prim (or node) and the
  attribute, exit 1; a light placed out of reach is skipped with a warning naming it, an
  IES profile of no light warns that its lights are black.
* Unbounded scenes (budgets.py, textures.py): a mesh declaring 1e8 faces or indices, a
  PointInstancer of 1e7 instances, instances past the triangle or mesh budget are one line
  naming the prim and the budget within seconds, from a .usdc of a few kilobytes (crate
  files compress runs); a 20000 × 20000 PNG (a 0.4 MB decompression bomb) renders, read at
  a reduced resolution with a warning; a header claiming 1e10 texels is not decoded; a
  tiled EXR over budget is read at its first MIP level that fits.

Every case runs the command line in this process under a hang alarm that also releases a
reader blocked on a FIFO.
"""

from __future__ import annotations

import os
import shutil
import signal
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import OpenImageIO as oiio
import pytest
from pxr import Gf, Usd, UsdGeom, Vt
from test_cli import RENDER_DIR, ball_lit_by, ball_of
from test_hostile_stage import TINY, own_logging

from pxr_layers.cli.main import main
from pxr_layers.stage.budgets import MAX_SCENE_MESHES, MAX_SCENE_TRIANGLES
from pxr_layers.texture_files import MAX_FILE_TEXELS, MAX_TEXTURE_TEXELS
from pxr_layers.stage.values import MAX_ARRAY_VALUES

HANG_SECONDS = 60
"""Longer than any case takes on a slow machine: past it, the command hangs."""


def run(capsys, argv: list[str], fifos: tuple[Path, ...] = ()) -> tuple[int, list[str]]:
    """main(argv) here: (exit code, stderr lines); no traceback, no internal error. A hang
    past HANG_SECONDS opens each of ``fifos`` for writing (a blocked reader then reads its
    end) and fails."""

    def hang(signal_number, frame):
        for fifo in fifos:
            try:
                os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass
        raise TimeoutError(f"no answer in {HANG_SECONDS} s: {argv}")

    capsys.readouterr()
    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(HANG_SECONDS)
    try:
        with own_logging():
            code = main(argv)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
    stderr = capsys.readouterr().err
    assert "Traceback" not in stderr and "internal error" not in stderr, stderr
    return code, stderr.strip().splitlines()


def render(capsys, shot: Path, *extra: str, fifos=()) -> tuple[int, list[str], np.ndarray | None]:
    """`pxr-layers render` of ``shot``: (exit code, stderr lines, RGBA pixels or None)."""
    code, lines = run(capsys, ["render", str(shot), "-o", str(shot.parent / "out"), *TINY, *extra], fifos)
    written = shot.parent / "out" / f"{shot.stem}.exr"
    pixels = OpenEXR.File(str(written)).channels()["RGBA"].pixels if written.exists() else None
    return code, lines, pixels


def one_error(code: int, lines: list[str], file: Path | str, *said: str) -> str:
    """The one error line, naming ``file`` first, with each of ``said``."""
    assert code == 1, lines
    (line,) = lines
    assert line.startswith(f"pxr-layers: error: {file}"), line
    assert all(part in line for part in said), (line, said)
    return line


# --- inputs that are not regular files ---------------------------------------------------

@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "pipe.pxlidx"  # the suffix view reads an index by
    os.mkfifo(path)
    return path


def _shot(tmp_path: Path) -> Path:
    shot = tmp_path / "shot.usda"
    shot.write_text(ball_lit_by('    def DistantLight "sun"\n    {\n    }\n'))
    return shot


# command (with {fifo}, {shot}, {folder} placeholders), what the FIFO is called, the file named
NOT_REGULAR = {
    "render a FIFO stage": (["render", "{fifo}", "-o", "{folder}/out"], "a USD file"),
    "render --recipe a FIFO": (["render", "{shot}", "--recipe", "{fifo}", "-o", "{folder}/out"], "a USD file"),
    "index info a FIFO": (["index", "info", "{fifo}"], "a path index"),
    "extract a FIFO": (["extract", "{fifo}", "-o", "{folder}/x.exr"], "a path index"),
    "suggest a FIFO": (["suggest", "{fifo}"], "a path index"),
    "view a FIFO": (["view", "{fifo}", "--no-browser"], "a path index"),
    "job run a FIFO": (["job", "run", "{fifo}"], "a job file"),
    "nuke a FIFO": (["nuke", "{fifo}"], "a multipart EXR"),
}


@pytest.mark.parametrize("case", sorted(NOT_REGULAR))
def test_a_fifo_given_as_an_input_is_refused_at_once_naming_it(tmp_path, capsys, fifo, case):
    words, what = NOT_REGULAR[case]
    shot = _shot(tmp_path)
    argv = [word.format(fifo=fifo, shot=shot, folder=tmp_path) for word in words]
    code, lines = run(capsys, argv, (fifo,))
    line = lines[-1]
    assert code == 1 and len(lines) == 1, lines
    assert f"{fifo}: is a FIFO (named pipe), not {what}" in line, line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("device, kind", [(os.devnull, "a character device"), ("{folder}", "a directory")])
def test_a_device_or_a_folder_given_as_the_stage_is_refused_naming_it(tmp_path, capsys, device, kind):
    path = device.format(folder=tmp_path)
    code, lines = run(capsys, ["render", path, "-o", str(tmp_path / "out")])
    one_error(code, lines, path, f"is {kind}, not a USD file")


def test_a_job_whose_stage_is_a_fifo_is_refused_naming_the_key(tmp_path, capsys, fifo):
    job = tmp_path / "shot.toml"
    job.write_text(f'stage = "{fifo.name}"\n')
    code, lines = run(capsys, ["job", "run", str(job)], (fifo,))
    one_error(code, lines, job, f"stage: {fifo}: is a FIFO (named pipe), not a USD file")


def _fifo_named_by_the_stage(tmp_path: Path, name: str) -> Path:
    os.mkfifo(tmp_path / name)
    return tmp_path / name


def test_files_the_stage_names_that_are_fifos_are_warnings_and_the_render_goes_on(tmp_path, capsys):
    """An IES profile, a texture and a MaterialX document that are FIFOs: each unreadable,
    with a warning naming it (as a missing one is), never a hang."""
    fifos = tuple(_fifo_named_by_the_stage(tmp_path, name) for name in ("spot.ies", "wood.png", "look.mtlx"))
    shot = tmp_path / "shot.usda"
    shot.write_text(ball_of('color3f inputs:diffuseColor.connect = </World/look/surface/tex.outputs:rgb>\n'
                            '            def Shader "tex"\n            {\n'
                            '                uniform token info:id = "UsdUVTexture"\n'
                            '                asset inputs:file = @./wood.png@\n                float3 outputs:rgb\n'
                            '            }').replace('    def DomeLight "sky"', '''    def SphereLight "spot" (prepend apiSchemas = ["ShapingAPI"])
    {
        asset inputs:shaping:ies:file = @./spot.ies@
        double3 xformOp:translate = (0, 3, 3)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Sphere "other" (prepend apiSchemas = ["MaterialBindingAPI"])
    {
        rel material:binding = </World/Looks/M>
        double3 xformOp:translate = (3, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
    def Scope "Looks" (prepend references = @./look.mtlx@</MaterialX/Materials>)
    {
    }
    def DomeLight "sky"'''))
    code, lines, pixels = render(capsys, shot, fifos=fifos)
    assert code == 0 and np.isfinite(pixels).all()
    for fifo in fifos:
        (line,) = [line for line in lines if str(fifo) in line]
        assert line.startswith("pxr-layers: WARNING: ") and "is a FIFO (named pipe)" in line, line


# --- numbers that are not numbers, or absurd ----------------------------------------------

def lamp(controls: str, kind: str = "SphereLight") -> str:
    """The ball under one shaped light /World/lamp with ``controls`` authored (USD text)."""
    return ball_lit_by(f'''    def {kind} "lamp" (prepend apiSchemas = ["ShapingAPI"])
    {{
        {controls}
        double3 xformOp:translate = (0, 3, 3)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
''')


def nested(input_line: str, shader_id: str, body: str, output: str = "float3 outputs:rgb") -> str:
    """The ball's UsdPreviewSurface with ``input_line`` connected to a shader "tex" of
    ``shader_id`` (authored ``body``) under it."""
    return ball_of(f'{input_line}\n            def Shader "tex"\n            {{\n'
                   f'                uniform token info:id = "{shader_id}"\n                {body}\n'
                   f'                {output}\n            }}')


def standard_surface(inputs: str) -> str:
    """The ball with a UsdShade network of a MaterialX standard_surface, ``inputs`` authored."""
    return ball_lit_by(f'''    def DomeLight "sky"
    {{
    }}
    def Material "look"
    {{
        token outputs:mtlx:surface.connect = </World/look/surface.outputs:surface>
        def Shader "surface"
        {{
            uniform token info:id = "ND_standard_surface_surfaceshader"
            {inputs}
            token outputs:surface
        }}
    }}''').replace('def Sphere "ball"\n    {\n', 'def Sphere "ball" (prepend apiSchemas = ["MaterialBindingAPI"])\n'
                   '    {\n        rel material:binding = </World/look>\n')


TEXTURE = 'color3f inputs:diffuseColor.connect = </World/look/surface/tex.outputs:rgb>'
# stage text, prim named, what the line says (after the file and the prim)
VALUE_ERRORS = {
    # UsdLux: shaping values were ignored when NaN (a cone, a focus silently not there)
    "cone angle NaN": (lamp("float inputs:shaping:cone:angle = nan"), "/World/lamp",
                       "inputs:shaping:cone:angle is nan: it must be a finite number"),
    "cone softness NaN": (lamp("float inputs:shaping:cone:softness = nan"), "/World/lamp",
                          "inputs:shaping:cone:softness is nan"),
    "focus NaN": (lamp("float inputs:shaping:focus = nan"), "/World/lamp", "inputs:shaping:focus is nan"),
    "focusTint NaN": (lamp("float inputs:shaping:focus = 2\n        color3f inputs:shaping:focusTint = (nan, 1, 1)"),
                      "/World/lamp", "inputs:shaping:focusTint is nan"),
    "sphere radius 1e30": (lamp("float inputs:radius = 1e30"), "/World/lamp",
                           "inputs:radius is 1e+30: it must be a finite number from 0 to 1e+11"),
    "rect width inf": (lamp("float inputs:width = inf", "RectLight"), "/World/lamp", "inputs:width is inf"),
    "distant angle 1e30": (ball_lit_by('    def DistantLight "lamp"\n    {\n        float inputs:angle = 1e30\n    }\n'),
                           "/World/lamp", "inputs:angle is 1e+30: it must be a finite number from 0 to 360"),
    "intensity 1e30": (lamp("float inputs:intensity = 1e30"), "/World/lamp",
                       "intensity · 2^exposure · color reaches 2^99.66: more than a render can hold"),
    "exposure 1e30": (lamp("float inputs:exposure = 1e30"), "/World/lamp", "reaches 2^1e+30"),
    "intensity a string": (lamp('string inputs:intensity = "bright"'), "/World/lamp",
                           "inputs:intensity is authored as string: it must be a number"),
    # UsdPreviewSurface: NaN made NaN pixels (refused by the beauty check, naming no prim),
    # 1e30 made pixels of 1e30, a specular colour of 1e30 negative ones
    "diffuseColor NaN": (ball_of("color3f inputs:diffuseColor = (nan, 1, 1)"), "/World/look/surface",
                         "inputs:diffuseColor is nan: it must be a finite number"),
    "diffuseColor 1e30": (ball_of("color3f inputs:diffuseColor = (1e30, 1, 1)"), "/World/look/surface",
                          "inputs:diffuseColor is 1e+30: it must be a finite number ≤ 10"),
    "diffuseColor in 0-255": (ball_of("color3f inputs:diffuseColor = (200, 30, 30)"), "/World/look/surface",
                              "inputs:diffuseColor is 200: it must be a finite number ≤ 10"),
    "emissiveColor 1e30": (ball_of("color3f inputs:emissiveColor = (1e30, 1, 1)"), "/World/look/surface",
                           "inputs:emissiveColor is 1e+30: it must be a finite number ≤ 1e+20"),
    "emissiveColor inf": (ball_of("color3f inputs:emissiveColor = (inf, 1, 1)"), "/World/look/surface",
                          "inputs:emissiveColor is inf"),
    "specularColor 1e30": (ball_of("color3f inputs:specularColor = (1e30, 0, 0)\n            "
                                   "int inputs:useSpecularWorkflow = 1"), "/World/look/surface",
                           "inputs:specularColor is 1e+30"),
    "metallic NaN": (ball_of("float inputs:metallic = nan"), "/World/look/surface", "inputs:metallic is nan"),
    "roughness inf": (ball_of("float inputs:roughness = inf"), "/World/look/surface", "inputs:roughness is inf"),
    "ior NaN": (ball_of("float inputs:ior = nan"), "/World/look/surface", "inputs:ior is nan"),
    "opacityThreshold NaN": (ball_of("float inputs:opacityThreshold = nan"), "/World/look/surface",
                             "inputs:opacityThreshold is nan"),
    "normal NaN": (ball_of("normal3f inputs:normal = (nan, 0, 1)"), "/World/look/surface", "inputs:normal"),
    "texture scale NaN": (nested(TEXTURE, "UsdUVTexture", "float4 inputs:scale = (nan, 1, 1, 1)"),
                          "/World/look/surface/tex", "inputs:scale is nan"),
    "texture fallback inf": (nested(TEXTURE, "UsdUVTexture", "float4 inputs:fallback = (inf, 0, 0, 1)"),
                             "/World/look/surface/tex", "inputs:fallback is inf"),
    "primvar reader fallback NaN": (nested('color3f inputs:diffuseColor.connect = </World/look/surface/tex.outputs:result>',
                                           "UsdPrimvarReader_float3", 'string inputs:varname = "tint"\n'
                                           "                float3 inputs:fallback = (nan, 0, 0)", "float3 outputs:result"),
                                    "/World/look/surface/tex", "inputs:fallback is nan"),
    "displayColor NaN": (ball_lit_by('    def DistantLight "sun"\n    {\n    }\n').replace(
        'def Sphere "ball"\n    {\n', 'def Sphere "ball"\n    {\n        color3f[] primvars:displayColor = [(nan, 1, 1)]\n'),
        "/World/ball", "primvars:displayColor is nan"),
    # MaterialX networks in USD: NaN or 1e30 inputs
    "base_color NaN": (standard_surface("color3f inputs:base_color = (nan, 0.5, 0.5)"), "/World/look/surface",
                       "inputs:base_color is nan: it must be a finite number"),
    "base 1e30": (standard_surface("float inputs:base = 1e30"), "/World/look",
                  "its MaterialX surface's diffuseColor is 8e+29: it must be a finite number ≤ 10"),
    "emission_color 1e30": (standard_surface("float inputs:emission = 1\n            "
                                             "color3f inputs:emission_color = (1e30, 1, 1)"), "/World/look",
                            "its MaterialX surface's emissiveColor is 1e+30: it must be a finite number ≤ 1e+20"),
    "specular_IOR NaN": (standard_surface("float inputs:specular_IOR = nan"), "/World/look/surface",
                         "inputs:specular_IOR is nan"),
}


@pytest.mark.parametrize("case", sorted(VALUE_ERRORS))
def test_a_number_no_image_can_be_made_of_is_one_line_naming_file_prim_and_attribute(tmp_path, capsys, case):
    text, prim, said = VALUE_ERRORS[case]
    shot = tmp_path / "shot.usda"
    shot.write_text(text)
    code, lines, pixels = render(capsys, shot)
    one_error(code, lines, f"{shot}, prim {prim}: ", said)
    assert pixels is None


def _mtlx(tmp_path: Path, base_color: str) -> Path:
    document = tmp_path / "look.mtlx"
    document.write_text(f'''<?xml version="1.0"?>
<materialx version="1.39">
  <standard_surface name="SR" type="surfaceshader">
    <input name="base_color" type="color3" value="{base_color}" />
  </standard_surface>
  <surfacematerial name="M" type="material">
    <input name="surfaceshader" type="surfaceshader" nodename="SR" />
  </surfacematerial>
</materialx>
''')
    shot = tmp_path / "shot.usda"
    shot.write_text(ball_lit_by('''    def DistantLight "sun"
    {
    }
    def Scope "Looks" (prepend references = @./look.mtlx@</MaterialX/Materials>)
    {
    }''').replace('def Sphere "ball"\n    {\n', 'def Sphere "ball" (prepend apiSchemas = ["MaterialBindingAPI"])\n'
                  '    {\n        rel material:binding = </World/Looks/M>\n'))
    return shot


@pytest.mark.parametrize("value", ["nan, 0.5, 0.5", "0.5, inf, 0.5", "1e999, 0, 0"])
def test_a_non_finite_value_in_a_materialx_document_names_the_document_and_the_node_input(tmp_path, capsys, value):
    shot = _mtlx(tmp_path, value)
    code, lines, _ = render(capsys, shot)
    one_error(code, lines, tmp_path / "look.mtlx", f"MaterialX input SR.base_color is '{value}': it must be finite",
              "/World/Looks/M")


def test_a_huge_value_in_a_materialx_document_names_the_material(tmp_path, capsys):
    shot = _mtlx(tmp_path, "1e30, 0, 0")
    code, lines, _ = render(capsys, shot)
    one_error(code, lines, f"{tmp_path / 'look.mtlx'}, prim /World/Looks/M: ", "its MaterialX surface's diffuseColor "
              "is 1e+30: it must be a finite number ≤ 10")


def write_ies(path: Path, candela: str = "100 50 0", vertical: str = "0 90 180", multiplier: str = "1") -> Path:
    path.write_text(f"IESNA:LM-63-2002\nTILT=NONE\n1 -1 {multiplier} 3 1 1 2 0 0 0\n1 1 10\n{vertical}\n0\n{candela}\n")
    return path


@pytest.mark.parametrize("candela, vertical, multiplier, said", [
    ("100 nan 0", "0 90 180", "1", "line 7: 'nan' is not a finite number"),
    ("100 50 inf", "0 90 180", "1", "line 7: 'inf' is not a finite number"),
    ("100 50 0", "0 nan 180", "1", "line 5: 'nan' is not a finite number"),
    ("100 50 0", "0 90 180", "1e999", "line 3: '1e999' is not a finite number"),
    ("1e300 50 0", "0 90 180", "1e300", "candela values × multiplier 1e+300 × ballast factor 1 overflow"),
])
def test_an_ies_profile_with_a_non_number_is_unusable_with_a_warning_naming_its_line(
        tmp_path, capsys, candela, vertical, multiplier, said):
    """The light keeps its other shaping (the rule for a malformed profile), never NaN."""
    profile = write_ies(tmp_path / "spot.ies", candela, vertical, multiplier)
    shot = tmp_path / "shot.usda"
    shot.write_text(lamp("asset inputs:shaping:ies:file = @./spot.ies@"))
    code, lines, pixels = render(capsys, shot)
    assert code == 0 and np.isfinite(pixels).all() and pixels[..., :3].max() > 0
    (line,) = lines
    assert line.startswith(f"pxr-layers: WARNING: IES profile unusable (/World/lamp; the light keeps the rest of "
                           f"its shaping): {profile}: {said}"), line


def test_an_ies_profile_too_bright_for_a_render_is_an_error_naming_the_light(tmp_path, capsys):
    write_ies(tmp_path / "spot.ies", "1e30 50 0")
    shot = tmp_path / "shot.usda"
    shot.write_text(lamp("asset inputs:shaping:ies:file = @./spot.ies@"))
    code, lines, _ = render(capsys, shot)
    one_error(code, lines, f"{shot}, prim /World/lamp: ", "the IES profile's peak (1e+30) reaches 2^99.66: "
              "more than a render can hold")


def test_an_ies_profile_of_no_light_says_its_light_is_black(tmp_path, capsys):
    profile = write_ies(tmp_path / "spot.ies", "0 0 0")
    shot = tmp_path / "shot.usda"
    shot.write_text(lamp("asset inputs:shaping:ies:file = @./spot.ies@"))
    code, lines, _ = render(capsys, shot)
    assert code == 0
    assert any(line.startswith(f"pxr-layers: WARNING: IES profile {profile} (/World/lamp): every candela value is 0: "
                               "the lights that use it are black") for line in lines), lines


@pytest.mark.parametrize("op", ["float3 xformOp:scale = (1e30, 1e30, 1e30)", "double3 xformOp:translate = (1e30, 0, 0)"])
def test_a_light_placed_out_of_reach_is_skipped_with_a_warning_naming_it(tmp_path, capsys, op):
    """As gprims placed beyond placement.MAX_WORLD_COORDINATE are: it used to be a silently
    black light (and numpy's overflow warnings)."""
    name = op.split()[1]
    shot = tmp_path / "shot.usda"
    shot.write_text(ball_lit_by(f'    def SphereLight "lamp"\n    {{\n        {op}\n'
                                f'        uniform token[] xformOpOrder = ["{name}"]\n    }}\n'
                                '    def DistantLight "sun"\n    {\n    }\n'))
    code, lines, pixels = render(capsys, shot)
    assert code == 0 and np.isfinite(pixels).all()
    (line,) = lines
    assert line == "pxr-layers: WARNING: lights placed beyond 1e+09 m from the origin (or whose size there overflows) " \
                   "skipped: /World/lamp", line


# --- unbounded scenes -----------------------------------------------------------------------

def usdc(tmp_path: Path, build) -> Path:
    """A .usdc under a camera and a sun, with what ``build(stage)`` defines: its arrays as
    Vt arrays (crate files compress runs of equal values: 1e8 zeros take kilobytes)."""
    path = tmp_path / "huge.usdc"
    stage = Usd.Stage.CreateNew(str(path))
    camera = UsdGeom.Camera.Define(stage, "/World/cam")
    UsdGeom.Xformable(camera).AddTranslateOp().Set((0, 0, 5))
    stage.DefinePrim("/World/sun", "DistantLight")
    build(stage)
    stage.Save()
    return path


def faces(count: int):
    def build(stage):
        UsdGeom.Mesh.Define(stage, "/World/bad").GetFaceVertexCountsAttr().Set(Vt.IntArray(count))
    return build


def indices(count: int):
    def build(stage):
        mesh = UsdGeom.Mesh.Define(stage, "/World/bad")
        mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray([3]))
        mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray(count))
        mesh.GetPointsAttr().Set(Vt.Vec3fArray(3))
    return build


def instancer(count: int, prototype=UsdGeom.Cube, path: str = "/World/bad", stretched: bool = False):
    """`count` point instances of one `prototype`; `stretched`: each scaled (1, 2, 1), not a
    similarity, so each is a copy of its own (uniform ones share one instanced surface)."""
    def build(stage):
        points = UsdGeom.PointInstancer.Define(stage, path)
        prototype.Define(stage, f"{path}/protos/shape")
        points.GetPrototypesRel().AddTarget(f"{path}/protos/shape")
        points.GetProtoIndicesAttr().Set(Vt.IntArray(count))
        if count < 10**6:
            points.GetPositionsAttr().Set(Vt.Vec3fArray(count))
        if stretched:
            points.GetScalesAttr().Set(Vt.Vec3fArray(count, Gf.Vec3f(1, 2, 1)))
    return build


def forest(stage):
    """600 instances of an instancer of 600 cubes: 360,000 meshes."""
    outer = UsdGeom.PointInstancer.Define(stage, "/World/bad")
    instancer(600, path="/World/bad/protos/tree")(stage)
    outer.GetPrototypesRel().AddTarget("/World/bad/protos/tree")
    outer.GetProtoIndicesAttr().Set(Vt.IntArray(600))
    outer.GetPositionsAttr().Set(Vt.Vec3fArray(600))


BUDGETS = {
    "1e8 faces": (faces(10**8), "/World/bad", f"faceVertexCounts holds 100,000,000 values: more than the "
                  f"{MAX_ARRAY_VALUES:,} an array may hold"),
    "1e8 indices": (indices(10**8), "/World/bad", "faceVertexIndices holds 100,000,000 values"),
    "2e7 faces": (faces(2 * 10**7), "/World/bad", f"faceVertexCounts declares 20,000,000 faces: more than the "
                  f"{MAX_SCENE_TRIANGLES:,} triangles a scene may hold"),
    "1e7 instances": (instancer(10**7), "/World/bad", f"protoIndices lists 10,000,000 instances: more than the "
                      f"{MAX_SCENE_MESHES:,} meshes a scene may hold"),
    "instances past the triangles": (instancer(4300, UsdGeom.Sphere, stretched=True), "/World/bad/instance_",
                                     f"its 3,968 triangles after the 16,776,704 before it: more than the "
                                     f"{MAX_SCENE_TRIANGLES:,} triangles"),
    "nested instances past the meshes": (forest, "/World/bad/instance_",
                                         f"protoIndices lists 600 instances after the 261,600 before it: more "
                                         f"than the {MAX_SCENE_MESHES:,} meshes"),
}


@pytest.mark.parametrize("case", sorted(BUDGETS))
def test_a_scene_past_its_budget_is_one_line_naming_the_prim_and_the_budget(tmp_path, capsys, case):
    build, prim, said = BUDGETS[case]
    shot = usdc(tmp_path, build)
    assert shot.stat().st_size < 10**7
    code, lines, pixels = render(capsys, shot)
    one_error(code, lines, f"{shot}, prim {prim}", said)
    assert pixels is None


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def grey_png(path: Path, width: int, height: int, value: int = 128, rows: int = 256) -> Path:
    """A grey 8-bit PNG of one value, written without holding it: its deflate stream is one
    compressed block of ``rows`` rows repeated (each block starts afresh after a full flush),
    so a 20000 × 20000 image is a 0.4 MB file."""
    row = b"\x00" + bytes([value]) * width  # filter type 0, then the row
    block = row * rows
    deflate = zlib.compressobj(9)
    head = deflate.compress(block) + deflate.flush(zlib.Z_FULL_FLUSH)
    body = deflate.compress(block) + deflate.flush(zlib.Z_FULL_FLUSH)
    full, rest = divmod(height, rows)
    tail = deflate.compress(row * rest) + deflate.flush()
    checksum = 1
    for _ in range(full):
        checksum = zlib.adler32(block, checksum)
    checksum = zlib.adler32(row * rest, checksum)
    stream = head + body * (full - 1) + tail[:-4] + struct.pack(">I", checksum)
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)  # 8-bit grey
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", stream) + _chunk(b"IEND", b""))
    return path


def textured(tmp_path: Path, name: str) -> Path:
    shot = tmp_path / "shot.usda"
    shot.write_text(nested(TEXTURE, "UsdUVTexture", f"asset inputs:file = @./{name}@"))
    return shot


def test_a_decompression_bomb_texture_renders_read_at_the_level_the_frame_needs(tmp_path, capsys):
    """A 20000 × 20000 PNG (0.4 MB; 1.6 GB of float32 as one channel): the tracer's texture
    cache reads it a band of rows at a time, averaged down to the MIP level an 8 × 8 frame
    needs, never whole: no warning, its value on the ball."""
    bomb = grey_png(tmp_path / "bomb.png", 20000, 20000)
    assert bomb.stat().st_size < 10**6
    code, lines, pixels = render(capsys, textured(tmp_path, "bomb.png"), "--norm-bounces", "0")
    assert code == 0 and np.isfinite(pixels).all() and pixels[..., :3].max() > 0.05
    assert lines == []


def test_a_texture_past_the_file_budget_is_not_decoded(tmp_path, capsys):
    """A 40000 × 40000 PNG (1.6 MB, 1.6 G texels): refused from its header, the texture's
    fallback used, with a warning (as for any unreadable texture)."""
    bomb = grey_png(tmp_path / "bomb.png", 40000, 40000)
    code, lines, pixels = render(capsys, textured(tmp_path, "bomb.png"))
    assert code == 0 and np.isfinite(pixels).all()
    (line,) = lines
    assert line == (f"pxr-layers: WARNING: cannot read texture {bomb} (used by /World/look/surface/tex): "
                    f"40000×40000 texels: more than the {MAX_FILE_TEXELS:,} a texture file may have; using the "
                    "fallback value instead"), line


def test_a_forged_texture_header_is_not_decoded(tmp_path, capsys):
    """A header claiming 100000 × 100000 texels in a 69-byte file: OpenImageIO's own check
    refuses it before ours; a warning all the same."""
    bomb = tmp_path / "bomb.png"
    header = struct.pack(">IIBBBBB", 100000, 100000, 8, 0, 0, 0, 0)
    bomb.write_bytes(b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header) + _chunk(b"IDAT", zlib.compress(b"\x00" * 100))
                     + _chunk(b"IEND", b""))
    code, lines, pixels = render(capsys, textured(tmp_path, "bomb.png"))
    assert code == 0 and np.isfinite(pixels).all()
    (line,) = lines
    assert line.startswith(f"pxr-layers: WARNING: cannot read texture {bomb} (used by /World/look/surface/tex): ")
    assert line.endswith("using the fallback value instead"), line


def test_a_mipmapped_texture_past_the_texel_budget_is_read_at_the_level_the_frame_needs(tmp_path, capsys):
    """An 8200² tiled, MIP-mapped EXR: the level an 8 × 8 frame needs is read from the file as it
    is, with no warning (texture_cache.fit_levels's own test holds the finest level to
    MAX_TEXTURE_TEXELS)."""
    path = tmp_path / "big.exr"
    output = oiio.ImageOutput.create(str(path))
    size = 8200  # 67,240,000 texels: just past the budget; level 1 is 4100²
    assert size * size > MAX_TEXTURE_TEXELS >= (size // 2) ** 2
    first = True
    while True:
        spec = oiio.ImageSpec(size, size, 1, oiio.HALF)
        spec.tile_width = spec.tile_height = 64
        spec.attribute("textureformat", "Plain Texture")  # MIP-mapped
        assert output.open(str(path), spec, "create" if first else "appendmiplevel"), output.geterror()
        assert output.write_image(np.full((size, size, 1), 0.5, np.float16)), output.geterror()
        if size == 1:
            break
        first, size = False, size // 2
    output.close()
    del output  # OpenImageIO finishes a MIP-mapped EXR's last levels only when its writer goes
    code, lines, pixels = render(capsys, textured(tmp_path, "big.exr"), "--norm-bounces", "0")
    assert code == 0 and np.isfinite(pixels).all() and pixels[..., :3].max() > 0.05
    assert lines == []


def test_a_render_within_the_budgets_is_untouched(tmp_path, capsys):
    """The shipped Cornell box: no warning, as before."""
    shot = tmp_path / "cornell.usda"
    shutil.copy(RENDER_DIR / "cornell.usda", shot)
    code, lines, pixels = render(capsys, shot)
    assert code == 0 and lines == [] and np.isfinite(pixels).all()
