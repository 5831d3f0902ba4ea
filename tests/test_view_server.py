"""The inspector's server over HTTP: the real `pxr-layers view` on a demo output, its access
rules, and its answers checked against the index and `pxr-layers extract` (the page itself
is tested in a real browser: test_view_browser.py)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from pxr_layers import lpe
from pxr_layers.errors import LpeSyntaxError
from pxr_layers.paths.events import path_text
from pxr_layers.paths.reader import PathIndex
from pxr_layers.scene import REC709_LUMINANCE

RED_WALL_DIRECT = "C RD'redWall' L'ceilingLight'"
CLI = [sys.executable, "-m", "pxr_layers.cli.main"]


class Server:
    """A running `pxr-layers view FOLDER --no-browser`: its URL's base and token."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.process = subprocess.Popen([*CLI, "view", str(folder), "--no-browser", "--port", "0", "-q"],
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        url = self.process.stdout.readline().strip()
        if not url:
            raise RuntimeError(f"the server did not start: {self.process.stderr.read()}")
        self.base, _, self.token = url.partition("/?token=")

    def request(self, path: str, body: dict | None = None, *, token: str | None = "header",
                headers: dict | None = None, method: str | None = None) -> tuple[int, bytes, dict]:
        """(status, body, headers) of GET path (POST body as JSON, or `method`); token: "header",
        "query" or None."""
        url = self.base + path
        sent = dict(headers or {})
        if token == "header":
            sent["X-Pxr-Token"] = self.token
        elif token == "query":
            url += ("&" if "?" in path else "?") + "token=" + self.token
        data = json.dumps(body).encode() if body is not None else None
        if data is not None:
            sent["Content-Type"] = "application/json"
        request = urllib.request.Request(url, data=data, headers=sent,
                                         method=method or ("POST" if data is not None else "GET"))
        try:
            with urllib.request.urlopen(request, timeout=120) as response:
                return response.status, response.read(), dict(response.headers)
        except urllib.error.HTTPError as error:
            return error.code, error.read(), dict(error.headers)

    def json(self, path: str, body: dict | None = None) -> dict:
        status, data, _ = self.request(path, body)
        assert status == 200, data
        return json.loads(data)

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(timeout=30)


@pytest.fixture(scope="module")
def folder(cornell_passes, tmp_path_factory) -> Path:
    copy = tmp_path_factory.mktemp("view") / "demo"
    shutil.copytree(cornell_passes, copy)
    return copy


@pytest.fixture(scope="module")
def server(folder):
    running = Server(folder)
    yield running
    running.stop()


def parts(path: Path) -> dict[str, np.ndarray]:
    """Part name → (h, w, c) float32 of a multipart EXR, read with OpenEXR directly."""
    exr = OpenEXR.File(str(path), separate_channels=True)
    out = {}
    for part in exr.parts:
        names = sorted(part.channels, key=lambda c: "RGBA".index(c[-1]) if c[-1] in "RGBA" else 9)
        out[part.name()] = np.stack([part.channels[c].pixels for c in names], -1).astype(np.float32)
    return out


# --- access --------------------------------------------------------------------------------


def test_every_request_needs_the_token(server):
    assert server.request("/api/session", token=None)[0] == 403
    assert server.request("/", token=None)[0] == 403
    assert server.request("/api/session", headers={"X-Pxr-Token": "x" * 32}, token=None)[0] == 403
    assert server.request("/?token=wrong", token=None)[0] == 403
    status, page, _ = server.request("/", token="query")
    assert status == 200 and server.token.encode() in page  # the page's assets carry it


def test_changes_take_the_header_token_only(server):
    """A form on another site can put the token in a URL it learnt, not in a header."""
    status, _, _ = server.request("/api/check", {"expression": "C.*"}, token="query")
    assert status == 403


def test_another_host_name_is_refused(server):
    """DNS rebinding: a page of evil.example resolved to 127.0.0.1 sends its own Host."""
    assert server.request("/api/session", headers={"Host": "evil.example"})[0] == 403


