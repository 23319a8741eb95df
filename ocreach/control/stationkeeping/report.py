"""Station-keeping report: event-triggered tube MPC vs robust tube MPC, continuous MPC and LQR
(Patel & Subbarao, "Station-keeping in the near rectilinear halo orbit", Fig. 7-8).

``ocreach report station-keeping --problem nrho-9-2 [--controllers event-mpc,tube-mpc,mpc,lqr]
[--revolutions N] [--plant cr3bp|ephemeris] [--reference cr3bp|ephemeris] [--out DIR]
[--set key=value]`` runs :func:`~ocreach.control.stationkeeping.runs.
run_station_keeping` and writes, atomically, ``metrics.json`` (one entry per controller and the
settings), ``report.md``, ``report.html`` and the figures ``trajectory.png`` (3-D with the thrust
arcs), ``projections.png`` (x-y and y-z with the tube boxes), ``gauge.png`` (with the trigger and
release lines; with the ephemeris reference only when a tube controller ran), ``thrust.png`` and
``delta_v.png``.  Every sentence with a number is computed from
the run.
"""
from __future__ import annotations

import html
import inspect
import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.control.stationkeeping.metrics import delta_v_si
from ocreach.control.stationkeeping.paper import PAPER_DELTA_V_MPS, PAPER_TF_HOURS
from ocreach.control.stationkeeping.runs import CONTROLLERS, StationKeepingRun, run_station_keeping
from ocreach.errors import ProblemError
from ocreach.fileio import atomic_write_text, json_text, jsonable
from ocreach.reach.plot import save_figure

DESCRIPTIONS = {
    "event-mpc": "event-triggered MPC: thrust off inside the drift tube, soft tube-constrained MPC "
                 "(Eq. 27) from gauge > 1 until gauge <= beta for m steps",
    "tube-mpc": "robust tube MPC (Chisci et al. 2001): every step, tube box tightened by the error "
                "tube of the LQR-stabilised error dynamics, thrust tightened likewise, LQR "
                "terminal set (level set of the Riccati cost in the tightened sets)",
    "mpc": "continuous nonlinear MPC (Eq. 27 without the tube), every step",
    "lqr": "time-varying LQR (periodic Riccati solution; finite-horizon on the non-periodic "
           "ephemeris-corrected reference), every step (radially saturated)",
}
ANTICIPATE_TEXT = (" (event-mpc: or the predicted gauge, in the next refresh's tube, of the drift "
                   "to that refresh > 1: the anticipating trigger, not in the paper)")
TABLE_KEYS = ["revolutions", "delta_v_mps", "delta_v_per_rev_mps", "activations", "duty_cycle",
              "max_gauge", "max_gauge_off", "excursions_off", "max_deviation_km",
              "rms_deviation_km", "max_deviation_mps", "rms_deviation_mps", "max_thrust_ratio",
              "time_per_step_ms", "time_per_solve_ms", "solves", "solver_failures", "total_time_s"]


def station_keeping_report(problem, out_dir: str | Path, **options: Any) -> dict:
    """Run the station-keeping comparison on ``problem`` and write the report into ``out_dir``.

    Options are those of :func:`~ocreach.control.stationkeeping.runs.run_station_keeping`
    (``controllers`` also as a comma-separated string).  Returns the content of ``metrics.json``.
    """
    allowed = [n for n in inspect.signature(run_station_keeping).parameters if n != "problem"]
    unknown = sorted(set(options) - set(allowed))
    if unknown:
        raise ProblemError(f"station-keeping report has no option(s) {unknown}; allowed: {allowed}")
    ctl = options.get("controllers")
    if isinstance(ctl, str):
        options["controllers"] = tuple(c.strip() for c in ctl.split(",") if c.strip())
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    run = run_station_keeping(problem, **options)
    data = {name: run.metrics[name] for name in run.results}
    data["settings"] = run.settings
    data["events"] = {name: r.events for name, r in run.results.items() if r.events}
    atomic_write_text(out / "metrics.json", json_text(data))
    figs = _figures(problem, run, out)
    lines = summary_lines(data)
    atomic_write_text(out / "report.md", _markdown(problem, data, lines, figs))
    atomic_write_text(out / "report.html", _html(problem, data, lines, figs))
    return data


