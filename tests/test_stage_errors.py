"""stage/: user mistakes become one-line StageErrors naming the file (and prim)."""

from __future__ import annotations

import pytest
from pxr import Usd, UsdGeom

from pxr_layers.errors import PxrLayersError, StageError
from pxr_layers.request import RenderRequest, VariantSelection
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
    error = expect_error(tmp_path / "shot.usda", "does not compose", request=RenderRequest("x", strict=True))
    assert "lighting.usda" in str(error) and path in str(error)


def test_missing_reference(tmp_path):
    write_usda(tmp_path / "shot.usda", CAMERA + 'def Xform "set" (references = @./set.usda@) {}\n')
    error = expect_error(tmp_path / "shot.usda", "does not compose", request=RenderRequest("x", strict=True))
    assert "set.usda" in str(error)


def test_composition_errors_are_warnings_naming_file_and_prim_unless_strict(tmp_path):
    path = write_usda(tmp_path / "shot.usda", CAMERA + 'def Xform "set" (references = @./set.usda@) {}\n',
                      "subLayers = [@./lighting.usda@]")
    scene, _ = load_stage(path)
    (warning,) = [text for text in scene.warnings if "composition errors" in text]
    assert path in warning and "/set" in warning and "set.usda" in warning and "lighting.usda" in warning
    assert "--strict" in warning and "\n" not in warning


def test_inconsistent_topology_names_the_prim(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "bad.usda"))
    UsdGeom.Camera.Define(stage, "/cam")
    mesh = UsdGeom.Mesh.Define(stage, "/torn")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 7])
    stage.GetRootLayer().Save()
    assert expect_error(tmp_path / "bad.usda", "faceVertexIndices").prim == "/torn"


def test_a_bad_variant_selection_names_the_flag_prim_and_choices(tmp_path):
    path = write_usda(tmp_path / "shot.usda", CAMERA + 'def Xform "asset" (variantSets = ["look"])\n{\n'
                      '    variantSet "look" = {\n        "red" {\n        }\n        "blue" {\n        }\n    }\n}\n')
    for text, pattern in (("/nowhere:look=red", "no such prim"), ("/asset:size=big", "no variant set 'size'"),
                          ("/asset:look=green", r"no variant 'green' in look \(it has: blue, red\)")):
        error = expect_error(path, pattern, request=RenderRequest("x", variants=(VariantSelection.parse(text),)))
        assert text in str(error)
