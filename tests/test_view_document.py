"""The inspector as a document, in a real browser (headless Chromium through Playwright, as
tests/test_view_browser.py runs it): the stack managed (duplicate, rename, reorder, group,
delete) with undo and redo; the working state kept beside the render and restored on reload
and on reopening a saved look; comparing looks (wipe, side by side, snapshots); the keyboard
alone; and an axe-core accessibility audit.

Each test gets its own render folder (the working state is kept in it), so they do not see
each other's edits.
"""

from __future__ import annotations

import base64
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from test_view_browser import (
    CORNELL,
    RED_DIRECT,
    RESOLUTION,
    SCRIPT,
    brightest_pixel,
    browser,  # noqa: F401  (the fixture: one headless Chromium for the module)
    canvas_image,
    layer_pixels,
    open_inspector,
    serving,
)

from pxr_layers.layers.multipart import read_multipart
from pxr_layers.layers.nuke import LayerGrade
from pxr_layers.layers.previews import to_display
from pxr_layers.view.composite import composite

SERIOUS = ("serious", "critical")
"""The axe-core impacts the audit must not report."""


@pytest.fixture(scope="module")
def rendered(tmp_path_factory) -> Path:
    """The Cornell light passes at 128², 16 spp, with the index and the object Cryptomatte:
    copied for each test."""
    folder = tmp_path_factory.mktemp("document-render")
    result = subprocess.run([SCRIPT, "render", str(CORNELL), "--recipe", "light_passes", "-o", str(folder),
                             "--resolution", str(RESOLUTION), str(RESOLUTION), "--spp", "16", "--quiet",
                             "--cryptomatte", "object"],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    return folder


@pytest.fixture
def folder(rendered, tmp_path) -> Path:
    """A fresh copy of the render (hard links: the files are never written in place)."""
    copy = tmp_path / "render"
    copy.mkdir()
    for path in rendered.iterdir():
        (copy / path.name).hardlink_to(path)
    return copy


@pytest.fixture
def opened(browser, folder):
    """(page, url) of the inspector on `folder`; uncaught page errors fail the test."""
    errors: list[str] = []

    def uncaught(error):
        errors.append(str(error.error))

    browser.on("weberror", uncaught)
    with serving(folder) as url:
        page = open_inspector(browser, url)
        yield page, url
        page.close()
    browser.remove_listener("weberror", uncaught)
    assert not errors, errors


def stack(page) -> list[dict]:
    return page.evaluate("pxrViewer.state().layers")


def names(page) -> list[str]:
    return [layer["name"] for layer in stack(page)]


def more(page, entry_id: str):
    """The "more" controls of an entry's row, opened."""
    row = page.locator(f'#stack li[data-id="{entry_id}"]')
    details = row.locator("details.more")
    if not details.evaluate("d => d.open"):
        details.locator("summary").click()
    return row


def persisted(page) -> dict:
    """The document once the server has written it."""
    page.evaluate("pxrViewer.persist()")
    return page.evaluate("pxrViewer.document()")


def test_the_stack_is_managed_and_every_edit_undoes_and_redoes(opened):
    page, _ = opened
    first = names(page)
    assert first[0] == "beauty" and "diffuse_direct" in first
    states = [stack(page)]

    row = more(page, "diffuse_direct")
    row.locator("button.duplicate").click()
    assert names(page).count("diffuse_direct_copy") == 1
    states.append(stack(page))

    copy = more(page, "diffuse_direct_copy")
    copy.locator("input.rename").fill("key_bounce")
    copy.locator("input.rename").press("Enter")
    page.wait_for_function("pxrViewer.state().layers.some(l => l.name === 'key_bounce')")
    states.append(stack(page))

    at = names(page).index("key_bounce")
    more(page, "diffuse_direct_copy").locator("button.move-up").click()
    assert names(page).index("key_bounce") == at - 1
    states.append(stack(page))

    group = more(page, "diffuse_direct_copy").locator("input.group-input")
    group.fill("key")
    group.press("Enter")
    page.wait_for_selector('#stack li.group[data-group="key"]')
    states.append(stack(page))

    page.evaluate("pxrViewer.setGrade('diffuse_direct_copy', {stops: 1.5, mute: true})")
    states.append(stack(page))

    more(page, "emission").locator("button.delete").click()
    assert "emission" not in names(page)
    states.append(stack(page))

    # a rename to a name the stack has is refused, not applied
    renamed = more(page, "diffuse_direct_copy").locator("input.rename")
    renamed.fill("diffuse_direct")
    renamed.press("Enter")
    assert renamed.get_attribute("aria-invalid") == "true" and stack(page) == states[-1]

    for expected in reversed(states[:-1]):
        page.click("#undo")
        assert stack(page) == expected
    assert page.locator("#undo").is_disabled()
    for expected in states[1:]:
        page.keyboard.press("Control+Shift+Z")
        assert stack(page) == expected
    page.keyboard.press("Control+z")
    assert stack(page) == states[-2]


def test_the_working_state_is_restored_on_reload(opened, folder):
    page, url = opened
    page.evaluate("pxrViewer.setGrade('diffuse_direct', {stops: -1.25, tint: [1, 0.5, 0.25]})")
    page.evaluate("pxrViewer.setGrade('emission', {mute: true})")
    page.fill("#exposure-number", "0.75")
    page.fill("#expression", "C<RD'redWall'>.*")
    page.fill("#layer-name", "red_wall")
    page.click("#add-layer")
    page.wait_for_selector('#stack li[data-id="red_wall"]')
    made = layer_pixels(page, "red_wall")
    page.keyboard.press("s")  # a snapshot
    page.evaluate("pxrViewer.setGrade('red_wall', {stops: 2})")
    page.select_option("#compare-mode", "wipe")
    page.click("#one-to-one")
    before = persisted(page)
    picture = canvas_image(page)
    assert (folder / "light_passes.view.json").is_file()
    assert json.loads((folder / "light_passes.view.json").read_text()) == before

    page.reload()
    page.wait_for_function("window.pxrViewer && pxrViewer.ready")
    assert page.evaluate("pxrViewer.document()") == before
    assert page.evaluate("pxrViewer.state().snapshots") == ["snapshot 1"]
    np.testing.assert_array_equal(layer_pixels(page, "red_wall"), made)  # extracted again from its expression
    np.testing.assert_array_equal(canvas_image(page), picture)


def test_a_saved_look_reopens_exactly_as_saved_and_reset_returns_to_it(opened, browser, folder):
    page, _ = opened
    more(page, "diffuse_indirect").locator("button.duplicate").click()
    page.evaluate("pxrViewer.setGrade('diffuse_direct', {stops: 1, tint: [1, 0.8, 0.6]})")
    page.evaluate("pxrViewer.setGrade('diffuse_indirect_copy', {stops: -2, solo: false})")
    page.evaluate("pxrViewer.setGrade('emission', {mute: true})")
    page.fill("#exposure-number", "-0.5")
    page.fill("#save-name", "warm_look")
    page.click("#save")
    page.wait_for_selector('#saved li[data-kind="document"]')
    saved = [{key: layer[key] for key in ("name", "stops", "tint", "mute", "solo", "group")} for layer in stack(page)]
    picture = canvas_image(page)
    assert (folder / "warm_look.view.json").is_file() and (folder / "warm_look.exr").is_file()

    with serving(folder / "warm_look.exr") as url:
        look = open_inspector(browser, url)
        try:
            shown = [{key: layer[key] for key in ("name", "stops", "tint", "mute", "solo", "group")}
                     for layer in stack(look)]
            assert shown == saved
            assert look.evaluate("pxrViewer.state().exposure") == -0.5
            assert look.evaluate("pxrViewer.state().saved") == "warm_look"
            np.testing.assert_array_equal(canvas_image(look), picture)
            # reset: back to the grades the look's recipe holds (its layers' stops and tint), not to 0
            look.evaluate("pxrViewer.setGrade('diffuse_direct', {stops: 3})")
            look.keyboard.press("r")
            direct = next(layer for layer in stack(look) if layer["name"] == "diffuse_direct")
            assert (direct["stops"], direct["tint"]) == (1, pytest.approx([1, 0.8, 0.6]))
        finally:
            look.close()


def test_compare_wipes_and_sets_side_by_side_the_look_and_the_raw_beauty(opened):
    page, _ = opened
    grade = {"diffuse_direct": LayerGrade(stops=1.5, tint=(1.0, 0.5, 0.25))}
    page.evaluate("pxrViewer.setGrade('diffuse_direct', {stops: 1.5, tint: [1, 0.5, 0.25]})")
    ids = [layer["id"] for layer in stack(page)]
    layers = [layer_pixels(page, entry) for entry in ids[1:]]
    beauty = layer_pixels(page, "beauty")
    graded = to_display(composite(beauty, layers, [grade.get(entry, LayerGrade()) for entry in ids[1:]])).astype(int)
    raw = to_display(composite(beauty, layers, [LayerGrade()] * len(layers))).astype(int)
    assert np.abs(graded - raw).max() > 8

    page.select_option("#compare-mode", "wipe")
    page.evaluate("pxrViewer.setCompare({against: 'beauty', wipe: 0.25})")
    shown = canvas_image(page).astype(int)
    split = RESOLUTION // 4
    assert np.abs(shown[:, :split] - graded[:, :split]).max() <= 1
    assert np.abs(shown[:, split:] - raw[:, split:]).max() <= 1
    handle = page.locator("#wipe")
    handle.focus()
    handle.press("End")
    assert page.evaluate("pxrViewer.state().compare.wipe") == 1
    assert np.abs(canvas_image(page).astype(int) - graded).max() <= 1

    # a snapshot of the graded look, then another grade: the wipe compares the two
    page.keyboard.press("s")
    page.evaluate("pxrViewer.setGrade('diffuse_direct', {stops: 0, tint: [1, 1, 1]})")
    page.evaluate("pxrViewer.setCompare({against: 'snapshot:0', wipe: 0})")
    assert np.abs(canvas_image(page).astype(int) - graded).max() <= 1

    page.select_option("#compare-mode", "side")
    page.click("#one-to-one")
    left = canvas_image(page).astype(int)  # the left half's image: the current look (ungraded now)
    assert np.abs(left - raw).max() <= 1
    page.select_option("#compare-mode", "one")


def test_the_keyboard_alone_inspects_a_pixel_and_grades_a_layer(opened):
    page, _ = opened
    page.focus("#canvas")
    page.keyboard.press("ArrowRight")
    page.keyboard.press("Enter")
    page.wait_for_selector("#tab-body tr[data-path]")
    assert page.evaluate("pxrViewer.state().selection") is not None
    page.focus('#stack li[data-id="diffuse_direct"] input.gain')
    page.keyboard.press("ArrowRight")
    assert next(layer for layer in stack(page) if layer["id"] == "diffuse_direct")["stops"] == 0.05
    page.focus('#stack li[data-id="diffuse_direct"] button.mute')
    page.keyboard.press("Enter")
    assert next(layer for layer in stack(page) if layer["id"] == "diffuse_direct")["mute"] is True
    page.keyboard.press("?")  # focus on a button: the shortcut still opens the help
    assert page.locator("#help").evaluate("d => d.open")
    assert "Ctrl+Z" in page.text_content("#help")
    page.keyboard.press("Escape")
    assert not page.locator("#help").evaluate("d => d.open")


def test_tab_reaches_every_control_and_leaves_none_trapped(opened):
    """Tab from the start of the page visits the controls in order and comes back round: no
    control keeps the focus (a trap), and each visited one has an accessible name."""
    page, _ = opened
    page.evaluate("document.activeElement.blur()")
    seen = []
    for _ in range(400):
        page.keyboard.press("Tab")
        focused = page.evaluate("""() => {
            const e = document.activeElement;
            if (!e || e === document.body) return null;
            const label = e.labels?.[0]?.textContent || e.getAttribute('aria-label') || e.textContent || e.title || e.id;
            return {key: e.id || e.outerHTML.slice(0, 120), label: (label || '').trim()};
        }""")
        if focused is None or (seen and focused["key"] == seen[0]["key"]):
            break
        seen.append(focused)
    else:
        pytest.fail("Tab never came back round")
    keys = [item["key"] for item in seen]
    assert "canvas" in keys and "save" in keys and "add-layer" in keys
    assert all(item["label"] for item in seen), [item for item in seen if not item["label"]]


@pytest.mark.parametrize("state", ["as opened", "layer controls open", "help open"])
def test_the_accessibility_audit_finds_nothing_serious(opened, state):
    from axe_playwright_python.sync_playwright import Axe

    page, _ = opened
    if state == "layer controls open":
        more(page, "diffuse_direct")
        page.select_option("#compare-mode", "wipe")
    elif state == "help open":
        page.click("#help-button")
    violations = Axe().run(page).response["violations"]
    serious = [(violation["id"], violation["impact"], [node["target"] for node in violation["nodes"]][:3])
               for violation in violations if violation["impact"] in SERIOUS]
    assert not serious, serious


def test_a_mask_picked_in_the_image_limits_the_grade_to_it(opened, folder):
    """Pick the red wall in the image for diffuse_direct's mask, grade the layer: the canvas
    is the numpy composite with that mask (the Cryptomatte's coverage) within 1/255, and
    differs from the unmasked grade."""
    page, _ = opened
    x, y, _, _ = brightest_pixel(folder / "cornell.pxlidx", RED_DIRECT)
    row = more(page, "diffuse_direct")
    row.locator("select.mask-kind").select_option("object")
    more(page, "diffuse_direct").locator("button.pick").click()
    page.click("#fit")
    page.mouse.click(*page.evaluate("([x, y]) => pxrViewer.imageToClient(x, y)", [x, y]))
    page.wait_for_function("pxrViewer.state().layers.find(l => l.id === 'diffuse_direct').mask?.names.length === 1")
    mask = next(layer for layer in stack(page) if layer["id"] == "diffuse_direct")["mask"]
    assert mask["kind"] == "object" and "redWall" in mask["names"][0], mask
    page.evaluate("pxrViewer.setGrade('diffuse_direct', {stops: 2, tint: [0.5, 1, 1]})")
    page.wait_for_function("mask => pxrViewer.maskData(mask) !== null", arg=mask)
    coverage = np.frombuffer(base64.b64decode(page.evaluate("mask => pxrViewer.maskData(mask)", mask)), "<f4")
    coverage = coverage.reshape(RESOLUTION, RESOLUTION)
    assert coverage[y, x] > 0.9 and coverage.mean() < 0.5

    ids = [layer["id"] for layer in stack(page)]
    grades = [LayerGrade(stops=2, tint=(0.5, 1, 1)) if entry == "diffuse_direct" else LayerGrade() for entry in ids[1:]]
    layers = [layer_pixels(page, entry) for entry in ids[1:]]
    masks = [coverage if entry == "diffuse_direct" else None for entry in ids[1:]]
    beauty = layer_pixels(page, "beauty")
    expected = to_display(composite(beauty, layers, grades, masks=masks)).astype(int)
    shown = canvas_image(page).astype(int)
    assert np.abs(shown - expected).max() <= 1
    assert np.abs(to_display(composite(beauty, layers, grades)).astype(int) - expected).max() > 8


def add_layer(page, name: str, expression: str) -> None:
    page.fill("#expression", expression)
    page.fill("#layer-name", name)
    page.uncheck("#solo-new")
    page.click("#add-layer")
    page.wait_for_selector(f'#stack li[data-id="{name}"]')


def test_overlapping_layers_are_shown_and_made_exclusive(opened):
    """A layer that claims paths the light passes claim already: the warning names the pair
    and the energy counted twice; its exclusive version takes its place, and then the stack
    sums to the beauty again."""
    page, _ = opened
    add_layer(page, "red_wall", "C<RD'redWall'>.*")
    page.wait_for_selector("#overlaps:not([hidden]) button")
    text = page.text_content("#overlaps")
    assert "counted twice" in text and "red_wall" in text
    overlaps = page.evaluate("pxrViewer.state().overlaps")
    assert overlaps["double_counted"] > 0.001 and "red_wall" in overlaps["exclusive"]
    page.locator("#overlaps button", has_text="red_wall without").first.click()
    page.wait_for_selector('#stack li[data-id="red_wall_only"]')
    assert "red_wall" not in [layer["name"] for layer in stack(page)]
    page.wait_for_function("pxrViewer.state().overlaps && pxrViewer.state().overlaps.double_counted === 0")
    assert page.locator("#overlaps").is_hidden()
    total = sum(layer_pixels(page, layer["id"]).astype(np.float64) for layer in stack(page)[1:])
    beauty = layer_pixels(page, "beauty").astype(np.float64)
    np.testing.assert_allclose(total, beauty, rtol=1e-5, atol=1e-6 * beauty.max())


def test_a_misspelled_name_shows_the_nearest_names_and_a_missing_bracket_its_position(opened):
    page, _ = opened
    page.fill("#expression", "C<RD'redWal'>.*")
    page.wait_for_selector("#expression-error button.nearest")
    assert "no 'redWal' in this index" in page.text_content("#expression-error")
    page.locator("#expression-error button.nearest", has_text="redWall").click()
    assert page.input_value("#expression") == "C<RD'redWall'>.*"
    page.wait_for_function("document.querySelector('#expression-error').textContent === 'valid expression'")

    page.fill("#expression", "C<RD'redWall'.*L")
    page.wait_for_function("document.querySelector('#expression-error').textContent.includes('^')")
    text, caret, message = page.text_content("#expression-error").split("\n", 2)
    assert caret == " " * len("C<RD'redWall'") + "^"
    assert "expected '>'" in message and "position 1" in message


def test_colour_temperature_grades_as_the_light_would(opened):
    """The Kelvin control multiplies by the blackbody colour a UsdLux light of that
    temperature gets (LayerGrade.kelvin): the canvas is the numpy composite within 1/255."""
    page, _ = opened
    row = more(page, "diffuse_direct")
    row.locator("input.kelvin-on").check()
    row.locator("input.kelvin-value").fill("3000")
    row.locator("input.kelvin-value").press("Enter")
    page.wait_for_function("pxrViewer.state().layers.find(l => l.id === 'diffuse_direct').kelvin === 3000")
    ids = [layer["id"] for layer in stack(page)]
    grades = [LayerGrade(kelvin=3000.0) if entry == "diffuse_direct" else LayerGrade() for entry in ids[1:]]
    expected = to_display(composite(layer_pixels(page, "beauty"), [layer_pixels(page, entry) for entry in ids[1:]],
                                    grades)).astype(int)
    assert np.abs(canvas_image(page).astype(int) - expected).max() <= 1
    assert "3000 K" in page.text_content('#stack li[data-id="diffuse_direct"] .tint-value')


def test_light_edits_are_badged_and_pushed_into_usd(opened, folder, tmp_path):
    """A layer of the whole ceiling light is a light edit; a pass of its diffuse bounces only
    is a compositing grade that says why; the push writes the override and the shot, and a
    render of the shot is the page's regraded beauty within noise.

    Tolerance (as tests/test_view_push.py derives it): the pixels are independent estimates,
    so the mean of D = rerender − the page's composite has standard error std(D)/√pixels; each
    channel's mean must be within 4 of them (plus 1e-6 of the mean, for renders whose paths
    coincide and whose D is rounding only)."""
    page, _ = opened
    add_layer(page, "ceiling", "C.*<L.'ceilingLight'>")
    page.evaluate("pxrViewer.setGrade('ceiling', {stops: 1, kelvin: 4000})")
    page.wait_for_selector('#stack li[data-id="ceiling"] .badge.light:not([hidden])')
    badge = page.locator('#stack li[data-id="diffuse_direct"] .badge')
    assert badge.text_content() == "comp" and "compositing grade" in badge.get_attribute("title")
    page.fill("#save-name", "warmer")
    page.click("#push")
    page.wait_for_selector("#saved li.pushed")
    assert "ceiling → ceilingLight" in page.text_content("#saved")
    assert (folder / "warmer.lights.usda").is_file() and (folder / "warmer.shot.usda").is_file()
    assert "over" in (folder / "warmer.lights.usda").read_text()

    ids = [layer["id"] for layer in stack(page)]
    grades = [LayerGrade(stops=1.0, kelvin=4000.0) if entry == "ceiling" else LayerGrade() for entry in ids[1:]]
    beauty = layer_pixels(page, "beauty")
    expected = composite(beauty, [layer_pixels(page, entry) for entry in ids[1:]], grades).astype(np.float64)
    again = tmp_path / "again"
    result = subprocess.run([SCRIPT, "render", str(folder / "warmer.shot.usda"), "-o", str(again), "--resolution",
                             str(RESOLUTION), str(RESOLUTION), "--spp", "16", "--quiet", "--no-index"],
                            capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    rendered = read_multipart(next(again.glob("*.exr"))).beauty[..., :3].astype(np.float64)
    difference = (rendered - expected).reshape(-1, 3)
    tolerance = 4.0 * difference.std(axis=0, ddof=1) / np.sqrt(len(difference)) + 1e-6 * expected.mean()
    assert np.all(np.abs(difference.mean(axis=0)) < tolerance), (difference.mean(axis=0), tolerance)
    moved = (expected - beauty).reshape(-1, 3).mean(axis=0)
    assert np.all(np.abs(moved) > 10 * tolerance), (moved, tolerance)  # the grade is far outside it


def test_another_view_transform_is_shown_kept_and_saved(opened, browser, folder):
    """The view transform (an OCIO view of the products' display): the canvas is the numpy
    composite through that view's processor, the choice survives a reload, and a saved
    look's previews and recipe use it."""
    from pxr_layers.layers.previews import display_processor

    page, url = opened
    display = page.evaluate("fetch('/api/session', {headers: {'X-Pxr-Token': new URLSearchParams(location.search).get('token')}}).then(r => r.json())")["display"]
    other = next(view for view in display["views"] if view != display["view"] and "Raw" not in view)
    page.select_option("#view-transform", other)
    page.wait_for_function("view => pxrViewer.document().display_view === view", arg=other)
    processor = display_processor(display["config"], display["display"], other)
    beauty = layer_pixels(page, "beauty")
    assert np.abs(canvas_image(page).astype(int) - to_display(beauty, processor).astype(int)).max() <= 1
    persisted(page)
    page.reload()
    page.wait_for_function("window.pxrViewer && pxrViewer.ready")
    assert page.input_value("#view-transform") == other
    assert np.abs(canvas_image(page).astype(int) - to_display(beauty, processor).astype(int)).max() <= 1
    page.fill("#save-name", "other_view")
    page.click("#save")
    page.wait_for_selector('#saved li[data-kind="document"]')
    assert f'"{other}"' in (folder / "other_view.usda").read_text()


def test_a_layer_of_a_misspelled_name_is_not_added_unless_asked_twice(opened):
    page, _ = opened
    page.fill("#expression", "C<RD'flor'>.*")
    page.fill("#layer-name", "floor_bounce")
    page.click("#add-layer")
    page.wait_for_function("document.querySelector('#layer-status').textContent.startsWith('not added')")
    assert "'flor' names nothing" in page.text_content("#layer-status")
    assert "floor" in page.text_content("#expression-error button.nearest")
    assert "floor_bounce" not in names(page)
    page.click("#add-layer")  # asked again: added, empty
    page.wait_for_selector('#stack li[data-id="floor_bounce"]')


def test_a_slider_dragged_alone_adds_its_layer_to_the_rest_summed_once(opened):
    """While one layer is regraded and the others stay, the frames add it to a float texture
    of the rest (renderer.js's base): the picture is still the numpy composite within 1/255,
    and back at its first grade it is the first picture exactly."""
    page, _ = opened
    rest = {"diffuse_indirect": LayerGrade(stops=-1.0, tint=(1.0, 0.8, 0.6)), "emission": LayerGrade(stops=0.5)}
    for name, grade in rest.items():
        page.evaluate("([id, grade]) => pxrViewer.setGrade(id, grade)", [name, {"stops": grade.stops, "tint": list(grade.tint)}])
    first = canvas_image(page)
    for stops in (0.5, 1.0, 1.5):
        page.evaluate("stops => { pxrViewer.setGrade('diffuse_direct', {stops}); pxrViewer.drawFinished(); }", stops)
    shown = canvas_image(page).astype(int)
    assert page.evaluate("pxrViewer.state().pass") == 2
    grades = {**rest, "diffuse_direct": LayerGrade(stops=1.5)}
    ids = [layer["id"] for layer in stack(page)]
    expected = to_display(composite(layer_pixels(page, "beauty"), [layer_pixels(page, entry) for entry in ids[1:]],
                                    [grades.get(entry, LayerGrade()) for entry in ids[1:]])).astype(int)
    assert np.abs(shown - expected).max() <= 1
    page.evaluate("pxrViewer.setGrade('diffuse_direct', {stops: 0}); pxrViewer.drawFinished()")
    np.testing.assert_array_equal(canvas_image(page), first)
    assert page.evaluate("pxrViewer.state().pass") == 2


def test_suggested_layers_come_with_their_explanations_and_are_not_offered_twice(opened, folder):
    """K left empty: the search chooses; each suggested layer shows its one-line explanation,
    which a saved look's recipe keeps; asked again, the same layers are not added twice."""
    page, _ = opened
    before = len(stack(page))
    page.fill("#suggest-k", "")
    page.click("#suggest")
    page.wait_for_function("pxrViewer.timings.suggest !== undefined", timeout=60_000)
    added = page.evaluate("pxrViewer.timings.suggest.layers")
    assert added and len(stack(page)) == before + len(added)
    notes = page.eval_on_selector_all("#stack li .layer-note", "notes => notes.map(n => n.textContent)")
    assert len(notes) == len(added) and all(notes), notes
    page.evaluate("pxrViewer.timings.suggest = undefined")
    page.click("#suggest")
    page.wait_for_function("pxrViewer.timings.suggest !== undefined", timeout=60_000)
    assert page.evaluate("pxrViewer.timings.suggest.layers") == []
    assert "not added again" in page.text_content("#suggest-status")
    page.fill("#save-name", "suggested_look")
    page.click("#save")
    page.wait_for_selector('#saved li[data-kind="recipe"]')
    recipe = (folder / "suggested_look.usda").read_text()
    assert all(f'doc = "{note}"' in recipe for note in notes), notes  # each RenderVar's doc
