"""Compose a shot: the stage, its recipe layers and variant selections, opened once.

USD reports problems three ways: ``Tf.ErrorException`` (the root layer cannot be read),
composition errors kept on the stage (missing sublayers, references, payloads, files no
file-format plugin reads), and Tf warnings printed on stderr. The first is a StageError.
Composition errors are warnings naming the file and the prim, and the rest of the stage
renders, as in usdview and husk; ``strict`` makes them fatal (a farm's submission check).
The Tf chatter is trapped (:func:`trapped_usd_diagnostics`) and sent to the debug log, so a
user sees our one-line messages instead of C++ source locations.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import re
from collections.abc import Iterator, Sequence

from pxr import Pcp, Sdf, Tf, Usd

from pxr_layers.errors import RecipeError, StageError
from pxr_layers.inputs import regular_input
from pxr_layers.request import VariantSelection

from .diagnostics import Diagnostics

logger = logging.getLogger(__name__)

# Pcp says this when a referenced file exists but no file-format plugin can read it, e.g.
# .mtlx in a usd-core wheel built without usdMtlx: a capability of this USD build, not a
# broken scene (and for .mtlx, not even a loss: the materialx package reads them).
_UNREADABLE_FORMAT = "Cannot determine file format"
_ASSET = re.compile(r"@([^@]+)@")  # Pcp quotes asset paths as @path@

SESSION_LAYER_NAME = "pxr_layers_session.usda"


def tf_error_summary(error: BaseException) -> str:
    """The user-facing messages of a Tf.ErrorException on one line, without C++ locations.

    The text is "\n\tError in 'F' at line N in file P : 'message'" per error, and a message
    may itself hold quotes and span lines.
    """
    messages = []
    for chunk in str(error).split("Error in ")[1:]:
        _, found, message = chunk.partition(" : '")
        if found:
            messages.append(" ".join(message.strip().removesuffix("'").split()))
    return "; ".join(messages) if messages else " ".join(str(error).split())


@contextlib.contextmanager
def trapped_usd_diagnostics(file: str) -> Iterator[None]:
    """Run USD calls with its Tf warnings and status lines kept off stderr (debug log only)
    and a Tf.ErrorException turned into a StageError naming ``file``."""
    with Tf.DiagnosticTrap() as trap:
        try:
            yield
        except Tf.ErrorException as error:
            raise StageError(f"USD failed while reading: {tf_error_summary(error)}", file=file) from None
        finally:
            for warning in trap.GetWarnings():
                logger.debug("USD: %s", warning.commentary)
            for status in trap.GetStatuses():
                logger.debug("USD: %s", status.commentary)
            trap.Clear()


def compose_stage(
    path: str,
    diagnostics: Diagnostics,
    *,
    recipe_layers: Sequence[str | os.PathLike[str]] = (),
    variants: Sequence[VariantSelection] = (),
    strict: bool = False,
) -> Usd.Stage:
    """Open ``path`` with every payload loaded and ``recipe_layers`` composed over it.

    The recipe layers are sublayers of the stage's session layer (the first strongest), and
    variant selections are authored in the session layer itself, so they win over both.
    Raises StageError (naming the file) when the shot file is missing, not a regular file
    (inputs.py) or not USD, RecipeError for a recipe layer missing or not a regular file,
    StageError for a variant selection that names no prim, no variant set or no variant of
    it, and for composition errors when ``strict``.
    """
    regular_input(path, "USD file", StageError)  # a FIFO or a device would block the open
    for layer in recipe_layers:
        regular_input(layer, "recipe layer", RecipeError)
        with Tf.DiagnosticTrap() as trap:
            try:
                readable = Sdf.Layer.FindOrOpen(os.fspath(layer)) is not None
            except Tf.ErrorException as error:
                raise RecipeError(f"cannot open as USD: {tf_error_summary(error)}", file=os.fspath(layer)) from None
            finally:
                trap.Clear()
        if not readable:
            raise RecipeError("cannot open as USD", file=os.fspath(layer))
    with Tf.DiagnosticTrap() as trap:
        try:
            root = Sdf.Layer.FindOrOpen(path)
            session = Sdf.Layer.CreateAnonymous(SESSION_LAYER_NAME)
            session.subLayerPaths = [os.path.abspath(layer) for layer in recipe_layers]
            stage = Usd.Stage.Open(root, session, Usd.Stage.LoadAll) if root else None
        except Tf.ErrorException as error:
            raise StageError(f"cannot open as USD: {tf_error_summary(error)}", file=path) from None
        finally:
            # Composition problems come back below through GetCompositionErrors(), with the
            # prim they concern; USD's own printout of them would only repeat them.
            for warning in trap.GetWarnings():
                logger.debug("USD: %s", warning.commentary)
            trap.Clear()
    if stage is None:
        raise StageError("cannot open as USD", file=path)
    stage.SetEditTarget(Usd.EditTarget(session))
    with trapped_usd_diagnostics(path):
        for selection in variants:
            _select_variant(stage, selection, path)
    _check_composition(stage, path, diagnostics, strict)
    return stage


def _select_variant(stage: Usd.Stage, selection: VariantSelection, file: str) -> None:
    where = f"--variant {selection}"
    if not Sdf.Path.IsValidPathString(selection.prim) or not Sdf.Path(selection.prim).IsAbsolutePath():
        raise StageError(f"{where}: {selection.prim!r} is not an absolute prim path", file=file)
    prim = stage.GetPrimAtPath(selection.prim)
    if not prim:
        raise StageError(f"{where}: no such prim", file=file, prim=selection.prim)
    variant_sets = prim.GetVariantSets()
    if not variant_sets.HasVariantSet(selection.variant_set):
        known = ", ".join(variant_sets.GetNames()) or "none"
        raise StageError(f"{where}: no variant set {selection.variant_set!r} (the prim has: {known})",
                         file=file, prim=selection.prim)
    variant_set = variant_sets.GetVariantSet(selection.variant_set)
    names = variant_set.GetVariantNames()
    if selection.value not in names:
        raise StageError(f"{where}: no variant {selection.value!r} in {selection.variant_set} "
                         f"(it has: {', '.join(names) or 'none'})", file=file, prim=selection.prim)
    variant_set.SetVariantSelection(selection.value)


def _check_composition(stage: Usd.Stage, path: str, diagnostics: Diagnostics, strict: bool) -> None:
    problems: list[tuple[str, str]] = []  # (kind, "prim: what")
    for error in stage.GetCompositionErrors():
        message = " ".join(str(error).split()).removesuffix("; skipping.")
        site = str(error.rootSite.path) if error.rootSite else "/"
        unreadable = error.errorType == Pcp.ErrorType_InvalidAssetPath and _UNREADABLE_FORMAT in message
        if unreadable:
            asset = _ASSET.search(message)
            if asset and asset.group(1).lower().endswith(".mtlx"):
                continue  # stage/materialx/ reads .mtlx documents itself, through the bindings into them
            problems.append(("unreadable-reference", f"{site} ({asset.group(1) if asset else message})"))
        else:
            problems.append(("composition", f"{site}: {message}"))
    if not problems:
        return
    if strict:
        more = f" (and {len(problems) - 1} more composition errors)" if len(problems) > 1 else ""
        raise StageError(f"does not compose (--strict): {problems[0][1]}{more}", file=path)
    for kind, problem in problems:
        if kind == "unreadable-reference":
            diagnostics.note(
                kind,
                f"{path}: skipped references to files this USD build cannot read (no file-format "
                "plugin, e.g. MaterialX), the rest renders: {prims}",
                problem,
            )
        else:
            diagnostics.note(
                kind,
                f"{path}: composition errors, the rest of the stage renders (--strict makes them fatal): {{prims}}",
                problem,
            )


def resolve_time(stage: Usd.Stage, frame: float | None) -> tuple[Usd.TimeCode, float]:
    """The time code every read uses, and its numeric frame (NaN for 'earliest sample')."""
    if frame is not None:
        return Usd.TimeCode(float(frame)), float(frame)
    if stage.GetRootLayer().HasStartTimeCode():
        start = float(stage.GetStartTimeCode())
        return Usd.TimeCode(start), start
    return Usd.TimeCode.EarliestTime(), math.nan
