"""One inspector session: the products and the index of one render, in memory, and what the
page asks of them (inspect a selection, make a layer, save the stack).

A session opens PATH once (:meth:`Session.open`):

* a folder: its path index (one ``.pxlidx``; several are refused, name one) and the
  products of that render (the multipart EXRs whose ``pxrLayers/renderId`` is the
  index's); without an index, every product EXR of the folder;
* an ``.exr`` product: it, and the index it names (``pxrLayers/index``) if that is beside it;
* a ``.pxlidx``: it, and the products of its render beside it (else its beauty only).

The colour layers of the products make the stack (data layers, depth or ids, are not
composited and are left out); the beauty is part 0 of the first product, or the render's
beauty EXR beside the index, or ``C.*`` from the index. Everything the page writes lands in
the session's folder.
"""

from __future__ import annotations

import functools
import json
import logging
import re
import threading
import time
import urllib.parse
from collections import OrderedDict
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .. import lpe
from ..errors import LpeSyntaxError, PxrLayersError, RecipeError
from ..layers.deliver import (DENOISED_SUFFIX, GUIDE_SOURCES, at_index_view, beauty_beside, deliver, denoised_path,
                               index_inputs, index_metadata)
from ..layers.cryptomatte import Cryptomatte, coverage, names_at
from ..layers.display_lut import DisplayLut, bake_display_lut, lut_bytes, lut_description
from ..layers.extract import extract
from ..layers.kelvin import kelvin_table
from ..layers.multipart import MultipartImage, read_multipart
from ..layers.nuke import NUKE_RESERVED_LAYERS, LayerGrade, write_nuke_script
from ..layers.overlaps import overlaps
from ..layers.previews import display_views, energy_shares, layers_partition
from ..lpe.labels import KnownNames, unknown_label_report
from ..outputs import OutputSet, reading
from ..paths.events import (
    SCATTERING_NAMES,
    SCATTERING_TYPE_NAMES,
    SCATTERING_TYPES,
    SCATTERINGS,
    event_paths,
)
from ..paths.format import SUFFIX as INDEX_SUFFIX, NormBins
from ..paths.reader import PathIndex
from ..recipe.model import (
    CRYPTOMATTE_KINDS,
    DEFAULT_CAMERA_PATH,
    LAYER_NAME,
    IndexSettings,
    Layer,
    Product,
    Recipe,
)
from . import document as documents
from . import inspect, push
from .grades import ViewError, _shown, _stops, grade_from_json, mask_from_json

log = logging.getLogger(__name__)

LUT_URL = "/api/lut"
"""Where the page fetches the display LUT's table (server.py's route)."""
SAVE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]*")
"""What /api/save writes: NAME.usda, NAME.exr (and its previews), NAME.nk, in the folder."""
MAX_NAME_CHARS = 120
"""Longest save or layer name (NAME.usda and its previews' names stay within the system's 255 bytes)."""
MAX_SUGGESTED = 32
"""Most layers /api/suggest makes at once."""
MAX_OVERLAP_LAYERS = 256
"""Layers /api/overlaps compares at most (a stack is far smaller)."""
VERSIONS = ("raw", "denoised")
"""The versions of a layer's pixels /api/image serves: as rendered, and from the denoised twin."""
MASKS_CACHED = 32
"""Masks (/api/mask answers) a session keeps, the most recently asked."""


@dataclass
class ViewLayer:
    """A layer of the stack. image : (h, w, 3) float32 linear, the beauty's scale."""

    id: str
    name: str
    kind: str  # "beauty" or "layer"
    product: str  # the EXR it came from ("" for a layer made in the page)
    expression: str | None
    image: np.ndarray
    share: float | None
    exposure: float = 0.0
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    denoised: np.ndarray | None = None
    _bytes: dict = field(default_factory=dict, repr=False)

    def pixels(self, version: str = "raw") -> bytes:
        """Little-endian float32 h × w × 3, top row first (/api/image): the layer as
        rendered ("raw") or from the render's denoised twin ("denoised")."""
        if version not in VERSIONS:
            raise ViewError(f"image version {_shown(version)}: one of {', '.join(VERSIONS)}")
        image = self.image if version == "raw" else self.denoised
        if image is None:
            raise ViewError(f"layer {self.id!r} has no denoised version (the render wrote no denoised twin)", 404)
        if version not in self._bytes:
            self._bytes[version] = np.ascontiguousarray(image, dtype="<f4").tobytes()
        return self._bytes[version]

    def description(self) -> dict:
        return {"id": self.id, "name": self.name, "kind": self.kind, "product": self.product,
                "expression": self.expression, "share": self.share, "exposure": self.exposure,
                "tint": list(self.tint)}


