"""shader_nodes: the expression trees of material inputs, folded in Python and interpreted
by the shading kernels with the same semantics."""

import math

import numpy as np
import pytest

from pxr_layers import shader_nodes as sn
from pxr_layers.scene import Material, SceneData, TextureImage
from pxr_layers.trace.shading import DIFFUSE, MaterialTable, inputs_at

TEXCOORD = sn.ShaderNode("texcoord")


def evaluate(tree, st, textures=()):
    """The kernels' value of `tree` as diffuse_color (components 0–2) at st (n, 2)."""
    scene = SceneData("test", 0.0, (), (Material("m", "/m", diffuse_color=tree),), (), tuple(textures))
    return inputs_at(MaterialTable(scene).arrays, 0, st)[:, DIFFUSE:DIFFUSE + 3]


def substituted(tree, s, t):
    """`tree` with texcoord replaced by the constant (s, t): what node() folds."""
    if tree.op == "texcoord":
        return sn.constant(s, t, 0.0, 1.0)
    return sn.node(tree.op, *(substituted(child, s, t) for child in tree.inputs), values=tree.values)


OPERATIONS = [(op, arity) for op, arity in sn._ARITY.items() if op not in ("constant", "texcoord", "primvar", "texture")]


@pytest.mark.parametrize("op, arity", OPERATIONS)
def test_every_operation_folds_as_the_kernels_evaluate_it(op, arity):
    rng = np.random.default_rng(sn.OP_CODE[op])
    st = rng.uniform(-2, 2, (64, 2)).astype(np.float32)
    inputs = [sn.node("add", sn.node("multiply", sn.swizzle(TEXCOORD, tuple(rng.integers(0, 2, 4))),
                                     sn.constant(*rng.uniform(-3, 3, 4))), sn.constant(*rng.uniform(-1, 1, 4)))
              for _ in range(arity)]
    values = {"dotproduct": (3,), "swizzle": (2, -2, 0, -1), "affine2d": tuple(rng.uniform(-2, 2, 6))}.get(op, ())
    tree = sn.node(op, *inputs, values=values)
    got = evaluate(tree, st)
    expected = np.array([substituted(tree, s, t).values[:3] for s, t in st.astype(np.float64)], np.float32)
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-5)


def test_folding_follows_the_documented_semantics():
    value = lambda tree: sn.node("add", tree, sn.constant()).values  # noqa: E731 (fold through a no-op)
    assert sn.node("divide", sn.constant(1, 2), sn.constant(0, 4)).values[:2] == (0.0, 0.5)
    assert sn.node("modulo", sn.constant(-1.25), sn.constant(1)).values[0] == pytest.approx(0.75)
    assert sn.node("power", sn.constant(-2, 4), sn.constant(2, 0.5)).values[:2] == (0.0, 2.0)
    assert sn.node("mix", sn.constant(0, 10), sn.constant(1, 20), sn.constant(0.25, 0.5)).values[:2] == (0.25, 15.0)
    assert value(sn.swizzle(sn.constant(1, 2, 3, 4), (3, -2, -1))) == (4.0, 1.0, 0.0, 0.0)
    rotated = sn.node("affine2d", sn.constant(1, 0), values=(0, -1, 0, 1, 0, 0)).values  # 90° counter-clockwise
    assert rotated[:2] == (0.0, 1.0)
    assert sn.node("ifgreater", sn.constant(2), sn.constant(1), sn.constant(7), sn.constant(9)).values[0] == 7


def test_texture_lookups_wrap_and_pick_udim_tiles():
    """A 1×1 texture per tile: tile 1001 covers st ∈ [0, 1)², 1002 [1, 2) × [0, 1), 1011
    [0, 1) × [1, 2); st outside every tile gives the fallback."""
    images = [TextureImage(f"tile{k}", np.full((1, 1, 4), k, np.float32)) for k in (1, 2, 3)]
    tree = sn.ShaderNode("texture", (TEXCOORD,), values=(-1, -1, -1, -1), tiles=((1001, 0), (1002, 1), (1011, 2)))
    st = np.array([[0.5, 0.5], [1.5, 0.5], [0.25, 1.75], [2.5, 0.5], [0.5, -0.5]], np.float32)
    np.testing.assert_array_equal(evaluate(tree, st, images)[:, 0], [1, 2, 3, -1, -1])


def test_equal_subtrees_are_computed_once():
    texel = sn.ShaderNode("texture", (TEXCOORD,), tiles=((0, 0),))
    scene = SceneData("test", 0.0, (), (Material("m", "/m", diffuse_color=texel, roughness=sn.swizzle(texel, (3,)),
                                                 metallic=sn.swizzle(texel, (0,))),), (),
                      (TextureImage("t", np.ones((2, 2, 4), np.float32)),))
    program = MaterialTable(scene).arrays.program
    assert (program[:, 0] == sn.TEXTURE).sum() == 1 and (program[:, 0] == sn.TEXCOORD).sum() == 1


def test_a_malformed_node_is_refused():
    with pytest.raises(ValueError, match="unknown shader node"):
        sn.ShaderNode("blur")
    with pytest.raises(ValueError, match="takes 2 inputs"):
        sn.ShaderNode("add", (TEXCOORD,))
    assert math.isfinite(sn.node("sqrt", sn.constant(-4)).values[0])


def test_a_combine_of_two_gives_zero_in_the_other_components_in_every_lane():
    s, t = sn.swizzle(TEXCOORD, (0,)), sn.swizzle(TEXCOORD, (1,))
    tree = sn.node("normalize", sn.node("combine", s, t))
    st = np.array([[0.6, 0.8], [0.0, 3.0], [0.6, 0.8]], np.float32)
    np.testing.assert_allclose(evaluate(tree, st), [[0.6, 0.8, 0.0], [0.0, 1.0, 0.0], [0.6, 0.8, 0.0]], atol=1e-6)
