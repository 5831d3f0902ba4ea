"""The previews' OCIO display/view baked into a 3D LUT that the inspector's WebGL2 shader applies.

The browser must show a composite exactly as :func:`pxr_layers.layers.previews.to_display`
would: at unit gains its pixels equal the preview PNGs within one 8-bit code. The LUT is
baked from the previews' own processor (:func:`~pxr_layers.layers.previews.display_processor`,
so the config / display / view checks and their errors are the previews'), and the shader
does, per pixel (``displayLut`` in :func:`lut_glsl`; :func:`apply_display_lut` is its numpy
twin)::

    rgb     = clamp(NaN → 0 (linear_rgb), ±65504)           as to_display replaces NaN and ±inf
    a       = BASIS · rgb                                    the lattice's axes
    L       = log2 a          for a ≥ 2^lo                   (per channel)
            = lo + (a − 2^lo) / (2^lo ln 2)  below           the tangent line: 0 and a little
                                                              below it stay representable
    L       = clamp(L, L0, hi)   L0 = lo − 2 / ln 2          (a = −2^lo: the toe's foot)
    u       = A · (L − L0) + B · (σ(L) − σ(L0))              σ(L) = 1 / (1 + 2^(pivot − L))
                                                              A, B: u(L0) = 0, u(hi) = 1,
                                                              the log2 term's share `weight`
    v       = tetrahedral(table, u · (size − 1))             4 texelFetch, by hand (RGB32F is not
                                                              filterable): c000, c111 and the two
                                                              the fractions' order picks
    display = clamp(sRGB_encode(v), 0, 1)                    the canvas rounds · 255

Why each step (measured on the pinned ACES 1.0 SDR view, size 65, against the processor's
unquantised output; "codes" are 8-bit code values):

- A log2 shaper on the rendering space's own axes with a linear toe (the first design) is
  off by 6-8 codes at 65³ and still 6 at 129³: two things are not smooth on that lattice.
- The sRGB encoding's break (linear below 0.0031308, a power above it) lands inside cells
  wherever a display channel rises out of black (a saturated colour's other channels). The
  table therefore holds the processor's output *decoded* with the sRGB curve, and the shader
  encodes after interpolating. This is exact at the lattice points for any display (the
  curve is only a change of variable), and smooth for the sRGB display.
- ACES 1.0 tone-maps each channel separately in AP1 after its desaturation matrix
  (``RRT_SAT``); on Rec.709 axes every display channel mixes three tone curves, and near a
  display primary's edge the large terms cancel, so 1-2 % interpolation error becomes
  several codes. The lattice's axes are therefore ``BASIS = RRT_SAT · AP1_FROM_REC709``: the
  output is then close to a sum of one-axis curves, which the interpolation follows (on
  such a sum tetrahedral interpolation, like trilinear, is the sum of each curve's linear
  interpolation; a positive matrix: non-negative colours keep non-negative axes). For other
  configs it is only a change of coordinates (still exact at the lattice points).
- Along each axis the display-linear output is the tone curve, whose shape a logistic in
  log2 (``a / (a + 2^pivot)``) follows; spacing the lattice evenly in that curve makes the
  interpolated terms nearly linear. Pure logistic spacing starves the blacks and the
  highlights of lattice points, where the non-separable parts (ACES glow, red modifier,
  dark-to-dim) still vary, so a share ``weight`` of plain log2 spacing is mixed in. A grid
  search over weight ∈ 0.15..0.6, pivot ∈ −3..0.5, the logistic's slope ∈ 0.8..1.6,
  lo ∈ −11..−9, hi ∈ 7..12 gave the defaults of :class:`Shaper` (slope 1, so no parameter).
- Tetrahedral, not trilinear, interpolation: 4 texture reads instead of 8. Headless
  Chromium's WebGL (SwiftShader, on the CPU) spends about 5 ms of a 1080p frame on each; with
  2 layer reads before it, displayLut draws 17.0-18.5 frames/s against trilinear's 13.2-14.1
  (about 56 ms a frame, not 73; a micro-benchmark on an idle 2-core machine). The cell's
  tetrahedron is the path c000 → c111 along the axes in decreasing order of their
  fractions, ``v = c0 + (c1 − c0)·f_max + (c2 − c1)·f_mid + (c3 − c2)·f_min``; ties go to r
  before g before b (:func:`_tetrahedral`; the browser's interpolation gives the same
  float32 bits, ties included, which a test checks). The vertices are chosen with step(),
  not branches (SwiftShader runs both sides of a divergent branch). Its error is no larger
  than trilinear's: the same worst, fewer values off by one (the figures below; trilinear's
  in brackets, measured the same way on the same demo render).
- Range: below 2^-10 on every axis ACES shows black; above 2^8 every channel is saturated
  (a Rec.709 primary at 2^11 is white); the previews' +inf (65504) clamps to 2^8.

Result (pinned defaults, size 65; bake 0.1 s, plus 0.05 s for the processor the previews
cache): the worst error found, hill-climbing from the worst of 1.6 M random colours, is
0.80 codes [0.80], so no channel is ever more than one code from the PNG; the mean is 0.023
codes [0.025]. Off by exactly one (rounding on the other side of a code boundary, about as
often as the mean error): 1.1-2.5 % of channel values [1.3-2.7 %] (3-7 % of pixels [3.5-8 %])
on the tests' synthetic images; on the demo's Cornell box 3.4 % of the beauty's values
[3.9 %] (9.7 % of its pixels [11.2 %]: dim, saturated walls, where the error is largest) and
up to 22 % of a layer's pixels [26 %] (the dim fill light's). Size 81 (6.4 MB, 0.18 s) gives
a worst of 0.50 codes [0.67] and 6.7 % of the beauty's pixels [7.8 %], size 97 (11 MB,
0.36 s) 0.35 codes [0.57] and 4.9 % [5.8 %].

Below zero: float noise (−1e-3 on dim colours, a channel at −1 % of the others) is within one
code; a channel further below zero than about 2 % of the others leaves the toe (axes below
−2^-10 clamp to its foot) where OCIO clamps in AP0 first, and is not matched (3 codes at −3 %,
35 at −10 %): renders are non-negative but for noise. :attr:`DisplayLut.max_error`
re-measures each bake on fixed probe colours; a bake worse than one code logs a warning
(views other than the pinned one are not tuned for).
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ..recipe.model import DEFAULT_DISPLAY, DEFAULT_OCIO_CONFIG, DEFAULT_VIEW, RENDERING_SPACE
from .previews import HALF_MAX, display_processor

logger = logging.getLogger(__name__)

FLOAT = np.float32
DEFAULT_SIZE = 65
"""Lattice points per axis (see the module docstring for the measured error)."""

AP1_FROM_REC709 = ((0.6130974024011883, 0.3395231461841055, 0.04737945141470726),
                   (0.0701937224695816, 0.9163538790573413, 0.01345239847307386),
                   (0.020615592882227, 0.1095697729381357, 0.8698146341796398))
"""Linear Rec.709 → ACEScg (AP1), Bradford D65 → D60, as the pinned config's processor has it."""
RRT_SAT = ((0.970889148671, 0.026963270632, 0.002147580696),
           (0.010889148671, 0.986963270632, 0.002147580696),
           (0.010889148671, 0.026963270632, 0.962147580696))