class Session:
    """The state behind one ``pxr-layers view``; thread-safe (one lock around the index and
    the stack: the server runs requests on a thread pool)."""

    def __init__(self, folder: Path, title: str, beauty: np.ndarray, layers: list[ViewLayer],
                 index: PathIndex | None, product: Product, threads: int,
                 guides: tuple[np.ndarray, np.ndarray] | None = None,
                 cryptomattes: dict[str, tuple[str, Cryptomatte]] | None = None):
        """guides: the denoiser's (albedo, normal) of a render with denoised twins, whose
        layers then carry their denoised versions (ViewLayer.denoised); None without.
        cryptomattes: mask kind (object, material, asset) → (its EXR layer, its Cryptomatte),
        what masks are keyed from (:meth:`mask`)."""
        self.folder, self.title, self.beauty, self.index, self.threads = folder, title, beauty, index, threads
        self.guides = guides
        self.base_product = product
        self.height, self.width = beauty.shape[:2]
        self.layers: dict[str, ViewLayer] = {layer.id: layer for layer in layers}
        self.lut: DisplayLut = bake_display_lut(product.ocio_config, product.display, product.view,
                                                product.rendering_space)
        self.views = display_views(product.ocio_config, product.display)
        self._lock = threading.Lock()  # the index's reads and the stack's layers
        self._document_lock = threading.Lock()  # the working state's file: not behind an extraction
        self._push_lock = threading.Lock()  # a push's check and writes together
        self.cryptomattes = dict(cryptomattes or {})
        self._masks: OrderedDict[tuple[str, tuple[str, ...]], bytes] = OrderedDict()
        self._masks_lock = threading.Lock()
        self._event_paths = event_paths(index.events) if index else []
        self._infos = [inspect.describe(path_class, self._event_paths) for path_class in index.classes] if index else []
        self.document_path = documents.document_path(folder, title)
        self.document = self._restored(documents.load(self.document_path))

    # -- opening

    @classmethod
    def open(cls, path: str | Path, *, threads: int = 1) -> Session:
        """The session of PATH (module docstring). Raises PxrLayersError naming the file."""
        path = Path(path)
        if not path.exists():
            raise ViewError(f"{path}: no such file or folder")
        if path.is_dir():
            folder, index, products = path, _folder_index(path), []
        elif path.suffix == INDEX_SUFFIX:
            folder, index, products = path.parent, PathIndex(path), []
        elif path.suffix.lower() == ".exr":
            folder, products = path.parent, [read_multipart(path)]
            named = _index_named(products[0]) or _index_of_beauty(path)
            index = PathIndex(folder / named) if named and (folder / named).is_file() else None
            if index is not None and index.manifest.get("render_id") not in _render_ids(products[0]):
                raise ViewError(f"{path}: {named} beside it is the index of another render (its renderId differs)")
        else:
            raise ViewError(f"{path}: not a folder, an .exr product or a {INDEX_SUFFIX} index")
        folder = folder.resolve()
        if not products:
            products = _same_size(_products_beside(folder, index), index)
        if index is not None and not products:
            beauty = beauty_beside(index)
        elif products:
            beauty = products[0].beauty
        else:
            raise ViewError(f"{path}: holds neither a path index nor a pxr-layers product EXR")
        if index is not None and tuple(index.manifest["resolution"]) != (beauty.shape[1], beauty.shape[0]):
            raise ViewError(f"{products[0].path}: {beauty.shape[1]}x{beauty.shape[0]}, its index "
                            f"{index.path.name} {'x'.join(map(str, index.manifest['resolution']))}")
        layers = [ViewLayer("beauty", "beauty", "beauty", products[0].path.name if products else "", lpe.BEAUTY,
                            np.ascontiguousarray(beauty[..., :3]), 1.0)]
        layers += _product_layers(products, beauty)
        guides = _denoised_twins(products, layers)
        product = _base_product(products, index, beauty)
        title = products[0].path.stem if products else index.path.stem
        log.info("%s: %d layers, %s%s", folder, len(layers) - 1,
                 f"index {index.path.name} ({index.record_count:,} records)" if index else "no index",
                 ", denoised twins" if guides else "")
        return cls(folder, title, beauty, layers, index, product, threads, guides, _product_cryptomattes(products))

    # -- what the page reads

    def description(self) -> dict:
        """/api/session."""
        layers = [layer for layer in self.layers.values() if layer.kind == "layer"]
        return {"title": self.title, "width": self.width, "height": self.height,
                "layers": [layer.description() for layer in self.layers.values()],
                "denoised": self.guides is not None,
                "document": self.document, "document_file": self.document_path.name,
                "partition": self._partition(layers), "index": self._index_description(),
                "cryptomattes": {kind: {"layer": layer, "names": sorted(matte.manifest)}
                                 for kind, (layer, matte) in self.cryptomattes.items()},
                "alphabet": {"types": list(zip(SCATTERING_TYPES, SCATTERING_TYPE_NAMES, strict=True)),
                             "scatterings": list(zip(SCATTERINGS, SCATTERING_NAMES, strict=True))},
                "display": self.display_description(),
                "kelvin": kelvin_table()}

    def display_description(self, view: str | None = None) -> dict:
        """/api/display: the display transform of `view` (the products' view when None): its
        config, display, view, the display's other views, and its LUT (the GLSL and where the
        table is)."""
        lut = self._lut(view)
        url = LUT_URL if view is None else f"{LUT_URL}?{urllib.parse.urlencode({'view': view})}"
        return {"config": lut.config, "display": lut.display, "view": lut.view, "views": self.views,
                "default_view": self.lut.view, "lut": {**lut_description(lut), "url": url}}

    def lut_pixels(self, view: str | None = None) -> bytes:
        return lut_bytes(self._lut(view))

    def _lut(self, view: str | None) -> DisplayLut:
        """The LUT of one of the display's views (baked once: bake_display_lut caches)."""
        if view is None or view == self.lut.view:
            return self.lut
        if view not in self.views:
            raise ViewError(f"view {_shown(view)} is not a view of {self.lut.display!r} "
                            f"(views: {', '.join(self.views)})")
        return bake_display_lut(self.lut.config, self.lut.display, view, self.lut.rendering_space)

    def layer(self, layer_id: str) -> ViewLayer:
        try:
            return self.layers[layer_id]
        except (KeyError, TypeError):
            raise ViewError(f"no layer {_shown(layer_id)}", 404) from None

    def _partition(self, layers: list[ViewLayer]) -> bool:
        return layers_partition(self.beauty, [layer.image for layer in layers])

    def _index_description(self) -> dict | None:
        index = self.index
        if index is None:
            return None
        lights = sorted({info.light for info in self._infos if info.end_type == "L" and info.light})
        objects = sorted({event.name for event in index.events if event.type in "RTO" and event.name})
        materials = sorted({material.rsplit("/", 1)[-1] for _, material in self._event_paths} - {""})
        return {"file": index.path.name, "spp": index.manifest["spp"], "records": index.record_count,
                "classes": index.class_count, "bounces": index.norm_slots, "has_sigma": index.has_sigma,
                "labels": sorted(index.labels), "lights": lights, "objects": objects, "materials": materials,
                "norm_bins": {"min": 2.0 ** NormBins.LOWEST_EXPONENT,
                              "max": 2.0 ** (NormBins.LOWEST_EXPONENT + NormBins.EDGES - 1),
                              "per_octave": 1, "exact": "0 and powers of two"}}

    # -- the working state (view/document.py)

    def put_document(self, document) -> dict:
        """/api/document: keep the page's working state beside the render. Every layer it
        shows must be one of the session's."""
        try:
            document = documents.checked(document)
        except documents.DocumentError as error:
            raise ViewError(f"document: {error}") from None
        with self._document_lock:  # self.layers only grows: read without the session's lock
            unknown = sorted(set(documents.sources(document)) - set(self.layers))
            if unknown:
                raise ViewError(f"document: no layer {unknown[0]!r} in this session", 404)
            documents.write(self.document_path, document)
            self.document = document
        return {"file": self.document_path.name}

    def _restored(self, document: dict | None) -> dict | None:
        """`document` with the layers it shows that the render's products do not hold (made on
        the page) extracted again from their expressions; entries of layers that cannot be
        (no index, no expression, an expression that no longer compiles) are dropped, with a
        warning naming them."""
        if document is None:
            return None
        missing = {source: expression for source, expression in documents.sources(document).items()
                   if source not in self.layers}
        restorable = {source: expression for source, expression in missing.items() if expression and self.index}
        if restorable:
            names = {f"restored_{number}": source for number, source in enumerate(restorable)}
            try:
                extraction = extract(self.index, {name: restorable[source] for name, source in names.items()},
                                     threads=self.threads)
            except PxrLayersError as error:
                log.warning("%s: its page-made layers are not restored (%s)", self.document_path.name,
                            str(error).splitlines()[0])
                restorable = {}
            else:
                shares = energy_shares(self.beauty, extraction.layers)
                denoised = self._denoised(extraction.layers)
                for name, source in names.items():
                    self.layers[source] = ViewLayer(source, source, "layer", "", restorable[source],
                                                    extraction.layers[name], shares[name], denoised=denoised.get(name))
        lost = sorted(set(missing) - set(restorable))
        if lost:
            log.warning("%s: %d layers it shows are gone and left out: %s", self.document_path.name, len(lost),
                        ", ".join(lost[:5]))
            for look in (document, *document["snapshots"], *([document["saved"]] if document["saved"] else [])):
                look["entries"] = [entry for entry in look["entries"] if entry["source"] not in lost]
        log.info("%s: the working state restored (%d entries, %d snapshots)", self.document_path.name,
                 len(document["entries"]) - 1, len(document["snapshots"]))
        return document

    # -- inspect

    def inspect(self, x0: int, y0: int, x1: int, y1: int) -> dict:
        """/api/inspect: the path classes of a pixel rectangle (x1, y1 exclusive)."""
        index = self._need_index("inspect a selection")
        if not (x0 < x1 and y0 < y1):
            raise ViewError(f"an empty selection ({x0}, {y0}) – ({x1}, {y1})")
        start = time.perf_counter()
        with self._lock:
            selection = inspect.select(index, x0, y0, x1, y1, threads=self.threads)
        result = inspect.summary(selection, self._infos)
        spp = index.manifest["spp"]
        pixels = max(selection.pixels, 1)
        result.update(pixels=selection.pixels, rgb=[value / spp / pixels for value in result.pop("rgb_total")],
                      energy=result.pop("energy_total") / spp / pixels, seconds=time.perf_counter() - start)
        return result

    def generalise(self, class_ids: list[int], keep: list[str]) -> str:
        self._need_index("generalise path classes")
        if not isinstance(class_ids, list) or not class_ids or \
                not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i < len(self._infos) for i in class_ids):
            raise ViewError("classes must be a non-empty list of the index's class ids")
        if not isinstance(keep, list) or not all(isinstance(aspect, str) for aspect in keep):
            raise ViewError(f"keep must be a list of aspects ({', '.join(inspect.ASPECTS)})")
        try:
            return inspect.generalise([self._infos[i] for i in class_ids], keep)
        except ValueError as error:
            raise ViewError(str(error)) from None

    # -- layers

    def check(self, expression: str) -> None:
        """Raise ViewError (with the position) unless `expression` compiles."""
        if not isinstance(expression, str):
            raise ViewError("the expression must be a string")
        try:
            lpe.compile(expression)
        except LpeSyntaxError as error:
            raise ViewError(error.message, position=error.position) from None
        except PxrLayersError as error:
            raise ViewError(str(error)) from None

    def add_layer(self, name: str, expression: str) -> tuple[ViewLayer, dict]:
        """Extract a new layer from the index into the stack: /api/layer. The facts: classes
        matched, seconds, and the warnings of labels that name nothing in the index."""
        index = self._need_index("make a layer")
        _check_layer_name(name)
        self.check(expression)
        start = time.perf_counter()
        with self._lock:
            if name in self.layers or name == "beauty":
                raise ViewError(f"there is a layer {name!r} already", 409)
            try:
                extraction = extract(index, {name: expression}, threads=self.threads)
            except PxrLayersError as error:
                raise ViewError(str(error).splitlines()[0]) from None
            image = extraction.layers[name]
            share = energy_shares(self.beauty, {name: image})[name]
            layer = ViewLayer(name, name, "layer", "", expression, image, share,
                              denoised=self._denoised({name: image}).get(name))
            self.layers[name] = layer
        seconds = time.perf_counter() - start
        log.info("layer %s = %s: %.2f s", name, expression, seconds)
        # a label naming nothing (a typo: 'flor' for 'floor') leaves the layer empty: the
        # answer says so, with the close names, as the log does
        return layer, {"classes": extraction.classes_matched, "seconds": seconds, "warnings": list(extraction.warnings)}

    def suggest_layers(self, k: int | None = None, exclude=None) -> tuple[list[ViewLayer], dict]:
        """Layers found automatically (pxr_layers.suggest, docs/suggest.md): K layers that
        partition the beauty (K None: the objective's elbow), extracted in one pass and added
        to the stack, but for those that cut the same paths as an expression of `exclude`
        (the stack's). /api/suggest."""
        from ..suggest import suggest

        index = self._need_index("suggest layers")
        if k is not None and (not isinstance(k, int) or isinstance(k, bool) or not 1 <= k <= MAX_SUGGESTED):
            raise ViewError(f"suggest asks for 1 to {MAX_SUGGESTED} layers (or none: the elbow), not {k!r}")
        if exclude is None:
            exclude = []
        if not isinstance(exclude, list) or not all(isinstance(text, str) for text in exclude):
            raise ViewError("suggest's exclude is a list of the stack's expressions")
        start = time.perf_counter()
        with self._lock:
            suggestion = suggest([index], k, threads=self.threads, exclude=exclude)
            names = {name: self._free_name(name, suggestion.layers) for name in suggestion.layers}
            expressions = {names[name]: expression for name, expression in suggestion.layers.items()}
            extraction = extract(index, expressions, threads=self.threads) if expressions else None
            shares = energy_shares(self.beauty, extraction.layers) if extraction else {}
            denoised = self._denoised(extraction.layers) if extraction else {}
            added = [ViewLayer(name, name, "layer", "", expression, extraction.layers[name], shares[name],
                               denoised=denoised.get(name))
                     for name, expression in expressions.items()]
            self.layers.update((layer.id, layer) for layer in added)
        seconds = time.perf_counter() - start
        log.info("suggested %d layers in %.2f s", len(added), seconds)
        return added, {"objective": suggestion.objective, "strategy": suggestion.strategy,
                       "splits": list(suggestion.splits), "seconds": seconds, "chosen_k": suggestion.chosen_k,
                       "explanations": {names[name]: text for name, text in suggestion.explanations.items()},
                       "already": suggestion.already}

    # -- energy that goes wrong: overlapping layers, names that match nothing

    def overlaps(self, stack) -> dict:
        """/api/overlaps: which layers of ``stack`` ([{"id", "expression"}], the page's layers
        in order) claim the same paths, per record (layers.overlaps): {"pairs": [{"a", "b",
        "share"}], "double_counted", "remainder", "claimed", "seconds", "unknown": ids of the
        layers without an expression (products read from an EXR without one), "warnings"}.
        Shares are of the beauty's energy. An entry's expression defaults to its layer's;
        the beauty (id "beauty") is the reference, not a layer of the sum, and is skipped."""
        index = self._need_index("find overlapping layers")
        if not isinstance(stack, list) or len(stack) > MAX_OVERLAP_LAYERS or \
                not all(isinstance(entry, dict) and isinstance(entry.get("id"), str) for entry in stack):
            raise ViewError(f"layers must be a list of at most {MAX_OVERLAP_LAYERS} {{\"id\", \"expression\"}} objects")
        expressions: dict[str, str] = {}
        unknown: list[str] = []
        for entry in stack:
            layer_id, expression = entry["id"], entry.get("expression")
            if layer_id == "beauty" or layer_id in expressions:
                continue
            if expression is None and layer_id in self.layers:
                expression = self.layers[layer_id].expression
            if expression is None or expression == "":
                unknown.append(layer_id)
                continue
            if not isinstance(expression, str):
                raise ViewError(f"layer {_shown(layer_id)}: the expression must be a string")
            try:
                lpe.parse(expression)
            except LpeSyntaxError as error:
                raise ViewError(f"layer {_shown(layer_id)}: {error.message}", position=error.position) from None
            expressions[layer_id] = expression
        if not expressions:
            return {"pairs": [], "double_counted": 0.0, "remainder": 1.0, "claimed": 0.0, "seconds": 0.0,
                    "unknown": unknown, "warnings": []}
        with self._lock:
            try:
                found = overlaps(index, expressions, self.beauty, threads=self.threads)
            except PxrLayersError as error:
                raise ViewError(str(error).splitlines()[0]) from None
        # What the page offers to make the stack sum to the beauty again: each layer that
        # shares paths with an earlier one, less the earlier ones; and the unclaimed rest.
        names = list(expressions)
        exclusive, rest = {}, None
        try:
            for (a, b), share in found.pairs.items():
                later = max(a, b, key=names.index)
                if share > 0 and later not in exclusive:
                    exclusive[later] = lpe.exclusive(expressions[later], [expressions[n] for n in names[:names.index(later)]])
            rest = lpe.remainder(list(expressions.values())) if found.remainder > 0 and not unknown else None
        except PxrLayersError as error:  # a layer that subtracts what is not in the stack: none offered
            log.info("overlaps: no exclusive or remainder layer offered (%s)", error)
        return {"pairs": [{"a": a, "b": b, "share": share} for (a, b), share in found.pairs.items()],
                "double_counted": found.double_counted, "remainder": found.remainder, "claimed": found.claimed,
                "seconds": found.seconds, "unknown": unknown, "warnings": list(found.warnings),
                "exclusive": exclusive, "remainder_expression": rest}

    def unknown_labels(self, expression: str) -> list[dict]:
        """The quoted labels of ``expression`` that name nothing in the index, with their
        position and the nearest names present ([{"label", "position", "nearest",
        "message"}]; lpe.labels.unknown_label_report); [] without an index or for an
        expression that does not parse (``check`` says why)."""
        if self.index is None or not isinstance(expression, str):
            return []
        try:
            return unknown_label_report(expression, self._known_names, str(self.index.shown_as))
        except PxrLayersError:
            return []

    @functools.cached_property
    def _known_names(self) -> KnownNames:
        return KnownNames.of_events(self.index.events)

    def _denoised(self, images: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Layers made from the index, denoised as the render's twins were (its beauty's input
        scale, its guides); nothing without a denoised render."""
        if self.guides is None:
            return {}
        from ..layers.denoise import denoise_images

        return denoise_images(self.beauty, images, *self.guides)

    def _free_name(self, name: str, others) -> str:
        """`name`, or `name_2`, `name_3`… when the stack (or `others`) has it already."""
        taken = set(self.layers) | {"beauty"}
        if name not in taken:
            return name
        number = 2
        while f"{name}_{number}" in taken or f"{name}_{number}" in others:
            number += 1
        return f"{name}_{number}"

    # -- masks

    @functools.cached_property
    def mask_names(self) -> dict[str, frozenset[str]]:
        """kind → the names its Cryptomatte's manifest has (what a mask may name)."""
        return {kind: frozenset(matte.manifest) for kind, (_, matte) in self.cryptomattes.items()}

    def mask_coverage(self, kind, names) -> np.ndarray:
        """(h, w) float32: the coverage of ``names`` in the Cryptomatte of ``kind``
        (layers.cryptomatte.coverage). ViewError (400) for an unknown kind or name, one line
        naming it and the nearest known."""
        mask = mask_from_json({"kind": kind, "names": names}, "mask", self.mask_names)
        return coverage(self.cryptomattes[mask.kind][1], mask.names)

    def mask(self, kind, names) -> bytes:
        """/api/mask: :meth:`mask_coverage` as little-endian float32 h × w, top row first;
        the last MASKS_CACHED answers are kept, per kind and set of names."""
        key = (kind, tuple(sorted(set(names)))) if isinstance(kind, str) and isinstance(names, list) and \
            all(isinstance(name, str) for name in names) else None
        with self._masks_lock:
            if key in self._masks:
                self._masks.move_to_end(key)
                return self._masks[key]
        pixels = np.ascontiguousarray(self.mask_coverage(kind, names), dtype="<f4").tobytes()
        with self._masks_lock:
            self._masks[key] = pixels
            while len(self._masks) > MASKS_CACHED:
                self._masks.popitem(last=False)
        return pixels

    def pick(self, x, y) -> dict:
        """/api/pick: the names under pixel (x, y) (x from the left, y from the top) in each
        kind's Cryptomatte, highest coverage first: {kind: [{"name", "coverage"}, ...]}."""
        if isinstance(x, bool) or isinstance(y, bool) or not isinstance(x, int) or not isinstance(y, int) \
                or not (0 <= x < self.width and 0 <= y < self.height):
            raise ViewError(f"pick needs a pixel x from 0 to {self.width - 1}, y from 0 to {self.height - 1}, "
                            f"not ({_shown(x)}, {_shown(y)})")
        return {kind: [{"name": name, "coverage": weight} for name, weight in names_at(matte, x, y)]
                for kind, (_, matte) in self.cryptomattes.items()}

    def look_cryptomattes(self, grades: dict[str, LayerGrade]) -> dict[str, Cryptomatte]:
        """The Cryptomattes a saved look needs for its masked grades, by source (CryptoObject,
        ...): a masked save writes them into its EXR (Recipe.with_cryptomattes of their
        sources, ``deliver(data=...)``), layers named after their source as the Nuke script's
        keyers expect (layers.nuke, ``mask_layers`` by default), so the look is whole without
        the render's EXR. ViewError for a mask of a kind the render has no Cryptomatte of."""
        needed = {}
        for grade in grades.values():
            if grade.mask is None:
                continue
            if grade.mask.kind not in self.cryptomattes:
                raise ViewError(f"a mask of {grade.mask.kind}s, but the render wrote no {grade.mask.kind} Cryptomatte")
            needed[grade.mask.source] = self.cryptomattes[grade.mask.kind][1]
        return needed

    # -- save

    def save(self, name: str, stack: list[dict], exposure: float = 0.0, overwrite: bool = False,
             document: dict | None = None) -> dict:
        """/api/save: NAME.usda (the recipe), NAME.exr and its previews (extracted from the
        index), NAME.nk (the grade), and with the page's `document`, NAME.view.json (the
        look's working state: opening NAME.exr shows exactly this), all in the folder,
        together or not at all."""
        from ..stage.recipe_writer import write_recipe  # USD is imported only when saving

        index = self._need_index("save the stack (its layers are extracted from it)")
        _check_save_name(name, "save")
        exposure = _stops(exposure, "exposure")
        chosen, grades = self._stack(stack)
        look = self._look_document(document, stack, chosen, exposure, name)
        # the raw stack (its grades are the look's; a render with --denoise makes the twin), with
        # the Cryptomattes its masked grades key, so that the look stands without the render's EXR
        cryptomattes = self.look_cryptomattes(grades)
        # its previews through the view the page shows (the document's choice)
        view = self._lut(look["display_view"] if look else None).view
        recipe = Recipe((replace(self.base_product, name=name.replace("-", "_"), output_name=f"{name}.exr", prim_path="",
                                 layers=tuple(chosen), per_light="none", denoise=False, view=view),)
                        ).with_cryptomattes(cryptomattes)
        paths = {"recipe": self.folder / f"{name}.usda", "exr": self.folder / f"{name}.exr",
                 "nuke": self.folder / f"{name}.nk"}
        if look is not None:
            paths["document"] = documents.document_path(self.folder, name)
        partition = self._partition([self.layers[entry["id"]] for entry in stack if entry["id"] != "beauty"])
        # The check and the writes together: of two saves of one name, one is refused. A save
        # named after the render (overwrite: true) does not replace the index and EXR it reads.
        with self._lock, reading(*index_inputs(index)), OutputSet():
            existing = [path.name for path in paths.values() if path.exists()]
            if existing and not overwrite:
                raise ViewError(f"{', '.join(existing)} exist in {self.folder}: save under another name, "
                                "or overwrite", 409)
            deliver(index, recipe, self.beauty, {recipe.products[0].name: paths["exr"]}, data=cryptomattes,
                    metadata=index_metadata(index, self.folder))
            write_recipe(paths["recipe"], recipe)
            write_nuke_script(paths["nuke"], paths["exr"], [layer.name for layer in chosen], grades,
                              resolution=(self.width, self.height), exposure=float(exposure), partition=partition,
                              pixel_aspect_ratio=self.base_product.pixel_aspect_ratio,
                              cryptomattes={source: matte.depth for source, matte in cryptomattes.items()})
            if look is not None:
                documents.write(paths["document"], look)
        log.info("saved %s", ", ".join(str(path) for path in paths.values()))
        return {key: path.name for key, path in paths.items()}

    def _stack(self, stack: list[dict]) -> tuple[list[Layer], dict[str, LayerGrade]]:
        """The recipe layers and the grades of the page's stack entries ({id: the server
        layer, name: the layer's name in the look (default: the server layer's), group, stops,
        tint, mute, solo}): one entry may rename a layer, two may show one layer."""
        if not isinstance(stack, list) or not stack:
            raise ViewError("the stack to save holds no layers")
        layers, grades = [], {}
        for entry in stack:
            if not isinstance(entry, dict):
                raise ViewError("each stack entry is an object {id, stops, tint, mute, solo}")
            if not isinstance(entry.get("id"), str):
                raise ViewError(f"a stack entry's id is a layer id (a string), not {_shown(entry.get('id'))}")
            layer = self.layer(entry.get("id"))
            if layer.kind == "beauty":
                continue
            layer_name = _check_layer_name(entry.get("name", layer.name))
            if layer_name in grades:
                raise ViewError(f"two layers of the stack are named {layer_name!r}")
            group = entry.get("group") or "inspector"
            if not isinstance(group, str) or len(group) > documents.MAX_TEXT:
                raise ViewError(f"layer {layer_name!r}: group is a name of at most {documents.MAX_TEXT} characters")
            note = entry.get("note") or ""
            if not isinstance(note, str) or len(note) > documents.MAX_NOTE or not note.isprintable():
                raise ViewError(f"layer {layer_name!r}: note is one line of at most {documents.MAX_NOTE} characters")
            grade = grade_from_json(entry, f"layer {layer_name!r}", known=self.mask_names)
            try:
                layers.append(Layer(layer_name, "lpe", layer.expression, exposure=grade.stops, tint=grade.tint,
                                    group=group, description=note))
            except (TypeError, ValueError, RecipeError) as error:
                raise ViewError(f"layer {layer_name!r}: {error}") from None
            grades[layer_name] = grade
        if not layers:
            raise ViewError("the stack to save holds no layers (the beauty is always part 0)")
        return layers, grades

    # -- push (the look back into the shot: view/push.py decides, stage/light_overrides.py writes)

    def pushable(self, stack: list[dict]) -> dict:
        """/api/pushable: which stack entries /api/push would write as light edits, and why
        each other one stays a compositing grade; no file is written. ``stage`` is why the
        shot's lights could not be read (their groups, animation...), else None."""
        index = self._need_index("push grades to lights")
        entries = self._push_entries(stack)
        plan, _, problem = self._push_plan(index, entries, need_stage=False)  # reads no records: no lock
        return {**plan.description(), "stage": problem}

    def push(self, name: str, stack: list[dict], exposure: float = 0.0, overwrite: bool = False) -> dict:
        """/api/push: the grades of whole lights as NAME.lights.usda (overrides of the UsdLux
        lights) and NAME.shot.usda (it over the stage), together or not at all; the other
        grades stay compositing grades, each with its reason."""
        from ..stage.light_overrides import LightChange, write_push

        index = self._need_index("push grades to lights")
        _check_save_name(name, "push")
        exposure = _stops(exposure, "exposure")
        entries = self._push_entries(stack)
        with self._push_lock:
            plan, lights, _ = self._push_plan(index, entries, need_stage=True)
            if not plan.pushed:
                raise ViewError("no layer of the stack is a grade of one whole light: nothing to push "
                                f"({'; '.join(f'{grade.layer}: {grade.why}' for grade in plan.compositing)})")
            changes = [LightChange(edit.lights, edit.layer, edit.grade.stops, edit.grade.tint, edit.grade.kelvin,
                                   edit.grade.mute) for edit in plan.pushed]
            try:
                paths, edits = write_push(self.folder, name, index.manifest, changes, lights, overwrite=overwrite,
                                          description=f"Rendered from {index.path.name}.")
            except PxrLayersError as error:  # the files exist, the stage changed, a light cannot take it
                raise ViewError(str(error).splitlines()[0], 409) from None
        notes = list(plan.notes)
        if exposure:
            notes.append(f"the view's exposure ({exposure:+g} stops) is a display setting: not pushed")
        log.info("pushed %d layers as light edits (%s, %s)", len(plan.pushed), *(p.name for p in paths.values()))
        return {"pushed": [{**edit.description(), "edits": {path: edits[path] for path in edit.lights}}
                           for edit in plan.pushed],
                "compositing": [grade.description() for grade in plan.compositing], "notes": notes,
                "files": {key: path.name for key, path in paths.items()}}

    def _push_plan(self, index: PathIndex, entries, *, need_stage: bool):
        """(the plan, the shot's lights or None, why they could not be read or None): entries
        whose edit cannot be written exactly on the stage (light_overrides.planned_edits)
        become compositing grades with that reason."""
        from ..stage.light_overrides import LightChange, planned_edits, read_shot_lights

        try:
            lights = read_shot_lights(index.manifest)
        except PxrLayersError as error:
            if need_stage:
                raise ViewError(str(error).splitlines()[0], 409) from None
            lights, problem = None, str(error).splitlines()[0]
        else:
            problem = None
        plan = push.classify(index, entries, {path: light.group for path, light in lights.items()} if lights else None)
        if lights is None:
            return plan, None, problem
        pushed, refused = [], []
        for edit in plan.pushed:
            grade = edit.grade
            change = LightChange(edit.lights, edit.layer, grade.stops, grade.tint, grade.kelvin, grade.mute)
            try:
                for path in edit.lights:
                    if path not in lights:
                        raise ViewError(f"{edit.light}: the stage has no light {path} now (renamed since the render?)")
                    planned_edits(change, lights[path])
            except PxrLayersError as error:
                refused.append(push.CompositingGrade(edit.layer, str(error).splitlines()[0]))
            else:
                pushed.append(edit)
        return push.PushPlan(tuple(pushed), plan.compositing + tuple(refused), plan.notes), lights, problem

    def _push_entries(self, stack: list[dict]) -> list[push.PushEntry]:
        """The page's stack entries ({id, name, stops, tint, kelvin, mute, solo, mask}) as
        push entries (the beauty left out)."""

        if not isinstance(stack, list) or not stack:
            raise ViewError("the stack to push holds no layers")
        entries = []
        for entry in stack:
            if not isinstance(entry, dict) or not isinstance(entry.get("id"), str):
                raise ViewError("each stack entry is an object {id, name, stops, tint, kelvin, mute, solo, mask}")
            layer = self.layer(entry["id"])
            if layer.kind == "beauty":
                continue
            shown = entry.get("name", layer.name)
            shown = shown if isinstance(shown, str) and 0 < len(shown) <= MAX_NAME_CHARS else layer.name
            grade = grade_from_json(entry, f"layer {shown!r}")  # a mask's names need not be checked: it is not pushed
            entries.append(push.PushEntry(shown, layer.expression, grade))
        if len({entry.name for entry in entries}) != len(entries):
            raise ViewError("two layers of the stack have one name")
        return entries

    def _look_document(self, document, stack: list[dict], chosen: list[Layer], exposure: float,
                       name: str) -> dict | None:
        """The document a saved look opens with (view/document.py): the page's `document` with
        each saved entry showing its part of NAME.exr (source = its layer name), the saved
        grades as the look's "saved" state. None without a document."""
        if document is None:
            return None
        try:
            document = documents.checked(json.loads(json.dumps(document)))
        except (documents.DocumentError, ValueError) as error:
            raise ViewError(f"document: {error}") from None
        saved = {layer.name for layer in chosen}
        renamed = {}  # a source of the render → the first saved entry's name showing it
        for entry in stack:
            if entry.get("name") in saved:
                renamed.setdefault(entry["id"], entry["name"])
        for entry in document["entries"]:
            if entry["kind"] == "layer" and entry["name"] in saved:
                entry["source"] = entry["name"]
        for snapshot in document["snapshots"]:
            for entry in snapshot["entries"]:
                entry["source"] = renamed.get(entry["source"], entry["source"])
        document["exposure"] = exposure
        document["saved"] = {"name": name, "exposure": exposure,
                             "entries": [entry for entry in document["entries"] if entry["kind"] == "layer"]}
        return document

    def _need_index(self, what: str) -> PathIndex:
        if self.index is None:
            raise ViewError(f"cannot {what}: {self.folder} has no path index of this render "
                            "(render with an index, and view its folder)", 409)
        return self.index


