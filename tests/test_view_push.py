"""Pushing the look back into the shot: which graded layers are light edits
(pxr_layers/view/push.py), the override layer they become (stage/light_overrides.py), the
session and the server, and a re-render of the pushed shot against the regraded beauty."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdLux

from pxr_layers.errors import StageError
from pxr_layers.layers.kelvin import KELVIN_MAX, KELVIN_MIN, KELVIN_STEP, kelvin_table
from pxr_layers.layers.multipart import read_multipart
from pxr_layers.layers.nuke import LayerGrade, LayerMask
from pxr_layers.lpe import per_light_passes
from pxr_layers.stage.light_overrides import LightChange, ShotLight, check_stage, planned_edits
from pxr_layers.stage.lights import blackbody_rgb
from pxr_layers.view import push
from pxr_layers.view.composite import composite
from pxr_layers.view.session import Session, ViewError

CORNELL = Path(__file__).resolve().parents[1] / "render" / "cornell.usda"
KEY, FILL = "/World/Lights/ceilingLight", "/World/Lights/fill"
RESOLUTION, SPP = 64, 64
CLI = [sys.executable, "-m", "pxr_layers.cli.main"]
SETTINGS = ["-q", "--resolution", str(RESOLUTION), str(RESOLUTION), "--spp", str(SPP)]
TWO_LIGHTS = f"""#usda 1.0
(
    subLayers = [@{CORNELL}@]
    defaultPrim = "World"
    metersPerUnit = 0.001
    upAxis = "Y"
    startTimeCode = 1
    endTimeCode = 1
    renderSettingsPrimPath = "/Render/Settings"
)

over "World"
{{
    over "Lights"
    {{
        def SphereLight "fill"
        {{
            float inputs:intensity = 6
            float inputs:radius = 30
            color3f inputs:color = (0.8, 0.9, 1)
            bool inputs:enableColorTemperature = 1
            float inputs:colorTemperature = 5000
            double3 xformOp:translate = (420, 400, 150)
            uniform token[] xformOpOrder = ["xformOp:translate"]
        }}
    }}
}}
"""
"""The Cornell box (its ceilingLight, temperature off) plus a blue sphere light "fill" whose
temperature is on: both ways a kelvin grade is pushed."""


def render(stage: Path, folder: Path) -> Path:
    subprocess.run([*CLI, "render", str(stage), "-o", str(folder), *SETTINGS], check=True)
    return folder


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    """The two-light shot rendered once (64², 64 spp): shot.usda, out/ (its EXR and index)."""
    folder = tmp_path_factory.mktemp("push")
    (folder / "shot.usda").write_text(TWO_LIGHTS)
    return render(folder / "shot.usda", folder / "out")


@pytest.fixture
def session(rendered, tmp_path) -> Session:
    """A session over a copy of the render (each test writes its own files); the index's
    stage is the module's shot.usda."""
    copy = tmp_path / "out"
    shutil.copytree(rendered, copy)
    return Session.open(copy)


def entries(session: Session, *layers: tuple[str, str, LayerGrade]) -> list[push.PushEntry]:
    return [push.PushEntry(name, expression, grade) for name, expression, grade in layers]


def classified(session: Session, expression: str, grade: LayerGrade = LayerGrade(stops=1.0), groups=None):
    plan = push.classify(session.index, [push.PushEntry("layer", expression, grade)], groups)
    return (plan.pushed or plan.compositing)[0]


# --- kelvin in the grade -----------------------------------------------------------------------


def test_kelvin_multiplies_by_the_light_s_blackbody():
    grade = LayerGrade(stops=1.0, tint=(1.0, 0.5, 0.25), kelvin=3200)
    expected = 2.0 * np.array([1.0, 0.5, 0.25]) * blackbody_rgb(3200)
    np.testing.assert_allclose(grade.multiply, expected, rtol=1e-12)
    assert LayerGrade().multiply == (1.0, 1.0, 1.0)
    for wrong in (999, 15001, float("nan"), "3200", True):
        with pytest.raises(ValueError, match="kelvin"):
            LayerGrade(kelvin=wrong)


