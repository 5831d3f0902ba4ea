"""What the integrator hands each stage's results to.

The integrator calls every observer of a batch after each stage (``escaped``, ``emitted``,
``lit``, ``scattered``): the batch's film (film.py), the path recorder and the first-bounce
covariance pictures (recorder.py). An observer that is not there costs nothing, and the
integrator has no branch on what is recorded.
"""

from __future__ import annotations

from .queues import PathQueue, ShadowQueue, Splats, SurfaceQueue
from .scatter import Scattering


class Observer:
    """Does nothing with any stage's results; subclasses pick what they watch."""

    def wants_norms(self, step: int) -> bool:
        """Whether the surfaces of bounce `step` need their covariance norms C and T."""
        return False

    def escaped(self, queue: PathQueue, splats: Splats) -> None:
        pass

    def emitted(self, queue: PathQueue, splats: Splats) -> None:
        pass

    def lit(self, queue: PathQueue, surfaces: SurfaceQueue, shadows: ShadowQueue) -> None:
        """Light samples, with their visibility (called before ``scattered`` at the same vertex)."""

    def scattered(self, queue: PathQueue, surfaces: SurfaceQueue, scattering: Scattering, step: int) -> None:
        pass
