"""The inspector's display LUT (layers/display_lut.py) against the previews' OCIO transform.

Tolerance: one 8-bit code per channel between ``_quantise(apply_display_lut(...))`` (what the
browser shows) and ``to_display(...)`` (the preview PNGs); the LUT's measured worst is 0.80
codes, so a code is only ever off by rounding.
"""

import base64
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from pxr_layers.layers.display_lut import (
    DEFAULT_SIZE,
    _tetrahedral,
    apply_display_lut,
    bake_display_lut,
    lut_bytes,
    lut_description,
    lut_glsl,
)
from pxr_layers.layers.previews import ColourError, _quantise, display_processor, to_display

PRIMARIES_AND_SECONDARIES = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [0, 1, 1], [1, 0, 1], [1, 1, 1]],
                                     dtype=np.float32)


@pytest.fixture(scope="module")
def lut():
    return bake_display_lut()


def codes_off(lut, image: np.ndarray) -> np.ndarray:
    """|browser − preview| per pixel and channel, in 8-bit codes: (h, w, 3) int."""
    shown = _quantise(apply_display_lut(lut, image)).astype(int)
    return np.abs(shown - to_display(image).astype(int))


def hdr_ramps() -> np.ndarray:
    """0..2^8 linearly, in each primary, secondary and grey: (7, 4096, 3)."""
    ramp = np.linspace(0.0, 256.0, 4096, dtype=np.float32)
    return ramp[None, :, None] * PRIMARIES_AND_SECONDARIES[:, None, :]


def saturated_log_ramps() -> np.ndarray:
    """2^-14..2^16 (past the previews' largest half, 65504) in each primary, secondary and
    grey: (7, 4096, 3)."""
    ramp = np.float32(2.0) ** np.linspace(-14.0, 16.0, 4096, dtype=np.float32)
    return ramp[None, :, None] * PRIMARIES_AND_SECONDARIES[:, None, :]


def random_colours(seed: int, zeros: float = 0.0) -> np.ndarray:
    """Each channel log2-uniform over −14..8, a ``zeros`` share of them 0: (256, 256, 3)."""
    rng = np.random.default_rng(seed)
    image = np.float32(2.0) ** rng.uniform(-14.0, 8.0, (256, 256, 3)).astype(np.float32)
    image[rng.random(image.shape) < zeros] = 0.0
    return image


def special_values() -> np.ndarray:
    """Zeros, float noise below zero, negative pixels, NaN and ±inf among ordinary colours:
    (8, 64, 3)."""
    rng = np.random.default_rng(5)
    base = np.float32(2.0) ** rng.uniform(-8.0, 4.0, (8, 64, 3)).astype(np.float32)
    base[0] = 0.0
    base[1] -= np.float32(1e-3)                     # noise around small values
    base[2] = -base[2]                              # every channel negative
    base[3, :, 1] = -rng.uniform(0.0, 1e-3, 64)     # one channel slightly negative
    base[4, ::2, 0] = np.nan
    base[4, 1::2] = np.nan
    base[5, ::2, 2] = np.inf
    base[5, 1::2] = np.inf
    base[6, ::2, 1] = -np.inf
    base[6, 1::2] = -np.inf
    base[7, :, 0] = np.nan
    base[7, :, 2] = np.inf
    return base


@pytest.mark.parametrize("image", [
    pytest.param(hdr_ramps(), id="hdr-ramps"),
    pytest.param(saturated_log_ramps(), id="saturated-log-ramps"),
    pytest.param(random_colours(1), id="random-1"),
    pytest.param(random_colours(2), id="random-2"),
    pytest.param(random_colours(3, zeros=0.3), id="random-with-zeros"),
    pytest.param(special_values(), id="zeros-negatives-nan-inf"),
])
def test_the_browser_shows_the_previews_within_one_code(lut, image):
    off = codes_off(lut, image)
    worst = np.unravel_index(np.argmax(off), off.shape)
    assert off.max() <= 1, f"{off.max()} codes off at {worst[:2]}: {image[worst[:2]]}"


def test_alpha_is_ignored(lut):
    rgb = random_colours(4)[:16, :16]
    rgba = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 0.25, np.float32)], axis=-1)
    assert apply_display_lut(lut, rgba).shape == rgb.shape
    np.testing.assert_array_equal(apply_display_lut(lut, rgba), apply_display_lut(lut, rgb))


def test_lattice_points_are_the_processor_exactly_and_in_the_served_layout(lut):
    """At a lattice point (distinct r, g, b indices, so a transposed layout would show)
    interpolation adds nothing: the shader gives the processor's value; and that point is
    element ((b·size + g)·size + r) of lut_bytes."""
    size = lut.size
    r, g, b = 40, 33, 21
    axis = lut.shaper.invert(np.linspace(0.0, 1.0, size))
    colour = np.linalg.solve(np.asarray(lut.shaper.basis), axis[[r, g, b]]).astype(np.float32)
    expected = colour.copy()[None, None, :]
    display_processor().applyRGB(expected)
    np.testing.assert_allclose(apply_display_lut(lut, colour[None, None, :]), np.clip(expected, 0, 1), atol=1e-5)
    served = np.frombuffer(lut_bytes(lut), dtype="<f4")
    element = ((b * size + g) * size + r) * 3
    np.testing.assert_array_equal(served[element : element + 3], lut.table[b, g, r])


