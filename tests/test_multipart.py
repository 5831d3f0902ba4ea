"""The deliverable: multipart EXR read back with OpenEXR and OpenImageIO; OCIO previews; contact sheet."""

from __future__ import annotations

import json

import numpy as np
import OpenEXR
import OpenImageIO as oiio
import pytest

from pxr_layers import __version__
from pxr_layers.errors import OutputError, RecipeError
from pxr_layers.layers.exr import REC709_CHROMATICITIES
from pxr_layers.layers.multipart import read_multipart, write_multipart
from pxr_layers.layers.previews import (
    PARTITION_TOLERANCE,
    check_colour_settings,
    display_processor,
    energy_shares,
    layers_partition,
    to_display,
    write_contact_sheet,
    write_png,
    write_previews,
)
from pxr_layers.recipe import DEFAULT_OCIO_CONFIG, Layer, Product, Recipe

HEIGHT, WIDTH = 24, 40


@pytest.fixture
def delivery(rng):
    """A beauty split exactly into two colour layers, plus half, depth and normal layers."""
    diffuse = rng.random((HEIGHT, WIDTH, 3), dtype=np.float32) * 2
    glossy = rng.random((HEIGHT, WIDTH, 3), dtype=np.float32)
    beauty = np.concatenate([diffuse + glossy, np.ones((HEIGHT, WIDTH, 1), np.float32)], axis=2)
    normal = rng.normal(size=(HEIGHT, WIDTH, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    images = {
        "diffuse": diffuse,
        "glossy": glossy,
        "key_half": glossy * 0.5,
        "depth": rng.random((HEIGHT, WIDTH), dtype=np.float32) * 10,
        "normal": normal,
    }
    product = Product(
        "beauty", "shot.exr", "/cam", (WIDTH, HEIGHT),
        (
            Layer("diffuse", "lpe", "C<RD>.*", group="passes", exposure=1.0),
            Layer("glossy", "lpe", "C<R[^D]>.*", group="passes", tint=(1.0, 0.5, 0.5)),
            Layer("key_half", "lpe", "C.*<L.'key'>", pixel_type="half", compression="dwaa", group="lights"),
            Layer("depth", "raw", "depth", data_type="float", compression="piz", group="data"),
            Layer("normal", "raw", "normal", data_type="normal3f", group="data", preview=False),
        ),
    )
    return beauty, images, product


def test_parts_channels_types_and_metadata_read_back_with_openexr(tmp_path, delivery):
    beauty, images, product = delivery
    recipe = Recipe((product,), settings_path="/Render/Settings")
    path = write_multipart(tmp_path / "shot.exr", beauty, images, product, recipe=recipe,
                           spp=16, seed=3, frame=1001, metadata={"stage": "shot.usda"})
    exr = OpenEXR.File(str(path), separate_channels=True)
    assert [part.name() for part in exr.parts] == ["rgba", "diffuse", "glossy", "key_half", "depth", "normal"]
    expected_channels = [
        {"R", "G", "B", "A"}, {"diffuse.R", "diffuse.G", "diffuse.B"}, {"glossy.R", "glossy.G", "glossy.B"},
        {"key_half.R", "key_half.G", "key_half.B"}, {"depth.Z"}, {"normal.X", "normal.Y", "normal.Z"},
    ]
    assert [set(part.channels) for part in exr.parts] == expected_channels
    windows = {tuple(map(tuple, part.header["dataWindow"])) for part in exr.parts}
    assert windows == {((0, 0), (WIDTH - 1, HEIGHT - 1))}
    for part in exr.parts:
        np.testing.assert_allclose(part.header["chromaticities"], REC709_CHROMATICITIES, rtol=1e-6)
        assert "view" not in part.header and "multiView" not in part.header
        assert part.header["pxrLayers/version"] == __version__
        assert part.header["pxrLayers/stage"] == "shot.usda"
        assert (part.header["pxrLayers/spp"], part.header["pxrLayers/seed"], part.header["pxrLayers/frame"]) == (
            "16", "3", "1001")
    rgba, diffuse, glossy, key_half, depth, normal = exr.parts
    # pixel types and compressions from the recipe
    assert {part.channels[name].pixels.dtype for part in exr.parts[:3] for name in part.channels} == {np.dtype(np.float32)}
    assert {c.pixels.dtype for c in key_half.channels.values()} == {np.dtype(np.float16)}
    assert key_half.header["compression"] == OpenEXR.DWAA_COMPRESSION
    assert depth.header["compression"] == OpenEXR.PIZ_COMPRESSION
    assert rgba.header["compression"] == OpenEXR.ZIP_COMPRESSION
    # float parts are exact, so the layers still add up to the beauty
    for index, channel in enumerate("RGBA"):
        np.testing.assert_array_equal(rgba.channels[channel].pixels, beauty[..., index])
    for index, channel in enumerate("RGB"):
        np.testing.assert_array_equal(diffuse.channels[f"diffuse.{channel}"].pixels, images["diffuse"][..., index])
        np.testing.assert_array_equal(
            diffuse.channels[f"diffuse.{channel}"].pixels + glossy.channels[f"glossy.{channel}"].pixels,
            beauty[..., index],
        )
    np.testing.assert_array_equal(depth.channels["depth.Z"].pixels, images["depth"])
    np.testing.assert_array_equal(normal.channels["normal.Y"].pixels, images["normal"][..., 1])
    np.testing.assert_allclose(key_half.channels["key_half.R"].pixels, images["key_half"][..., 0], atol=0.02)  # DWAA: lossy
    # metadata: expressions, sources, the recipe
    assert rgba.header["pxrLayers/expression"] == "C.*"
    assert diffuse.header["pxrLayers/expression"] == "C<RD>.*"
    assert key_half.header["pxrLayers/group"] == "lights"
    assert depth.header["pxrLayers/sourceType"] == "raw" and depth.header["pxrLayers/source"] == "depth"
    assert json.loads(rgba.header["pxrLayers/expressions"]) == product.expressions()
    assert rgba.header["pxrLayers/recipe"] == recipe.to_json()


def test_the_file_reads_in_openimageio_as_a_compositor_sees_it(tmp_path, delivery):
    beauty, images, product = delivery
    path = write_multipart(tmp_path / "shot.exr", beauty, images, product, metadata={"spp": 16})
    found = []
    reader = oiio.ImageInput.open(str(path))
    try:
        subimage = 0
        while reader.seek_subimage(subimage, 0):
            spec = reader.spec()
            found.append((spec.getattribute("name"), spec.channelnames, (spec.width, spec.height),
                          str(spec.channelformat(0)), spec.getattribute("pxrLayers/spp")))
            subimage += 1
    finally:
        reader.close()
    assert found == [
        ("rgba", ("R", "G", "B", "A"), (WIDTH, HEIGHT), "float", "16"),
        ("diffuse", ("diffuse.R", "diffuse.G", "diffuse.B"), (WIDTH, HEIGHT), "float", "16"),
        ("glossy", ("glossy.R", "glossy.G", "glossy.B"), (WIDTH, HEIGHT), "float", "16"),
        ("key_half", ("key_half.R", "key_half.G", "key_half.B"), (WIDTH, HEIGHT), "half", "16"),
        ("depth", ("depth.Z",), (WIDTH, HEIGHT), "float", "16"),
        ("normal", ("normal.X", "normal.Y", "normal.Z"), (WIDTH, HEIGHT), "float", "16"),
    ]
    glossy = oiio.ImageBuf(str(path), 2, 0).get_pixels(oiio.FLOAT)
    np.testing.assert_array_equal(glossy, images["glossy"])


def test_without_a_product_defaults_apply(tmp_path, rng):
    beauty = rng.random((HEIGHT, WIDTH, 4), dtype=np.float32)
    layers = {"a": rng.random((HEIGHT, WIDTH, 3), dtype=np.float32), "depth": np.ones((HEIGHT, WIDTH), np.float32)}
    exr = OpenEXR.File(str(write_multipart(tmp_path / "x.exr", beauty, layers)), separate_channels=True)
    assert [(p.name(), sorted(p.channels)) for p in exr.parts] == [
        ("rgba", ["A", "B", "G", "R"]), ("a", ["a.B", "a.G", "a.R"]), ("depth", ["depth.Z"])]


def test_strided_inputs_are_written_correctly(tmp_path, rng):
    # The OpenEXR binding ignores numpy strides: the writer must hand it contiguous planes.
    planar = rng.random((3, HEIGHT, WIDTH), dtype=np.float32)
    layer = np.moveaxis(planar, 0, 2)  # (h, w, 3) view, not contiguous
    beauty = np.asfortranarray(rng.random((HEIGHT, WIDTH, 4), dtype=np.float32))
    exr = OpenEXR.File(str(write_multipart(tmp_path / "x.exr", beauty, {"a": layer})), separate_channels=True)
    np.testing.assert_array_equal(exr.parts[1].channels["a.G"].pixels, planar[1])
    np.testing.assert_array_equal(exr.parts[0].channels["B"].pixels, beauty[..., 2])


def test_half_parts_clamp_to_the_half_range(tmp_path, rng):
    beauty = np.full((2, 3, 4), 1e6, np.float32)
    product = Product("p", "p.exr", "/cam", (3, 2), (Layer("a", pixel_type="half"),), pixel_type="half")
    exr = OpenEXR.File(str(write_multipart(tmp_path / "x.exr", beauty, {"a": -beauty[..., :3]}, product)),
                       separate_channels=True)
    assert exr.parts[0].channels["R"].pixels.dtype == np.float16
    assert (exr.parts[0].channels["R"].pixels == np.float16(65504)).all()
    assert (exr.parts[1].channels["a.G"].pixels == np.float16(-65504)).all()


def test_bad_inputs_are_refused_and_leave_no_file(tmp_path, delivery):
    beauty, images, product = delivery
    target = tmp_path / "shot.exr"
    with pytest.raises(ValueError, match=r"beauty must be \(h, w, 4\)"):
        write_multipart(target, beauty[..., :3], images, product)
    with pytest.raises(ValueError, match="missing normal"):
        write_multipart(target, beauty, {k: v for k, v in images.items() if k != "normal"}, product)
    with pytest.raises(ValueError, match="not in the recipe extra"):
        write_multipart(target, beauty, {**images, "extra": images["glossy"]}, product)
    with pytest.raises(ValueError, match=r"layer 'depth': expected shape \(24, 40, 1\)"):
        write_multipart(target, beauty, {**images, "depth": images["normal"]}, product)
    assert list(tmp_path.iterdir()) == []
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OutputError, match="file: is a file, not a folder"):
        write_multipart(blocker / "shot.exr", beauty, images, product)


# --- previews ---------------------------------------------------------------------------


def test_previews_have_the_image_size_and_are_not_blank(tmp_path, delivery):
    beauty, images, product = delivery
    written = write_previews(tmp_path, "shot.1001", beauty, images, product)
    # normal has preview off; the contact sheet is written by default
    assert set(written) == {"rgba", "diffuse", "glossy", "key_half", "depth", "contact"}
    for name, path in written.items():
        assert path.name == f"shot.1001.{'contact' if name == 'contact' else name}.png"
        pixels = oiio.ImageBuf(str(path)).get_pixels(oiio.UINT8)
        if name != "contact":
            assert pixels.shape == (HEIGHT, WIDTH, 3)
        assert pixels.std() > 5, name
    assert not list(tmp_path.glob("*.tmp*"))


def test_display_transform_is_the_pinned_ocio_view_and_applies_the_grade(delivery):
    _beauty, images, product = delivery
    rgb = images["diffuse"]
    reference = oiio.ImageBufAlgo.ociodisplay(
        oiio.ImageBuf(np.ascontiguousarray(rgb)), product.display, product.view, fromspace=product.rendering_space,
        unpremult=False, colorconfig=DEFAULT_OCIO_CONFIG,
    ).get_pixels(oiio.FLOAT)
    shown = to_display(rgb, display_processor())
    assert np.abs(shown.astype(np.float32) - np.clip(reference, 0, 1) * 255).max() <= 0.51  # quantisation only
    brighter = to_display(rgb, display_processor(), exposure=1.0)
    np.testing.assert_array_equal(brighter, to_display(rgb * 2, display_processor()))
    assert to_display(rgb, None, tint=(1, 0, 0))[..., 1:].max() < shown[..., 1:].max()
    assert to_display(np.full((2, 2, 3), np.nan, np.float32)).max() == to_display(np.zeros((2, 2, 3), np.float32)).max()


def test_contact_sheet_lists_every_layer_with_its_energy_share(tmp_path, delivery):
    beauty, images, product = delivery
    shares = energy_shares(beauty, images, {layer.name: layer for layer in product.layers})
    assert shares["diffuse"] + shares["glossy"] == pytest.approx(1.0, rel=1e-6)
    assert shares["depth"] is None and shares["normal"] is None
    path = write_contact_sheet(tmp_path / "contact.png", beauty, images, product, tile_width=32, columns=3)
    sheet = oiio.ImageBuf(str(path)).get_pixels(oiio.UINT8)
    # beauty + 5 layers in 3 columns: 2 rows of 32 x 19 tiles with their labels
    assert sheet.shape == (6 + 2 * (19 + 38 + 6), 6 + 3 * (32 + 6), 3)
    label_band = sheet[6 + 19 : 6 + 19 + 38, 6 : 6 + 32]
    assert (label_band > 150).sum() > 20  # the text is drawn


def test_colour_settings_are_checked():
    check_colour_settings()
    with pytest.raises(RecipeError, match="display 'Nope' is not in") as caught:
        check_colour_settings(display="Nope")
    assert caught.value.setting == "display"
    with pytest.raises(RecipeError, match="colour space 'lin_nope'"):
        check_colour_settings(rendering_space="lin_nope")
    check_colour_settings(rendering_space="lin_rec709_srgb")  # an alias of the default


def test_a_png_keeps_its_description(tmp_path):
    """Debug images say what they show (quantity, units, ramp) in the PNG's ImageDescription."""
    import OpenImageIO as oiio

    path = write_png(tmp_path / "c.png", np.full((4, 5, 3), 7, np.uint8), "C in 1/m; ramp 0..2")
    image = oiio.ImageInput.open(str(path))
    try:
        assert image.spec().getattribute("ImageDescription") == "C in 1/m; ramp 0..2"
        assert (image.spec().width, image.spec().height, image.spec().nchannels) == (5, 4, 3)
    finally:
        image.close()


def test_read_multipart_gives_back_what_was_written(tmp_path, delivery):
    beauty, images, product = delivery
    recipe = Recipe((product,), settings_path="/Render/Settings")
    read = read_multipart(write_multipart(tmp_path / "shot.exr", beauty, images, product, recipe=recipe))
    np.testing.assert_array_equal(read.beauty, beauty)
    assert list(read.parts) == list(images)
    for name, image in images.items():
        expected = np.asarray(image, np.float32).reshape(read.parts[name].shape)
        if name == "key_half":  # half, DWAA: lossy on noise
            assert np.abs(read.parts[name] - expected).mean() < 0.005
        else:
            np.testing.assert_array_equal(read.parts[name], expected)
    assert read.metadata["key_half"]["expression"] == "C.*<L.'key'>"
    assert read.recipe == recipe


def test_read_multipart_names_a_file_it_cannot_read(tmp_path):
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"not an exr")
    with pytest.raises(OutputError, match="bad.exr"):
        read_multipart(bad)


