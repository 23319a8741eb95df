"""Patel & Scheeres (2022) cases 1-5 with ffoe and ole, figures like the paper's Fig. 1-11, and the
100-direction validation of ffoe / ole / bvp on the Foss DRO against a direct transcription.

    python examples/patel_scheeres_cases.py                 # cases 1-5 -> docs/figures/ps_fig*.png
    python examples/patel_scheeres_cases.py --dro           # DRO validation table (slow: ~10 min)
    python examples/patel_scheeres_cases.py --cases 1,2 --samples 50

Positions are plotted in km, Earth-centred ECLIPJ2000 axes (the paper's frame); Earth and Moon are
drawn (Moon at the final time, with its path over the span).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ocreach.reach.base import reach
from ocreach.reach.plot import save_figure
from ocreach.registry import get_problem

ROOT = Path(__file__).resolve().parents[1]
R_EARTH_KM, R_MOON_KM = 6378.137, 1737.4
CASES = {1: "elliptic-earth", 2: "lunar-flyby", 3: "lunar-flyby-backward", 4: "lunar-flyby-uncertain",
         5: "lunar-flyby-backward-uncertain"}


def _km(prob, arr):
    return np.asarray(arr)[..., :3] * prob.units.length / 1e3


def _moon(prob, k=None):
    eph = prob.model.cache["ephemeris"]
    t = prob.grid * prob.units.time
    pos = eph.position("moon", t, "earth", frame="eclipj2000")
    return pos if k is None else pos[k]


def _bodies(ax, prob, dims=(0, 1), moon=True, earth=True):
    if earth:
        ax.add_patch(plt.Circle((0, 0), R_EARTH_KM * 3, color="tab:blue", zorder=5))
        ax.annotate("Earth", (0, 0), xytext=(6, 6), textcoords="offset points")
    if moon:
        path = _moon(prob)
        ax.plot(path[:, dims[0]], path[:, dims[1]], ":", color="0.5", lw=1, label="Moon path")
        mk = path[-1]
        ax.add_patch(plt.Circle((mk[dims[0]], mk[dims[1]]), R_MOON_KM * 3, color="0.4", zorder=5))
        ax.annotate("Moon (t_f)", (mk[dims[0]], mk[dims[1]]), xytext=(6, -12), textcoords="offset points")


def _final_cloud(ax, prob, res, label, color, dims=(0, 1), k=-1):
    pts = _km(prob, res.trajectories[:, k])
    ax.scatter(pts[:, dims[0]], pts[:, dims[1]], s=8, color=color, label=label, zorder=4)


def _save(fig, out: Path, name: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for ax in fig.axes:  # km-scale ticks: scientific offsets instead of overlapping 6-digit labels
        if ax.name == "rectilinear":
            ax.ticklabel_format(style="sci", scilimits=(-3, 4), useMathText=True)
    fig.tight_layout()
    save_figure(fig, out / name, dpi=130)
    print("wrote", out / name)


def _nominal(prob):
    from ocreach.dynamics.flow import propagate

    return propagate(prob.model, prob.x0, np.zeros((prob.n_segments, prob.model.n_u)), prob.grid,
                     p=prob.params)


def run_case(case: int, samples: int, out: Path) -> dict:
    prob = get_problem(CASES[case])
    reach(prob, "ffoe", samples=4)  # compile / warm caches
    t0 = time.perf_counter()
    ffoe = reach(prob, "ffoe", samples=samples)
    t_ffoe = time.perf_counter() - t0
    t0 = time.perf_counter()
    ole = reach(prob, "ole", samples=samples)
    t_ole = time.perf_counter() - t0
    nom = _km(prob, _nominal(prob))
    dirs = ffoe.meta["directions"]
    gap_km = (ole.meta["cost"] - ffoe.meta["cost"]) * prob.units.length / 1e3
    info = {"case": case, "problem": prob.id, "ffoe_s": t_ffoe, "ole_s": t_ole,
            "gap_km_max": float(gap_km.max()), "gap_km_median": float(np.median(gap_km)),
            "ole_iter_max": int(ole.meta["iterations"].max()),
            "ole_iter_median": float(np.median(ole.meta["iterations"])),
            "ole_converged": int(ole.meta["converged"].sum()), "samples": samples,
            "support_km_median": float(np.median((ole.meta["cost"] - dirs @ _nominal(prob)[-1])
                                                 * prob.units.length / 1e3))}
    fig_no = {1: [1], 2: [2, 3, 4, 5], 3: [6], 4: [7, 8], 5: [9, 10, 11]}[case]

    # final reachable-set projections, FFOE against OLE (Fig. 1, 2, 6, 8, 10)
    main = {1: 1, 2: 2, 3: 6, 4: 8, 5: 10}[case]
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    for ax, dims in zip(axes, [(0, 1), (0, 2)]):
        _final_cloud(ax, prob, ffoe, "FFOE", "tab:orange", dims)
        _final_cloud(ax, prob, ole, "OLE", "tab:green", dims)
        ax.plot(nom[-1, dims[0]], nom[-1, dims[1]], "k+", ms=12, label="unpowered")
        ax.set_xlabel("xyz"[dims[0]] + " [km]")
        ax.set_ylabel("xyz"[dims[1]] + " [km]")
        ax.set_aspect("equal", adjustable="datalim")
        ax.legend(fontsize=8)
    fig.suptitle(f"Case {case} ({prob.id}): {'controllable' if prob.backward else 'reachable'} set at "
                 f"t_f, {samples} directions; FFOE {t_ffoe:.2f} s, OLE {t_ole:.2f} s")
    _save(fig, out, f"ps_fig{main:02d}_{prob.id}.png")

    # whole trajectories with Earth and Moon (Fig. 3 for case 2, also the context of every case)
    fig, ax = plt.subplots(figsize=(7, 7))
    tr = _km(prob, ole.trajectories)
    for j in range(0, tr.shape[0], max(1, tr.shape[0] // 40)):
        ax.plot(tr[j, :, 0], tr[j, :, 1], color="tab:green", lw=0.4, alpha=0.6)
    ax.plot(nom[:, 0], nom[:, 1], "k-", lw=1.2, label="unpowered")
    _bodies(ax, prob)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [km]")
    ax.set_ylabel("y [km]")
    ax.legend(fontsize=8)
    ax.set_title(f"Case {case}: OLE trajectories in the X-Y plane")
    name = "ps_fig03_lunar-flyby_xy.png" if case == 2 else f"ps_case{case}_xy.png"
    _save(fig, out, name)

    if case == 2:  # Fig. 4: close approach, Moon-centred; Fig. 5: 3-D inclination change
        moon = _moon(prob)
        rel = tr - moon[None]
        k_ca = int(np.argmin(np.linalg.norm(nom - moon, axis=1)))
        lo, hi = max(0, k_ca - 25), min(prob.n_segments, k_ca + 25)
        fig, ax = plt.subplots(figsize=(7, 7))
        for j in range(0, tr.shape[0], max(1, tr.shape[0] // 40)):
            ax.plot(rel[j, lo:hi, 0], rel[j, lo:hi, 1], color="tab:green", lw=0.5)
        nrel = nom - moon
        ax.plot(nrel[lo:hi, 0], nrel[lo:hi, 1], "k-", lw=1.2, label="unpowered")
        ax.add_patch(plt.Circle((0, 0), R_MOON_KM, color="0.4"))
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x - x_Moon [km]")
        ax.set_ylabel("y - y_Moon [km]")
        ax.set_title(f"Case 2: near-Moon passage (closest unpowered approach "
                     f"{np.linalg.norm(nrel[k_ca]):.0f} km)")
        ax.legend(fontsize=8)
        _save(fig, out, "ps_fig04_lunar-flyby_moon.png")
        info["closest_approach_km"] = float(np.linalg.norm(nrel[k_ca]))
        fig = plt.figure(figsize=(8, 7))
        ax = fig.add_subplot(projection="3d")
        for j in range(0, tr.shape[0], max(1, tr.shape[0] // 30)):
            ax.plot(tr[j, :, 0], tr[j, :, 1], tr[j, :, 2], color="tab:green", lw=0.4)
        ax.plot(moon[:, 0], moon[:, 1], moon[:, 2], ":", color="0.5")
        ax.scatter([0], [0], [0], color="tab:blue", s=40)
        ax.scatter(*moon[-1], color="0.4", s=20)
        ax.set_xlabel("x [km]")
        ax.set_ylabel("y [km]")
        ax.set_zlabel("z [km]")
        ax.view_init(elev=20, azim=-60)
        ax.set_title("Case 2: 3-D view, inclination change after the flyby")
        _save(fig, out, "ps_fig05_lunar-flyby_3d.png")

    if case in (4, 5):  # Fig. 7 / 9: the uncertainty envelope early in the trajectory
        early = min(15, prob.n_segments)
        fig = plt.figure(figsize=(8, 7))
        ax = fig.add_subplot(projection="3d")
        for k, c in [(0, "tab:red"), (early // 2, "tab:purple"), (early, "tab:green")]:
            p = tr[:, k]
            ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=6, color=c, label=f"t = {k * prob.extra['segment_s'] / 3600:.0f} h")
        ax.set_xlabel("x [km]")
        ax.set_ylabel("y [km]")
        ax.set_zlabel("z [km]")
        ax.legend(fontsize=8)
        ax.set_title(f"Case {case}: {prob.extra['sigma_km']:g} km initial position sphere, early trajectory")
        _save(fig, out, f"ps_fig{7 if case == 4 else 9:02d}_{prob.id}_early.png")
    if case == 5:  # Fig. 11: skewed 3-D view of the contorted controllable set
        fig = plt.figure(figsize=(8, 7))
        ax = fig.add_subplot(projection="3d")
        p = _km(prob, ole.trajectories[:, -1])
        ax.scatter(p[:, 0], p[:, 1], p[:, 2], s=8, color="tab:green")
        ax.view_init(elev=35, azim=30)
        ax.set_xlabel("x [km]")
        ax.set_ylabel("y [km]")
        ax.set_zlabel("z [km]")
        ax.set_title("Case 5: skewed view of the controllable set with uncertainty")
        _save(fig, out, "ps_fig11_lunar-flyby-backward-uncertain_3d.png")
    info["figures"] = fig_no
    return info


# ----------------------------------------------------------------------------- DRO validation
def resimulate(prob, x0, controls, p) -> np.ndarray:
    """Piecewise-constant controls, SciPy DOP853 (rtol 1e-12) one segment at a time."""
    from scipy.integrate import solve_ivp

    f = prob.model.f_fun
    x, out = np.array(x0, float), [np.array(x0, float)]
    for k in range(prob.n_segments):
        u = controls[k]
        sol = solve_ivp(lambda t, y, u=u: np.asarray(f(y, u, t, p)).ravel(), (prob.grid[k], prob.grid[k + 1]),
                        x, method="DOP853", rtol=1e-12, atol=1e-13)
        x = sol.y[:, -1]
        out.append(x)
    return np.array(out)


def dro_validation(samples: int, out: Path) -> dict:
    """ffoe / ole / bvp on dro with ``samples`` position directions against the direct transcription
    :func:`ocreach.reach.direct.transcription_support` (30 segments; 300 segments and a Richardson
    bound for bvp).  The tests check that function against their own hand-written transcription."""
    from ocreach.reach.direct import transcription_support

    prob = get_problem("dro")

    def dt_optimum(z, refine=1, n_sub=20):
        return transcription_support(prob, z, refine=refine, n_sub=n_sub)

    res, times = {}, {}
    for m in ("ffoe", "ole", "bvp"):
        reach(prob, m, samples=4)
        t0 = time.perf_counter()
        res[m] = reach(prob, m, samples=samples)
        times[m] = time.perf_counter() - t0
    dirs = res["ffoe"].meta["directions"]
    t0 = time.perf_counter()
    coarse = np.array([dt_optimum(z) for z in dirs])
    fine = np.array([dt_optimum(z, refine=10, n_sub=4) for z in dirs])
    times["transcription"] = time.perf_counter() - t0
    cont = fine + (fine - coarse) / 99.0
    half = samples // 2
    width = coarse + np.roll(coarse, half)
    out_d = {"samples": samples, "runtime_s": times, "width_min": float(width.min()),
             "width_max": float(width.max())}
    for m, truth in (("ffoe", coarse), ("ole", coarse), ("bvp", fine)):
        J = res[m].meta["cost"]
        out_d[m] = {"max_rel_err": float(np.max(np.abs(J - truth) / width)),
                    "mean_rel_err": float(np.mean(np.abs(J - truth) / width)),
                    "max_gap_below": float(np.max(truth - J)),
                    "max_excess": float(np.max(J - (cont if m == "bvp" else truth)))}
    for m in ("ffoe", "ole"):
        r = res[m]
        err = max(np.max(np.abs(resimulate(prob, r.trajectories[j, 0], r.controls[j], r.meta["params"])
                                - r.trajectories[j])) for j in range(samples))
        out_d[m]["resim_err"] = float(err)
    out_d["ole"]["iterations_max"] = int(res["ole"].meta["iterations"].max())
    out_d["bvp"]["shots"] = int(res["bvp"].meta["shots"])
    # figure: final points of the three methods and the transcription optimum's support lines
    fig, ax = plt.subplots(figsize=(7, 6))
    for m, c in (("ffoe", "tab:orange"), ("ole", "tab:green"), ("bvp", "tab:blue")):
        p = res[m].points[-1]
        ax.scatter(p[:, 0], p[:, 1], s=10, color=c, label=m)
    ang = np.arctan2(dirs[:, 1], dirs[:, 0])
    for z, h, an in zip(dirs, coarse, ang):
        base = h * z[:2]
        tvec = np.array([-np.sin(an), np.cos(an)]) * 0.01
        ax.plot([base[0] - tvec[0], base[0] + tvec[0]], [base[1] - tvec[1], base[1] + tvec[1]],
                color="0.6", lw=0.6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [DU]")
    ax.set_ylabel("y [DU]")
    ax.legend()
    ax.set_title(f"dro, t = 3 TU: {samples} position directions (grey: transcription support lines)")
    _save(fig, out, "ps_dro_validation.png")
    return out_d


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="1,2,3,4,5")
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--dro", action="store_true", help="run the DRO validation instead of the cases")
    ap.add_argument("--out", default=str(ROOT / "docs" / "figures"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.dro:
        import json

        print(json.dumps(dro_validation(args.samples, out), indent=1))
        return 0
    for c in [int(v) for v in args.cases.split(",") if v.strip()]:
        print(run_case(c, args.samples, out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
