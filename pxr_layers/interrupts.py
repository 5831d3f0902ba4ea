"""Ctrl-C and SIGTERM, one mechanism for the whole program.

SIGTERM (what farm managers send before SIGKILL) raises :class:`~pxr_layers.errors.Terminated`,
a KeyboardInterrupt, wherever Ctrl-C would raise, so the same clean-up runs
(:func:`signals_raise`). Both are also noted (:func:`noted`): a native library that receives
the interrupt while it loads turns it into an error of its own (pybind11's "ImportError:
initialization failed", OpenColorIO's) or swallows it (USD's module loader prints a warning and
goes on), and the command must still end as interrupted. Where an interrupt must not land at an arbitrary bytecode (in the
middle of renaming a frame's files; in a garbage-collector callback of Dask, which prints
it and goes on), :func:`recorded` makes both signals only record themselves, and
:func:`raise_recorded` raises them where the caller chooses.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator

from .errors import Terminated

SIGNALS = (signal.SIGINT, signal.SIGTERM)


_NOTED: list[int] = []


def _raise_terminated(signal_number, frame) -> None:
    _NOTED.append(signal_number)
    raise Terminated(signal_number)


def _raise_interrupt(signal_number, frame) -> None:
    _NOTED.append(signal_number)
    raise KeyboardInterrupt


OURS = (signal.default_int_handler, _raise_interrupt, _raise_terminated)
"""The handlers that raise: :func:`recorded` may stand in for them."""


def noted() -> KeyboardInterrupt | None:
    """The interrupt the handlers of :func:`signals_raise` raised last in its block (None:
    none), as the exception it was: for an error a library made of it."""
    return _interrupt(_NOTED[-1]) if _NOTED else None


def _interrupt(signal_number: int) -> KeyboardInterrupt:
    """The exception a signal raises: Terminated for SIGTERM, KeyboardInterrupt for SIGINT."""
    return Terminated(signal_number) if signal_number == signal.SIGTERM else KeyboardInterrupt()


def raise_if_swallowed() -> None:
    """Raise again an interrupt that a library caught and dropped (llvmlite's ctypes callbacks
    print it and return; USD's module loader prints it): our handler noted it, nothing unwound.
    Long work calls this as it goes (progress.Progress.advance)."""
    interrupt = noted()
    if interrupt is not None:
        raise interrupt


def _quiet_interrupts(unraisable) -> None:
    """sys.unraisablehook: an interrupt raised in a callback that cannot raise is not printed
    (a traceback instead of our one line); :func:`raise_if_swallowed` raises it again."""
    if unraisable.exc_type is not None and issubclass(unraisable.exc_type, KeyboardInterrupt):
        return
    sys.__unraisablehook__(unraisable)


def _silent(unraisable) -> None:
    """sys.unraisablehook once an interrupt has ended the command (signals_raise)."""


@contextlib.contextmanager
def signals_raise() -> Iterator[None]:
    """While the block runs, SIGTERM raises Terminated and SIGINT KeyboardInterrupt, both
    noted (unless a program embedding us has handlers of its own)."""
    _NOTED.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous_hook, sys.unraisablehook = sys.unraisablehook, _quiet_interrupts
    wanted = {signal.SIGTERM: (signal.SIG_DFL, _raise_terminated), signal.SIGINT: (signal.default_int_handler,
                                                                                 _raise_interrupt)}
    previous = {number: signal.getsignal(number) for number in wanted}
    for number, (default, handler) in wanted.items():
        if previous[number] is default:
            signal.signal(number, handler)
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        # After an interrupt the process ends: objects it cut short in their constructors
        # (llvmlite's) fail in their finalisers at exit, which is not the user's to read.
        sys.unraisablehook = _silent if _NOTED else previous_hook
        _NOTED.clear()


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
        if handler in OURS:
            signal.signal(number, lambda signum, frame: received.append(signum))
    try:
        yield received
    finally:
        for number, handler in previous.items():
            if handler in OURS:
                signal.signal(number, handler)


def raise_recorded(received: list[int]) -> None:
    """Raise the first signal :func:`recorded` received: Terminated or KeyboardInterrupt."""
    if received:
        raise _interrupt(received[0])