"""The ACES 1.0 RRT's desaturation in AP1, applied just before its per-channel tone curve."""
BASIS = tuple(map(tuple, (np.array(RRT_SAT) @ np.array(AP1_FROM_REC709)).tolist()))
"""The lattice's axes from the rendering space's RGB: ``axes = BASIS @ rgb``."""

SRGB_BREAK = 0.0031308
"""Where the sRGB encoding turns from ·12.92 to the power 1/2.4 (IEC 61966-2-1)."""
SRGB_EXPONENT = 1.0 / 2.4


def _glsl_float(value: float) -> str:
    """A GLSL float literal holding exactly the float32 value numpy uses."""
    return np.format_float_positional(FLOAT(value), unique=True, trim="0")


# --- the shader's maths: numpy and GLSL side by side ------------------------------------


class _Terms(NamedTuple):
    """The shaper's float32 constants, shared by the numpy and the GLSL code."""

    toe: np.float32        # 2^lo
    toe_slope: np.float32  # 1 / (2^lo ln 2): d log2(a) / da at the toe's top
    lo: np.float32
    l0: np.float32         # L at the toe's foot, a = −2^lo
    l1: np.float32         # hi
    pivot: np.float32
    s0: np.float32         # σ(L0)
    a: np.float32          # weight of (L − L0)
    b: np.float32          # weight of (σ(L) − σ(L0))


