"""What to render and how: one :class:`RenderRequest`, built by ``pxr-layers render``'s flags
and by a shot job's TOML alike, with its defaults here and nowhere else.

Plain data (no pxr, no numpy): it travels to Dask workers and into tests as it is.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

from .errors import RenderSettingsError
from .recipe.model import COVARIANCE_MODES, INDEX_MODES, MAX_INDEX_BOUNCES

DEFAULT_SPP = 64
DEFAULT_MAX_DEPTH = 8
DEFAULT_SEED = 0
DEFAULT_RESOLUTION = (512, 512)
"""(width, height) in pixels of a stage whose recipe (or lack of one) names no resolution."""
MAX_SPP = 1 << 16
"""Samples per pixel at most (65536: far past convergence; more is a typo)."""
MAX_PIXELS = 1 << 28
"""Pixels of one image at most (16384 × 16384): every per-pixel buffer must fit in memory."""
MAX_DEPTH = 1024
"""Scattering events per path at most (Russian roulette ends paths long before; more is a typo)."""
MAX_SEED = (1 << 64) - 1
"""The largest seed: seeds key 64-bit random streams, so a larger one would wrap silently."""
DEFAULT_SUBDIV_LEVEL = 2
"""Uniform refinement levels of subdivision surfaces: each level splits a quad in four, so
level 2 turns a cube into 96 quads; enough for a smooth silhouette at shot resolution of
the cages studios author, and cheap next to the render."""
MAX_SUBDIV_LEVEL = 6
"""Past this a level multiplies a production mesh's triangles by another 4x: a mistake, not a
look (a 100 k-face cage at 6 is 400 M quads)."""
MAX_REFINED_FACES = 1 << 16
"""The most faces a subdivision surface is refined to. Each level multiplies the faces by 4,
and a dense cage (a scan, a sculpt, the OpenChessSet's 20 k-face pieces) is already finer
than a pixel at shot resolution: refining it would multiply the render's triangles by 16 at
level 2 for no visible change. Such meshes get the levels that fit, or their cage."""



@dataclass(frozen=True)
class VariantSelection:
    """``PRIM:SET=VALUE``: select ``value`` in the variant set ``variant_set`` of ``prim``."""

    prim: str
    variant_set: str
    value: str

    _SYNTAX = re.compile(r"^(?P<prim>/[^:=]*):(?P<set>[^:=/]+)=(?P<value>[^=]*)$")

    @classmethod
    def parse(cls, text: str, *, where: str = "--variant") -> VariantSelection:
        """``"/World/Teapot:modelVariant=Fancy"`` → the selection; RenderSettingsError when
        it is not of that form (``where`` names the flag or job key in the message)."""
        match = cls._SYNTAX.match(text.strip())
        if match is None:
            raise RenderSettingsError(f"{where} {text!r}: expected PRIM:SET=VALUE, e.g. /World/Teapot:modelVariant=Fancy")
        return cls(match["prim"].rstrip("/") or "/", match["set"], match["value"])

    def __str__(self) -> str:
        return f"{self.prim}:{self.variant_set}={self.value}"


@dataclass(frozen=True)
class RenderRequest:
    """A shot render, before the stage is read.

    stage          : the USD file
    recipe_layers  : USD layers composed over it (the first strongest)
    variants       : variant selections authored over the composed stage
    settings       : the RenderSettings prim; None = the one rule of ``stage.find_settings``
    camera         : camera prim path overriding the recipe's; None = the recipe's, else the
                     stage's first camera, else an automatic one that frames the stage
    per_light      : "none" | "lights" | "groups" overriding each product's perLight; None = as authored
    resolution     : (width, height) pixels overriding the recipe's; None = the recipe's
    spp            : samples per pixel; max_depth : most scattering events per path
    seed           : the random seed (with the frame, pixel and sample, keys every stream)
    norm_bounces   : events per path whose covariance norms the index keeps; None = the
                     products' ``pxrLayers:index:bounces``, raised to ``max_depth`` when a
                     layer has a covariance condition (:meth:`resolved_norm_bounces`)
    index_mode     : "merged" | "records" overriding the products' ``pxrLayers:index:mode``
    index_covariance : "norms" | "sigma" overriding the products' ``pxrLayers:index:covariance``
    subdiv_level   : uniform refinement level of subdivision surfaces (0 = the cage)
    default_lights : a stage without any light gets the default rig (``/pxrLayers/defaultLights``)
    strict         : any composition error (missing or unreadable reference, payload,
                     sublayer) is fatal instead of a warning
    """

    stage: Path
    recipe_layers: tuple[Path, ...] = ()
    variants: tuple[VariantSelection, ...] = ()
    settings: str | None = None
    camera: str | None = None
    per_light: str | None = None
    resolution: tuple[int, int] | None = None
    spp: int = DEFAULT_SPP
    max_depth: int = DEFAULT_MAX_DEPTH
    seed: int = DEFAULT_SEED
    norm_bounces: int | None = None
    index_mode: str | None = None
    index_covariance: str | None = None
    subdiv_level: int = DEFAULT_SUBDIV_LEVEL
    default_lights: bool = True
    strict: bool = False

    def __post_init__(self) -> None:
        # Absolute: the paths end up in the files' metadata, which must not depend on the cwd.
        object.__setattr__(self, "stage", Path(os.path.abspath(self.stage)))
        object.__setattr__(self, "recipe_layers", tuple(Path(os.path.abspath(layer)) for layer in self.recipe_layers))
        object.__setattr__(self, "variants", tuple(self.variants))
        if self.resolution is not None:
            object.__setattr__(self, "resolution", (int(self.resolution[0]), int(self.resolution[1])))
        for name, low in (("spp", 1), ("max_depth", 0), ("seed", 0), ("norm_bounces", 0)):
            value = getattr(self, name)
            if value is None:
                continue
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise RenderSettingsError(f"{name} must be an integer >= {low}, not {value!r}")
        for name, allowed in (("index_mode", INDEX_MODES), ("index_covariance", COVARIANCE_MODES)):
            if getattr(self, name) not in (None, *allowed):
                raise RenderSettingsError(f"{name.replace('_', ' ')} must be one of {', '.join(allowed)}, "
                                          f"not {getattr(self, name)!r}")
        if not 0 <= self.subdiv_level <= MAX_SUBDIV_LEVEL:
            raise RenderSettingsError(f"subdiv level must be 0 to {MAX_SUBDIV_LEVEL}, not {self.subdiv_level}")
        if self.resolution is not None and min(self.resolution) <= 0:
            raise RenderSettingsError(f"resolution must be positive, not {self.resolution}")
        if self.max_depth > MAX_DEPTH:
            raise RenderSettingsError(f"max depth must be at most {MAX_DEPTH}, not {self.max_depth}")
        if self.norm_bounces is not None and self.norm_bounces > MAX_INDEX_BOUNCES:
            raise RenderSettingsError(f"norm bounces must be at most {MAX_INDEX_BOUNCES}, not {self.norm_bounces}")
        if self.seed > MAX_SEED:
            raise RenderSettingsError(f"seed must be at most 2^64 − 1, not {self.seed}")
        check_work(self.resolution, self.spp)

    def resolved_norm_bounces(self, product_bounces: int, has_conditions: bool) -> int:
        """The norm-bounce rule: the request's own number, else the products' index bounces
        raised to ``max_depth`` (at most MAX_INDEX_BOUNCES) when a layer has a covariance
        condition (a condition under ``.*`` may test any event of the path)."""
        if self.norm_bounces is not None:
            return self.norm_bounces
        return max(product_bounces, min(self.max_depth, MAX_INDEX_BOUNCES)) if has_conditions else product_bounces


def check_work(resolution: tuple[int, int] | None, spp: int) -> None:
    """Raise RenderSettingsError when a render would be beyond MAX_SPP samples per pixel or
    MAX_PIXELS pixels, before anything is allocated for it."""
    if spp > MAX_SPP:
        raise RenderSettingsError(f"{spp} samples per pixel is more than the {MAX_SPP} a render takes")
    if resolution is not None and resolution[0] * resolution[1] > MAX_PIXELS:
        raise RenderSettingsError(f"a {resolution[0]}×{resolution[1]} image is more than the {MAX_PIXELS} pixels "
                                  "(16384 × 16384) a render takes")