def test_the_kelvin_table_is_the_slider_s_steps():
    table = kelvin_table()
    assert (table["min"], table["max"], table["step"]) == (KELVIN_MIN, KELVIN_MAX, KELVIN_STEP)
    assert len(table["rgb"]) == int((KELVIN_MAX - KELVIN_MIN) / KELVIN_STEP) + 1
    for k in (0, 55, len(table["rgb"]) - 1):
        np.testing.assert_array_equal(table["rgb"][k], blackbody_rgb(KELVIN_MIN + k * KELVIN_STEP))
    json.dumps(table)  # the browser's


def test_the_session_describes_the_kelvin_table(session):
    assert session.description()["kelvin"] == kelvin_table()


# --- which layers are one light --------------------------------------------------------------


@pytest.mark.parametrize("expression", [
    "C.*<L.'ceilingLight'>",                       # the inspector's spelling
    f"C.*<L.'{KEY}'>",                             # by prim path
    "C<L.'ceilingLight'>|C.+<L.'ceilingLight'>",   # seen directly, or after bounces
    per_light_passes(["ceilingLight"])["light_ceilingLight"],  # the recipe's per-light layer
])
def test_layers_of_one_whole_light_push(session, expression):
    result = classified(session, expression)
    assert isinstance(result, push.LightEdit), result
    assert result.lights == (KEY,) and result.light == "ceilingLight"


@pytest.mark.parametrize("expression, why", [
    ("C<RD>.*<L.'ceilingLight'>", "only part of ceilingLight's paths: its diffuse reflection bounces, "
                                  "not the light seen directly"),
    ("C<RD><L.'fill'>", "only part of fill's paths: its diffuse reflection bounces (direct only), not"),
    ("C.*<L>", "matches paths of 2 lights (ceilingLight, fill)"),
    ("C.*", "matches paths of 2 lights"),
    ("C<RD>@(|S_C| = 0).*<L.'fill'>", "has covariance conditions"),
    ("C<RG>.*<L.'fill'>", "matches no path of this render"),
    ("C<RD", "its expression does not compile"),
])
def test_other_layers_stay_compositing_grades_and_say_why(session, expression, why):
    result = classified(session, expression)
    assert isinstance(result, push.CompositingGrade)
    assert why in result.why, result.why


def test_solo_and_masks_are_not_light_edits(session):
    solo = classified(session, "C.*<L.'fill'>", LayerGrade(solo=True))
    assert "solo is a viewing state" in solo.why
    plan = push.classify(session.index, [push.PushEntry("masked", "C.*<L.'fill'>", LayerGrade(mask=LayerMask("object", ("/World/fill",))))])
    assert "masked to objects" in plan.compositing[0].why


def test_a_layer_of_every_light_of_one_group_pushes_to_the_group(session):
    groups = {KEY: "room", FILL: "room"}
    result = classified(session, "C.*<L>", groups=groups)
    assert isinstance(result, push.LightEdit) and result.lights == (KEY, FILL) and result.light == "room"
    apart = classified(session, "C.*<L>", groups={KEY: "room", FILL: ""})
    assert "matches paths of 2 lights" in apart.why


def test_two_layers_of_one_light_are_refused_both(session):
    plan = push.classify(session.index, entries(session, ("a", "C.*<L.'fill'>", LayerGrade(stops=1)),
                                                 ("b", f"C.*<L.'{FILL}'>", LayerGrade(stops=-1)),
                                                 ("c", "C.*<L.'ceilingLight'>", LayerGrade(stops=1))))
    assert [edit.layer for edit in plan.pushed] == ["c"]
    assert [grade.layer for grade in plan.compositing] == ["a", "b"]
    assert all("add up in the composite" in grade.why for grade in plan.compositing)


# --- the override layer ------------------------------------------------------------------------


