"""Model draw modes (UsdGeomModelAPI): which models their stand-ins replace, and the cards.

A model's ``model:drawMode`` (inherited down the model hierarchy, resolved by
``UsdGeom.ModelAPI.ComputeModelDrawMode``) replaces its whole subtree where it *applies*:
on a model whose ``model:applyDrawMode`` is true, or, where that is not authored, on a
model of kind component (UsdImaging's rule). Of the stand-ins, only ``cards`` has
surfaces; ``bounds`` and ``origin`` are wireframe guides, so those models render nothing.

:func:`author_draw_mode_cards` turns each cards model into ordinary prims in the stage's
session layer, under ``/pxrLayers/drawModeCards/<model name>``, so the rest of the reader
(materials, textures, labels) reads them as it reads any mesh::

    Xform <model name>       the model's world transform at the time, baked as one matrix
        Mesh cards           one quad per card, ``primvars:st``, a GeomSubset per material
        Scope Materials      one Material per card texture (UsdPreviewSurface ← UsdUVTexture
                             rgb and alpha, cut out below 0.1 alpha as Storm does), or one
                             ``color`` Material of the model's ``model:drawModeColor``

The cards are those usdview (Storm, ``UsdImaging_DrawModeStandin``) draws, in its order,
winding and texture coordinates, so card images rendered for Storm map the same way:

* ``box``: the six faces of the model's extent; ``cross``: three axis-aligned pairs of
  back-to-back quads through the extent's centre. Only the axes with a texture get cards
  (a face without its own texture shows its opposite's, mirrored); a model without any
  texture gets all six, in ``model:drawModeColor``.
* ``fromTexture``: one quad per texture carrying ``worldtoscreen`` metadata, placed by that
  matrix's inverse. Textures without it are skipped; a model none of whose textures has it
  gets box cards, with a warning (Storm would draw nothing).

Storm culls the back of a card; this renderer is two-sided, so the two quads of a cross
pair sit ``_CROSS_GAP`` of the extent apart (each one toward its own side) for a ray to
meet the one facing it first.

The extent is the model's ``extentsHint`` when authored, else the bound of its default,
proxy and render geometry, in the model's own space (UsdImaging's rule).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import OpenImageIO as oiio
from pxr import Gf, Kind, Sdf, Usd, UsdGeom, Vt

from pxr_layers.inputs import input_problem

from .defaults import ROOT
from .diagnostics import Diagnostics
from .textures import anchored_asset_path

logger = logging.getLogger(__name__)

# Beside the automatic camera and default lights, under pxr-layers' own session-layer root.
CARDS_ROOT = Sdf.Path(ROOT).AppendChild("drawModeCards")
# customData keys, under a "pxrLayers" dictionary: on CARDS_ROOT, every model the cards pass
# handled (given cards, or skipped with a warning); on each card Xform, the model it stands
# in for. (The ":" is USD's key path separator in GetCustomDataByKey.)
_CUSTOM_DATA = "pxrLayers"
_HANDLED_MODELS = "drawModeModels"
_SOURCE_MODEL = "drawModeModel"

# How far apart the two back-to-back quads of a cross pair are, as a fraction of the
# extent's largest side: well above float32 resolution at the model's distance from the
# camera, well below anything visible (0.3 mm on a 30 cm teapot).
_CROSS_GAP = 1e-3
# Storm cuts card texels out below this alpha (UsdPreviewSurface opacityThreshold).
_CARD_OPACITY_THRESHOLD = 0.1

_GUIDE_MODES = (UsdGeom.Tokens.bounds, UsdGeom.Tokens.origin)
_MODEL_API_DEFINITION = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition("GeomModelAPI")
# Card faces in Storm's value order: index k = axis + 3 · (k is the negative side).
_FACE_NAMES = ("XPos", "YPos", "ZPos", "XNeg", "YNeg", "ZNeg")
# Storm's quad for the +X face of the unit cube at x = 1 (x = 0.5 for a cross), counter-
# clockwise seen from +X, and the texture coordinates of its corners.
_UNIT_QUAD = np.array([(1.0, 1.0, 1.0), (1.0, 0.0, 1.0), (1.0, 0.0, 0.0), (1.0, 1.0, 0.0)])
_QUAD_UVS = np.array([(1.0, 1.0), (0.0, 1.0), (0.0, 0.0), (1.0, 0.0)])
# fromTexture quads: the screen's corners at depth 0, in the order of _QUAD_UVS.
_SCREEN_CORNERS = ((1.0, -1.0, 0.0), (-1.0, -1.0, 0.0), (-1.0, 1.0, 0.0), (1.0, 1.0, 0.0))


def applied_draw_mode(prim: Usd.Prim) -> str | None:
    """The draw mode that replaces ``prim`` and its subtree, or None where it renders as
    authored (not a model, draw mode ``default``, or a draw mode that does not apply here)."""
    if not prim.IsModel() or prim.IsPseudoRoot():
        return None
    mode = str(UsdGeom.ModelAPI(prim).ComputeModelDrawMode())
    if mode == UsdGeom.Tokens.default_:
        return None
    apply_attribute = prim.GetAttribute(UsdGeom.Tokens.modelApplyDrawMode)
    if apply_attribute and apply_attribute.HasAuthoredValue():
        applies = bool(apply_attribute.Get())
    else:
        applies = Kind.Registry.IsA(Usd.ModelAPI(prim).GetKind(), Kind.Tokens.component)
    return mode if applies else None


def is_guide_mode(mode: str) -> bool:
    """Whether a draw mode's stand-in is a wireframe guide (no surface to render)."""
    return mode in _GUIDE_MODES


