"""Divergence and validity guard shared by every method: no silent garbage.

A reachable-set estimate whose sets or samples are non-finite, or reach further from the origin
than ``divergence_factor`` times the problem's scale, is garbage: the run stops with a
:class:`~ocreach.errors.SolverError` naming the method, the time and the size, and carries the
part computed before it as ``err.partial`` (a ``ReachResult`` with ``meta["truncated"] = True``).

* Scale of a problem: ``max(1, ||x0||_inf, ||initial set||_inf)`` (models are non-dimensional,
  so 1 is the natural unit); size of a set or sample cloud at a time: its ``||.||_inf`` bound
  (largest ``|x_i|`` over the interval hull, or over the samples).
* ``divergence_factor`` (default :data:`DIVERGENCE_FACTOR` = 100): a common option of every
  method (``--set divergence_factor=1e4`` raises it; ``inf`` switches the size check off; the
  finiteness check always runs).

Every method's ``solve`` is checked on return (:meth:`ocreach.reach.base.Method` wraps it);
a method with an explicit step loop (``stt``) also calls :func:`check_step` after each step so a
diverging run stops early.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.errors import SolverError
from ocreach.reach.result import ReachResult

if TYPE_CHECKING:
    from ocreach.problem import Problem

#: Default bound on ``||x||_inf`` of a result, in units of the problem's scale.
DIVERGENCE_FACTOR = 100.0


def problem_scale(problem: Problem) -> float:
    """``max(1, ||x0||_inf, ||initial set||_inf)``."""
    scale = max(1.0, float(np.max(np.abs(problem.x0))))
    if problem.initial_set is not None and hasattr(problem.initial_set, "interval_hull"):
        h = problem.initial_set.interval_hull()
        scale = max(scale, float(np.max(np.abs(np.concatenate([h.lo, h.hi])))))
    if problem.stochastic is not None:
        st = problem.stochastic
        scale = max(scale, float(np.max(np.abs(st.x0_mean) + 3 * np.sqrt(np.diag(st.x0_cov)))))
    return scale


def set_extent(s: Any) -> float:
    """``||.||_inf`` bound of one set (inf if it cannot be bounded or is not finite)."""
    try:
        h = s.interval_hull()
        val = float(np.max(np.abs(np.concatenate([np.asarray(h.lo), np.asarray(h.hi)]))))
    except (ArithmeticError, ValueError, AttributeError, np.linalg.LinAlgError):
        return float("inf")
    return val if np.isfinite(val) else float("inf")


def extents(seq: Sequence[Any] | None, points: bool = False) -> np.ndarray:
    """Per-time size of a list of sets, of point clouds (``points=True``) or of a lazy ellipsoid
    sequence with ``mean``/``cov``/``s2`` (checked from its arrays, without building the sets)."""
    if seq is None:
        return np.zeros(0)
    if points:
        out = np.array([float(np.max(np.abs(p))) if np.size(p) else 0.0 for p in seq])
        return np.where(np.isfinite(out), out, np.inf)
    if all(hasattr(seq, a) for a in ("mean", "cov", "s2")):
        m, c = np.asarray(seq.mean), np.asarray(seq.cov)
        sd = np.sqrt(np.abs(seq.s2 * np.diagonal(c, axis1=-2, axis2=-1)))
        out = np.max(np.abs(m) + sd, axis=-1)
        return np.where(np.isfinite(out), out, np.inf)
    return np.array([set_extent(s) for s in seq])


def _first_bad(sizes: np.ndarray, bound: float) -> int | None:
    bad = np.flatnonzero(~(sizes <= bound))
    return int(bad[0]) if bad.size else None


def _message(method: str, problem: Problem, t: float, size: float, bound: float,
             factor: float, kept: int) -> str:
    what = ("is not finite (NaN or inf)" if not np.isfinite(size) else
            f"has grown to {size:.3g} (||x||_inf), beyond the bound {bound:.3g} = "
            f"divergence_factor {factor:g} x problem scale {bound / factor:.3g}")
    return (f"method {method!r} diverged on {problem.id!r}: the estimate at t = {t:g} {what}; "
            f"the {kept} time(s) before it are kept as a truncated partial result. Use a smaller "
            f"step or horizon, another method, or --set divergence_factor=... to accept larger sets")


def check_result(result: ReachResult, problem: Problem, factor: float = DIVERGENCE_FACTOR) -> ReachResult:
    """``result`` unchanged if every set / sample is finite and within the bound, else a
    :class:`SolverError` with the valid prefix as ``partial``."""
    bound = float(factor) * problem_scale(problem)
    sizes = extents(result.sets) if result.sets is not None else extents(result.points, points=True)
    k = _first_bad(sizes, bound)
    if result.tubes is not None:  # tube k covers [t_k, t_{k+1}]: bad tube k invalidates time k+1
        kt = _first_bad(extents(result.tubes), bound)
        if kt is not None and (k is None or kt + 1 < k):
            k, sizes = kt + 1, np.append(sizes[: kt + 1], extents(result.tubes)[kt])
    if k is None:
        return result
    msg = _message(result.method, problem, float(result.times[k]), float(sizes[k]), bound, factor, k)
    partial = result.truncated(k, msg) if k >= 1 else None
    raise SolverError(msg, partial=partial)


def check_step(method: Any, problem: Problem, sets: list[Any], tubes: list[Any] | None = None) -> None:
    """Per-step check of a set-propagating method (call after appending ``sets[-1]``): raises the
    :class:`SolverError` of :func:`check_result` with ``sets[:-1]`` as the partial result."""
    from ocreach.interrupt import check_interrupt

    check_interrupt()
    factor = getattr(method, "divergence_factor", DIVERGENCE_FACTOR)
    bound = float(factor) * problem_scale(problem)
    size = set_extent(sets[-1])
    if size <= bound:
        return
    k = len(sets) - 1
    msg = _message(method.name, problem, float(problem.grid[k]), size, bound, factor, k)
    partial = None
    if k >= 1:
        meta = {**method.base_meta(problem, {}), "truncated": True, "truncated_reason": msg}
        partial = ReachResult(times=problem.grid[:k], sets=list(sets[:k]), meta=meta,
                              tubes=None if not tubes else list(tubes[: k - 1]))
    raise SolverError(msg, partial=partial)
