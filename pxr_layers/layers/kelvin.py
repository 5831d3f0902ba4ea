"""A grade's colour temperature: the blackbody colour a UsdLux light with
``enableColorTemperature`` gets in our renderer, as a multiplier of a layer.

:func:`blackbody` is ``pxr_layers.stage.lights.blackbody_rgb`` (the one definition: Gf's
Planckian locus in linear Rec.709, of luminance 1, as hdEmbree computes it), imported when
first asked for, so that grading does not import USD. :func:`kelvin_table` is that function
at every step of the inspector's Kelvin slider, so the page multiplies by exactly the values
a pushed light (``pxr_layers/stage/light_overrides.py``) renders with.
"""

from __future__ import annotations

import functools
import math

KELVIN_MIN, KELVIN_MAX = 1000.0, 15000.0
"""The temperatures a grade takes, in Kelvin: where Gf's Planckian locus is defined
(it clamps beyond, so other values would give the colour of the nearest end). A light's own
``colorTemperature`` is accepted from 1 K (stage/lights.py); a grade's, within this range."""
KELVIN_STEP = 100.0
"""The inspector's slider step, in Kelvin: the table has one row per step."""


def check_kelvin(kelvin) -> float | None:
    """``kelvin`` as a float within [KELVIN_MIN, KELVIN_MAX], or None (no temperature);
    ValueError naming the range otherwise."""
    if kelvin is None:
        return None
    if isinstance(kelvin, bool) or not isinstance(kelvin, (int, float)) or not math.isfinite(kelvin) \
            or not KELVIN_MIN <= kelvin <= KELVIN_MAX:
        raise ValueError(f"kelvin must be none or a temperature from {KELVIN_MIN:g} to {KELVIN_MAX:g} K, "
                         f"not {kelvin!r}")
    return float(kelvin)


@functools.lru_cache(maxsize=4096)
def blackbody(kelvin: float) -> tuple[float, float, float]:
    """(r, g, b) linear Rec.709 of luminance 1: stage.lights.blackbody_rgb(kelvin)."""
    from ..stage.lights import blackbody_rgb  # USD is imported only when a temperature is used

    return tuple(float(channel) for channel in blackbody_rgb(kelvin))


@functools.cache
def kelvin_table() -> dict:
    """The browser's table: ``{"min": K0, "max": K1, "step": 100, "rgb": [[r, g, b], ...]}``,
    row k being :func:`blackbody` of K0 + k·step (K1 the last row)."""
    steps = int(round((KELVIN_MAX - KELVIN_MIN) / KELVIN_STEP))
    return {"min": KELVIN_MIN, "max": KELVIN_MAX, "step": KELVIN_STEP,
            "rgb": [list(blackbody(KELVIN_MIN + k * KELVIN_STEP)) for k in range(steps + 1)]}
