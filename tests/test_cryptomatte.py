"""Cryptomatte, checked by a decoder written here from Psyop's specification 1.1 (not by
calling pxr_layers.layers.cryptomatte):

* ids: MurmurHash3_x86_32 (seed 0) of the name's UTF-8 bytes, its bits read as a float32
  with the exponent clamped to [1, 254] (the specification's Python and C++ code); the
  manifest's values are those float bits in 8 hex digits;
* parts ``NAME00``, ``NAME01``, ... with R, G, B, A = id, coverage, id, coverage of ranks
  2k, 2k + 1; a name's matte is the sum of the coverages of the ranks holding its id;
* header attributes ``cryptomatte/<key>/name|hash|conversion|manifest``, the key the first 7
  hex digits of the type name's id (as the Nuke gizmo's ``layer_hash`` makes it).

The reference coverage of every object comes from the primId data AOV (one ray through each
pixel centre) rendered at SUPERSAMPLE times the resolution and box-downsampled: an
independent route to the share of each pixel an object covers.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from pxr_layers.cli import main as cli_main
from pxr_layers.cli.demo import embedded_scene

MASK = 0xFFFFFFFF
SPEC_MANIFEST_EXAMPLES = {"bunny": "13851a76", "default": "42c9679f", "bunny_porcelain_mat": "b24b26d4"}
"""The manifests of the specification's metadata example (names → their ids' hex)."""
MURMUR_VECTORS = {b"": 0, b"hello": 0x248BFA47, b"The quick brown fox jumps over the lazy dog": 0x2E4FF723}
"""MurmurHash3_x86_32, seed 0: published reference values."""
TYPES = ("CryptoObject", "CryptoMaterial", "CryptoAsset")


# --- the decoder ---------------------------------------------------------------------------


def murmur3_32(data: bytes) -> int:
    """MurmurHash3_x86_32 with seed 0, after Appleby's MurmurHash3.cpp."""
    def rotl(x: int, r: int) -> int:
        return ((x << r) | (x >> (32 - r))) & MASK

    h, n = 0, len(data)
    for i in range(0, n - n % 4, 4):
        k = data[i] | data[i + 1] << 8 | data[i + 2] << 16 | data[i + 3] << 24
        k = rotl(k * 0xCC9E2D51 & MASK, 15) * 0x1B873593 & MASK
        h = (rotl(h ^ k, 13) * 5 + 0xE6546B64) & MASK
    rest = data[n - n % 4:]
    k = 0
    for shift, byte in enumerate(rest):
        k |= byte << (8 * shift)
    if rest:
        h ^= rotl(k * 0xCC9E2D51 & MASK, 15) * 0x1B873593 & MASK
    h ^= n
    for shift, factor in ((16, 0x85EBCA6B), (13, 0xC2B2AE35)):
        h = (h ^ (h >> shift)) * factor & MASK
    return h ^ (h >> 16)


def spec_id_bits(name: str) -> int:
    """The specification's hash_to_float: the exponent clamped to [1, 254], bit for bit."""
    h = murmur3_32(name.encode("utf-8"))
    exponent = min(max((h >> 23) & 0xFF, 1), 254)
    return (h & 0x80000000) | (exponent << 23) | (h & 0x7FFFFF)


def spec_id(name: str) -> np.float32:
    return np.array([spec_id_bits(name)], np.uint32).view(np.float32)[0]


def read_cryptomattes(path: Path) -> tuple[dict[str, dict], np.ndarray, list]:
    """({type name: {"key", "manifest", "parts": [(h, w, 4) ...], "attributes"}}, part 0's
    alpha (h, w), the file's parts) read with OpenEXR alone."""
    exr = OpenEXR.File(str(path), separate_channels=True)
    first = exr.parts[0]
    types = {}
    for key, value in first.header.items():
        match = re.fullmatch(r"cryptomatte/([0-9a-f]{1,7})/name", key)
        if match:
            types[str(value)] = {"key": match.group(1)}
    for name, entry in types.items():
        prefix = f"cryptomatte/{entry['key']}/"
        entry["attributes"] = {k[len(prefix):]: str(v) for k, v in first.header.items() if k.startswith(prefix)}
        entry["manifest"] = json.loads(entry["attributes"]["manifest"])
        parts = sorted((part for part in exr.parts if re.fullmatch(re.escape(name) + r"\d\d", part.name())),
                       key=lambda part: part.name())
        entry["parts"] = [np.stack([part.channels[f"{part.name()}.{c}"].pixels for c in "RGBA"], axis=-1)
                          for part in parts]
        entry["part_headers"] = [part.header for part in parts]
    return types, first.channels["A"].pixels, exr.parts