def cards_pass_models(stage: Usd.Stage) -> frozenset[str]:
    """Paths of the models the last :func:`author_draw_mode_cards` on ``stage`` handled."""
    root = stage.GetPrimAtPath(CARDS_ROOT)
    if not root:
        return frozenset()
    return frozenset(root.GetCustomDataByKey(f"{_CUSTOM_DATA}:{_HANDLED_MODELS}") or ())


@dataclass(frozen=True)
class _CardFace:
    """One card quad in the model's space.

    corners  : (4, 3) float64, stage units, counter-clockwise seen from the front
    uvs      : (4, 2) float64, the corners' texture coordinates
    material : name of the Material it shows (a face name, or "color")
    """

    corners: np.ndarray
    uvs: np.ndarray
    material: str


@dataclass(frozen=True)
class _Cards:
    """Everything authored for one model, computed before anything is written.

    world_from_model : the model's local-to-world transform (Gf row-vector convention)
    textures         : material name → absolute image path; empty for the "color" material
    """

    model_path: str
    world_from_model: Gf.Matrix4d
    purpose: str
    color: Gf.Vec3f
    faces: tuple[_CardFace, ...]
    textures: dict[str, str]


def author_draw_mode_cards(
    stage: Usd.Stage, time: Usd.TimeCode, diagnostics: Diagnostics | None = None
) -> tuple[str, ...]:
    """Author the cards of every visible model whose applied draw mode is ``cards``.

    Writes into ``stage.GetSessionLayer()`` under CARDS_ROOT (replacing what an earlier
    call wrote, so it can run once per frame on the same stage) and returns the paths of
    the models now represented by cards. Models without an extent, with a non-finite world
    transform, or inside PointInstancer prototypes get no cards; the first two are noted
    in ``diagnostics`` (logged directly when it is None).
    """
    own_diagnostics = diagnostics is None
    diagnostics = Diagnostics() if own_diagnostics else diagnostics
    layer = stage.GetSessionLayer()
    bounds = UsdGeom.BBoxCache(
        time, [UsdGeom.Tokens.default_, UsdGeom.Tokens.proxy, UsdGeom.Tokens.render],
        useExtentsHint=True,
    )
    xforms = UsdGeom.XformCache(time)
    handled: list[str] = []
    planned: list[_Cards] = []
    for model in _cards_models(stage, time):
        handled.append(str(model.GetPath()))
        cards = _plan_cards(model, time, bounds, xforms, diagnostics)
        if cards is not None:
            planned.append(cards)
    with Sdf.ChangeBlock():
        stale = layer.GetPrimAtPath(CARDS_ROOT)
        if stale:
            del stale.nameParent.nameChildren[stale.name]
        if handled:
            root = _define(layer, CARDS_ROOT, "Scope")
            root.customData = {_CUSTOM_DATA: {_HANDLED_MODELS: Vt.StringArray(handled)}}
            names: set[str] = set()
            for cards in planned:
                _author_cards(layer, root, _unique_name(cards.model_path, names), cards)
    if own_diagnostics:
        diagnostics.finish()
    represented = tuple(cards.model_path for cards in planned)
    if represented:
        logger.info("%d models in cards draw mode drawn as their cards", len(represented))
    return represented


