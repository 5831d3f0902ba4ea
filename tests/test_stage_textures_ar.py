"""stage/textures: textures read through USD's asset resolver (members of .usdz packages).

The reference for a package member is the same member taken out with Python's zipfile and
decoded by OIIO from a plain file: the pixels must be identical, bit for bit.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import zipfile

import numpy as np
import OpenImageIO as oiio
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade

from pxr_layers.scene import FLOAT
from pxr_layers.stage import load_stage
from pxr_layers.stage import textures as textures_module
from pxr_layers.stage.diagnostics import Diagnostics
from pxr_layers.stage.textures import TextureLibrary
from pxr_layers.trace.texture_cache import decoded

USDZ_ASSETS = [  # under ../shared/scenes (the shared_scenes fixture)
    "usd-wg/test_assets/RoughnessTest/RoughnessTest.usdz",
    "usd-wg/test_assets/USDZ/AnimatedCube/AnimatedCube.usdz",
    "usd-wg/test_assets/NormalsTextureBiasAndScale/NormalsTextureBiasAndScale.usdz",
]
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tga", ".exr", ".tif", ".tiff", ".hdr")


def image_members(package: str) -> list[str]:
    with zipfile.ZipFile(package) as archive:
        return [name for name in archive.namelist() if name.lower().endswith(IMAGE_EXTENSIONS)]


def member_path(package: str, member: str) -> str:
    """The resolved path USD gives a package member (Sdf.AssetPath.resolvedPath)."""
    return f"{package}[{member}]"


def decode_plain_file(path: str) -> np.ndarray:
    """(h, w, c) float32 as stored, read by OIIO from a plain file with the reader's settings."""
    config = oiio.ImageSpec()
    config.attribute("oiio:UnassociatedAlpha", 1)
    image_input = oiio.ImageInput.open(path, config)
    assert image_input is not None, oiio.geterror()
    spec = image_input.spec()
    pixels = image_input.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
    image_input.close()
    return np.asarray(pixels, dtype=FLOAT).reshape(spec.height, spec.width, spec.nchannels)


def as_raw(stored: np.ndarray) -> np.ndarray:
    """Raw values as the library stores them: the file's channels, up to four (textures.py)."""
    return np.asarray(stored[..., :4], dtype=FLOAT)


def extracted(package: str, member: str, folder) -> str:
    with zipfile.ZipFile(package) as archive:
        return archive.extract(member, str(folder))


@pytest.fixture
def usdz_asset(request, shared_scenes):
    return str(shared_scenes / request.param)


@pytest.fixture
def private_temp_dir(tmp_path, monkeypatch):
    """Where the reader's temporary files go during the test, to check they are all deleted."""
    folder = tmp_path / "tempdir"
    folder.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(folder))
    return folder


@pytest.fixture(autouse=True)
def forget_remembered_textures(monkeypatch):
    """Each test starts with no textures remembered from an earlier read."""
    monkeypatch.setattr(textures_module, "_REMEMBERED", {})


@pytest.mark.parametrize("usdz_asset", USDZ_ASSETS, indirect=True, ids=os.path.basename)
def test_package_members_decode_like_the_extracted_file(usdz_asset, tmp_path, private_temp_dir):
    members = image_members(usdz_asset)
    assert members
    diagnostics = Diagnostics()
    library = TextureLibrary(diagnostics)
    for member in members:
        loaded = library.load(member_path(usdz_asset, member), "raw", "/Material/Texture")
        assert loaded is not None, member
        image = library.images[loaded.index]
        assert image.path == member_path(usdz_asset, member)
        plain = extracted(usdz_asset, member, tmp_path / "extracted")
        np.testing.assert_array_equal(image.pixels, as_raw(decode_plain_file(plain)))
        # The whole decoding (colour space, wrap metadata) matches the plain file's too.
        from_plain = library.load(plain, "auto", "/Material/Texture")
        from_package = library.load(member_path(usdz_asset, member), "auto", "/Material/Texture")
        np.testing.assert_array_equal(library.images[from_package.index].pixels,
                                      decoded(library.images[from_plain.index]))
        assert from_package.wrap_modes == from_plain.wrap_modes
    assert diagnostics.finish() == ()
    assert list(private_temp_dir.iterdir()) == []  # every temporary file deleted


def test_members_are_remembered_by_package_identity_and_name(tmp_path, shared_scenes):
    package = str(shared_scenes / USDZ_ASSETS[0])
    copy = str(tmp_path / "copy.usdz")
    shutil.copy(package, copy)
    first_member, second_member = image_members(copy)[:2]

    first_read = TextureLibrary(Diagnostics())
    first = first_read.load(member_path(copy, first_member), "raw", "/T")
    first_read.load(member_path(copy, second_member), "raw", "/T")
    first_read.remember()

    next_read = TextureLibrary(Diagnostics())
    again = next_read.load(member_path(copy, first_member), "raw", "/T")
    other = next_read.load(member_path(copy, second_member), "raw", "/T")
    assert next_read.images[again.index].pixels is first_read.images[first.index].pixels
    assert next_read.images[other.index].pixels is not next_read.images[again.index].pixels
    next_read.remember()

    stat = os.stat(copy)
    os.utime(copy, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1_000_000_000))  # the package changed
    changed_read = TextureLibrary(Diagnostics())
    reread = changed_read.load(member_path(copy, first_member), "raw", "/T")
    assert changed_read.images[reread.index].pixels is not first_read.images[first.index].pixels
    np.testing.assert_array_equal(changed_read.images[reread.index].pixels, first_read.images[first.index].pixels)