# ------------------------------------------------------------------------------------------------
# text
# ------------------------------------------------------------------------------------------------
def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return f"{float(v):.4g}"


def summary_lines(data: dict) -> list[str]:
    """Summary sentences, every number from ``data`` (the metrics of this run)."""
    s = data["settings"]
    names = [n for n in CONTROLLERS if n in data]
    lines = []
    rf = s.get("reference") or {"reference": "cr3bp"}
    if rf["reference"] == "ephemeris":
        return lines + ephemeris_reference_lines(data, names)
    per_rev = s.get("refresh_steps_per_rev")
    if per_rev:
        when = (f"refreshed at reference steps {', '.join(str(r) for r in per_rev)} of every "
                "revolution (restarted from the initial set where the sound method stops)")
    else:
        every = ("every revolution" if s["tube_interval_steps"] == s["steps_per_rev"]
                 else f"every {s['tube_interval_steps']} steps")
        when = f"refreshed at reference step {s['refresh_phase_step']} and then {every}"
    lines.append(f"Tube: membership {s['membership']}, {when}; "
                 + ("every tube a guaranteed enclosure." if s["tube_guaranteed"] else
                    "NOT a guaranteed enclosure of the plant's drift: the tubes enclose the "
                    "CR3BP drift, the plant is the DE421 model." if s.get("tube_model") == "cr3bp"
                    else "NOT a guaranteed enclosure where a tube is linearised (no remainder "
                    "term: gauges near perilune carry its linearisation error)."))
    lines += tube_lines(s.get("tubes") or [])
    pl = s.get("plant") or {"plant": "cr3bp"}
    if pl["plant"] == "ephemeris":
        lines.append(f"Plant: DE421 ephemeris, point masses {', '.join(pl['bodies'])}, epoch "
                     f"{pl['epoch']} TDB = reference time 0; {pl['frame']}. The controllers and "
                     "tubes predict with the CR3BP, so the CR3BP-vs-ephemeris mismatch is part of "
                     "what they must correct.")
    else:
        lines.append("Plant: the CR3BP itself (the prediction model of the controllers).")
    paper_rate = PAPER_DELTA_V_MPS / PAPER_TF_HOURS
    for n in names:
        m = data[n]
        rate = m["delta_v_mps"] / (m["revolutions"] * s["period_hours"])
        lines.append(
            f"{n}: Delta-V {m['delta_v_mps']:.4g} m/s over {m['revolutions']:.3g} revolutions "
            f"({m['delta_v_per_rev_mps']:.4g} m/s per revolution, {rate / paper_rate:.3g}x the "
            f"paper's rate of {PAPER_DELTA_V_MPS} m/s per {PAPER_TF_HOURS:g} h); "
            f"{m['activations']} activation(s), duty cycle {100 * m['duty_cycle']:.3g} %, max "
            f"deviation {m['max_deviation_km']:.4g} km / {m['max_deviation_mps']:.4g} m/s, max "
            f"gauge {m['max_gauge']:.3g}"
            + (f" ({m['max_gauge_off']:.3g} while thrust off, {m['excursions_off']} step(s) "
               "outside the tube with thrust off)" if m["max_gauge_off"] is not None else "")
            + f", {m['time_per_step_ms']:.3g} ms per step, {m['solver_failures']} solver "
              "failure(s).")
    lines += terminal_set_lines(data)
    if "event-mpc" in data and len(names) > 1:
        e = data["event-mpc"]
        for n in names:
            if n == "event-mpc" or data[n]["delta_v_mps"] == 0:
                continue
            lines.append(f"Event-triggered / {n} Delta-V: "
                         f"{e['delta_v_mps'] / data[n]['delta_v_mps']:.3g}.")
    return lines + [offset_line(s)]


def offset_line(s: dict) -> str:
    """The sentence on the initial offset, disturbance and navigation error (settings ``s``)."""
    return (f"Initial offset (same for all): |dr| = {s['offset_position_km']:.4g} km, "
            f"|dv| = {s['offset_velocity_mps']:.4g} m/s (seed {s['seed']}); disturbance "
            f"W = {s['disturbance_W']}; navigation error {s['navigation']}.")


