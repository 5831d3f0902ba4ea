"""Every failure a user can cause has its own exception class, all under PxrLayersError.

The CLI turns any PxrLayersError into one line on stderr and exit code 1; anything else is a
bug: one "internal error" line and exit code 3, the traceback with -v.
"""

import unicodedata


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
    message, then the query's line, then a caret under the fault. The caret is placed by
    display width (wide CJK and emoji characters take two columns, combining marks none);
    control characters are shown escaped (``\\x1b``), and a line longer than the context
    shown on each side of the fault (SHOWN_CONTEXT) is cut, with ``…`` at each cut.
    """

    SHOWN_CONTEXT = 60
    """Characters of the query's line shown on each side of the fault."""

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
        first, last = max(0, column - self.SHOWN_CONTEXT), min(len(line), column + self.SHOWN_CONTEXT)
        before = ("…" if first > 0 else "") + _shown(line[first:column])
        after = _shown(line[column:last]) + ("…" if last < len(line) else "")
        return f"{self.message}\n  {before}{after}\n  {_padding(before)}^"


def _shown(text: str) -> str:
    """``text`` as a terminal may show it: control characters (but tabs) escaped, so that
    the query cannot move the cursor or colour the terminal, and the caret stays aligned."""
    return "".join(
        char if char == "\t" or unicodedata.category(char) != "Cc" else repr(char)[1:-1] for char in text
    )


ZERO_WIDTH_JOINER = "\u200d"


def _padding(text: str) -> str:
    """Blanks as wide on a terminal as ``text``: tabs kept, wide characters (east Asian
    wide or full-width, most emoji) two columns, combining marks and format characters
    (zero-width joiners) none, a character joined to the previous one by a zero-width
    joiner (the parts of 👩‍💻) none, anything else one."""
    blanks = []
    joined = False
    for char in text:
        if char == "\t":
            blanks.append("\t")
        elif not (joined or unicodedata.combining(char) or unicodedata.category(char) in ("Mn", "Me", "Cf")):
            blanks.append("  " if unicodedata.east_asian_width(char) in ("W", "F") else " ")
        joined = char == ZERO_WIDTH_JOINER
    return "".join(blanks)


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


class Terminated(KeyboardInterrupt):
    """SIGTERM (what farm managers send before SIGKILL), raised where Ctrl-C's
    KeyboardInterrupt would be, so the same clean-up runs: temporaries removed, a frame's
    outputs all or nothing. ``exit_code``: 128 + the signal's number, as a shell reports it."""

    def __init__(self, signal_number: int = 15):
        super().__init__("SIGTERM")
        self.exit_code = 128 + signal_number