def write_package(path: str, files: dict[str, bytes], folder) -> None:
    """A .usdz holding ``files`` (name → bytes), written by Sdf's own package writer."""
    writer = Sdf.ZipFileWriter.CreateNew(path)
    for name, contents in files.items():
        source = folder / name
        source.parent.mkdir(parents=True, exist_ok=True)
        source.write_bytes(contents)
        writer.AddFile(str(source), name)
    writer.Save()


def test_an_undecodable_member_warns_uses_the_fallback_and_leaves_no_file(tmp_path, private_temp_dir):
    package = str(tmp_path / "broken.usdz")
    write_package(package, {"scene.usda": b"#usda 1.0\n", "maps/broken.png": b"not a png at all"}, tmp_path / "src")
    diagnostics = Diagnostics()
    library = TextureLibrary(diagnostics)
    assert library.load(member_path(package, "maps/broken.png"), "auto", "/Looks/Tex") is None
    warnings = diagnostics.finish()
    assert len(warnings) == 1
    assert member_path(package, "maps/broken.png") in warnings[0] and "fallback" in warnings[0]
    assert str(private_temp_dir) not in warnings[0]  # the warning names the asset, not the temp file
    assert list(private_temp_dir.iterdir()) == []


def test_a_missing_member_is_reported_with_the_fallback(tmp_path):
    """A member the package lacks does not resolve: materials.py warns and uses the fallback."""
    package = str(tmp_path / "pkg.usdz")
    write_package(package, {"scene.usda": b"#usda 1.0\n"}, tmp_path / "src")
    stage = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    UsdGeom.Camera.Define(stage, "/Camera")
    texture = textured_quad(stage, "./pkg.usdz[maps/missing.png]")
    texture.CreateInput("fallback", Sdf.ValueTypeNames.Float4).Set((0.25, 0.5, 0.75, 1.0))
    stage.GetRootLayer().Save()
    scene, _ = load_stage(stage.GetRootLayer().realPath, camera="/Camera")
    assert scene.textures == ()
    assert any("missing.png" in warning and "fallback" in warning for warning in scene.warnings)


def textured_quad(stage: Usd.Stage, file: str) -> UsdShade.Shader:
    """A quad whose diffuseColor reads UsdUVTexture ``file``; returns the texture shader."""
    mesh = UsdGeom.Mesh.Define(stage, "/Quad")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    material = UsdShade.Material.Define(stage, "/Looks/Textured")
    surface = UsdShade.Shader.Define(stage, "/Looks/Textured/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    material.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    texture = UsdShade.Shader.Define(stage, "/Looks/Textured/Texture")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    rgb = texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(rgb)
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)
    return texture


# NormalsTextureBiasAndScale's textures feed only UsdPreviewSurface 'normal', which the reader
# does not support (it warns): no texture of it reaches SceneData, so it is checked above only.
@pytest.mark.parametrize("usdz_asset", USDZ_ASSETS[:2], indirect=True, ids=os.path.basename)
def test_a_stage_over_the_package_gets_its_real_textures(usdz_asset, tmp_path, private_temp_dir):
    """The package's own materials, read by load_stage (the package sublayered under a shot
    that adds a camera): every texture is the member's image, none falls back."""
    stage = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    stage.GetRootLayer().subLayerPaths.append(usdz_asset)
    UsdGeom.Camera.Define(stage, "/PxrLayersTestCamera")
    stage.GetRootLayer().Save()

    scene, _ = load_stage(stage.GetRootLayer().realPath, camera="/PxrLayersTestCamera")

    assert not [warning for warning in scene.warnings if "texture" in warning]
    assert scene.textures
    for image in scene.textures:
        package, member = image.path[:-1].split("[", 1)
        assert package == usdz_asset
        plain = extracted(usdz_asset, member, tmp_path / "extracted")
        library = TextureLibrary(Diagnostics())
        reference = decoded(library.images[library.load(plain, "raw", "/T").index])
        srgb = decoded(library.images[library.load(plain, "sRGB", "/T").index])
        # The material chose the colour space; either way the pixels are the member's.
        assert np.array_equal(image.pixels, reference) or np.array_equal(image.pixels, srgb)
    used = {image.path for image in scene.textures}
    assert used <= {member_path(usdz_asset, member) for member in image_members(usdz_asset)}
    assert list(private_temp_dir.iterdir()) == []