def terminal_set_lines(data: dict) -> list[str]:
    """The tube MPC's terminal set and its robust-invariance check (if it ran with one)."""
    ts = (data.get("tube-mpc") or {}).get("terminal_set")
    if not ts:
        return []
    return [f"tube-mpc terminal set d^T P d <= alpha = {ts['alpha']:.3g}: sqrt(V) "
            f"contracts by {ts['contraction']:.6g} per step, the disturbance moves the "
            f"terminal state by <= {ts['disturbance_term']:.3g}; "
            + ("robustly invariant (recursive feasibility of the hard form, for the "
               "linearised error dynamics)." if ts["robustly_invariant"] else
               "NOT robustly invariant: no recursive-feasibility guarantee.")]


def tube_lines(tubes: list[dict]) -> list[str]:
    """One sentence per run of consecutive refresh intervals with the same tube (source and
    guarantee), in revolutions from the start of the run."""
    out = []
    for key, group in itertools.groupby(tubes, key=lambda e: (e["source"], e["guaranteed"])):
        group = list(group)
        a, b = group[0]["revolutions"][0], group[-1]["revolutions"][1]
        why = group[0].get("fallback_reason")
        out.append(f"Tube used for revolutions {a:.3g}-{b:.3g} ({len(group)} refresh "
                   f"interval(s)): {key[0]}, "
                   + ("GUARANTEED (sound method)" if key[1] else "LINEARISED, not guaranteed")
                   + (f"; the sound method failed: {why}" if why else "") + ".")
    return out


def ephemeris_reference_lines(data: dict, names: list[str]) -> list[str]:
    """Summary sentences of a run on the DE421-corrected reference (its tubes, if any)."""
    s = data["settings"]
    rf, pl = s["reference"], s["plant"]
    lines = [f"Reference: the CR3BP orbit corrected over {rf['revolutions_corrected']} "
             f"revolutions into an orbit of the DE421 plant (point masses {', '.join(pl['bodies'])}, epoch "
             f"{pl['epoch']} TDB = reference time 0) by multiple shooting on "
             f"{rf['patch_points']} patch points ({rf['iterations']} iterations, largest defect "
             f"{rf['max_defect']:.2g}; patch points moved up to "
             f"{rf['seed_to_corrected_max_position_km']:.4g} km from the CR3BP seed). Not "
             "periodic: the LQR is finite-horizon, and LQR and MPC predict with the plant's own "
             f"dynamics ({rf['prediction_model']})."
             + (" Drift tubes computed along it in that model, one per refresh interval (step "
                "0, every apolune, and where the sound method stops), nothing re-used:"
                if s.get("tubes") else " No tube, so no gauge.")]
    lines += tube_lines(s.get("tubes") or [])
    for n in names:
        m = data[n]
        lines.append(
            f"{n}: Delta-V {m['delta_v_mps']:.4g} m/s over {m['revolutions']:.3g} revolutions "
            f"({m['delta_v_per_rev_mps']:.4g} m/s per revolution); {m['activations']} "
            f"activation(s), duty cycle "
            f"{100 * m['duty_cycle']:.3g} %, max deviation {m['max_deviation_km']:.4g} km / "
            f"{m['max_deviation_mps']:.4g} m/s"
            + (f", max gauge while thrust off {m['max_gauge_off']:.3g}"
               if m.get("max_gauge_off") is not None else "")
            + f", {m['time_per_step_ms']:.3g} ms per step, {m['solver_failures']} solver "
              "failure(s).")
    lines += terminal_set_lines(data)
    return lines + [offset_line(s)]


def _table(data: dict) -> tuple[list[str], list[list[str]]]:
    names = [n for n in CONTROLLERS if n in data]
    rows = [[k] + [_fmt(data[n].get(k)) for n in names] for k in TABLE_KEYS]
    return ["metric", *names], rows


