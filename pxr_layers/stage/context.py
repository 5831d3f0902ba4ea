"""State shared by every part of one ``load_stage`` call."""

from __future__ import annotations

from dataclasses import dataclass, field

from pxr import Usd, UsdGeom

from pxr_layers.scene import DEFAULT_INCLUDED_PURPOSES

from .budgets import SceneBudget
from .diagnostics import Diagnostics


@dataclass
class ReadContext:
    """One stage read at one time code.

    xform_cache       : world transforms at ``time``; shared so each ancestor is composed once
    file              : the path given to load_stage, for error messages
    rendered_purposes : gprim purposes that render (RenderSettings includedPurposes)
    budget            : what the read has taken of the scene's budgets (budgets.py)
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