def matte(entry: dict, names: list[str]) -> np.ndarray:
    """The matte of ``names``: Σ over ranks of coverage where the rank's id is one of theirs."""
    ids = np.array([np.array([int(entry["manifest"][n], 16)], np.uint32).view(np.float32)[0] for n in names])
    total = np.zeros(entry["parts"][0].shape[:2], np.float64)
    for part in entry["parts"]:
        for id_channel, coverage_channel in ((0, 1), (2, 3)):
            total += np.where(np.isin(part[..., id_channel], ids), part[..., coverage_channel], 0.0)
    return total


def total_coverage(entry: dict) -> np.ndarray:
    return sum(part[..., 1].astype(np.float64) + part[..., 3] for part in entry["parts"])


# --- the hashes ----------------------------------------------------------------------------


def test_the_decoders_murmurhash_gives_the_published_values():
    for data, expected in MURMUR_VECTORS.items():
        assert murmur3_32(data) == expected


def test_ids_match_the_specifications_examples():
    from pxr_layers.layers.cryptomatte import id_hex, name_id, type_key

    for name, expected in SPEC_MANIFEST_EXAMPLES.items():
        assert f"{spec_id_bits(name):08x}" == expected  # the decoder agrees with the specification
        assert id_hex(name) == expected
        assert name_id(name) == spec_id(name)
    assert type_key("CryptoObject") == f"{spec_id_bits('CryptoObject'):08x}"[:7]
    # the examples of layers/cryptomatte.py's docstring (the specification's d593dd7 is not CryptoObject's)
    assert (type_key("CryptoObject"), type_key("uCryptoAsset"), id_hex("/World/floor")) == \
        ("3ae39a5", "d593dd7", "7d36650d")


def test_exponents_0_and_255_are_moved_into_range():
    """Names whose hash has exponent bits 0 or 255 (found by search) get finite normal ids."""
    from pxr_layers.layers.cryptomatte import name_id

    found = {0: None, 255: None}
    for number in range(200000):
        name = f"n{number}"
        exponent = (murmur3_32(name.encode()) >> 23) & 0xFF
        if exponent in found and found[exponent] is None:
            found[exponent] = name
        if all(found.values()):
            break
    for exponent, name in found.items():
        value = name_id(name)
        assert np.isfinite(value) and value != 0 and abs(value) >= np.finfo(np.float32).tiny, (exponent, name)
        assert value == spec_id(name)


# --- renders -------------------------------------------------------------------------------


def render_cli(tmp_path: Path, stage: str, *flags: str) -> Path:
    out = tmp_path / "render.exr"
    code = cli_main.main(["render", str(stage), "--no-index", "--no-previews", "--quiet", "-o", str(out), *flags])
    assert code == 0
    return out


@pytest.mark.parametrize("scene", ["cornell.usda", "showcase.usda"])
def test_coverages_sum_to_alpha_and_the_manifest_names_every_object(tmp_path, scene):
    from pxr_layers.jobs.frame import plan_frame, prepare_frame
    from pxr_layers.request import RenderRequest

    stage = embedded_scene(scene)
    path = render_cli(tmp_path, stage, "--resolution", "40", "30", "--spp", "16", "--cryptomatte",
                      "object,material,asset")
    types, alpha, parts = read_cryptomattes(path)
    assert set(types) == set(TYPES)
    plan = plan_frame(RenderRequest(stage=Path(stage), resolution=(40, 30), spp=1, keep_index=False, previews=False),
                      None, directory=tmp_path)
    objects = set(prepare_frame(plan).world.object_paths)
    assert set(types["CryptoObject"]["manifest"]) == objects
    assert set(types["CryptoAsset"]["manifest"]) == {"/World"}  # no kind authored: the top-level prim
    for name, entry in types.items():
        assert entry["key"] == f"{spec_id_bits(name):08x}"[:7]
        assert entry["attributes"] == {"name": name, "hash": "MurmurHash3_32", "conversion": "uint32_to_float32",
                                       "manifest": entry["attributes"]["manifest"]}
        assert len(entry["parts"]) == 3  # depth 6
        for header in entry["part_headers"]:  # the parts carry the attributes too
            assert header[f"cryptomatte/{entry['key']}/manifest"] == entry["attributes"]["manifest"]
        for value, bits in entry["manifest"].items():
            assert bits == f"{spec_id_bits(value):08x}"
        np.testing.assert_allclose(total_coverage(entry), alpha, atol=1e-6)
        ranks = np.concatenate([p[..., 1::2] for p in entry["parts"]], axis=-1)
        assert (np.diff(ranks, axis=-1) <= 0).all()  # highest coverage first
    assert len({part.name() for part in parts}) == len(parts)


