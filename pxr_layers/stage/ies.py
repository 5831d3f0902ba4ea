"""IES LM-63 photometric files (LM-63-1986, -1991, -1995, -2002, -2019) → scene.IesProfile.

A file is keyword lines up to ``TILT=``, then numbers separated by whitespace or commas,
spanning lines freely: #lamps, lumens per lamp, candela multiplier, #vertical angles,
#horizontal angles, photometric type, units, width, length, height; ballast factor, future
use (the ballast-lamp photometric factor before 1995), input watts; the vertical angles;
the horizontal angles; the candela values, one row of vertical values per horizontal angle.

* ``TILT=NONE``: no tilt. ``TILT=INCLUDE``: its tilt block (lamp-to-luminaire geometry, the
  number of tilt angles N, N angles, N factors) is skipped. ``TILT=<file>``: the tilt is not
  applied and :func:`parse_ies` says so in its notes for the caller to warn. A tilt varies the
  output with the lamp's inclination in the luminaire, which a render does not model.
* Candela values are multiplied by the candela multiplier and the ballast factor. The third
  factor (future use, or the old ballast-lamp factor) is left out, as hdEmbree's pxrIES and
  Cycles' reader (which it builds on) leave it out.
* Photometric type C only (1); types A and B (3 and 2) are errors.
* Horizontal angles are unfolded to cover [0°, 360°] inclusive, by LM-63's symmetries: one
  angle: rotationally symmetric; 0–90: quadrant symmetric (mirrored about the 90° plane, then
  about the 180° plane); 0–180: bilateral (mirrored about the 180° plane); 0–360 as is (its
  360° plane as given: LM-63 makes it the 0° plane again); 90–270: that half, mirrored about
  the 90°–270° plane. Any other range is an error.
* Vertical angles (0° = nadir, the light's −Z axis) are kept as given, ascending within
  [0°, 180°]: a file may cover 0–90, 90–180 or 0–180, and its intensity is 0 outside them.
* ``power`` is hdEmbree's ``shaping:ies:normalize`` divisor (pxrIES.cpp, "matches Karma and
  RIS"): Σ over patches of the unfolded grid of the patch centre's bilinear intensity ×
  dφ × dθ × sin(θ + dθ/2), divided by 4π, or by 2π when the vertical angles span no more than
  π/2 + 0.1 rad (a hemisphere, with hdEmbree's slack).

Malformed files raise StageError naming the file and what is wrong (the line of a bad
number, NaN and infinities included, or how many numbers the header's counts need against
how many there are). How bright a profile may make its light is the light's rule
(lights.py: its peak intensity counts in the light's brightest radiance).
"""

from __future__ import annotations

import math
import re

import numpy as np
from pxr import Ar

from pxr_layers.errors import StageError
from pxr_layers.scene import IesProfile

from .textures import on_disk

# hdEmbree's slack (rad) above π/2 for a vertical span that still counts as a hemisphere.
_HEMISPHERE_SLACK = 0.1
_PHOTOMETRIC_TYPES = {1: "C", 2: "B", 3: "A"}
_TILT = re.compile(r"\s*TILT\s*=\s*(.*?)\s*$", re.IGNORECASE)
_SEPARATORS = re.compile(r"[\s,]+")


def read_ies(resolved_path: str) -> tuple[IesProfile, tuple[str, ...]]:
    """Read and parse the IES file at a resolved asset path (a file, a package member, any
    path USD's asset resolver resolved): :func:`parse_ies` of its text."""
    try:
        if on_disk(resolved_path, "IES profile"):
            with open(resolved_path, "rb") as file:
                contents = file.read()
        else:
            asset = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved_path))
            if not asset:
                raise OSError("USD's asset resolver cannot open it")
            with asset:
                contents = bytes(asset.GetBuffer())
    except OSError as error:
        raise StageError(f"cannot read the IES profile: {error}", file=resolved_path) from None
    # LM-63 text is ASCII; keyword lines in the wild carry Latin-1 (°, ©), which never fails.
    return parse_ies(contents.decode("latin-1"), resolved_path)


