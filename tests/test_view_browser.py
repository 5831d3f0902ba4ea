"""The layer inspector (`pxr-layers view`) in a real browser: the OS's headless Chromium,
driven by Playwright, on the page the real server serves for a small demo render.

The page is read through its test hook `window.pxrViewer` (pxr_layers/view/static/app.js):
`readImage()` gives the canvas's pixels at 1:1 with gl.readPixels (a screenshot would be
scaled and colour-managed), `imageToClient(x, y)` where to click an image pixel,
`layerData(id)` a stack entry's float32 pixels as the page uploaded them.

Skipped without /usr/bin/chromium or Playwright, unless PXR_LAYERS_REQUIRE_BROWSER is set
(CI sets it), where their absence fails.
"""

from __future__ import annotations

import base64
import contextlib
import http.client
import os
import queue
import subprocess
import threading
import urllib.parse
from dataclasses import replace
from pathlib import Path
from typing import Iterator

import numpy as np
import OpenImageIO as oiio
import pytest
from test_cli import RENDER_DIR, SCRIPT

from pxr_layers.layers.nuke import LayerGrade
from pxr_layers.layers.previews import to_display
from pxr_layers.paths.events import path_text
from pxr_layers.paths.reader import PathIndex
from pxr_layers.scene import REC709_LUMINANCE
from pxr_layers.view.composite import composite

CHROMIUM = Path("/usr/bin/chromium")
REQUIRE_BROWSER = "PXR_LAYERS_REQUIRE_BROWSER"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
VIEWPORT = {"width": 1280, "height": 800}
RESOLUTION = 128
CORNELL = RENDER_DIR / "cornell.usda"
RED_DIRECT = "C RD'redWall' L'ceilingLight'"
TOP_CLASSES = 5
"""How far down the inspect list the red wall's direct light may be at a red wall pixel."""
SERVER_START_SECONDS = 60
PAGE_READY_MS = 30_000


def _sync_playwright():
    """Playwright's entry point; skips (fails under PXR_LAYERS_REQUIRE_BROWSER) without it or Chromium."""
    missing = [] if CHROMIUM.exists() else [f"{CHROMIUM} (apt install chromium)"]
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        sync_playwright = None
        missing.append("Playwright for Python (pip install playwright; no `playwright install`)")
    if missing:
        message = f"no browser to test the inspector in: {', '.join(missing)} missing"
        if os.environ.get(REQUIRE_BROWSER):
            pytest.fail(f"{message} and {REQUIRE_BROWSER} is set")
        pytest.skip(message)
    return sync_playwright


def launch(playwright, profile: Path, viewport: dict = VIEWPORT):
    """Chromium as the tests run it: headless, software WebGL, a new empty profile."""
    return playwright.chromium.launch_persistent_context(
        str(profile), executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True, viewport=viewport)