def _check_layer_name(name) -> str:
    """`name` if it may name a layer of a look (an EXR part Nuke reads as its own layer)."""
    if not isinstance(name, str) or len(name) > MAX_NAME_CHARS or not LAYER_NAME.fullmatch(name) \
            or name in NUKE_RESERVED_LAYERS:
        raise ViewError(f"layer name {_shown(name)}: at most {MAX_NAME_CHARS} letters, digits and _, not starting "
                        f"with a digit, and none of the layers Nuke keeps for itself "
                        f"({', '.join(sorted(NUKE_RESERVED_LAYERS))})")
    return name


def _check_save_name(name, what: str) -> None:
    """`name` may name the files /api/save or /api/push writes (SAVE_NAME)."""
    if not isinstance(name, str) or len(name) > MAX_NAME_CHARS or not SAVE_NAME.fullmatch(name):
        raise ViewError(f"{what} name {_shown(name)}: at most {MAX_NAME_CHARS} letters, digits, _ and -, "
                        "not starting with a digit or -")


# --- opening helpers ----------------------------------------------------------------------


def _folder_index(folder: Path) -> PathIndex | None:
    indexes = sorted(folder.glob(f"*{INDEX_SUFFIX}"))
    if len(indexes) > 1:
        raise ViewError(f"{folder} holds {len(indexes)} path indexes ({', '.join(p.name for p in indexes)}): "
                        "view one of them")
    return PathIndex(indexes[0]) if indexes else None


