"""The graph walker: a CasADi SX Function as a single-assignment schedule of operation groups.

CasADi has no interval arithmetic, so the evaluator needs the Function's algorithm as data.  The
walker reads the instruction list once (``n_instructions``, ``instruction_id``,
``instruction_input``, ``instruction_output``, ``instruction_constant`` and the ``casadi.OP_*``
codes), renames CasADi's reused work slots into single-assignment values, groups independent
instructions of one operation class (list scheduling on the graph, :func:`_schedule`: fewer
groups than grouping by depth) and lays the values out as rows: the inputs, the constants, then
every group as a contiguous slice.  The result is a :class:`Schedule` (frozen data), which the
numpy evaluator (:mod:`ocreach.intervals.evaluator`, one numpy call per group over ``B`` boxes)
and the compiled interpreter (:mod:`ocreach.intervals.kernel`, one operation and one box at a
time) both run.

Imports the op tables of :mod:`ocreach.intervals.ops` (arities, pseudo op codes, scheduling
classes) and :mod:`ocreach.errors`.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError
from ocreach.intervals.ops import (
    _CLASS,
    _KERNELS,
    _OP_ADDSUB,
    _OP_MULC,
    _OP_MULDIV,
    _OP_NAMES,
    SUPPORTED_OPS,
)


@dataclass(frozen=True)
class Group:
    """One group of the schedule: entries of one op code (or of one mixed class, :data:`_OP_ADDSUB`,
    :data:`_OP_MULDIV`) whose arguments are all computed by earlier groups."""

    op: int
    start: int          # first value row written by the group
    stop: int
    a: np.ndarray | slice    # value rows of the first argument (a slice if consecutive)
    b: np.ndarray | slice | None
    instr: np.ndarray   # CasADi instruction index of each row (for messages)
    #: (g, 1) masks of a mixed group: the subtractions of an add/sub group; the divisions and the
    #: products of two values (not by a constant) of a mul/div group; None otherwise
    sub: np.ndarray | None = None
    div: np.ndarray | None = None
    mul: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Schedule:
    """A Function's algorithm as single-assignment value rows and groups (:func:`walk`).

    Rows ``0 .. n_in_values - 1`` are the input entries read (``in_gather``), then the constants
    (``const_rows``, values ``const_vals``), then the groups in order from ``op_start`` on
    (``groups``, their first rows ``starts``).  Output ``i`` is read from the rows
    ``out_rows[i]`` into its dense column-major entries ``out_dense[i]``."""

    fun: ca.Function                  # the SX Function walked
    name: str
    names_in: tuple[str, ...]
    in_numel: tuple[int, ...]
    out_shape: tuple[tuple[int, int], ...]
    out_numel: tuple[int, ...]
    n_values: int                     # value rows
    n_ops: int                        # operation instructions
    groups: tuple[Group, ...]
    starts: np.ndarray                # first row of each group
    max_group: int                    # entries of the largest group
    instr_op: dict[int, int]          # instruction index -> its CasADi op (for messages)
    #: per Function input: the value rows and the dense entries of the input they read
    in_gather: tuple[tuple[np.ndarray, np.ndarray], ...]
    const_rows: slice
    const_vals: np.ndarray            # (n_const, 1)
    op_start: int                     # first row written by an operation
    out_rows: tuple[np.ndarray, ...]
    out_dense: tuple[np.ndarray, ...]

    @property
    def n_in(self) -> int:
        return len(self.in_numel)

    @property
    def n_out(self) -> int:
        return len(self.out_shape)


def _rows_or_slice(rows: list[int]) -> np.ndarray | slice:
    """Value rows read by a group: a slice (a view, no copy) when they are consecutive."""
    r = np.asarray(rows, dtype=np.int64)
    if r.size and np.all(np.diff(r) == 1):
        return slice(int(r[0]), int(r[-1]) + 1)
    return r


def _as_sx(fun: ca.Function) -> ca.Function:
    if not isinstance(fun, ca.Function):
        raise ProblemError(f"fun must be a casadi.Function; got {type(fun).__name__}")
    if fun.is_a("SXFunction"):
        return fun
    try:
        out = fun.expand()
    except Exception as exc:
        raise ProblemError(f"Function {fun.name()!r} ({fun.class_name()}) cannot be expanded to an "
                           f"SX Function for interval evaluation: {exc}") from exc
    if not out.is_a("SXFunction"):
        raise ProblemError(f"Function {fun.name()!r} expanded to {out.class_name()}, not an SX "
                           "Function; interval evaluation needs SX")
    return out


def _schedule(ops: list[int], args: list[tuple[int, ...]]) -> list[list[int]]:
    """Group operation nodes into batches of one op code whose arguments are all computed.

    List scheduling on the DAG (``args[i]``: the operation nodes node ``i`` reads): at every step
    the op code of the ready node with the longest path still below it is run, for *all* ready
    nodes of that code.  This gives far fewer groups than grouping by (depth, op) (e.g. 27 instead
    of 53 for the spatial CR3BP Hessian), and so fewer numpy calls per evaluation.  ``ops`` may be
    scheduling classes (:data:`_CLASS`: add with sub, mul with div), whose mixed groups run as
    one stacked kernel.
    """
    n = len(ops)
    users: list[list[int]] = [[] for _ in range(n)]
    waiting = [len(set(a)) for a in args]
    for i, a in enumerate(args):
        for j in set(a):
            users[j].append(i)
    height = [0] * n
    for i in range(n - 1, -1, -1):          # instructions are in topological order
        for j in args[i]:
            height[j] = max(height[j], height[i] + 1)
    ready: dict[int, list[int]] = {}
    for i in range(n):
        if waiting[i] == 0:
            ready.setdefault(ops[i], []).append(i)
    batches = []
    while ready:
        op = max(ready, key=lambda o: (max(height[i] for i in ready[o]), len(ready[o]), -o))
        batch = ready.pop(op)
        batches.append(batch)
        for i in batch:
            for u in users[i]:
                waiting[u] -= 1
                if waiting[u] == 0:
                    ready.setdefault(ops[u], []).append(u)
    return batches




def walk(fun: ca.Function) -> Schedule:
    """The :class:`Schedule` of ``fun`` (an SX Function, or one that expands to SX).

    Raises :class:`ProblemError` for a Function that is not SX (and cannot be expanded) and for
    an operation the interval kernels do not bound (a free symbol, a call node, ...), naming it.
    """
    f = _as_sx(fun)
    n_in, n_out = f.n_in(), f.n_out()
    out_shape = tuple(f.sparsity_out(i).shape for i in range(n_out))
    in_dense = [np.asarray(f.sparsity_in(i).find(), dtype=np.int64) for i in range(n_in)]
    out_dense = [np.asarray(f.sparsity_out(i).find(), dtype=np.int64) for i in range(n_out)]

    # --- pass 1: rename CasADi's reused work slots into single-assignment values.  Leaves:
    # input entries and constants (deduplicated); nodes: one per operation instruction.
    slot: dict[int, tuple[str, int]] = {}
    inputs: dict[tuple[int, int], int] = {}      # (input, dense index) -> leaf number
    consts: dict[float, int] = {}
    node_op: list[int] = []
    node_args: list[tuple[tuple[str, int], ...]] = []
    node_instr: list[int] = []
    outputs: list[tuple[int, int, tuple[str, int]]] = []   # (output, dense index, value)
    for k in range(f.n_instructions()):
        op = f.instruction_id(k)
        if op == ca.OP_INPUT:
            i, nz = f.instruction_input(k)
            key = (i, int(in_dense[i][nz]))
            slot[f.instruction_output(k)[0]] = ("in", inputs.setdefault(key, len(inputs)))
        elif op == ca.OP_CONST:
            v = float(f.instruction_constant(k))   # -0.0 and 0.0 are the same real number
            slot[f.instruction_output(k)[0]] = ("const", consts.setdefault(v, len(consts)))
        elif op == ca.OP_OUTPUT:
            o, nz = f.instruction_output(k)
            outputs.append((o, int(out_dense[o][nz]), slot[f.instruction_input(k)[0]]))
        elif op in _KERNELS:
            arity = _KERNELS[op][0]
            args = tuple(slot[s] for s in f.instruction_input(k)[:arity])
            if op == ca.OP_MUL and "const" in (args[0][0], args[1][0]):
                op = _OP_MULC                      # constant second: 2 products, not 4
                args = args if args[1][0] == "const" else (args[1], args[0])
            node_args.append(args)
            node_op.append(op)
            node_instr.append(k)
            slot[f.instruction_output(k)[0]] = ("op", len(node_op) - 1)
        else:
            name = _OP_NAMES.get(op, f"code {op}")
            hint = (" (a free SX symbol: make it a Function input)" if op == ca.OP_PARAMETER
                    else " (a call node, e.g. a Callback or external Function whose graph "
                    "the evaluator cannot see: inline it or write it in SX)"
                    if op == ca.OP_CALL else "")
            raise ProblemError(f"interval evaluation of Function {f.name()!r}: operation "
                               f"{name!r}{hint} (instruction {k}) is not supported; "
                               f"supported: {list(SUPPORTED_OPS)}")

    # --- pass 2: schedule the nodes into groups, lay out the value rows (inputs, constants,
    # then the groups in order, each a contiguous slice)
    op_class = [_CLASS.get(op, op) for op in node_op]
    instr_op = {k: (ca.OP_MUL if op == _OP_MULC else op) for k, op in zip(node_instr, node_op)}
    batches = _schedule(op_class, [tuple(j for kind, j in a if kind == "op") for a in node_args])
    n_in_vals, n_const = len(inputs), len(consts)
    op_row = np.empty(len(node_op), dtype=np.int64)
    pos = n_in_vals + n_const
    for batch in batches:
        op_row[batch] = np.arange(pos, pos + len(batch))
        pos += len(batch)

    def row(v: tuple[str, int]) -> int:
        kind, j = v
        return j if kind == "in" else n_in_vals + j if kind == "const" else int(op_row[j])

    groups = []
    for batch in batches:
        op = node_op[batch[0]]
        masks: dict[str, np.ndarray] = {}
        neg = np.asarray([node_op[i] == ca.OP_SUB for i in batch])[:, None]
        if op in (ca.OP_ADD, ca.OP_SUB) and neg.any() and not neg.all():
            op = _OP_ADDSUB
            masks = {"sub": neg}
        elif _CLASS.get(op, op) == ca.OP_MUL and len({node_op[i] for i in batch}) > 1:
            op = _OP_MULDIV
            masks = {"div": np.asarray([node_op[i] == ca.OP_DIV for i in batch])[:, None],
                     "mul": np.asarray([node_op[i] == ca.OP_MUL for i in batch])[:, None]}
        a = _rows_or_slice([row(node_args[i][0]) for i in batch])
        b = (_rows_or_slice([row(node_args[i][1]) for i in batch])
             if _KERNELS[op][0] == 2 else None)
        start = int(op_row[batch[0]])
        groups.append(Group(op, start, start + len(batch), a, b,
                            np.asarray([node_instr[i] for i in batch], dtype=np.int64), **masks))
    # input gathers: per Function input, the value rows and the dense entries they read
    keys = sorted(inputs, key=inputs.get)
    in_gather = []
    for i in range(n_in):
        rows = [inputs[key] for key in keys if key[0] == i]
        in_gather.append((np.asarray(rows, dtype=np.int64),
                          np.asarray([key[1] for key in keys if key[0] == i], dtype=np.int64)))
    return Schedule(
        fun=f, name=f.name(), names_in=tuple(f.name_in(i) for i in range(n_in)),
        in_numel=tuple(f.sparsity_in(i).numel() for i in range(n_in)), out_shape=out_shape,
        out_numel=tuple(int(r * c) for r, c in out_shape), n_values=pos, n_ops=len(node_op),
        groups=tuple(groups), starts=np.asarray([g.start for g in groups], dtype=np.int64),
        max_group=max((g.stop - g.start for g in groups), default=1), instr_op=instr_op,
        in_gather=tuple(in_gather), const_rows=slice(n_in_vals, n_in_vals + n_const),
        const_vals=np.asarray(sorted(consts, key=consts.get), dtype=float)[:, None],
        op_start=n_in_vals + n_const,
        out_rows=tuple(np.asarray([row(v) for (o, d, v) in outputs if o == i], dtype=np.int64)
                       for i in range(n_out)),
        out_dense=tuple(np.asarray([d for (o, d, v) in outputs if o == i], dtype=np.int64)
                        for i in range(n_out)))
