"""Shot job definitions: TOML → Job (frames, templates, extends, paths, every error), the
demo show's shot010 with its recipe, and the animated showcase it renders."""

from __future__ import annotations

import dataclasses
import pickle
import textwrap
from pathlib import Path

import numpy as np
import pytest

from pxr_layers.errors import JobError, PxrLayersError
from pxr_layers.request import RenderRequest
from pxr_layers.jobs import (
    Job,
    definition,
    expand_template,
    has_frame_token,
    load_job,
    parse_frames,
)
from pxr_layers.recipe import preset

ROOT = Path(__file__).resolve().parents[1]
SHOT010 = ROOT / "pipelines" / "shows" / "demo" / "shot010.toml"
ANIMATED = ROOT / "render" / "showcase_animated.usda"
STILL = ROOT / "render" / "showcase.usda"


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(textwrap.dedent(text).lstrip())
    return path


@pytest.fixture
def stage(tmp_path: Path) -> Path:
    """An empty file standing in for a stage: the definition only checks that it exists."""
    return write(tmp_path / "assets" / "shot.usda", "#usda 1.0\n")


def job_file(tmp_path: Path, body: str = "", name: str = "shot.toml",
             head: str = 'stage = "assets/shot.usda"\nframes = "1-3"\n') -> Path:
    return write(tmp_path / name, head + textwrap.dedent(body))


# --- frames -------------------------------------------------------------------------------


@pytest.mark.parametrize(("value", "frames"), [
    ("1-24", tuple(range(1, 25))),
    ("1-24x4", (1, 5, 9, 13, 17, 21)),
    ("1-10x3, 20, 30-34x2", (1, 4, 7, 10, 20, 30, 32, 34)),
    (" 7 ", (7,)),
    ("-5--3", (-5, -4, -3)),
    ("1001-1003", (1001, 1002, 1003)),
    ([1, 5, 9], (1, 5, 9)),
    ([12, 3.0], (12, 3)),
    (42, (42,)),
])
def test_frames(value, frames):
    parsed = parse_frames(value)
    assert parsed == tuple(float(f) for f in frames)
    assert all(isinstance(f, float) for f in parsed)


@pytest.mark.parametrize(("text", "position", "words"), [
    ("1-24y4", 4, "expected ',', 'x' or the end, found 'y' at character 5"),
    ("1y", 1, "found 'y'"),
    ("", 0, "expected a frame number, found the end"),
    ("1-", 2, "expected the last frame of the range"),
    ("1,", 2, "expected a frame number"),
    ("24-1", 0, "ends before it starts (write 1-24)"),
    ("1-24x0", 5, "the step must be at least 1"),
    ("1-24x-2", 5, "expected a step"),
    ("1-4, 3", 5, "frame 3 is listed twice"),
    ("a-b", 0, "expected a frame number"),
])
def test_bad_frame_text_names_the_position(text, position, words):
    with pytest.raises(JobError) as caught:
        parse_frames(text, file="shot.toml")
    assert caught.value.position == position
    assert caught.value.file == "shot.toml" and caught.value.key == "frames"
    assert words in str(caught.value)
    assert str(caught.value).startswith(f"shot.toml: frames: bad frame range {text!r}")


@pytest.mark.parametrize(("value", "key", "words"), [
    ([1, 1.5], "frames[1]", "not a whole number"),
    ([1, 2, 1], "frames[2]", "listed twice"),
    ([1, "2"], "frames[1]", "must be a frame number"),
    ([], "frames", "empty"),
    (True, "frames", "not True"),
    ({"a": 1}, "frames", "not a table"),
])
def test_bad_frame_lists(value, key, words):
    with pytest.raises(JobError, match=words) as caught:
        parse_frames(value)
    assert caught.value.key == key


# --- templates ----------------------------------------------------------------------------


@pytest.mark.parametrize(("template", "frame", "expanded"), [
    ("shot010.$F4", 7, "shot010.0007"),
    ("shot010.${F4}_beauty", 7, "shot010.0007_beauty"),
    ("shot010.$F", 7, "shot010.7"),
    ("shot010.$F4", 1001, "shot010.1001"),
    ("shot010.$F2", 1001, "shot010.1001"),
    ("shot010.####", 12, "shot010.0012"),
    ("shot010.#", 12, "shot010.12"),
    ("$JOB.$F4", 3.0, "shot020.0003"),
    ("shot010.$F4", -1, "shot010.-001"),
    ("plain", 5, "plain"),
])
def test_expand_template(template, frame, expanded):
    assert expand_template(template, frame, "shot020") == expanded


