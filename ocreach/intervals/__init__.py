"""Sound interval evaluation of CasADi SX Functions over many boxes at once.

The bound every guaranteed method needs: the Lagrange remainder of ``taylor`` (Patel & Subbarao
Eq. 13-15), ``R_err`` of ``sdc`` (Eq. 25), the window error of the ephemeris tubes.

* :mod:`~ocreach.intervals.ops` -- the outward-rounded operations: rounding helpers and mode,
  one kernel per CasADi op code, the stacked kernels, the op tables, :data:`SUPPORTED_OPS`,
  :data:`LIBM_REL` / :data:`LIBM_ABS`;
* :mod:`~ocreach.intervals.walker` -- the graph walker: a Function as a single-assignment
  :class:`~ocreach.intervals.walker.Schedule` of operation groups (:func:`~ocreach.intervals.walker.walk`);
* :mod:`~ocreach.intervals.evaluator` -- the vectorised evaluator of a schedule
  (:class:`IntervalFunction`, :func:`interval_function`, :func:`bound`, :func:`split_boxes`,
  :class:`ModelIntervals`, :func:`for_model`, :class:`IntervalDomainError`);
* :mod:`~ocreach.intervals.kernel` -- the same schedule in a small compiled C interpreter, for
  the few boxes of one reachability step.

Imports run one way: ``walker -> ops``, ``kernel -> walker, ops``, ``evaluator -> walker, ops,
kernel``.  The soundness argument and its measurements: ``docs/intervals.md``.  May import: the
helpers and :mod:`ocreach.native` (the compiler).
"""
from ocreach.intervals.evaluator import (
    Box,
    IntervalDomainError,
    IntervalFunction,
    ModelIntervals,
    bound,
    for_model,
    interval_function,
    split_boxes,
)
from ocreach.intervals.ops import LIBM_ABS, LIBM_REL, SUPPORTED_OPS
from ocreach.intervals.walker import Schedule, walk

__all__ = ["LIBM_ABS", "LIBM_REL", "SUPPORTED_OPS", "Box", "IntervalDomainError",
           "IntervalFunction", "ModelIntervals", "Schedule", "bound", "for_model",
           "interval_function", "split_boxes", "walk"]