@dataclass(frozen=True)
class Shaper:
    """Linear RGB → lattice coordinates u in 0..1 per axis (the module docstring's formula).

    lo, hi : log2 of the toe's top and of the largest axis value resolved
    weight : share of plain log2 spacing; the rest follows the logistic σ
    pivot : log2 of the logistic's midpoint (the axis value at which σ = 1/2)
    basis : the lattice's axes from the rendering space's RGB (rows)
    """

    lo: float = -10.0
    hi: float = 8.0
    weight: float = 0.2
    pivot: float = -2.0
    basis: tuple[tuple[float, float, float], ...] = BASIS

    def terms(self) -> _Terms:
        toe = 2.0 ** self.lo
        l0 = self.lo - 2.0 / math.log(2.0)

        def sigma(level: float) -> float:
            return 1.0 / (1.0 + 2.0 ** (self.pivot - level))

        return _Terms(*map(FLOAT, (toe, 1.0 / (toe * math.log(2.0)), self.lo, l0, self.hi, self.pivot,
                                   sigma(l0), self.weight / (self.hi - l0),
                                   (1.0 - self.weight) / (sigma(self.hi) - sigma(l0)))))

    def apply(self, rgb: np.ndarray) -> np.ndarray:
        """(..., 3) float32 finite linear RGB → (..., 3) float32 u in 0..1 (GLSL: displayLutShaper)."""
        t = self.terms()
        axes = rgb @ np.asarray(self.basis, dtype=FLOAT).T
        level = np.where(axes >= t.toe, np.log2(np.maximum(axes, t.toe)), t.lo + (axes - t.toe) * t.toe_slope)
        return np.clip(self._coordinate(np.clip(level, t.l0, t.l1), t), FLOAT(0.0), FLOAT(1.0))

    @staticmethod
    def _coordinate(level: np.ndarray, t: _Terms) -> np.ndarray:
        """u of a clamped L, in L's dtype (float32 in :meth:`apply`, float64 in :meth:`invert`)."""
        sigma = 1.0 / (1.0 + np.exp2(t.pivot - level))
        return t.a * (level - t.l0) + t.b * (sigma - t.s0)

    def glsl(self) -> str:
        """GLSL ES 3.00 of ``vec3 displayLutShaper(vec3 linearRgb)``, the same maths as :meth:`apply`."""
        t = {name: _glsl_float(value) for name, value in self.terms()._asdict().items()}
        columns = ", ".join(_glsl_float(self.basis[row][column]) for column in range(3) for row in range(3))
        return f"""\
vec3 displayLutShaper(vec3 linearRgb) {{
    const mat3 BASIS = mat3({columns});  // columns
    const float TOE = {t['toe']}, TOE_SLOPE = {t['toe_slope']}, LO = {t['lo']}, L0 = {t['l0']}, L1 = {t['l1']};
    const float PIVOT = {t['pivot']}, S0 = {t['s0']}, A = {t['a']}, B = {t['b']};
    vec3 axes = BASIS * linearRgb;
    vec3 level = mix(LO + (axes - TOE) * TOE_SLOPE, log2(max(axes, vec3(TOE))), greaterThanEqual(axes, vec3(TOE)));
    level = clamp(level, L0, L1);
    vec3 sigma = 1.0 / (1.0 + exp2(PIVOT - level));
    return clamp(A * (level - L0) + B * (sigma - S0), 0.0, 1.0);
}}
"""

    def invert(self, u: np.ndarray) -> np.ndarray:
        """Lattice coordinates (n,) in 0..1 → the axis values (n,) float64 the shaper maps to them."""
        t = self.terms()
        low, high = np.full(np.shape(u), float(t.l0)), np.full(np.shape(u), float(t.l1))
        for _ in range(60):  # bisection: u is increasing in L; 60 halvings reach float64's resolution
            middle = 0.5 * (low + high)
            below = self._coordinate(middle, t) < u
            low, high = np.where(below, middle, low), np.where(below, high, middle)
        level = 0.5 * (low + high)
        return np.where(level >= self.lo, 2.0 ** level, float(t.toe) + (level - self.lo) / float(t.toe_slope))


