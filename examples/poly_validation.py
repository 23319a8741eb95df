"""Validation of the sound ``poly`` method (conservative polynomialization) against independent
truth, side by side with ``taylor``: the rows of ``docs/validation/poly.md``.

For every case the script runs ``poly`` and ``taylor`` (keeping the sets of a method that stops,
``SolverError.partial``), then checks the sets against trajectories integrated by SciPy's DOP853
(rtol 1e-12, atol 1e-14) on right-hand sides written out here in numpy (not the project's CasADi
models or integrators): half of the initial states at vertices of the initial set, half uniform
inside, the controls constant, bang-bang (a new unit direction / box corner every grid step) or
uniform random per step.  Every state at every grid time must lie in that time's set, and the
states at the step midpoints (of the first ``--tube-samples``) in the step's time-interval tube,
decided by the verified three-way membership of :mod:`ocreach.sets.pz_witness`
(:func:`~ocreach.sets.pz_witness.classify` for polynomial zonotopes, warm-started from the same
trajectory's witness at the previous grid time; :func:`~ocreach.sets.pz_witness.classify_zonotope`
for zonotopes and their unions): a verified witness proves a point inside, a verified certificate
(a direction beyond the support) outside -- an escape --, and a point neither is reported as
undecided, never counted as inside.

A point escapes when it is outside the set enlarged by ``1e-9 (1 + |x|)`` (the truth's own
error is far below).  Tightness at the last time both reached and at each method's last time: the
ratio of the set's width to the samples' width in 50 random position directions (for a polynomial
zonotope the rigorous upper support bound of :func:`ocreach.sets.pz_exact.support_bounds`).

    python examples/poly_validation.py [--cases vdp,dro,nrho24,nrho76,nrho76sun,halo80,em200,em200mee]
        [--samples 10000] [--tube-samples 2000] [--pz-every 1] [--methods poly,taylor]
        [--out out/poly_validation]

Progress and every escape are printed as they are found; ``summary.json`` is rewritten
(atomically) after every case, so an interrupted run keeps the cases it finished.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp

import ocreach
from ocreach.errors import SolverError
from ocreach.fileio import atomic_write_text, json_text, jsonable
from ocreach.sets.polyzonotope import PolyZonotope
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.pz_witness import classify, classify_zonotope
from ocreach.sets.union import ZonotopeUnion
from ocreach.sets.zonotope import Zonotope

HOUR = 3600.0 / 375200.0
ABS_TOL = 1e-9
RTOL, ATOL = 1e-12, 1e-14

#: case -> (problem id, problem overrides, poly options, taylor options): the rows of
#: ``benchmarks/bench_poly.py`` (the same options), and two longer horizons
CASES = {
    "vdp": ("vdp", {}, {}, {}),
    "dro": ("dro", {"t_final": 2.0}, {"substeps": 8}, {"substeps": 8}),
    "nrho24": ("nrho-9-2", {"t_final": 24 * HOUR}, {}, {}),
    "nrho76": ("nrho-9-2", {}, {"max_parts": 1}, {"max_parts": 1}),
    "nrho76sun": ("nrho-9-2", {}, {"max_parts": 1, "coordinates": "sundman:k=1.5"},
                  {"max_parts": 1, "coordinates": "sundman:k=1.5"}),
    "halo80": ("l2-halo", {"t_final": 80 * HOUR}, {"max_parts": 1}, {"max_parts": 1}),
    "em200": ("earth-mars", {"t_days": 200.0}, {"max_parts": 1}, {"max_parts": 1}),
    "em200mee": ("earth-mars", {"t_days": 200.0}, {"max_parts": 1, "coordinates": "mee"},
                 {"max_parts": 1, "coordinates": "mee"}),
    "nrho157": ("nrho-9-2", {"t_final": 157 * HOUR}, {"max_parts": 8}, {"max_parts": 8}),
    "halo200": ("l2-halo", {"t_final": 200 * HOUR}, {"max_parts": 8}, {"max_parts": 8}),
}


# ------------------------------------------------------------------------------------------------
# independent truth
# ------------------------------------------------------------------------------------------------
def rhs_for(problem):
    """``(X (N, n), U (N, m)) -> dX/dt`` in numpy for the models of the cases."""
    m = problem.model
    if m.name.startswith("cr3bp"):
        mu, a = problem.param("mu"), problem.param("a_max")
        planar = m.n_x == 4

        def rhs(X, U):
            if planar:
                x, y, vx, vy = X.T
                z = vz = np.zeros_like(x)
            else:
                x, y, z, vx, vy, vz = X.T
            r1 = np.sqrt((x + mu) ** 2 + y**2 + z**2)
            r2 = np.sqrt((x - 1 + mu) ** 2 + y**2 + z**2)
            ax = x + 2 * vy - (1 - mu) * (x + mu) / r1**3 - mu * (x - 1 + mu) / r2**3 + a * U[:, 0]
            ay = y - 2 * vx - (1 - mu) * y / r1**3 - mu * y / r2**3 + a * U[:, 1]
            if planar:
                return np.column_stack([vx, vy, ax, ay])
            az = -(1 - mu) * z / r1**3 - mu * z / r2**3 + a * U[:, 2]
            return np.column_stack([vx, vy, vz, ax, ay, az])
        return rhs
    if m.name == "vanderpol":
        mu, g = problem.param("mu"), problem.param("gain")

        def rhs(X, U):
            x1, x2 = X.T
            return np.column_stack([x2, mu * (1 - x1**2) * x2 - x1 + g * U[:, 0]])
        return rhs
    if m.name == "twobody":
        mu, a = problem.param("mu"), problem.param("a_max")

        def rhs(X, U):
            r = X[:, :3]
            rn = np.linalg.norm(r, axis=1, keepdims=True)
            return np.hstack([X[:, 3:], -mu * r / rn**3 + a * U])
        return rhs
    raise ValueError(f"no numpy truth for model {m.name}")


def initial_states(problem, N: int, rng) -> np.ndarray:
    S = problem.initial_set
    if S is None:
        return np.tile(problem.x0, (N, 1))
    Z = S if isinstance(S, Zonotope) else S.to_zonotope()
    nv = N // 2
    return np.vstack([Z.sample(nv, rng, mode="extreme"), Z.sample(N - nv, rng)])


def controls(problem, N: int, K: int, rng) -> np.ndarray:
    """(N, K, m): a third constant, a third bang-bang, a third uniform random, per grid step."""
    m = problem.model.n_u
    ball = problem.control_set.kind == "ball"
    laws = np.arange(N) % 3
    if ball:
        U = rng.standard_normal((N, K, m))
        U /= np.linalg.norm(U, axis=-1, keepdims=True)
        U[laws == 0] = U[laws == 0][:, :1]
        rad = rng.uniform(size=(N, K, 1)) ** (1.0 / m)
        U[laws == 2] *= rad[laws == 2]
    else:
        U = rng.choice([-1.0, 1.0], size=(N, K, m))
        U[laws == 0] = U[laws == 0][:, :1]
        U[laws == 2] = rng.uniform(-1, 1, size=(int((laws == 2).sum()), K, m))
    return U


def truth(problem, K: int, N: int, seed: int = 0):
    """States at the grid times (N, K+1, n) and at the step midpoints (N, K, n)."""
    rng = np.random.default_rng(seed)
    rhs = rhs_for(problem)
    X = initial_states(problem, N, rng)
    U = controls(problem, N, K, rng)
    n = X.shape[1]
    grid = problem.grid
    ends = np.empty((N, K + 1, n))
    mids = np.empty((N, K, n))
    ends[:, 0] = X
    for k in range(K):
        Uk = U[:, k]

        def f(t, y, Uk=Uk):
            return rhs(y.reshape(N, n), Uk).ravel()
        t0, t1 = float(grid[k]), float(grid[k + 1])
        sol = solve_ivp(f, (t0, t1), X.ravel(), method="DOP853", rtol=RTOL, atol=ATOL,
                        t_eval=[0.5 * (t0 + t1), t1])
        if not sol.success:
            raise RuntimeError(sol.message)
        mids[:, k] = sol.y[:, 0].reshape(N, n)
        X = sol.y[:, 1].reshape(N, n)
        ends[:, k + 1] = X
    return ends, mids


# ------------------------------------------------------------------------------------------------
# containment
# ------------------------------------------------------------------------------------------------
def check(S, P: np.ndarray, start=None):
    """The three-way verdicts (:class:`ocreach.sets.pz_witness.Classified`) of the points ``P``
    against the set enlarged by ``ABS_TOL (1 + |P|_inf)``: polynomial zonotopes by
    :func:`~ocreach.sets.pz_witness.classify` (warm-started from ``start``, the verdicts of the same
    trajectories at the previous grid time), zonotopes and their unions by
    :func:`~ocreach.sets.pz_witness.classify_zonotope`."""
    eps = ABS_TOL * (1.0 + float(np.abs(P).max()))
    if isinstance(S, (PolyZonotope, PZUnion)):
        return classify(S, P, eps, start=start)
    return classify_zonotope(S, P, eps)


def widths(S, D: np.ndarray, dims) -> np.ndarray:
    """Upper bounds of the set's width in the directions ``D`` (on ``dims``)."""
    from ocreach.sets.pz_exact import support_bounds

    parts = S.parts if isinstance(S, (PZUnion, ZonotopeUnion)) else [S]
    DD = np.vstack([D, -D])
    vals = []
    for p in parts:
        q = p.project(dims)
        if isinstance(q, PolyZonotope):
            vals.append(support_bounds(q, DD, tol=1e-3).upper)
        else:
            vals.append(q.support(DD))
    u = np.max(vals, axis=0)
    return u[: len(D)] + u[len(D):]


