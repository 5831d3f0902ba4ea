"""What pxr-layers reads must be a regular file: the one rule, for every input it opens.

A FIFO (named pipe) given as a stage, a recipe layer, a path index or a job file makes the
open block until some other process writes into it, which is a hang as far as a user can
tell; a character device (``/dev/zero``, ``/dev/urandom``) never ends; a directory or a
socket has no contents to read. None of them can be the file the user meant, so each is
refused before it is opened, by name, as a missing file is.

:func:`input_problem` is the rule: why a path cannot be read as an input, or None.
:func:`regular_input` raises it as the caller's own error class (StageError for a stage,
PathIndexError for an index, ...), whose message names the file. Symbolic links are
followed: a link to a regular file is that file.

``os.stat`` looks at a FIFO without opening it, so the check itself never blocks. A file
swapped for a FIFO between the check and the open is not guarded against: that takes a
hostile process on the machine, not a hostile file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from .errors import PxrLayersError

_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)
"""What a path that is not a regular file is, as messages say it."""


def input_problem(path: str | os.PathLike[str], what: str) -> str | None:
    """Why ``path`` cannot be read as ``what`` (a noun phrase: "USD file", "path index"), or
    None when it is a regular file (or a link to one): "file not found", "is a FIFO (named
    pipe), not a path index", "cannot read it: Permission denied"."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "file not found"
    except (OSError, ValueError) as error:  # ELOOP, ENAMETOOLONG, EACCES on a folder; NUL in the name
        return f"cannot read it: {getattr(error, 'strerror', None) or error}"
    if stat.S_ISREG(mode):
        return None
    kind = next((name for test, name in _KINDS if test(mode)), "not a regular file")
    return f"is {kind}, not a {what}"


def regular_input(path: str | os.PathLike[str], what: str, error: type[PxrLayersError], *,
                  name: str | os.PathLike[str] | None = None) -> Path:
    """``path`` as a Path when it is a regular file (see :func:`input_problem`); else
    ``error(problem, file=name)``, where ``name`` is what messages call the file (default:
    ``path``). ``error`` is a PxrLayersError subclass that takes ``file=`` (StageError,
    RecipeError, PathIndexError, JobError)."""
    problem = input_problem(path, what)
    if problem is not None:
        raise error(problem, file=os.fspath(name if name is not None else path))
    return Path(path)
