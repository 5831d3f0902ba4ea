"""Hostile input (issue 18's campaign, as far as it is built): each case is a clear error
(exit 1, one line naming the file and prim or the flag or query position; exit 2 for usage),
never a traceback, never NaN or negative pixels written with exit 0."""

from __future__ import annotations

import pytest

from pxr_layers import lpe
from pxr_layers.cli.main import main
from pxr_layers.errors import LpeSyntaxError
from pxr_layers.lpe.parser import MAX_NESTING

from test_cli import RENDER_DIR, SMALL, ball_lit_by, run

def lit_by_key(control: str) -> str:
    """The ball under a SphereLight "key" with one control authored (USD text)."""
    return ball_lit_by(f"""    def SphereLight "key"
    {{
        {control}
        double3 xformOp:translate = (2, 2, 2)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }}""")


@pytest.mark.parametrize("control, attribute", [
    ("float inputs:intensity = -20", "inputs:intensity is -20"),
    ("float inputs:intensity = nan", "inputs:intensity is nan"),
    ("float inputs:intensity = inf", "inputs:intensity is inf"),
    ("float inputs:exposure = 1000", "2^exposure"),
    ("color3f inputs:color = (nan, -1, 2)", "inputs:color is nan"),
    ("color3f inputs:color = (1, -1, 2)", "inputs:color is -1"),
    ("float inputs:radius = -1", "inputs:radius is -1"),
    ("float inputs:diffuse = nan", "inputs:diffuse is nan"),
    ("bool inputs:enableColorTemperature = 1\n        float inputs:colorTemperature = -5",
     "inputs:colorTemperature is -5"),
])
def test_a_light_value_no_image_can_hold_is_one_line_naming_the_prim(tmp_path, control, attribute):
    shot = tmp_path / "light.usda"
    shot.write_text(lit_by_key(control))
    result = run("render", str(shot), "-o", str(tmp_path / "out"), *SMALL, "--no-previews", "--no-index")
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert str(shot) in line and "/World/key" in line and attribute in line and "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_a_very_low_exposure_is_darkness_not_an_error(tmp_path):
    shot = tmp_path / "light.usda"
    shot.write_text(lit_by_key("float inputs:exposure = -5000"))
    result = run("render", str(shot), "-o", str(tmp_path / "out"), *SMALL, "--no-previews", "--no-index")
    assert result.returncode == 0 and "will be black" in result.stderr


@pytest.fixture(scope="module")
def cornell_index(tmp_path_factory):
    folder = tmp_path_factory.mktemp("hostile")
    assert main(["render", str(RENDER_DIR / "cornell.usda"), "-o", str(folder), *SMALL]) == 0
    return folder / "cornell.pxlidx"


@pytest.mark.parametrize("layers", [["--layer", "a=C.*", "--layer", "a=CB"],
                                    ["--passes", "--layer", "emission=CB"],
                                    ["--lights", "--layer", "light_other=C.*"]])
def test_a_layer_name_given_twice_is_a_usage_error(cornell_index, tmp_path, layers):
    result = run("extract", str(cornell_index), *layers, "-o", str(tmp_path / "x.exr"), "--quiet")
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "given twice" in line and "Traceback" not in result.stderr
    assert not (tmp_path / "x.exr").exists()


@pytest.mark.parametrize("opening, closing", [("(", ")"), ("[", "]")])
def test_deep_nesting_is_a_syntax_error_at_its_position(opening, closing):
    query = "C" + opening * 300 + "D" + closing * 300 + "L"
    with pytest.raises(LpeSyntaxError) as raised:
        lpe.parse(query)
    assert "nest" in str(raised.value) and raised.value.position == 1 + MAX_NESTING
    shallow = "C" + opening * MAX_NESTING + "D" + closing * MAX_NESTING + "L"
    lpe.parse(shallow)  # the limit itself parses


@pytest.mark.parametrize("flags", [["--frame", "nan"], ["--frame", "inf"], ["--frame", "-inf"]])
def test_a_frame_that_is_not_a_number_is_a_usage_error(tmp_path, flags):
    result = run("render", str(RENDER_DIR / "cornell.usda"), *flags, "-o", str(tmp_path), *SMALL)
    assert result.returncode == 2 and "--frame" in result.stderr and "Traceback" not in result.stderr


@pytest.mark.parametrize("flags, said", [
    (["--spp", "99999999999999999999"], "samples per pixel"),
    (["--spp", "4294967296", "--resolution", "1", "1"], "samples per pixel"),
    (["--resolution", "1000000", "1000000"], "pixels"),
    (["--seed", "99999999999999999999999"], "seed"),
])
def test_work_past_the_stated_limits_is_refused_before_it_starts(tmp_path, flags, said):
    result = run("render", str(RENDER_DIR / "cornell.usda"), "-o", str(tmp_path / "out"), "--quiet", *flags)
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert said in line and "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


@pytest.mark.parametrize("action", ["run", "status"])
def test_a_binary_job_file_is_one_line(tmp_path, action):
    job = tmp_path / "binary.toml"
    job.write_bytes(bytes(range(256)) * 2)
    result = run("job", action, str(job))
    assert result.returncode == 1
    (line,) = result.stderr.strip().splitlines()
    assert str(job) in line and "not a text file" in line and "Traceback" not in result.stderr


@pytest.mark.parametrize("flags, said", [
    (["--max-depth", "1000000000"], "max depth must be at most 1024"),
    (["--norm-bounces", "1000000000"], "norm bounces must be at most 64"),
])
def test_depths_past_the_stated_limits_are_refused(tmp_path, flags, said):
    """A billion norm bounces once meant a 592 GiB allocation (a MemoryError traceback)."""
    result = run("render", str(RENDER_DIR / "cornell.usda"), "-o", str(tmp_path), *SMALL, *flags)
    assert result.returncode == 1 and result.stderr.count("\n") == 1 and said in result.stderr, result.stderr
    assert not any(tmp_path.iterdir())


def test_index_bounces_past_the_limit_are_a_recipe_error():
    from pxr_layers.errors import RecipeError
    from pxr_layers.recipe.model import MAX_INDEX_BOUNCES, IndexSettings

    IndexSettings(bounces=MAX_INDEX_BOUNCES)
    with pytest.raises(RecipeError, match=f"from 0 to {MAX_INDEX_BOUNCES}"):
        IndexSettings(bounces=MAX_INDEX_BOUNCES + 1)