def _cards_models(stage: Usd.Stage, time: Usd.TimeCode) -> list[Usd.Prim]:
    """Visible models whose applied draw mode is cards, outside PointInstancers."""
    found = []
    iterator = iter(Usd.PrimRange(
        stage.GetPseudoRoot(), Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
    ))
    for prim in iterator:
        if prim.IsPseudoRoot():
            continue
        # Models form a contiguous hierarchy from the root: below a non-model (/pxrLayers
        # included) there are none. Prototypes of PointInstancers are not drawn where they
        # are authored.
        if not prim.IsModel() or prim.IsA(UsdGeom.PointInstancer):
            iterator.PruneChildren()
            continue
        mode = applied_draw_mode(prim)
        if mode is None:
            continue
        iterator.PruneChildren()
        imageable = UsdGeom.Imageable(prim)
        if mode == UsdGeom.Tokens.cards and not (
            imageable and imageable.ComputeVisibility(time) == UsdGeom.Tokens.invisible
        ):
            found.append(prim)
    return found


def _model_value(prim: Usd.Prim, name: str, time: Usd.TimeCode):
    """A GeomModelAPI attribute's value, or its schema fallback where the API is not
    applied (the attribute then has no definition to fall back on)."""
    attribute = prim.GetAttribute(name)
    value = attribute.Get(time) if attribute else None
    return _MODEL_API_DEFINITION.GetAttributeFallbackValue(name) if value is None else value


def _card_texture(prim: Usd.Prim, face: str, time: Usd.TimeCode) -> str | None:
    """The image file of ``model:cardTexture<face>``, or None when none is authored."""
    attribute = prim.GetAttribute(f"model:cardTexture{face}")
    asset = attribute.Get(time) if attribute else None
    if not asset or not asset.path:
        return None
    # An unresolved path is kept (anchored, for the missing-file warning to name it): the
    # texture's fallback, the draw mode colour, then shows, as in Storm.
    return asset.resolvedPath or anchored_asset_path(attribute, asset, time)