def _index_named(product: MultipartImage) -> str | None:
    """The index a product names (``pxrLayers/index`` on its parts)."""
    for attributes in (product.beauty_metadata, *product.metadata.values()):
        if attributes.get("index"):
            return attributes["index"]
    return None


def _index_of_beauty(path: Path) -> str | None:
    """The index beside `path` whose render wrote it as its beauty (a product without
    layers names no index; the index names its beauty, manifest ``beauty``)."""
    for candidate in sorted(path.parent.glob(f"*{INDEX_SUFFIX}")):
        try:
            if PathIndex(candidate).manifest.get("beauty") == path.name:
                return candidate.name
        except PxrLayersError:
            continue
    return None


def _render_ids(product: MultipartImage) -> set[str | None]:
    return {attributes.get("renderId") for attributes in (product.beauty_metadata, *product.metadata.values())}


def _products_beside(folder: Path, index: PathIndex | None) -> list[MultipartImage]:
    """The product EXRs of the folder that `index`'s render wrote (all of them without an
    index), in name order; EXRs that are not pxr-layers products, and denoised twins, are
    skipped."""
    render_id = index.manifest.get("render_id") if index else None
    products = []
    for path in sorted(folder.glob("*.exr")):
        if path.stem.endswith(DENOISED_SUFFIX):  # a denoised twin: the inspector shows the raw stack
            continue
        try:
            product = read_multipart(path)
        except PxrLayersError as error:
            log.info("skipping %s: %s", path.name, error)
            continue
        if product.parts and (render_id is None or render_id in _render_ids(product)):
            products.append(product)
    return products


