"""Sound interval evaluation of CasADi SX Functions over many boxes at once.

The bound every guaranteed method needs: the Lagrange remainder of ``taylor`` (Patel & Subbarao
Eq. 13-15), ``R_err`` of ``sdc`` (Eq. 25), the window error of the ephemeris tubes.

* :mod:`~ocreach.intervals.evaluator` -- the graph walker, the outward-rounded operations and
  the vectorised evaluator (:class:`IntervalFunction`, :func:`interval_function`,
  :func:`for_model`);
* :mod:`~ocreach.intervals.kernel` -- the same schedule in a small compiled C interpreter, for
  the few boxes of one reachability step.

The soundness argument and its measurements: ``docs/intervals.md``.  May import: the helpers
and :mod:`ocreach.native` (the compiler).
"""
from ocreach.intervals.evaluator import (
    LIBM_ABS,
    LIBM_REL,
    SUPPORTED_OPS,
    Box,
    IntervalDomainError,
    IntervalFunction,
    ModelIntervals,
    bound,
    for_model,
    interval_function,
    split_boxes,
)

__all__ = ["LIBM_ABS", "LIBM_REL", "SUPPORTED_OPS", "Box", "IntervalDomainError",
           "IntervalFunction", "ModelIntervals", "bound", "for_model", "interval_function",
           "split_boxes"]
