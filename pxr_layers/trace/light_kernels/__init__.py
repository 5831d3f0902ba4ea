"""Per-lane light functions of the kernels: light sampling for next-event estimation and
light densities for multiple importance sampling, one module per light type with its sample
and pdf side by side (after Cycles' kernel/light/). The tables they read are built once per
frame on the host (trace/lights.py: LightSampler); table.py declares them.

    dispatch.py      sample (pick a source, sample it), emitter_pdf (a hit emitter's density)
    triangle.py      emitting triangles (area lights, emissive surfaces): emitted, sample, pdf
    sphere.py        sphere lights by solid angle: sample, pdf
    point.py         point and line lights (delta): sample
    distant.py       distant lights (delta or cone): sample, pdf
    dome.py          dome lights (lat-long map): radiance, sample, pdf
    shaping.py       ShapingAPI and IES profiles: what a light sends toward a direction
    linking.py       light and shadow links, camera visibility, diffuse/specular multipliers
    distribution.py  inverse cdf, uniform cone
    table.py         LightArrays, EmissionTable and their column constants
"""

from .dispatch import emitter_pdf, sample
from .distant import cone_pdf
from .dome import dome_pdf, dome_radiance
from .linking import blocks, found_by_hit, group_of, lit, response
from .table import EmissionTable, LightArrays
from .triangle import emitted

__all__ = ["EmissionTable", "LightArrays", "blocks", "cone_pdf", "dome_pdf", "dome_radiance", "emitted",
           "emitter_pdf", "found_by_hit", "group_of", "lit", "response", "sample"]
