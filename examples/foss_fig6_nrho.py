"""Foss Fig. 6 (NRHO Moon flyby, ephemeris model): STT sets with and without splitting, and why
order 2 fails.

    python examples/foss_fig6_nrho.py [--problem nrho-flyby] [--out docs/figures] [--extremals 1000]

1. Pointwise validity of the STT polynomial: the per-step polynomials ``dx_{k+1} = sum_j 1/j!
   Phi_k^(j)[dx_k, u_k]^j`` composed along the controls of 1000 Monte Carlo trajectories (no set,
   no reduction, no input-set approximation) against the true endpoints, for n = 1, 2, 3.
2. The same with ideal parts: the true states at ``t_s`` clustered (k-means, 1 .. 256 clusters),
   each cluster's samples composed about the ballistic reference from its centroid -- how many
   compact parts an exact splitting would need for the expansion to hold.
3. Set extent at every time: ``max_d (h(d) - d^T x_ref)`` over 64 position directions, for the STT
   runs in :data:`RUNS` (with and without ``split``), against the ``ode`` extremals and Monte Carlo
   endpoints, and the smallest margin ``min_d (h_upper(d) - max_truth(d))`` (negative: a true
   endpoint is certainly outside the set in direction d).  Lower and upper bounds by branch and
   bound (:func:`ocreach.sets.pz_exact.support_bounds`), per part for unions of at most
   :data:`EXACT_PARTS` parts; larger unions: upper = the parts' zonotope enclosures, lower = 256
   extreme samples per part.
4. Figure like Foss Fig. 6: x-y and y-z projections of the split order-1 sets with 100 extremals,
   and the extent ratio of every run against time.
Writes ``OUT/foss_fig6_<problem>.png`` and ``OUT/foss_fig6_<problem>.json``; with ``--x0 X,Y,Z,VX,VY,VZ``
(another x1, e.g. from ``examples/foss_flyby_sensitivity.py``) and/or ``--epoch`` the files are
``OUT/foss_fig6_<problem>_<tag>.*`` (``--tag``, default from x0).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.dynamics.flow import stt as stt_flow
from ocreach.errors import SolverError
from ocreach.fileio import atomic_write_text
from ocreach.geometry.directions import fibonacci_sphere
from ocreach.reach.plot import save_figure
from ocreach.reach.stt import STTReach, stt_polynomial
from ocreach.registry import get_problem
from ocreach.sets import PZUnion
from ocreach.sets.pz_exact import support_bounds

#: STT runs measured (name -> options); all with the problem's ball input as 10-generator zonotopes
#: (``ball_input="zonotope-coarse"``, passed explicitly so a change of the default does not change
#: the runs, see :data:`BALL_INPUT`)
BALL_INPUT = "zonotope-coarse"
RUNS = {
    "o2_h60": dict(order=2, h_max=60),
    "o2_h60_box64": dict(order=2, h_max=60, split="box", max_parts=64),
    "o2_h200_box64": dict(order=2, h_max=200, split="box", max_parts=64),
    "o1_h60": dict(order=1, h_max=60),
    "o1_h200": dict(order=1, h_max=200),
    "o1_h60_box16": dict(order=1, h_max=60, split="box", max_parts=16),
    "o1_h200_factor16": dict(order=1, h_max=200, split="factor", max_parts=16),
    "o1_h200_box16": dict(order=1, h_max=200, split="box", max_parts=16),
    "o1_h200_box64": dict(order=1, h_max=200, split="box", max_parts=64),
    "o1_h200_box16_keep45": dict(order=1, h_max=200, split="box", max_parts=16, split_keep=45),
    "o1_h200_box16_keep60": dict(order=1, h_max=200, split="box", max_parts=16, split_keep=60),
}
#: unions of at most this many parts get branch-and-bound support bounds per part (more: the
#: parts' zonotope enclosures and extreme samples, faster but a weaker lower bound)
EXACT_PARTS = 16
#: the run drawn in the figure
FIGURE_RUN = "o1_h200_box16"


def pointwise_errors(problem, mc, orders=(1, 2, 3)) -> dict:
    """Pointwise error / MC extent per time of the per-step STT polynomials (Foss Eq. 13) about
    the ballistic reference, composed along the MC control histories (no set, no reduction)."""
    U = np.asarray(mc.controls)
    K = problem.grid.size - 1
    out = {}
    for order in orders:
        ref = stt_flow(problem.model, problem.x0, np.zeros((K, problem.model.n_u)), problem.grid, order,
                       p=problem.params)
        dx = np.zeros((U.shape[0], problem.model.n_x))
        rel = []
        for k in range(K):
            dx = sum(stt_polynomial([ph[k] for ph in ref.phi], np.hstack([dx, U[:, k, :]])))
            true = np.asarray(mc.points[k + 1]) - ref.states[k + 1]
            ext = np.linalg.norm(true[:, :3], axis=1).max()
            rel.append(float(np.linalg.norm(dx[:, :3] - true[:, :3], axis=1).max() / ext))
        out[f"order{order}"] = rel
    return out


def partition_errors(problem, mc, t_split: float = 0.6, parts=(1, 4, 16, 64, 256), orders=(1, 2)) -> dict:
    """Pointwise error / MC extent of the STT polynomials composed from ``t_split`` about the
    references of k-means clusters of the true states there (ideal compact parts)."""
    from scipy.cluster.vq import kmeans2

    X = np.stack([np.asarray(P) for P in mc.points], axis=1)
    U = np.asarray(mc.controls)
    K, g = problem.grid.size - 1, problem.grid
    ks = int(np.argmin(np.abs(g - t_split)))
    ref = stt_flow(problem.model, problem.x0, np.zeros((K, problem.model.n_u)), g, 1, p=problem.params).states
    ext = np.array([np.linalg.norm(X[:, k, :3] - ref[k, :3], axis=1).max() for k in range(ks + 1, K + 1)])
    Z = X[:, ks]
    sd = Z.std(axis=0)
    out: dict = {"t_split": float(g[ks]), "times": g[ks + 1:].tolist()}
    for P in parts:
        if P == 1:
            lab, cen = np.zeros(len(Z), dtype=int), Z.mean(axis=0, keepdims=True)
        else:
            cen, lab = kmeans2(Z / sd, P, seed=1, minit="++")
            cen = cen * sd
        for order in orders:
            worst = np.zeros(K - ks)
            for j in range(P):
                idx = np.flatnonzero(lab == j)
                if idx.size == 0:
                    continue
                r = stt_flow(problem.model, cen[j], np.zeros((K - ks, problem.model.n_u)), g[ks:], order,
                             p=problem.params)
                dx = X[idx, ks] - cen[j]
                for i, k in enumerate(range(ks, K)):
                    dx = sum(stt_polynomial([ph[i] for ph in r.phi], np.hstack([dx, U[idx, k]])))
                    err = np.linalg.norm(dx[:, :3] - (X[idx, k + 1, :3] - r.states[i + 1, :3]), axis=1)
                    worst[i] = max(worst[i], float(err.max()))
            out[f"order{order}_parts{P}"] = (worst / ext).tolist()
    return out


def support_range(S, D: np.ndarray, rng) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds of the support of a PZ or a union of PZs (position projection)."""
    if isinstance(S, PZUnion) and len(S.parts) <= EXACT_PARTS:
        sbs = [support_bounds(p.project([0, 1, 2]), D, tol=1e-3) for p in S.parts]
        return np.max([b.lower for b in sbs], axis=0), np.max([b.upper for b in sbs], axis=0)
    if isinstance(S, PZUnion):
        parts = [p.project([0, 1, 2]) for p in S.parts]
        hi = np.max([np.atleast_1d(p.support(D)) for p in parts], axis=0)
        lo = np.max([(p.sample(256, rng, mode="extreme") @ D.T).max(axis=0) for p in parts], axis=0)
        return lo, hi
    P = S.project([0, 1, 2])
    if P.n_generators == 0:
        return D @ P.c, D @ P.c
    sb = support_bounds(P, D, tol=1e-3)
    return sb.lower, sb.upper


