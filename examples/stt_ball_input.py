"""Ball-input representations of stt measured on a problem (docs/validation/stt-tightness.md,
"Ball input within 3 % of the ball").

    python examples/stt_ball_input.py --problem nrho-flyby --steps 6 10 --h-max 60 200 --order 2
        [--inputs zonotope-coarse zonotope pz pz-compact b3] [--mc 1000] [--seed 3] [--dirs 52]
        [--horizon K] [--ffoe 100] [--direct] [--reduce-group parallel]

Truth: ``--mc`` Monte Carlo endpoints (``MonteCarlo(samples, seed)`` on the grid cut at step k;
with ``--horizon K`` one grid of K steps for the MC, the optional ``--ffoe`` extremals and one STT
run, evaluated at each of ``--steps``); ``--direct`` joins the support of the true reachable set by
direct multiple shooting (:func:`ocreach.reach.direct.transcription_support`, per direction and
step; the truth is then the larger of it and the MC support, and the width uses it too).
Metric: for ``--dirs`` directions d in position space (Fibonacci on the sphere, or the circle for
two position coordinates), the excess ``(h_upper(d) - max_mc d.x) / (max_mc d.x - min_mc d.x)``
of the STT set's support upper bound (branch and bound on the set's own factors,
``support_bounds``) over the truth, max over d, in % of the width; also the lower bound's excess,
the smallest margin ``min_d (h_upper(d) - max_mc d.x)`` (negative: a true point lies outside)
and the warm runtime (median of ``--reps`` after one warm-up run).
``--reduce-group parallel``: stt's ``reduce_group`` option (grouped enclosure of parallel removed
monomials, :func:`ocreach.sets.reduce.enclose_removed`).
Input ``b3`` is the 12-generator 3-D leaf of :mod:`ocreach.sets.ball_pz` (3 factors).
``--problem dro4``: a test model with a 4-D ball input (not in the registry): ``dro``'s planar
CR3BP with ``u`` in the unit ball of R^4, ``dv/dt += a_max u[0:2]`` (thrust) and
``dr/dt += a_max u[2:4]`` (a velocity error sharing the same budget); position directions on the
circle.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import statistics
import time

import numpy as np

import ocreach
from ocreach.geometry.directions import fibonacci_sphere, plane_directions
from ocreach.reach.mc import MonteCarlo
from ocreach.registry import get_problem
from ocreach.sets.pz_exact import support_bounds

stt_mod = importlib.import_module("ocreach.reach.stt")


def dro4():
    """``dro`` with a 4-D ball input (see the module docstring)."""
    import casadi as ca

    from ocreach.model import Model

    p = get_problem("dro")
    m = p.model
    u = ca.SX.sym("u", 4)
    a = m.p[1]
    f0 = ca.substitute(m.f, m.u, ca.SX.zeros(2))
    f = f0 + ca.vertcat(a * u[2:4], a * u[0:2])
    model = Model.build("cr3bp-planar-u4", m.x, u, f, t=m.t, p=m.p, p_default=m.p_default,
                        state_names=m.state_names, param_names=m.param_names, thrust_param="a_max",
                        control_set="ball", description="planar CR3BP, 4-D ball input (test model)")
    return dataclasses.replace(p, id="dro4", model=model, control_set=None, method_options={})


def direct_support(p, k: int, pos: list, D: np.ndarray) -> np.ndarray:
    """Support of the true reachable set at step k in the position directions ``D`` (cached)."""
    from ocreach.reach.direct import transcription_support

    key = (k, D.tobytes())
    if key not in _DIRECT:
        pk = dataclasses.replace(p, grid=p.grid[:k + 1])
        out = []
        for d in D:
            z = np.zeros(p.model.n_x)
            z[pos] = d
            out.append(transcription_support(pk, z))
        _DIRECT[key] = np.array(out)
    return _DIRECT[key]


_DIRECT: dict = {}


def _input(kind, n_u, n_throttle=0, ball="pz"):
    """input_pz with the extra candidate "b3" (the compact 3-D leaf with 3 factors)."""
    if kind == "ball" and ball == "b3":
        from ocreach.sets.ball_pz import compact_ball_pz
        U = compact_ball_pz(n_u, plan="b3")
        return U.cartesian(_ORIG("box", n_throttle)) if n_throttle else U
    return _ORIG(kind, n_u, n_throttle, ball)


_ORIG = stt_mod.input_pz


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problem", default="nrho-flyby")
    ap.add_argument("--steps", type=int, nargs="+", default=[6, 10])
    ap.add_argument("--h-max", type=int, nargs="+", default=[60, 200])
    ap.add_argument("--order", type=int, nargs="+", default=[2])
    ap.add_argument("--inputs", nargs="+", default=["zonotope-coarse", "zonotope", "pz", "pz-compact", "b3"])
    ap.add_argument("--mc", type=int, default=1000)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--dirs", type=int, default=52)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--horizon", type=int, default=0)
    ap.add_argument("--ffoe", type=int, default=0)
    ap.add_argument("--direct", action="store_true")
    ap.add_argument("--reduce-group", default=None)
    a = ap.parse_args(argv)
    stt_mod.input_pz = _input
    stt_mod.BALL_INPUTS = tuple(dict.fromkeys(stt_mod.BALL_INPUTS + ("b3",)))
    p = dro4() if a.problem == "dro4" else get_problem(a.problem)
    cut = {k: a.horizon or k for k in a.steps}
    truth = {}
    for K in sorted(set(cut.values())):
        pK = dataclasses.replace(p, grid=p.grid[:K + 1])
        pts = MonteCarlo(samples=a.mc, seed=a.seed).solve(pK).points
        if a.ffoe:
            ff = ocreach.reach(pK, "ffoe", samples=a.ffoe).points
            pts = [np.vstack([x, y]) for x, y in zip(pts, ff)]
        truth[K] = pts
    pos = list(p.position_dims)
    D = plane_directions(a.dirs)[0] if len(pos) == 2 else fibonacci_sphere(a.dirs)
    rows = []
    for order in a.order:
        for h in a.h_max:
            runs: dict = {}
            for k in a.steps:
                K = cut[k]
                pk = dataclasses.replace(p, grid=p.grid[:K + 1])
                X = truth[K][k][:, pos] @ D.T
                hi, low = X.max(axis=0), X.min(axis=0)
                if a.direct:
                    hi = np.maximum(hi, direct_support(p, k, pos, D))
                    low = np.minimum(low, -direct_support(p, k, pos, -D))
                width = hi - low
                for inp in a.inputs:
                    times = []
                    try:
                        if (K, inp) not in runs:
                            for _ in range(a.reps + 1):
                                t0 = time.perf_counter()
                                res = ocreach.reach(pk, "stt", order=order, h_max=h, input_set="ball", ball_input=inp,
                                                     reduce_group=a.reduce_group)
                                times.append(time.perf_counter() - t0)
                            runs[K, inp] = res, times
                        res, times = runs[K, inp]
                        sb = support_bounds(res.sets[k].project(pos), D)
                        up = float(np.max((sb.upper - hi) / width)) * 100
                        lo = float(np.max((sb.lower - hi) / width)) * 100
                        out = float(np.min(sb.upper - hi))
                    except Exception as exc:  # noqa: BLE001 - a diverged run is a result here
                        up = lo = out = float("nan")
                        print(f"  {inp}: {type(exc).__name__}: {str(exc)[:120]}")
                    row = dict(order=order, h_max=h, steps=k, t=float(p.grid[k]), input=inp, upper=up, lower=lo,
                               min_margin=out, runtime=statistics.median(times[1:]) if len(times) > 1 else float("nan"))
                    rows.append(row)
                    print(f"order {order} h_max {h:4d} steps {k:3d} {inp:16s} +{up:7.1f} % (lower +{lo:7.1f} %)"
                          f"  min margin {out:+.2e}  {row['runtime']:.3f} s", flush=True)
    return rows


if __name__ == "__main__":
    main()
