"""Patel & Subbarao, set-based reachability: Figs. 2, 4, 5, 6 and Table 1 with the *sound* zonotope
methods ``taylor`` (Method 1) and ``sdc`` (Method 2), checked against Monte Carlo truth.

For every case the script runs the method, and where the enclosure cannot be continued (the
remainder loop cannot close within the part budget) it keeps the sets computed so far
(``SolverError.partial``) and reports the time it reached.  Truth: ``--samples`` trajectories
(default 10,000) from the initial set's vertices (half) and uniform inside (half), with the
Monte Carlo control laws of ``ocreach.reach.mc`` (random, constant and bang-bang thrust),
integrated by the project's DOP853 batch integrator (``ocreach.dynamics.flow.propagate``, rtol 1e-11) on a
grid refined by the segment midpoints; every endpoint must lie in the set at its grid time, the
midpoints of the first ``TUBE_SAMPLES`` (2,000) trajectories in their step's time-interval set
(scaled gauge <= 1 + 1e-9); so must the boundary points of ``ode`` (PMP extremals from the
initial set's boundary) at every grid time.  Tightness: the ratio of the
set's width to the samples' width in 50 random position directions, and of the position volumes.

    python examples/patel_subbarao_sets.py [--samples 10000] [--out out/patel_subbarao_sets]
        [--cases fig2,fig4,fig6,table1] [--quick]

Figures: ``fig2_l2_halo_taylor.png``, ``fig4_nrho_taylor_vs_sdc.png``, ``fig5_nrho_volume.png``,
``fig6_nrho_sdc_orbit.png``; table and numbers: ``summary.md`` and ``summary.json`` (the
numbers quoted in ``docs/validation/sound-zonotope.md``).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.compare import position_volume
from ocreach.dynamics.flow import propagate
from ocreach.errors import SolverError
from ocreach.fileio import atomic_write_text, jsonable
from ocreach.reach.mc import sample_controls
from ocreach.reach.plot import save_figure
from ocreach.registry import get_problem
from ocreach.sets.union import union_gauge
from ocreach.sets.zonotope import Zonotope

HOUR = 3600.0 / 375200.0
PAPER_TABLE1 = {200: 3.443, 300: 5.103}
#: samples checked against the time-interval sets (every step midpoint); all are checked at grid times
TUBE_SAMPLES = 2000


def run(problem, method: str, **opts):
    """``(result, runtime, failure message or None)``; a failure keeps the partial result."""
    t0 = time.perf_counter()
    try:
        res = ocreach.reach(problem, method, **opts)
        return res, time.perf_counter() - t0, None
    except SolverError as exc:
        if getattr(exc, "partial", None) is None:
            raise
        return exc.partial, time.perf_counter() - t0, str(exc)


def truth(problem, samples: int, seed: int, K: int):
    """Endpoints (N, K+1, n) on the first ``K`` grid segments and midpoints (N, K, n)."""
    rng = np.random.default_rng(seed)
    Z = problem.initial_set if problem.initial_set is not None else Zonotope(problem.x0)
    nv = samples // 2
    X0 = (np.vstack([Z.sample(nv, rng, "extreme"), Z.sample(samples - nv, rng)])
          if Z.n_generators else np.tile(Z.c, (samples, 1)))
    sub = problem.__class__(**{**problem.__dict__, "grid": problem.grid[: K + 1]})
    u, _ = sample_controls(sub, samples, rng, (0.4, 0.2, 0.4))
    g = problem.grid[: K + 1]
    fine = np.empty(2 * K + 1)
    fine[0::2] = g
    fine[1::2] = 0.5 * (g[:-1] + g[1:])
    traj = propagate(problem.model, X0, np.repeat(u, 2, axis=1), fine, p=problem.params,
                     rtol=1e-11, atol=1e-13)
    return traj[:, 0::2], traj[:, 1::2]


def extremal_check(problem, res, K: int) -> dict:
    """Boundary points of ``ode`` (PMP extremals from the initial set's boundary, admissible
    trajectories of the same model) on the first ``K`` segments: each must lie in the set at its
    grid time.  ``ffoe`` needs an ellipsoidal initial set, so it is not used for these problems."""
    from ocreach.errors import OcreachError

    sub = problem.__class__(**{**problem.__dict__, "grid": problem.grid[: K + 1]})
    t0 = time.perf_counter()
    try:
        ext = ocreach.reach(sub, "ode")
    except OcreachError as exc:
        return {"extremals": f"ode failed: {str(exc)[:200]}"}
    worst, escapes, n = 0.0, 0, 0
    for k in range(ext.times.size):
        P = ext.points_at(k)
        gk = union_gauge(res.sets[k], P)
        worst = max(worst, float(gk.max()))
        escapes += int(np.sum(gk > 1 + 1e-9))
        n += len(P)
    return {"extremal_points": n, "extremal_escapes": escapes, "max_gauge_extremals": worst,
            "extremals_runtime_s": time.perf_counter() - t0}


def check(problem, res, samples: int, seed: int = 0) -> dict:
    """MC containment at every grid time and step midpoint, tightness at the last time."""
    K = res.times.size - 1
    if K == 0:
        return {"samples": samples, "escapes": 0, "checked_times": 0}
    ends, mids = truth(problem, samples, seed, K)
    worst, escapes = 0.0, 0
    for k in range(K + 1):
        gk = union_gauge(res.sets[k], ends[:, k])
        worst = max(worst, float(gk.max()))
        escapes += int(np.sum(gk > 1 + 1e-9))
    worst_tube = 0.0
    if res.tubes is not None:
        for k in range(K):
            gk = union_gauge(res.tubes[k], mids[: TUBE_SAMPLES, k])
            worst_tube = max(worst_tube, float(gk.max()))
            escapes += int(np.sum(gk > 1 + 1e-9))
    pos = list(problem.position_dims)
    D = np.random.default_rng(7).standard_normal((50, len(pos)))
    D /= np.linalg.norm(D, axis=1, keepdims=True)
    S = res.sets[-1].project(pos)
    P = ends[:, -1][:, pos]
    w_set = S.support(D) + S.support(-D)
    w_mc = (P @ D.T).max(axis=0) + (-P @ D.T).max(axis=0)
    ratio = w_set / w_mc
    from scipy.spatial import ConvexHull

    v_set = position_volume(res, problem)
    v_mc = float(ConvexHull(P).volume)
    return {"samples": samples, "escapes": escapes, "tube_samples": min(samples, TUBE_SAMPLES),
            "max_gauge_sets": worst, "max_gauge_tubes": worst_tube,
            "checked_times": K + 1, "width_ratio_mean": float(ratio.mean()),
            "width_ratio_min": float(ratio.min()), "width_ratio_max": float(ratio.max()),
            "volume_ratio": v_set / v_mc if v_mc > 0 else float("nan"),
            **extremal_check(problem, res, K)}


def volumes(problem, res) -> np.ndarray:
    return np.array([position_volume(res, problem, k) for k in range(res.times.size)])


def plot3d(ax, problem, res, every: int, color: str, label: str) -> None:
    pos = list(problem.position_dims)
    rng = np.random.default_rng(0)
    for k in range(0, res.times.size, every):
        pts = res.sets[k].project(pos).sample(300, rng, mode="extreme")
        ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=1, color=color, alpha=0.3,
                   label=label if k == 0 else None)
    c = np.array([s.interval_hull().center for s in res.sets])[:, pos]
    ax.plot(c[:, 0], c[:, 1], c[:, 2], "k-", lw=0.8)
    ax.set_xlabel("x [DU]")
    ax.set_ylabel("y [DU]")
    ax.set_zlabel("z [DU]")


def single3d(path: Path, problem, res, color: str, label: str, title: str) -> None:
    """One 3-D position projection figure (Figs. 2 and 6)."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    plot3d(ax, problem, res, every=6, color=color, label=label)
    ax.set_title(title)
    save_figure(fig, path)


