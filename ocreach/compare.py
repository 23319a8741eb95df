"""Side-by-side comparison of reachability methods on one problem.

Metrics, per method, at the final time of the grid and on 2-D projections (position and velocity
planes):

* ``runtime_s``: wall time of ``solve``;
* ``support_err``: mean over 64 directions of ``(h_method(d) - h_true(d)) / w_true(d)``, where
  ``h_true`` is the best known *lower bound* of the true support function (the max over every real
  trajectory endpoint of every sample-based method, Monte Carlo truth included) and ``w_true`` the
  width ``h_true(d) + h_true(-d)``.  Positive values are over-approximation (or points the other
  methods missed), negative values under-approximation;
* ``area``: area of the projection (convex hull of samples, or the set's outline);
* ``mc_covered``: fraction of the Monte Carlo endpoints inside the method's estimate, tested as:
  convex sets (interval, zonotope, ellipsoid): exact membership of the projection (within the
  set's ``tol``); sample-based methods: the convex hull of the method's samples;
  polynomial zonotopes and unions of them (``stt``): the exact queries of
  :mod:`ocreach.sets.pz_exact` on the set itself -- ``mc_covered`` is the fraction *not certainly
  outside* (no exclusion certificate), ``mc_outside`` the number with a certificate.

For polynomial-zonotope results the metrics come with bounds (the set's own support function
is bracketed by branch and bound, not read off its zonotope enclosure): ``support_err`` uses the
upper bound (``support_err_lower`` the lower bound, ``support_err_max`` the largest upper-bound
excess), ``area`` is the upper bound of the area of the projection's convex hull
(``area_lower`` the lower bound: the hull of points of the set).

Methods that used a different input set than the problem's control set (``meta["input_set"]``,
e.g. ``stt`` with the paper's box on ``dro``) are named in the table's notes: their estimate is of
a different (larger) reachable set than the Monte Carlo truth, which uses the problem's set.
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.errors import ProblemError
from ocreach.fileio import atomic_write_text, json_text
from ocreach.geometry import (
    circle_directions,
    convex_hull_polygon,
    in_convex_hull,
    outline_area,
    points_in_polygons,
    polygon_area,
)
from ocreach.problem import Problem
from ocreach.reach.base import method_class, reach
from ocreach.reach.result import ReachResult
from ocreach.registry import get_problem


@dataclass
class Comparison:
    """Results of :func:`compare`: per-method results and metrics, plus the truth samples."""

    problem: Problem
    results: dict[str, ReachResult]
    metrics: dict[str, dict[str, Any]]
    truth: np.ndarray
    errors: dict[str, str] = field(default_factory=dict)
    interrupted: bool = False

    def table(self) -> str:
        """Markdown table of the metrics."""
        planes = list(self.problem.planes().items())
        head = ["method", "runtime [s]", "samples/sets"]
        for tag, _ in planes:
            head += [f"support err ({tag})", f"area ({tag})", f"MC covered ({tag})"]
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for name, m in self.metrics.items():
            row = [name, f"{m['runtime_s']:.3f}", str(m["size"])]
            for tag, _ in planes:
                pm = m["planes"].get(tag, {})
                row += [f"{pm.get('support_err', float('nan')):+.3%}",
                        f"{pm.get('area', float('nan')):.4g}",
                        f"{pm.get('mc_covered', float('nan')):.1%}"]
            lines.append("| " + " | ".join(row) + " |")
        for name, err in self.errors.items():
            lines.append(f"| {name} | failed: {err} |" + " |" * (len(head) - 2))
        lines += ["", "runtime: wall time of each method's solve in this process, including any one-off "
                  "compilation of generated C code (cached on disk for later runs)."]
        vols = {n: m["volume_pos"] for n, m in self.metrics.items()
                if m.get("volume_pos") is not None}
        if vols:  # position-space volume at the final time (Patel & Subbarao Fig. 5)
            lines += ["position-space volume at the final time: " + ", ".join(
                f"{n} {v:.4g}" + (" (guaranteed)" if self.results[n].meta.get("guaranteed") else "")
                for n, v in vols.items())]
        lines += [f"Note: {n}" for n in self.notes()]
        return "\n".join(lines)

    def notes(self) -> list[str]:
        """Methods whose input set differs from the problem's control set (see module docstring)."""
        kind = self.problem.control_set.kind
        out = []
        for name, res in self.results.items():
            used = res.meta.get("input_set")
            if used is not None and used != kind:
                out.append(f"{name} used the {used!r} input set, the problem (and the Monte Carlo "
                           f"truth) the {kind!r} control set: {name} estimates a different reachable "
                           f"set, so its support error and area include that difference.")
        return out