def parse_ies(text: str, path: str) -> tuple[IesProfile, tuple[str, ...]]:
    """The profile of an LM-63 file's ``text`` (``path`` names it in errors and the profile),
    and notes: one line each for what the file asks that is not applied (a TILT file)."""
    lines = text.splitlines()
    tilt_line = next((index for index, line in enumerate(lines) if _TILT.match(line)), None)
    if tilt_line is None:
        raise StageError("no TILT= line: not an IES LM-63 photometric file", file=path)
    numbers = _Numbers(lines, tilt_line + 1, path)
    tilt = _TILT.match(lines[tilt_line]).group(1)
    notes: list[str] = []
    if tilt.upper() == "INCLUDE":
        numbers.take(1, "TILT=INCLUDE block")  # lamp-to-luminaire geometry
        count = numbers.count("number of tilt angles", minimum=0)
        numbers.take(2 * count, "TILT=INCLUDE block")  # its angles, then its factors
    elif not tilt:
        raise StageError(f"line {tilt_line + 1}: TILT= names no tilt (NONE, INCLUDE or a file)", file=path)
    elif tilt.upper() != "NONE":
        notes.append(f"its tilt file {tilt} is not applied (the profile is used as if untilted)")

    numbers.take(2, "header")  # number of lamps, lumens per lamp
    multiplier = float(numbers.take(1, "header")[0])
    vertical_count = numbers.count("number of vertical angles")
    horizontal_count = numbers.count("number of horizontal angles")
    photometric_type = numbers.count("photometric type")
    if photometric_type != 1:
        kind = _PHOTOMETRIC_TYPES.get(photometric_type)
        what = f"{kind} ({photometric_type})" if kind else f"{photometric_type}, not 1, 2 or 3"
        raise StageError(f"photometric type {what}: only type C (1) is supported", file=path)
    numbers.take(4, "header")  # units, width, length, height
    ballast = float(numbers.take(1, "header")[0])
    numbers.take(2, "header")  # future use (ballast-lamp factor before 1995), input watts
    vertical = numbers.take(vertical_count, "vertical angles")
    horizontal = numbers.take(horizontal_count, "horizontal angles")
    candela = numbers.take(vertical_count * horizontal_count, "candela values")
    numbers.finish(vertical_count, horizontal_count)

    _check_angles(vertical, 180.0, "vertical", path)
    _check_angles(horizontal, 360.0, "horizontal", path)
    if vertical_count < 2:
        raise StageError("one vertical angle describes no distribution (at least 2 are needed)", file=path)
    factor = multiplier * ballast
    if factor < 0.0 or (candela < 0.0).any():
        raise StageError(f"negative candela values (multiplier {multiplier} × ballast factor {ballast})",
                         file=path)
    with np.errstate(over="ignore"):
        scaled = candela.reshape(horizontal_count, vertical_count) * factor
    if not np.isfinite(scaled).all():
        raise StageError(f"candela values × multiplier {multiplier:g} × ballast factor {ballast:g} overflow: "
                         f"the largest is {float(candela.max()):g}", file=path)
    horizontal, candela = _unfold(horizontal, scaled, path)
    vertical, horizontal = np.radians(vertical), np.radians(horizontal)
    return IesProfile(path=path, vertical=vertical, horizontal=horizontal, candela=candela,
                      power=_power(vertical, horizontal, candela)), tuple(notes)