# ------------------------------------------------------------------------------------------------
def run(problem, method: str, opts: dict):
    t0 = time.perf_counter()
    try:
        res = ocreach.reach(problem, method, **opts)
        return res, time.perf_counter() - t0, None
    except SolverError as exc:
        if getattr(exc, "partial", None) is None:
            raise
        return exc.partial, time.perf_counter() - t0, " ".join(str(exc).split())[:300]


def check_method(res, ends, mids, tube_samples: int, pz_every: int, log) -> dict:
    """Escapes, undecided and points of the sets (every grid time; a polynomial-zonotope set in
    full at every ``pz_every``-th grid time and the last, against its zonotope enclosure at the
    others) and of the tubes (the step midpoints of the first ``tube_samples`` trajectories)."""
    Km = res.times.size - 1
    cnt = {"set_escapes": 0, "set_undecided": 0, "set_points": 0, "pz_times": 0,
           "enclosure_only_times": 0, "tube_escapes": 0, "tube_undecided": 0, "tube_points": 0,
           "escape_times": []}
    prev = None
    t0 = time.perf_counter()
    for k in range(Km + 1):
        S, P = res.sets[k], ends[:, k]
        full = not isinstance(S, (PolyZonotope, PZUnion)) or k % pz_every == 0 or k == Km
        if full:
            v = check(S, P, start=prev)
            prev = v if v.witness is not None else None
            cnt["pz_times"] += isinstance(S, (PolyZonotope, PZUnion))
        else:                       # the zonotope enclosure: an escape from it is an escape
            parts = S.parts if isinstance(S, PZUnion) else [S]
            v = check(ZonotopeUnion([p.to_zonotope() for p in parts]), P)
            cnt["enclosure_only_times"] += 1
        e, u = int(v.outside.sum()), int(v.undecided.sum())
        cnt["set_escapes"] += e
        cnt["set_undecided"] += u
        cnt["set_points"] += P.shape[0]
        if e:
            cnt["escape_times"].append(k)
            log(f"  ESCAPE: {e} of {P.shape[0]} points outside the set at grid index {k} "
                f"(t = {res.times[k]:.6g})")
        if k % 10 == 0 or k == Km:
            log(f"  sets: grid index {k}/{Km}, {cnt['set_escapes']} escapes, "
                f"{cnt['set_undecided']} undecided, {time.perf_counter() - t0:.0f} s")
    for k in range(min(Km, len(res.tubes or []))):
        P = mids[:tube_samples, k]
        v = check(res.tubes[k], P)
        e = int(v.outside.sum())
        cnt["tube_escapes"] += e
        cnt["tube_undecided"] += int(v.undecided.sum())
        cnt["tube_points"] += P.shape[0]
        if e:
            log(f"  ESCAPE: {e} step midpoints outside the tube of step {k}")
    cnt["check_s"] = time.perf_counter() - t0
    return cnt


