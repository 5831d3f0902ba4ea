"""Every failure a user can cause has its own exception class, all under PxrLayersError.

The CLI turns any PxrLayersError into one line on stderr and exit code 1; anything else is a
bug and keeps its traceback.
"""


class PxrLayersError(Exception):
    """Base class of every error caused by the user's input or environment."""


class StageError(PxrLayersError):
    """A USD stage cannot be opened, composed or understood.

    The message names the file and, where there is one, the prim path and attribute.
    """

    def __init__(self, message: str, *, file: str | None = None, prim: str | None = None):
        where = ", ".join(part for part in (file, prim and f"prim {prim}") if part)
        super().__init__(f"{where}: {message}" if where else message)
        self.file = file
        self.prim = prim


class RenderSettingsError(PxrLayersError):
    """Render settings (flags or UsdRender prims) that cannot be honoured."""


class OutputError(PxrLayersError):
    """An output file cannot be written."""