def entry(problem, name, res, rt, fail, samples) -> dict:
    out = {"problem": problem.id, "method": name, "runtime_s": rt,
           "horizon_requested_h": float(problem.grid[-1] / HOUR) if problem.id != "earth-mars" else None,
           "reached_t": float(res.times[-1]), "steps": int(res.times.size - 1),
           "max_parts": int(max(res.meta["steps"]["parts"], default=1)),
           "max_substeps": int(max(res.meta["steps"].get("substeps", [1]), default=1)),
           "failure": fail}
    if problem.units is not None and problem.id != "earth-mars":
        out["reached_h"] = float(res.times[-1] / HOUR)
    if problem.id == "earth-mars":
        out["reached_days"] = float(res.times[-1] / problem.extra["day_TU"])
    if samples:
        out.update(check(problem, res, samples))
    return out


def main() -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=10_000)
    ap.add_argument("--out", default="out/patel_subbarao_sets")
    ap.add_argument("--cases", default="fig2,fig4,fig6,table1")
    ap.add_argument("--quick", action="store_true", help="short horizons, 1,000 samples")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    samples = 1000 if args.quick else args.samples
    cases = set(args.cases.split(","))
    rows: list[dict] = []
    tay_opts = {"max_parts": 8}

    if "fig4" in cases:  # NRHO 76 h: Method 1 vs SDC, volume (Fig. 5)
        p = get_problem("nrho-9-2", t_final=(12 if args.quick else 76) * HOUR)
        res = {}
        for name in ("taylor", "sdc"):
            r, rt, fail = run(p, name, **tay_opts)
            res[name] = r
            rows.append(entry(p, name, r, rt, fail, samples))
            print(json.dumps(jsonable(rows[-1])))
        fig = plt.figure(figsize=(12, 5))
        for i, (name, col) in enumerate((("taylor", "tab:red"), ("sdc", "tab:blue"))):
            ax = fig.add_subplot(1, 2, i + 1, projection="3d")
            plot3d(ax, p, res[name], every=6, color=col, label=name)
            ax.set_title(f"nrho-9-2, {name}: {res[name].times[-1] / HOUR:.0f} h")
        save_figure(fig, out / "fig4_nrho_taylor_vs_sdc.png")
        fig, ax = plt.subplots(figsize=(6, 4))
        for name, col in (("taylor", "tab:red"), ("sdc", "tab:blue")):
            ax.semilogy(res[name].times / HOUR, volumes(p, res[name]), color=col, label=name)
        ax.set_xlabel("time [h]")
        ax.set_ylabel("position volume [DU^3]")
        ax.grid(alpha=0.3)
        ax.legend()
        ax.set_title("nrho-9-2: guaranteed position-space volume (Fig. 5)")
        save_figure(fig, out / "fig5_nrho_volume.png")

    if "fig2" in cases:  # L2 halo, Method 1
        p = get_problem("l2-halo", t_final=(12 if args.quick else 200) * HOUR)
        r, rt, fail = run(p, "taylor", **tay_opts)
        rows.append(entry(p, "taylor", r, rt, fail, samples))
        print(json.dumps(jsonable(rows[-1])))
        single3d(out / "fig2_l2_halo_taylor.png", p, r, "tab:red", "taylor",
                 f"l2-halo, taylor: {r.times[-1] / HOUR:.0f} h (Fig. 2)")

    if "fig6" in cases:  # SDC over the full NRHO orbit
        p0 = get_problem("nrho-9-2")
        # the orbit period rounded down to whole 1 h steps (the grid needs a multiple of dt)
        hours = 24 if args.quick else np.floor(p0.extra["period_TU"] / HOUR)
        p = get_problem("nrho-9-2", t_final=hours * HOUR)
        r, rt, fail = run(p, "sdc", **tay_opts)
        rows.append(entry(p, "sdc", r, rt, fail, 0))
        print(json.dumps(jsonable(rows[-1])))
        single3d(out / "fig6_nrho_sdc_orbit.png", p, r, "tab:blue", "sdc",
                 f"nrho-9-2, sdc: {r.times[-1] / HOUR:.0f} h of the {p.grid[-1] / HOUR:.0f} h orbit")

    if "table1" in cases:  # Earth-Mars runtimes
        for days in ((20,) if args.quick else (200, 300)):
            p = get_problem("earth-mars", t_days=float(days))
            for name in ("taylor", "sdc"):
                r, rt, fail = run(p, name, **tay_opts)
                e = entry(p, name, r, rt, fail, samples if (days == 200 and name == "taylor") or args.quick else 0)
                e["paper_runtime_s"] = PAPER_TABLE1.get(days)
                rows.append(e)
                print(json.dumps(jsonable(rows[-1])))

    lines = [("| problem | method | reached | requested | runtime [s] | parts | escapes / samples | "
              "ode extremals: escapes / points | width ratio mean (min..max) | volume ratio |"),
             "|" + "---|" * 10]
    for e in rows:
        reached = (f"{e['reached_days']:.0f} d" if "reached_days" in e else f"{e.get('reached_h', 0):.1f} h")
        lines.append(f"| {e['problem']} | {e['method']} | {reached} | "
                     f"{'ok' if e['failure'] is None else 'stopped'} | {e['runtime_s']:.2f} | {e['max_parts']} | "
                     f"{e.get('escapes', '-')} / {e.get('samples', '-')} | "
                     f"{e.get('extremal_escapes', '-')} / {e.get('extremal_points', '-')} | "
                     f"{e.get('width_ratio_mean', float('nan')):.3g} ({e.get('width_ratio_min', float('nan')):.3g}.."
                     f"{e.get('width_ratio_max', float('nan')):.3g}) | {e.get('volume_ratio', float('nan')):.3g} |")
    text = "\n".join(lines)
    print(text)
    atomic_write_text(out / "summary.md", text + "\n\n" + "\n".join(
        f"- {e['problem']} {e['method']}: {e['failure']}" for e in rows if e["failure"]) + "\n")
    atomic_write_text(out / "summary.json", json.dumps(jsonable(rows), indent=2))


if __name__ == "__main__":
    main()
