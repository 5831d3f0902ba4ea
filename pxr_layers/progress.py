"""Progress of long work: a one-line bar on a terminal, a log line every 10 % elsewhere."""

from __future__ import annotations

import logging
import sys
import time

from .interrupts import raise_if_swallowed

log = logging.getLogger("pxr_layers")


class Progress:
    """Counts `total` units of work. Silent when `enabled` is False."""

    def __init__(self, total: int, label: str, *, enabled: bool = True, stream=None):
        self.total = max(int(total), 1)
        self.label = label
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.interactive = enabled and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.done = 0
        self.start = time.perf_counter()
        self._last_decile = -1

    def advance(self, units: int) -> None:
        raise_if_swallowed()  # a Ctrl-C a library caught and dropped ends the work here
        self.done += units
        if not self.enabled:
            return
        fraction = min(self.done / self.total, 1.0)
        elapsed = time.perf_counter() - self.start
        remaining = elapsed * (1 - fraction) / fraction if fraction > 0 else float("nan")
        if self.interactive:
            filled = int(fraction * 30)
            self.stream.write(
                f"\r{self.label} [{'#' * filled}{'.' * (30 - filled)}] {fraction:6.1%} "
                f"{elapsed:6.1f}s elapsed, {remaining:6.1f}s left"
            )
            if self.done >= self.total:
                self.stream.write("\n")
            self.stream.flush()
        else:
            decile = int(fraction * 10)
            if decile > self._last_decile:
                self._last_decile = decile
                log.info("%s: %3.0f%% (%.1fs elapsed)", self.label, fraction * 100, elapsed)