def _plan_cards(
    model: Usd.Prim,
    time: Usd.TimeCode,
    bounds: UsdGeom.BBoxCache,
    xforms: UsdGeom.XformCache,
    diagnostics: Diagnostics,
) -> _Cards | None:
    path = str(model.GetPath())
    world_from_model = xforms.GetLocalToWorldTransform(model)
    if not np.isfinite(np.array(world_from_model)).all():
        diagnostics.note(
            "cards-non-finite",
            "models in cards draw mode with NaN or infinite transforms skipped: {prims}",
            path,
        )
        return None
    extent = bounds.ComputeUntransformedBound(model).ComputeAlignedBox()
    low, high = np.array(extent.GetMin()), np.array(extent.GetMax())
    if extent.IsEmpty() or not (np.isfinite(low).all() and np.isfinite(high).all()):
        diagnostics.note(
            "cards-no-extent",
            "models in cards draw mode without an extent (no extentsHint, no bounded "
            "geometry) render nothing: {prims}",
            path,
        )
        return None
    textures = [_card_texture(model, face, time) for face in _FACE_NAMES]
    geometry = str(_model_value(model, UsdGeom.Tokens.modelCardGeometry, time))
    faces = None
    if geometry == UsdGeom.Tokens.fromTexture:
        faces = _from_texture_faces(textures)
        if faces is None:
            diagnostics.note(
                "cards-from-texture",
                "cardGeometry fromTexture needs worldtoscreen metadata in the card textures; "
                "drawn as box cards: {prims}",
                path,
            )
            geometry = UsdGeom.Tokens.box
    if faces is None:
        faces = _storm_faces(geometry == UsdGeom.Tokens.box, [t is not None for t in textures],
                             low, high)
    used = {face.material for face in faces}
    imageable = UsdGeom.Imageable(model)
    return _Cards(
        model_path=path,
        world_from_model=world_from_model,
        purpose=str(imageable.ComputePurpose()) if imageable else UsdGeom.Tokens.default_,
        color=Gf.Vec3f(_model_value(model, UsdGeom.Tokens.modelDrawModeColor, time)),
        faces=tuple(faces),
        textures={_FACE_NAMES[k]: file for k, file in enumerate(textures)
                  if file is not None and _FACE_NAMES[k] in used},
    )


def _to_axis(points: np.ndarray, axis: int) -> np.ndarray:
    """Storm's map of the +X card onto ``axis`` in the unit cube: a quarter turn about Z for
    Y, a third of a turn about the diagonal for Z (both rotations, so the winding stays)."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    if axis == 1:
        return np.stack([1.0 - y, x, z], axis=1)
    if axis == 2:
        return np.stack([y, z, x], axis=1)
    return points


def _storm_faces(
    is_box: bool, has_texture: list[bool], low: np.ndarray, high: np.ndarray
) -> list[_CardFace]:
    """Box or cross cards of the extent [low, high] (each (3,), model space)."""
    has_face = [False] * 6
    for k in range(6):
        if has_texture[k]:
            has_face[k] = has_face[(k + 3) % 6] = True
    textured = any(has_texture)
    if not textured:
        has_face = [True] * 6  # all six faces, in the draw mode colour
    size = high - low
    quad = _UNIT_QUAD.copy()
    if not is_box:
        quad[:, 0] = 0.5
    faces = []
    for axis in range(3):  # Storm's point order: XPos, XNeg, YPos, YNeg, ZPos, ZNeg
        for negative in (False, True):
            k = axis + 3 * negative
            if not has_face[k]:
                continue
            if negative:
                # The opposite face: the point reflection through the cube's centre, its
                # corners reversed so it faces outward.
                unit = 1.0 - _to_axis(quad[::-1], axis)
            else:
                unit = _to_axis(quad, axis)
            corners = low + unit * size
            if not is_box:
                outward = np.zeros(3)
                outward[axis] = -1.0 if negative else 1.0
                corners = corners + outward * (0.5 * _CROSS_GAP * float(size.max()))
            # A face without its own texture shows its opposite's, mirrored.
            flip_u, flip_v = not has_texture[k], False
            if axis == 2:
                flip_u, flip_v = (True, has_texture[k]) if negative else (False, not has_texture[k])
            uvs = _QUAD_UVS.copy()
            if flip_u:
                uvs[:, 0] = 1.0 - uvs[:, 0]
            if flip_v:
                uvs[:, 1] = 1.0 - uvs[:, 1]
            source = k if has_texture[k] else (k + 3) % 6
            faces.append(_CardFace(corners, uvs, _FACE_NAMES[source] if textured else "color"))
    return faces


def _from_texture_faces(textures: list[str | None]) -> list[_CardFace] | None:
    """One quad per texture with worldtoscreen metadata, or None when none has it."""
    faces = []
    for axis in range(3):
        for negative in (False, True):
            k = axis + 3 * negative
            world_to_screen = _world_to_screen(textures[k]) if textures[k] else None
            if world_to_screen is None:
                continue
            screen_to_model = world_to_screen.GetInverse()
            corners = np.array([screen_to_model.Transform(Gf.Vec3d(*corner))
                                for corner in _SCREEN_CORNERS])
            faces.append(_CardFace(corners, _QUAD_UVS.copy(), _FACE_NAMES[k]))
    return faces or None


def _world_to_screen(path: str) -> Gf.Matrix4d | None:
    """The image's ``worldtoscreen`` matrix (16 row-major values), or None."""
    if input_problem(path, "texture") is not None:
        return None  # missing, or a FIFO that would block the open: textures.py says which
    image = oiio.ImageInput.open(path)
    if image is None:
        oiio.geterror()  # clear OIIO's error; the missing file is reported by textures.py
        return None
    try:
        spec = image.spec()
        # OIIO before 2.2 wrote this matrix as worldToNDC (see UsdImaging's comment).
        values = spec.getattribute("worldtoscreen")
        if values is None:
            values = spec.getattribute("worldToNDC")
    finally:
        image.close()
    if values is None or len(values) != 16:
        return None
    return Gf.Matrix4d(*(float(value) for value in values))


