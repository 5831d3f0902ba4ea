"""End to end: `pxr-layers render --recipe` writes each product as a compositor reads it, and
`pxr-layers extract --recipe` re-cuts the same layers from the index without rendering."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import OpenEXR
import OpenImageIO as oiio
import pytest
from test_cli import SCRIPT

from pxr_layers import __version__

SMALL = ("--spp", "4", "--resolution", "40", "30", "--quiet")
PASSES = ("emission", "background", "diffuse_direct", "diffuse_indirect", "glossy_direct", "glossy_indirect",
          "transmission", "volume")


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([SCRIPT, *args], capture_output=True, text=True, check=False)


def parts(path) -> dict[str, OpenEXR.Part]:
    return {part.name(): part for part in OpenEXR.File(str(path)).parts}


def colour(part: OpenEXR.Part, name: str) -> np.ndarray:
    """(h, w, 3) float of a layer part (the binding groups NAME.R/G/B into one channel NAME)."""
    channels = part.channels
    if name in channels:
        return np.asarray(channels[name].pixels, np.float64)
    return np.stack([channels[f"{name}.{c}"].pixels for c in "RGB"], axis=-1).astype(np.float64)


@pytest.fixture(scope="module")
def showcase_render(tmp_path_factory, shipped_scene):
    """The showcase with the light passes + data AOVs (WithData) and one layer per light.

    The index keeps the norms of events 1..5 and paths have at most 5 bounces, so covariance
    conditions can be cut later (extract) on every event."""
    out = tmp_path_factory.mktemp("render")
    result = run("render", str(shipped_scene("showcase.usda")), "--recipe", "light_passes", "--settings",
                 "/Render/LightPasses/WithData", "--per-light", "lights", "--frame", "3", "--seed", "7", "--max-depth", "5", "-o",
                 str(out), *SMALL)
    assert result.returncode == 0, result.stderr
    return out, result.stdout.split()


def test_render_writes_every_product_with_its_index(showcase_render):
    out, printed = showcase_render
    assert printed == [str(out / "light_passes.0003.exr"), str(out / "light_passes_data.0003.exr")]
    assert (out / "showcase.0003.pxlidx").exists()
    assert not [p for p in out.iterdir() if ".tmp" in p.name]


def test_parts_channels_types_and_metadata_with_openexr(showcase_render):
    out, _ = showcase_render
    found = parts(out / "light_passes.0003.exr")
    lights = ["light_key", "light_fill", "light_sky", "light_other"]
    assert list(found) == ["rgba", *PASSES, *lights]
    for name, part in found.items():
        assert np.array_equal(part.header["dataWindow"], part.header["displayWindow"])
        assert (part.width(), part.height()) == (40, 30)
        assert part.header["pxrLayers/version"] == __version__
        assert part.header["pxrLayers/spp"] == "4" and part.header["pxrLayers/seed"] == "7"
        assert part.header["pxrLayers/frame"] == "3.0"
        if name != "rgba":
            assert part.header["pxrLayers/sourceType"] == "lpe"
            assert colour(part, name).dtype == np.float64 and part.channels[name].pixels.dtype == np.float32
    assert found["diffuse_direct"].header["pxrLayers/expression"] == "C<RD>[LOB]"
    assert found["light_key"].header["pxrLayers/expression"] == "C.*<L.'key'>"
    expressions = json.loads(found["rgba"].header["pxrLayers/expressions"])
    assert list(expressions) == [*PASSES, *lights]
    recipe = json.loads(found["rgba"].header["pxrLayers/recipe"])
    assert recipe["settings_path"] == "/Render/LightPasses/WithData"
    assert found["rgba"].header["pxrLayers/index"] == "showcase.0003.pxlidx"


def test_the_passes_and_the_light_split_each_add_up_to_the_beauty(showcase_render):
    out, _ = showcase_render
    found = parts(out / "light_passes.0003.exr")
    beauty = np.asarray(found["rgba"].channels["RGBA"].pixels, np.float64)[..., :3]
    for group in (PASSES, ["light_key", "light_fill", "light_sky", "light_other"]):
        total = sum(colour(found[name], name) for name in group)
        np.testing.assert_allclose(total, beauty, rtol=1e-5, atol=1e-6)
    assert beauty.max() > 0


def test_the_file_reads_in_openimageio(showcase_render):
    out, _ = showcase_render
    image = oiio.ImageInput.open(str(out / "light_passes_data.0003.exr"))
    try:
        names = []
        subimage = 0
        while image.seek_subimage(subimage, 0):
            spec = image.spec()
            names.append((spec.getattribute("name"), tuple(spec.channelnames), spec.format.basetype))
            subimage += 1
    finally:
        image.close()
    assert names == [
        ("rgba", ("R", "G", "B", "A"), oiio.FLOAT),
        ("depth", ("depth.Z",), oiio.FLOAT),
        ("normal", ("normal.X", "normal.Y", "normal.Z"), oiio.FLOAT),
        ("primId", ("primId.id",), oiio.FLOAT),
        ("instanceId", ("instanceId.id",), oiio.FLOAT),
    ]


def test_data_layers_hold_the_render_geometry(showcase_render):
    out, _ = showcase_render
    found = parts(out / "light_passes_data.0003.exr")
    depth = np.asarray(found["depth"].channels["depth.Z"].pixels)
    prim = np.asarray(found["primId"].channels["primId.id"].pixels)
    normal = np.stack([found["normal"].channels[f"normal.{axis}"].pixels for axis in "XYZ"], axis=-1)
    alpha = np.asarray(found["rgba"].channels["RGBA"].pixels)[..., 3]
    hit = prim >= 0
    assert hit.any() and np.isfinite(depth[hit]).all() and (depth[hit] > 0).all()
    assert np.isinf(depth[~hit]).all()
    np.testing.assert_allclose(np.linalg.norm(normal[hit], axis=-1), 1.0, atol=1e-5)
    assert np.array_equal(prim, np.round(prim))
    paths = json.loads(found["primId"].header["pxrLayers/primPaths"])
    assert all(path.startswith("/") for path in paths) and int(prim.max()) < len(paths)
    # a pixel every camera sample hits (alpha 1) has an object at its centre
    assert hit[alpha == 1.0].all()


def test_previews_have_the_image_size_and_are_not_blank(showcase_render):
    out, _ = showcase_render
    for name in ("rgba", "diffuse_direct", "light_key", "contact"):
        image = oiio.ImageBuf(str(out / f"light_passes.0003.{name}.png"))
        pixels = image.get_pixels(oiio.UINT8)
        if name != "contact":
            assert pixels.shape == (30, 40, 3)
        assert pixels.max() > 40 and pixels.std() > 1
    # the data product of the preset asks for no previews of its layers, and no contact sheet
    assert sorted(p.name for p in out.glob("light_passes_data.*.png")) == ["light_passes_data.0003.rgba.png"]


def test_extract_with_the_recipe_reproduces_what_render_wrote(tmp_path, showcase_render, shipped_scene):
    out, _ = showcase_render
    result = run("extract", str(out / "showcase.0003.pxlidx"), "--recipe", "light_passes", "--per-light", "lights",
                 "-o", str(tmp_path), "--quiet")
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [str(tmp_path / "light_passes.0003.exr")]
    rendered, extracted = parts(out / "light_passes.0003.exr"), parts(tmp_path / "light_passes.0003.exr")
    assert list(rendered) == list(extracted)
    for name, part in rendered.items():
        for channel, values in part.channels.items():
            assert np.array_equal(values.pixels, extracted[name].channels[channel].pixels), (name, channel)
        assert part.header["pxrLayers/expression"] == extracted[name].header["pxrLayers/expression"]


def test_extract_cuts_a_new_recipe_from_the_same_index(tmp_path, showcase_render):
    """The showcase selections were not asked for at render time: extract adds them."""
    out, _ = showcase_render
    result = run("extract", str(out / "showcase.0003.pxlidx"), "--recipe", "showcase", "-o", str(tmp_path), "--quiet")
    assert result.returncode == 0, result.stderr
    found = parts(tmp_path / "showcase_selections.0003.exr")
    assert {"texture_high", "glossy_last", "flat", "curved"} <= set(found)
    flat, curved = colour(found["flat"], "flat"), colour(found["curved"], "curved")
    assert flat.sum() > 0 and curved.sum() > 0


def test_extract_refuses_data_layers_it_cannot_make(tmp_path, showcase_render):
    out, _ = showcase_render
    result = run("extract", str(out / "showcase.0003.pxlidx"), "--recipe", "light_passes", "--settings",
                 "/Render/LightPasses/WithData", "-o", str(tmp_path), "--quiet")
    assert result.returncode == 1
    assert "/Render/LightPasses/DataVars/depth" in result.stderr and "sourceName" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_one_exr_path_for_several_products_is_a_user_error(tmp_path, shipped_scene):
    result = run("render", str(shipped_scene("showcase.usda")), "--recipe", "light_passes", "--settings",
                 "/Render/LightPasses/PerLight", "-o", str(tmp_path / "x.exr"), *SMALL)
    assert result.returncode == 1 and "give a directory" in result.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_missing_recipe_is_a_user_error(tmp_path, shipped_scene):
    result = run("render", str(shipped_scene("cornell.usda")), "--recipe", str(tmp_path / "nope.usda"),
                 "-o", str(tmp_path), *SMALL)
    assert result.returncode == 1 and "nope.usda" in result.stderr


def test_a_raw_var_the_renderer_does_not_make_fails_before_rendering(tmp_path, shipped_scene):
    recipe = tmp_path / "recipe.usda"
    recipe.write_text('''#usda 1.0
(
    renderSettingsPrimPath = "/Render/Ids/Settings"
)
def Scope "Render"
{
    def Scope "Ids"
    {
        def RenderSettings "Settings"
        {
            rel products = </Render/Ids/ids>
        }
        def RenderProduct "ids"
        {
            rel orderedVars = </Render/Ids/element>
            token productName = "ids.exr"
        }
        def RenderVar "element"
        {
            uniform token sourceType = "raw"
            uniform string sourceName = "elementId"
            uniform token dataType = "int"
        }
    }
}
''')
    result = run("render", str(shipped_scene("cornell.usda")), "--recipe", str(recipe), "-o", str(tmp_path / "out"),
                 *SMALL)
    assert result.returncode == 1
    assert "/Render/Ids/element" in result.stderr and "elementId" in result.stderr
    assert not (tmp_path / "out").exists()


def test_a_recipe_with_conditions_keeps_the_norms_of_every_bounce(tmp_path, shipped_scene):
    result = run("render", str(shipped_scene("showcase.usda")), "--recipe", "showcase", "--max-depth", "7",
                 "-o", str(tmp_path), *SMALL)
    assert result.returncode == 0, result.stderr
    from pxr_layers.paths.reader import PathIndex

    assert PathIndex(tmp_path / "showcase.pxlidx").manifest["norm_slots"] >= 7
    found = parts(tmp_path / "showcase_selections.exr")
    beauty = np.asarray(found["rgba"].channels["RGBA"].pixels, np.float64)[..., :3]
    flat, curved = colour(found["flat"], "flat"), colour(found["curved"], "curved")
    assert flat.sum() > 0 and curved.sum() > 0 and (flat + curved).sum() <= beauty.sum() * (1 + 1e-6)
