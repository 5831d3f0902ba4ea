"""Nothing silently wrong (issue 33 §3): what renders "fine" but is not what was meant is a
warning, one line naming the reason, the prims and the close names; the command still
succeeds (exit 0).

* a black picture whose reason the renderer sees: every light sends nothing (each light's
  reason: it emits 0, its image is black, it has no size, its light link holds nothing),
  lights that light nothing (inputs:diffuse and inputs:specular 0), the camera inside closed
  geometry, the camera seeing nothing;
* a label of a layer that names no light, object or material (a typo: 'flor' for 'floor'),
  with the closest names of its kind, in ``extract``, ``render``'s recipe layers and the
  inspector;
* two Cryptomatte names whose ids collide.

Each render is 8 × 8 at 1 spp, through the command line, in this process.
"""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio
import pytest
from test_cli import RENDER_DIR, ball_lit_by
from test_hostile_stage import SUN, own_logging, render

from pxr_layers.cli.main import main
from pxr_layers.layers.cryptomatte import collisions, id_hex, manifest, murmurhash3_32, warn_of_collisions

WARNING = "pxr-layers: WARNING: "


def light(type_name: str, *controls: str, name: str = "key", schemas: str = "") -> str:
    """A light /World/<name> at (2, 2, 2) with `controls` authored (USD text)."""
    body = "".join(f"        {control}\n" for control in controls)
    return (f'    def {type_name} "{name}"{schemas}\n    {{\n{body}'
            '        double3 xformOp:translate = (2, 2, 2)\n'
            '        uniform token[] xformOpOrder = ["xformOp:translate"]\n    }\n')


def black_sky(tmp_path) -> str:
    """A DomeLight /World/sky whose image (sky.exr, written here) is black."""
    image = oiio.ImageOutput.create(str(tmp_path / "sky.exr"))
    image.open(str(tmp_path / "sky.exr"), oiio.ImageSpec(8, 4, 3, "float"))
    image.write_image(np.zeros((4, 8, 3), np.float32))
    image.close()
    return '    def DomeLight "sky"\n    {\n        asset inputs:texture:file = @./sky.exr@\n    }\n'


def warnings_of(lines: list[str]) -> list[str]:
    assert all(line.startswith(WARNING) for line in lines), lines
    return [line.removeprefix(WARNING) for line in lines]


# --- a black picture: no light sends anything -------------------------------------------------

DARK_LIGHTS = {
    "intensity-0": (light("SphereLight", "float inputs:intensity = 0"), ["/World/key emits nothing"]),
    "black-colour": (light("SphereLight", "color3f inputs:color = (0, 0, 0)"), ["/World/key emits nothing"]),
    "exposure-minus-5000": (light("SphereLight", "float inputs:exposure = -5000"), ["/World/key emits nothing"]),
    "rect-width-0": (light("RectLight", "float inputs:width = 0"), ["/World/key has no area"]),
    "sphere-radius-0": (light("SphereLight", "float inputs:radius = 0"), ["/World/key has no area"]),
    "disk-scale-0": (light("DiskLight", "double3 xformOp:scale = (0, 0, 0)").replace(
        '["xformOp:translate"]', '["xformOp:translate", "xformOp:scale"]'), ["/World/key has no area"]),
    "sun-scale-0": (light("DistantLight", "double3 xformOp:scale = (0, 0, 0)").replace(
        '["xformOp:translate"]', '["xformOp:translate", "xformOp:scale"]'), ["/World/key has no direction"]),
    "point-radius-0": (light("SphereLight", "bool treatAsPoint = 1", "float inputs:radius = 0"),
                       ["/World/key has no size"]),
    "linked-to-nothing": (light("SphereLight", "uniform bool collection:lightLink:includeRoot = 0",
                                schemas=' (\n        prepend apiSchemas = ["CollectionAPI:lightLink"]\n    )'),
                          ["/World/key lights nothing (its collection:lightLink includes no object)"]),
    "two-dark-lights": (light("SphereLight", "float inputs:intensity = 0") +
                        '    def DistantLight "sun"\n    {\n        color3f inputs:color = (0, 0, 0)\n    }\n',
                        ["/World/key emits nothing", "/World/sun emits nothing"]),
}


@pytest.mark.parametrize("case", list(DARK_LIGHTS))
def test_lights_that_send_nothing_are_one_warning_naming_each_light_and_its_reason(tmp_path, capsys, case):
    text, reasons = DARK_LIGHTS[case]
    code, lines, pixels = render(capsys, tmp_path, ball_lit_by(text))
    assert code == 0 and pixels[..., :3].max() == 0.0
    (line,) = warnings_of(lines)  # the lights' reason, not another one about the camera
    assert line.startswith(f"{tmp_path / 'shot.usda'}: no light emits anything: the image will be black ("), line
    for reason in reasons:
        assert reason in line, line


