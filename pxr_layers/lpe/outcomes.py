"""What an expression says about one path class: never, always, or depending on covariance.

A path class is a distinct event sequence of the index; the automaton matches it once.
When the expression carries covariance conditions, the answer for the records of the class
is a Boolean function of a few "atoms" (condition c holds at event k); :class:`Conditional`
keeps that function as a truth table and evaluates it over many records at once.

Event indices count from the camera event: index 0 is the camera (no covariance), index
k >= 1 reads row k - 1 of the index's per-record arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import LpeError
from . import conditions as cond


class Outcome:
    """Base of the three outcomes. ``kind`` is 'never', 'always' or 'conditional'."""

    kind: str = ""
    bounces: tuple[int, ...] = ()
    """Event indices whose covariance decides the match (empty unless conditional)."""

    def mask(self, norms: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        """Which records of the class match.

        norms : (r, N, 3) float32, |S_C| (1/m), |S_T| (cycles/m), |S_R| (cycles/rad) of events 1..N
        sigma : (r, N, 10) float32 upper triangle of Σ per event (xx xy xu xv yy yu yv uu uv vv), or None
        returns : (r,) bool
        """
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"<{self.kind}>"


class Never(Outcome):
    kind = "never"

    def mask(self, norms, sigma=None):
        return np.zeros(len(norms), dtype=bool)


class Always(Outcome):
    kind = "always"

    def mask(self, norms, sigma=None):
        return np.ones(len(norms), dtype=bool)


NEVER = Never()
ALWAYS = Always()


@dataclass(frozen=True, eq=False)
class Conditional(Outcome):
    """The class matches for the records whose covariance passes a Boolean function of atoms.

    atoms : ((event index, condition), ...), one per input of the truth table
    table : (2**len(atoms),) bool; entry ``sum(atom_j << j)`` is the answer for that
        combination of atom values
    layer, events : for error messages (which layer, which path class)
    """

    atoms: tuple[tuple[int, cond.Condition], ...]
    table: np.ndarray
    layer: str = ""
    events: tuple = ()

    kind = "conditional"

    @property
    def bounces(self) -> tuple[int, ...]:
        return tuple(sorted({index for index, _ in self.atoms}))

    def __repr__(self) -> str:
        atoms = ", ".join(f"{cond.canonical(condition)} at event {index}" for index, condition in self.atoms)
        return f"<conditional on {atoms}>"

    def mask(self, norms: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        norms, sigma = checked_arrays(norms, sigma)
        kept = norms.shape[1]
        code = np.zeros(len(norms), dtype=np.int64)
        for bit, (index, condition) in enumerate(self.atoms):
            check_available(self.layer, self.events, index, condition, kept, sigma is not None)
            row = index - 1
            values = cond.evaluate(condition, norms[:, row], None if sigma is None else sigma[:, row])
            code |= values.astype(np.int64) << bit
        return self.table[code]


def checked_arrays(norms: np.ndarray, sigma: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """``norms`` and ``sigma`` as arrays, LpeError unless they have the shapes mask() takes."""
    norms = np.asarray(norms)
    if norms.ndim != 3 or norms.shape[2] != 3:
        raise LpeError(f"norms must be (records, events, 3) (C, T, R per event), got shape {norms.shape}")
    if sigma is not None:
        sigma = np.asarray(sigma)
        if sigma.shape != (*norms.shape[:2], cond.SIGMA_ENTRY_COUNT):
            raise LpeError(f"sigma must be (records, events, 10) like norms {norms.shape[:2]}, got {sigma.shape}")
    return norms, sigma


def check_available(layer: str, events: tuple, index: int, condition: cond.Condition, kept: int,
                    has_sigma: bool) -> None:
    """LpeError unless the per-record arrays hold what ``condition`` at event ``index`` reads."""
    where = f"layer {layer!r}: " if layer else ""
    event = f" ({events[index]})" if index < len(events) else ""
    if index == 0:
        raise LpeError(f"{where}{cond.canonical(condition)} is on the camera event, which has no covariance")
    if index > kept:
        raise LpeError(
            f"{where}{cond.canonical(condition)} tests event {index}{event} of the path, but the index "
            f"keeps covariance norms for events 1..{kept} only"
        )
    if cond.reads_sigma(condition) and not has_sigma:
        raise LpeError(
            f"{where}{cond.canonical(condition)} at event {index}{event} reads entries of Σ, but the index "
            "keeps only the norms: render it with `--index-covariance sigma` (or pxrLayers:index:covariance = "
            "\"sigma\")"
        )


def reduce_table(atoms: list, table: np.ndarray) -> tuple[list, np.ndarray]:
    """Drop the atoms a truth table does not depend on.

    atoms : A atoms; table : (2**A,) bool. Returns the kept atoms and their (2**A',) table.
    """
    codes = np.arange(table.size)
    for bit in reversed(range(len(atoms))):
        flipped = table[codes ^ (1 << bit)]
        if np.array_equal(flipped, table):
            # Keep the half where this atom is false, then close the gap its bit leaves.
            keep = (codes >> bit) & 1 == 0
            table = table[keep]
            atoms = atoms[:bit] + atoms[bit + 1 :]
            codes = np.arange(table.size)
    return atoms, table
