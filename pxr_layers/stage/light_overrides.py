"""Push a look back into the shot: grades of whole lights as a USD override layer on the
UsdLux lights, and a shot file that renders the stage with it.

A layer that holds exactly the paths of one light (or of every light of one
``pxrLayers:lightGroup``; ``pxr_layers/view/push.py`` decides) graded by ``2^stops · tint ·
blackbody(kelvin)`` renders the same as the light with, in our renderer (stage/lights.py:
radiance = intensity · 2^exposure · color · blackbody(colorTemperature) / sizeFactor)::

    inputs:exposure   += stops
    inputs:color      *= tint
    kelvin, the light's temperature off: inputs:enableColorTemperature = true,
                                         inputs:colorTemperature = kelvin
    kelvin, the light's temperature on:  inputs:color *= blackbody(kelvin) as well (its own
                                         temperature stays: the product is the grade's colour)
    mute:                                inputs:intensity = 0 (nothing else)

:func:`write_push` writes ``NAME.lights.usda`` (only ``over`` prims with the changed
attributes, and customLayerData saying what it is) and ``NAME.shot.usda`` (subLayers
``[NAME.lights.usda, the stage]``, relative when possible, with the stage root layer's
metadata, upAxis, metersPerUnit, time codes, renderSettingsPrimPath, ..., which USD reads from
the root layer only, and the render's variant selections), together or not at all, so that
``pxr-layers render NAME.shot.usda`` renders the shot with the pushed look.

What cannot be written exactly is refused with its reason rather than written wrong
(:attr:`ShotLight.problem`): an attribute the edit needs that is animated (time samples: an
``over`` with one value would flatten the animation) or connected (its value comes from
elsewhere), a light inside a native instance (an instance proxy takes no opinions), a light
of the default rig (the renderer makes it; it is not in the stage). A stage whose root
layer changed since the render (its SHA-256, the index manifest's ``stage_sha256``) is
refused as a whole: the index's values would no longer be the stage's.
"""

from __future__ import annotations

import functools
import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from pxr import Gf, Sdf, Usd, UsdLux

from ..errors import OutputError, StageError
from ..outputs import OutputSet, reading, write_atomically
from ..request import VariantSelection
from .defaults import is_ours
from .lights import blackbody_rgb
from .opening import resolve_time, trapped_usd_diagnostics

logger = logging.getLogger(__name__)

LIGHTS_SUFFIX = ".lights.usda"
SHOT_SUFFIX = ".shot.usda"
_SKIPPED_ROOT_FIELDS = frozenset({"subLayers", "subLayerOffsets", "documentation", "comment", "customLayerData",
                                  "primChildren", "expressionVariables"})
"""Root layer fields the shot file does not copy from the stage (it has its own)."""


@dataclass(frozen=True)
class ShotLight:
    """A light of the shot as the render saw it (at the index's frame).

    path, name : the prim's; group : its pxrLayers:lightGroup ("" none)
    intensity, exposure, color, enable_temperature, temperature : the UsdLux values
    animated, connected : names of those attributes that are time-sampled / connected
    problem : why no override can be written on it at all (None: it can)
    """

    path: str
    name: str
    group: str
    intensity: float
    exposure: float
    color: tuple[float, float, float]
    enable_temperature: bool
    temperature: float
    animated: tuple[str, ...] = ()
    connected: tuple[str, ...] = ()
    problem: str | None = None


@dataclass(frozen=True)
class LightChange:
    """One pushed grade on lights. paths : the light prims; layer : the stack entry it comes
    from (named in the written layer); stops, tint, kelvin, mute : the grade (nuke.LayerGrade's)."""

    paths: tuple[str, ...]
    layer: str
    stops: float = 0.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    kelvin: float | None = None
    mute: bool = False

    @property
    def changes_nothing(self) -> bool:
        return not self.mute and self.stops == 0.0 and tuple(self.tint) == (1.0, 1.0, 1.0) and self.kelvin is None


def check_stage(manifest: Mapping) -> Path:
    """The stage file the index was rendered from; StageError (one line) when it is gone or
    changed since (its SHA-256 is not the manifest's ``stage_sha256``)."""
    from ..jobs.frame import file_sha256  # the render's own hash of the stage

    stage = manifest.get("stage")
    if not stage:
        raise StageError("the index names no stage (not written by `pxr-layers render`?): nothing to push into")
    path = Path(stage)
    try:
        digest = file_sha256(path)
    except OSError as error:
        raise StageError(f"cannot read the stage the index was rendered from ({error.strerror or error})",
                         file=str(path)) from None
    if manifest.get("stage_sha256") and digest != manifest["stage_sha256"]:
        raise StageError("changed since the render (its SHA-256 is not the index's): the lights' values the "
                         "look was graded on are no longer the stage's; render again, then push", file=str(path))
    return path