def test_pushed_layers_are_overrides_of_the_lights(session):
    stack = [{"id": "beauty"}, {"id": session.add_layer("key", "C.*<L.'ceilingLight'>")[0].id, "stops": 1.0,
                                 "tint": [1.0, 0.9, 0.8], "kelvin": 4000},
             {"id": session.add_layer("fill", "C.*<L.'fill'>")[0].id, "stops": -0.5, "kelvin": 9000},
             {"id": session.add_layer("key_diffuse", "C<RD>.*<L.'ceilingLight'>")[0].id, "stops": 2.0}]
    answer = session.push("look", stack, exposure=0.5)
    assert answer["files"] == {"lights": "look.lights.usda", "shot": "look.shot.usda"}
    assert [(entry["layer"], entry["light"]) for entry in answer["pushed"]] == [("key", "ceilingLight"),
                                                                               ("fill", "fill")]
    assert [entry["layer"] for entry in answer["compositing"]] == ["key_diffuse"]
    assert any("display setting" in note for note in answer["notes"])
    key, fill = (answer["pushed"][k]["edits"] for k in range(2))
    assert set(key[KEY]) == {"exposure", "color", "enableColorTemperature", "colorTemperature"}
    assert set(fill[FILL]) == {"exposure", "color"}  # its temperature was on: the grade's is in its colour

    layer = Sdf.Layer.FindOrOpen(str(session.folder / "look.lights.usda"))
    assert all(spec.specifier == Sdf.SpecifierOver for spec in (layer.GetPrimAtPath(KEY), layer.GetPrimAtPath(FILL),
                                                                 layer.GetPrimAtPath("/World")))
    assert layer.customLayerData["pxrLayers"]["kind"] == "light overrides"
    stage = Usd.Stage.Open(str(session.folder / "look.shot.usda"))
    assert stage.GetMetadata("metersPerUnit") == 0.001 and stage.GetMetadata("upAxis") == "Y"
    assert stage.GetRootLayer().subLayerPaths[0] == "./look.lights.usda"
    key_light, fill_light = UsdLux.LightAPI(stage.GetPrimAtPath(KEY)), UsdLux.LightAPI(stage.GetPrimAtPath(FILL))
    assert key_light.GetExposureAttr().Get() == 1.0 and fill_light.GetExposureAttr().Get() == -0.5
    np.testing.assert_allclose(key_light.GetColorAttr().Get(), np.array([1, 0.5975581, 0.14975634]) * [1.0, 0.9, 0.8],
                               rtol=1e-6)
    assert key_light.GetEnableColorTemperatureAttr().Get() and key_light.GetColorTemperatureAttr().Get() == 4000
    np.testing.assert_allclose(fill_light.GetColorAttr().Get(), np.array([0.8, 0.9, 1.0]) * blackbody_rgb(9000),
                               rtol=1e-6)
    assert fill_light.GetColorTemperatureAttr().Get() == 5000  # its own temperature stays
    with pytest.raises(ViewError, match="exist"):
        session.push("look", stack)


def test_a_mute_is_intensity_zero_and_nothing_else():
    light = ShotLight(KEY, "key", "", 2.0, 0.5, (1.0, 0.5, 0.25), False, 6500.0)
    assert planned_edits(LightChange((KEY,), "key", stops=3.0, kelvin=3000, mute=True), light) == {"intensity": 0.0}


@pytest.mark.parametrize("light, why", [
    (ShotLight(KEY, "key", "", 1.0, 0.0, (1, 1, 1), False, 6500.0, animated=("exposure",)), "animated"),
    (ShotLight(KEY, "key", "", 1.0, 0.0, (1, 1, 1), False, 6500.0, connected=("exposure",)), "connected"),
    (ShotLight(KEY, "key", "", 1.0, 0.0, (1, 1, 1), False, 6500.0, problem="inside a native instance"), "instance"),
])
def test_what_cannot_be_written_exactly_is_refused(light, why):
    with pytest.raises(StageError, match=why):
        planned_edits(LightChange((KEY,), "key", stops=1.0), light)
    if light.problem is None:  # an attribute the edit does not write may be animated or connected
        assert planned_edits(LightChange((KEY,), "key", tint=(1, 1, 0.5)), light) == {"color": (1, 1, 0.5)}


def test_a_changed_stage_is_refused_and_nothing_is_written(session):
    layer = session.add_layer("key", "C.*<L.'ceilingLight'>")[0]
    session.index.manifest["stage_sha256"] = "0" * 64
    with pytest.raises(StageError, match="changed since the render"):
        check_stage(session.index.manifest)
    with pytest.raises(ViewError, match="changed since the render") as error:
        session.push("look", [{"id": layer.id, "stops": 1.0}])
    assert error.value.status == 409 and len(str(error.value).splitlines()) == 1
    assert not list(session.folder.glob("look.*"))
    dry = session.pushable([{"id": layer.id, "stops": 1.0}])  # the badges still come, from the index alone
    assert dry["pushed"][0]["light"] == "ceilingLight" and "changed since the render" in dry["stage"]