@pytest.mark.parametrize("path", [
    "/files/../cornell.pxlidx", "/files/%2e%2e/%2e%2e/etc/passwd", "/files//etc/passwd", "/files/%2Fetc%2Fpasswd",
    "/files/..%2F..%2Fetc%2Fpasswd", "/static/../session.py", "/static/%2e%2e%2fsession.py", "/etc/passwd",
    "/files/outside/secret.txt",
])
def test_nothing_outside_the_folder_is_served(server, folder, path):
    (folder.parent / "secret.txt").write_text("not yours")
    (folder / "outside").mkdir(exist_ok=True)
    if not (folder / "outside" / "secret.txt").exists():
        (folder / "outside" / "secret.txt").symlink_to(folder.parent / "secret.txt")
    status, body, _ = server.request(path)
    assert status in (403, 404), (path, status)
    assert b"not yours" not in body and b"root:" not in body


def test_the_folder_s_files_are_served(server, folder):
    status, body, _ = server.request("/files/light_passes.rgba.png")
    assert status == 200 and body == (folder / "light_passes.rgba.png").read_bytes()


# --- what the page reads ----------------------------------------------------------------------


def test_the_session_lists_the_products_layers(server, folder):
    session = server.json("/api/session")
    exr = parts(folder / "light_passes.exr")
    names = [layer["name"] for layer in session["layers"]]
    assert names[0] == "beauty" and names[1:] == [name for name in exr if name != "rgba"]
    assert (session["width"], session["height"]) == exr["rgba"].shape[1::-1]
    assert session["partition"] is True  # the light passes sum to the beauty
    assert session["index"]["file"] == "cornell.pxlidx" and "ceilingLight" in session["index"]["lights"]
    luminance = np.asarray(REC709_LUMINANCE)
    total = (exr["rgba"][..., :3].astype(np.float64) @ luminance).sum()
    for layer in session["layers"][1:]:
        expected = (exr[layer["name"]].astype(np.float64) @ luminance).sum() / total
        assert layer["share"] == pytest.approx(expected, rel=1e-9)


def test_images_are_the_exr_s_pixels(server, folder):
    exr = parts(folder / "light_passes.exr")
    for layer, part in (("beauty", "rgba"), ("diffuse_direct", "diffuse_direct")):
        status, body, headers = server.request(f"/api/image/{layer}")
        assert status == 200 and (int(headers["X-Width"]), int(headers["X-Height"])) == exr[part].shape[1::-1]
        pixels = np.frombuffer(body, "<f4").reshape(exr[part].shape[0], exr[part].shape[1], 3)
        np.testing.assert_array_equal(pixels, exr[part][..., :3])
    assert server.request("/api/image/nope")[0] == 404


def test_the_lut_is_as_described(server):
    lut = server.json("/api/session")["display"]["lut"]
    status, body, _ = server.request("/api/lut")
    assert status == 200 and len(body) == lut["size"] ** 3 * 3 * 4
    assert "displayLut" in lut["glsl"]


# --- inspect ------------------------------------------------------------------------------------


def red_wall_pixel(index: PathIndex) -> tuple[int, int, float]:
    """(x, y, share) of the pixel where the red wall's direct light is largest, and that
    class's share of the pixel's luminance: straight from the index's records."""
    width = index.manifest["resolution"][0]
    target = next(c.id for c in index.classes if path_text(c.events) == RED_WALL_DIRECT)
    luminance = np.asarray(REC709_LUMINANCE)
    pixel_total = np.zeros(width * index.manifest["resolution"][1])
    pixel_class = np.zeros_like(pixel_total)
    for chunk in index.records(norms=False):
        energy = chunk.rgb.astype(np.float64) @ luminance
        np.add.at(pixel_total, chunk.pixel, energy)
        np.add.at(pixel_class, chunk.pixel, np.where(chunk.class_id == target, energy, 0.0))
    pixel = int(np.argmax(pixel_class))
    return pixel % width, pixel // width, pixel_class[pixel] / pixel_total[pixel]


def test_a_click_on_the_red_wall_lists_its_direct_light(server, folder):
    x, y, share = red_wall_pixel(PathIndex(folder / "cornell.pxlidx"))
    result = server.json(f"/api/inspect?x0={x}&y0={y}&x1={x + 1}&y1={y + 1}")
    listed = {entry["path"]: entry for entry in result["classes"][:5]}
    assert RED_WALL_DIRECT in listed
    entry = listed[RED_WALL_DIRECT]
    assert entry["share"] == pytest.approx(share, rel=1e-9)
    assert entry["lpe"] == "C<RD'redWall'><L.'ceilingLight'>"
    assert (entry["light"], entry["first_object"]) == ("ceilingLight", "redWall")
    assert sum(c["share"] for c in result["classes"]) <= 1 + 1e-9
    assert result["groups"]["light"][0]["key"] == "ceilingLight"
    assert result["pixels"] == 1 and len(result["norms"]["bounces"]) >= 1


