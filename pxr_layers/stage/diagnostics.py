"""User-facing warnings raised while reading a stage, logged and collected for SceneData.

A production stage can trip the same problem on thousands of prims (every curve of a groom,
every degenerate sliver of a scan). Warnings are therefore grouped by *kind*: the reader
notes each offending prim under a kind, and :meth:`Diagnostics.finish` emits one line per
kind naming the prims, so the log stays readable and SceneData.warnings stays small.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

logger = logging.getLogger(__name__)

# A warning lists at most this many prim paths, then "and N more": enough to find the
# culprits in a DCC without turning one warning into a page.
MAX_LISTED_PRIMS = 8


@dataclass
class _Group:
    """Prims (with a count each) noted under one kind of warning."""

    template: str
    counts: dict[str, int] = field(default_factory=dict)


class Diagnostics:
    """Collects warnings for one ``load_stage`` call.

    ``warn`` emits immediately (one-off problems with their own wording); ``note`` groups a
    prim under a kind whose ``template`` is formatted once at the end with ``{prims}`` (the
    listed paths) and ``{count}`` (the summed counts, e.g. dropped triangles).
    """

    def __init__(self) -> None:
        self._messages: list[str] = []
        self._groups: dict[str, _Group] = {}
        self._once_keys: set[str] = set()

    def warn(self, message: str, *, once_key: str | None = None) -> None:
        """Log ``message`` and keep it; with ``once_key``, only the first call per key counts."""
        if once_key is not None:
            if once_key in self._once_keys:
                return
            self._once_keys.add(once_key)
        logger.warning(message)
        self._messages.append(message)

    def note(self, kind: str, template: str, prim_path: str, count: int = 1) -> None:
        """Group ``prim_path`` under ``kind``; the first template given for a kind is used."""
        group = self._groups.setdefault(kind, _Group(template))
        group.counts[prim_path] = group.counts.get(prim_path, 0) + count

    def finish(self) -> tuple[str, ...]:
        """Emit one warning per noted kind and return every warning in emission order."""
        for group in self._groups.values():
            paths = list(group.counts)
            listed = ", ".join(paths[:MAX_LISTED_PRIMS])
            if len(paths) > MAX_LISTED_PRIMS:
                listed += f" and {len(paths) - MAX_LISTED_PRIMS} more"
            message = group.template.format(prims=listed, count=sum(group.counts.values()))
            logger.warning(message)
            self._messages.append(message)
        self._groups.clear()
        return tuple(self._messages)