def _unique_name(model_path: str, taken: set[str]) -> str:
    """The model's name, numbered when models elsewhere share it."""
    base = Sdf.Path(model_path).name
    name, number = base, 1
    while name in taken:
        number += 1
        name = f"{base}_{number}"
    taken.add(name)
    return name


# --- authoring (Sdf, inside one change block: one recomposition however many models) ----


def _define(layer: Sdf.Layer, path: Sdf.Path, type_name: str = "") -> Sdf.PrimSpec:
    spec = Sdf.CreatePrimInLayer(layer, path)
    # CreatePrimInLayer leaves missing ancestors as overs; /pxrLayers must exist as a def.
    for ancestor in path.GetPrefixes():
        ancestor_spec = layer.GetPrimAtPath(ancestor)
        if ancestor_spec.specifier == Sdf.SpecifierOver:
            ancestor_spec.specifier = Sdf.SpecifierDef
    spec.typeName = type_name
    return spec


def _attribute(spec: Sdf.PrimSpec, name: str, type_name, value=None, *, uniform: bool = False,
               interpolation: str | None = None) -> Sdf.AttributeSpec:
    variability = Sdf.VariabilityUniform if uniform else Sdf.VariabilityVarying
    attribute = Sdf.AttributeSpec(spec, name, type_name, variability)
    if value is not None:
        attribute.default = value
    if interpolation is not None:
        attribute.SetInfo("interpolation", interpolation)
    return attribute


def _connect(spec: Sdf.PrimSpec, name: str, type_name, source: Sdf.Path) -> None:
    _attribute(spec, name, type_name).connectionPathList.explicitItems = [source]


def _bind(spec: Sdf.PrimSpec, material: Sdf.Path) -> None:
    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=["MaterialBindingAPI"]))
    binding = Sdf.RelationshipSpec(spec, "material:binding", custom=False)
    binding.targetPathList.explicitItems = [material]


