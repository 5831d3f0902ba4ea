"""State shared by every part of one ``load_stage`` call."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from pxr import Usd, UsdGeom

from pxr_layers.scene import DEFAULT_INCLUDED_PURPOSES

from .budgets import SceneBudget
from .diagnostics import Diagnostics

if TYPE_CHECKING:
    from .motion import Shutter


@dataclass
class ReadContext:
    """One stage read at one time code.

    xform_cache       : world transforms at ``time``; shared so each ancestor is composed once
    file              : the path given to load_stage, for error messages
    rendered_purposes : gprim purposes that render (RenderSettings includedPurposes)
    budget            : what the read has taken of the scene's budgets (budgets.py)
    shutter           : the render camera's shutter when things may move over it (motion.py);
                        None: everything is read at ``time`` alone
    """

    stage: Usd.Stage
    time: Usd.TimeCode
    meters_per_unit: float
    up_axis: str
    xform_cache: UsdGeom.XformCache
    diagnostics: Diagnostics
    file: str
    rendered_purposes: tuple[str, ...] = DEFAULT_INCLUDED_PURPOSES
    budget: SceneBudget = field(default_factory=SceneBudget)
    shutter: Shutter | None = None