def test_a_region_sums_its_pixels(server, folder):
    """The region's mean rgb is the mean of the beauty over it (the index holds all of it)."""
    result = server.json("/api/inspect?x0=8&y0=8&x1=24&y1=20")
    beauty = parts(folder / "light_passes.exr")["rgba"][8:20, 8:24, :3].astype(np.float64)
    np.testing.assert_allclose(result["rgb"], beauty.mean(axis=(0, 1)), rtol=1e-4)
    assert result["pixels"] == 16 * 12


def test_bad_selections_are_refused(server):
    assert server.request("/api/inspect?x0=3&y0=3&x1=3&y1=9")[0] == 400
    assert server.request("/api/inspect?x0=a")[0] == 400


# --- layers and saving ---------------------------------------------------------------------------


def test_a_new_layer_is_what_extract_cuts(server, folder, tmp_path):
    expression = "C<RD'redWall'>.*<L.'ceilingLight'>"
    made = server.json("/api/layer", {"name": "red_wall", "expression": expression})
    assert made["id"] == "red_wall" and 0 < made["share"] < 1
    status, body, _ = server.request("/api/image/red_wall")
    out = tmp_path / "cut.exr"
    subprocess.run([*CLI, "extract", str(folder / "cornell.pxlidx"), "--layer", f"red_wall={expression}",
                    "-o", str(out), "--no-previews", "-q"], check=True)
    expected = parts(out)["red_wall"]
    np.testing.assert_array_equal(np.frombuffer(body, "<f4").reshape(expected.shape), expected)
    assert server.request("/api/layer", {"name": "red_wall", "expression": "C.*"})[0] == 409
    assert server.request("/api/layer", {"name": "9lives", "expression": "C.*"})[0] == 400


def test_a_bad_expression_says_where(server):
    with pytest.raises(LpeSyntaxError) as expected:
        lpe.compile("C<RD.*")
    status, body, _ = server.request("/api/layer", {"name": "broken", "expression": "C<RD.*"})
    answer = json.loads(body)
    assert status == 400 and answer == {"error": expected.value.message, "position": expected.value.position}
    checked = server.json("/api/check", {"expression": "C<RD.*"})
    assert checked == {"ok": False, "error": expected.value.message, "position": expected.value.position}
    assert server.json("/api/check", {"expression": "C<RD>.*"}) == {"ok": True, "unknown_labels": []}


def test_labels_that_name_nothing_come_with_their_position_and_the_nearest_names(server):
    expression = "C<RD'flor'>.*<L.'ceilingLite'>"
    checked = server.json("/api/check", {"expression": expression})
    assert checked["ok"] is True
    unknown = {entry["label"]: entry for entry in checked["unknown_labels"]}
    assert unknown["flor"]["position"] == expression.index("'flor'") and unknown["flor"]["nearest"][0] == "floor"
    assert unknown["ceilingLite"]["position"] == expression.index("'ceilingLite'")
    assert unknown["ceilingLite"]["nearest"][0] == "ceilingLight"
    assert "names no" in unknown["flor"]["message"]
    made = server.json("/api/layer", {"name": "typo", "expression": expression})
    assert made["unknown_labels"] == checked["unknown_labels"] and len(made["warnings"]) == 2