def _author_cards(layer: Sdf.Layer, root: Sdf.PrimSpec, name: str, cards: _Cards) -> None:
    types = Sdf.ValueTypeNames
    xform = _define(layer, root.path.AppendChild(name), "Xform")
    xform.customData = {_CUSTOM_DATA: {_SOURCE_MODEL: cards.model_path}}
    _attribute(xform, "xformOp:transform", types.Matrix4d, cards.world_from_model)
    _attribute(xform, "xformOpOrder", types.TokenArray, ["xformOp:transform"], uniform=True)
    if cards.purpose != UsdGeom.Tokens.default_:
        _attribute(xform, "purpose", types.Token, cards.purpose, uniform=True)

    materials_path = xform.path.AppendChild("Materials")
    _define(layer, materials_path, "Scope")
    material_names = sorted({face.material for face in cards.faces})
    for material in material_names:
        _author_material(layer, materials_path.AppendChild(material), cards.color,
                         cards.textures.get(material))

    mesh = _define(layer, xform.path.AppendChild("cards"), "Mesh")
    corners = np.concatenate([face.corners for face in cards.faces])
    uvs = np.concatenate([face.uvs for face in cards.faces])
    _attribute(mesh, "points", types.Point3fArray,
               Vt.Vec3fArray.FromNumpy(corners.astype(np.float32)))
    _attribute(mesh, "faceVertexCounts", types.IntArray, [4] * len(cards.faces))
    _attribute(mesh, "faceVertexIndices", types.IntArray, list(range(len(corners))))
    _attribute(mesh, "extent", types.Float3Array,
               [Gf.Vec3f(*corners.min(axis=0)), Gf.Vec3f(*corners.max(axis=0))])
    _attribute(mesh, "subdivisionScheme", types.Token, UsdGeom.Tokens.none, uniform=True)
    _attribute(mesh, "doubleSided", types.Bool, True, uniform=True)
    _attribute(mesh, "primvars:st", types.TexCoord2fArray,
               Vt.Vec2fArray.FromNumpy(uvs.astype(np.float32)), interpolation=UsdGeom.Tokens.vertex)
    _attribute(mesh, "primvars:displayColor", types.Color3fArray, [cards.color],
               interpolation=UsdGeom.Tokens.constant)
    if len(material_names) == 1:
        _bind(mesh, materials_path.AppendChild(material_names[0]))
        return
    for material in material_names:
        subset = _define(layer, mesh.path.AppendChild(material), "GeomSubset")
        indices = [index for index, face in enumerate(cards.faces) if face.material == material]
        _attribute(subset, "elementType", types.Token, UsdGeom.Tokens.face, uniform=True)
        _attribute(subset, "familyName", types.Token, "materialBind", uniform=True)
        _attribute(subset, "indices", types.IntArray, indices)
        _bind(subset, materials_path.AppendChild(material))


def _author_material(
    layer: Sdf.Layer, path: Sdf.Path, color: Gf.Vec3f, texture: str | None
) -> None:
    """A UsdPreviewSurface of ``texture`` (rgb, and alpha cut out as Storm does), or of
    ``color`` when there is no texture."""
    types = Sdf.ValueTypeNames
    _define(layer, path, "Material")
    surface = _define(layer, path.AppendChild("Surface"), "Shader")
    _attribute(surface, "info:id", types.Token, "UsdPreviewSurface", uniform=True)
    _attribute(surface, "outputs:surface", types.Token)
    material = layer.GetPrimAtPath(path)
    _connect(material, "outputs:surface", types.Token,
             surface.path.AppendProperty("outputs:surface"))
    if texture is None:
        _attribute(surface, "inputs:diffuseColor", types.Color3f, color)
        return
    image = _define(layer, path.AppendChild("Texture"), "Shader")
    reader = _define(layer, path.AppendChild("St"), "Shader")
    _attribute(reader, "info:id", types.Token, "UsdPrimvarReader_float2", uniform=True)
    _attribute(reader, "inputs:varname", types.String, "st")
    _attribute(reader, "outputs:result", types.Float2)
    _attribute(image, "info:id", types.Token, "UsdUVTexture", uniform=True)
    _attribute(image, "inputs:file", types.Asset, Sdf.AssetPath(texture))
    _connect(image, "inputs:st", types.Float2, reader.path.AppendProperty("outputs:result"))
    _attribute(image, "inputs:wrapS", types.Token, "clamp")
    _attribute(image, "inputs:wrapT", types.Token, "clamp")
    # Storm's card texture falls back on the draw mode colour (a missing file shows it).
    _attribute(image, "inputs:fallback", types.Float4, Gf.Vec4f(*color, 1.0))
    _attribute(image, "outputs:rgb", types.Float3)
    _attribute(image, "outputs:a", types.Float)
    _connect(surface, "inputs:diffuseColor", types.Color3f,
             image.path.AppendProperty("outputs:rgb"))
    _connect(surface, "inputs:opacity", types.Float, image.path.AppendProperty("outputs:a"))
    _attribute(surface, "inputs:opacityThreshold", types.Float, _CARD_OPACITY_THRESHOLD)