def validate(name: str, samples: int, tube_samples: int, pz_every: int, log, methods=("poly", "taylor"),
             seed: int = 0) -> dict:
    pid, over, popts, topts = CASES[name]
    problem = ocreach.get_problem(pid, **over)
    out = {"case": name, "problem": pid, "overrides": over, "samples": samples,
           "tube_samples": min(samples, tube_samples), "pz_every": pz_every,
           "asked_steps": int(problem.grid.size - 1)}
    results = {}
    for method, opts in (("poly", popts), ("taylor", topts)):
        run(problem, method, opts)          # warm the compiled functions
        res, rt, fail = run(problem, method, opts)
        results[method] = res
        out[method] = {"options": opts, "runtime_s": rt, "reached_steps": int(res.times.size - 1),
                       "reached_t": float(res.times[-1]), "failure": fail,
                       "max_parts_used": res.meta.get("max_parts_used")}
        log(f"{name}: {method} reached {res.times.size - 1} of {problem.grid.size - 1} steps "
            f"in {rt:.2f} s")
    K = max(r.times.size - 1 for r in results.values())
    t0 = time.perf_counter()
    ends, mids = truth(problem, K, samples, seed)
    out["truth_runtime_s"] = time.perf_counter() - t0
    log(f"{name}: {samples} trajectories over {K} steps in {out['truth_runtime_s']:.1f} s")
    pos = list(problem.position_dims) if problem.position_dims else list(range(problem.model.n_x))
    D = np.random.default_rng(7).standard_normal((50, len(pos)))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    for method, res in results.items():
        if method not in methods:
            continue
        Km = res.times.size - 1
        entry = out[method]
        entry.update(check_method(res, ends, mids, tube_samples, pz_every, log))
        log(f"{name}: {method}: {entry['set_escapes']} escapes / {entry['set_undecided']} undecided "
            f"of {entry['set_points']} set points, {entry['tube_escapes']} escapes / "
            f"{entry['tube_undecided']} undecided of {entry['tube_points']} tube points "
            f"({entry['check_s']:.0f} s)")
        P = ends[:, Km][:, pos]
        wmc = (P @ D.T).max(axis=0) + (-P @ D.T).max(axis=0)
        r = widths(res.sets[Km], D, pos) / wmc
        entry["width_ratio_last"] = {"k": Km, "mean": float(r.mean()), "min": float(r.min()),
                                     "max": float(r.max())}
    Kc = min(r.times.size - 1 for r in results.values())
    P = ends[:, Kc][:, pos]
    wmc = (P @ D.T).max(axis=0) + (-P @ D.T).max(axis=0)
    out["common_k"] = Kc
    for method, res in results.items():
        r = widths(res.sets[Kc], D, pos) / wmc
        out[method]["width_ratio_common"] = {"mean": float(r.mean()), "min": float(r.min()),
                                             "max": float(r.max())}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default="vdp,dro,nrho24")
    ap.add_argument("--samples", type=int, default=10000)
    ap.add_argument("--tube-samples", type=int, default=2000)
    ap.add_argument("--pz-every", type=int, default=1,
                    help="check polynomial-zonotope sets in full at every N-th grid time and the "
                         "last (their zonotope enclosures at the others)")
    ap.add_argument("--methods", default="poly,taylor",
                    help="the methods to check (both always run: the width ratios compare them); "
                         "the others' entries of an earlier row of the case are kept")
    ap.add_argument("--out", default="out/poly_validation")
    args = ap.parse_args()
    outdir = Path(args.out)
    outdir.mkdir(parents=True, exist_ok=True)
    path = outdir / "summary.json"
    rows = json.loads(path.read_text()) if path.exists() else []

    def log(msg: str) -> None:
        print(msg, flush=True)

    for name in args.cases.split(","):
        if name not in CASES:
            raise SystemExit(f"--cases: unknown case {name!r}; known: {', '.join(CASES)}")
        methods = args.methods.split(",")
        row = validate(name, args.samples, args.tube_samples, args.pz_every, log, methods)
        old = next((r for r in rows if r.get("case") == name), {})
        for method in ("poly", "taylor"):
            if method in methods:
                row[method].update(date=time.strftime("%Y-%m-%d %H:%M"),
                                   load_average_1min=os.getloadavg()[0])
            elif method in old:
                row[method] = old[method]
        rows = [r for r in rows if r.get("case") != name] + [row]
        atomic_write_text(path, json_text(rows, indent=1))   # a row at a time
        log(json.dumps(jsonable(row), indent=1))


if __name__ == "__main__":
    main()