def _damaged_cryptomatte(tmp_path, change):
    """A product with a Cryptomatte layer, rewritten with ``change(header, channels)`` applied
    to its Cryptomatte part."""
    from pxr_layers.layers.cryptomatte import Cryptomatte, manifest

    height, width = 4, 5
    table = manifest(["/World/a", "/World/b"])
    matte = Cryptomatte(np.zeros((height, width, 2), np.float32), np.zeros((height, width, 2), np.float32), table)
    product = Product("mattes", "mattes.exr", "/camera", (width, height),
                      (Layer("CryptoObject", "raw", "CryptoObject", data_type="float4", preview=False),))
    path = write_multipart(tmp_path / "mattes.exr", np.zeros((height, width, 4), np.float32),
                           {"CryptoObject": matte}, product)
    assert read_multipart(path).cryptomattes["CryptoObject"].manifest == table
    exr = OpenEXR.File(str(path), separate_channels=True)
    part = exr.parts[1]
    header, channels = dict(part.header), {name: channel.pixels for name, channel in part.channels.items()}
    change(header, channels)
    OpenEXR.File([OpenEXR.Part(dict(exr.parts[0].header), {c: exr.parts[0].channels[c].pixels for c in "RGBA"},
                               "rgba"), OpenEXR.Part(header, channels, part.name())]).write(str(path))
    return path