def _pz_parts(S) -> list | None:
    """The polynomial-zonotope parts of a set (a PZ or a union of PZs), else None."""
    from ocreach.sets import PolyZonotope

    if isinstance(S, PolyZonotope):
        return [S]
    parts = getattr(S, "parts", None)
    if parts and all(isinstance(q, PolyZonotope) for q in parts):
        return list(parts)
    return None


def _pz_metrics(S, dims: Sequence[int], dirs: np.ndarray, h_true: np.ndarray, width: np.ndarray,
                mc: np.ndarray) -> dict[str, Any]:
    """Support, hull-area and coverage bounds of a (union of) polynomial zonotope(s) from the exact
    queries (:mod:`ocreach.sets.pz_exact`); see the module docstring."""
    from ocreach.sets.pz_exact import _halfplane_polygon, membership, support_bounds

    parts = [q.project(list(dims)) for q in _pz_parts(S)]
    sbs = [support_bounds(q, dirs) for q in parts]
    lower = np.max([b.lower for b in sbs], axis=0)
    upper = np.max([b.upper for b in sbs], axis=0)
    d256 = circle_directions(256)
    s256 = [support_bounds(q, d256) for q in parts]
    pts = np.vstack([b.points for b in s256])
    inner = convex_hull_polygon(pts)
    up256 = np.max([b.upper for b in s256], axis=0)
    outer = _halfplane_polygon(d256, up256 + 1e-12 * max(1.0, float(np.abs(up256).max())), pts.mean(axis=0))
    w = np.where(width > 0, width, 1.0)
    out = {"support_err": float(np.mean((upper - h_true) / w)),
           "support_err_lower": float(np.mean((lower - h_true) / w)),
           "support_err_max": float(np.max((upper - h_true) / w)),
           "support_gap_max": float(np.max((upper - lower) / w)),
           "area": polygon_area(outer), "area_lower": polygon_area(inner)}
    if mc.shape[0]:
        outside = np.ones(mc.shape[0], dtype=bool)
        for q in parts:
            todo = np.flatnonzero(outside)
            if todo.size == 0:
                break
            outside[todo[~membership(q, mc[todo]).outside]] = False
        out["mc_covered"] = float(np.mean(~outside))
        out["mc_outside"] = int(np.sum(outside))
    return out


def _projected_estimate(result: ReachResult, dims: Sequence[int]):
    """(support function callable, area, containment callable) of the final-time projection."""
    dims = list(dims)
    if result.sets is not None:
        s = result.sets[-1].project(dims)
        outline = s.outline() if hasattr(s, "outline") else convex_hull_polygon(
            s.sample(4000, np.random.default_rng(0), mode="extreme"))
        if isinstance(outline, (list, tuple)):  # PZ / union of PZs: pieces of the non-convex outline
            contains = lambda pts: points_in_polygons(pts, outline)
        else:
            contains = lambda pts: np.asarray(s.contains(pts), dtype=bool)
        return (lambda d: np.asarray(s.support(d), dtype=float), outline_area(outline), contains)
    pts = np.asarray(result.points[-1])[:, dims]
    poly = convex_hull_polygon(pts)
    return (lambda d: np.max(pts @ d.T, axis=0), polygon_area(poly),
            lambda q: in_convex_hull(q, pts))