class _Numbers:
    """The numbers after the TILT= line, taken in order, with the line each came from."""

    def __init__(self, lines: list[str], first_line: int, path: str) -> None:
        self._path = path
        values, line_numbers = [], []
        for line_number, line in enumerate(lines[first_line:], start=first_line + 1):
            for token in _SEPARATORS.split(line.strip()):
                if not token:
                    continue
                try:
                    value = float(token)
                except ValueError:
                    raise StageError(f"line {line_number}: {token!r} is not a number", file=path) from None
                if not math.isfinite(value):  # "nan", "inf", "1e999": no angle, count or intensity is
                    raise StageError(f"line {line_number}: {token!r} is not a finite number", file=path)
                values.append(value)
                line_numbers.append(line_number)
        self._values = np.array(values, dtype=np.float64)
        self._lines = line_numbers
        self._next = 0

    def take(self, count: int, what: str) -> np.ndarray:
        """The next ``count`` numbers, part of the file's ``what``."""
        left = len(self._values) - self._next
        if count > left:
            raise StageError(f"the file ends in its {what}: {left} of {count} numbers", file=self._path)
        taken = self._values[self._next:self._next + count]
        self._next += count
        return taken

    def count(self, what: str, minimum: int = 1) -> int:
        """The next number, which must be a whole number ≥ ``minimum``."""
        value = float(self.take(1, what)[0])
        if value != math.floor(value) or value < minimum:
            line = self._lines[self._next - 1]
            raise StageError(f"line {line}: the {what} must be a whole number ≥ {minimum}, not {value:g}",
                             file=self._path)
        return int(value)

    def finish(self, vertical_count: int, horizontal_count: int) -> None:
        """Fail if numbers are left: the header's counts do not match the data."""
        extra = len(self._values) - self._next
        if extra:
            raise StageError(
                f"{extra} numbers after the {horizontal_count} × {vertical_count} candela values "
                f"(from line {self._lines[self._next]}): the header's angle counts do not match the data",
                file=self._path,
            )


def _check_angles(angles: np.ndarray, largest: float, which: str, path: str) -> None:
    if (np.diff(angles) <= 0.0).any() or angles[0] < 0.0 or angles[-1] > largest:
        raise StageError(f"the {which} angles must ascend within 0–{largest:g}°, not "
                         f"{angles[0]:g}…{angles[-1]:g}°", file=path)


def _unfold(horizontal: np.ndarray, candela: np.ndarray, path: str) -> tuple[np.ndarray, np.ndarray]:
    """(H,) degrees and (H, V) candela of a file → the same over [0°, 360°] inclusive."""
    first, last = horizontal[0], horizontal[-1]
    if len(horizontal) == 1:  # rotationally symmetric
        return np.array([0.0, 360.0]), np.repeat(candela, 2, axis=0)
    if first == 0.0 and last in (90.0, 180.0, 360.0):
        # Mirror about the last plane until the circle is closed: 90 → 180 → 360, 180 → 360.
        while horizontal[-1] < 360.0:
            horizontal = np.concatenate([horizontal, 2.0 * horizontal[-1] - horizontal[-2::-1]])
            candela = np.concatenate([candela, candela[-2::-1]])
        return horizontal, candela
    if first == 90.0 and last == 270.0:
        # Symmetric about the 90°–270° plane: φ and 180° − φ look alike. The images of the
        # given half fill the other one; 90° and 270° are their own images.
        images = np.mod(180.0 - horizontal, 360.0)
        other = (images < 90.0) | (images > 270.0)
        horizontal = np.concatenate([horizontal, images[other]])
        candela = np.concatenate([candela, candela[other]])
        order = np.argsort(horizontal)
        horizontal, candela = horizontal[order], candela[order]
        if horizontal[0] > 0.0:  # no 180° sample to mirror onto 0°: interpolate across the seam
            below = horizontal[-1] - 360.0
            weight = -below / (horizontal[0] - below)
            horizontal = np.concatenate([[0.0], horizontal])
            candela = np.concatenate([[(1.0 - weight) * candela[-1] + weight * candela[0]], candela])
        return np.concatenate([horizontal, [360.0]]), np.concatenate([candela, candela[:1]])
    raise StageError(
        f"horizontal angles {first:g}…{last:g}° match no LM-63 type C layout (one angle, 0–90, "
        "0–180, 0–360 or 90–270)",
        file=path,
    )


def _power(vertical: np.ndarray, horizontal: np.ndarray, candela: np.ndarray) -> float:
    """hdEmbree's profile power (see the module docstring); angles in radians, (H, V) candela."""
    d_vertical = np.diff(vertical)
    centre = (candela[:-1, :-1] + candela[:-1, 1:] + candela[1:, :-1] + candela[1:, 1:]) / 4.0
    solid_angles = np.diff(horizontal)[:, None] * (d_vertical * np.sin(vertical[:-1] + d_vertical / 2.0))
    is_sphere = vertical[-1] - vertical[0] > math.pi / 2.0 + _HEMISPHERE_SLACK
    return float((centre * solid_angles).sum() / (math.pi * (4.0 if is_sphere else 2.0)))