def measure(problem, opts: dict, D: np.ndarray, truth: list, ref: np.ndarray,
            divergence_factor: float = 1e30) -> dict:
    """One STT run (warm: the second of two), its runtime and its extents / margins per time."""
    m = STTReach(**{"ball_input": BALL_INPUT, **opts}, divergence_factor=divergence_factor)
    rec: dict = {"options": opts}
    try:
        m.solve(problem)  # warm-up (compiled code, caches)
        t0, c0 = time.perf_counter(), time.process_time()
        res = m.solve(problem)
        rec["runtime_s"], rec["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        sets = res.sets
        rec["parts"] = list(map(int, res.meta["parts"]))
        if "truncation_error" in res.meta:
            rec["truncation_error"] = np.asarray(res.meta["truncation_error"]).tolist()
    except SolverError as exc:
        rec["error"] = str(exc)
        return rec
    rng = np.random.default_rng(0)
    lo_r, hi_r, margin = [], [], []
    for k in range(1, len(sets)):
        lo, hi = support_range(sets[k], D, rng)
        c = D @ ref[k, :3]
        ext = float(np.max(truth[k] - c))
        with np.errstate(invalid="ignore", over="ignore"):
            lo_r.append(float(np.max(lo - c)) / ext)
            hi_r.append(float(np.max(hi - c)) / ext)
            margin.append(float(np.min(hi - truth[k])) / ext)
    rec["extent_ratio_lower"], rec["extent_ratio_upper"], rec["margin_over_extent"] = lo_r, hi_r, margin
    rec["sets"] = sets
    return rec


def truth_data(p, extremals: int = 1000, mc_samples: int = 1000, directions: int = 64) -> dict:
    """The truth the STT sets are measured against: ``mc_samples`` Monte Carlo endpoints (seed 3)
    and ``extremals`` ``ode`` extremals per time; ``D`` (Fibonacci directions in position space),
    ``ref`` (ballistic reference states), ``support[k]`` = max over the true points of ``D x`` at
    time k, and the extents ``max_d (h(d) - d^T x_ref)`` of the ode and MC points per time."""
    mc = ocreach.reach(p, "mc", samples=mc_samples, seed=3)
    ode = ocreach.reach(p, "ode", samples=extremals)
    D = fibonacci_sphere(directions)
    ref = stt_flow(p.model, p.x0, np.zeros((p.n_segments, p.model.n_u)), p.grid, 1, p=p.params).states

    def extent(res):
        return [float(np.max((np.asarray(P)[:, :3] - ref[k, :3]) @ D.T)) for k, P in enumerate(res.points)]

    pts = [np.vstack([np.asarray(mc.points[k])[:, :3], np.asarray(ode.points[k])[:, :3]]) for k in range(p.grid.size)]
    return {"mc": mc, "ode": ode, "D": D, "ref": ref, "support": [(P @ D.T).max(axis=0) for P in pts],
            "ode_extent": extent(ode), "mc_extent": extent(mc)}


def parse_x0(text: str) -> list[float]:
    """``"0.91,-0.01,0.16,0.03,-0.08,0.01"`` (or a JSON list) -> 6 floats (checked by the problem)."""
    return [float(v) for v in text.strip().strip("[]").split(",") if v.strip()]


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problem", default="nrho-flyby")
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--extremals", type=int, default=1000)
    ap.add_argument("--runs", default="", help="comma-separated names of RUNS (default: all)")
    ap.add_argument("--x0", default=None, help="initial state X,Y,Z,VX,VY,VZ (DU, DU/TU; default the problem's)")
    ap.add_argument("--epoch", default=None, help="TDB epoch of t = 0 (default the problem's)")
    ap.add_argument("--tag", default=None, help="file name suffix with --x0 / --epoch (default from x0)")
    ap.add_argument("--no-partition", action="store_true", help="skip the ideal-parts measurement")
    a = ap.parse_args(argv)
    out = Path(a.out)
    overrides = {k: v for k, v in (("x0", None if a.x0 is None else parse_x0(a.x0)), ("epoch", a.epoch))
                 if v is not None}
    p = get_problem(a.problem, **overrides)
    stem = f"foss_fig6_{p.id}"
    if overrides:
        stem += "_" + (a.tag or "x0_" + "_".join(f"{v:.4f}" for v in p.x0))
    tr = truth_data(p, a.extremals)
    mc, ode, D, ref, truth_support = tr["mc"], tr["ode"], tr["D"], tr["ref"], tr["support"]
    report: dict = {"problem": p.id, "x0": p.x0.tolist(), "epoch": p.extra.get("epoch"),
                    "times": p.grid.tolist(), "load_average": os.getloadavg(),
                    "blas_threads": {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")},
                    "pointwise_err_over_extent": pointwise_errors(p, mc)}
    if not a.no_partition:
        report["ideal_parts_err_over_extent"] = partition_errors(p, mc)
    report["ode_extent"], report["mc_extent"] = tr["ode_extent"], tr["mc_extent"]
    runs = {}
    for name, opts in RUNS.items():
        if a.runs and name not in a.runs.split(","):
            continue
        runs[name] = measure(p, opts, D, truth_support, ref)
        r = runs[name]
        print(name, "error" if "error" in r else f"{r['runtime_s']:.2f} s", "parts", r.get("parts", [0])[-1],
              "ratio", " ".join(f"{v:.3g}" for v in r.get("extent_ratio_upper", [])[1::2]),
              "margin", " ".join(f"{v:.2f}" for v in r.get("margin_over_extent", [])[1::2]))
    report["runs"] = {k: {kk: vv for kk, vv in v.items() if kk != "sets"} for k, v in runs.items()}
    fig_run = FIGURE_RUN if FIGURE_RUN in runs else next(iter(runs))
    fig_sets = runs[fig_run]["sets"]
    # figure like Foss Fig. 6
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(17, 5))
    traj = np.stack([np.asarray(P)[:100] for P in ode.points], axis=1)
    for ax, dims in zip(axes[:2], ((0, 1), (1, 2))):
        for tr in traj:
            ax.plot(tr[:, dims[0]], tr[:, dims[1]], color="0.6", lw=0.4)
        for k, S in enumerate(fig_sets):
            if k == 0 or S.n_generators == 0:
                continue
            for i, poly in enumerate(S.outline(list(dims), pieces=64)):
                ax.fill(poly[:, 0], poly[:, 1], alpha=0.25, color="tab:blue", lw=0.3,
                        label=f"stt {fig_run} (parts' outlines)" if k == 1 and i == 0 else None)
        ax.set_xlabel("xyz"[dims[0]] + " [DU]")
        ax.set_ylabel("xyz"[dims[1]] + " [DU]")
        ax.grid(alpha=0.3)
        ax.axis("equal")
    axes[0].legend(fontsize=8)
    ax = axes[2]
    for name, r in runs.items():
        if "extent_ratio_upper" in r:
            ax.semilogy(p.grid[1:], np.clip(r["extent_ratio_upper"], 1e-3, 1e6), marker=".", lw=1, label=name)
    ax.axhline(1.5, color="k", ls="--", lw=0.8)
    ax.set_ylim(0.8, 1e3)
    ax.set_xlabel("t [TU]")
    ax.set_ylabel("STT extent / max(ode, mc) extent")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    start = "" if not overrides else f" (x0 = {np.array2string(p.x0, precision=4, separator=', ')}, epoch {p.extra['epoch']})"
    fig.suptitle(f"{p.id}{start}: STT sets and 100 ode extremals, t = 0..{p.grid[-1]:g} TU")
    fig.tight_layout()
    save_figure(fig, out / f"{stem}.png", dpi=130)
    atomic_write_text(out / f"{stem}.json", json.dumps(report, indent=1))
    for key in ("pointwise_err_over_extent", "ideal_parts_err_over_extent"):
        for k2, v2 in report.get(key, {}).items():
            if isinstance(v2, list):
                print(key, k2, " ".join(f"{v:.3g}" for v in v2[1::2]))
    return report


if __name__ == "__main__":
    main()
