"""The `pxr-layers` command as a user runs it: the real console script in a subprocess."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import OpenImageIO as oiio
import pytest

from pxr_layers.cli.main import main
from pxr_layers.layers.exr import write_atomically

SCRIPT = shutil.which("pxr-layers", path=str(Path(sys.executable).parent)) or "pxr-layers"
RENDER_DIR = Path(__file__).resolve().parents[1] / "render"
SMALL = ["--spp", "2", "--resolution", "24", "24", "--max-depth", "3", "--quiet"]


def run(*args: str, cwd=None) -> subprocess.CompletedProcess:
    env = {**os.environ, "CI": "1"}
    return subprocess.run([SCRIPT, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=300, check=False)


def test_help_lists_every_subcommand_and_flag():
    top = run("--help")
    assert top.returncode == 0
    assert "render" in top.stdout and "demo" in top.stdout
    sub = run("render", "--help")
    assert sub.returncode == 0
    for flag in ("-o", "--spp", "--max-depth", "--resolution", "--seed", "--frame", "--camera", "--settings"):
        assert flag in sub.stdout


@pytest.mark.parametrize("args", [["render"], ["render", "x.usda", "--spp", "0"], ["bogus"], ["render", "x.usda", "--nope"]])
def test_usage_errors_exit_2(args):
    assert main(args) == 2


def test_missing_stage_is_one_line_and_exit_1(tmp_path):
    result = run("render", str(tmp_path / "nowhere.usda"), "-o", str(tmp_path))
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "nowhere.usda" in lines[0] and "Traceback" not in result.stderr
    assert not list(tmp_path.iterdir())


BROKEN_SHOT = """#usda 1.0
(
    subLayers = [@./missing_lighting.usda@]
)
def Xform "World"
{
    def Sphere "ball" {}
    def Xform "set" (references = @./missing_set.usda@) {}
    def Xform "look" (references = @./look.mtlx@) {}
}
"""


def test_composition_problems_are_warnings_each_printed_once_and_no_usd_chatter(tmp_path):
    shot = tmp_path / "shot.usda"
    shot.write_text(BROKEN_SHOT)
    (tmp_path / "look.mtlx").write_text('<?xml version="1.0"?><materialx version="1.38"/>')
    result = run("render", str(shot), "-o", str(tmp_path / "out"), *SMALL, "--no-previews")
    assert result.returncode == 0, result.stderr
    lines = result.stderr.strip().splitlines()
    assert all(line.startswith("pxr-layers: WARNING: ") for line in lines), lines  # nothing raw from USD
    assert len(lines) == len(set(lines)), lines
    text = "\n".join(lines)
    for name in ("missing_lighting.usda", "missing_set.usda", "default rig"):
        assert text.count(name) == 1, (name, lines)
    assert "/World/set" in text
    # usd-core cannot compose .mtlx, but stage/materialx/ reads it through the bindings into it
    assert "look.mtlx" not in text
    assert (tmp_path / "out" / "shot.exr").is_file()
    strict = run("render", str(shot), "-o", str(tmp_path / "strict"), *SMALL, "--strict")
    assert strict.returncode == 1 and "--strict" in strict.stderr and len(strict.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "strict").exists()


def test_a_stage_without_camera_or_lights_is_framed_and_lit_by_default(tmp_path):
    shot = tmp_path / "bare.usda"
    shot.write_text('#usda 1.0\n(\n    upAxis = "Z"\n)\ndef Cube "box"\n{\n    double size = 2\n}\n')
    result = run("render", str(shot), "-o", str(tmp_path / "bare.exr"), *SMALL[:-1], "--no-previews")
    assert result.returncode == 0, result.stderr
    assert "/pxrLayers/autoCamera frames the stage" in result.stderr
    assert result.stderr.count("default rig") == 1
    rgba = OpenEXR.File(str(tmp_path / "bare.exr")).channels()["RGBA"].pixels
    assert 0.05 < rgba[..., 3].mean() < 0.95  # the box fills part of the frame, not all of it
    assert rgba[12, 12, 3] == 1.0  # and is centred
    dark = run("render", str(shot), "-o", str(tmp_path / "dark.exr"), *SMALL, "--no-default-lights", "--no-previews")
    assert dark.returncode == 0 and "black" in dark.stderr
    assert OpenEXR.File(str(tmp_path / "dark.exr")).channels()["RGBA"].pixels[..., :3].max() == 0.0


def test_a_recipe_layer_that_is_not_usd_is_one_line_naming_it(tmp_path):
    junk = tmp_path / "junk.usda"
    junk.write_text("not usd {{")
    result = run("render", str(RENDER_DIR / "cornell.usda"), "--recipe", str(junk), "-o", str(tmp_path / "out"), *SMALL)
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and str(junk) in lines[0] and "cannot open as USD" in lines[0]


def test_a_dome_alone_renders_the_sky(tmp_path):
    shot = tmp_path / "sky.usda"
    shot.write_text('#usda 1.0\ndef DomeLight "sky"\n{\n    float inputs:intensity = 2\n}\n')
    result = run("render", str(shot), "-o", str(tmp_path / "sky.exr"), *SMALL, "--no-previews")
    assert result.returncode == 0, result.stderr
    assert "has no geometry that renders" in result.stderr and "default rig" not in result.stderr
    rgba = OpenEXR.File(str(tmp_path / "sky.exr")).channels()["RGBA"].pixels
    assert np.allclose(rgba[..., :3], 2.0) and (rgba[..., 3] == 0.0).all()


def ball_lit_by(light: str) -> str:
    """A stage: a camera 5 m from a unit ball, and `light` (USD prim text) beside them."""
    return f"""#usda 1.0
