"""Denoised layer stacks (layers/denoise.py, trace/guides.py): the guides against the
materials they see, the twin product against the raw one, the stack's sum, and the error
against a many-sample reference."""

from __future__ import annotations

from importlib import resources

import numpy as np
import OpenEXR
import pytest

from pxr_layers.cli.main import main
from pxr_layers.jobs.frame import render_frame
from pxr_layers.layers.deliver import denoised_path
from pxr_layers.layers.multipart import read_multipart
from pxr_layers.recipe.presets import preset
from pxr_layers.request import RenderRequest

CORNELL = resources.files("pxr_layers.render").joinpath("cornell.usda")
RED = (0.570068, 0.0430135, 0.0443706)  # the Cornell box's red wall (render/cornell.usda)


def render(tmp_path, spp: int, resolution: int = 48, denoise: bool = True, **options):
    options.setdefault("recipe_layers", (preset("light_passes"),))
    request = RenderRequest(stage=CORNELL, resolution=(resolution, resolution),
                            spp=spp, denoise=denoise, **options)
    return render_frame(request, output=tmp_path)


@pytest.fixture(scope="module")
def denoised(tmp_path_factory):
    folder = tmp_path_factory.mktemp("denoised")
    return render(folder, spp=8, cryptomattes=("CryptoObject",))


def test_the_guides_are_the_albedo_and_normal_the_camera_sees(denoised):
    """On the red wall (the image's left columns, facing +x... toward the camera's right):
    albedo its diffuseColor, normal its own, in every sample of the pixel."""
    albedo, normal = denoised.guides
    wall = albedo[20:28, 1:4]
    np.testing.assert_allclose(wall.reshape(-1, 3), np.broadcast_to(RED, (len(wall.reshape(-1, 3)), 3)), atol=1e-5)
    facing = normal[20:28, 1:4].reshape(-1, 3)
    np.testing.assert_allclose(np.abs(facing[:, 0]), 1.0, atol=1e-4)  # the wall's normal is ±x
    assert np.all(albedo >= 0) and np.all(albedo <= 1)


def test_the_twin_has_the_products_parts_channels_and_headers(denoised):
    """A comp swaps one Read path: the twin's parts, channels, pixel types and headers are
    the raw product's (but the pxrLayers/denoised mark); its Cryptomattes are the raw ones."""
    raw_path = denoised.delivered[0].exr
    twin_path = denoised_path(raw_path)
    raw, twin = OpenEXR.File(str(raw_path)), OpenEXR.File(str(twin_path))
    assert [part.name() for part in twin.parts] == [part.name() for part in raw.parts]
    for raw_part, twin_part in zip(raw.parts, twin.parts):
        assert list(twin_part.channels) == list(raw_part.channels)
        for name, channel in raw_part.channels.items():
            assert twin_part.channels[name].pixels.dtype == channel.pixels.dtype
        raw_header, twin_header = dict(raw_part.header), dict(twin_part.header)
        assert twin_header.pop("pxrLayers/denoised").startswith("oidn inputScale=")
        assert twin_header.keys() == raw_header.keys()
        for key, value in raw_header.items():
            assert str(twin_header[key]) == str(value), key
        if raw_part.name().startswith(("CryptoObject", "denoise")):  # data and guides: as they are
            for name, channel in raw_part.channels.items():
                np.testing.assert_array_equal(twin_part.channels[name].pixels, channel.pixels)
    assert {"denoiseAlbedo", "denoiseNormal"} <= {part.name() for part in raw.parts}
    assert raw_path.with_name(raw_path.stem + ".contact.png").exists()


def test_the_denoised_stack_adds_up_to_the_denoised_beauty(denoised):
    twin = read_multipart(denoised_path(denoised.delivered[0].exr))
    beauty = twin.beauty[..., :3].astype(np.float64)
    total = sum(layer.astype(np.float64) for layer in twin.colour_layers().values())
    assert np.abs(total - beauty).max() <= 1e-5 * beauty.mean()


def relative_mse(image: np.ndarray, reference: np.ndarray) -> float:
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + 0.01)))


