"""Output of the ARCH suite: ``arch.csv`` in the ARCH-COMP result format (``benchmark, instance,
result, time, accuracy, timesteps`` as in the repeatability packages' ``results.csv``),
``arch.md`` (the table, the specs, the truth check), ``results.json`` (every row in full) and one
figure per benchmark, as the reports draw them."""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.fileio import atomic_write_text, json_text
from ocreach.outdir import OutputDir
from ocreach.specs import Linear, support_bound

#: the ARCH-COMP result columns, then the suite's own: the method, how far the guaranteed sets
#: were computed, and the sampled truth's escapes from them (expected 0) and states checked
CSV_HEADER = ["benchmark", "instance", "result", "time", "accuracy", "timesteps", "method",
              "computed_to", "truth_escapes", "truth_points"]

#: per benchmark: ("time", coefficients of the plotted quantity, its label, reference lines) or
#: ("plane", [(x name, y name), ...], reference lines); the axes of the reports' figures
FIGURES: dict[str, tuple] = {
    "CVDP20": ("plane", [("x1", "y1"), ("x2", "y2")], {"y": [2.75, 4.05]}),
    "CVDP23": ("plane", [("x1", "y1"), ("x2", "y2")], {"y": [2.75]}),
    "LALO20": ("time", {"x4": 1.0}, "x4", [4.5, 5.0]),
    "QUAD20": ("time", {"x3": 1.0}, "x3 (height)", [1.4, 0.9, 0.98, 1.02]),
    "PRDE20": ("time", {"z": 1.0}, "z", []),
    "ROBE21": ("time", {"x": 1.0, "y": 1.0, "z": 1.0}, "s = x + y + z", []),
    "LOVO21": ("plane", [("x", "y")], {"circle": (1.0, 1.0, 0.161)}),
    "SPRE22": ("plane", [("x", "y")], {"cone": 20.0, "target": 2.0}),
}
COLOURS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]


def fmt(v: Any, digits: int = 4) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return ""
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def csv_text(rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_HEADER)
    for r in rows:
        tr = r.truth or {}
        w.writerow([r.benchmark, r.instance, {"verified": 1, "violated": 0}.get(r.result, ""),
                    fmt(r.time, 6), fmt(r.accuracy, 6), r.timesteps, r.method,
                    fmt(r.computed_to, 6), tr.get("escapes", ""), tr.get("points_checked", "")])
    return buf.getvalue()