def test_a_dome_of_a_black_image_is_named(tmp_path, capsys):
    code, lines, pixels = render(capsys, tmp_path, ball_lit_by(black_sky(tmp_path)))
    assert code == 0 and pixels[..., :3].max() == 0.0
    (line,) = warnings_of(lines)
    assert "no light emits anything" in line and "/World/sky has a black image (inputs:texture:file)" in line, line


def test_no_light_at_all_says_so(tmp_path, capsys):
    shot = tmp_path / "shot.usda"
    shot.write_text(ball_lit_by(""))
    with own_logging():
        code = main(["render", str(shot), "-o", str(tmp_path / "out"), "--no-default-lights", "--spp", "1",
                     "--resolution", "8", "8", "--quiet", "--no-previews", "--no-index"])
    lines = warnings_of(capsys.readouterr().err.strip().splitlines())
    assert code == 0
    assert any("the renderer sees no light (an inactive or invisible light is none) and no emissive surface" in line
               for line in lines), lines


def test_lights_whose_diffuse_and_specular_are_0_light_nothing(tmp_path, capsys):
    code, lines, pixels = render(capsys, tmp_path, ball_lit_by(
        light("SphereLight", "float inputs:diffuse = 0", "float inputs:specular = 0")))
    assert code == 0
    (line,) = warnings_of(lines)
    assert "every light that sends light has inputs:diffuse and inputs:specular 0 (/World/key)" in line, line


# --- a black picture: the camera ----------------------------------------------------------------

BOX = '''    def Cube "box"
    {
        double size = 2
        double3 xformOp:translate = (0, 0, 5)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
'''


def looking_away(text: str) -> str:
    """`text` (ball_lit_by's) with the camera turned to look away from the ball."""
    return text.replace('uniform token[] xformOpOrder = ["xformOp:translate"]\n    }\n    def Sphere',
                        'float xformOp:rotateY = 180\n        uniform token[] xformOpOrder = '
                        '["xformOp:translate", "xformOp:rotateY"]\n    }\n    def Sphere', 1)


def test_a_camera_inside_closed_geometry_is_named_with_the_prim_around_it(tmp_path, capsys):
    code, lines, pixels = render(capsys, tmp_path, ball_lit_by(SUN + BOX))
    assert code == 0 and pixels[..., :3].max() == 0.0 and pixels[..., 3].min() == 1.0
    (line,) = warnings_of(lines)
    assert line == (f"{tmp_path / 'shot.usda'}: the picture is black: the camera /World/cam is inside /World/box: "
                    "256 of 256 rays through its film hit the back of a surface"), line


def test_a_camera_that_sees_nothing_says_so(tmp_path, capsys):
    code, lines, pixels = render(capsys, tmp_path, looking_away(ball_lit_by(SUN)))
    assert code == 0 and pixels.max() == 0.0
    (line,) = warnings_of(lines)
    assert line.startswith(f"{tmp_path / 'shot.usda'}: the picture is black: no ray of the camera /World/cam hits "
                           "anything"), line


@pytest.mark.parametrize("text", [
    ball_lit_by(SUN),  # an ordinary picture
    ball_lit_by(BOX + light("SphereLight", "float inputs:radius = 0.1").replace("(2, 2, 2)", "(0.5, 0.5, 4.5)")),
    looking_away(ball_lit_by('    def DomeLight "sky"\n    {\n    }\n')),  # the dome is what it sees
], ids=["ball-in-the-sun", "inside-a-box-with-its-own-light", "looking-at-the-sky"])
def test_a_picture_that_is_not_black_has_no_such_warning(tmp_path, capsys, text):
    code, lines, pixels = render(capsys, tmp_path, text)
    assert code == 0 and pixels[..., :3].max() > 0.0
    assert lines == []


# --- labels that name nothing -------------------------------------------------------------------

@pytest.fixture(scope="module")
def cornell(tmp_path_factory):
    """The Cornell box's index: lights ceilingLight; objects floor, ceiling, backWall, redWall,
    greenWall, tallBox, shortBox; materials white, red, green, box; the diffuse lobe only."""
    folder = tmp_path_factory.mktemp("cornell")
    with own_logging():
        assert main(["render", str(RENDER_DIR / "cornell.usda"), "-o", str(folder), "--spp", "1", "--resolution",
                     "8", "8", "--quiet", "--no-previews"]) == 0
    return folder / "cornell.pxlidx"