def _encode(values: np.ndarray) -> np.ndarray:
    """sRGB encoding of (..., 3) float32 display-linear values, ·12.92 below the break and for
    negatives, as OCIO's does (GLSL: displayLutEncode)."""
    power = FLOAT(1.055) * np.power(np.maximum(values, FLOAT(SRGB_BREAK)), FLOAT(SRGB_EXPONENT)) - FLOAT(0.055)
    return np.where(values > FLOAT(SRGB_BREAK), power, values * FLOAT(12.92))


ENCODE_GLSL = f"""\
vec3 displayLutEncode(vec3 v) {{
    vec3 power = 1.055 * pow(max(v, vec3({SRGB_BREAK})), vec3({_glsl_float(SRGB_EXPONENT)})) - 0.055;
    return mix(v * 12.92, power, greaterThan(v, vec3({SRGB_BREAK})));
}}
"""
"""GLSL of :func:`_encode`."""


def _decode(display: np.ndarray) -> np.ndarray:
    """The inverse of :func:`_encode`, in float64 (bake time only)."""
    display = np.asarray(display, dtype=np.float64)
    power = ((np.maximum(display, SRGB_BREAK * 12.92) + 0.055) / 1.055) ** 2.4
    return np.where(display > SRGB_BREAK * 12.92, power, display / 12.92)