def test_bake_is_cached_and_measured(lut):
    assert bake_display_lut() is lut
    assert lut.size == DEFAULT_SIZE
    assert lut.table.shape == (DEFAULT_SIZE,) * 3 + (3,) and lut.table.dtype == np.float32
    assert not lut.table.flags.writeable
    assert 0.0 < lut.max_error < 1.0


def lattice_coordinates(size: int, seed: int) -> np.ndarray:
    """u in 0..1 where the tetrahedra meet, and between: random; two fractions equal; grey
    (all three equal); on lattice planes; on eighths of a cell: (5·4096, 3) float32."""
    rng = np.random.default_rng(seed)
    u = rng.random((4096, 3)).astype(np.float32)
    pairs = u.copy()
    pairs[:, 1] = pairs[:, 0]
    pairs[1::3, 2] = pairs[1::3, 0]
    pairs[1::3, 1] = u[1::3, 1]
    greys = np.repeat(u[:, :1], 3, axis=1)
    planes = (rng.integers(0, size, (4096, 3)) / np.float32(size - 1)).astype(np.float32)
    planes[::2, 2] = u[::2, 2]
    eighths = (rng.integers(0, 8 * (size - 1) + 1, (4096, 3)) / np.float32(8 * (size - 1))).astype(np.float32)
    return np.concatenate([u, pairs, greys, planes, eighths])


def test_tetrahedral_interpolation_is_exact_on_a_sum_of_axis_curves():
    """The lattice's axes make the output nearly a sum of one-axis curves (the module
    docstring); on an exact sum the tetrahedra give each curve's linear interpolation, ties
    (where the tetrahedra meet) included, and the lattice points themselves."""
    size = 9
    rng = np.random.default_rng(3)
    curves = rng.random((3, size, 3))
    b, g, r = np.meshgrid(np.arange(size), np.arange(size), np.arange(size), indexing="ij")
    table = (curves[0][r] + curves[1][g] + curves[2][b]).astype(np.float32)
    u = lattice_coordinates(size, 4)
    nodes = np.linspace(0.0, 1.0, size)
    expected = sum(np.stack([np.interp(u[:, axis], nodes, curves[axis][:, c]) for c in range(3)], axis=-1)
                   for axis in range(3))
    np.testing.assert_allclose(_tetrahedral(table, u), expected, atol=1e-5)


def test_tetrahedral_interpolation_is_continuous_across_its_ties():
    """Moving a fraction from just below another to just above it changes the tetrahedron,
    not the value: the faces are shared (on the baked table)."""
    lut = bake_display_lut()
    u = np.random.default_rng(6).uniform(0.05, 0.95, (4096, 3)).astype(np.float32)
    for axis, other in ((0, 1), (1, 2), (0, 2)):
        below, above = u.copy(), u.copy()
        below[:, axis] = np.nextafter(u[:, other], np.float32(0.0))
        above[:, axis] = np.nextafter(u[:, other], np.float32(1.0))
        tie = u.copy()
        tie[:, axis] = u[:, other]
        for side in (below, above):
            np.testing.assert_allclose(_tetrahedral(lut.table, side), _tetrahedral(lut.table, tie), atol=1e-5)


