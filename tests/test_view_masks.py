"""Per-layer masks from the Cryptomattes (issue 39): the coverage of names on a real render
(checked by test_cryptomatte's own decoder of the specification), the masked composite
rule, the session's and the server's answers (/api/session's cryptomattes, /api/mask,
/api/pick), a page's stack entry read by grade_from_json, and a masked look written with its
Cryptomatte so that its Nuke script rebuilds the masked composite."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import CORNELL_RESOLUTION, CORNELL_SPP
from test_cryptomatte import matte, read_cryptomattes
from test_view_server import Server

from pxr_layers.layers.cryptomatte import coverage, names_at
from pxr_layers.layers.multipart import read_multipart
from pxr_layers.layers.nuke import LayerGrade, LayerMask
from pxr_layers.view.composite import composite
from pxr_layers.layers.kelvin import KELVIN_MAX, KELVIN_MIN
from pxr_layers.view.grades import grade_from_json
from pxr_layers.view.session import Session, ViewError

WALL = "/World/Geometry/redWall"
KINDS = {"object": "CryptoObject", "material": "CryptoMaterial", "asset": "CryptoAsset"}


@pytest.fixture(scope="module")
def render(tmp_path_factory) -> Path:
    """The Cornell box in the light_passes preset with all three Cryptomattes, by the real
    console script (the folder: light_passes.exr, cornell.pxlidx)."""
    from pxr_layers.cli.demo import embedded_scene

    folder = tmp_path_factory.mktemp("masks") / "cornell"
    subprocess.run([sys.executable, "-m", "pxr_layers.cli.main", "render", str(embedded_scene("cornell.usda")),
                    "--recipe", "light_passes", "-o", str(folder), "-q", "--resolution", *map(str, CORNELL_RESOLUTION),
                    "--spp", str(CORNELL_SPP), "--cryptomatte", "object,material,asset"], check=True)
    return folder


@pytest.fixture(scope="module")
def session(render) -> Session:
    return Session.open(render)


@pytest.fixture(scope="module")
def server(render, tmp_path_factory):
    copy = tmp_path_factory.mktemp("served") / "cornell"
    shutil.copytree(render, copy)
    running = Server(copy)
    yield running
    running.stop()


# --- coverage ---------------------------------------------------------------------------------


def test_a_wall_s_coverage_is_one_on_it_zero_elsewhere_and_fractional_on_its_edges(render):
    exr = render / "light_passes.exr"
    product = read_multipart(exr)
    entry = read_cryptomattes(exr)[0]["CryptoObject"]
    wall = coverage(product.cryptomattes["CryptoObject"], [WALL])
    assert wall.dtype == np.float32 and wall.shape == CORNELL_RESOLUTION[::-1]
    np.testing.assert_allclose(wall, matte(entry, [WALL]), atol=1e-6)  # the specification's decoder
    inside, outside = wall >= 1 - 1e-6, wall <= 0.0
    edge = ~inside & ~outside
    assert inside.sum() > 100 and outside.sum() > 1000 and edge.any()
    # the fractional pixels are the wall's anti-aliased border: each within the pixel
    # filter's reach (2 pixels) of a pixel wholly on it
    padded = np.pad(inside, 2)
    beside = np.zeros_like(inside)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            beside |= padded[2 + dy:2 + dy + inside.shape[0], 2 + dx:2 + dx + inside.shape[1]]
    assert beside[edge].all() and edge.sum() < inside.sum()


def test_the_coverages_of_all_names_sum_to_one_where_there_is_geometry(render):
    product = read_multipart(render / "light_passes.exr")
    alpha = product.beauty[..., 3]
    for source, matte_ in product.cryptomattes.items():
        total = sum(coverage(matte_, [name]) for name in matte_.manifest)
        np.testing.assert_allclose(total, alpha, atol=1e-5, err_msg=source)
        assert (alpha == 1).sum() > 0.5 * alpha.size
        np.testing.assert_allclose(coverage(matte_, list(matte_.manifest)), np.clip(total, 0, 1), atol=1e-6)


def test_names_at_a_pixel_are_its_ranks(render):
    product = read_multipart(render / "light_passes.exr")
    objects = product.cryptomattes["CryptoObject"]
    wall = coverage(objects, [WALL])
    y, x = np.argwhere(wall == 1)[0]
    assert names_at(objects, x, y) == [(WALL, 1.0)]
    y, x = np.argwhere((wall > 0) & (wall < 1))[0]
    picked = dict(names_at(objects, x, y))
    assert picked[WALL] == pytest.approx(float(wall[y, x]))
    assert sum(picked.values()) == pytest.approx(float(product.beauty[y, x, 3]), abs=1e-5)  # the pixel's alpha


# --- the composite rule -------------------------------------------------------------------------


def test_a_masked_composite_is_the_rule_computed_by_hand():
    """Three pixels, masks 0, 0.25, 1: w = 1 + m·(g − 1), inside soloed and unsoloed forms."""
    beauty = np.array([[[2.0, 2.0, 2.0], [4.0, 4.0, 4.0], [8.0, 8.0, 8.0]]], np.float32)
    key = np.array([[[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [4.0, 4.0, 4.0]]], np.float32)
    fill = np.full((1, 3, 3), 0.5, np.float32)
    m = np.array([[0.0, 0.25, 1.0]], np.float32)
    masked = LayerGrade(stops=1.0, tint=(1.0, 0.5, 0.0), mask=LayerMask("object", (WALL,)))  # g = 2, 1, 0
    fill_grade = LayerGrade(stops=-1.0)  # g = 0.5
    out = composite(beauty, [key, fill], [masked, fill_grade], exposure=1.0, masks=[m, None])
    # w_key per pixel and channel: 1 + m·(g − 1) = [1,1,1], [1.25, 1, 0.75], [2, 1, 0]
    w = np.array([[[1, 1, 1], [1.25, 1, 0.75], [2, 1, 0]]], np.float64)
    expected = (beauty + (w - 1) * key + (0.5 - 1) * fill) * 2.0
    np.testing.assert_array_equal(out, expected.astype(np.float32))
    soloed = composite(beauty, [key, fill], [replace(masked, solo=True), fill_grade], masks=[m, None])
    np.testing.assert_array_equal(soloed, (w * key).astype(np.float32))
    muted = composite(beauty, [key, fill], [replace(masked, mute=True), fill_grade], masks=[m, None])
    np.testing.assert_array_equal(muted, (beauty - m[..., None] * key - 0.5 * fill).astype(np.float32))


def test_a_mask_of_zero_is_the_ungraded_layer_and_of_one_the_unmasked_grade_bit_for_bit(rng):
    beauty = rng.uniform(0, 8, (4, 5, 3)).astype(np.float32)
    layers = [rng.uniform(0, 2, (4, 5, 3)).astype(np.float32) for _ in range(2)]
    grades = [LayerGrade(stops=1.37, tint=(0.3, 1.0, 2.2)), LayerGrade(stops=-0.6)]
    masked = [replace(grade, mask=LayerMask("material", ("/m",))) for grade in grades]
    zeros, ones = np.zeros((4, 5), np.float32), np.ones((4, 5), np.float32)
    for solo in (False, True):
        graded = [replace(grade, solo=solo) for grade in grades]
        masked_ = [replace(grade, solo=solo) for grade in masked]
        np.testing.assert_array_equal(composite(beauty, layers, masked_, masks=[ones, ones]),
                                      composite(beauty, layers, graded))
        np.testing.assert_array_equal(composite(beauty, layers, masked_, masks=[zeros, zeros]),
                                      composite(beauty, layers, [replace(LayerGrade(), solo=solo)] * 2))


# --- the session and the server -----------------------------------------------------------------


def test_the_session_describes_the_render_s_cryptomattes(server, render):
    described = server.json("/api/session")["cryptomattes"]
    product = read_multipart(render / "light_passes.exr")
    assert set(described) == set(KINDS)
    for kind, source in KINDS.items():
        assert described[kind] == {"layer": source, "names": sorted(product.cryptomattes[source].manifest)}
    assert WALL in described["object"]["names"]


def test_a_render_without_cryptomattes_has_none(cornell_passes):
    session = Session.open(cornell_passes)
    assert session.description()["cryptomattes"] == {}
    with pytest.raises(ViewError, match="mask: the render wrote no object Cryptomatte"):
        session.mask("object", [WALL])
    assert session.pick(3, 3) == {}


def test_api_mask_serves_the_coverage(server, render):
    product = read_multipart(render / "light_passes.exr")
    names = [WALL, "/World/Geometry/floor"]
    expected = coverage(product.cryptomattes["CryptoObject"], names)
    status, body, headers = server.request("/api/mask?kind=object&names=" + json.dumps(names).replace(" ", ""))
    assert status == 200 and (int(headers["X-Width"]), int(headers["X-Height"])) == CORNELL_RESOLUTION
    np.testing.assert_array_equal(np.frombuffer(body, "<f4").reshape(expected.shape), expected)
    status, repeated, _ = server.request("/api/mask?kind=object&names=%2FWorld%2FGeometry%2Ffloor&names=" +
                                         WALL.replace("/", "%2F"))
    assert status == 200 and repeated == body
    status, body, _ = server.request("/api/mask?kind=material&names=%2FWorld%2FMaterials%2Fred")
    red = np.frombuffer(body, "<f4").reshape(expected.shape)
    np.testing.assert_array_equal(red, coverage(product.cryptomattes["CryptoMaterial"], ["/World/Materials/red"]))
    assert red.max() == 1.0


@pytest.mark.parametrize("query, message", [
    ("kind=objects&names=%2FWorld", "mask kind 'objects': one of object, material, asset"),
    ("names=%2FWorld", "mask kind None: one of object, material, asset"),
    ("kind=object&names=%2FWorld%2FGeometry%2Fredwall",
     "mask: no object '/World/Geometry/redwall' in the render's Cryptomatte; nearest: /World/Geometry/redWall"),
    ("kind=object", "mask names are a list of 1 to"),
    ("kind=object&names=[1]", "mask names are a list of 1 to"),
    ("kind=object&names=[%22%2Fa%22", "names is a JSON array of names, or names= repeated"),
    ("kind=object&names=[NaN]", "names is a JSON array of names, or names= repeated"),
    ("kind=object&names=" + "[" * 2000 + "]" * 2000, "names is a JSON array of names, or names= repeated"),
])
def test_api_mask_refuses_unknown_kinds_and_names_in_one_line(server, query, message):
    status, body, _ = server.request("/api/mask?" + query)
    error = json.loads(body)["error"]
    assert status == 400 and message in error and "\n" not in error


def test_masks_are_cached_per_kind_and_names(session):
    first = session.mask("object", [WALL, "/World/Geometry/floor"])
    assert session.mask("object", ["/World/Geometry/floor", WALL]) is first
    assert session.mask("asset", ["/World"]) is not first


def test_api_pick_names_what_is_under_a_pixel(server, render):
    product = read_multipart(render / "light_passes.exr")
    wall = coverage(product.cryptomattes["CryptoObject"], [WALL])
    y, x = np.argwhere(wall == 1)[0]
    picked = server.json(f"/api/pick?x={x}&y={y}")
    assert picked["object"] == [{"name": WALL, "coverage": 1.0}]
    assert picked["material"] == [{"name": "/World/Materials/red", "coverage": 1.0}]
    assert picked["asset"] == [{"name": "/World", "coverage": 1.0}]
    for query in ("x=64&y=0", "x=-1&y=0", "x=a&y=0", "x=1"):
        status, body, _ = server.request("/api/pick?" + query)
        assert status == 400 and "pick needs" in json.loads(body)["error"]


# --- a page's stack entry --------------------------------------------------------------------------


def test_grade_from_json_reads_an_entry():
    grade = grade_from_json({"id": "key", "stops": 1.5, "tint": [1, 0.5, 0], "mute": False, "solo": True,
                             "mask": {"kind": "object", "names": [WALL, WALL, "/World/Geometry/floor"]}},
                            "layer 'key'")
    assert grade == LayerGrade(stops=1.5, tint=(1.0, 0.5, 0.0), solo=True,
                               mask=LayerMask("object", (WALL, "/World/Geometry/floor")))
    assert grade_from_json({"id": "key"}, "layer 'key'") == LayerGrade()
    assert grade_from_json({"id": "key", "mask": None, "kelvin": None}, "layer 'key'") == LayerGrade()


@pytest.mark.parametrize("entry, message", [
    ({"stops": "1"}, "layer 'key': stops (stops) must be a number"),
    ({"stops": 1e9}, "layer 'key': stops (stops) must be a number"),
    ({"tint": [1, 1]}, "layer 'key': tint is three numbers"),
    ({"tint": [1, -1, 1]}, "layer 'key': tint must be a number from 0"),
    ({"mute": 1}, "layer 'key': mute is true or false, not 1"),
    ({"solo": "yes"}, "layer 'key': solo is true or false"),
    ({"mask": []}, "layer 'key': mask is null or"),
    ({"mask": {"kind": "object", "names": [WALL], "invert": True}}, "layer 'key': mask is null or"),
    ({"mask": {"kind": "prim", "names": [WALL]}}, "layer 'key': mask kind 'prim': one of object, material, asset"),
    ({"mask": {"kind": "object", "names": []}}, "layer 'key': mask names are a list of 1 to"),
    ({"mask": {"kind": "object", "names": WALL}}, "layer 'key': mask names are a list of 1 to"),
    ({"mask": {"kind": "object", "names": [""]}}, "layer 'key': mask names are a list of 1 to"),
    ({"kelvin": 200}, f"layer 'key': kelvin is null or a colour temperature from {KELVIN_MIN:g} to {KELVIN_MAX:g} K"),
    ({"kelvin": "6500"}, "layer 'key': kelvin is null or a colour temperature"),
    ({"kelvin": True}, "layer 'key': kelvin is null or a colour temperature"),
])
def test_grade_from_json_names_the_layer_and_the_field(entry, message):
    with pytest.raises(ViewError) as raised:
        grade_from_json({"id": "key", **entry}, "layer 'key'")
    assert message in str(raised.value) and raised.value.status == 400 and "\n" not in str(raised.value)


def test_grade_from_json_passes_kelvin_through():
    assert grade_from_json({"kelvin": 6500}, "layer 'key'").kelvin == 6500.0


def test_grade_from_json_checks_mask_names_against_the_render(session):
    known = session.mask_names
    entry = {"mask": {"kind": "material", "names": ["/World/Materials/gren"]}}
    with pytest.raises(ViewError, match="layer 'key': mask: no material '/World/Materials/gren' in the render's "
                                        "Cryptomatte; nearest: /World/Materials/green"):
        grade_from_json(entry, "layer 'key'", known=known)
    entry["mask"]["names"] = ["/World/Materials/green"]
    assert grade_from_json(entry, "layer 'key'", known=known).mask == LayerMask("material", ("/World/Materials/green",))


# --- a masked look ---------------------------------------------------------------------------------


def test_a_masked_look_carries_its_cryptomatte_and_its_script_rebuilds_the_masked_composite(session, render,
                                                                                             tmp_path):
    """What a masked /api/save writes: the look's recipe gains the Cryptomatte layers of its
    masks (Session.look_cryptomattes), written into its EXR by deliver, so the Nuke script's
    keyers read them from the look's own EXR; the script is then the masked composite."""
    from test_nuke_script import bound, composite_rule, evaluate

    from pxr_layers.layers.deliver import deliver, index_metadata
    from pxr_layers.layers.nuke import write_nuke_script
    from pxr_layers.recipe.model import Layer, Recipe

    grades = {"diffuse": LayerGrade(stops=1.5, tint=(1.0, 0.6, 0.3), mask=LayerMask("object", (WALL, "/World/Geometry/tallBox"))),
              "glossy": LayerGrade(stops=-1.0, mute=True, mask=LayerMask("material", ("/World/Materials/white",)))}
    chosen = [Layer("diffuse", "lpe", "C<RD>.*"), Layer("glossy", "lpe", "C<RG>.*")]
    crypto = session.look_cryptomattes(grades)
    assert set(crypto) == {"CryptoObject", "CryptoMaterial"}
    recipe = Recipe((replace(session.base_product, name="look", output_name="look.exr", prim_path="",
                             layers=tuple(chosen), per_light="none", denoise=False),)).with_cryptomattes(crypto)
    exr, script = tmp_path / "look.exr", tmp_path / "look.nk"
    deliver(session.index, recipe, session.beauty, {"look": exr}, data=crypto, previews=False,
            metadata=index_metadata(session.index, tmp_path))
    write_nuke_script(script, exr, ["diffuse", "glossy"], grades, resolution=(session.width, session.height),
                      partition=False, cryptomattes={source: matte_.depth for source, matte_ in crypto.items()})
    look = read_multipart(exr)
    for source, matte_ in crypto.items():
        assert look.cryptomattes[source].manifest == matte_.manifest
        np.testing.assert_array_equal(look.cryptomattes[source].ids, matte_.ids)
    out, nuke = evaluate(script.read_text(), script)
    layers = {name: look.parts[name] for name in ("diffuse", "glossy")}
    masks = {name: matte(read_cryptomattes(exr)[0][grade.mask.source], list(grade.mask.names))
             for name, grade in grades.items()}
    expected = composite_rule(look.beauty, layers, grades, 0.0, masks)
    assert np.all(np.abs(out[..., :3] - expected) <= 2 * bound(look.beauty, layers, grades, 0.0) + 1e-6)
    assert nuke.nodes["Merge_glossy"].knob("disable") is None  # muted, but masked: the layer stays outside
    inspector = composite(look.beauty[..., :3], list(layers.values()), list(grades.values()), 0.0,
                          [session.mask_coverage(grade.mask.kind, list(grade.mask.names)) for grade in grades.values()])
    np.testing.assert_allclose(inspector, expected, rtol=1e-5, atol=1e-6)


def test_a_mask_of_a_kind_the_render_did_not_write_is_refused(cornell_passes):
    with pytest.raises(ViewError, match="a mask of objects, but the render wrote no object Cryptomatte"):
        Session.open(cornell_passes).look_cryptomattes({"key": LayerGrade(mask=LayerMask("object", (WALL,)))})
