"""The standard light passes, as expressions: what artists expect out of the box.

``STANDARD_PASSES`` split the beauty ``C.*`` of every path that ends at an emitter: each
path ``C (R|T|V)* [LOB]`` matches exactly one of them, so their sum is the beauty. The
split is decided by the first event after the camera, then by direct (one bounce) versus
indirect (more). See docs/lpe.md for the differences from the table of LPE.md.
"""

from __future__ import annotations

from collections.abc import Mapping

BEAUTY = "C.*"

STANDARD_PASSES = {
    "emission": "C[LO]",
    "background": "CB",
    "diffuse_direct": "C<RD>[LOB]",
    "diffuse_indirect": "C<RD>.+[LOB]",
    "glossy_direct": "C<R[^D]>[LOB]",
    "glossy_indirect": "C<R[^D]>.+[LOB]",
    "transmission": "C<T.>.*",
    "volume": "C<V.>.*",
}
"""Layer name → expression. Glossy takes every reflection that is not diffuse (G, S and
the rare s), the background counts as an emitter seen after a bounce (a dome), and volumes
have their own pass, so that nothing falls between two passes."""

OTHER_EMITTERS_LAYER = "light_other"


def per_light_passes(groups) -> dict[str, str]:
    """One layer per light group (``light_<group>`` = ``C.*<L.'group'>``) plus ``light_other``.

    groups : labels, one layer each named after it; or a mapping name → labels, one layer
             ``light_<name>`` per group with its labels in one label set (``C.*<L.['a''b']>``)

    ``light_other`` takes paths that end at a light of no listed group, at an emissive
    object or in the background, so the split is complete too (as long as a light carries
    at most one of the listed group labels).
    """
    if isinstance(groups, Mapping):
        sets = {name: tuple(labels) for name, labels in groups.items() if labels}
    else:
        sets = {group: (group,) for group in dict.fromkeys(groups)}
    layers = {f"light_{name}": f"C.*<L.{_label_set(labels)}>" for name, labels in sets.items()}
    listed = "".join(f"'{label}'" for label in dict.fromkeys(label for labels in sets.values() for label in labels))
    layers[OTHER_EMITTERS_LAYER] = f"C.*<L.[^{listed}]>|C.*[OB]" if listed else "C.*[LOB]"
    return layers


def _label_set(labels: tuple[str, ...]) -> str:
    return f"'{labels[0]}'" if len(labels) == 1 else "[" + "".join(f"'{label}'" for label in labels) + "]"
