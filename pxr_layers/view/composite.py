"""The regrade rule of the inspector, in numpy: what the page's fragment shader computes
(static/app.js), kept here as the reference the tests compare the page against, and what
the saved Nuke script rebuilds (layers/nuke.py).

    no layer soloed:   out = beauty + Σ_i (w_i − 1) · layer_i
    some layer soloed: out = Σ_{i soloed} w_i · layer_i
    then · 2^exposure

with the weight w_i = 1 + m_i · (g_i − 1), g_i = 2^stops_i · tint_i (0 if muted) and m_i the
layer's mask (LayerGrade.mask: the Cryptomatte coverage of its names at the pixel, in
[0, 1]; m_i = 1 for a layer without a mask, whose w_i is g_i): the grade inside the mask,
unity outside. At unit gains the first form is the beauty itself, bit for bit, whether or
not the layers partition it; when they do, it is the sum of the graded layers.

In float32, in this order (the shader's; static/app.js does not key masks yet and is to
follow it when it does): an unmasked layer adds (g − 1) · layer, or g · layer
when soloed; a masked one (m · (g − 1)) · layer, or (m · g + (1 − m)) · layer when soloed, both
exact where m is 0 (the layer as it is) or 1 (as if unmasked).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..layers.nuke import LayerGrade


def composite(beauty: np.ndarray, layers: Sequence[np.ndarray], grades: Sequence[LayerGrade],
              exposure: float = 0.0, masks: Sequence[np.ndarray | None] | None = None) -> np.ndarray:
    """beauty : (h, w, 3) float32 linear; layers : (h, w, 3) float32 each, with its grade and
    its mask: (h, w) float32 in [0, 1] for a grade with a mask (the coverage of its names,
    layers.cryptomatte.coverage), None for one without (``masks`` None: no layer has one).
    Returns (h, w, 3) float32 linear, before the display transform (float32 arithmetic, in
    the shader's order: layer by layer)."""
    masks = [None] * len(layers) if masks is None else list(masks)
    if len(masks) != len(layers):
        raise ValueError(f"{len(masks)} masks for {len(layers)} layers")
    soloed = any(grade.solo for grade in grades)
    out = np.zeros_like(beauty, dtype=np.float32) if soloed else np.array(beauty, dtype=np.float32)
    one = np.float32(1.0)
    for layer, grade, mask in zip(layers, grades, masks, strict=True):
        multiplier = np.zeros(3, np.float32) if grade.mute else np.asarray(grade.multiply, np.float32)
        if mask is None:
            weight = multiplier if soloed else multiplier - one
        else:
            m = np.asarray(mask, np.float32)[..., None]
            weight = m * multiplier + (one - m) if soloed else m * (multiplier - one)
        if soloed:
            if grade.solo:
                out += weight * layer
        else:
            out += weight * layer
    return out * np.float32(2.0 ** exposure)
