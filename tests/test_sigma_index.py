"""The whole Σ kept in the path index, end to end through the CLI: the paper's
direction-aware query on render/striped.usda selects the stripes and not the checker of
the same texture norm; an index without Σ refuses the query with one line."""

from __future__ import annotations

import subprocess

import numpy as np
import OpenImageIO as oiio
import pytest
from test_cli import SCRIPT

from pxr_layers.paths.reader import PathIndex

DIRECTIONAL = "C<RD>@(S11 >> S22 or S22 >> S11).*"
LAYERS = {"directional": DIRECTIONAL, "stripes": "C<RD'stripes'>.*", "checker": "C<RD'checker'>.*"}


def run(*arguments):
    return subprocess.run([SCRIPT, *map(str, arguments)], capture_output=True, text=True, check=False)


def read_parts(path) -> dict[str, np.ndarray]:
    parts, image = {}, oiio.ImageInput.open(str(path))
    try:
        subimage = 0
        while image.seek_subimage(subimage, 0):
            parts[image.spec().getattribute("name") or str(subimage)] = image.read_image(format="float")
            subimage += 1
    finally:
        image.close()
    return parts


@pytest.fixture(scope="module", params=["merged", "records"])
def sigma_render(request, shipped_scene, tmp_path_factory):
    folder = tmp_path_factory.mktemp(f"sigma-{request.param}")
    result = run("render", shipped_scene("striped.usda"), "-o", folder, "--resolution", "48", "48", "--spp", "4",
                 "--index-covariance", "sigma", "--index-mode", request.param, "--norm-bounces", "2",
                 "--no-previews", "--quiet")
    assert result.returncode == 0, result.stderr
    return folder


def test_the_index_keeps_sigma(sigma_render):
    index = PathIndex(sigma_render / "striped.pxlidx")
    assert index.manifest["covariance"] == "sigma" and index.has_sigma
    chunk = next(index.records())
    assert chunk.sigma.shape == (len(chunk.pixel), 2, 10) and np.isfinite(chunk.sigma).all()
    info = run("index", "info", sigma_render / "striped.pxlidx")
    assert info.returncode == 0 and "whole 4×4 Σ" in info.stdout


def test_stripes_and_not_the_checker(sigma_render):
    arguments = [item for name, text in LAYERS.items() for item in ("--layer", f"{name}={text}")]
    result = run("extract", sigma_render / "striped.pxlidx", *arguments, "-o", sigma_render / "layers.exr",
                 "--no-previews", "--quiet")
    assert result.returncode == 0, result.stderr
    parts = read_parts(sigma_render / "layers.exr")
    energy = {name: float(np.sum(next(image for part, image in parts.items() if part.startswith(name))[..., :3]))
              for name in LAYERS}
    assert energy["stripes"] > 0 and energy["checker"] > 0
    # the directional layer holds the stripes' directly lit diffuse light, and none of the checker's
    stripes_direct = float(np.sum(extract_one(sigma_render, "C<RD'stripes'>L")))
    checker_direct = float(np.sum(extract_one(sigma_render, "C<RD'checker'>L")))
    selected = extract_one(sigma_render, DIRECTIONAL)
    on_checker = extract_one(sigma_render, "C<RD'checker'>@(S11 >> S22 or S22 >> S11).*")
    assert float(np.sum(selected)) >= 0.9 * stripes_direct
    assert float(np.sum(on_checker)) <= 0.02 * checker_direct


def extract_one(folder, expression: str) -> np.ndarray:
    from pxr_layers.layers.extract import extract

    return extract(PathIndex(folder / "striped.pxlidx"), {"layer": expression}).layers["layer"]


def test_an_index_of_norms_refuses_a_query_on_sigma(shipped_scene, tmp_path):
    result = run("render", shipped_scene("striped.usda"), "-o", tmp_path, "--resolution", "16", "16", "--spp", "1",
                 "--norm-bounces", "2", "--no-previews", "--quiet")
    assert result.returncode == 0, result.stderr
    refused = run("extract", tmp_path / "striped.pxlidx", "--layer", f"directional={DIRECTIONAL}", "--no-previews",
                  "-o", tmp_path / "layers.exr")
    assert refused.returncode == 1 and len(refused.stderr.strip().splitlines()) == 1, refused.stderr
    assert "--index-covariance sigma" in refused.stderr and "Traceback" not in refused.stderr
    assert not (tmp_path / "layers.exr").exists()


def test_a_batch_without_contributions_merges_to_no_records():
    """A batch of pixels that see nothing (sky-less background rows of the Cornell box at
    256², 64 spp) has no record: its merged Σ codes are empty, shaped as any batch's."""
    from pxr_layers.trace.merge import merged
    from pxr_layers.trace.recorder import Contributions

    slots = 5
    empty = Contributions(pixel=np.zeros(0, np.int64), sample=np.zeros(0, np.int32), rgb=np.zeros((0, 3), np.float32),
                          path_class=np.zeros(0, np.int64), norms=np.zeros((0, slots, 3), np.float16),
                          class_nodes=np.zeros(0, np.int64), trie_parent=np.full(1, -1, np.int64),
                          trie_event=np.zeros(1, np.int64), sigma=np.zeros((0, slots, 10), np.float32))
    result = merged(empty, 0, 1024)
    assert result.sigma_codes.shape == (0, slots, 10) and result.norm_codes.shape == (0, slots, 3)
    assert len(result.pixel) == 0 and result.contributions == 0