# --- the re-render -------------------------------------------------------------------------------


def test_a_render_of_the_pushed_shot_is_the_regraded_beauty(session, tmp_path):
    """Grade the per-light layers cut from the index (ceilingLight +1 stop, tint, 4000 K with
    its temperature off; fill −½ stop, 9000 K with its temperature on), composite them as the
    page does (view/composite.py), push, render the pushed shot with the same settings, and
    compare the mean of each channel.

    Tolerance, from the data: pixels are independent Monte Carlo estimates, so the mean of
    the per-pixel difference D = rerender − composite has standard error SE = std(D)/√pixels
    (D's own spread, whatever the correlation of the two renders within a pixel). The mean
    must be within 4·SE per channel. Measured (64², 64 spp): means of D 5.7e-4, 2.0e-4, 8.1e-5
    for SE 3.5e-4, 9.9e-5, 9.2e-5 (1.6, 2.1, 0.9 SE), while the grade moves the means by
    about 1000, 550 and −65 SE: a push that got the stops, the tint or either kelvin wrong
    would be far outside."""
    key = session.add_layer("key", "C.*<L.'ceilingLight'>")[0]
    fill = session.add_layer("fill", "C.*<L.'fill'>")[0]
    grades = [LayerGrade(1.0, (1.0, 0.9, 0.8), kelvin=4000), LayerGrade(-0.5, kelvin=9000)]
    stack = [{"id": layer.id, "stops": grade.stops, "tint": list(grade.tint), "kelvin": grade.kelvin}
             for layer, grade in zip((key, fill), grades)]
    assert len(session.pushable(stack)["pushed"]) == 2
    files = session.push("look", stack)["files"]
    expected = composite(session.beauty[..., :3], [key.image, fill.image], grades).astype(np.float64)

    out = render(session.folder / files["shot"], tmp_path / "again")
    again = read_multipart(next(out.glob("*.exr"))).beauty[..., :3].astype(np.float64)
    difference = (again - expected).reshape(-1, 3)
    standard_error = difference.std(axis=0, ddof=1) / np.sqrt(len(difference))
    mean = difference.mean(axis=0)
    assert np.all(np.abs(mean) < 4.0 * standard_error), (mean, standard_error)
    moved = (expected - session.beauty[..., :3]).reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(moved) > 30.0 * standard_error), (moved, standard_error)  # the test can tell


# --- the server ------------------------------------------------------------------------------------


def test_the_server_badges_and_pushes(session):
    from test_view_server import Server

    running = Server(session.folder)
    try:
        layer = running.json("/api/layer", {"name": "key", "expression": "C.*<L.'ceilingLight'>"})
        partial = running.json("/api/layer", {"name": "part", "expression": "C<RD>.*<L.'ceilingLight'>"})
        stack = [{"id": layer["id"], "name": "key", "stops": 1, "tint": [1, 1, 1], "kelvin": None, "mute": False,
                  "solo": False, "mask": None},
                 {"id": partial["id"], "name": "part", "stops": 1, "tint": [1, 1, 1], "kelvin": None, "mute": False,
                  "solo": False, "mask": None}]
        badges = running.json("/api/pushable", {"layers": stack})
        assert [entry["layer"] for entry in badges["pushed"]] == ["key"] and badges["stage"] is None
        assert badges["compositing"][0]["layer"] == "part"
        assert not list(session.folder.glob("*.lights.usda"))
        answer = running.json("/api/push", {"name": "look", "layers": stack})
        assert answer["files"] == {"lights": "look.lights.usda", "shot": "look.shot.usda"}
        assert answer["pushed"][0]["edits"] == {KEY: {"exposure": 1.0}}
        status, body, _ = running.request("/api/push", {"name": "look", "layers": stack})
        assert status == 409 and "exist" in json.loads(body)["error"]
        status, body, _ = running.request("/api/push", {"name": "../x", "layers": stack})
        assert status == 400
    finally:
        running.stop()
