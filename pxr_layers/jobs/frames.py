"""A job's frames and file names: frame ranges (``"1-24x4"``) and output templates
(``shot010.$F4``, ``####``, ``$JOB``), with the errors that name the job file and key.

Plain text work (no pxr, no numpy): :mod:`pxr_layers.jobs.definition` reads the keys,
this module reads what the frame and name keys say.
"""

from __future__ import annotations

import re
from typing import Any

from ..errors import JobError
from ..request import type_name


def job_error(message: str, file: str | None, key: str | None, position: int | None = None) -> JobError:
    """The JobError of a value: the file that sets it, its dotted key, the position in its text."""
    return JobError(message, file=file, key=key, position=position)


MAX_FRAMES = 100_000
"""Frames one job may have: over an hour of film at 24 fps, more than any shot, so a larger
set is a typo ("1-99999999999999"). A frame range is counted before it is expanded, so such
a range is refused at once, without building the frames it would hold."""
MAX_FRAME_NUMBER = 1 << 53
"""Frame numbers are at most this far from 0: every whole number up to 2^53 is exact as a
USD time code (a double), so consecutive frames stay distinct frames."""


def parse_frames(value: Any, *, file: str | None = None, key: str | None = "frames") -> tuple[float, ...]:
    """Frames from a job file's value: ``"1-24"``, ``"1-24x4"`` (start-end, every 4th),
    ``"1-10, 20, 30-40x2"``, a list ``[1, 5, 9]`` or one integer. Negative frames are
    written with a sign (``"-5--1"``). Every frame must be a whole number within
    ±MAX_FRAME_NUMBER and listed once, and there are at most MAX_FRAMES of them (counted
    before anything is expanded: time and memory are O(frames) ≤ O(MAX_FRAMES)).

    Raises JobError naming ``file`` and ``key``; for text, with the 0-based ``position`` of
    the fault.
    """
    if isinstance(value, bool):
        raise job_error(f"must be a frame range text or a list of frames, not {value!r}", file, key)
    if isinstance(value, (int, float)):
        value = [value]
    if isinstance(value, list):
        if len(value) > MAX_FRAMES:
            raise job_error(f"{len(value)} frames listed, more than the {MAX_FRAMES} a job may have (MAX_FRAMES)",
                         file, key)
        frames: list[float] = []
        seen: set[float] = set()
        for number, entry in enumerate(value):
            entry_key = f"{key}[{number}]" if key else None
            if isinstance(entry, bool) or not isinstance(entry, (int, float)):
                raise job_error(f"must be a frame number, not {type_name(entry)} ({entry!r})", file, entry_key)
            if not float(entry).is_integer():
                raise job_error(f"frame {entry!r} is not a whole number", file, entry_key)
            if abs(entry) > MAX_FRAME_NUMBER:
                raise job_error(f"frame {entry!r} is beyond ±{MAX_FRAME_NUMBER} (2^53, MAX_FRAME_NUMBER)",
                             file, entry_key)
            if float(entry) in seen:
                raise job_error(f"frame {int(entry)} is listed twice", file, entry_key)
            seen.add(float(entry))
            frames.append(float(entry))
        if not frames:
            raise job_error("no frames: the list is empty", file, key)
        return tuple(frames)
    if not isinstance(value, str):
        raise job_error(f"must be a frame range text or a list of frames, not {type_name(value)}", file, key)
    return _FrameText(value, file, key).parse()