def test_layers_cut_later_are_denoised_with_the_renders_guides(denoised, tmp_path, capsys):
    """extract --denoise: a new layer and its twin, denoised with the guides kept in the
    render's EXR; a render without them is refused in one line."""
    index = denoised.index_path
    assert main(["extract", str(index), "--layer", "walls=C<RD>.*", "--denoise", "-o", str(tmp_path)]) == 0
    cut = tmp_path / f"{index.stem}.layers.exr"
    twin = read_multipart(denoised_path(cut))
    assert set(twin.colour_layers()) == {"walls"} and np.any(twin.colour_layers()["walls"] > 0)
    np.testing.assert_allclose(twin.parts["denoiseAlbedo"], denoised.guides[0])
    plain = render(tmp_path / "plain", spp=2, denoise=False)
    capsys.readouterr()
    assert main(["extract", str(plain.index_path), "--layer", "walls=C<RD>.*", "--denoise", "-o",
                 str(tmp_path / "refused")]) == 1
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "holds no denoising guides" in error[0]


EDGE_BOUND_LAYERS = {"emission": 2.5}
"""Layers whose error is the coverage of a light's edges seen directly (the same noise the
guides carry), and the gain they are held to instead of 4 (bench_denoise.py reports it)."""


@pytest.mark.slow
def test_denoising_lowers_the_error_of_every_noisy_layer(tmp_path):
    """At 16 spp against 1024: a layer whose relMSE is above 1e-3 is at least 4x lower once
    denoised (EDGE_BOUND_LAYERS: less), and no layer gets worse; the beauty too."""
    noisy = render(tmp_path / "noisy", spp=16, resolution=64)
    reference = read_multipart(render(tmp_path / "reference", spp=1024, resolution=64, denoise=False)
                               .delivered[0].exr)
    raw = read_multipart(noisy.delivered[0].exr)
    twin = read_multipart(denoised_path(noisy.delivered[0].exr))
    images = [(name, raw.colour_layers()[name], twin.colour_layers()[name], truth)
              for name, truth in reference.colour_layers().items()]
    images.append(("beauty", raw.beauty[..., :3], twin.beauty[..., :3], reference.beauty[..., :3]))
    checked = 0
    for name, before_image, after_image, truth in images:
        before, after = relative_mse(before_image, truth), relative_mse(after_image, truth)
        assert after <= before * 1.05, (name, before, after)
        if before > 1e-3:
            checked += 1
            assert after <= before / EDGE_BOUND_LAYERS.get(name, 4.0), (name, before, after)
    assert checked >= 3


def test_a_recipe_product_asks_for_its_denoised_twin(tmp_path):
    """pxrLayers:denoise on the RenderProduct: the twin without --denoise."""
    layer = tmp_path / "denoised_recipe.usda"
    layer.write_text('''#usda 1.0
over "Render"
{
    over "LightPasses"
    {
        over "passes" (prepend apiSchemas = ["PxrLayersProductAPI"])
        {
            uniform bool pxrLayers:denoise = 1
        }
    }
}
''')
    result = render(tmp_path, spp=2, denoise=False, recipe_layers=(layer, preset("light_passes")))
    assert result.plan.recipe.products[0].denoise and result.guides is not None
    assert denoised_path(result.delivered[0].exr).exists()


def test_the_nuke_script_of_a_denoised_render_reads_its_twin(tmp_path):
    result = render(tmp_path, spp=2, nuke_scripts=True)
    script = result.delivered[0].nuke_script.read_text()
    assert denoised_path(result.delivered[0].exr).name in script


def test_the_inspector_opens_a_denoised_render_and_saves_its_raw_stack(denoised):
    """The inspector reads the raw products and their twins' versions (a layer made from
    the index gets one too), and a saved look is the raw stack (its product not denoised)."""
    import shutil

    from pxr_layers.view.session import Session

    folder = denoised.index_path.parent
    copy = folder.parent / "inspected"
    shutil.copytree(folder, copy)
    session = Session.open(copy)
    assert "diffuse_indirect" in session.layers and not any("denoised" in name for name in session.layers)
    assert session.description()["denoised"]
    twin = read_multipart(denoised_path(denoised.delivered[0].exr)).colour_layers()["diffuse_indirect"]
    shown = np.frombuffer(session.layers["diffuse_indirect"].pixels("denoised"), "<f4").reshape(twin.shape)
    np.testing.assert_array_equal(shown, twin)
    made, _ = session.add_layer("walls", "C<RD>.*")  # made from the index: denoised as the twins were
    assert made.denoised is not None and made.denoised.shape == made.image.shape
    saved = session.save("look", [{"id": "diffuse_direct"}, {"id": "diffuse_indirect"}])
    assert (copy / saved["exr"]).exists() and not (copy / "look.denoised.exr").exists()