def compare(problem: Problem | str, methods: Sequence[str], *, options: dict[str, dict] | None = None,
            truth_samples: int = 2000, seed: int = 0, progress: bool = True,
            out_dir: str | Path | None = None, stage=None) -> Comparison:
    """Run ``methods`` on ``problem`` and compute the metrics of the module docstring.

    ``options`` maps a method name to its options.  Monte Carlo truth (``mc`` with
    ``truth_samples``) is run as well unless ``mc`` is among the methods.  A method that fails is
    reported in ``Comparison.errors`` with its message, not swallowed silently.  With ``out_dir``
    each method's result is saved there (atomically) as soon as it finishes.  Ctrl-C stops the
    remaining work; the methods that finished are kept, metrics are computed from them and
    ``Comparison.interrupted`` is set (also when native code turned the Ctrl-C into another
    error, :func:`ocreach.interrupt.interrupt_requested`).  ``stage(name)`` is called before each
    method (``"method:NAME"``, the CLI's interruption points).
    """
    from tqdm import tqdm

    from ocreach.interrupt import acknowledge, interrupt_requested

    problem = problem if isinstance(problem, Problem) else get_problem(problem)
    options = options or {}
    for name in methods:  # unknown names fail before any work is done
        method_class(name)
    unused = sorted(set(options) - set(methods))
    if unused:
        raise ProblemError(f"options given for method(s) {unused} that are not compared; "
                           f"methods: {list(methods)}")
    results: dict[str, ReachResult] = {}
    runtimes: dict[str, float] = {}
    errors: dict[str, str] = {}
    interrupted = False
    for name in tqdm(list(methods), desc=f"compare {problem.id}", disable=not progress):
        t0 = time.perf_counter()
        try:
            if stage is not None:
                stage(f"method:{name}")
            res = reach(problem, name, **options.get(name, {}))
        except KeyboardInterrupt:
            errors[name] = "interrupted (Ctrl-C)"
            interrupted = True
            acknowledge()  # handled: reported in errors and Comparison.interrupted
            break
        except Exception as exc:  # reported in the table and the return value, never silent
            errors[name] = f"{type(exc).__name__}: {exc}"
            if interrupt_requested():
                errors[name] = "interrupted (Ctrl-C)"
                interrupted = True
                acknowledge()
                break
            continue
        runtimes[name] = time.perf_counter() - t0
        results[name] = res
        if out_dir is not None:
            res.save(Path(out_dir) / _result_name(problem, name))
    mc_end = None
    if "mc" in results:
        mc_end = np.asarray(results["mc"].points[-1])
    elif not interrupted:
        try:
            if stage is not None:
                stage("method:mc (truth)")
            mc_end = np.asarray(reach(problem, "mc", samples=truth_samples,
                                      seed=seed + 1).points[-1])
        except KeyboardInterrupt:
            errors["mc (truth)"] = "interrupted (Ctrl-C)"
            interrupted = True
            acknowledge()
    real = ([] if mc_end is None else [mc_end]) + [
        np.asarray(r.points[-1]) for r in results.values() if r.points is not None]
    truth = np.vstack(real) if real else np.empty((0, problem.model.n_x))
    if mc_end is None:
        mc_end = np.empty((0, problem.model.n_x))

    metrics: dict[str, dict[str, Any]] = {}
    planes = problem.planes()
    dirs = circle_directions(64)
    for name, res in results.items():
        entry: dict[str, Any] = {"runtime_s": runtimes[name],
                                 "size": len(res.sets) if res.sets is not None else
                                 int(np.asarray(res.points[-1]).shape[0]),
                                 "planes": {}}
        for tag, dims in planes.items():
            if truth.shape[0] == 0:  # interrupted before any sample existed: nothing to measure
                continue
            tp = truth[:, list(dims)]
            h_true = np.max(tp @ dirs.T, axis=0)
            width = h_true + np.max(tp @ (-dirs).T, axis=0)
            if res.sets is not None and _pz_parts(res.sets[-1]) is not None:
                entry["planes"][tag] = {**_pz_metrics(res.sets[-1], dims, dirs, h_true, width,
                                                      mc_end[:, list(dims)]), "dims": list(dims)}
                continue
            support, area, contains = _projected_estimate(res, dims)
            err = (support(dirs) - h_true) / np.where(width > 0, width, 1.0)
            covered = contains(mc_end[:, list(dims)]) if mc_end.shape[0] else np.array([np.nan])
            entry["planes"][tag] = {"support_err": float(np.mean(err)),
                                    "support_err_max": float(np.max(np.abs(err))),
                                    "area": float(area), "mc_covered": float(np.mean(covered)),
                                    "dims": list(dims)}
        volume = position_volume(res, problem)
        # None (JSON null) where it cannot be computed: metrics.json stays strict JSON, no NaN
        entry["volume_pos"] = volume if np.isfinite(volume) else None
        metrics[name] = entry
    return Comparison(problem=problem, results=results, metrics=metrics, truth=truth, errors=errors,
                      interrupted=interrupted)