LABELS = [
    # expression, what the one warning says
    ("C<RD'flor'>.*", "label 'flor' names no object, material or lobe in {index}; closest: 'floor'"),
    ("C.*<L.'ceilingLite'>", "label 'ceilingLite' names no light in {index}; closest: 'ceilingLight'"),
    ("C.*<L.'lamp'>", "label 'lamp' names no light in {index}; the lights are '/World/Lights/ceilingLight', "
                      "'ceilingLight'"),
    ("C<RD'whte'>.*", "label 'whte' names no object, material or lobe in {index}; closest: 'white'"),
    ("C.*<L.'floor'>", "label 'floor' names no light in {index} (it is an object)"),
    ("C<RD[^'flor']>.*", "label 'flor' names no object, material or lobe in {index}; closest: 'floor'"),
    ("C<..'/World/Geometry/flor'>.*", "label '/World/Geometry/flor' names no light, object, material or lobe in "
                                      "{index}; closest: '/World/Geometry/floor'"),
    ("C.*<L.'/World/Lamps/*'>", "label '/World/Lamps/*' names no light in {index}; the lights are "
                                "'/World/Lights/ceilingLight', 'ceilingLight'"),
    ("C<RG'specular'>.*", "label 'specular' names no object, material or lobe in {index} (no path took that lobe)"),
]


@pytest.mark.parametrize("expression, said", LABELS, ids=[said.split("'")[1] + "@" + expression
                                                         for expression, said in LABELS])
def test_extract_warns_of_a_label_that_names_nothing_with_the_close_names_of_its_kind(cornell, tmp_path, capsys,
                                                                                      expression, said):
    capsys.readouterr()
    with own_logging():
        code = main(["extract", str(cornell), "--layer", f"typo={expression}", "--layer", "fine=C<RD'floor'>.*",
                     "-o", str(tmp_path / "x.exr"), "--quiet", "--no-previews"])
    assert code == 0
    (line,) = warnings_of(capsys.readouterr().err.strip().splitlines())
    assert line.startswith("layer '") and ": " + said.format(index=cornell) in line, line


def test_a_typo_shared_by_layers_is_one_warning_naming_them_all(cornell, tmp_path, capsys):
    capsys.readouterr()
    with own_logging():
        code = main(["extract", str(cornell), "--layer", "lit=C<RD'flor'>L", "--layer", "unlit=C<RD[^'flor']>.*",
                     "-o", str(tmp_path / "x.exr"), "--quiet", "--no-previews"])
    assert code == 0
    (line,) = warnings_of(capsys.readouterr().err.strip().splitlines())
    assert line.startswith("layers 'cornell.layers/lit', 'cornell.layers/unlit': label 'flor' names no object, "
                           "material or lobe") and line.endswith("closest: 'floor'"), line


def test_labels_that_name_something_are_not_warned_of(cornell, tmp_path, capsys):
    capsys.readouterr()
    with own_logging():
        code = main(["extract", str(cornell), "--layer", "a=C<RD'floor'>.*", "--layer", "b=C.*<L.'/World/Lights/*'>",
                     "--layer", "c=C<RD'white'><RD[^'red''green']>.*", "--layer", "d=C<RD'diffuse'>.*",
                     "--layer", "e=C<RD.>.*", "-o", str(tmp_path / "x.exr"), "--quiet", "--no-previews"])
    assert code == 0 and capsys.readouterr().err == ""


RECIPE = '''#usda 1.0
(
    renderSettingsPrimPath = "/Render/Typo/Settings"
)
def Scope "Render"
{
    def Scope "Typo"
    {
        def RenderSettings "Settings"
        {
            rel products = </Render/Typo/typo>
        }
        def RenderProduct "typo"
        {
            rel orderedVars = </Render/Typo/flor>
            token productName = "typo.exr"
        }
        def RenderVar "flor"
        {
            uniform token sourceType = "lpe"
            uniform string sourceName = "C<RD'flor'>.*"
            uniform token dataType = "color3f"
        }
    }
}
'''


def test_render_warns_of_a_recipe_layer_naming_nothing(tmp_path, capsys):
    recipe = tmp_path / "recipe.usda"
    recipe.write_text(RECIPE)
    capsys.readouterr()
    with own_logging():
        code = main(["render", str(RENDER_DIR / "cornell.usda"), "--recipe", str(recipe), "-o", str(tmp_path / "out"),
                     "--spp", "1", "--resolution", "8", "8", "--quiet", "--no-previews", "--no-index"])
    assert code == 0
    (line,) = warnings_of(capsys.readouterr().err.strip().splitlines())
    assert line.startswith("layer 'typo/flor': label 'flor' names no object, material or lobe in ") \
        and line.endswith("closest: 'floor'"), line