def _tetrahedral(table: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(..., 3) lattice coordinates in 0..1 → (..., 3) float32 values of ``table`` (size, size,
    size, 3) [b, g, r], interpolated in the tetrahedron of the cell that holds them (GLSL: the
    body of displayLut, the same float32 operations in the same order).

    The path c000 → c1 → c2 → c111 steps first along the axis of the largest fraction (ties to
    the earlier axis, r before g before b), last along the smallest's (ties to the later axis):
    so the three steps are distinct axes, and c1, c2 and the sorted fractions (exact: max, min
    and the median of three are selections) are the same numbers in numpy and GLSL, ties
    included (a grey's fractions are all equal).
    """
    size = table.shape[0]
    scaled = u * FLOAT(size - 1)
    index = np.minimum(scaled.astype(np.int32), size - 2)  # ivec3() truncates; u ≥ 0
    f = scaled - index.astype(FLOAT)
    fr, fg, fb = f[..., 0], f[..., 1], f[..., 2]
    first_r = (fr >= fg) & (fr >= fb)
    first_g = ~first_r & (fg >= fb)
    first = np.stack([first_r, first_g, ~first_r & ~first_g], axis=-1).astype(np.int32)
    last_b = (fb <= fr) & (fb <= fg)
    last_g = ~last_b & (fg <= fr)
    last = np.stack([~last_b & ~last_g, last_g, last_b], axis=-1).astype(np.int32)
    high = np.maximum(fr, np.maximum(fg, fb))[..., None]
    low = np.minimum(fr, np.minimum(fg, fb))[..., None]
    middle = np.maximum(np.minimum(fr, fg), np.minimum(np.maximum(fr, fg), fb))[..., None]
    flat = table.reshape(-1, 3)

    def texel(at: np.ndarray) -> np.ndarray:
        return flat[(at[..., 2] * size + at[..., 1]) * size + at[..., 0]]

    c0, c1, c2, c3 = texel(index), texel(index + first), texel(index + 1 - last), texel(index + 1)
    return c0 + (c1 - c0) * high + (c2 - c1) * middle + (c3 - c2) * low


LUT_GLSL = f"""\
vec3 displayLut(vec3 linearRgb, highp sampler3D lut) {{
    // NaN -> 0 and +-inf -> +-65504, as the previews do before their OCIO processor
    vec3 rgb = clamp(mix(linearRgb, vec3(0.0), isnan(linearRgb)), -{_glsl_float(HALF_MAX)}, {_glsl_float(HALF_MAX)});
    int size = textureSize(lut, 0).x;
    vec3 scaled = displayLutShaper(rgb) * float(size - 1);
    ivec3 index = min(ivec3(scaled), ivec3(size - 2));
    vec3 f = scaled - vec3(index);
    // the tetrahedron: first the largest fraction's axis (ties to the earlier), last the
    // smallest's (ties to the later); chosen with step(), as SwiftShader runs both sides of a branch
    float firstR = step(f.y, f.x) * step(f.z, f.x);
    float firstG = (1.0 - firstR) * step(f.z, f.y);
    ivec3 first = ivec3(vec3(firstR, firstG, (1.0 - firstR) * (1.0 - firstG)));
    float lastB = step(f.z, f.x) * step(f.z, f.y);
    float lastG = (1.0 - lastB) * step(f.y, f.x);
    ivec3 last = ivec3(vec3((1.0 - lastB) * (1.0 - lastG), lastG, lastB));
    float high = max(f.x, max(f.y, f.z));
    float low = min(f.x, min(f.y, f.z));
    float middle = max(min(f.x, f.y), min(max(f.x, f.y), f.z));
    vec3 c0 = texelFetch(lut, index, 0).rgb;
    vec3 c1 = texelFetch(lut, index + first, 0).rgb;
    vec3 c2 = texelFetch(lut, index + ivec3(1) - last, 0).rgb;
    vec3 c3 = texelFetch(lut, index + ivec3(1), 0).rgb;
    return clamp(displayLutEncode(c0 + (c1 - c0) * high + (c2 - c1) * middle + (c3 - c2) * low), 0.0, 1.0);
}}
"""
"""GLSL of :func:`apply_display_lut` after the shaper (texture x = r, y = g, z = b)."""


# --- the baked LUT ------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class DisplayLut:
    """One display/view baked for the shader.

    table : (size, size, size, 3) float32 [b, g, r] (r fastest in memory, as :func:`lut_bytes`
            gives it), read-only: the processor's output at the lattice points, sRGB-decoded
    shaper : how linear RGB finds its lattice coordinates
    config, display, view, rendering_space : the colour settings it was baked from
    max_error : the largest |LUT − processor| over the bake's probe colours, in 8-bit codes
    """

    table: np.ndarray
    shaper: Shaper
    config: str
    display: str
    view: str
    rendering_space: str
    max_error: float

    @property
    def size(self) -> int:
        return self.table.shape[0]


@lru_cache(maxsize=4)
def bake_display_lut(config: str = DEFAULT_OCIO_CONFIG, display: str = DEFAULT_DISPLAY, view: str = DEFAULT_VIEW,
                     rendering_space: str = RENDERING_SPACE, size: int = DEFAULT_SIZE) -> DisplayLut:
    """Bake the previews' processor for these settings into a ``size``³ LUT (cached).

    Raises :class:`~pxr_layers.layers.previews.ColourError` for a config, display, view or
    colour space that does not exist (the previews' own check).
    """
    if size < 2:
        raise ValueError(f"a display LUT needs at least 2 lattice points per axis, not {size}")
    started = time.perf_counter()
    processor = display_processor(config, display, view, rendering_space)
    shaper = Shaper()
    axis = shaper.invert(np.linspace(0.0, 1.0, size))
    b, g, r = np.meshgrid(axis, axis, axis, indexing="ij")
    lattice = np.stack([r, g, b], axis=-1).reshape(-1, 3) @ np.linalg.inv(np.asarray(shaper.basis)).T
    pixels = np.ascontiguousarray(lattice, dtype=FLOAT)
    processor.applyRGB(pixels)
    table = _decode(pixels).astype(FLOAT).reshape(size, size, size, 3)
    table.flags.writeable = False
    unmeasured = DisplayLut(table, shaper, config, display, view, rendering_space, math.nan)
    probe = _probe_colours()
    expected = probe.copy()
    processor.applyRGB(expected)
    error = float(np.abs(apply_display_lut(unmeasured, probe) - np.clip(expected, 0.0, 1.0)).max()) * 255.0
    lut = replace(unmeasured, max_error=error)
    seconds = time.perf_counter() - started
    (logger.warning if error >= 1.0 else logger.debug)(
        "display LUT %d³ for %s / %s / %s from %s: %.2f s, worst %.2f codes on the probe colours%s",
        size, config, display, view, rendering_space, seconds, error,
        " (the inspector may differ from the previews by more than one code)" if error >= 1.0 else "")
    return lut


def _probe_colours() -> np.ndarray:
    """(n, 1, 3) float32 colours where the LUT is hardest: seeded random, each channel
    log2-uniform over −12..9 or zero (one in five), and a grey ramp 2^-12..2^12."""
    rng = np.random.default_rng(0)
    colours = 2.0 ** rng.uniform(-12.0, 9.0, (1 << 14, 3))
    colours[rng.random(colours.shape) < 0.2] = 0.0
    grey = np.repeat(2.0 ** np.linspace(-12.0, 12.0, 1024)[:, None], 3, axis=1)
    return np.concatenate([colours, grey]).astype(FLOAT)[:, None, :]


def apply_display_lut(lut: DisplayLut, rgb: np.ndarray) -> np.ndarray:
    """What the shader shows: (h, w, 3|4) linear RGB in the rendering space (alpha ignored)
    → (h, w, 3) float32 display values in 0..1 (the canvas, and previews._quantise, round ·255).

    NaN becomes 0 and ±inf ±65504 first, as :func:`~pxr_layers.layers.previews.to_display` does.
    """
    pixels = np.asarray(rgb)[..., :3].astype(FLOAT)
    pixels = np.clip(np.nan_to_num(pixels, nan=0.0), -HALF_MAX, HALF_MAX)
    return np.clip(_encode(_tetrahedral(lut.table, lut.shaper.apply(pixels))), FLOAT(0.0), FLOAT(1.0))


def lut_glsl(lut: DisplayLut) -> str:
    """GLSL ES 3.00 source of ``vec3 displayLut(vec3 linearRgb, highp sampler3D lut)`` and its
    helpers (names start with displayLut). Insert it after the shader's ``#version 300 es``
    line; ``lut`` is :func:`lut_bytes` as a 3D RGB32F texture (x = r, y = g, z = b)."""
    return ("// pxr-layers display LUT (pxr_layers/layers/display_lut.py)\n"
            "precision highp float;\nprecision highp int;\nprecision highp sampler3D;\n\n"
            + lut.shaper.glsl() + "\n" + ENCODE_GLSL + "\n" + LUT_GLSL)


def lut_description(lut: DisplayLut) -> dict:
    """The LUT for the browser (JSON-able): its size, the shaper's parameters (for reading:
    the GLSL already holds them), its measured error and the GLSL. Where the browser fetches
    :func:`lut_bytes` is the server's to add."""
    shaper = lut.shaper
    return {
        "size": lut.size,
        "shaper": {"kind": "log2-logistic", "basis": [list(row) for row in shaper.basis], "lo": shaper.lo,
                   "hi": shaper.hi, "weight": shaper.weight, "pivot": shaper.pivot, "table": "sRGB-decoded"},
        "max_error": round(lut.max_error, 3),
        "glsl": lut_glsl(lut),
    }


def lut_bytes(lut: DisplayLut) -> bytes:
    """The table as the browser's texture takes it: little-endian float32, element
    ``((b·size + g)·size + r)·3 + c``."""
    return lut.table.astype("<f4", copy=False).tobytes()
