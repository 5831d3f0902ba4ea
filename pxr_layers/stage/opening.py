"""Open a USD stage and turn every way it can fail into a one-line StageError.

USD reports problems three ways: ``Tf.ErrorException`` (the root layer cannot be read),
composition errors kept on the stage (missing sublayers, references, payloads), and Tf
warnings printed on stderr. The first two become StageError; the Tf chatter is trapped and
sent to the debug log so the user sees one clean line instead of C++ source locations.
"""

from __future__ import annotations

import logging
import math
import os
import re

from pxr import Pcp, Tf, Usd

from pxr_layers.errors import StageError

from .diagnostics import Diagnostics

logger = logging.getLogger(__name__)

# Tf.ErrorException text looks like "\n\tError in 'Func' at line N in file F : 'message'";
# only the quoted message means anything to a user.
_TF_MESSAGE = re.compile(r" : '(.*)'\s*$")

# Pcp says this when a referenced file exists but no file-format plugin can read it, e.g.
# .mtlx in a usd-core wheel built without usdMtlx. That is a capability of this USD build,
# not a broken scene, so it is a warning rather than an error.
_UNREADABLE_FORMAT = "Cannot determine file format"


def tf_error_summary(error: BaseException) -> str:
    """The user-facing messages of a Tf.ErrorException on one line."""
    messages = []
    for line in str(error).splitlines():
        match = _TF_MESSAGE.search(line)
        if match:
            messages.append(match.group(1))
    return "; ".join(messages) if messages else " ".join(str(error).split())


def open_stage(path: str, diagnostics: Diagnostics) -> Usd.Stage:
    """Open ``path`` with every payload loaded.

    Raises StageError (naming the file) when the file is missing, is not a USD layer, or
    does not compose (missing sublayer, reference or payload, arc cycles, ...). References to
    files this USD build has no reader for are skipped with one warning.
    """
    if not os.path.exists(path):
        raise StageError("file not found", file=path)
    if os.path.isdir(path):
        raise StageError("is a directory, not a USD file", file=path)
    with Tf.DiagnosticTrap() as trap:
        try:
            stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
        except Tf.ErrorException as error:
            raise StageError(f"cannot open as USD: {tf_error_summary(error)}", file=path) from None
        finally:
            # Keep USD's own warnings out of stderr; composition problems come back below
            # through GetCompositionErrors() with better context.
            for warning in trap.GetWarnings():
                logger.debug("USD: %s", warning.commentary)
            trap.Clear()
    if stage is None:
        raise StageError("cannot open as USD", file=path)
    _check_composition(stage, path, diagnostics)
    return stage


def _check_composition(stage: Usd.Stage, path: str, diagnostics: Diagnostics) -> None:
    fatal: list[str] = []
    for error in stage.GetCompositionErrors():
        message = str(error).strip()
        if error.errorType == Pcp.ErrorType_InvalidAssetPath and _UNREADABLE_FORMAT in message:
            diagnostics.note(
                "unreadable-reference",
                "skipped references to files this USD build cannot read (no file-format "
                "plugin, e.g. MaterialX) under: {prims}",
                str(error.rootSite.path),
            )
            continue
        # Pcp words sublayer errors as "...; skipping." but here they stop the read.
        fatal.append(message.removesuffix("; skipping."))
    if fatal:
        more = f" (and {len(fatal) - 1} more composition errors)" if len(fatal) > 1 else ""
        raise StageError(f"does not compose: {fatal[0]}{more}", file=path)


def resolve_time(stage: Usd.Stage, frame: float | None) -> tuple[Usd.TimeCode, float]:
    """The time code every read uses, and its numeric frame (NaN for 'earliest sample')."""
    if frame is not None:
        return Usd.TimeCode(float(frame)), float(frame)
    if stage.GetRootLayer().HasStartTimeCode():
        start = float(stage.GetStartTimeCode())
        return Usd.TimeCode(start), start
    return Usd.TimeCode.EarliestTime(), math.nan