@contextlib.contextmanager
def serving(path: Path) -> Iterator[str]:
    """`pxr-layers view PATH` on a free port, for the block: its URL (with the token), the
    first line it prints."""
    process = subprocess.Popen([SCRIPT, "view", str(path), "--no-browser", "--port", "0"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first_line: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: first_line.put(process.stdout.readline()), daemon=True).start()
    try:
        try:
            url = first_line.get(timeout=SERVER_START_SECONDS).strip()
        except queue.Empty:
            url = ""
        if not url.startswith("http://127.0.0.1:"):
            process.kill()
            stderr = process.communicate()[1]
            raise RuntimeError(f"`pxr-layers view` printed {url!r} first, not its URL: {stderr[-2000:]}")
        yield url
    finally:
        if process.poll() is None:
            process.terminate()
            process.wait(timeout=10)


def open_inspector(context, url: str):
    """A new tab on the inspector at `url`, once its first frame is drawn."""
    tab = context.new_page()
    tab.goto(url)
    tab.wait_for_function("window.pxrViewer && (pxrViewer.ready || pxrViewer.error !== null)", timeout=PAGE_READY_MS)
    error = tab.evaluate("pxrViewer.error")
    if error is not None:
        raise RuntimeError(f"the inspector did not start: {error}")
    return tab


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    sync_playwright = _sync_playwright()
    with sync_playwright() as playwright:
        context = launch(playwright, tmp_path_factory.mktemp("chromium-profile"))
        yield context
        context.close()


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    """A 128×128, 16 spp render of the Cornell box into light passes: light_passes.exr,
    cornell.pxlidx, the previews."""
    folder = tmp_path_factory.mktemp("view-demo")
    result = subprocess.run([SCRIPT, "render", str(CORNELL), "--recipe", "light_passes", "-o", str(folder),
                             "--resolution", str(RESOLUTION), str(RESOLUTION), "--spp", "16", "--quiet"],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    return folder


@pytest.fixture(scope="module")
def server(demo):
    """The real server on `demo`: its URL (with the token)."""
    with serving(demo) as url:
        yield url


@pytest.fixture
def page(browser, server):
    """A new tab on the inspector, loaded, every grade at unity."""
    errors: list[str] = []

    def uncaught(error):
        errors.append(str(error.error))

    browser.on("weberror", uncaught)  # from the first script on, which a tab's own listener would miss
    tab = open_inspector(browser, server)
    tab.keyboard.press("r")
    yield tab
    tab.close()
    browser.remove_listener("weberror", uncaught)
    assert not errors, errors


def canvas_image(page) -> np.ndarray:
    """(h, w, 3) uint8: the canvas at 1:1, as drawn."""
    page.click("#one-to-one")  # not the key 1: focus may be in a field
    shown = page.evaluate("pxrViewer.readImage()")
    rgba = np.frombuffer(base64.b64decode(shown["rgba"]), np.uint8)
    return rgba.reshape(shown["height"], shown["width"], 4)[..., :3]


def layer_pixels(page, layer_id: str) -> np.ndarray:
    """(h, w, 3) float32: a stack entry's pixels as the page uploaded them."""
    data = np.frombuffer(base64.b64decode(page.evaluate("id => pxrViewer.layerData(id)", layer_id)), "<f4")
    return data.reshape(RESOLUTION, RESOLUTION, 3)


def read_png(path: Path) -> np.ndarray:
    image = oiio.ImageInput.open(str(path))
    try:
        return image.read_image(format="uint8")[..., :3]
    finally:
        image.close()


def read_part(path: Path, name: str) -> np.ndarray | None:
    """(h, w, 3) float32 R, G, B of the part `name` of a multipart EXR, or None."""
    image = oiio.ImageInput.open(str(path))
    try:
        subimage = 0
        while image.seek_subimage(subimage, 0):
            spec = image.spec()
            if spec.getattribute("name") == name:
                pixels = image.read_image(format="float")
                columns = [spec.channelnames.index(f"{name}.{c}") for c in "RGB"]
                return pixels[..., columns]
            subimage += 1
        return None
    finally:
        image.close()


def brightest_pixel(index_path: Path, path: str) -> tuple[int, int, int, float]:
    """(x, y, class id, share): the pixel where the class of `path` (path notation) brings the
    most energy, and its share of that pixel's energy (Rec.709 luminance), from the records."""
    index = PathIndex(index_path)
    width, height = index.manifest["resolution"]
    target = next(c.id for c in index.classes if path_text(c.events) == path)
    luminance = np.asarray(REC709_LUMINANCE, np.float64)
    pixel_energy = np.zeros(width * height)
    class_energy = np.zeros(width * height)
    for chunk in index.records(norms=False):
        energy = chunk.rgb.astype(np.float64) @ luminance
        np.add.at(pixel_energy, chunk.pixel, energy)
        mine = chunk.class_id == target
        np.add.at(class_energy, chunk.pixel[mine], energy[mine])
    pixel = int(np.argmax(class_energy))
    y, x = divmod(pixel, width)
    return x, y, target, class_energy[pixel] / pixel_energy[pixel]


@pytest.fixture(scope="module")
def red_wall(demo) -> tuple[int, int, int, float]:
    """Where the red wall's direct light is brightest, its class and share there."""
    return brightest_pixel(demo / "cornell.pxlidx", RED_DIRECT)


def click_pixel(page, x: int, y: int) -> None:
    page.click("#fit")
    page.mouse.click(*page.evaluate("([x, y]) => pxrViewer.imageToClient(x, y)", [x, y]))
    page.wait_for_function(
        "([x, y]) => { const s = pxrViewer.state().selection; return s && s.x0 === x && s.y0 === y; }", arg=[x, y])
    page.wait_for_selector("#tab-body tr[data-path]")


def test_beauty_at_one_to_one_is_the_preview(page, demo):
    """Unit gains through the display LUT: the preview PNG within 1/255 per channel."""
    shown = canvas_image(page).astype(int)
    preview = read_png(demo / "light_passes.rgba.png").astype(int)
    assert shown.shape == preview.shape == (RESOLUTION, RESOLUTION, 3)
    assert np.abs(shown - preview).max() <= 1


def test_click_on_the_red_wall_lists_its_direct_light_with_the_index_share(page, red_wall):
    x, y, _, share = red_wall
    click_pixel(page, x, y)
    rows = page.eval_on_selector_all(
        "#tab-body tr[data-path]", "rows => rows.map(r => [r.dataset.path, Number(r.dataset.share)])")
    paths = [path for path, _ in rows]
    assert RED_DIRECT in paths[:TOP_CLASSES], paths[:TOP_CLASSES]
    assert dict(rows)[RED_DIRECT] == pytest.approx(share, rel=1e-9)
    shown = page.text_content(f'#tab-body tr[data-path="{RED_DIRECT}"] .percent')
    assert shown == f"{share * 100:.1f} %"


def test_a_layer_made_from_the_click_and_saved_extracts_to_the_same_pixels(page, demo, red_wall, tmp_path):
    x, y, class_id, _ = red_wall
    click_pixel(page, x, y)
    page.check(f'#tab-body input[data-class="{class_id}"]')
    for box in page.query_selector_all("#keep input[type=checkbox]"):
        box.uncheck()  # keep nothing: exactly the ticked class
    page.click("#generalise")
    page.wait_for_function("document.querySelector('#expression').value !== ''")
    page.fill("#layer-name", "red_direct")
    page.click("#add-layer")
    page.wait_for_selector('#stack li[data-id="red_direct"]')
    page.wait_for_function("pxrViewer.timings.layer && pxrViewer.timings.layer.name === 'red_direct'")
    made = layer_pixels(page, "red_direct")
    assert made.max() > 0

    page.fill("#save-name", "red_look")
    page.click("#save")
    page.wait_for_selector("#saved li[data-kind]")
    written = page.eval_on_selector_all("#saved li[data-kind]", "items => items.map(i => i.textContent)")
    assert "red_look.usda" in written, written
    assert (demo / "red_look.usda").is_file()

    out = tmp_path / "extracted"
    result = subprocess.run([SCRIPT, "extract", str(demo / "cornell.pxlidx"), "--recipe", str(demo / "red_look.usda"),
                             "-o", str(out), "--no-previews", "--quiet"], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    parts = [part for exr in sorted(out.glob("*.exr")) if (part := read_part(exr, "red_direct")) is not None]
    assert len(parts) == 1, sorted(out.iterdir())
    np.testing.assert_array_equal(parts[0], made)  # the demo's products are float: bit for bit


def test_the_query_builder_writes_the_expression_and_the_server_checks_it(page):
    page.click("#builder-box summary")
    page.click("#add-bounce")
    bounce = '#builder .bounce[data-bounce="1"]'
    page.select_option(f"{bounce} select[title='event type']", "R")
    page.select_option(f"{bounce} select[title='scattering']", "D")
    page.fill(f"{bounce} input.label-input", "redWall")
    page.fill(f'{bounce} input[data-quantity="C"][data-bound="max"]', "0")
    page.fill(f'{bounce} input[data-quantity="T"][data-bound="min"]', "0.5")
    page.fill("#end-label", "ceilingLight")
    expected = "C<RD'redWall'>@(|S_C| = 0 and |S_T| >= 0.5).*<L.'ceilingLight'>"
    assert page.input_value("#expression") == expected
    page.wait_for_function("document.querySelector('#expression-error').textContent === 'valid expression'")

    unclosed = "C<RD'redWall'>.*<L.'ceilingLight'"
    page.fill("#expression", unclosed)
    page.wait_for_function("document.querySelector('#expression-error').textContent.includes('^')")
    text, caret, message = page.text_content("#expression-error").split("\n", 2)
    reply = page.evaluate("""expression => fetch('/api/check', {method: 'POST', body: JSON.stringify({expression}),
        headers: {'X-Pxr-Token': new URLSearchParams(location.search).get('token')}}).then(r => r.json())""", unclosed)
    assert not reply["ok"] and (text, message) == (unclosed, reply["error"])
    assert caret == " " * reply["position"] + "^"



def test_keys_and_the_wheel_move_the_view_and_reset_the_grades(page):
    page.keyboard.press("1")
    assert page.evaluate("pxrViewer.state().view.scale") == 1
    page.keyboard.press("f")
    view = page.evaluate("pxrViewer.state().view")
    assert view["fit"] and view["scale"] == int(view["scale"]) > 1  # the whole image, in whole pixels
    under = page.evaluate("pxrViewer.imageToClient(20, 30)")
    page.mouse.move(*under)
    page.mouse.wheel(0, -300)  # zooms in twice, around the cursor
    page.wait_for_function("scale => pxrViewer.state().view.scale === 2 * scale", arg=view["scale"])
    assert page.evaluate("pxrViewer.imageToClient(20, 30)") == pytest.approx(under, abs=view["scale"])
    page.evaluate("pxrViewer.setGrade('diffuse_direct', { stops: 2, solo: true })")
    page.keyboard.press("r")
    assert page.evaluate("pxrViewer.state().layers.find(l => l.id === 'diffuse_direct')") | {"share": None} == {
        "id": "diffuse_direct", "source": "diffuse_direct", "name": "diffuse_direct", "kind": "layer", "share": None,
        "group": "", "stops": 0, "tint": [1, 1, 1], "kelvin": None, "mute": False, "solo": False, "mask": None}


REGRADE = {"diffuse_direct": LayerGrade(stops=1.5, tint=(1.0, 0.5, 0.25)), "diffuse_indirect": LayerGrade(stops=-2.0),
           "emission": LayerGrade(mute=True)}
"""A grade of the demo's passes: a gain and a tint, a cut, a mute."""


@pytest.mark.parametrize("soloed", [(), ("diffuse_direct", "emission")])
def test_a_regrade_is_the_numpy_composite_through_the_display(page, soloed):
    """The canvas against view/composite.py's rule and the previews' OCIO processor, within
    1/255 (a muted layer stays out of the solo)."""
    grades = {name: replace(grade, solo=name in soloed) for name, grade in REGRADE.items()}
    for name, grade in grades.items():
        page.evaluate("([id, grade]) => pxrViewer.setGrade(id, grade)",
                      [name, {"stops": grade.stops, "tint": list(grade.tint), "mute": grade.mute, "solo": grade.solo}])
    page.fill("#exposure-number", "0.5")
    shown = canvas_image(page).astype(int)
    stack = [layer["id"] for layer in page.evaluate("pxrViewer.state().layers")]
    layers = stack[1:]
    expected = to_display(composite(layer_pixels(page, stack[0]), [layer_pixels(page, name) for name in layers],
                                    [grades.get(name, LayerGrade()) for name in layers], exposure=0.5))
    assert np.abs(shown - expected).max() <= 1


def test_gain_to_zero_and_back_restores_the_picture_exactly(page):
    before = canvas_image(page)
    row = '#stack li[data-id="diffuse_direct"]'
    page.click(f"{row} button.mute")  # gain 0
    muted = canvas_image(page)
    page.click(f"{row} button.mute")
    assert np.abs(muted.astype(int) - before).max() > 8
    np.testing.assert_array_equal(canvas_image(page), before)

    page.fill(f"{row} input.stops", "-3")
    darker = canvas_image(page)
    page.fill(f"{row} input.stops", "0")
    assert np.abs(darker.astype(int) - before).max() > 8
    np.testing.assert_array_equal(canvas_image(page), before)


@pytest.mark.parametrize("target", [
    "/static/../../pyproject.toml", "/static/%2e%2e/%2e%2e/pyproject.toml", "/static/%2e%2e/",
    "/static/..%2f..%2fpyproject.toml", "/static//etc/passwd", "/etc/passwd", "//etc/passwd", "/../../../../etc/passwd",
    "/api/image/..%2f..%2f..%2fetc%2fpasswd", "/static/%2fetc%2fpasswd", "/cornell.pxlidx/../../../etc/passwd",
    "/files/../pyproject.toml", "/files/%2e%2e/%2e%2e/pyproject.toml", "/files//etc/passwd", "/files/%2fetc%2fpasswd",
])
def test_paths_outside_the_served_files_are_refused(server, target):
    """Sent byte for byte (http.client does not normalise), with the right token."""
    address = urllib.parse.urlsplit(server)
    token = urllib.parse.parse_qs(address.query)["token"][0]
    connection = http.client.HTTPConnection(address.hostname, address.port, timeout=10)
    try:
        connection.request("GET", target, headers={"X-Pxr-Token": token})
        response = connection.getresponse()
        body = response.read()
    finally:
        connection.close()
    assert 400 <= response.status < 500, (response.status, body[:200])
    assert b"root:" not in body and b"[project]" not in body


def test_the_token_is_required(server):
    address = urllib.parse.urlsplit(server)
    connection = http.client.HTTPConnection(address.hostname, address.port, timeout=10)
    try:
        for target in ("/", "/static/app.js", "/api/session"):
            connection.request("GET", target)
            response = connection.getresponse()
            response.read()
            assert response.status == 403, target
    finally:
        connection.close()


def test_suggest_layers_fills_the_stack_with_a_partition(page):
    """The "suggest layers" action: K layers that add up to the beauty join the stack at unit
    gain, so the picture does not change; muting one of them does."""
    before = canvas_image(page)
    count = len(page.evaluate("pxrViewer.state().layers"))
    page.fill("#suggest-k", "3")
    page.click("#suggest")
    page.wait_for_function("pxrViewer.timings.suggest !== undefined", timeout=60_000)
    added = page.evaluate("pxrViewer.timings.suggest.layers")
    assert 1 <= len(added) <= 3 and len(page.evaluate("pxrViewer.state().layers")) == count + len(added)
    np.testing.assert_array_equal(canvas_image(page), before)
    total = sum(layer_pixels(page, layer_id).astype(np.float64) for layer_id in added)
    beauty = layer_pixels(page, "beauty").astype(np.float64)
    np.testing.assert_allclose(total, beauty, rtol=1e-5, atol=1e-6 * beauty.max())
    page.click(f'#stack li[data-id="{added[0]}"] button.mute')
    assert np.abs(canvas_image(page).astype(int) - before).max() > 0


@pytest.fixture(scope="module")
def denoised_render(tmp_path_factory) -> Path:
    """The Cornell passes rendered with --denoise: light_passes.exr and its denoised twin."""
    folder = tmp_path_factory.mktemp("view-denoised")
    result = subprocess.run([SCRIPT, "render", str(CORNELL), "--recipe", "light_passes", "-o", str(folder),
                             "--resolution", str(RESOLUTION), str(RESOLUTION), "--spp", "4", "--denoise", "--quiet"],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    return folder


def test_the_denoised_toggle_shows_the_twins_stack_and_keeps_the_grades(browser, denoised_render):
    """The button (and the key d) swaps every image for the denoised twin's, and back; the
    grades stay and apply to either; the composite is the numpy rule on the twin's pixels."""
    with serving(denoised_render) as url:
        page = open_inspector(browser, url)
        try:
            button = page.locator("#denoised")
            assert button.is_visible() and button.get_attribute("aria-pressed") == "false"
            raw = read_part(denoised_render / "light_passes.exr", "diffuse_indirect")
            twin = read_part(denoised_render / "light_passes.denoised.exr", "diffuse_indirect")
            np.testing.assert_array_equal(layer_pixels(page, "diffuse_indirect"), raw)
            page.evaluate("([id, grade]) => pxrViewer.setGrade(id, grade)",
                          ["diffuse_indirect", {"stops": 1.5, "tint": [1, 0.5, 0.25], "mute": False, "solo": False}])
            button.click()
            page.wait_for_function("pxrViewer.state().denoised && !document.querySelector('#denoised').disabled")
            assert button.get_attribute("aria-pressed") == "true"
            np.testing.assert_array_equal(layer_pixels(page, "diffuse_indirect"), twin)
            stack = page.evaluate("pxrViewer.state().layers")
            assert next(layer for layer in stack if layer["id"] == "diffuse_indirect")["stops"] == 1.5
            ids = [layer["id"] for layer in stack]
            grades = [LayerGrade(stops=layer["stops"], tint=tuple(layer["tint"])) for layer in stack[1:]]
            expected = to_display(composite(layer_pixels(page, ids[0]), [layer_pixels(page, i) for i in ids[1:]],
                                            grades))
            assert np.abs(canvas_image(page).astype(int) - expected).max() <= 1
            page.locator("body").press("d")
            page.wait_for_function("!pxrViewer.state().denoised && !document.querySelector('#denoised').disabled")
            np.testing.assert_array_equal(layer_pixels(page, "diffuse_indirect"), raw)
        finally:
            page.close()