def _same_size(products: list[MultipartImage], index: PathIndex | None) -> list[MultipartImage]:
    """The products of the index's size (of the first product's, without an index); the
    others, from another render, are left out with a warning."""
    if not products:
        return products
    size = tuple(index.manifest["resolution"]) if index else products[0].beauty.shape[1::-1]
    kept = []
    for product in products:
        if product.beauty.shape[1::-1] == size:
            kept.append(product)
        else:
            log.warning("leaving out %s: %dx%d, not %dx%d", product.path.name, *product.beauty.shape[1::-1], *size)
    return kept


def _product_layers(products: list[MultipartImage], beauty: np.ndarray) -> list[ViewLayer]:
    """The colour layers of the products, in product then part order; a name seen in an
    earlier product gets its product's stem as a prefix."""
    layers: list[ViewLayer] = []
    seen: set[str] = {"beauty"}
    for product in products:
        grades = {layer.name: layer for product_ in (product.recipe.products if product.recipe else ())
                  for layer in product_.layers}
        colour = product.colour_layers()
        shares = energy_shares(beauty, colour)
        for name, image in colour.items():
            layer_id = name if name not in seen else f"{product.path.stem}.{name}"
            seen.add(layer_id)
            recipe_layer = grades.get(name)
            attributes = product.metadata[name]
            layers.append(ViewLayer(layer_id, name, "layer", product.path.name, attributes.get("expression"), image,
                                    shares[name], recipe_layer.exposure if recipe_layer else 0.0,
                                    recipe_layer.tint if recipe_layer else (1.0, 1.0, 1.0)))
    return layers