def test_frame_tokens():
    assert has_frame_token("a.$F4") and has_frame_token("a.${F3}") and has_frame_token("a.##")
    assert has_frame_token("a.$F")
    assert not has_frame_token("$JOB.beauty") and not has_frame_token("light_passes.exr")
    assert expand_template("a.$F4.####", None) == "a.$F4.####"
    with pytest.raises(JobError, match="not a whole number"):
        expand_template("a.$F4", 1.5)


# --- resolution: defaults, extends, paths -------------------------------------------------


def test_minimal_job_takes_every_default(tmp_path, stage):
    job = load_job(job_file(tmp_path))
    assert job.file == tmp_path / "shot.toml" and job.name == "shot"
    assert job.request.stage == stage and job.frames == (1.0, 2.0, 3.0)
    assert job.sources == (job.file,)
    assert job.request.recipe_layers == () and job.request.settings is None and job.request.per_light is None
    assert job.request == RenderRequest(stage)  # every default is the render command's
    assert job.request.resolution is None
    assert job.output_directory == tmp_path / "out" / "shot"
    assert job.output_template == "$JOB.$F4"
    assert (job.batch_pixels, job.retries, job.scheduler) == (16384, 2, None)
    assert job.workers == definition.default_workers() >= 1
    assert job.output_stem(2) == "shot.0002"
    assert job.beauty_path(2) == tmp_path / "out" / "shot" / "shot.0002.exr"
    assert job.index_path(2) == tmp_path / "out" / "shot" / "shot.0002.pxlidx"
    assert job.frame_directory(2) == tmp_path / "out" / "shot" / "shot.0002"
    assert job.product_path("light_passes.exr", 2) == job.output_directory / "shot.0002.light_passes.exr"
    assert job.product_path("sphere.####.exr", 2) == job.output_directory / "sphere.0002.exr"
    assert job.product_path("/abs/x.$F4.exr", 2) == Path("/abs/x.0002.exr")
    assert pickle.loads(pickle.dumps(job)) == job  # Dask ships it to workers
    with pytest.raises(dataclasses.FrozenInstanceError):
        job.request.spp = 1


def test_the_readme_documents_every_key():
    lines = (ROOT / "pipelines" / "README.md").read_text().splitlines()
    for key in definition.KEYS:
        table, _, leaf = key.name.rpartition(".")
        row = f"| `[{table}]` `{leaf}` |" if table else f"| `{leaf}` |"
        (line,) = [line for line in lines if line.startswith(row)]
        default = line.removeprefix(row).split("|")[0]
        assert key.default.strip('"') in default, (key.name, default)


def test_defaults_are_the_render_commands(tmp_path):
    from pxr_layers.cli.main import build_parser
    from pxr_layers.cli.render import request_from_args

    args = build_parser().parse_args(["render", "shot.usda"])
    assert request_from_args(Path("shot.usda"), args) == RenderRequest(Path("shot.usda"))
    from pxr_layers.paths.format import SUFFIX

    assert definition.INDEX_SUFFIX == SUFFIX


def test_every_key_set(tmp_path, stage):
    write(tmp_path / "looks" / "grade.usda", "#usda 1.0\n")
    job = load_job(job_file(tmp_path, """
        settings = "/Render/Other"
        [recipe]
        layers = ["light_passes", "looks/grade.usda"]
        per_light = "groups"
        [render]
        spp = 4
        seed = 9
        max_depth = 3
        norm_bounces = 0
        resolution = [320, 180]
        [output]
        directory = "/tmp/renders/$JOB"
        stem = "beauty/${JOB}_v2.####"
        [dask]
        scheduler = "tcp://farm.example:8786"
        workers = 3
        batch_pixels = 1000
        retries = 0
    """))
    assert job.request.settings == "/Render/Other"
    assert job.request.recipe_layers == (preset("light_passes"), tmp_path / "looks" / "grade.usda")
    assert job.request.per_light == "groups"
    assert (job.request.spp, job.request.seed, job.request.max_depth, job.request.norm_bounces, job.request.resolution) == (4, 9, 3, 0, (320, 180))
    assert job.output_directory == Path("/tmp/renders/shot")
    assert job.beauty_path(3) == Path("/tmp/renders/shot/beauty/shot_v2.0003.exr")
    assert (job.scheduler, job.workers, job.batch_pixels, job.retries) == ("tcp://farm.example:8786", 3, 1000, 0)


