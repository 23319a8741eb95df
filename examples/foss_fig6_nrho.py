"""Foss Fig. 6 (NRHO Moon flyby, ephemeris model) with the exact set queries, and why order 2 fails.

    python examples/foss_fig6_nrho.py [--problem nrho-flyby] [--out docs/figures] [--extremals 1000]

1. Pointwise validity of the STT polynomial: the per-step polynomials ``dx_{k+1} = sum_j 1/j!
   Phi_k^(j)[dx_k, u_k]^j`` composed along the controls of 1000 Monte Carlo trajectories (no set,
   no reduction, no input-set approximation) against the true endpoints, for n = 1, 2, 3.
2. Set extent at every time: ``max_d (h(d) - d^T x_ref)`` over 64 position directions, for the STT
   sets (upper and lower bounds by branch and bound, :func:`ocreach.sets.pz_exact.support_bounds`),
   the ``ode`` extremals and Monte Carlo endpoints.
3. Figure like Foss Fig. 6: x-y and y-z projections of the STT sets (outer hull polygons of the
   upper support bounds) with 100 of the extremals.
Writes ``OUT/foss_fig6_<problem>.png`` and ``OUT/foss_fig6_<problem>.json``.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import ocreach
from ocreach.errors import SolverError
from ocreach.plot import save_figure
from ocreach.problem import get_problem
from ocreach.reach.result import atomic_write_text
from ocreach.reach.stt import STTReach, stt_polynomial
from ocreach.sets.pz_exact import hull_polygons, support_bounds


def sphere_directions(m: int, seed: int = 0) -> np.ndarray:
    """Quasi-uniform unit vectors in 3-D (Fibonacci sphere)."""
    i = np.arange(m) + 0.5
    phi = np.arccos(1 - 2 * i / m)
    th = np.pi * (1 + 5 ** 0.5) * i
    return np.c_[np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)]


def pointwise_errors(problem, mc, orders=(1, 2, 3)) -> dict:
    U = np.asarray(mc.controls)
    out = {}
    for order in orders:
        m = STTReach(order=order, h_max=60)
        try:
            m.solve(problem)
        except SolverError:
            pass  # only the STTs along the reference are needed (m._ref)
        ref = m._ref
        dx = np.zeros((U.shape[0], problem.model.n_x))
        rel = []
        for k in range(problem.grid.size - 1):
            dx = sum(stt_polynomial([ph[k] for ph in ref.phi], np.hstack([dx, U[:, k, :]])))
            true = np.asarray(mc.points[k + 1]) - ref.states[k + 1]
            ext = np.linalg.norm(true[:, :3], axis=1).max()
            rel.append(float(np.linalg.norm(dx[:, :3] - true[:, :3], axis=1).max() / ext))
        out[f"order{order}"] = rel
    return out


def extents(sets, ref, D) -> tuple[list, list]:
    lo, hi = [], []
    for k, S in enumerate(sets):
        P = S.project([0, 1, 2])
        if P.n_generators == 0:
            lo.append(0.0)
            hi.append(0.0)
            continue
        sb = support_bounds(P, D, tol=1e-3)
        c = D @ ref[k, :3]
        lo.append(float(np.max(sb.lower - c)))
        hi.append(float(np.max(sb.upper - c)))
    return lo, hi


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problem", default="nrho-flyby")
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--extremals", type=int, default=1000)
    a = ap.parse_args(argv)
    out = Path(a.out)
    p = get_problem(a.problem)
    mc = ocreach.reach(p, "mc", samples=1000, seed=3)
    ode = ocreach.reach(p, "ode", samples=a.extremals)
    report: dict = {"problem": p.id, "times": p.grid.tolist(), "pointwise_err_over_extent": pointwise_errors(p, mc)}
    D = sphere_directions(64)
    ref = None
    for tag, opts in {"order1_ball": dict(order=1, input_set="ball"), "order1_box": dict(order=1, input_set="box"),
                      "order2_ball": dict(order=2, input_set="ball")}.items():
        m = STTReach(h_max=60, **opts)
        try:
            res = m.solve(p)
            sets = res.sets
            report[f"{tag}_runtime_s"] = float(sum(res.meta["runtime"].values()))
        except SolverError as exc:
            sets = None
            report[f"{tag}_error"] = str(exc)
        ref = m._ref.states
        if sets is not None:
            lo, hi = extents(sets, ref, D)
            report[f"{tag}_extent_lower"], report[f"{tag}_extent_upper"] = lo, hi
            if tag == "order1_ball":
                fig_sets = sets
    for tag, res in (("ode", ode), ("mc", mc)):
        report[f"{tag}_extent"] = [float(np.max((np.asarray(P)[:, :3] - ref[k, :3]) @ D.T)) if k else 0.0
                                   for k, P in enumerate(res.points)]
    ex = np.maximum(np.asarray(report["ode_extent"]), np.asarray(report["mc_extent"]))
    for tag in ("order1_ball", "order1_box", "order2_ball"):
        if f"{tag}_extent_upper" in report:
            with np.errstate(invalid="ignore", divide="ignore"):
                report[f"{tag}_ratio_upper"] = (np.asarray(report[f"{tag}_extent_upper"]) / ex).tolist()
                report[f"{tag}_ratio_lower"] = (np.asarray(report[f"{tag}_extent_lower"]) / ex).tolist()
    # figure like Foss Fig. 6
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 5))
    traj = np.stack([np.asarray(P)[:100] for P in ode.points], axis=1)
    for ax, dims in zip(axes, ((0, 1), (1, 2))):
        for tr in traj:
            ax.plot(tr[:, dims[0]], tr[:, dims[1]], color="0.6", lw=0.4)
        for k, S in enumerate(fig_sets):
            if k == 0 or S.n_generators == 0:
                continue
            _, outer, _ = hull_polygons(S.project(list(dims)), (0, 1), n_dirs=64)
            ax.fill(outer[:, 0], outer[:, 1], alpha=0.35, color="tab:blue", lw=0.5,
                    label="stt n=1 (ball), hull of upper bounds" if k == 1 else None)
        ax.set_xlabel("xyz"[dims[0]] + " [DU]")
        ax.set_ylabel("xyz"[dims[1]] + " [DU]")
        ax.grid(alpha=0.3)
        ax.axis("equal")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{p.id}: STT sets (n = 1, h_max = 60) and 100 ode extremals, t = 0..{p.grid[-1]:g} TU")
    fig.tight_layout()
    save_figure(fig, out / f"foss_fig6_{p.id}.png", dpi=130)
    atomic_write_text(out / f"foss_fig6_{p.id}.json", json.dumps(report, indent=1))
    for key, val in report.items():
        if isinstance(val, list):
            print(key, " ".join(f"{v:.3g}" for v in val[::2]))
        elif isinstance(val, dict):
            for k2, v2 in val.items():
                print(key, k2, " ".join(f"{v:.3g}" for v in v2[1::2]))
        else:
            print(key, val)
    return report


if __name__ == "__main__":
    main()
