"""Deliberately broken copies of guaranteed methods, to show that the harness catches them.

:func:`scaled_remainder_taylor` is ``taylor`` with its Lagrange remainder bound
(:meth:`ocreach.reach.taylor.TaylorError.bound`, the box enclosing ``f - f0 - A (x - x*) -
B (v - v*)`` over the tube) multiplied by ``factor``: with ``factor < 1`` the sets are too small
and trajectories escape them.  The copy is a subclass: the real ``taylor`` is untouched, and the
copy is not in the method registry unless a test puts it there.
"""
from __future__ import annotations

from ocreach.reach.result import ReachResult
from ocreach.reach.taylor import TaylorZonotope, ZonotopeReach, check_smooth
from ocreach.reach.taylor_step import TaylorError
from ocreach.sets.zonotope import Zonotope


def scaled_remainder_taylor(factor: float) -> type[TaylorZonotope]:
    """A ``taylor`` whose remainder bound is ``factor`` times the sound one (``alg="ct"``)."""

    class ScaledRemainder(TaylorError):
        def bound(self, *args, **kwargs) -> Zonotope:
            Z = super().bound(*args, **kwargs)
            return Zonotope(factor * Z.c, factor * Z.G)

    class ScaledRemainderTaylor(TaylorZonotope):
        name = f"taylor-remainder-x{factor:g}"
        description = f"taylor with its remainder bound scaled by {factor:g} (a broken copy)"

        def solve(self, problem) -> ReachResult:
            check_smooth(problem.model)
            return ZonotopeReach(self, problem, self.options,
                                 lambda prob: ScaledRemainder(prob.model, prob.params),
                                 {"alg": "ct"}).run()

    return ScaledRemainderTaylor