def read_shot_lights(manifest: Mapping) -> dict[str, ShotLight]:
    """prim path → ShotLight of every light the render saw (the walk's rule, Shot.lights), read
    at the index's frame with its variant selections. Raises StageError (check_stage)."""
    path = check_stage(manifest)
    frame = None if manifest.get("frame", "default") == "default" else float(manifest["frame"])
    return dict(_read_lights(path, _stage_digest(manifest), frame, _variants(manifest),
                             manifest.get("defaultLights") != "false"))


def _stage_digest(manifest: Mapping) -> str:
    return str(manifest.get("stage_sha256", ""))


@functools.lru_cache(maxsize=4)
def _read_lights(path: Path, digest: str, frame: float | None, variants: tuple[VariantSelection, ...],
                 default_lights: bool) -> tuple[tuple[str, ShotLight], ...]:
    """read_shot_lights' work, once per stage file contents (`digest`, checked by the caller):
    the inspector asks on every change of the stack, and a big shot takes seconds to compose."""
    from .shot import open_shot

    shot = open_shot(path, variants=variants, default_lights=default_lights)
    found = {}
    with trapped_usd_diagnostics(str(path)):
        time, _ = resolve_time(shot.stage, frame)
        for name, prim_path, group in shot.lights(frame=frame):
            found[prim_path] = _shot_light(shot.stage.GetPrimAtPath(prim_path), name, group, time)
    return tuple(found.items())


def _variants(manifest: Mapping) -> tuple[VariantSelection, ...]:
    return tuple(VariantSelection.parse(text, where="the index's variants")
                 for text in str(manifest.get("variants", "")).split())


def _attributes(light: UsdLux.LightAPI) -> dict[str, Usd.Attribute]:
    return {"intensity": light.GetIntensityAttr(), "exposure": light.GetExposureAttr(), "color": light.GetColorAttr(),
            "enableColorTemperature": light.GetEnableColorTemperatureAttr(),
            "colorTemperature": light.GetColorTemperatureAttr()}


def _shot_light(prim: Usd.Prim, name: str, group: str, time: Usd.TimeCode) -> ShotLight:
    light = UsdLux.LightAPI(prim)
    attributes = _attributes(light)
    values = {key: attribute.Get(time) for key, attribute in attributes.items()}
    animated = tuple(key for key, attribute in attributes.items() if attribute.GetNumTimeSamples() > 0)
    connected = tuple(key for key, attribute in attributes.items() if attribute.HasAuthoredConnections())
    problem = None
    if is_ours(prim.GetPath()):
        problem = "a light of the default rig (the renderer adds it to a stage without lights; it is not in the stage)"
    elif prim.IsInstanceProxy():
        problem = "inside a native instance (its prototype is shared: an instance proxy takes no overrides)"
    color = values["color"]
    return ShotLight(str(prim.GetPath()), name, group, float(values["intensity"] if values["intensity"] is not None else 1.0),
                     float(values["exposure"] or 0.0), tuple(float(c) for c in (color if color is not None else (1, 1, 1))),
                     bool(values["enableColorTemperature"]), float(values["colorTemperature"] or 6500.0),
                     animated, connected, problem)


def planned_edits(change: LightChange, light: ShotLight) -> dict[str, object]:
    """The attributes (UsdLux names without ``inputs:``) `change` writes on `light`, with their
    new values; StageError naming the light when they cannot be written exactly."""
    if light.problem:
        raise StageError(f"cannot push {change.layer!r}: {light.problem}", prim=light.path)
    if change.mute:
        edits: dict[str, object] = {"intensity": 0.0}
    else:
        edits = {}
        if change.stops:
            edits["exposure"] = light.exposure + change.stops
        factor = tuple(float(channel) for channel in change.tint)
        if change.kelvin is not None:
            if light.enable_temperature:
                warm = blackbody_rgb(change.kelvin)
                factor = tuple(channel * float(w) for channel, w in zip(factor, warm, strict=True))
            else:
                edits["enableColorTemperature"] = True
                edits["colorTemperature"] = float(change.kelvin)
        if factor != (1.0, 1.0, 1.0):
            edits["color"] = tuple(c * f for c, f in zip(light.color, factor, strict=True))
    for attribute in edits:
        if attribute in light.animated:
            raise StageError(f"cannot push {change.layer!r}: its {attribute} is animated (time samples), and an "
                             "override of one value would flatten the animation", prim=light.path)
        if attribute in light.connected:
            raise StageError(f"cannot push {change.layer!r}: its {attribute} is connected (its value comes from "
                             "another prim)", prim=light.path)
    return edits