def show_and_shot(tmp_path: Path, show: str, shot: str) -> Path:
    """shows/demo/show.toml (with its own recipe file) and shows/demo/shots/a/shot.toml."""
    write(tmp_path / "assets" / "shot.usda", "#usda 1.0\n")
    write(tmp_path / "shows" / "demo" / "show_recipe.usda", "#usda 1.0\n")
    write(tmp_path / "shows" / "demo" / "show.toml", show)
    return write(tmp_path / "shows" / "demo" / "shots" / "a" / "shot.toml", shot)


SHOW = """
    frames = "1-10"
    [recipe]
    layers = ["light_passes", "show_recipe.usda"]
    [render]
    spp = 32
    seed = 5
    [output]
    directory = "renders/$JOB"
    [dask]
    retries = 4
"""


def test_extends_merges_key_by_key_and_the_child_wins(tmp_path):
    shot = show_and_shot(tmp_path, SHOW, """
        extends = "../../show.toml"
        stage = "../../../../assets/shot.usda"
        frames = "1-24x4"
        [render]
        spp = 8
        [output]
        stem = "a.$F4"
    """)
    job = load_job(shot)
    show = tmp_path / "shows" / "demo" / "show.toml"
    assert job.sources == (shot, show)
    assert job.frames == (1.0, 5.0, 9.0, 13.0, 17.0, 21.0)  # the shot's
    assert (job.request.spp, job.request.seed) == (8, 5)                    # [render] merged key by key
    assert job.retries == 4                                 # only the show sets it
    # Relative paths are relative to the file that sets them: the show's recipe file and
    # output directory from the show, the stage from the shot; $JOB is the shot's name.
    assert job.request.recipe_layers == (preset("light_passes"), show.parent / "show_recipe.usda")
    assert job.output_directory == show.parent / "renders" / "shot"
    assert job.request.stage == tmp_path / "assets" / "shot.usda"
    assert job.index_path(5) == show.parent / "renders" / "shot" / "a.0005.pxlidx"


def test_recipe_layers_replace_and_add_layers_append(tmp_path):
    head = 'extends = "../../show.toml"\nstage = "../../../../assets/shot.usda"\n'
    shot = show_and_shot(tmp_path, SHOW, head + '[recipe]\nadd_layers = ["showcase", "mine.usda"]\n')
    write(shot.parent / "mine.usda", "#usda 1.0\n")
    show_recipe = tmp_path / "shows" / "demo" / "show_recipe.usda"
    assert load_job(shot).request.recipe_layers == (
        preset("light_passes"), show_recipe, preset("showcase"), shot.parent / "mine.usda")
    shot.write_text(head + '[recipe]\nlayers = ["showcase"]\n')
    assert load_job(shot).request.recipe_layers == (preset("showcase"),)
    shot.write_text(head + '[recipe]\nlayers = []\nadd_layers = ["showcase"]\n')
    assert load_job(shot).request.recipe_layers == (preset("showcase"),)


def test_a_chain_of_three(tmp_path, stage):
    write(tmp_path / "studio.toml", '[render]\nmax_depth = 4\nseed = 1\n[dask]\nbatch_pixels = 64\n')
    write(tmp_path / "show.toml", 'extends = "studio.toml"\n[render]\nseed = 2\n')
    job = load_job(job_file(tmp_path, '[dask]\nbatch_pixels = 128\n', head='extends = "show.toml"\n'
                            'stage = "assets/shot.usda"\nframes = [1]\n'))
    assert (job.request.max_depth, job.request.seed, job.batch_pixels) == (4, 2, 128)
    assert [p.name for p in job.sources] == ["shot.toml", "show.toml", "studio.toml"]


def test_a_single_frame_needs_no_frame_token(tmp_path, stage):
    job = load_job(job_file(tmp_path, '[output]\nstem = "still"\n', head='stage = "assets/shot.usda"\nframes = 1\n'))
    assert job.beauty_path(1).name == "still.exr"


def test_overrides(tmp_path, stage, monkeypatch):
    monkeypatch.chdir(tmp_path)
    write(tmp_path / "other.usda", "#usda 1.0\n")
    job = load_job(job_file(tmp_path), {"frames": "2-3", "render.spp": 4, "stage": "other.usda",
                                         "dask.scheduler": "local"})
    assert (job.frames, job.request.spp, job.request.stage, job.scheduler) == ((2.0, 3.0), 4, tmp_path / "other.usda", None)
    with pytest.raises(JobError, match="cannot be overridden"):
        load_job(job_file(tmp_path), {"extends": "x.toml"})
    with pytest.raises(JobError, match=r"did you mean render\.spp") as caught:
        load_job(job_file(tmp_path), {"render.sp": 4})
    assert caught.value.file == definition.OVERRIDES