class _FrameText:
    """``item ("," item)*`` with ``item = N | N "-" N ["x" STEP]``; spaces allowed."""

    _NUMBER = re.compile(r"[+-]?\d+")
    _UNSIGNED = re.compile(r"\d+")
    _DIGITS = len(str(MAX_FRAME_NUMBER))

    def __init__(self, text: str, file: str | None, key: str | None):
        self.text = text
        self.file = file
        self.key = key
        self.position = 0

    def fail(self, message: str, position: int | None = None, *, found: bool = True) -> JobError:
        """The error at ``position`` (default: here); ``found`` names what is there."""
        position = self.position if position is None else position
        if found:
            message += ", found " + (repr(self.text[position]) if position < len(self.text) else "the end")
        return job_error(f"bad frame range {shortened(self.text)}: {message} at character {position + 1}",
                      self.file, self.key, position)

    def skip_spaces(self) -> None:
        while self.position < len(self.text) and self.text[self.position].isspace():
            self.position += 1

    def peek(self) -> str:
        return self.text[self.position] if self.position < len(self.text) else ""

    def number(self, what: str, signed: bool = True) -> int:
        self.skip_spaces()
        match = (self._NUMBER if signed else self._UNSIGNED).match(self.text, self.position)
        if not match:
            raise self.fail(f"expected {what}")
        digits = match.group().lstrip("+-").lstrip("0")
        # Digits counted before int(): a number of thousands of digits is refused, not parsed.
        if len(digits) > self._DIGITS or int(digits or 0) > MAX_FRAME_NUMBER:
            raise self.fail(f"{what} beyond ±{MAX_FRAME_NUMBER} (2^53, MAX_FRAME_NUMBER)", self.position,
                            found=False)
        self.position = match.end()
        return int(match.group())

    def parse(self) -> tuple[float, ...]:
        ranges: list[tuple[int, int, int, int]] = []  # (start, end, step, position) of each item
        total = 0
        while True:
            self.skip_spaces()
            item_start = self.position
            start = self.number("a frame number")
            end, step = start, 1
            expected = "',', '-' or the end"
            self.skip_spaces()
            if self.peek() == "-":
                expected = "',', 'x' or the end"
                self.position += 1
                end = self.number("the last frame of the range")
                self.skip_spaces()
                if self.peek() in ("x", "X"):
                    self.position += 1
                    step_position = self.position
                    step = self.number("a step", signed=False)
                    if step <= 0:
                        raise self.fail("the step must be at least 1", step_position)
                    expected = "',' or the end"
                    self.skip_spaces()
                if end < start:
                    raise self.fail(f"the range ends before it starts (write {end}-{start})", item_start,
                                    found=False)
            # Counted, not expanded: a range of 10^14 frames is refused here at once.
            total += (end - start) // step + 1
            if total > MAX_FRAMES:
                so_far = " up to here" if ranges else ""
                raise self.fail(f"{total} frames{so_far}, more than the {MAX_FRAMES} a job may have (MAX_FRAMES; "
                                "split the shot into several jobs)", item_start, found=False)
            ranges.append((start, end, step, item_start))
            if self.position == len(self.text):
                break
            if self.peek() != ",":
                raise self.fail(f"expected {expected}")
            self.position += 1
        frames: list[float] = []
        seen: set[int] = set()
        for start, end, step, item_start in ranges:
            for frame in range(start, end + 1, step):
                if frame in seen:
                    raise self.fail(f"frame {frame} is listed twice", item_start, found=False)
                seen.add(frame)
                frames.append(float(frame))
        return tuple(frames)


_SHOWN_TEXT = 60
"""Characters of a frame range text quoted in an error (the position says where the fault is)."""


def shortened(text: str) -> str:
    """``text`` quoted for an error message, cut to _SHOWN_TEXT characters."""
    return repr(text) if len(text) <= _SHOWN_TEXT else repr(text[:_SHOWN_TEXT]) + f"… ({len(text)} characters)"


_TEMPLATE_TOKEN = re.compile(r"\$\{(?P<braced>[A-Za-z_]+)(?P<braced_pad>\d*)\}|\$(?P<name>[A-Za-z_]+)(?P<pad>\d*)|#+")


def _frame_number(frame: float) -> int:
    if not float(frame).is_integer():
        raise JobError(f"frame {frame!r} is not a whole number: the output templates need one")
    return int(frame)


def expand_template(template: str, frame: float | None, job_name: str = "") -> str:
    """``template`` with ``$F`` / ``$F4`` / ``${F4}`` / ``####`` replaced by the frame number
    (padded to 4 / to the run's length) and ``$JOB`` by ``job_name``.

    ``frame`` None leaves the frame tokens as they are. Raises JobError for an unknown
    variable (check_template says which key at load time).
    """

    def replace(match: re.Match) -> str:
        token = match.group()
        if token.startswith("#"):
            return token if frame is None else f"{_frame_number(frame):0{len(token)}d}"
        name = match["braced"] or match["name"]
        pad = match["braced_pad"] if match["braced"] else match["pad"]
        if name == "F":
            if frame is None:
                return token
            return f"{_frame_number(frame):0{int(pad)}d}" if pad else str(_frame_number(frame))
        if name == "JOB":
            return job_name + pad
        raise JobError(f"unknown variable ${name} in {template!r} (known: $F, $F4 / ${{F4}}, ####, $JOB)")

    return _TEMPLATE_TOKEN.sub(replace, template)


def has_frame_token(template: str) -> bool:
    """Whether ``template`` changes with the frame ($F, $F4, ####)."""
    for match in _TEMPLATE_TOKEN.finditer(template):
        if match.group().startswith("#") or (match["braced"] or match["name"]) == "F":
            return True
    return False


def check_template(template: str, *, file: str | None, key: str | None, frame_tokens: bool = True) -> None:
    """Raise JobError (naming file and key) for an unknown variable, a ``$F0`` pad, or a frame
    token where the value cannot depend on the frame."""
    for match in _TEMPLATE_TOKEN.finditer(template):
        token = match.group()
        if token.startswith("#"):
            name, pad = "F", str(len(token))
        else:
            name = match["braced"] or match["name"]
            pad = match["braced_pad"] if match["braced"] else match["pad"]
        if name not in ("F", "JOB"):
            raise job_error(f"unknown variable ${name} in {template!r} (known: $F, $F4 / ${{F4}}, ####, $JOB)",
                         file, key, match.start())
        if name == "F" and not frame_tokens:
            raise job_error(f"{template!r} cannot depend on the frame ({token}): put the frame in output.stem",
                         file, key, match.start())
        if name == "F" and pad and not 1 <= int(pad) <= 9 and not token.startswith("#"):
            raise job_error(f"{token}: the padding must be 1..9 digits", file, key, match.start())