def markdown(rows, machine: str, samples: int, date: str, timing: dict | None = None,
             workers: int = 1, load: dict | None = None) -> str:
    la = "; load average (1, 5, 15 min) " + ", then ".join(
        f"{' / '.join(f'{x:.2f}' for x in v)} at the {k}" for k, v in load.items()) if load else ""
    lines = ["# ARCH-COMP NLN benchmarks (ocreach)", "",
             f"{date}; {machine}; {workers} instance(s) at once{la}.  Times are wall seconds of "
             "the reachable set and the spec checks, "
             "after a warm-up over the first grid steps (compilation, reported apart).  "
             "\"computed to\": the guaranteed sets enclose every run up to that time (the horizon, "
             "or where the method stopped); the sampled truth is compared with them up to there.",
             "", "| benchmark | instance | method | result | time [s] | measure | value | steps | "
             "computed to | truth: samples / escapes / counter-examples |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        tr = r.truth or {}
        t = (f"{tr.get('samples', '')} / {tr.get('escapes', '')} / {len(tr.get('violations', {}))}"
             if tr else "not run")
        lines.append(f"| {r.benchmark} | {r.instance or '-'} | {r.method} | {r.result} | "
                     f"{fmt(r.time)} | {r.accuracy_label} | {fmt(r.accuracy)} | {r.timesteps} | "
                     f"{fmt(r.computed_to)} | {t} |")
    if timing:
        lines += ["", "Where the time went (seconds): " + ", ".join(
            f"{k} {fmt(float(v))}" for k, v in timing.items()) + "."]
    lines += ["", "## Details", ""]
    for r in rows:
        lines.append(f"### {r.benchmark} {r.instance}".rstrip())
        lines.append("")
        lines.append(f"- problem `{r.problem_id}`, method `{r.method}`, options "
                     f"`{ {k: v for k, v in r.options.items() if v} }`")
        cpu = ", ".join(f"{k} {fmt(float(v))}" for k, v in r.cpu_s.items())
        specs = f"{fmt(r.check_s)} s" if fmt(r.check_s) else "not checked (the run stopped)"
        lines.append(f"- reachable set {fmt(r.reach_s)} s, specs {specs}, warm-up "
                     f"{fmt(r.warmup_s)} s (wall); CPU s: {cpu}; {r.timesteps} steps")
        for s in r.specs:
            m = f", margin {fmt(s['margin'])}" if s.get("margin") is not None else ""
            lines.append(f"- spec *{s['name']}*: **{s['status']}** ({s['detail']}{m})")
        for k, v in r.measures.items():
            tv = (r.truth or {}).get("measures", {}).get(k)
            lines.append(f"- {k}: {fmt(v, 6)}" + (f" (sampled truth: {fmt(tv, 6)}, a lower "
                                                   "bound)" if tv is not None else ""))
        if r.paths:
            lines.append(f"- final jump sequences: {r.paths.get('final_paths')}; jump counts "
                         f"{r.paths.get('final_jump_counts')}; {r.paths.get('branches')} branches")
        if r.truth:
            tr = r.truth
            lines.append(f"- sampled truth: {tr['samples']} samples, {tr['points_checked']} states "
                         f"up to t = {fmt(tr.get('checked_to'))} checked, {tr['escapes']} outside "
                         f"the guaranteed sets (worst gauge {fmt(tr['worst_gauge'], 12)}), "
                         f"{tr['time_s']:.1f} s")
            for k, v in tr["violations"].items():
                lines.append(f"  - counter-example of *{k}*: {v['detail']}")
            if tr.get("paths"):
                lines.append(f"  - sampled jump sequences: {tr['paths']}")
            if tr.get("blocked"):
                lines.append(f"  - {tr['blocked']} runs blocked (no enabled transition)")
        if r.error:
            lines.append(f"- **reason**: {r.error}")
        lines.append("")
    return "\n".join(lines)


# =============================================================================== figures
def _flow(res, names):
    """``(t_lo, t_hi, set, location, names)`` of every set of a result."""
    if hasattr(res, "pieces"):
        return [(p.t_lo, p.t_hi, p.set, p.location, p.names) for p in res.pieces]
    out = [(float(res.times[k]), float(res.times[k + 1]), T, "", tuple(names))
           for k, T in enumerate(res.tubes or [])]
    return out


def _parts(S):
    return list(S.parts) if hasattr(S, "parts") else [S]


def _label(row, loc: str = "") -> str:
    """``instance location (result)``, with how far a run that stopped got."""
    stop = "" if not row.stopped else \
        f", stopped at t = {fmt(row.computed_to)}; the sets that blew up before are not drawn"
    return " ".join(x for x in (row.instance, loc) if x) + f" ({row.result}{stop})"


def _window(boxes: np.ndarray) -> np.ndarray | None:
    """``[[x_lo, x_hi], [y_lo, y_hi]]`` of the figure from ``(t, lo_x, hi_x, lo_y, hi_y,
    partial)`` rows of the drawn sets: the runs computed to the end and the first three quarters
    of the time of the runs that stopped (whose last sets blew up before the stop), padded by 5 %."""
    if boxes.size == 0:
        return None
    keep = boxes[:, 5] == 0
    part = ~keep
    if part.any():
        t = boxes[part, 0]
        keep |= part & (boxes[:, 0] <= t.min() + 0.75 * (t.max() - t.min()))
    B = boxes[keep]
    if B.size == 0 or not np.all(np.isfinite(B[:, 1:5])):
        return None
    W = np.array([[B[:, 1].min(), B[:, 2].max()], [B[:, 3].min(), B[:, 4].max()]])
    pad = 0.05 * (W[:, 1] - W[:, 0]) + 1e-12 * (1 + np.abs(W).max(axis=1))
    return W + np.column_stack([-pad, pad])


def _inside(box, W: np.ndarray | None, factor: float = 3.0) -> bool:
    """Whether a drawn set's box fits in the window grown ``factor`` times about its centre (a
    set of a stopped run that blew up is not drawn; it would hide every other set)."""
    if W is None:
        return True
    c, r = W.mean(axis=1), 0.5 * factor * (W[:, 1] - W[:, 0])
    return bool(box[1] >= c[0] - r[0] and box[2] <= c[0] + r[0]
                and box[3] >= c[1] - r[1] and box[4] <= c[1] + r[1])


def figure(benchmark: str, runs: list[tuple[Any, Any, Any]], path: Path) -> Path | None:
    """The benchmark's figure from ``[(row, problem, result), ...]``: every guaranteed set drawn,
    a run that stopped early as far as it got (the scale set by the runs computed to the end)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection

    from ocreach.reach.plot import save_figure
    from ocreach.sets.zonotope import zonotope_polygon

    spec = FIGURES.get(benchmark)
    done = [(r, p, res) for r, p, res in runs if res is not None]
    if spec is None or not done:
        return None
    kind = spec[0]
    if kind == "time":
        _, coeffs, label, hlines = spec
        fig, ax = plt.subplots(figsize=(7, 4.5))
        drawn = []
        for i, (row, prob, res) in enumerate(done):
            names = prob.model.state_names
            for t0, t1, S, _loc, nm in _flow(res, names):
                d = Linear(tuple(coeffs.items()), 0.0).vector(nm)
                for Z in _parts(S):
                    hi, lo = support_bound(Z, d), -support_bound(Z, -d)
                    drawn.append((i, [(t0, lo), (t1, lo), (t1, hi), (t0, hi)],
                                  (t0, t0, t1, lo, hi, row.stopped)))
        W = _window(np.array([b for _, _, b in drawn], dtype=float).reshape(-1, 6))
        for i, (row, _prob, _res) in enumerate(done):
            rects = [q for k, q, b in drawn if k == i and (b[5] == 0 or _inside(b, W))]
            ax.add_collection(PolyCollection(rects, facecolor=COLOURS[i % 5], edgecolor="none",
                                             alpha=0.6, label=_label(row)))
        for h in hlines:
            ax.axhline(h, color="red", ls="--", lw=1)
        ax.autoscale_view()
        if W is not None:
            ax.set_ylim(*W[1])
        ax.set_xlabel("t")
        ax.set_ylabel(label)
    else:
        _, planes, extra = spec
        fig, axes = plt.subplots(1, len(planes), figsize=(6 * len(planes), 5.5), squeeze=False)
        for ax, (a, b) in zip(axes[0], planes):
            drawn = []
            for i, (row, prob, res) in enumerate(done):
                names = prob.model.state_names
                flow = _flow(res, names)
                step = max(1, len(flow) // 4000)
                for t0, _t1, S, lc, nm in flow[::step]:
                    ia, ib = nm.index(a), nm.index(b)
                    for Z in _parts(S):
                        P = Z.project([ia, ib])
                        V = zonotope_polygon(P.c, P.G)
                        lo, hi = V.min(axis=0), V.max(axis=0)
                        drawn.append((i, lc, V, (t0, lo[0], hi[0], lo[1], hi[1], row.stopped)))
            W = _window(np.array([q[3] for q in drawn], dtype=float).reshape(-1, 6))
            for i, (row, _prob, _res) in enumerate(done):
                locs = sorted({lc for k, lc, _, _ in drawn if k == i})
                for j, loc in enumerate(locs):
                    polys = [V for k, lc, V, bx in drawn
                             if k == i and lc == loc and (bx[5] == 0 or _inside(bx, W))]
                    col = COLOURS[(i + j) % 5]
                    ax.add_collection(PolyCollection(polys, facecolor=col, edgecolor=col,
                                                     linewidth=0.2, alpha=0.5,
                                                     label=_label(row, loc)))
            ax.autoscale_view()
            if W is not None:
                ax.set_xlim(*W[0])
                ax.set_ylim(*W[1])
            ax.set_xlabel(a)
            ax.set_ylabel(b)
            for y in extra.get("y", []):
                ax.axhline(y, color="red", ls="--", lw=1)
            if "circle" in extra:
                cx, cy, r = extra["circle"]
                th = np.linspace(0, 2 * np.pi, 200)
                ax.plot(cx + r * np.cos(th), cy + r * np.sin(th), "k-", lw=1)
            if "cone" in extra:
                tan = math.tan(math.radians(extra["cone"]))
                ax.plot([-100, 0, -100], [-100 * tan, 0, 100 * tan], "g-", lw=1, label="line of sight")
            if "target" in extra:
                h = extra["target"]
                ax.add_patch(matplotlib.patches.Rectangle((-h, -h), 2 * h, 2 * h, color="k"))
    for ax in fig.axes:
        ax.legend(fontsize=7, loc="best")
        ax.set_title(f"{benchmark}: guaranteed sets (ocreach)", fontsize=9)
    fig.tight_layout()
    return save_figure(fig, path, palette=True)


class Writer:
    """Writes the suite's files into an :class:`~ocreach.outdir.OutputDir` as instances finish
    (``arch.csv`` and ``arch.md`` are rewritten each time, so a partial run keeps what finished)."""

    def __init__(self, out: OutputDir, machine: str, samples: int, date: str, figures: bool = True,
                 order: list[str] | None = None):
        self.out, self.machine, self.samples, self.date = out, machine, samples, date
        self.figures = figures
        self.order = list(order or [])
        self.rows: list = []
        self.by_bench: dict[str, list] = {}
        #: wall seconds per phase (set by the caller: suite, figures, total)
        self.timing: dict[str, float] = {}
        #: instances run at once (set by the caller)
        self.workers = 1
        #: the machine's load averages (1, 5, 15 min) at the start and end of the run
        self.load: dict[str, list[float]] = {}

    def _rank(self, row) -> int:
        return self.order.index(row.problem_id) if row.problem_id in self.order else len(self.order)

    def add(self, row, problem, result) -> None:
        """Add a finished instance (in any order; the tables keep the suite's order) and
        rewrite the tables."""
        self.rows.append(row)
        self.rows.sort(key=self._rank)
        self.write_tables()
        lst = self.by_bench.setdefault(row.benchmark, [])
        lst.append((row, problem, result))
        lst.sort(key=lambda t: self._rank(t[0]))

    def phase_totals(self) -> dict[str, float]:
        """Summed wall seconds of the instances' phases (warm-up, reachable sets and spec
        checks, sampled truth), with :attr:`timing` (the caller's wall clock) after them."""
        f = (lambda v: 0.0 if v is None or not math.isfinite(v) else float(v))
        tot = {"warm-up": sum(f(r.warmup_s) for r in self.rows),
               "reachable sets": sum(f(r.reach_s) for r in self.rows),
               "spec checks": sum(f(r.check_s) for r in self.rows),
               "sampled truth": sum(f((r.truth or {}).get("time_s")) for r in self.rows)}
        cpu: dict[str, float] = {}
        for r in self.rows:
            for k, v in r.cpu_s.items():
                cpu[k] = cpu.get(k, 0.0) + float(v)
        return {**{f"{k} (wall, summed over instances)": v for k, v in tot.items()},
                **{f"{k} (CPU, summed)": v for k, v in cpu.items()}, **self.timing}

    def write_tables(self) -> None:
        base = Path(self.out.path)
        timing = self.phase_totals()
        atomic_write_text(base / "arch.csv", csv_text(self.rows))
        atomic_write_text(base / "arch.md", markdown(self.rows, self.machine, self.samples,
                                                     self.date, timing, self.workers,
                                                     self.load))
        atomic_write_text(base / "results.json", json_text({
            "machine": self.machine, "date": self.date, "samples": self.samples,
            "workers": self.workers, "load_average": self.load, "timing_s": timing,
            "rows": [r.as_dict() for r in self.rows]}))

    def write_figures(self) -> list[Path]:
        if not self.figures:
            return []
        out = []
        for bench, runs in self.by_bench.items():
            p = figure(bench, runs, Path(self.out.path) / f"{bench}.png")
            if p is not None:
                out.append(p)
        return out