# --- errors: each names the file and the key ----------------------------------------------


def error_of(path: Path, overrides=None) -> JobError:
    with pytest.raises(JobError) as caught:
        load_job(path, overrides)
    assert isinstance(caught.value, PxrLayersError)
    return caught.value


@pytest.mark.parametrize(("body", "key", "words"), [
    ("spp = 3\n", "spp", "unknown key (did you mean render.spp?)"),
    ("[render]\nsp = 3\n", "render.sp", "unknown key (did you mean render.spp?)"),
    ("[render]\nmax_dpeth = 3\n", "render.max_dpeth", "did you mean render.max_depth?"),
    ("[rendr]\nspp = 3\n", "rendr", "did you mean the table [render]?"),
    ("[output]\nframes = 3\n", "output.frames", "did you mean frames?"),
    ("render = 3\n", "render", "must be a table"),
    ("[render]\nspp = 0\n", "render.spp", "must be at least 1, not 0"),
    ("[render]\nspp = -4\n", "render.spp", "must be at least 1, not -4"),
    ("[render]\nspp = 2.5\n", "render.spp", "must be an integer"),
    ("[render]\nspp = true\n", "render.spp", "must be an integer"),
    ("[render]\nmax_depth = -1\n", "render.max_depth", "at least 0"),
    ("[render]\nresolution = [0, 10]\n", "render.resolution", "must be positive"),
    ("[render]\nresolution = [10]\n", "render.resolution", "[width, height]"),
    ("[dask]\nbatch_pixels = 0\n", "dask.batch_pixels", "at least 1"),
    ("[dask]\nretries = -1\n", "dask.retries", "at least 0"),
    ("[dask]\nworkers = 0\n", "dask.workers", "at least 1"),
    ('[dask]\nscheduler = "http://farm:8786"\n', "dask.scheduler", "unknown protocol 'http'"),
    ('[dask]\nscheduler = "tcp://farm"\n', "dask.scheduler", "bad scheduler address 'tcp://farm'"),
    ('[dask]\nscheduler = "tcp://farm:99999"\n', "dask.scheduler", "port 99999"),
    ('[dask]\nscheduler = "farm 8786"\n', "dask.scheduler", "bad scheduler address"),
    ('[dask]\nscheduler = "tcp://256.1.1.1:8786"\n', "dask.scheduler", "neither an IP address nor a host name"),
    ('[dask]\nscheduler = "tcp://farm..local:8786"\n', "dask.scheduler", "neither an IP address nor a host name"),
    ('[recipe]\nper_light = "all"\n', "recipe.per_light", "allowed: none, lights, groups, recipe"),
    ('[recipe]\nlayers = ["light_pases"]\n', "recipe.layers[0]", "did you mean 'light_passes'?"),
    ('[recipe]\nlayers = ["light_passes", 3]\n', "recipe.layers[1]", "must be a string"),
    ('[recipe]\nlayers = ["missing.usda"]\n', "recipe.layers[0]", "missing.usda: file not found"),
    ('settings = "Render/Settings"\n', "settings", "not an absolute prim path"),
    ('[output]\nstem = "shot"\n', "output.stem", "no frame number"),
    ('[output]\nstem = "shot.$F4.exr"\n', "output.stem", "without a suffix"),
    ('[output]\nstem = "shot.$G4"\n', "output.stem", "unknown variable $G"),
    ('[output]\nstem = "shot.$F0"\n', "output.stem", "padding must be 1..9"),
    ('[output]\nstem = "$JOB_v2.$F4"\n', "output.stem", "unknown variable $JOB_v"),
    ('[output]\ndirectory = "out/$F4"\n', "output.directory", "cannot depend on the frame"),
])
def test_errors_name_file_and_key(tmp_path, stage, body, key, words):
    path = job_file(tmp_path, body)
    error = error_of(path)
    assert error.file == str(path) and error.key == key
    assert words in str(error)
    assert str(error).startswith(f"{path}: {key}: ")


