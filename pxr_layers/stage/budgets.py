"""How big a scene may be: the budgets of a flattened scene, and the counter that keeps them.

The reader flattens a stage: every gprim, every native instance's gprims and every point
instance's copy becomes one scene.Mesh of world-space triangles. Memory and read time grow
with that flattened scene, not with the file: a .usdc of a few kilobytes can declare 1e8
faces (crate files compress runs of equal values) or a PointInstancer of 1e7 copies. The
budgets below bound both. A scene past one is a StageError naming the file, the prim that
crosses it, the count and the budget, raised as soon as the count is known (an array's
length, before it is triangulated, placed or even copied by numpy), within seconds and
without a large allocation: never a MemoryError, never an hour of work.

Textures have their own budgets (texture_files.MAX_TEXTURE_TEXELS, the tracer's
--texture-memory), and so do arrays (values.MAX_ARRAY_VALUES, derived from the triangles'). Subdivision surfaces are not refused
but fitted: their levels are lowered until they fit request.MAX_SUBDIVISION_TRIANGLES
(:func:`fit_subdivision_levels`).
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from typing import TypeVar

from pxr_layers.errors import StageError
from pxr_layers.request import MAX_SUBDIVISION_TRIANGLES

MAX_SCENE_TRIANGLES = 1 << 24
"""The most triangles a flattened scene may hold (16,777,216): every mesh, subdivision surfaces
as refined, every instance's copy counted. A render's peak memory grows by about 500 bytes a
triangle (the stage's world-space copies, the tracer's tables, Embree's BVH; measured: a
2 M-triangle grid peaks 0.95 GB above an empty render), so some 8 GiB at the budget. Seven
times the OpenChessSet (2.5 M triangles as read), 150 times the Standard Shader Ball."""

MAX_SCENE_MESHES = 1 << 18
"""The most meshes a flattened scene may hold (262,144): each gprim, each native instance's
gprims and each point instance's copy of a prototype gprim is one. Each costs its own read,
placement and bookkeeping, about a third of a millisecond: a minute and a half at the budget."""


class SceneBudget:
    """What one stage read has taken of the budgets so far."""

    def __init__(self) -> None:
        self.meshes = 0
        self.triangles = 0

    def check_meshes(self, count: int, why: str, *, file: str | None, prim: str) -> None:
        """StageError when ``count`` more meshes for ``prim`` (``why``: what makes them,
        "protoIndices lists 10,000,000 instances") would take the scene past
        MAX_SCENE_MESHES; nothing is counted."""
        if self.meshes + count > MAX_SCENE_MESHES:
            before = f" after the {self.meshes:,} before it" if self.meshes else ""
            raise StageError(f"{why}{before}: more than the {MAX_SCENE_MESHES:,} meshes a scene may hold (every "
                             "gprim and every point instance's copy of one is a mesh)", file=file, prim=prim)

    def take_meshes(self, count: int, why: str, *, file: str | None, prim: str) -> None:
        """:meth:`check_meshes`, then count them."""
        self.check_meshes(count, why, file=file, prim=prim)
        self.meshes += count

    def check_triangles(self, count: int, why: str, *, file: str | None, prim: str) -> None:
        """StageError when ``count`` more triangles (``why``: "faceVertexCounts declares 100,000,000
        faces") would take the scene past MAX_SCENE_TRIANGLES; nothing is counted."""
        if self.triangles + count > MAX_SCENE_TRIANGLES:
            before = f" after the {self.triangles:,} before it" if self.triangles else ""
            raise StageError(f"{why}{before}: more than the {MAX_SCENE_TRIANGLES:,} triangles a scene may hold",
                             file=file, prim=prim)

    def take_triangles(self, count: int, why: str, *, file: str | None, prim: str) -> None:
        """:meth:`check_triangles`, then count them."""
        self.check_triangles(count, why, file=file, prim=prim)
        self.triangles += count


Surface = TypeVar("Surface", bound=Hashable)


def fit_subdivision_levels(
    wanted: Mapping[Surface, int], triangles: Mapping[Surface, Sequence[int]],
    budget: int = MAX_SUBDIVISION_TRIANGLES,
) -> dict[Surface, int]:
    """The levels of ``wanted`` lowered, the highest first, until the surfaces' triangles fit
    ``budget``. At one level the surfaces with the most triangles are lowered first (the
    densest cages, which lose least); none goes below 0, so cages alone past the budget stay
    as they are (MAX_SCENE_TRIANGLES still bounds them).

    wanted    : surface → level
    triangles : surface → triangles of all its placed copies at each level 0, 1, ... (at
                least up to its wanted level)
    """
    levels = dict(wanted)
    total = sum(triangles[surface][level] for surface, level in levels.items())
    for level in range(max(levels.values(), default=0), 0, -1):
        if total <= budget:
            break
        at_level = sorted((surface for surface, chosen in levels.items() if chosen == level),
                          key=lambda surface: triangles[surface][level], reverse=True)
        for surface in at_level:
            if total <= budget:
                break
            total -= triangles[surface][level] - triangles[surface][level - 1]
            levels[surface] = level - 1
    return levels