def position_volume(result: ReachResult, problem: Problem, k: int = -1) -> float:
    """Volume of the position-space projection at time index ``k`` (Patel & Subbarao Fig. 5):
    exact for a zonotope, the sum over the parts (an upper bound) for a union of zonotopes, the
    convex hull of the samples for sample-based results; NaN when it cannot be computed (the
    comparison writes that as null)."""
    dims = list(problem.position_dims)
    try:
        if result.sets is not None:
            S = result.sets[k].project(dims)
            if hasattr(S, "volume_bound"):
                return S.volume_bound()
            return float(S.volume()) if hasattr(S, "volume") else float("nan")
        from scipy.spatial import ConvexHull

        return float(ConvexHull(np.asarray(result.points[k])[:, dims]).volume)
    except (ValueError, ArithmeticError, RuntimeError):  # a degenerate hull (QhullError) or too
        return float("nan")  # many generator subsets (SetError): no number, not a failure


def _result_name(problem: Problem, method: str) -> str:
    return f"{problem.id}_{method}.npz"


def write_comparison(cmp: Comparison, out_dir: str | Path) -> dict[str, Path]:
    """Write ``comparison.md``, ``metrics.json``, ``overlay.png`` and one result file per method."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ocreach.reach.plot import axis_label, plot_result, save_figure, time_label

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, res in cmp.results.items():
        paths[f"result_{name}"] = res.save(out / _result_name(cmp.problem, name))
    p = cmp.problem
    planes = list(p.planes().values())
    fig, axes = plt.subplots(1, len(planes), figsize=(6 * len(planes), 5), squeeze=False)
    colors = plt.get_cmap("tab10")
    mc_end = cmp.results["mc"].points[-1] if "mc" in cmp.results else None
    for ax, dims in zip(axes[0], planes):
        if mc_end is None:
            ax.plot(cmp.truth[:, dims[0]], cmp.truth[:, dims[1]], ".", ms=1.5, color="0.7",
                    label="truth samples")
        for i, (name, res) in enumerate(cmp.results.items()):
            plot_result(res, ax=ax, dims=dims, k=-1, color=colors(i), label=name,
                        show_points=res.points is not None)
        ax.set_xlabel(axis_label(p, dims[0]))
        ax.set_ylabel(axis_label(p, dims[1]))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"{p.id}: final reachable-set estimates at {time_label(p, p.grid[-1])}")
    fig.tight_layout()
    paths["figure"] = save_figure(fig, out / "overlay.png")
    text = (f"# Method comparison: {p.id}\n\n{p.summary()}\n\n{cmp.table()}\n\n"
            "support err: mean signed support-function error against the best known lower bound "
            "(all real trajectory endpoints), as a fraction of the width; MC covered: fraction of "
            "Monte Carlo endpoints inside the estimate.\n")
    paths["table"] = atomic_write_text(out / "comparison.md", text)
    paths["metrics"] = atomic_write_text(out / "metrics.json",
                                         json_text(cmp.metrics))
    return paths