def test_the_shaders_interpolation_is_the_numpy_twins_bit_for_bit(lut):
    """displayLut in the browser's WebGL2 (headless Chromium, SwiftShader) with the shaper and
    the encoding left out: the same float32 bits as _tetrahedral, ties included (a grey's
    fractions are all equal; the tie rule picks its tetrahedron). The shaper and the encoding
    (log2, exp2, pow) are the GPU's own and agree to about 1e-6 (the other tests' one code)."""
    from test_view_browser import CHROMIUM_ARGS, CHROMIUM, _sync_playwright

    sync_playwright = _sync_playwright()
    glsl = lut_glsl(lut)
    glsl, shapers = re.subn(r"vec3 displayLutShaper\(vec3 linearRgb\) \{.*?\n\}\n",
                            "vec3 displayLutShaper(vec3 linearRgb) { return linearRgb; }\n", glsl, flags=re.S)
    glsl, encodes = re.subn(r"vec3 displayLutEncode\(vec3 v\) \{.*?\n\}\n",
                            "vec3 displayLutEncode(vec3 v) { return v; }\n", glsl, flags=re.S)
    assert shapers == encodes == 1
    u = lattice_coordinates(lut.size, 5)
    width = 1024
    height = len(u) // width
    shader = json.dumps("#version 300 es\n" + glsl + """
uniform highp sampler2D u_image;
uniform highp sampler3D u_lut;
out vec4 colour;
void main() { colour = vec4(displayLut(texelFetch(u_image, ivec2(gl_FragCoord.xy), 0).rgb, u_lut), 1.0); }
""")
    script = f"""(() => {{
const floats = text => new Float32Array(Uint8Array.from(atob(text), c => c.charCodeAt(0)).buffer);
const gl = document.createElement('canvas').getContext('webgl2');
if (!gl.getExtension('EXT_color_buffer_float')) return null;
function texture(unit, target) {{
  gl.activeTexture(gl.TEXTURE0 + unit);
  const made = gl.createTexture();
  gl.bindTexture(target, made);
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(target, p, gl.NEAREST);
  return made;
}}
texture(0, gl.TEXTURE_2D);
gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGB32F, {width}, {height});
gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, {width}, {height}, gl.RGB, gl.FLOAT,
                 floats('{base64.b64encode(u.tobytes()).decode()}'));
texture(1, gl.TEXTURE_3D);
gl.texStorage3D(gl.TEXTURE_3D, 1, gl.RGB32F, {lut.size}, {lut.size}, {lut.size});
gl.texSubImage3D(gl.TEXTURE_3D, 0, 0, 0, 0, {lut.size}, {lut.size}, {lut.size}, gl.RGB, gl.FLOAT,
                 floats('{base64.b64encode(lut_bytes(lut)).decode()}'));
const target = texture(2, gl.TEXTURE_2D);
gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, {width}, {height});
gl.bindFramebuffer(gl.FRAMEBUFFER, gl.createFramebuffer());
gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, target, 0);
function compiled(type, source) {{
  const made = gl.createShader(type);
  gl.shaderSource(made, source);
  gl.compileShader(made);
  if (!gl.getShaderParameter(made, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(made));
  return made;
}}
const program = gl.createProgram();
gl.attachShader(program, compiled(gl.VERTEX_SHADER, `#version 300 es
void main() {{ gl_Position = vec4(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0, 0.0, 1.0); }}`));
gl.attachShader(program, compiled(gl.FRAGMENT_SHADER, {shader}));
gl.linkProgram(program);
gl.useProgram(program);
gl.uniform1i(gl.getUniformLocation(program, 'u_image'), 0);
gl.uniform1i(gl.getUniformLocation(program, 'u_lut'), 1);
gl.viewport(0, 0, {width}, {height});
gl.drawArrays(gl.TRIANGLES, 0, 3);
const pixels = new Float32Array({width} * {height} * 4);
gl.readPixels(0, 0, {width}, {height}, gl.RGBA, gl.FLOAT, pixels);
return Array.from(pixels);
}})()"""
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)
        try:
            shown = browser.new_page().evaluate(script)
        finally:
            browser.close()
    if shown is None:
        pytest.skip("this WebGL2 cannot render to float32")
    shown = np.asarray(shown, dtype=np.float32).reshape(-1, 4)[:, :3]
    expected = np.clip(_tetrahedral(lut.table, u), np.float32(0.0), np.float32(1.0))
    np.testing.assert_array_equal(shown, expected)


def test_unknown_colour_settings_are_the_previews_errors():
    with pytest.raises(ColourError) as raised:
        bake_display_lut(view="No Such View")
    assert raised.value.setting == "view"


def test_description_agrees_with_the_bytes(lut):
    description = json.loads(json.dumps(lut_description(lut)))
    assert "url" not in description  # the server's to add: layers/ does not know the HTTP API
    assert description["size"] == lut.size
    assert len(lut_bytes(lut)) == description["size"] ** 3 * 3 * 4
    assert description["shaper"]["lo"] == lut.shaper.lo and description["shaper"]["hi"] == lut.shaper.hi
    glsl = description["glsl"]
    assert "vec3 displayLut(vec3 linearRgb, highp sampler3D lut)" in glsl
    assert glsl.count("texelFetch(lut, ") == 4  # tetrahedral
    assert not re.search(r"\bif\b|\?", glsl)  # no branches: SwiftShader would run both sides
    assert "#version" not in glsl  # the frontend's shader starts with its own


@pytest.mark.skipif(shutil.which("glslangValidator") is None, reason="glslangValidator is not installed")
def test_glsl_compiles_as_glsl_es_300(lut, tmp_path):
    shader = tmp_path / "display.frag"
    shader.write_text("#version 300 es\n" + lut_glsl(lut) + """
uniform highp sampler3D u_lut;
uniform highp sampler2D u_image;
out vec4 colour;
void main() {
    colour = vec4(displayLut(texelFetch(u_image, ivec2(gl_FragCoord.xy), 0).rgb, u_lut), 1.0);
}
""")
    result = subprocess.run(["glslangValidator", str(shader)], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
