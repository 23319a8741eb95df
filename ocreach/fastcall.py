"""Low-overhead numeric calls of small CasADi Functions (``Function.buffer``).

A plain ``Function.__call__`` converts every argument and result between numpy and ``DM``, about
150-200 us per call for the few-state models here, which dominated the per-step cost of the zonotope
methods (two calls per step).  :class:`FastFunction` binds numpy buffers once and triggers the
evaluation (~10-15 us), returning dense numpy arrays.  The numbers are CasADi's own evaluation,
bit for bit.
"""
from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError


class FastFunction:
    """Callable ``(*args) -> list of dense arrays`` for a CasADi Function with dense inputs.

    Not re-entrant: the result arrays are fresh, but the input buffers are shared, so one instance
    must not be called from two threads at once (make one per run; building it costs microseconds)."""

    def __init__(self, fun: ca.Function):
        self.fun = fun
        for i in range(fun.n_in()):
            if not fun.sparsity_in(i).is_dense():
                raise ProblemError(f"FastFunction: input {fun.name_in(i)!r} of {fun.name()!r} is "
                                   "sparse; only dense inputs are supported")
        self._buf, self._trigger = fun.buffer()
        self._ins = [np.zeros(fun.nnz_in(i)) for i in range(fun.n_in())]
        self._outs = [np.zeros(fun.nnz_out(i)) for i in range(fun.n_out())]
        for i, a in enumerate(self._ins):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate(self._outs):
            self._buf.set_res(i, memoryview(a))
        self._pattern = []
        for i in range(fun.n_out()):
            sp = fun.sparsity_out(i)
            self._pattern.append((np.asarray(sp.row(), dtype=np.int64),
                                  np.asarray(sp.get_col(), dtype=np.int64), sp.shape))

    def __call__(self, *args: Any) -> list[np.ndarray]:
        if len(args) != len(self._ins):
            raise ProblemError(f"{self.fun.name()!r} takes {len(self._ins)} arguments; got {len(args)}")
        for buf, a in zip(self._ins, args):
            buf[:] = np.ravel(np.asarray(a, dtype=float), order="F")
        self._trigger()
        res = []
        for vals, (r, c, shape) in zip(self._outs, self._pattern):
            D = np.zeros(shape)
            D[r, c] = vals
            res.append(D)
        return res

