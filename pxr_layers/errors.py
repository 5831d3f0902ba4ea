"""Every failure a user can cause has its own exception class, all under PxrLayersError.

The CLI turns any PxrLayersError into one line on stderr and exit code 1; anything else is a
bug: one "internal error" line and exit code 3, the traceback with -v.
"""


class PxrLayersError(Exception):
    """Base class of every error caused by the user's input or environment."""


def _located(message: str, places, separator: str = ": ") -> str:
    """``message`` after the places that are given (file, prim, key...), or alone."""
    where = separator.join(place for place in places if place)
    return f"{where}: {message}" if where else message


class StageError(PxrLayersError):
    """A USD stage cannot be opened, composed or understood.

    The message names the file and, where there is one, the prim path and attribute.
    """

    def __init__(self, message: str, *, file: str | None = None, prim: str | None = None):
        super().__init__(_located(message, (file, prim and f"prim {prim}"), ", "))
        self.file = file
        self.prim = prim


class RenderSettingsError(PxrLayersError):
    """Render settings (flags or UsdRender prims) that cannot be honoured."""


class OutputError(PxrLayersError):
    """An output file cannot be written."""


class LpeError(PxrLayersError):
    """A Light Path Expression cannot be evaluated as asked (e.g. a condition on a bounce
    whose covariance norms the index did not keep)."""


class LpeSyntaxError(LpeError):
    """A Light Path Expression (or a path in the textual notation) that does not parse.

    ``position`` is the 0-based character offset of the fault in ``query``; str() shows the
    message, then the query's line, then a caret under the fault.
    """

    def __init__(self, message: str, query: str, position: int):
        super().__init__(message)
        self.message = message
        self.query = query
        self.position = max(0, min(position, len(query)))

    def __str__(self) -> str:
        line_start = self.query.rfind("\n", 0, self.position) + 1
        line_end = self.query.find("\n", self.position)
        line = self.query[line_start : line_end if line_end >= 0 else len(self.query)]
        column = self.position - line_start
        # Tabs keep their width on the caret line so the caret stays under the fault.
        padding = "".join("\t" if char == "\t" else " " for char in line[:column])
        return f"{self.message}\n  {line}\n  {padding}^"


class PathIndexError(PxrLayersError):
    """A path index file is truncated, corrupted, foreign or of an unsupported version.

    The message names the file and what is wrong with it.
    """

    def __init__(self, message: str, *, file: str | None = None):
        super().__init__(_located(message, (file,)))
        self.file = file


class RecipeError(PxrLayersError):
    """A layer recipe (UsdRender settings, products, vars, pxrLayers attributes) that cannot be used.

    The message names the file, then the prim and attribute at fault as a USD property path
    (``/Render/Vars/diffuse.sourceName``), then what is wrong; a bad Light Path Expression
    keeps the LPE error's caret lines under it.
    """

    def __init__(self, message: str, *, file: str | None = None, prim: str | None = None,
                 attribute: str | None = None):
        site = f"{prim}.{attribute}" if prim and attribute else prim or (attribute and f"attribute {attribute}")
        super().__init__(_located(message, (file, site)))
        self.message = message
        self.file = file
        self.prim = prim
        self.attribute = attribute


class JobError(PxrLayersError):
    """A shot job definition (a TOML job file, or one it extends) that cannot be used.

    The message names the file that sets the value at fault, then its key as a dotted TOML
    path (``render.spp``), then what is wrong. ``position`` is the 0-based character offset
    of the fault in a frame range text, when there is one.
    """

    def __init__(self, message: str, *, file: str | None = None, key: str | None = None,
                 position: int | None = None):
        super().__init__(_located(message, (file, key)))
        self.message = message
        self.file = file
        self.key = key
        self.position = position