SUPERSAMPLE = 96
SIZE = (24, 18)
SPP = 16384


@pytest.mark.parametrize("scene", ["cornell.usda", "showcase.usda"])
def test_object_mattes_equal_the_supersampled_primid_coverage(tmp_path, scene):
    """Each object's matte against the share of SUPERSAMPLE² pixel-centre rays of primId
    that hit it: within 2 % on edges (at SPP samples the matte's own noise is below
    0.5/√SPP ≈ 0.4 %), exactly 1 inside (the pixel and its neighbours wholly the object's)."""
    from pxr_layers.jobs.frame import plan_frame, prepare_frame, render_frame
    from pxr_layers.request import RenderRequest
    from pxr_layers.trace import render_data_aovs

    stage = Path(embedded_scene(scene))
    width, height = SIZE
    result = render_frame(RenderRequest(stage=stage, resolution=SIZE, spp=SPP, cryptomattes=("CryptoObject",),
                                        keep_index=False, previews=False), output=tmp_path / "mattes")
    entry = read_cryptomattes(result.delivered[0].exr)[0]["CryptoObject"]

    fine = plan_frame(RenderRequest(stage=stage, resolution=(width * SUPERSAMPLE, height * SUPERSAMPLE), spp=1,
                                    keep_index=False, previews=False), None, directory=tmp_path)
    fine_integrator = prepare_frame(fine)
    prim = render_data_aovs(fine_integrator, ["primId"])["primId"].astype(np.int64)
    paths = fine_integrator.world.object_paths
    checked_edges = 0
    for index, object_path in enumerate(paths):
        mask = (prim == index).reshape(height, SUPERSAMPLE, width, SUPERSAMPLE)
        reference = mask.mean(axis=(1, 3))
        if not reference.any():
            continue
        found = matte(entry, [object_path])
        edge = (reference > 0) & (reference < 1)
        assert np.abs(found - reference)[edge].max(initial=0) <= 0.02, object_path
        whole = reference == 1
        inside = whole.copy()
        inside[1:-1, 1:-1] = whole[1:-1, 1:-1] & whole[:-2, 1:-1] & whole[2:, 1:-1] & whole[1:-1, :-2] & whole[1:-1, 2:]
        inside[[0, -1], :] = False
        inside[:, [0, -1]] = False
        assert (found[inside] == 1.0).all(), object_path
        checked_edges += int(edge.sum())
    assert checked_edges > 20  # the scenes have silhouettes


def test_a_recipe_asks_with_raw_rendervars_and_the_depth_is_settable(tmp_path):
    recipe = tmp_path / "crypto.usda"
    recipe.write_text('''#usda 1.0
(
    renderSettingsPrimPath = "/Render/Crypto/Settings"
)
def Scope "Render"
{
    def Scope "Crypto"
    {
        def RenderSettings "Settings"
        {
            rel products = </Render/Crypto/product>
        }
        def RenderProduct "product"
        {
            token productName = "crypto.exr"
            rel orderedVars = [</Render/Crypto/Vars/color>, </Render/Crypto/Vars/CryptoMaterial>]
        }
        def Scope "Vars"
        {
            def RenderVar "color"
            {
                uniform token sourceType = "raw"
                uniform string sourceName = "color"
                uniform token dataType = "color3f"
            }
            def RenderVar "CryptoMaterial"
            {
                uniform token sourceType = "raw"
                uniform string sourceName = "CryptoMaterial"
                uniform token dataType = "float4"
            }
        }
    }
}
''')
    path = render_cli(tmp_path, embedded_scene("cornell.usda"), "--recipe", str(recipe), "--resolution", "20", "16",
                      "--spp", "4", "--cryptomatte-depth", "3")
    types, alpha, parts = read_cryptomattes(path)
    assert list(types) == ["CryptoMaterial"]
    entry = types["CryptoMaterial"]
    assert [part.name() for part in parts] == ["rgba", "CryptoMaterial00", "CryptoMaterial01"]
    assert not entry["parts"][1][..., 2:].any()  # depth 3: rank 3 is not written
    assert "/World/Materials/white" in entry["manifest"]
    np.testing.assert_allclose(total_coverage(entry), alpha, atol=1e-6)
    assert (matte(entry, ["/World/Materials/white"]) > 0.5).mean() > 0.3  # walls, floor, ceiling