def write_push(folder: Path, name: str, manifest: Mapping, changes: Sequence[LightChange],
               lights: Mapping[str, ShotLight], *, overwrite: bool = False,
               description: str = "") -> tuple[dict[str, Path], dict[str, dict[str, object]]]:
    """Write ``NAME.lights.usda`` and ``NAME.shot.usda`` into `folder`, together or not at all.

    changes : the light edits (each light in one change at most); lights : read_shot_lights'.
    Returns ({"lights": path, "shot": path}, {prim path: {attribute: new value}}). Raises
    StageError when the stage changed or a change cannot be written (planned_edits), OutputError
    when the files exist (and not `overwrite`) or cannot be written.
    """
    stage = check_stage(manifest)
    edits: dict[str, dict[str, object]] = {}
    sources: dict[str, str] = {}
    for change in changes:
        for path in change.paths:
            if path not in lights:
                raise StageError(f"cannot push {change.layer!r}: the stage has no light there now", prim=path)
            if path in edits:
                raise StageError(f"layers {sources[path]!r} and {change.layer!r} both push to this light",
                                 prim=path)
            sources[path] = change.layer
            edits[path] = planned_edits(change, lights[path])
    paths = {"lights": folder / f"{name}{LIGHTS_SUFFIX}", "shot": folder / f"{name}{SHOT_SUFFIX}"}
    existing = [path.name for path in paths.values() if path.exists()]
    if existing and not overwrite:
        raise OutputError(f"{', '.join(existing)} exist in {folder}: push under another name, or overwrite")
    with trapped_usd_diagnostics(str(stage)):
        overrides = _lights_layer(name, stage, edits, sources, description)
        shot = _shot_layer(name, stage, folder, _variants(manifest))
    with reading(stage), OutputSet():
        for key, layer in (("lights", overrides), ("shot", shot)):
            _export(layer, paths[key])
    with trapped_usd_diagnostics(str(stage)):
        for path in paths.values():
            if held := Sdf.Layer.Find(str(path)):  # a layer of this path held open would hide the new file
                held.Reload(force=True)
    logger.info("pushed %d lights: %s, %s", sum(1 for e in edits.values() if e), *(p.name for p in paths.values()))
    return paths, edits


def _lights_layer(name: str, stage: Path, edits: Mapping[str, Mapping[str, object]], sources: Mapping[str, str],
                  description: str) -> Sdf.Layer:
    layer = Sdf.Layer.CreateAnonymous(LIGHTS_SUFFIX)
    layer.documentation = (f"pxr-layers push {name!r}: the inspector's grades of whole lights as overrides of the "
                           f"UsdLux lights of {stage.name}. " + description).strip()
    layer.customLayerData = {"pxrLayers": {"kind": "light overrides", "stage": str(stage),
                                           "layers": {path: sources[path] for path in edits if edits[path]}}}
    types = {"intensity": Sdf.ValueTypeNames.Float, "exposure": Sdf.ValueTypeNames.Float,
             "color": Sdf.ValueTypeNames.Color3f, "enableColorTemperature": Sdf.ValueTypeNames.Bool,
             "colorTemperature": Sdf.ValueTypeNames.Float}
    for path, attributes in edits.items():
        if not attributes:
            continue
        spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(path))
        spec.SetInfo("comment", f"from layer {sources[path]}")
        for attribute, value in attributes.items():
            attribute_spec = Sdf.AttributeSpec(spec, f"inputs:{attribute}", types[attribute])
            attribute_spec.default = Gf.Vec3f(*value) if attribute == "color" else value
    return layer


def _shot_layer(name: str, stage: Path, folder: Path, variants: Sequence[VariantSelection]) -> Sdf.Layer:
    """The shot file: the overrides over the stage, with the stage root layer's metadata
    (which USD reads from the root layer only) and the render's variant selections."""
    root = Sdf.Layer.FindOrOpen(str(stage))
    if root is None:
        raise StageError("cannot open as USD", file=str(stage))
    layer = Sdf.Layer.CreateAnonymous(SHOT_SUFFIX)
    for key in root.pseudoRoot.ListInfoKeys():
        if key not in _SKIPPED_ROOT_FIELDS:
            layer.pseudoRoot.SetInfo(key, root.pseudoRoot.GetInfo(key))
    try:
        stage_path = os.path.relpath(stage, folder)
    except ValueError:  # another drive
        stage_path = str(stage)
    if not (os.path.isabs(stage_path) or stage_path.startswith("..")):
        stage_path = f"./{stage_path}"  # anchored to the shot file, never a search path
    layer.subLayerPaths = [f"./{name}{LIGHTS_SUFFIX}", stage_path]
    layer.documentation = (f"pxr-layers push {name!r}: {stage.name} with the light overrides of "
                           f"{name}{LIGHTS_SUFFIX}; render it as the shot itself.")
    layer.customLayerData = {"pxrLayers": {"kind": "pushed shot", "stage": str(stage)}}
    for selection in variants:
        spec = Sdf.CreatePrimInLayer(layer, Sdf.Path(selection.prim))
        spec.variantSelections[selection.variant_set] = selection.value
    return layer


def _export(layer: Sdf.Layer, path: Path) -> None:
    def export(temporary: Path) -> None:
        with trapped_usd_diagnostics(str(path)):
            if not layer.Export(str(temporary)):
                raise OSError(f"USD could not export the layer to {temporary.name}")

    write_atomically(path, export)