def Xform "World"
{{
    def Camera "cam"
    {{
        double3 xformOp:translate = (0, 0, 5)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}
    def Sphere "ball"
    {{
    }}
{light}
}}
"""


BAD_SKY = ball_lit_by("""    def DomeLight "sky"
    {
        asset inputs:texture:file = @./sky.exr@
    }""")


def bad_sky(tmp_path, texel: float) -> Path:
    """A dome whose image holds `texel` in half its pixels (a wide-gamut HDRI holds small
    negative texels): the reader reads NaN, infinite and negative ones as 0, with a warning."""
    pixels = np.ones((4, 8, 3), np.float32)
    pixels[:, :4] = texel
    image = oiio.ImageOutput.create(str(tmp_path / "sky.exr"))
    image.open(str(tmp_path / "sky.exr"), oiio.ImageSpec(8, 4, 3, "float"))
    image.write_image(pixels)
    image.close()
    shot = tmp_path / "sky.usda"
    shot.write_text(BAD_SKY)
    return shot


def ball_of(surface_input: str) -> str:
    """A stage: the camera and ball of ball_lit_by under a plain dome, the ball's
    UsdPreviewSurface with `surface_input` authored (USD text): material values the beauty
    check is there for (the reader refuses constants that are not finite or out of range;
    a primvar's values are data it reads as they are)."""
    return ball_lit_by(f"""    def DomeLight "sky"
    {{
    }}
    def Material "look"
    {{
        token outputs:surface.connect = </World/look/surface.outputs:surface>
        def Shader "surface"
        {{
            uniform token info:id = "UsdPreviewSurface"
            {surface_input}
            token outputs:surface
        }}
    }}""").replace('def Sphere "ball"\n    {\n', 'def Sphere "ball" (prepend apiSchemas = ["MaterialBindingAPI"])\n    {\n'
                   '        rel material:binding = </World/look>\n')


def test_a_beauty_with_negative_pixels_names_the_paths_that_made_them(tmp_path):
    shot = tmp_path / "glow.usda"
    shot.write_text(ball_of("color3f inputs:emissiveColor = (-5, 1, 1)"))
    result = run("render", str(shot), "-o", str(tmp_path / "out"), *SMALL, "--no-previews")
    assert result.returncode == 0
    (warning,) = [line for line in result.stderr.splitlines() if "negative pixels" in line]
    assert "C O'ball'" in warning


def test_a_beauty_with_nan_pixels_is_refused_naming_the_paths_that_made_them(tmp_path):
    shot = tmp_path / "nan.usda"
    # A NaN primvar through a UsdPrimvarReader (a NaN constant input is the reader's error)
    shot.write_text(ball_of('color3f inputs:diffuseColor.connect = </World/look/surface/tint.outputs:result>\n'
                            '            def Shader "tint"\n            {\n'
                            '                uniform token info:id = "UsdPrimvarReader_float3"\n'
                            '                string inputs:varname = "tint"\n                float3 outputs:result\n'
                            '            }').replace("rel material:binding = </World/look>\n",
                                        "rel material:binding = </World/look>\n        color3f primvars:tint = (nan, 1, 1)\n"))
    result = run("render", str(shot), "-o", str(tmp_path / "out"), *SMALL, "--no-previews")
    assert result.returncode == 1
    error = result.stderr.strip().splitlines()[-1]
    assert "NaN or infinite pixels" in error and "C RD'ball' L'sky'" in error and "Traceback" not in result.stderr
    assert not list((tmp_path / "out").glob("*"))  # neither the EXR nor the index


def test_garbage_file_is_a_user_error(tmp_path):
    bad = tmp_path / "garbage.usda"
    bad.write_bytes(b"\x00\x01 this is not usd")
    result = run("render", str(bad), "-o", str(tmp_path / "out.exr"))
    assert result.returncode == 1 and "garbage.usda" in result.stderr
    assert not (tmp_path / "out.exr").exists()


def test_render_writes_an_exr_that_openexr_and_oiio_read(tmp_path):
    out = tmp_path / "shots" / "beauty.exr"
    result = run("render", str(RENDER_DIR / "cornell.usda"), "-o", str(out), "--seed", "3", *SMALL)
    assert result.returncode == 0, result.stderr
    exr = OpenEXR.File(str(out))
    header = exr.header()
    assert header["pxrLayers/spp"] == "2" and header["pxrLayers/seed"] == "3"
    assert header["pxrLayers/camera"] == "/World/Camera"
    rgba = exr.channels()["RGBA"].pixels
    assert rgba.shape == (24, 24, 4) and rgba.dtype == np.float32
    assert np.isfinite(rgba).all() and rgba[..., :3].mean() > 0.05
    assert np.all(rgba[2:-2, 2:-2, 3] == 1.0)  # inside the box every camera ray hits something
    spec = oiio.ImageInput.open(str(out)).spec()
    assert (spec.width, spec.height, spec.nchannels) == (24, 24, 4)
    assert sorted(p.name for p in out.parent.iterdir()) == ["beauty.exr", "beauty.pxlidx", "beauty.rgba.png"]  # no temporary left


def test_output_directory_and_frame_name_the_file(tmp_path):
    result = run("render", str(RENDER_DIR / "cornell.usda"), "-o", str(tmp_path / "dir"), "--frame", "1", *SMALL)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "dir" / "cornell.0001.exr").exists()
    result = run("render", str(RENDER_DIR / "cornell.usda"), *SMALL, cwd=tmp_path)
    assert result.returncode == 0 and (tmp_path / "cornell.exr").exists()


def test_same_command_gives_the_same_bytes(tmp_path):
    for name in ("a", "b"):
        assert run("render", str(RENDER_DIR / "cornell.usda"), "-o", str(tmp_path / name), *SMALL).returncode == 0
    for name in ("cornell.exr", "cornell.pxlidx"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_demo_renders_the_embedded_demo_shot_denoised(tmp_path):
    """Its two products, each with its denoised twin, every light pass holding light."""
    result = run("demo", "-o", str(tmp_path), *SMALL)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [str(tmp_path / "demo_passes.exr"), str(tmp_path / "demo_lights.exr")]
    assert (tmp_path / "demo.pxlidx").exists() and (tmp_path / "demo_passes.contact.png").exists()
    from pxr_layers.layers.multipart import read_multipart

    passes = read_multipart(tmp_path / "demo_passes.denoised.exr").colour_layers()
    assert len(passes) == 6 and all(image.max() > 0 for image in passes.values())
    assert (tmp_path / "demo_lights.denoised.exr").exists()


def test_unknown_camera_is_a_user_error(tmp_path):
    result = run("render", str(RENDER_DIR / "cornell.usda"), "--camera", "/World/NoSuchCamera", "-o", str(tmp_path), *SMALL)
    assert result.returncode == 1 and "/World/NoSuchCamera" in result.stderr


def test_failed_write_leaves_nothing_behind(tmp_path):
    target = tmp_path / "beauty.exr"

    def crash(temporary):
        temporary.write_bytes(b"half an image")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        write_atomically(target, crash)
    assert list(tmp_path.iterdir()) == []


def test_debug_covariance_writes_norm_images(tmp_path):
    result = run("render", str(RENDER_DIR / "showcase.usda"), "-o", str(tmp_path), "--debug-covariance",
                 "--spp", "2", "--resolution", "48", "48", "--max-depth", "2", "--quiet")
    assert result.returncode == 0, result.stderr
    channels = OpenEXR.File(str(tmp_path / "showcase.covariance.exr")).channels()
    norms = {name: channels[name].pixels for name in "CTR"}
    assert all(image.shape == (48, 48) and image.dtype == np.float32 for image in norms.values())
    assert np.nanmax(norms["C"]) == pytest.approx(2.5, rel=1e-3)  # the r = 0.4 m sphere
    assert np.nanmax(norms["T"]) > 0 and np.nanmax(norms["R"]) > 0
    for name in "CTR":
        image = oiio.ImageBuf(str(tmp_path / f"showcase.covariance.{name}.png"))
        assert (image.spec().width, image.spec().height, image.spec().nchannels) == (48, 48, 3)
        pixels = image.get_pixels()
        assert pixels.std() > 0.01  # not blank


def test_lpe_check_and_match_through_the_console_script():
    check = run("lpe", "check", "C D C(|S_C| = 0) T(|S_T| > 6) .* L")
    assert check.returncode == 0, check.stderr
    assert "canonical: CD@(|S_C| = 0 and |S_T| > 6).*L" in check.stdout
    matched = run("lpe", "match", "C<RD>.*<L.'key'>", "C RD'floor' L'key'", "C RG'chrome' L'key'")
    assert matched.returncode == 0 and matched.stdout.splitlines() == ["match", "no match"]
    bad = run("lpe", "check", "C<RD")
    assert bad.returncode == 1 and "^" in bad.stderr and "Traceback" not in bad.stderr


def test_extract_cuts_passes_that_sum_to_the_beauty(tmp_path):
    rendered = run("render", str(RENDER_DIR / "showcase.usda"), "-o", str(tmp_path), *SMALL)
    assert rendered.returncode == 0, rendered.stderr
    out = tmp_path / "layers.exr"
    result = run("extract", str(tmp_path / "showcase.pxlidx"), "--passes", "--layer", "flat=C<R.>@(|S_C| = 0).*",
                 "-o", str(out), "--quiet")
    assert result.returncode == 0, result.stderr
    parts = OpenEXR.File(str(out)).parts
    names = [part.name() for part in parts]
    assert names[0] == "rgba" and "diffuse_direct" in names and "flat" in names
    beauty = parts[0].channels["RGBA"].pixels[..., :3].astype(np.float64)
    passes = [p for p in parts[1:] if p.name() != "flat"]
    # the OpenEXR binding groups NAME.R/G/B into one (h, w, 3) channel called NAME
    total = sum(p.channels[p.name()].pixels.astype(np.float64) for p in passes)
    np.testing.assert_allclose(total, beauty, rtol=1e-5, atol=1e-6)
    assert parts[names.index("flat")].header["pxrLayers/expression"] == "C<R.>@(|S_C| = 0).*"


def test_extract_with_a_bad_expression_points_at_it(tmp_path):
    assert run("render", str(RENDER_DIR / "cornell.usda"), "-o", str(tmp_path), *SMALL).returncode == 0
    result = run("extract", str(tmp_path / "cornell.pxlidx"), "--layer", "bad=C<RD", "-o", str(tmp_path / "x.exr"))
    assert result.returncode == 1 and "^" in result.stderr and not (tmp_path / "x.exr").exists()
    usage = run("extract", str(tmp_path / "cornell.pxlidx"), "--layer", "no-equals-sign")
    assert usage.returncode == 2


def test_extract_without_layers_is_a_usage_error(tmp_path):
    assert run("render", str(RENDER_DIR / "cornell.usda"), "-o", str(tmp_path), *SMALL).returncode == 0
    result = run("extract", str(tmp_path / "cornell.pxlidx"))
    assert result.returncode == 2 and "no layers" in result.stderr