def test_missing_stage(tmp_path):
    path = write(tmp_path / "shot.toml", 'frames = "1-3"\n')
    error = error_of(path)
    assert (error.file, error.key) == (str(path), "stage")
    assert "not set" in str(error)
    path.write_text('stage = "nowhere/shot.usda"\nframes = "1-3"\n')
    error = error_of(path)
    assert (error.file, error.key) == (str(path), "stage")
    assert f"{tmp_path / 'nowhere' / 'shot.usda'}: file not found" in str(error)


def test_missing_frames(tmp_path, stage):
    error = error_of(write(tmp_path / "shot.toml", 'stage = "assets/shot.usda"\n'))
    assert error.key == "frames" and "not set" in str(error)


def test_errors_name_the_file_that_sets_the_value(tmp_path):
    """A missing recipe file or a bad frame range in the show names the show, not the shot."""
    show = tmp_path / "shows" / "demo" / "show.toml"
    shot = show_and_shot(tmp_path, '[recipe]\nlayers = ["gone.usda"]\n',
                         'extends = "../../show.toml"\nstage = "../../../../assets/shot.usda"\nframes = "1-3"\n')
    error = error_of(shot)
    assert (error.file, error.key) == (str(show), "recipe.layers[0]")
    assert str(show.parent / "gone.usda") in str(error)
    show.write_text('frames = "1-x"\n')
    error = error_of(shot)
    assert (error.file, error.key, error.position) == (str(show), "frames", 2)
    # add_layers entries are named by their own key.
    show.write_text("")
    shot.write_text(shot.read_text() + '[recipe]\nadd_layers = ["light_passes", "nope.usda"]\n')
    error = error_of(shot)
    assert (error.file, error.key) == (str(shot), "recipe.add_layers[1]")


def test_extends_cycle(tmp_path, stage):
    a = job_file(tmp_path, head='extends = "b.toml"\nstage = "assets/shot.usda"\nframes = "1-3"\n', name="a.toml")
    b = write(tmp_path / "b.toml", 'extends = "a.toml"\n')
    error = error_of(a)
    assert (error.file, error.key) == (str(b), "extends")
    assert "extends cycle: a.toml -> b.toml -> a.toml" in str(error)
    a.write_text('extends = "a.toml"\n')
    error = error_of(a)
    assert (error.file, error.key) == (str(a), "extends")
    assert "a.toml -> a.toml" in str(error)


def test_extends_missing_file(tmp_path, stage):
    path = job_file(tmp_path, head='extends = "../nowhere/show.toml"\n')
    error = error_of(path)
    assert (error.file, error.key) == (str(path), "extends")
    assert "file not found" in str(error) and str(tmp_path.parent / "nowhere" / "show.toml") in str(error)


def test_missing_job_file_and_bad_toml(tmp_path):
    error = error_of(tmp_path / "nope.toml")
    assert error.file == str(tmp_path / "nope.toml") and "file not found" in str(error)
    bad = write(tmp_path / "bad.toml", 'stage = "x\n')
    error = error_of(bad)
    assert error.file == str(bad) and "not valid TOML" in str(error) and "line 1" in str(error)


# --- the demo show's shot010 --------------------------------------------------------------


def test_shot010_loads():
    job = load_job(SHOT010)
    demo = SHOT010.parent
    assert isinstance(job, Job) and job.name == "shot010"
    assert job.sources == (SHOT010, demo / "show.toml")
    assert job.request.stage == ANIMATED
    assert job.frames == tuple(float(f) for f in range(1, 25))
    assert job.request.recipe_layers == (preset("light_passes"), preset("showcase"), demo / "shot010_recipe.usda")
    assert job.request.per_light == "lights"
    assert job.request.norm_bounces is None and job.request.max_depth == 8
    assert job.output_directory == ROOT / "out" / "demo" / "shot010"
    assert job.beauty_path(1).name == "shot010.0001.exr"
    assert job.index_path(24).name == "shot010.0024.pxlidx"


def test_shot010_recipe_resolves():
    from pxr_layers.stage import load_recipe

    job = load_job(SHOT010)
    recipe = load_recipe(job.request.stage, job.request.settings, recipe_layers=job.request.recipe_layers, per_light=job.request.per_light)
    assert recipe.settings_path == "/Render/Shot010/Settings"
    lights = ["light_key", "light_fill", "light_sky", "light_other"]
    products = {product.name: product for product in recipe.products}
    assert list(products) == ["passes", "selections", "sphere"]
    assert [layer.name for layer in products["sphere"].layers] == ["sphere", *lights]
    assert products["sphere"].expressions()["sphere"] == "C<RD'curvedSphere'>.*"
    assert [layer.name for layer in products["passes"].layers][-4:] == lights
    for product in recipe.products:
        assert product.camera == "/World/Camera" and product.resolution == (256, 256)
    paths = {job.product_path(product.output_name, 7).name for product in recipe.products}
    assert paths == {"shot010.0007.light_passes.exr", "shot010.0007.showcase_selections.exr",
                     "shot010.0007.sphere.exr"}


