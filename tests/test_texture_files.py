"""Image files' headers (texture_files.read_header): a JPEG's read from its markers must say
exactly what OpenImageIO's own open says, and any file that reading does not vouch for
must behave as OIIO makes it behave."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from pxr_layers import texture_files
from pxr_layers.scene import TextureImage
from pxr_layers.texture_files import read_header, read_level
from pxr_layers.trace.texture_cache import resident_textures
from test_stage_materials import bind, load, new_stage, quad, textured_material, write_image

JPEGS = {  # name: (width, height, channels, OIIO attributes)
    "baseline.jpg": (67, 45, 3, {}),
    "progressive.jpg": (67, 45, 3, {"jpeg:progressive": 1}),
    "grey.jpg": (33, 20, 1, {}),
    "grey_progressive.jpg": (33, 20, 1, {"jpeg:progressive": 1}),
    "subsampled.jpg": (67, 45, 3, {"jpeg:subsampling": "4:2:0"}),
    "subsampled_progressive.jpg": (67, 45, 3, {"jpeg:subsampling": "4:2:0", "jpeg:progressive": 1}),
    # OIIO reports Exif orientation as metadata and never turns the image: no width for height
    "rotated.jpg": (67, 45, 3, {"Orientation": 6, "ImageDescription": "a comment segment"}),
    "wrapped.jpg": (16, 8, 3, {"wrapmodes": "periodic,clamp"}),  # OIIO keeps no wrap modes in a JPEG
    "named_as_a.png": (16, 8, 3, {}),  # a JPEG by its first bytes, whatever its name
}


def oiio_header(path: str, monkeypatch: pytest.MonkeyPatch):
    """read_header's result (a header, or the OSError's message) with OIIO alone reading."""
    with monkeypatch.context() as patch:
        patch.setattr(texture_files, "_jpeg_frame", lambda path: None)
        try:
            return read_header(path)
        except OSError as error:
            return str(error)


def our_header(path: str):
    try:
        return read_header(path)
    except OSError as error:
        return str(error)


def write_jpeg(path: Path, width: int, height: int, channels: int, attributes: dict) -> Path:
    if path.suffix != ".jpg":  # OIIO picks its writer by the name
        return write_jpeg(path.with_suffix(".jpg"), width, height, channels, attributes).rename(path)
    pixels = np.random.default_rng(7).integers(0, 256, (height, width, channels), dtype=np.uint8)
    write_image(path, pixels, oiio.UINT8, **attributes)
    return path


@pytest.fixture
def jpegs(tmp_path) -> dict[str, Path]:
    return {name: write_jpeg(tmp_path / name, *shape) for name, shape in JPEGS.items()}


def scan_end(data: bytes) -> int:
    """Where the first scan's coded data begins: the end of its SOS segment."""
    at = 2
    while data[at + 1] != 0xDA:
        at += 2 + int.from_bytes(data[at + 2:at + 4])
    return at + 2 + int.from_bytes(data[at + 2:at + 4])


@pytest.mark.parametrize("name", JPEGS)
def test_a_jpeg_header_is_read_from_its_markers_as_oiio_reads_it(jpegs, name, monkeypatch):
    path = str(jpegs[name])
    assert texture_files._jpeg_frame(path) is not None  # the markers were read, not OIIO
    width, height, channels, _ = JPEGS[name]
    assert our_header(path) == oiio_header(path, monkeypatch)
    assert our_header(path) == texture_files.TextureHeader(width, height, channels, "uint8", 1, (None, None))


def test_the_chess_sets_jpegs_read_as_oiio_reads_them(shared_scenes, monkeypatch):
    paths = sorted((shared_scenes / "usd-wg" / "full_assets" / "OpenChessSet").rglob("*.jpg"))
    assert paths
    for path in map(str, paths):
        assert texture_files._jpeg_frame(path) is not None, path
        assert our_header(path) == oiio_header(path, monkeypatch), path


def test_files_that_are_no_jpeg_are_left_to_oiio(tmp_path, monkeypatch):
    png = write_image(tmp_path / "named_as_a.jpg.png", np.zeros((4, 6, 3), np.uint8), oiio.UINT8)
    Path(png).rename(tmp_path / "named_as_a.jpg")
    (tmp_path / "empty.jpg").write_bytes(b"")
    (tmp_path / "soi.jpg").write_bytes(b"\xff\xd8")
    for name in ("named_as_a.jpg", "empty.jpg", "soi.jpg", "missing.jpg"):
        path = str(tmp_path / name)
        assert texture_files._jpeg_frame(path) is None
        assert our_header(path) == oiio_header(path, monkeypatch)
    assert our_header(str(tmp_path / "named_as_a.jpg")).width == 6


@pytest.mark.parametrize("name", ["baseline.jpg", "progressive.jpg", "grey_progressive.jpg"])
def test_a_jpeg_cut_anywhere_in_its_header_or_changed_in_one_byte_reads_as_with_oiio(jpegs, name, tmp_path,
                                                                                   monkeypatch):
    """Every truncation up to a little into the coded data, and three changes of every byte
    before it: the header or the OSError OIIO's open gives. (Past the header OIIO opens a
    truncated file, its missing rows read as grey.)"""
    data = jpegs[name].read_bytes()
    end = scan_end(data)
    variants = [data[:cut] for cut in range(end + 8)]
    variants += [data[:at] + bytes([value]) + data[at + 1:] for at in range(2, end)
                 for value in {0x00, 0xFF, data[at] ^ 0x01, data[at] ^ 0x10} - {data[at]}]
    path = str(tmp_path / "variant.jpg")
    read_by_markers = 0
    for variant in variants:
        Path(path).write_bytes(variant)
        read_by_markers += texture_files._jpeg_frame(path) is not None
        assert our_header(path) == oiio_header(path, monkeypatch), variant
    assert read_by_markers > len(variants) // 2  # not all handed to OIIO


def test_a_truncated_jpeg_is_one_warning_naming_it_and_its_fallback(jpegs, tmp_path):
    data = jpegs["progressive.jpg"].read_bytes()
    (tmp_path / "cut.jpg").write_bytes(data[:scan_end(data) - 20])
    stage = new_stage(tmp_path)
    bind(quad(stage), textured_material(stage, "/Looks/m", "cut.jpg", fallback=(0.25, 0.5, 1.0, 1.0)))
    scene, _ = load(stage)
    assert scene.textures == ()
    (warning,) = [w for w in scene.warnings if "cut.jpg" in w]
    assert warning.startswith(f"cannot read texture {tmp_path / 'cut.jpg'} (used by /Looks/m/Texture): ")
    assert "Premature end of JPEG file" in warning and warning.endswith("using the fallback value instead")


@pytest.mark.parametrize("name", ["baseline.jpg", "progressive.jpg", "grey.jpg"])
def test_the_tracer_decodes_a_jpeg_read_by_its_markers_through_oiio(jpegs, name):
    path = str(jpegs[name])
    image = TextureImage(path, None, read_header(path), "raw", "/World/look/tex")
    resident = resident_textures([image])
    np.testing.assert_array_equal(resident.finest_linear(0), read_level(path, 0, "float")[1])