def test_overlaps_of_the_stack(server, folder):
    server.json("/api/layer", {"name": "all_diffuse", "expression": "C<RD>.*"})
    stack = [{"id": "beauty"}, {"id": "all_diffuse"}, {"id": "diffuse_direct"},
             {"id": "mine", "expression": "C.*'redWall'.*"}, {"id": "product_only", "expression": None}]
    found = server.json("/api/overlaps", {"layers": stack})
    pairs = {(pair["a"], pair["b"]): pair["share"] for pair in found["pairs"]}
    assert set(found) >= {"pairs", "double_counted", "remainder", "seconds", "unknown"}
    assert found["unknown"] == ["product_only"] and ("all_diffuse", "diffuse_direct") in pairs
    index = PathIndex(folder / "cornell.pxlidx")
    from pxr_layers.layers.multipart import read_multipart
    from pxr_layers.layers.overlaps import overlaps

    expected = overlaps(index, {"all_diffuse": "C<RD>.*", "diffuse_direct": "C<RD>[LOB]", "mine": "C.*'redWall'.*"},
                        read_multipart(folder / "light_passes.exr").beauty)
    assert pairs == pytest.approx(expected.pairs) and found["double_counted"] == pytest.approx(expected.double_counted)
    assert found["remainder"] == pytest.approx(expected.remainder) and found["remainder"] > 0
    status, body, _ = server.request("/api/overlaps", {"layers": [{"id": "x", "expression": "C<RD"}]})
    assert status == 400 and json.loads(body)["position"] == 4
    assert server.request("/api/overlaps", {"layers": "all"})[0] == 400


def test_a_remainder_layer_is_saved_and_extracted_again(server, folder, tmp_path):
    stack = ["C<RD>.*", "C.*'redWall'.*"]
    server.json("/api/layer", {"name": "diffuse_all", "expression": stack[0]})
    server.json("/api/layer", {"name": "red_only", "expression": lpe.exclusive(stack[1], stack[:1])})
    server.json("/api/layer", {"name": "the_rest", "expression": lpe.remainder(stack)})
    layers = [{"id": name} for name in ("diffuse_all", "red_only", "the_rest")]
    found = server.json("/api/overlaps", {"layers": layers})
    assert found["pairs"] == [] and found["double_counted"] == 0 and found["remainder"] == 0
    server.json("/api/save", {"name": "exclusive_look", "layers": layers})
    saved = parts(folder / "exclusive_look.exr")
    out = tmp_path / "again"
    subprocess.run([*CLI, "extract", str(folder / "cornell.pxlidx"), "--recipe", str(folder / "exclusive_look.usda"),
                    "-o", str(out), "--no-previews", "-q"], check=True)
    again = parts(out / "exclusive_look.exr")
    for name in ("diffuse_all", "red_only", "the_rest"):
        np.testing.assert_array_equal(again[name], saved[name])
    total = sum(saved[name][..., :3].astype(np.float64) for name in ("diffuse_all", "red_only", "the_rest"))
    beauty = saved["rgba"][..., :3].astype(np.float64)
    assert np.abs(total - beauty).max() <= 1e-5 * beauty.max()


def test_generalise_keeps_what_is_asked(server, folder):
    index = PathIndex(folder / "cornell.pxlidx")
    ids = [c.id for c in index.classes if path_text(c.events).startswith("C RD'redWall'")][:5]
    lpe = server.json("/api/generalise", {"classes": ids, "keep": ["light", "first_object"]})["lpe"]
    assert lpe == "C<..'redWall'>.*<L.'ceilingLight'>"
    assert server.request("/api/generalise", {"classes": ids, "keep": ["colour"]})[0] == 400


def test_save_writes_a_recipe_extract_accepts_and_a_nuke_script(server, folder, tmp_path):
    server.json("/api/layer", {"name": "key_diffuse", "expression": "C<RD>.*<L.'ceilingLight'>"})
    stack = [{"id": "key_diffuse", "stops": 1.0, "tint": [1.0, 0.9, 0.8]},
             {"id": "glossy_direct", "stops": 0.0, "mute": True}]
    written = server.json("/api/save", {"name": "look", "layers": stack})
    assert written == {"recipe": "look.usda", "exr": "look.exr", "nuke": "look.nk"}
    saved = parts(folder / "look.exr")
    assert list(saved) == ["rgba", "key_diffuse", "glossy_direct"]
    out = tmp_path / "again"
    subprocess.run([*CLI, "extract", str(folder / "cornell.pxlidx"), "--recipe", str(folder / "look.usda"),
                    "-o", str(out), "--no-previews", "-q"], check=True)
    again = parts(out / "look.exr")
    for name in saved:
        np.testing.assert_array_equal(again[name], saved[name])
    assert "Read {" in (folder / "look.nk").read_text()
    assert server.request("/api/save", {"name": "look", "layers": stack})[0] == 409
    assert server.request("/api/save", {"name": "../look", "layers": stack})[0] == 400