def _markdown(problem, data: dict, lines: list[str], figs: list[str]) -> str:
    s = data["settings"]
    head, rows = _table(data)
    out = [f"# Station keeping: {problem.id}", "", problem.description, "",
           (f"{s['revolutions']:.3g} revolutions of {s['steps_per_rev']} steps of "
            f"{s['dt_hours']:.4g} h (period {s['period_hours']:.4g} h); N = {s['n_p']}; trigger "
            f"gauge > 1{ANTICIPATE_TEXT if s.get('anticipate') else ''}, release gauge <= beta = "
            f"{s['beta']} for m = {s['m']} steps; initial "
            f"deviation set {s['initial_set']}; W = {s['disturbance_W']}; RK4 with "
            f"{s['rk4_substeps']} substeps; Q = {s['Q']}, R = {s['R']} (on the thrust "
            f"acceleration); tube slack penalty {s['tube_slack']}."), ""]
    out += [f"- `{n}`: {DESCRIPTIONS[n]}" for n in head[1:]]
    out += ["", "| " + " | ".join(head) + " |", "| --- |" + " ---: |" * (len(head) - 1)]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    out += ["", "## Summary", ""] + [f"- {x}" for x in lines]
    if data.get("events"):
        out += ["", "## Solver events", ""]
        for n, ev in data["events"].items():
            out += [f"- {n} step {e['step']}: {e['reason']} -> {e['fallback']}" for e in ev[:50]]
    out += [""] + [f"![{f}]({f})" for f in figs] + [""]
    return "\n".join(out)


def _html(problem, data: dict, lines: list[str], figs: list[str]) -> str:
    esc = html.escape
    head, rows = _table(data)
    th = "".join(f"<th>{esc(h)}</th>" for h in head)
    tr = "".join("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>" for r in rows)
    li = "".join(f"<li>{esc(x)}</li>" for x in lines)
    imgs = "".join(f'<p><img src="{esc(f)}" alt="{esc(f)}"></p>' for f in figs)
    st = esc(json.dumps(jsonable(data["settings"])))
    return (f"<!doctype html><html><head><meta charset='utf-8'><title>Station keeping: "
            f"{esc(problem.id)}</title></head><body><h1>Station keeping: {esc(problem.id)}</h1>"
            f"<p>{esc(problem.description)}</p><table border='1' cellpadding='4'><tr>{th}</tr>"
            f"{tr}</table><h2>Summary</h2><ul>{li}</ul><h2>Settings</h2><pre>{st}</pre>{imgs}"
            f"</body></html>")


