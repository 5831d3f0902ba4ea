"""The regrade rule of the inspector, in numpy: what the page's fragment shader computes
(static/app.js), kept here as the reference the tests compare the page against, and what
the saved Nuke script rebuilds (layers/nuke.py).

    no layer soloed:   out = beauty + Σ_i (gain_i · tint_i − 1) · layer_i     (muted: gain_i = 0)
    some layer soloed: out = Σ_{i soloed, not muted} gain_i · tint_i · layer_i
    then · 2^exposure

with gain_i = 2^stops_i. At unit gains the first form is the beauty itself, bit for bit,
whether or not the layers partition it; when they do, it is the sum of the graded layers.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..layers.nuke import LayerGrade


def composite(beauty: np.ndarray, layers: Sequence[np.ndarray], grades: Sequence[LayerGrade],
              exposure: float = 0.0) -> np.ndarray:
    """beauty : (h, w, 3) float32 linear; layers : (h, w, 3) float32 each, with its grade.
    Returns (h, w, 3) float32 linear, before the display transform (float32 arithmetic, in
    the shader's order: layer by layer)."""
    soloed = any(grade.solo for grade in grades)
    out = np.zeros_like(beauty, dtype=np.float32) if soloed else np.array(beauty, dtype=np.float32)
    for layer, grade in zip(layers, grades, strict=True):
        multiplier = np.zeros(3, np.float32) if grade.mute else np.asarray(grade.multiply, np.float32)
        if soloed:
            if grade.solo:
                out += multiplier * layer
        else:
            out += (multiplier - np.float32(1.0)) * layer
    return out * np.float32(2.0 ** exposure)