def test_a_folder_without_an_index_is_viewed_but_not_inspected(folder, tmp_path):
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(folder / "light_passes.exr", bare)
    running = Server(bare)
    try:
        assert running.json("/api/session")["index"] is None
        status, body, _ = running.request("/api/inspect?x0=0&y0=0&x1=1&y1=1")
        assert status == 409 and b"no path index" in body
    finally:
        running.stop()


def test_bad_paths_get_one_line(tmp_path):
    for path, message in ((tmp_path / "missing", "no such file"), (tmp_path, "neither a path index")):
        result = subprocess.run([*CLI, "view", str(path), "--no-browser"], capture_output=True, text=True,
                                timeout=60)
        assert result.returncode == 1 and message in result.stderr and "Traceback" not in result.stderr
        assert len(result.stderr.strip().splitlines()) == 1


def test_suggested_layers_partition_the_beauty(server, folder):
    suggested = server.json("/api/suggest", {"k": 4})
    names = [layer["id"] for layer in suggested["layers"]]
    assert 1 <= len(names) <= 4 and suggested["strategy"] in ("beam", "greedy")
    shape = parts(folder / "light_passes.exr")["rgba"].shape[:2] + (3,)
    total = sum(np.frombuffer(server.request(f"/api/image/{name}")[1], "<f4").reshape(shape).astype(np.float64)
                for name in names)
    beauty = np.frombuffer(server.request("/api/image/beauty")[1], "<f4").reshape(shape)
    np.testing.assert_allclose(total, beauty, rtol=1e-5, atol=1e-6 * beauty.max())
    again = [layer["id"] for layer in server.json("/api/suggest", {"k": 4})["layers"]]
    assert not set(again) & set(names) and not set(again) & {"emission", "beauty"}  # numbered, not clashing
    assert server.request("/api/suggest", {"k": 0})[0] == 400


def test_suggest_chooses_k_explains_and_skips_the_stack(server):
    """k left out: the elbow; each layer explained; `exclude` (the stack's expressions)
    keeps a suggestion that cuts the same paths from being added again."""
    first = server.json("/api/suggest", {})
    names = [layer["id"] for layer in first["layers"]]
    assert first["chosen_k"] == "elbow" and set(first["explanations"]) == set(names)
    assert all(text.strip() for text in first["explanations"].values())
    stack = [layer["expression"] for layer in first["layers"]]
    again = server.json("/api/suggest", {"exclude": stack})
    assert again["layers"] == [] and set(again["already"].values()) <= set(stack) and again["already"]
    assert server.request("/api/suggest", {"exclude": "C.*"})[0] == 400
    assert server.request("/api/suggest", {"exclude": ["C<RD"]})[0] == 400


@pytest.mark.parametrize("path, body", [
    ("/api/generalise", {}), ("/api/generalise", {"classes": None}), ("/api/generalise", {"classes": [0], "keep": [{}]}),
    ("/api/generalise", {"classes": [True]}), ("/api/layer", {"name": "x", "expression": None}),
    ("/api/save", {"name": "look2", "layers": [{"id": "beauty"}], "exposure": "bright"}),
    ("/api/save", {"name": "look2", "layers": "all"}), ("/api/suggest", {"k": "six"}),
    ("/api/overlaps", {}), ("/api/overlaps", {"layers": [{"id": 3}]}),
    ("/api/overlaps", {"layers": [{"id": "x", "expression": 7}]}),
])
def test_wrong_types_get_one_line_not_an_internal_error(server, path, body):
    status, answer, _ = server.request(path, body)
    assert status == 400 and set(json.loads(answer)) <= {"error", "position"}, (path, body, answer)


def test_check_answers_a_non_string(server):
    assert server.json("/api/check", {"expression": None})["ok"] is False


def test_a_beauty_exr_finds_the_index_of_its_render(tmp_path, shipped_scene):
    """A render without a recipe writes its beauty alone: viewing that .exr opens its index."""
    from pxr_layers.view.session import Session

    subprocess.run([*CLI, "render", str(shipped_scene("cornell.usda")), "--resolution", "24", "24", "--spp", "2",
                    "-o", str(tmp_path), "-q", "--no-previews"], check=True)
    (beauty,) = tmp_path.glob("*.exr")
    session = Session.open(beauty)
    assert session.index is not None and session.index.path.suffix == ".pxlidx"
    assert list(session.layers) == ["beauty"]