def _product_cryptomattes(products: list[MultipartImage]) -> dict[str, tuple[str, Cryptomatte]]:
    """mask kind → (EXR layer, Cryptomatte) of the products' Cryptomatte layers, by their
    source (CRYPTOMATTE_KINDS); of two of one source, the first product's."""
    kinds = {source: kind for kind, source in CRYPTOMATTE_KINDS.items()}
    found: dict[str, tuple[str, Cryptomatte]] = {}
    for product in products:
        for name, matte in product.cryptomattes.items():
            kind = kinds.get(product.metadata.get(name, {}).get("source", name))
            if kind is not None and kind not in found:
                found[kind] = (name, matte)
    return found


def _denoised_twins(products: list[MultipartImage], layers: list[ViewLayer]) -> tuple[np.ndarray, np.ndarray] | None:
    """Give `layers` (the beauty's and the products', ViewLayer.product naming their EXR)
    their versions from the products' denoised twins beside them, and return the twins'
    guides (deliver.GUIDE_SOURCES); None, and no denoised version, unless every product has
    its twin of the same render."""
    twins = {}
    for product in products:
        path = denoised_path(product.path)
        if not path.is_file():
            return None
        try:
            twin = read_multipart(path)
        except PxrLayersError as error:
            log.warning("leaving out the denoised twins: %s", error)
            return None
        if _render_ids(twin) != _render_ids(product) or not all(source in twin.parts for source in GUIDE_SOURCES):
            return None
        twins[product.path.name] = twin
    if not twins:
        return None
    for layer in layers:
        twin = twins[layer.product]
        layer.denoised = twin.beauty[..., :3] if layer.kind == "beauty" else twin.colour_layers()[layer.name]
    first = twins[products[0].path.name]
    return tuple(first.parts[source] for source in GUIDE_SOURCES)


def _base_product(products: list[MultipartImage], index: PathIndex | None, beauty: np.ndarray) -> Product:
    """What a saved recipe inherits: the first product's colour and index settings, else
    the defaults at the index's camera and resolution."""
    for product in products:
        if product.recipe is not None:
            return at_index_view(product.recipe.products[0], index) if index else product.recipe.products[0]
    camera = index.manifest.get("camera", "") if index else ""
    bounces = index.norm_slots if index else IndexSettings().bounces
    return Product("inspector", "inspector.exr", camera or DEFAULT_CAMERA_PATH, (beauty.shape[1], beauty.shape[0]),
                   (Layer("beauty", "raw", "color"),), index=IndexSettings(bounces=bounces))  # save() sets the layers
