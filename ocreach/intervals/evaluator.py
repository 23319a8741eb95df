"""Sound interval evaluation of CasADi SX Functions, vectorised over many boxes.

:class:`IntervalFunction` runs the :class:`~ocreach.intervals.walker.Schedule` of a Function
(:func:`~ocreach.intervals.walker.walk`: single-assignment values, groups of like operations)
with the outward-rounded kernels of :mod:`ocreach.intervals.ops`, every group as one numpy
operation on arrays of shape ``(n_values, B)``: ``B`` boxes at once, in chunks that keep the
temporaries in cache; with ``native=True`` the compiled interpreter of
:mod:`ocreach.intervals.kernel` runs the same schedule for the few boxes of a step.  This is the
bound the remainders of Patel & Subbarao's methods need (the Lagrange remainder of Method 1, Eq.
13-15, bounded by the interval Hessian over the interval hull of the reachable set; ``R_err`` of
Method 2, Eq. 25, which the paper leaves undefined).  Around it: :func:`interval_function`
(cached on a model), :func:`split_boxes` and :func:`bound` (tighter bounds on sub-boxes) and
:class:`ModelIntervals` / :func:`for_model` (a model's ``f``, Jacobians and Hessian).

Where no finite bound exists the evaluator raises :class:`IntervalDomainError`, naming the op
and the box: division by (or a negative power of) an interval containing 0 (a primary body may
lie inside the box), ``sqrt``/``log`` of negative numbers, a pole of ``tan``, an ``if_else``
whose condition is undecided on the box (or a comparison feeding one), and a NaN in any value.
The soundness argument of the operations is in :mod:`ocreach.intervals.ops` and
``docs/intervals.md``.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError, SolverError, check_count
from ocreach.intervals.ops import (
    _KERNELS,
    _KINK_TESTS,
    _OP_ADDSUB,
    _OP_MULDIV,
    _OP_NAMES,
    _ROUNDING,
    _STACKED,
    _addsub2,
    _Fail,
    _muldiv2,
    _require,
)
from ocreach.intervals.walker import Group, Schedule, walk

#: An evaluation whose largest group has at most this many entries (rows x boxes of the whole
#: call, so the choice does not depend on the chunking) is rounded outward by ``np.nextafter``
#: (one call, faster for small arrays, e.g. the few boxes of one reachability step), larger ones
#: by the scaled-ulp formula of :func:`~ocreach.intervals.ops._dn` (both sound; they may differ
#: by one ulp).
NEXTAFTER_MAX = 1024
#: Memory budget (bytes) of the value arrays of one evaluation chunk.
CHUNK_BYTES = 2**27
#: Target number of elements (rows x boxes) of the largest group's temporaries per chunk: boxes
#: are evaluated in chunks that keep those in cache (measured up to ~1.5x faster than one chunk).
CHUNK_GROUP_ELEMS = 2**16
UNDECIDED = ("error", "hull")
KINKS = ("bound", "error")


class IntervalDomainError(SolverError):
    """An interval bound does not exist (or is not decidable) on a box.

    Attributes: ``op`` (CasADi operation name), ``box`` (index of the offending box among the
    ``B`` evaluated), ``inputs`` (list of ``(lo, hi)`` of every Function input on that box).
    """

    def __init__(self, message: str, op: str = "", box: int = -1, inputs: list | None = None):
        super().__init__(message)
        self.op = op
        self.box = box
        self.inputs = inputs or []


class IntervalFunction:
    """Sound interval extension of a CasADi Function, evaluated over many boxes at once.

    Built once per Function (``__init__`` walks it into its :attr:`schedule`, a
    :class:`~ocreach.intervals.walker.Schedule`); call with ``lo``/``hi``: lists (one per
    Function input) of arrays of shape ``(numel_i,)`` or ``(numel_i, B)`` (matrix inputs
    flattened column-major, as CasADi does; a scalar input also takes shape ``(B,)``; a single
    column broadcasts over the ``B`` boxes).  Returns a list (one per output) of ``(lo, hi)``
    arrays of shape ``(numel_out, B)``, dense column-major (structural zeros are exact zeros).
    :meth:`reshape` turns one of them into ``(rows, cols, B)``.

    ``undecided``: ``"error"`` (default) raises :class:`IntervalDomainError` where a comparison or
    an ``if_else`` condition is undecided on a box; ``"hull"`` returns the sound hull of both
    branches instead (wider, never wrong).

    ``kinks``: ``"bound"`` (default) bounds ``fabs``, ``sign``, ``copysign``, ``fmin``, ``fmax``,
    ``floor``, ``ceil`` exactly, also where the box contains their kink or jump.  ``"error"``
    raises there instead: then a passing evaluation of ``f`` certifies that every non-smooth op
    of ``f`` keeps one smooth branch on the box, which a derivative-based bound (a Lagrange
    remainder from the Hessian) needs -- CasADi differentiates ``fabs`` to ``sign`` and ``sign``
    to 0, so the Hessian of a kinked ``f`` alone would silently give a wrong remainder.

    ``native``: ``True`` evaluates Functions made of the correctly rounded operations
    (``+ - * /``, ``sq``, ``sqrt``, ``inv``, ``neg``, ``twice``) in a compiled C interpreter, one
    box at a time (:mod:`ocreach.intervals.kernel`: the bounds of the ``nextafter`` mode,
    ~20x faster for the few boxes of a reachability step); any failure re-runs the numpy
    evaluator, which reports it.  Without a compiler, or for other operations, numpy is used.
    """

    def __init__(self, fun: ca.Function, *, undecided: str = "error", kinks: str = "bound",
                 native: bool = False):
        if undecided not in UNDECIDED:
            raise ProblemError(f"undecided must be one of {UNDECIDED}; got {undecided!r}")
        if kinks not in KINKS:
            raise ProblemError(f"kinks must be one of {KINKS}; got {kinks!r}")
        self.undecided = undecided
        self.kinks = kinks
        s = walk(fun)
        #: the single-assignment schedule of the Function (:mod:`ocreach.intervals.walker`)
        self.schedule: Schedule = s
        self.fun = s.fun
        self.name = s.name
        self.names_in = list(s.names_in)
        self.n_in, self.n_out = s.n_in, s.n_out
        self.in_numel = list(s.in_numel)
        self.out_shape = list(s.out_shape)
        self.n_values = s.n_values
        self.n_ops = s.n_ops
        #: per group: (group, kernel, a is a slice, b is a slice, stacked kernel or None)
        self._plan = [(g, _KERNELS[g.op][1], isinstance(g.a, slice), isinstance(g.b, slice),
                       functools.partial(_addsub2, neg=g.sub) if g.op == _OP_ADDSUB
                       else functools.partial(_muldiv2, isdiv=g.div, ismul=g.mul)
                       if g.op == _OP_MULDIV
                       else _STACKED.get(g.op) if not (kinks == "error" and g.op in _KINK_TESTS)
                       else None)
                      for g in s.groups]
        #: entries of the largest group: the rounding mode's size test (:data:`NEXTAFTER_MAX`)
        self._max_group = s.max_group
        if not isinstance(native, (bool, np.bool_)):
            raise ProblemError(f"native must be True or False; got {native!r}")
        #: the compiled kernel (:mod:`ocreach.intervals.kernel`), built on the first call
        #: when ``native=True``; False when not wanted or not available
        self._native: Any = None if native else False

    # ------------------------------------------------------------------ evaluation
    @property
    def n_groups(self) -> int:
        """Number of vectorised numpy steps (operation groups) per evaluation."""
        return len(self.schedule.groups)

    def _check_inputs(self, lo, hi) -> tuple[list[np.ndarray], list[np.ndarray], int]:
        name = self.name
        if not isinstance(lo, (list, tuple)) or not isinstance(hi, (list, tuple)) \
                or len(lo) != self.n_in or len(hi) != self.n_in:
            raise ProblemError(f"lo and hi must be lists of {self.n_in} arrays (one per input of "
                               f"Function {name!r}: {self.names_in})")
        los, his, widths = [], [], set()
        for i in range(self.n_in):
            arg = self.names_in[i]
            l = np.asarray(lo[i], dtype=float)
            h = np.asarray(hi[i], dtype=float)
            n = self.in_numel[i]
            shape_1d = (1, -1) if n == 1 else (-1, 1)   # a scalar input: (B,) is B boxes
            l = l.reshape(shape_1d) if l.ndim <= 1 else l
            h = h.reshape(shape_1d) if h.ndim <= 1 else h
            if l.ndim != 2 or h.ndim != 2 or l.shape[0] != n or h.shape != l.shape:
                raise ProblemError(f"input {arg!r} of {name!r}: lo and hi must have shape ({n},) "
                                   f"or ({n}, B); got {np.shape(lo[i])} and {np.shape(hi[i])}")
            if not (np.isfinite(l).all() and np.isfinite(h).all()):
                raise ProblemError(f"input {arg!r} of {name!r}: box bounds must be finite; "
                                   f"got lo={l.ravel()[:8]!r}, hi={h.ravel()[:8]!r}")
            if (l > h).any():
                j, b = np.argwhere(l > h)[0]
                raise ProblemError(f"input {arg!r} of {name!r}: inverted box (lo > hi) at entry "
                                   f"{j} of box {b}: lo={l[j, b]!r} > hi={h[j, b]!r}")
            if n:
                widths.add(l.shape[1])
            los.append(l)
            his.append(h)
        widths.discard(1)
        if len(widths) > 1:
            raise ProblemError(f"inputs of {name!r} have different numbers of boxes {sorted(widths)}; "
                               "give each input B columns (or 1 to broadcast)")
        B = widths.pop() if widths else 1
        return los, his, B

    def _trusted_inputs(self, lo, hi) -> tuple[list[np.ndarray], list[np.ndarray], int]:
        """Shapes only (``check=False``): float arrays of the documented shapes from the caller."""
        los, his, B = [], [], 1
        for i, n in enumerate(self.in_numel):
            l, h = lo[i], hi[i]
            if l.ndim <= 1:
                shape_1d = (1, -1) if n == 1 else (-1, 1)
                l, h = l.reshape(shape_1d), h.reshape(shape_1d)
            if n and l.shape[1] != 1:
                B = l.shape[1]
            los.append(l)
            his.append(h)
        return los, his, B

    def __call__(self, lo: Sequence, hi: Sequence, *, check: bool = True
                 ) -> list[tuple[np.ndarray, np.ndarray]]:
        """Bounds over the boxes (class docstring).  ``check=False`` skips the validation of the
        inputs (shapes, finiteness, ``lo <= hi``) for internal callers that pass float arrays of
        the right shapes; non-finite results are still reported by the NaN guard and the caller."""
        los, his, B = self._check_inputs(lo, hi) if check else self._trusted_inputs(lo, hi)
        if self._native is None:
            from ocreach.intervals.kernel import build_interval_kernel
            self._native = build_interval_kernel(self.schedule) or False
        if self._native:
            res = self._native(los, his, B)
            if res is not None:
                return res
            # a flagged failure (domain error, NaN): numpy reports it (or bounds it its own way)
        outs = [(np.zeros((k, B)), np.zeros((k, B))) for k in self.schedule.out_numel]
        cache_chunk = int(np.clip(CHUNK_GROUP_ELEMS // max(self._max_group, 1), 256, 2048))
        chunk = max(1, min(B, cache_chunk, CHUNK_BYTES // (16 * max(self.n_values, 1))))
        previous = _ROUNDING.nextafter
        _ROUNDING.nextafter = self._max_group * B <= NEXTAFTER_MAX
        try:
            for s in range(0, B, chunk):
                e = min(B, s + chunk)
                self._eval_chunk(los, his, s, e, outs)
        finally:
            _ROUNDING.nextafter = previous
        return outs

    def _eval_chunk(self, los, his, s, e, outs):
        # lower and upper bounds in one array V[0], V[1]: one gather per argument of a group
        sch = self.schedule
        nb = e - s
        V = np.empty((2, self.n_values, nb))
        for i, (rows, idx) in enumerate(sch.in_gather):
            if rows.size:
                li, hi_ = los[i], his[i]
                V[0, rows] = li[idx] if li.shape[1] == 1 else li[idx, s:e]
                V[1, rows] = hi_[idx] if hi_.shape[1] == 1 else hi_[idx, s:e]
        V[:, sch.const_rows] = sch.const_vals
        und = self.undecided
        kink_check = self.kinks == "error"
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
            for g, fn, a_slice, b_slice, fn2 in self._plan:
                try:
                    # ndarray.take is several times faster than fancy indexing on small arrays
                    A = V[:, g.a] if a_slice else V.take(g.a, axis=1)
                    if fn2 is not None:
                        fn2(A, V[:, g.b] if b_slice else V.take(g.b, axis=1),
                            V[:, g.start:g.stop])
                        continue
                    if g.b is None:
                        args = (A[0], A[1], None, None)
                    else:
                        Bv = V[:, g.b] if b_slice else V.take(g.b, axis=1)
                        args = (A[0], A[1], Bv[0], Bv[1])
                    if kink_check and g.op in _KINK_TESTS:
                        _require(_KINK_TESTS[g.op](*args), "non-smooth point (kink or jump of "
                                 "the op) inside the box, so derivative-based bounds of this "
                                 "function do not hold there; split the box")
                    rlo, rhi = fn(*args, und)
                except _Fail as fail:
                    self._raise(fail.mask, fail.reason, g, los, his, s)
                V[0, g.start:g.stop] = rlo
                V[1, g.start:g.stop] = rhi
        # NaN guard, once per chunk: values are never overwritten, so a NaN made by any group is
        # still in its row (NaN arguments make later comparisons undecided, i.e. errors, too)
        bad = np.isnan(V[:, sch.op_start:]).any(axis=0)
        if bad.any():
            r0 = sch.op_start + int(np.argwhere(bad)[0][0])
            g = sch.groups[int(np.searchsorted(sch.starts, r0, side="right")) - 1]
            self._raise(bad[g.start - sch.op_start:g.stop - sch.op_start],
                        "the bound is not a number (an overflow to inf, then inf - inf or 0 * inf)",
                        g, los, his, s)
        for i, (olo, ohi) in enumerate(outs):
            O = V.take(sch.out_rows[i], axis=1)
            olo[sch.out_dense[i], s:e] = O[0]
            ohi[sch.out_dense[i], s:e] = O[1]

    def _raise(self, mask, reason, g: Group, los, his, offset):
        r, c = np.argwhere(mask)[0]
        box = int(offset + c)
        inputs = [(l[:, 0 if l.shape[1] == 1 else box].copy(), h[:, 0 if h.shape[1] == 1 else box].copy())
                  for l, h in zip(los, his)]
        real = self.schedule.instr_op.get(int(g.instr[r]), g.op)   # a mixed group: the entry's op
        op = _OP_NAMES.get(real, str(real))

        def fmt(a):   # repr of each float (exact, round-trips); cheap, unlike array2string
            items = [repr(float(v)) for v in a[:24]]
            return "[" + ", ".join(items) + (", ..." if a.size > 24 else "") + "]"

        desc = "; ".join(f"{self.names_in[i]}: lo={fmt(l)} hi={fmt(h)}"
                         for i, (l, h) in enumerate(inputs))
        extra = (" A primary (a singularity of the dynamics, e.g. the centre of a body) may lie "
                 "inside the box: shrink or split the box, or move it away from the singularity."
                 if real in (ca.OP_DIV, ca.OP_INV, ca.OP_POW, ca.OP_CONSTPOW, ca.OP_LOG, ca.OP_TAN)
                 else "")
        raise IntervalDomainError(
            f"interval evaluation of {self.name!r} failed at instruction {int(g.instr[r])} "
            f"({op}): {reason}, on box {box}: {desc}.{extra}", op=op, box=box, inputs=inputs) from None

    # ------------------------------------------------------------------ helpers
    def reshape(self, out: tuple[np.ndarray, np.ndarray], i: int) -> tuple[np.ndarray, np.ndarray]:
        """Output ``i`` (as returned by ``__call__``) reshaped to ``(rows, cols, B)``."""
        rows, cols = self.out_shape[i]
        return tuple(np.reshape(a, (cols, rows, a.shape[-1])).transpose(1, 0, 2) for a in out)

    def __repr__(self) -> str:
        return (f"IntervalFunction({self.name!r}: {self.n_ops} operations in "
                f"{self.n_groups} groups, {self.n_values} values)")


def interval_function(fun: ca.Function, *, model: Any = None, key: Any = None,
                      undecided: str = "error", kinks: str = "bound",
                      native: bool = False) -> IntervalFunction:
    """:class:`IntervalFunction` of ``fun``, cached through ``model.cached`` when ``model`` is
    given (``key`` defaults to the Function's name); ``native=True`` evaluates it in compiled C
    where it can (:mod:`ocreach.intervals.kernel`, the same bounds)."""
    if model is None:
        return IntervalFunction(fun, undecided=undecided, kinks=kinks, native=native)
    k = ("intervals", key if key is not None else fun.name(), undecided, kinks, native)
    return model.cached(k, lambda: IntervalFunction(fun, undecided=undecided, kinks=kinks,
                                                    native=native))


# ---------------------------------------------------------------------------- sub-box splitting
def split_boxes(lo: Sequence, hi: Sequence, splits: int, *, max_boxes: int = 4096,
                dims: Sequence[tuple[int, int]] | None = None) -> tuple[list, list, int]:
    """Split one box (lists of ``(n_i,)`` arrays per input) into a uniform grid of sub-boxes.

    The widest entries (over all inputs; or the ``(input, entry)`` pairs in ``dims``) are cut into
    ``splits`` pieces each, as many entries as fit into ``max_boxes`` sub-boxes.  Neighbouring
    sub-boxes share their cut points exactly, so the sub-boxes cover the box.  Returns
    ``(lo_list, hi_list, S)`` with arrays of shape ``(n_i, S)``.
    """
    splits = check_count("splits", splits, 1)
    max_boxes = check_count("max_boxes", max_boxes, 1)
    lo = [np.asarray(a, dtype=float).ravel() for a in lo]
    hi = [np.asarray(a, dtype=float).ravel() for a in hi]
    if dims is None:
        cand = sorted(((float(h[j] - l[j]), i, j) for i, (l, h) in enumerate(zip(lo, hi))
                       for j in range(l.size) if h[j] > l[j]), reverse=True)
        n_dims = 0 if splits == 1 else math.floor(math.log(max_boxes) / math.log(splits) + 1e-12)
        dims = [(i, j) for (_, i, j) in cand[:n_dims]]
    dims = list(dims)
    if splits ** len(dims) > max_boxes:
        raise ProblemError(f"splits={splits} over {len(dims)} dims gives {splits ** len(dims)} "
                           f"sub-boxes > max_boxes={max_boxes}")
    S = splits ** len(dims)
    out_lo = [np.repeat(l[:, None], S, axis=1) for l in lo]
    out_hi = [np.repeat(h[:, None], S, axis=1) for h in hi]
    if dims:
        grid = np.indices((splits,) * len(dims)).reshape(len(dims), S)
        for d, (i, j) in enumerate(dims):
            cuts = lo[i][j] + (hi[i][j] - lo[i][j]) * (np.arange(splits + 1) / splits)
            cuts[0], cuts[-1] = lo[i][j], hi[i][j]
            cuts = np.maximum.accumulate(np.clip(cuts, lo[i][j], hi[i][j]))
            out_lo[i][j] = cuts[grid[d]]
            out_hi[i][j] = cuts[grid[d] + 1]
    return out_lo, out_hi, S


def bound(fun: ca.Function | IntervalFunction, lo: Sequence, hi: Sequence, *, splits: int = 1,
          max_boxes: int = 4096, dims: Sequence[tuple[int, int]] | None = None
          ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Interval bound of ``fun`` over one box, tightened by splitting it into sub-boxes.

    ``lo``/``hi``: lists of ``(n_i,)`` arrays (one per input).  With ``splits = k`` the widest
    entries are each cut into ``k`` pieces (as many as fit into ``max_boxes`` sub-boxes, see
    :func:`split_boxes`); the result is the union hull over the sub-boxes, as a list of
    ``(lo, hi)`` arrays of shape ``(numel_out,)``.
    """
    ifun = fun if isinstance(fun, IntervalFunction) else IntervalFunction(fun)
    ifun._check_inputs([np.asarray(a, dtype=float).ravel() for a in lo],
                       [np.asarray(a, dtype=float).ravel() for a in hi])
    slo, shi, _ = split_boxes(lo, hi, splits, max_boxes=max_boxes, dims=dims)
    return [(l.min(axis=1), h.max(axis=1)) for (l, h) in ifun(slo, shi)]


# ---------------------------------------------------------------------------- model bounds
Box = tuple[Any, Any]


class ModelIntervals:
    """Interval bounds of a :class:`ocreach.model.Model`'s ``f``, Jacobians and Hessian tensor.

    Every method takes boxes ``x = (lo, hi)``, ``u = (lo, hi)`` with arrays of shape ``(n,)`` or
    ``(n, B)`` (``u`` is required: the control set enters every remainder); ``t`` a number, a
    ``(B,)`` array or a box ``(lo, hi)`` (default 0); ``p`` ``None`` (the model's defaults), a
    vector or a box.  Get it with :func:`for_model` (cached on the model).
    """

    def __init__(self, model: Any, undecided: str = "error"):
        self.model = model
        self.undecided = undecided

    FUNCTIONS = ("f", "jac", "hessian", "all")

    def function(self, what: str, kinks: str = "bound") -> IntervalFunction:
        """The :class:`IntervalFunction` behind :meth:`f` (``"f"``, the model's ``f_fun``),
        :meth:`jacobians` (``"jac"``, ``jac_fun``), :meth:`hessian` (``"hessian"``) and
        :meth:`all` (``"all"``), built once per model (``Model.cached``); inputs ``(x, u, t, p)``."""
        if what not in self.FUNCTIONS:
            raise ProblemError(f"unknown model interval function {what!r}; allowed: "
                               f"{list(self.FUNCTIONS)}")
        m = self.model

        def build() -> ca.Function:
            args = [m.x, m.u, m.t, m.p]
            names = ["x", "u", "t", "p"]
            if what == "f":
                return m.f_fun
            if what == "jac":
                return m.jac_fun
            if what == "hessian":
                return ca.Function("f_hessian", args, [m.derivative_expressions(2)[1]], names, ["H"])
            d1, d2 = m.derivative_expressions(2)[:2]
            return ca.Function("f_jac_hess", args, [m.f, d1, d2], names, ["f", "J", "H"])

        return m.cached(("intervals", "model", what, self.undecided, kinks),
                        lambda: IntervalFunction(build(), undecided=self.undecided, kinks=kinks))

    def _args(self, x: Box, u: Box, t, p) -> tuple[list, list]:
        m = self.model
        t = (t, t) if np.ndim(t) == 0 or (not isinstance(t, tuple)) else t
        if p is None:
            p = (m.p_default, m.p_default)
        elif not isinstance(p, tuple):
            p = (p, p)
        lo = [x[0], u[0], np.reshape(np.asarray(t[0], dtype=float), (1, -1)), p[0]]
        hi = [x[1], u[1], np.reshape(np.asarray(t[1], dtype=float), (1, -1)), p[1]]
        return lo, hi

    def f(self, x: Box, u: Box, t=0.0, p=None) -> tuple[np.ndarray, np.ndarray]:
        """Bound of ``f(x, u, t; p)``: ``(lo, hi)`` of shape ``(n_x, B)``."""
        return self.function("f")(*self._args(x, u, t, p))[0]

    def jacobians(self, x: Box, u: Box, t=0.0, p=None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Bounds of ``[f, df/dx, df/du]``: shapes ``(n_x, B)``, ``(n_x, n_x, B)``, ``(n_x, n_u, B)``."""
        F = self.function("jac")
        out = F(*self._args(x, u, t, p))
        return [out[0], F.reshape(out[1], 1), F.reshape(out[2], 2)]

    def check_smooth(self, x: Box, u: Box, t=0.0, p=None) -> None:
        """Raise :class:`IntervalDomainError` unless every non-smooth op of ``f`` (``fabs``,
        ``sign``, ``fmin``, ``if_else`` ...) keeps one smooth branch on the boxes: the condition
        for derivative bounds (:meth:`hessian`, :meth:`all`) to bound a Taylor remainder."""
        self.function("f", kinks="error")(*self._args(x, u, t, p))

    def hessian(self, x: Box, u: Box, t=0.0, p=None, *, smooth_check: bool = True
                ) -> tuple[np.ndarray, np.ndarray]:
        """Bound of the Hessian tensor ``H[i, a, b] = d^2 f_i / dz_a dz_b``, ``z = (x, u)``:
        ``(lo, hi)`` of shape ``(n_x, n_z, n_z, B)`` (Foss et al. Eq. 11 layout, as
        :meth:`ocreach.model.Model.tensors`).  ``smooth_check`` first runs :meth:`check_smooth`."""
        if smooth_check:
            self.check_smooth(x, u, t, p)
        F = self.function("hessian")
        return self._hess(F, F(*self._args(x, u, t, p))[0])

    def all(self, x: Box, u: Box, t=0.0, p=None, *, smooth_check: bool = True
            ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """``f`` (n_x, B), ``J = df/dz`` (n_x, n_z, B) and ``H`` (n_x, n_z, n_z, B) in one pass
        (after :meth:`check_smooth` unless ``smooth_check=False``)."""
        if smooth_check:
            self.check_smooth(x, u, t, p)
        F = self.function("all")
        out = F(*self._args(x, u, t, p))
        return {"f": out[0], "J": F.reshape(out[1], 1), "H": self._hess(F, out[2])}

    def _hess(self, F: IntervalFunction, out, i: int = -1):
        m = self.model
        lo, hi = F.reshape(out, F.n_out - 1 if i < 0 else i)
        B = lo.shape[-1]
        return (lo.reshape(m.n_x, m.n_z, m.n_z, B), hi.reshape(m.n_x, m.n_z, m.n_z, B))


def for_model(model: Any, *, undecided: str = "error") -> ModelIntervals:
    """The :class:`ModelIntervals` of ``model`` (cached with ``model.cached``)."""
    if undecided not in UNDECIDED:
        raise ProblemError(f"undecided must be one of {UNDECIDED}; got {undecided!r}")
    return model.cached(("intervals", "model", undecided), lambda: ModelIntervals(model, undecided))