# --- the animated showcase ----------------------------------------------------------------


@pytest.fixture(scope="module")
def animated():
    from pxr_layers.stage import load_stage

    return {frame: load_stage(ANIMATED, frame=frame) for frame in (1, 24)}


def _mesh(scene, name):
    (mesh,) = [mesh for mesh in scene.meshes if mesh.name == name]
    return mesh


def test_animated_showcase_composes():
    from pxr import Usd

    stage = Usd.Stage.Open(str(ANIMATED))
    assert stage.GetCompositionErrors() == []
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (1, 24, 24)
    assert stage.GetMetadata("renderSettingsPrimPath") == "/Render/Settings"
    # Geometry and materials come from the still showcase, not a copy.
    assert ANIMATED.read_text().count("def ") == 0


def test_animated_showcase_moves_between_frames(animated):
    (first, first_spec), (last, last_spec) = animated[1], animated[24]
    assert first.frame == 1.0 and last.frame == 24.0
    assert first_spec.settings_path == last_spec.settings_path == "/Render/Settings"
    # The camera trucks and dollies: a different matrix, still looking at the set.
    assert not np.allclose(first_spec.camera.world_from_camera, last_spec.camera.world_from_camera)
    np.testing.assert_allclose(last_spec.camera.world_from_camera[:3, 3], (0.2, 1.55, 3.9), atol=1e-6)
    # The key brightens (40 → 64); the fill does not change.
    lights = {a.name: (a, b) for a, b in zip(first.lights, last.lights)}
    np.testing.assert_allclose(lights["key"][0].radiance, 40.0)
    np.testing.assert_allclose(lights["key"][1].radiance, 64.0)
    np.testing.assert_array_equal(lights["fill"][0].radiance, lights["fill"][1].radiance)
    # The sphere rolls from (-1.05, 0.4, 0.2) to (-1.15, 0.4, 0.6); the box stays.
    start, end = _mesh(first, "curvedSphere").points, _mesh(last, "curvedSphere").points
    np.testing.assert_allclose(end - start, np.broadcast_to((-0.1, 0.0, 0.4), start.shape), atol=1e-5)
    np.testing.assert_array_equal(_mesh(first, "matteBox").points, _mesh(last, "matteBox").points)


def test_animated_showcase_frame_1_is_the_still_showcase(animated):
    from pxr_layers.stage import load_stage

    still, still_spec = load_stage(STILL)
    scene, spec = animated[1]
    np.testing.assert_allclose(spec.camera.world_from_camera, still_spec.camera.world_from_camera, atol=1e-6)
    assert [m.name for m in scene.meshes] == [m.name for m in still.meshes]
    for mesh, reference in zip(scene.meshes, still.meshes):
        np.testing.assert_allclose(mesh.points, reference.points, atol=1e-6)
    for light, reference in zip(scene.lights, still.lights):
        np.testing.assert_allclose(light.radiance, reference.radiance)


def test_variants_and_the_stage_reading_keys_reach_the_request(tmp_path):
    stage = tmp_path / "shot.usda"
    stage.write_text("#usda 1.0\n")
    job_file = tmp_path / "shot.toml"
    job_file.write_text(textwrap.dedent("""
        stage = "shot.usda"
        frames = "1"
        variants = ["/World/Teapot:modelVariant=Fancy", "/World/Teapot:shadingVariant=Blue"]
        [render]
        subdiv_level = 1
        default_lights = false
        strict = true
    """))
    request = load_job(job_file).request
    assert [str(selection) for selection in request.variants] == ["/World/Teapot:modelVariant=Fancy",
                                                                  "/World/Teapot:shadingVariant=Blue"]
    assert (request.subdiv_level, request.default_lights, request.strict) == (1, False, True)
    job_file.write_text(job_file.read_text().replace("Blue", "Blue=x"))
    with pytest.raises(JobError, match=r"variants\[1\]"):
        load_job(job_file)
    job_file.write_text(job_file.read_text().replace("Blue=x", "Blue").replace("subdiv_level = 1", "subdiv_level = 9"))
    with pytest.raises(JobError, match="at most 6"):
        load_job(job_file)
