"""Per-light layers: one layer per light (or light group) plus ``light_other``; pure Python.

A light event of the path index carries the light's prim name and prim path as labels, so
``C.*<L.'key'>`` takes every path that ends at the light called key. A group of several
lights lists them in a label set, ``C.*<L.['key''rim']>``. ``light_other`` takes the rest:
paths that end at a light of no listed group, at an emissive object (O) or in the
background (B). So the per-light layers add up to the beauty, as the standard passes do.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping

from ..errors import RecipeError
from .model import Layer

LIGHT_LAYER_PREFIX = "light_"
OTHER_LIGHTS_LAYER = "light_other"  # lpe.passes.OTHER_EMITTERS_LAYER
LIGHTS_GROUP = "lights"
"""The ``group`` of generated per-light layers."""


def per_light_layers(lights: Iterable[str] | Mapping[str, Iterable[str]], *, group: str = LIGHTS_GROUP,
                     **layer_fields) -> tuple[Layer, ...]:
    """Layers ``light_<name>`` = ``C.*<L.'name'>`` for each light, then ``light_other``.

    lights : light labels (prim names, prim paths or globs such as ``'/World/Lights/rim*'``),
             one layer each; or a mapping group name → labels, one layer per group (the
             group's lights in one label set)
    group  : the layers' ``group`` field; layer_fields: other :class:`Layer` fields
             (pixel_type, compression, preview, ...) given to every layer

    Layer names are ``light_`` + the group name or the label's last path component, made
    an identifier (other characters become ``_``). Raises RecipeError when two lights would
    give the same layer name, or a label holds a quote.
    """
    if isinstance(lights, Mapping):
        groups = {str(name): tuple(str(label) for label in labels) for name, labels in lights.items()}
    else:
        groups = {str(label): (str(label),) for label in lights}
    # Imported here: the recipe model does not load the LPE compiler.
    from ..lpe.passes import per_light_passes

    names: dict[str, str] = {}  # layer name → the group (or label) it was made from
    sets: dict[str, tuple[str, ...]] = {}
    for group_name, labels in groups.items():
        if not labels:
            continue
        for label in labels:
            if "'" in label or not label:
                raise RecipeError(f"light label {label!r} cannot be quoted in an expression")
        name = _identifier(group_name.rstrip("/").rsplit("/", 1)[-1])
        layer_name = LIGHT_LAYER_PREFIX + name  # as per_light_passes names it
        if layer_name in names or layer_name == OTHER_LIGHTS_LAYER:
            raise RecipeError(f"lights {names.get(layer_name, layer_name)!r} and {group_name!r} would both "
                              f"make layer {layer_name!r}: list them by prim path in a mapping of groups")
        names[layer_name] = group_name
        sets[name] = labels
    return tuple(Layer(name, "lpe", expression, group=group, **layer_fields)
                 for name, expression in per_light_passes(sets).items())


def _identifier(text: str) -> str:
    name = re.sub(r"[^A-Za-z0-9_]", "_", text)
    return name if name else "_"