def test_read_multipart_names_the_file_of_a_damaged_cryptomatte_manifest(tmp_path):
    def damage(header, channels):
        key = next(key for key in header if key.endswith("/manifest"))
        header[key] = '{"/World/a": "0'

    path = _damaged_cryptomatte(tmp_path, damage)
    with pytest.raises(OutputError, match=r"mattes\.exr: the Cryptomatte manifest of part 'CryptoObject00' is not JSON"):
        read_multipart(path)


def test_read_multipart_names_the_file_of_a_cryptomatte_part_without_a_channel(tmp_path):
    path = _damaged_cryptomatte(tmp_path, lambda header, channels: channels.pop("CryptoObject00.A"))
    with pytest.raises(OutputError, match=r"mattes\.exr: the Cryptomatte part 'CryptoObject00' has no channel "
                       r"CryptoObject00\.A"):
        read_multipart(path)


def test_colour_layers_are_the_colour_parts_as_rgb(tmp_path, delivery):
    beauty, images, product = delivery
    with_alpha = Layer("emission", "raw", "emission", data_type="color4f")
    images = {**images, "emission": np.concatenate([images["glossy"], np.ones((HEIGHT, WIDTH, 1), np.float32)], 2)}
    product = Product(product.name, product.output_name, product.camera, product.resolution,
                      (*product.layers, with_alpha))
    read = read_multipart(write_multipart(tmp_path / "shot.exr", beauty, images, product))
    colour = read.colour_layers()
    assert list(colour) == ["diffuse", "glossy", "key_half", "emission"]  # not depth, normal
    assert all(image.shape == (HEIGHT, WIDTH, 3) for image in colour.values())
    np.testing.assert_array_equal(colour["emission"], images["glossy"])


def test_layers_partition_the_beauty_within_the_tolerance_of_its_peak(delivery):
    beauty, images, _ = delivery
    layers = [images["diffuse"], images["glossy"]]
    assert layers_partition(beauty, layers)
    peak = float(beauty[..., :3].max())
    off = np.zeros_like(images["glossy"])
    off[3, 4, 1] = 2 * PARTITION_TOLERANCE * peak
    assert not layers_partition(beauty, [images["diffuse"], images["glossy"] + off])
    assert layers_partition(beauty, [images["diffuse"], images["glossy"] + off / 4])
    assert not layers_partition(beauty, [])
    assert not layers_partition(beauty, [images["diffuse"]])