def test_the_inspector_answers_a_layer_naming_nothing_with_the_warning(cornell, caplog):
    from pxr_layers.view.session import Session

    session = Session.open(cornell)
    layer, facts = session.add_layer("typo", "C<RD'flor'>.*")
    (warning,) = facts["warnings"]
    assert "label 'flor' names no object, material or lobe" in warning and "closest: 'floor'" in warning
    assert float(layer.image.max()) == 0.0
    _, facts = session.add_layer("floor", "C<RD'floor'>.*")
    assert facts["warnings"] == []


# --- Cryptomatte ids that collide ---------------------------------------------------------------

# Found by brute force over /World/o0000000 ... /World/o0999999 with the project's own hash:
# the first pair's MurmurHash3 values are equal; the second's differ in bit 23 alone, which
# the specification's exponent fix (bit 23 flipped for an exponent of 0) makes one id.
SAME_HASH = ("/World/o0492712", "/World/o0609240")
SAME_ID_AFTER_THE_FIX = ("/World/o0623467", "/World/o0864229")


def test_the_colliding_pairs_collide():
    first, second = SAME_HASH
    assert murmurhash3_32(first.encode()) == murmurhash3_32(second.encode())
    first, second = SAME_ID_AFTER_THE_FIX
    assert murmurhash3_32(first.encode()) ^ murmurhash3_32(second.encode()) == 1 << 23
    assert id_hex(first) == id_hex(second) == "00ba2d39"


def test_collisions_are_found_and_named_and_distinct_ids_are_silent(caplog):
    table = manifest(["/World/floor", *SAME_HASH, "/World/key", *SAME_ID_AFTER_THE_FIX])
    assert collisions(table) == [SAME_HASH, SAME_ID_AFTER_THE_FIX]
    message = warn_of_collisions("CryptoObject", table)
    assert message == ("CryptoObject: names share a Cryptomatte id, so a matte of one picks the other too: "
                       "'/World/o0492712' and '/World/o0609240' (id 0267d7fe); '/World/o0623467' and "
                       "'/World/o0864229' (id 00ba2d39) (rename one of each)")
    assert warn_of_collisions("CryptoObject", manifest(["/World/floor", "/World/key"])) is None


@pytest.mark.parametrize("pair", [SAME_HASH, SAME_ID_AFTER_THE_FIX], ids=["same-hash", "same-id-after-the-fix"])
def test_a_render_whose_cryptomatte_names_collide_names_both(tmp_path, capsys, pair):
    cubes = "".join(f'    def Cube "{path.rsplit("/", 1)[1]}"\n    {{\n        double size = 0.5\n'
                    f'        double3 xformOp:translate = ({x}, 0, 1)\n'
                    '        uniform token[] xformOpOrder = ["xformOp:translate"]\n    }\n'
                    for path, x in zip(pair, (-1, 1)))
    shot = tmp_path / "shot.usda"
    shot.write_text(ball_lit_by(SUN + cubes))
    capsys.readouterr()
    with own_logging():
        code = main(["render", str(shot), "-o", str(tmp_path / "out"), "--cryptomatte", "CryptoObject", "--spp", "1",
                     "--resolution", "8", "8", "--quiet", "--no-previews", "--no-index"])
    assert code == 0
    (line,) = warnings_of(capsys.readouterr().err.strip().splitlines())
    assert line.startswith("CryptoObject: names share a Cryptomatte id") and f"'{pair[0]}' and '{pair[1]}'" in line


def test_a_job_frame_without_its_integrator_is_diagnosed_all_the_same(tmp_path, caplog):
    """A job's committed tiles hold no Integrator: the frame is prepared again, for a black
    picture only."""
    from pxr_layers.jobs.frame import plan_frame, warn_of_black_picture
    from pxr_layers.request import RenderRequest

    shot = tmp_path / "shot.usda"
    shot.write_text(ball_lit_by(SUN + BOX))
    plan = plan_frame(RenderRequest(stage=shot, spp=1, resolution=(8, 8)), None, directory=tmp_path)
    black = np.zeros((8, 8, 4), np.float32)
    black[..., 3] = 1.0
    message = warn_of_black_picture(plan, black)
    assert message is not None and "the camera /World/cam is inside /World/box" in message
    black[0, 0, 0] = 0.5  # one lit pixel: not a black picture
    assert warn_of_black_picture(plan, black) is None
