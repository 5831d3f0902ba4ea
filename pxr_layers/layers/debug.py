"""``--debug-covariance`` pictures: the first bounce's C, T and R as an EXR and as PNGs.

The EXR keeps the values (channels C in 1/m, T in cycles/m, R in cycles/rad; NaN where
no sample's first event scattered). Each PNG maps one norm through a viridis-like colour
ramp, dark = 0, so a person sees at a glance that walls are flat, the sphere is curved,
textured regions differ and glossy beats diffuse. C and T are mapped linearly from 0 to
their largest value, R logarithmically (it spans 0 to ~1600); the range is written in the
PNG's description.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from .exr import write_channels
from .previews import write_png

log = logging.getLogger(__name__)

NORMS = (("C", "1/m", False), ("T", "cycles/m", False), ("R", "cycles/rad", True))
# viridis at 0, 0.25, 0.5, 0.75, 1 (sRGB-encoded display values)
_RAMP = np.array([[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551],
                  [0.369, 0.789, 0.383], [0.993, 0.906, 0.144]])
_NO_DATA = np.array([0.5, 0.5, 0.5])


def write_covariance_debug(beauty: Path, norms: np.ndarray, metadata: dict[str, str]) -> list[Path]:
    """Write STEM.covariance.exr and STEM.covariance.{C,T,R}.png beside `beauty`.

    norms : (h, w, 3) float32 first-bounce C, T, R. Returns the paths written.
    """
    stem = beauty.with_suffix("")
    exr = write_channels(stem.with_name(stem.name + ".covariance.exr"),
                         {name: norms[..., index] for index, (name, _, _) in enumerate(NORMS)}, metadata)
    written = [exr]
    for index, (name, unit, logarithmic) in enumerate(NORMS):
        values = norms[..., index].astype(np.float64)
        finite = np.isfinite(values)
        top = float(values[finite].max()) if finite.any() else 0.0
        if logarithmic:
            scaled = np.log1p(np.where(finite, values, 0.0)) / max(np.log1p(top), 1e-12)
        else:
            scaled = np.where(finite, values, 0.0) / (top if top > 0 else 1.0)
        rgb = colour_ramp(scaled)
        rgb[~finite] = _NO_DATA
        scale = "log(1 + value)" if logarithmic else "linear"
        description = f"first-bounce {name} in {unit}, {scale} from 0 (dark) to {top:.4g} (yellow); grey: no data"
        path = stem.with_name(f"{stem.name}.covariance.{name}.png")
        write_png(path, np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8), description)
        written.append(path)
    log.info("wrote covariance debug images %s", ", ".join(str(p) for p in written))
    return written


def colour_ramp(values: np.ndarray) -> np.ndarray:
    """(…) values in [0, 1] -> (…, 3) display RGB on the viridis-like ramp."""
    position = np.clip(values, 0.0, 1.0) * (len(_RAMP) - 1)
    low = np.minimum(np.floor(position).astype(int), len(_RAMP) - 2)
    fraction = (position - low)[..., None]
    return _RAMP[low] * (1 - fraction) + _RAMP[low + 1] * fraction


