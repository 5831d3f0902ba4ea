"""Ctrl-C and SIGTERM, one mechanism for the whole program.

SIGTERM (what farm managers send before SIGKILL) raises :class:`~pxr_layers.errors.Terminated`,
a KeyboardInterrupt, wherever Ctrl-C would raise, so the same clean-up runs
(:func:`sigterm_raises`). Where an interrupt must not land at an arbitrary bytecode (in the
middle of renaming a frame's files; in a garbage-collector callback of Dask, which prints
it and goes on), :func:`recorded` makes both signals only record themselves, and
:func:`raise_recorded` raises them where the caller chooses.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

from .errors import Terminated

SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _raise_terminated(signal_number, frame) -> None:
    raise Terminated(signal_number)


@contextlib.contextmanager
def sigterm_raises() -> Iterator[None]:
    """While the block runs, SIGTERM raises Terminated (unless a program embedding us has a
    handler of its own)."""
    previous = signal.getsignal(signal.SIGTERM)
    if previous is not signal.SIG_DFL or threading.current_thread() is not threading.main_thread():
        yield
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def recorded() -> Iterator[list[int]]:
    """While the block runs, SIGINT and SIGTERM only append their number to the list it
    yields. Only in the main thread, where Python runs handlers, and only over Python's and
    our handlers: a signal that is ignored, or that a program embedding us handles, is left
    as it is. (pthread_sigmask would not do: the process's other threads, Embree's and
    numba's, would take the signal.)"""
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = {number: signal.getsignal(number) for number in SIGNALS}
    for number, handler in previous.items():
        if handler in (signal.default_int_handler, _raise_terminated):
            signal.signal(number, lambda signum, frame: received.append(signum))
    try:
        yield received
    finally:
        for number, handler in previous.items():
            if handler in (signal.default_int_handler, _raise_terminated):
                signal.signal(number, handler)


def raise_recorded(received: list[int]) -> None:
    """Raise the first signal :func:`recorded` received: Terminated or KeyboardInterrupt."""
    if received:
        raise Terminated(received[0]) if received[0] == signal.SIGTERM else KeyboardInterrupt