def test_extract_copies_them_from_the_render_beside_the_index(tmp_path):
    render = tmp_path / "shot.exr"
    assert cli_main.main(["render", str(embedded_scene("cornell.usda")), "--no-previews", "--quiet", "-o", str(render),
                          "--resolution", "16", "12", "--spp", "4", "--cryptomatte", "object"]) == 0
    out = tmp_path / "cut.exr"
    assert cli_main.main(["extract", str(render.with_suffix(".pxlidx")), "--passes", "--cryptomatte", "object",
                          "--no-previews", "--quiet", "-o", str(out)]) == 0
    original, cut = read_cryptomattes(render)[0]["CryptoObject"], read_cryptomattes(out)[0]["CryptoObject"]
    assert original["manifest"] == cut["manifest"]
    for a, b in zip(original["parts"], cut["parts"], strict=True):
        np.testing.assert_array_equal(a, b)
    render.unlink()  # nothing beside the index to copy from: refused, not faked
    assert cli_main.main(["extract", str(render.with_suffix(".pxlidx")), "--passes", "--cryptomatte", "object",
                          "--no-previews", "--quiet", "-o", str(tmp_path / "again.exr")]) == 1


def test_openimageio_reads_our_parts_as_the_pipeline_conventions_say(tmp_path):
    """PIPELINE.md's conventions, as OpenImageIO (the reader under most compositors' tools)
    reads a product: part 0 'rgba' R G B A, parts named after layers with NAME.R/G/B,
    depth.Z, NAME00.R/G/B/A for Cryptomattes, one data window, one chromaticities, no
    view, float32 on data parts, the cryptomatte attributes on part 0."""
    import OpenImageIO as oiio

    recipe = tmp_path / "data.usda"
    recipe.write_text('''#usda 1.0
(
    renderSettingsPrimPath = "/Render/D/Settings"
)
def Scope "Render"
{
    def Scope "D"
    {
        def RenderSettings "Settings"
        {
            rel products = </Render/D/product>
        }
        def RenderProduct "product"
        {
            token productName = "data.exr"
            rel orderedVars = [</Render/D/Vars/diffuse>, </Render/D/Vars/depth>, </Render/D/Vars/CryptoObject>]
        }
        def Scope "Vars"
        {
            def RenderVar "diffuse"
            {
                uniform token sourceType = "lpe"
                uniform string sourceName = "C<RD>.*"
                uniform token dataType = "color3f"
            }
            def RenderVar "depth"
            {
                uniform token sourceType = "raw"
                uniform string sourceName = "depth"
                uniform token dataType = "float"
            }
            def RenderVar "CryptoObject"
            {
                uniform token sourceType = "raw"
                uniform string sourceName = "CryptoObject"
                uniform token dataType = "float4"
            }
        }
    }
}
''')
    path = render_cli(tmp_path, embedded_scene("cornell.usda"), "--recipe", str(recipe), "--resolution", "20", "14",
                      "--spp", "4")
    image = oiio.ImageInput.open(str(path))
    specs = []
    subimage = 0
    while image.seek_subimage(subimage, 0):
        specs.append(image.spec())
        subimage += 1
    image.close()
    names = [spec.getattribute("oiio:subimagename") for spec in specs]
    assert names == ["rgba", "diffuse", "depth", "CryptoObject00", "CryptoObject01", "CryptoObject02"]
    channels = [list(spec.channelnames) for spec in specs]
    assert channels[0] == ["R", "G", "B", "A"]
    assert channels[1] == ["diffuse.R", "diffuse.G", "diffuse.B"]
    assert channels[2] == ["depth.Z"]
    for number, part in enumerate(channels[3:]):
        assert part == [f"CryptoObject0{number}.{c}" for c in "RGBA"]
    for spec in specs:
        assert (spec.x, spec.y, spec.width, spec.height) == (0, 0, 20, 14)
        assert (spec.full_width, spec.full_height) == (20, 14)
        assert tuple(spec.getattribute("chromaticities")) == pytest.approx(
            (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290))
        assert spec.getattribute("view") is None
    for spec in specs[2:]:
        assert all(str(fmt) == "float" for fmt in spec.channelformats) or str(spec.format) == "float"
    key = f"{spec_id_bits('CryptoObject'):08x}"[:7]
    assert specs[0].getattribute(f"cryptomatte/{key}/name") == "CryptoObject"
    assert json.loads(specs[0].getattribute(f"cryptomatte/{key}/manifest"))
