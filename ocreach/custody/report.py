"""Custody analysis of the Tucker et al. problems: tables, ``custody.json`` / ``custody.md`` and the
figures (x-y sets with their balls at scale and zoomed, the Gateway set in 3-D, probability
against time per FOV, the focal-plane view), all written atomically.

For every (problem, control set) the reachable balls come from :class:`ReachableBalls` (one
warm-started ``bvp`` solve per horizon, shared by all observers and FOVs).  For every observer and
FOV the custody probability uses the *outer* ball (conservative; the boresight on its centre) and
the horizon search of :func:`ocreach.custody.horizon.custody_horizon`; the same search on the inner ball
(the MEB of the bvp endpoints, Tucker Sec. 2.3) and Tucker's Eq. 14 as printed are reported beside
it.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ocreach.custody.fov import FOV, ball_outline, gnomonic, make_fov, points_in_fov
from ocreach.custody.horizon import Horizon, custody_horizon
from ocreach.custody.observers import Observer, parse_observer
from ocreach.custody.probability import check_probability, custody_probability
from ocreach.custody.reach_balls import ReachableBalls, validate_with_mc
from ocreach.errors import ProblemError

#: resolution of the report's figures (with 8-bit palette PNGs they take ~20 KB each)
FIGURE_DPI = 100
CUSTODY_PROBLEMS = ("custody-l1", "custody-l2", "custody-l3", "custody-l4", "custody-l5", "custody-gateway")


@dataclass
class CaseResult:
    """One (problem, observer, FOV, control set) row."""

    problem: str
    observer: str
    fov_deg: float
    fov_shape: str
    control_set: str
    p_required: float
    t_safe_days: float | None
    t_loss_days: float | None
    t_safe_days_inner: float | None
    t_loss_days_inner: float | None
    t_loss_days_tucker_eq14: float | None
    horizons: list = field(default_factory=list)
    evaluations: list = field(default_factory=list)
    #: ground sites: first time (days) the nominal object sets below the elevation mask (None: never)
    t_set_days: float | None = None
    #: whether the (outer-ball) horizon search met its tolerance, and why not (Horizon.converged)
    converged: bool = True
    search_message: str = ""


def first_set_time(observer: Observer, problem, t_max: float, tol: float) -> float | None:
    """First time (days) the unpowered object drops below a ground site's elevation mask: a
    10-minute scan of the nominal trajectory and bisection to ``tol``; None for observers in space
    or when it stays visible up to ``t_max``.  The custody search of a ground site stops there."""
    from ocreach.dynamics.flow import propagate

    if observer.up_fn is None:
        return None
    day = problem.extra["day_TU"]
    p0 = problem.params.copy()
    p0[problem.model.param_names.index("a_max")] = 0.0

    def vis(ts):
        ts = np.atleast_1d(np.asarray(ts, float))
        grid = np.concatenate([[0.0], ts]) * day
        X = propagate(problem.model, problem.x0, np.zeros((ts.size, 3)), grid, p=p0)[1:, :3]
        return observer.visible(ts * day, X)

    ts = np.arange(1, int(np.ceil(t_max * 144)) + 1) / 144.0
    ts = ts[ts <= t_max]
    if not vis([0.0 + 1e-9])[0]:
        return 0.0
    v = vis(ts)
    if v.all():
        return None
    k = int(np.argmin(v))
    lo, hi = (ts[k - 1] if k else 0.0), ts[k]
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if vis([mid])[0] else (lo, mid)
    return float(hi)


def _search(prob, p_required, t_max, step, tol, t_set):
    """Custody horizon, stopped where a ground site loses sight of the object."""
    if t_set is not None and t_set <= 0:
        return Horizon(None, 0.0, p_required, (), True, "the object is below the site's elevation mask at t = 0")
    if t_set is None or t_set >= t_max:
        return custody_horizon(prob, p_required, t_max, t_step=step, tol=tol)
    h = custody_horizon(prob, p_required, t_set, t_step=min(step, t_set), tol=tol)
    if h.t_loss is None:  # custody holds until the object sets
        return Horizon(max(h.t_safe - tol, 0.0), t_set, p_required, h.evaluations, h.converged,
                          f"custody holds until the object sets at t = {t_set:g} d")
    return h


def _probability(rb: ReachableBalls, observer: Observer, fov: FOV, ball: str = "outer",
                 model: str = "covered"):
    day = rb.base.extra["day_TU"]

    def p(t_days: float) -> float:
        if t_days == 0:  # the start of the search: the initial state (or initial ellipsoid)
            center, radius = rb.start_ball()
        else:
            hb = rb.at(t_days)
            b = hb.outer if ball == "outer" else hb.inner
            center, radius = b.center, b.radius
        o = observer.position([t_days * day])[0]
        return custody_probability(center, radius, o, fov, model=model)

    return p


def analyse(problem_ids: Sequence[str], observers: Sequence[str], fovs: Sequence[float], *,
            fov_shape: str = "circle", p_required: float = 0.95, horizons: Sequence[float] | None = None,
            control_sets: Sequence[str] = ("box",), tol_days: float = 0.01, step_days: float = 0.5,
            samples: int = 40, epoch: str = "2026-01-01", mc_samples: int = 0, progress=print):
    """Run the custody analysis; returns ``(cases, per_problem)`` where ``per_problem[(pid, cs)]``
    holds the :class:`ReachableBalls`, the report horizons and the MC validation rows."""
    from ocreach.errors import check_positive

    p_required = check_probability(p_required)
    check_positive("tol (days)", tol_days)
    check_positive("step (days)", step_days)
    if mc_samples < 0:
        raise ProblemError(f"mc (Monte Carlo samples) must be >= 0; got {mc_samples!r}")
    fov_objs = [make_fov(f, fov_shape) for f in fovs]
    cases: list[CaseResult] = []
    per_problem: dict = {}
    for pid in problem_ids:
        for cs in control_sets:
            rb = ReachableBalls(pid, overrides={"control_set": cs}, bvp_options={"samples": samples},
                                keep_results=True)
            hz = sorted(float(h) for h in (horizons or rb.base.extra["horizons_days"]))
            if not hz or hz[0] <= 0:
                raise ProblemError(f"--horizons must be positive days; got {horizons!r}")
            t_max = max(hz)
            # parse the observers before any solve, so bad input fails fast
            obs_map = {ospec: parse_observer(ospec, rb.base, epoch) for ospec in observers}
            curve_t = sorted(set(np.round(np.arange(step_days, t_max + 1e-9, step_days), 9).tolist()) | set(hz))
            for t in curve_t:
                rb.at(t)
            mc_rows = [validate_with_mc(rb, t, samples=mc_samples, keep_points=True) for t in hz] \
                if mc_samples else []
            per_problem[(pid, cs)] = {"balls": rb, "horizons": hz, "curve_t": curve_t, "mc": mc_rows,
                                      "observers": {}}
            for ospec, obs in obs_map.items():
                per_problem[(pid, cs)]["observers"][ospec] = obs
                t_set = first_set_time(obs, rb.base, t_max, tol_days)
                for fdeg, fov in zip(fovs, fov_objs):
                    res = {}
                    for ball in ("outer", "inner"):
                        res[ball] = _search(_probability(rb, obs, fov, ball), p_required, t_max, step_days,
                                            tol_days, t_set)
                    tk = _search(_probability(rb, obs, fov, "inner", "tucker-eq14"), p_required, t_max,
                                 step_days, tol_days, t_set)
                    day = rb.base.extra["day_TU"]
                    rows = []
                    for i, t in enumerate(hz):
                        hb = rb.at(t)
                        o = obs.position([t * day])[0]
                        rng_km = float(np.linalg.norm(hb.outer.center - o) * rb.base.units.length / 1e3)
                        extra = {}
                        if mc_rows:  # sampled reachable positions inside the FOV (gnomonic projection)
                            inside = points_in_fov(mc_rows[i]["points"], o, fov, hb.outer.center - o)
                            extra["mc_fraction_in_fov"] = float(inside.mean())
                        rows.append({**extra, "t_days": t, "meb_radius_km": hb.inner.radius * rb.base.units.length / 1e3,
                                     "inner_radius_km": hb.inner.radius * rb.base.units.length / 1e3,
                                     "outer_radius_km": hb.outer.radius * rb.base.units.length / 1e3,
                                     "range_km": rng_km,
                                     "probability": _probability(rb, obs, fov)(t)})
                    case = CaseResult(pid, obs.name, float(fdeg), fov_shape, cs, p_required,
                                      res["outer"].t_safe, res["outer"].t_loss, res["inner"].t_safe,
                                      res["inner"].t_loss, tk.t_loss, rows,
                                      [list(e) for e in res["outer"].evaluations], t_set,
                                      res["outer"].converged, res["outer"].message)
                    cases.append(case)
                    progress(f"{pid} [{cs}] {case.observer} FOV {fov.label()}: t_safe {_fmt_safe(case.t_safe_days)} d, "
                             f"t_loss {_fmt_t(case.t_loss_days, t_max, case.converged)} d "
                             f"({rb.solves} bvp solves so far)")
    return cases, per_problem


def _fmt_t(t, t_max, converged: bool = True) -> str:
    return f"> {t_max:g}" if t is None else f"{t:.3f}" + ("" if converged else " (not converged)")


def _fmt_safe(t) -> str:
    return "lost at start" if t is None else f"{t:.3f}"


def markdown_table(cases: Sequence[CaseResult]) -> str:
    hz = sorted({r["t_days"] for c in cases for r in c.horizons})
    head = ("| problem | control | observer | FOV (deg) | " + " | ".join(f"MEB r {h:g} d (km)" for h in hz)
            + " | outer r at last (km) | t_safe (d) | t_loss (d) | t_loss inner MEB (d) | Tucker Eq. 14 t_loss (d) "
            "| object sets (d) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for c in cases:
        by_t = {r["t_days"]: r for r in c.horizons}
        t_max = max(by_t)
        cells = [f"{by_t[h]['meb_radius_km']:.1f}" if h in by_t else "-" for h in hz]
        lines.append(f"| {c.problem} | {c.control_set} | {c.observer} | {c.fov_deg:g} {c.fov_shape} | "
                     + " | ".join(cells)
                     + f" | {by_t[t_max]['outer_radius_km']:.1f} | {_fmt_safe(c.t_safe_days)} | {_fmt_t(c.t_loss_days, t_max, c.converged)} | "
                     f"{_fmt_t(c.t_loss_days_inner, t_max)} | {_fmt_t(c.t_loss_days_tucker_eq14, t_max)} | "
                     + ("-" if c.t_set_days is None else f"{c.t_set_days:.3f}") + " |")
    return "\n".join(lines)


def mc_table(per_problem: dict) -> str:
    rows = ["| problem | control | t (d) | MC endpoints | outside outer ball | above a bvp support value | "
            "max excess / r | inner r (km) | outer r (km) |", "|---|---|---|---|---|---|---|---|---|"]
    for (pid, cs), info in per_problem.items():
        for m in info["mc"]:
            rows.append(f"| {pid} | {cs} | {m['t_days']:g} | {m['samples']} | {m['outside_outer']} | "
                        f"{m['above_support']} | {m['max_support_excess_rel']:.1e} | {m['inner_km']:.2f} | "
                        f"{m['outer_km']:.2f} |")
    return "\n".join(rows)


def write_outputs(cases, per_problem, out: str | Path, *, figures: bool = True, p_required: float = 0.95) -> dict:
    """``custody.json``, ``custody.md`` and the figures in ``out`` (atomic writes)."""
    from ocreach.fileio import atomic_write_text, json_text

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    payload = {"p_required": p_required, "ball_for_custody": "outer (support-polytope ball; conservative)",
               "cases": [c.__dict__ for c in cases],
               "mc_validation": {f"{k[0]}:{k[1]}": [{a: b for a, b in m.items() if a != "points"}
                                                    for m in v["mc"]] for k, v in per_problem.items()}}
    atomic_write_text(out / "custody.json", json_text(payload))
    md = ["# Custody (Tucker et al.)", "", markdown_table(cases)]
    if any(v["mc"] for v in per_problem.values()):
        md += ["", "## Monte Carlo check of the balls", "", mc_table(per_problem)]
    paths = {"json": out / "custody.json", "md": out / "custody.md", "figures": []}
    if figures:
        for (pid, cs), info in per_problem.items():
            paths["figures"] += write_figures(pid, cs, info, [c for c in cases if c.problem == pid and
                                                                c.control_set == cs], out, p_required)
        md += ["", "## Figures", ""] + [f"![{p.stem}]({p.name})" for p in paths["figures"]]
    atomic_write_text(out / "custody.md", "\n".join(md) + "\n")
    return paths


# ---------------------------------------------------------------------------------- figures
def _circle(ax, c, r, **kw):
    th = np.linspace(0, 2 * np.pi, 200)
    ax.plot(c[0] + r * np.cos(th), c[1] + r * np.sin(th), **kw)


def write_figures(pid: str, cs: str, info: dict, cases, out: Path, p_required: float) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ocreach.geometry import convex_hull_polygon
    from ocreach.orbits import lagrange_points
    from ocreach.reach.plot import save_figure as _save

    def save_figure(fig, path):  # committed to docs/figures/tucker: 100 dpi, 8-bit palette PNG
        return _save(fig, path, dpi=FIGURE_DPI, palette=True)

    rb: ReachableBalls = info["balls"]
    prob = rb.base
    km = prob.units.length / 1e3
    mu = prob.model.param("mu", prob.params)
    L = lagrange_points(mu)
    hz = info["horizons"]
    colors = plt.get_cmap("viridis")(np.linspace(0.1, 0.85, len(hz)))
    written = []
    tag = f"{pid}_{cs}"
    # x-y sets with their balls: at scale with the Moon and Lagrange points, then zoomed on each
    # horizon (Tucker Figs. 3-12)
    def panel(ax, ks, scale_view: bool):
        for k in ks:
            t = hz[k]
            hb = rb.at(t)
            poly = convex_hull_polygon(hb.endpoints[:, :2])
            if poly is not None:
                cl = np.vstack([poly, poly[:1]])
                ax.fill(cl[:, 0], cl[:, 1], color=colors[k], alpha=0.35, label=f"{t:g} d reachable (bvp)")
            _circle(ax, hb.inner.center, hb.inner.radius, color=colors[k], ls="--", lw=1.2,
                    label=f"{t:g} d MEB r = {hb.inner.radius * km:.0f} km")
            _circle(ax, hb.outer.center, hb.outer.radius, color=colors[k], ls=":", lw=1.0)
            ax.plot(*hb.nominal[:2], "x", color=colors[k])
        ax.plot(*prob.x0[:2], "k*", ms=9, label="x0")
        if scale_view:
            ax.plot(1 - mu, 0, "o", color="0.45", ms=8, mec="k", label="Moon")
            for i, p in enumerate(L):
                ax.plot(p[0], p[1], "+", color="tab:red", ms=8)
                ax.annotate(f"L{i + 1}", p[:2], textcoords="offset points", xytext=(4, 4), fontsize=8)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel("x [DU]")
        ax.set_ylabel("y [DU]")
        ax.legend(fontsize=7, loc="best")
        ax.grid(alpha=0.3)

    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    panel(ax, range(len(hz)), True)
    ax.set_title(f"{pid} ({cs} thrust): x-y reachable positions, MEB (dashed), outer ball (dotted)", fontsize=9)
    fig.tight_layout()
    written.append(save_figure(fig, out / f"{tag}_xy.png"))
    fig, axs = plt.subplots(1, len(hz), figsize=(4.8 * len(hz), 4.6), squeeze=False)
    for k, ax in enumerate(axs[0]):
        panel(ax, [k], False)
        ax.set_title(f"{pid} ({cs}): {hz[k]:g} d (zoom)", fontsize=9)
    fig.tight_layout()
    written.append(save_figure(fig, out / f"{tag}_xy_zoom.png"))
    if pid == "custody-gateway":  # the set in 3-D with the orbit (Tucker Figs. 13-15)
        from ocreach.dynamics.flow import propagate

        fig = plt.figure(figsize=(6.5, 5.5))
        ax = fig.add_subplot(projection="3d")
        p0 = prob.params.copy()
        p0[prob.model.param_names.index("a_max")] = 0.0
        T = prob.reference.period if prob.reference is not None else prob.grid[-1]
        orbit = propagate(prob.model, prob.x0, np.zeros((200, 3)), np.linspace(0, T, 201), p=p0)
        ax.plot(orbit[:, 0], orbit[:, 1], orbit[:, 2], "-", color="0.5", lw=0.8, label="9:2 NRHO")
        u, v = np.mgrid[0:2 * np.pi:24j, 0:np.pi:12j]
        for k, t in enumerate(hz):
            hb = rb.at(t)
            E = hb.endpoints
            ax.scatter(E[:, 0], E[:, 1], E[:, 2], s=6, color=colors[k], label=f"{t:g} d bvp endpoints")
            c, r = hb.inner.center, hb.inner.radius
            ax.plot_wireframe(c[0] + r * np.cos(u) * np.sin(v), c[1] + r * np.sin(u) * np.sin(v),
                              c[2] + r * np.cos(v), color=colors[k], lw=0.3, alpha=0.5)
        ax.scatter([1 - mu], [0], [0], s=40, color="0.45", label="Moon")
        ax.set_xlabel("x [DU]")
        ax.set_ylabel("y [DU]")
        ax.set_zlabel("z [DU]")
        ax.set_title(f"{pid} ({cs}): reachable positions and MEBs in 3-D", fontsize=9)
        ax.legend(fontsize=7)
        written.append(save_figure(fig, out / f"{tag}_3d.png"))
    # probability against time per FOV (one panel per observer)
    for ospec, obs in info["observers"].items():
        fig, ax = plt.subplots(figsize=(6.5, 4.5))
        ts = np.array(sorted(hb.t_days for hb in rb.cache.values()))  # scan and bisection points
        for c in [c for c in cases if c.observer in (ospec, obs.name)]:
            fov = make_fov(c.fov_deg, c.fov_shape)
            ps = [_probability(rb, obs, fov)(t) for t in ts]
            line, = ax.plot(ts, ps, "o-", ms=3, label=f"FOV {c.fov_deg:g} deg")
            if c.t_loss_days is not None:
                ax.axvline(c.t_loss_days, color=line.get_color(), ls=":", lw=0.8)
        ax.axhline(p_required, color="k", ls="--", lw=0.8, label=f"p = {p_required:g}")
        ax.set_xlabel("horizon [days]")
        ax.set_ylabel("custody probability (covered fraction, outer ball)")
        ax.set_ylim(-0.02, 1.05)
        ax.set_title(f"{pid} ({cs}) seen from {obs.name}", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
        fig.tight_layout()
        safe = obs.name.replace(":", "_").replace(",", "_").replace("(", "").replace(")", "")
        written.append(save_figure(fig, out / f"{tag}_probability_{safe}.png"))
        # focal-plane view at the last horizon for the smallest FOV of this observer
        mine = [c for c in cases if c.observer in (ospec, obs.name)]
        if mine:
            t = max(info["horizons"])
            hb = rb.at(t)
            o = obs.position([t * prob.extra["day_TU"]])[0]
            axis = hb.outer.center - o
            fig, ax = plt.subplots(figsize=(5.5, 5.5))
            XY, front = gnomonic(hb.endpoints, o, axis)
            ax.plot(np.rad2deg(np.arctan(XY[front, 0])), np.rad2deg(np.arctan(XY[front, 1])), ".", ms=3,
                    color="tab:blue", label=f"bvp endpoints ({t:g} d)")
            for b, ls, lab in ((hb.inner, "--", "MEB"), (hb.outer, ":", "outer ball")):
                ell = ball_outline(b.center, b.radius, o, axis)
                if ell is not None:
                    e = np.rad2deg(np.arctan(np.vstack([ell, ell[:1]])))
                    ax.plot(e[:, 0], e[:, 1], ls, color="k", lw=1, label=lab)
            for c in mine:
                f = make_fov(c.fov_deg, c.fov_shape)
                poly = np.rad2deg(np.arctan(np.vstack([f.polygon(256), f.polygon(256)[:1]])))
                ax.plot(poly[:, 0], poly[:, 1], "-", lw=0.8, label=f"FOV {c.fov_deg:g} deg")
            ax.set_aspect("equal")
            ax.set_xlabel("focal plane e1 [deg] (gnomonic)")
            ax.set_ylabel("focal plane e2 [deg]")
            ax.set_title(f"{pid} ({cs}) from {obs.name}, {t:g} d", fontsize=9)
            ax.legend(fontsize=7)
            ax.grid(alpha=0.3)
            fig.tight_layout()
            written.append(save_figure(fig, out / f"{tag}_focal_{safe}.png"))
    return written
