"""The inspector's working state on the server (view/document.py, PUT /api/document): kept
beside the render, given back by /api/session and by a new session on the folder, layers made
on the page extracted again; anything that is not a document refused in one line, the file
left as it was; a file on disk that is not one read as none, with a warning."""

from __future__ import annotations

import copy
import json
import logging

import numpy as np
import pytest
from test_view_server import folder, server  # noqa: F401  (the fixtures: a Cornell render, its server)

from pxr_layers.view.document import SUFFIX
from pxr_layers.view.session import Session


def entry(source: str, name: str | None = None, **grade) -> dict:
    return {"id": name or source, "source": source, "name": name or source, "kind": "beauty" if source == "beauty" else "layer",
            "expression": "", "group": "", "note": "", "stops": 0.0, "tint": [1.0, 1.0, 1.0], "kelvin": None,
            "mute": False, "solo": False, "mask": None, **grade}


def document(*entries: dict, **fields) -> dict:
    return {"format": 1, "exposure": 0.5, "entries": [entry("beauty"), *entries], "snapshots": [], "saved": None,
            "view": {"fit": True, "scale": 1, "cx": 0.5, "cy": 0.5},
            "compare": {"mode": "wipe", "against": "beauty", "wipe": 0.25}, "denoised": False, "display_view": None,
            **fields}


def test_the_document_is_kept_and_given_back(server, folder):  # noqa: F811
    layers = [layer["id"] for layer in server.json("/api/session")["layers"] if layer["kind"] == "layer"]
    made = server.json("/api/layer", {"name": "red_wall", "expression": "C<RD'redWall'>.*"})
    kept = document(entry(layers[0], stops=1.5, tint=[1, 0.5, 0.25], kelvin=4000, group="key"),
                    entry(layers[0], "copy_of_it", mute=True),
                    {**entry("red_wall"), "expression": made["expression"], "note": "the red wall's light"},
                    snapshots=[{"name": "snapshot 1", "exposure": 0.0, "entries": [entry(layers[1], solo=True)]}])
    status, body, _ = server.request("/api/document", kept, method="PUT")
    assert status == 200, body
    title = server.json("/api/session")["title"]
    path = folder / f"{title}{SUFFIX}"
    assert json.loads(path.read_text()) == kept == server.json("/api/session")["document"]

    again = Session.open(folder)  # the view opened again: red_wall was made on the page
    assert again.document == kept
    np.testing.assert_array_equal(again.layers["red_wall"].image, server_image(server, "red_wall"))


def server_image(server, layer_id: str) -> np.ndarray:
    status, body, headers = server.request(f"/api/image/{layer_id}")
    assert status == 200
    return np.frombuffer(body, "<f4").reshape(int(headers["X-Height"]), int(headers["X-Width"]), 3)


BAD = {
    "a missing field": (lambda d: d.pop("compare"), "the document: an object with exactly"),
    "another field": (lambda d: d.update(extra=1), "the document: an object with exactly"),
    "another format": (lambda d: d.update(format=2), "format 2"),
    "a tint of two": (lambda d: d["entries"][1].update(tint=[1, 1]), "entries[1].tint"),
    "a negative tint": (lambda d: d["entries"][1].update(tint=[1, -1, 1]), "entries[1].tint"),
    "a kelvin of 10": (lambda d: d["entries"][1].update(kelvin=10), "entries[1].kelvin"),
    "stops of 1e9": (lambda d: d["entries"][1].update(stops=1e9), "entries[1].stops"),
    "a mute of 1": (lambda d: d["entries"][1].update(mute=1), "entries[1].mute"),
    "the beauty second": (lambda d: d["entries"].reverse(), "entries: the beauty first"),
    "two entries of one name": (lambda d: d["entries"].append(copy.deepcopy(d["entries"][1])), "a second entry"),
    "a name with a space": (lambda d: d["entries"][1].update(name="a b"), "entries[1].name"),
    "a control character": (lambda d: d["entries"][1].update(group="a\x00b"), "entries[1].group"),
    "300 entries": (lambda d: d["entries"].extend(copy.deepcopy(d["entries"][1]) for _ in range(300)), "a list of at most 256"),
    "a compare mode": (lambda d: d["compare"].update(mode="blend"), "compare.mode"),
    "a wipe of 2": (lambda d: d["compare"].update(wipe=2), "compare.wipe"),
    "a scale of 0": (lambda d: d["view"].update(scale=0), "view.scale"),
    "a snapshot without entries": (lambda d: d["snapshots"].append({"name": "s", "exposure": 0}), "snapshots[0]"),
}


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_what_is_not_a_document_is_refused_in_one_line(server, folder, case):  # noqa: F811
    change, message = BAD[case]
    layer = next(layer["id"] for layer in server.json("/api/session")["layers"] if layer["kind"] == "layer")
    before = {path.name: path.read_bytes() for path in folder.glob(f"*{SUFFIX}")}
    bad = document(entry(layer))
    change(bad)
    status, body, _ = server.request("/api/document", bad, method="PUT")
    error = json.loads(body)["error"]
    assert status == 400 and message in error and "\n" not in error, (status, error)
    assert {path.name: path.read_bytes() for path in folder.glob(f"*{SUFFIX}")} == before


def test_a_layer_the_session_does_not_have_is_a_404(server):  # noqa: F811
    status, body, _ = server.request("/api/document", document(entry("no_such_layer")), method="PUT")
    assert status == 404 and "no_such_layer" in json.loads(body)["error"]


def test_a_file_that_is_not_a_document_is_read_as_none_with_a_warning(folder, tmp_path, caplog):  # noqa: F811
    import shutil

    copy_of = tmp_path / "render"
    shutil.copytree(folder, copy_of)
    title = Session.open(copy_of).title
    (copy_of / f"{title}{SUFFIX}").write_text('{"format": 1, "entries": [')
    with caplog.at_level(logging.WARNING):
        session = Session.open(copy_of)
    assert session.document is None
    assert any(f"{title}{SUFFIX}: not read" in record.getMessage() for record in caplog.records)
