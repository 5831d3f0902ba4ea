"""Check the Light Path Expressions of a recipe with the LPE compiler (:mod:`pxr_layers.lpe`)."""

from __future__ import annotations

from ..errors import LpeError, RecipeError

LPE_PREFIX = "lpe:"
"""Some tools write ``sourceName = "lpe:C<RD>.*"``; the prefix is accepted and dropped."""


def normalise_expression(text: str) -> str:
    """The expression without surrounding spaces and without a leading ``lpe:``."""
    text = text.strip()
    return text[len(LPE_PREFIX):].strip() if text.startswith(LPE_PREFIX) else text


def check_expression(expression: str, prim: str | None = None, attribute: str | None = "sourceName",
                     *, file: str | None = None):
    """Compile ``expression``; a syntax error becomes a RecipeError naming the prim and attribute.

    The message keeps the compiler's caret line under the fault. Returns the compiled
    :class:`pxr_layers.lpe.Expression`.
    """
    from .. import (
        lpe,  # the compiler is pure Python; imported here to keep the model light
    )

    try:
        return lpe.compile(expression)
    except LpeError as error:  # syntax errors included
        raise RecipeError(f"bad Light Path Expression: {error}", file=file, prim=prim, attribute=attribute) from error


def covariance_needs(compiled) -> tuple[bool, bool]:
    """(uses any covariance condition, reads matrix entries Σij) of a compiled expression."""
    from ..lpe import conditions, nodes

    patterns = [pattern for pattern in nodes.event_patterns(compiled.tree) if pattern.condition is not None]
    return bool(patterns), any(conditions.reads_sigma(pattern.condition) for pattern in patterns)
