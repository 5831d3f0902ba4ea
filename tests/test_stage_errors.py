"""stage/: user mistakes become one-line StageErrors naming the file (and prim)."""

from __future__ import annotations

import pytest
from pxr import Usd, UsdGeom

from pxr_layers.errors import PxrLayersError, StageError
from pxr_layers.stage import load_stage

CAMERA = 'def Camera "cam" {}\n'


def write_usda(path, body: str, header: str = "") -> str:
    path.write_text(f"#usda 1.0\n({header})\n{body}")
    return str(path)


def expect_error(path, match: str, **kwargs) -> StageError:
    with pytest.raises(StageError, match=match) as caught:
        load_stage(path, **kwargs)
    error = caught.value
    assert isinstance(error, PxrLayersError)
    assert "\n" not in str(error)
    assert error.file == str(path)
    return error


def test_missing_file(tmp_path):
    expect_error(tmp_path / "absent.usda", "not found")


def test_garbage_file(tmp_path):
    garbage = tmp_path / "garbage.usda"
    garbage.write_text("this is not usd {{{")
    error = expect_error(garbage, "cannot open as USD")
    assert "garbage.usda" in str(error)


def test_file_that_is_not_usd_at_all(tmp_path):
    image = tmp_path / "picture.png"
    image.write_bytes(b"\x89PNG\r\n\x1a\n")
    expect_error(image, "cannot open as USD")


def test_missing_sublayer(tmp_path):
    path = write_usda(tmp_path / "shot.usda", CAMERA, "subLayers = [@./lighting.usda@]")
    error = expect_error(tmp_path / "shot.usda", "does not compose")
    assert "lighting.usda" in str(error) and path in str(error)


def test_missing_reference(tmp_path):
    write_usda(tmp_path / "shot.usda", CAMERA + 'def Xform "set" (references = @./set.usda@) {}\n')
    error = expect_error(tmp_path / "shot.usda", "does not compose")
    assert "set.usda" in str(error)


def test_nan_points_name_the_prim(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "bad.usda"))
    UsdGeom.Camera.Define(stage, "/cam")
    mesh = UsdGeom.Mesh.Define(stage, "/World/broken")
    mesh.CreatePointsAttr([(0, 0, 0), (float("nan"), 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    stage.GetRootLayer().Save()
    error = expect_error(tmp_path / "bad.usda", "NaN or infinite")
    assert error.prim == "/World/broken" and "/World/broken" in str(error)


def test_inconsistent_topology_names_the_prim(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "bad.usda"))
    UsdGeom.Camera.Define(stage, "/cam")
    mesh = UsdGeom.Mesh.Define(stage, "/torn")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 7])
    stage.GetRootLayer().Save()
    assert expect_error(tmp_path / "bad.usda", "faceVertexIndices").prim == "/torn"


def test_no_camera_names_the_file(tmp_path):
    write_usda(tmp_path / "empty.usda", 'def Xform "world" {}\n')
    expect_error(tmp_path / "empty.usda", "no camera")