# ------------------------------------------------------------------------------------------------
# figures
# ------------------------------------------------------------------------------------------------
def _figures(problem, run: StationKeepingRun, out: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    units = problem.units
    L = units.length / 1e3
    th = units.time / 3600.0
    pos = list(problem.position_dims)
    ref = run.reference
    names = list(run.results)
    figs = []
    first = run.results[names[0]]
    t = (first.times - first.times[0]) * th

    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*(first.X_ref[:, pos] * L).T, "r--", lw=1.0, label="reference")
    for n, r in run.results.items():
        P = r.X[:, pos] * L
        ax.plot(*P.T, lw=0.7, label=n)
        on = run.active[n]
        if n == "event-mpc" and on.any():
            ax.scatter(*P[:-1][on].T, s=8, c="gold", edgecolors="k", linewidths=0.2,
                       label="event-mpc thrust on")
    ax.set_xlabel("x (km)")
    ax.set_ylabel("y (km)")
    ax.set_zlabel("z (km)")
    ax.set_title(f"{problem.id}: closed loop (rotating frame)")
    ax.legend(fontsize=7)
    save_figure(fig, out / "trajectory.png", bbox_inches="tight")
    figs.append("trajectory.png")

    fig, axs = plt.subplots(1, 2, figsize=(12, 5.5))
    sched = run.schedule
    K = first.U.shape[0]
    box_steps = np.arange(0, min(K, ref.n_steps), max(1, ref.n_steps // 40))
    for ax, (i, j) in zip(axs, [(pos[0], pos[1]), (pos[1], pos[2])], strict=True):
        for k in box_steps if sched is not None else ():
            z = sched.tube(int(k)).zonotope(int(k))
            hw = np.abs(z.G).sum(axis=1)
            ax.add_patch(Rectangle(((z.c[i] - hw[i]) * L, (z.c[j] - hw[j]) * L), 2 * hw[i] * L,
                                   2 * hw[j] * L, fc="lightblue", ec="steelblue", lw=0.4, alpha=0.5))
        ax.plot(first.X_ref[:, i] * L, first.X_ref[:, j] * L, "r--", lw=1.0, label="reference")
        for n, r in run.results.items():
            ax.plot(r.X[:, i] * L, r.X[:, j] * L, lw=0.7, label=n)
            if n == "event-mpc" and run.active[n].any():
                P = r.X[:-1][run.active[n]]
                ax.scatter(P[:, i] * L, P[:, j] * L, s=8, c="gold", edgecolors="k",
                           linewidths=0.2, zorder=5, label="event-mpc thrust on")
        lab = "xyz"
        ax.set_xlabel(f"{lab[i]} (km)")
        ax.set_ylabel(f"{lab[j]} (km)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axs[0].legend(fontsize=7)
    axs[0].set_title("x-y, tube boxes of the first revolution" if sched is not None else "x-y")
    axs[1].set_title("y-z")
    save_figure(fig, out / "projections.png", bbox_inches="tight")
    figs.append("projections.png")
    if sched is not None:
        figs.append(_gauge_figure(problem, run, t, out))
    return figs + _thrust_figures(problem, run, t, out)


def _gauge_figure(problem, run: StationKeepingRun, t: np.ndarray, out: Path) -> str:
    import matplotlib.pyplot as plt

    names, s, ref, sched = list(run.results), run.settings, run.reference, run.schedule
    K = run.results[names[0]].U.shape[0]
    th = problem.units.time / 3600.0
    fig, ax = plt.subplots(figsize=(9, 4))
    for n in names:
        ax.semilogy(t, np.maximum(run.gauges[n], 1e-6), lw=0.8, label=n)
    pred = run.predicted_gauges.get("event-mpc")
    if pred is not None and len(pred):
        ax.semilogy(t[: len(pred)], np.maximum(pred, 1e-6), ":", color="tab:blue", lw=0.7,
                    label="event-mpc: predicted gauge at the next refresh")
    if "event-mpc" in run.active:
        on = run.active["event-mpc"]
        ax.fill_between(t[:-1], 1e-6, 1e6, where=on, step="post", color="gold", alpha=0.3,
                        label="event-mpc thrust on")
    ax.axhline(1.0, color="k", ls="--", lw=0.9, label="trigger (gauge = 1)")
    ax.axhline(s["beta"], color="g", ls=":", lw=0.9, label=f"release (gauge = beta = {s['beta']})")
    for r in sched.refresh_steps(K + 1):
        ax.axvline(max(r, 0) * ref.dt * th, color="0.7", lw=0.5)
    top = max([float(np.nanmax(run.gauges[n])) for n in names]
              + [float(np.nanmax(p)) for p in run.predicted_gauges.values() if len(p)])
    ax.set_ylim(1e-3, max(10.0, 2 * top))
    ax.set_xlabel("time (h)")
    ax.set_ylabel("tube gauge of the true state")
    ax.set_title("gauge (grey lines: tube refreshes)")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3, which="both")
    save_figure(fig, out / "gauge.png", bbox_inches="tight")
    return "gauge.png"


def _thrust_figures(problem, run: StationKeepingRun, t: np.ndarray, out: Path) -> list[str]:
    import matplotlib.pyplot as plt

    units, ref, s, figs = problem.units, run.reference, run.settings, []
    a = s["a_max"]
    thrust_N = s.get("thrust_N") or 1.0
    fig, ax = plt.subplots(figsize=(9, 4))
    for n, r in run.results.items():
        ax.step(t[:-1], np.linalg.norm(r.U_applied, axis=1) * thrust_N * 1e3, where="post",
                lw=0.8, label=n)
    ax.axhline(thrust_N * 1e3, color="k", ls="--", lw=0.8, label="T_max")
    ax.set_yscale("symlog", linthresh=1e-3 * thrust_N * 1e3)
    ax.set_xlabel("time (h)")
    ax.set_ylabel("thrust magnitude (mN)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    save_figure(fig, out / "thrust.png", bbox_inches="tight")
    figs.append("thrust.png")

    fig, ax = plt.subplots(figsize=(9, 4))
    for n, r in run.results.items():
        dv = np.r_[0.0, np.cumsum(delta_v_si(r.U_applied, a, ref.dt, units))]
        ax.plot(t, dv, lw=1.0, label=n)
    ax.set_xlabel("time (h)")
    ax.set_ylabel("cumulative Delta-V (m/s)")
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    save_figure(fig, out / "delta_v.png", bbox_inches="tight")
    figs.append("delta_v.png")
    return figs


# ------------------------------------------------------------------------------------------------
# command line
# ------------------------------------------------------------------------------------------------
__all__ = ["station_keeping_report", "summary_lines", "tube_lines"]
