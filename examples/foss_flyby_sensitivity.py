"""Foss Sec. 4.2 (nrho-flyby): how much does the two-digit x1 of the paper decide the flyby, and
does any x1 it allows make the paper's STT run (n = 2, h_max = 60) work?

    python examples/foss_flyby_sensitivity.py [--sobol 256] [--stt] [--half 0.005] [--full]
        [--out docs/figures]

1. Perilune (closest Moon approach within 1 TU, ballistic, :func:`perilune`) for x1 over the
   rounding box ``x1 +- 0.005`` of every component: the nominal x1, the 64 corners and ``--sobol``
   scrambled Sobol points (seed 0).  Distribution of the distance and time, how many have a
   perilune inside (0, 1) TU, how many hit the Moon.
2. The same box under other readings of Sec. 2.2.2 / 4: the epoch as UTC (+69.184 s TDB) and
   +-1 day; x1 in units of the instantaneous Earth-Moon distance at the epoch (positions and
   velocities scaled by ``d(t0) / DU``); the CR3BP (circular Earth-Moon stand-in, same DU/TU).
3. The farthest and closest perilune in the box by a bounded Powell search from the best sweep
   point, and the sweep point at the median: the representative x1 for
   ``examples/foss_fig6_nrho.py --x0 ...``.
4. ``--stt``: for every x1 of the sweep, the paper's run ``stt`` n = 2, h_max = 60 and the
   reduction-light n = 2, h_max = 200 (by default; 10-generator zonotope ball input, ``ball_input =
   "zonotope-coarse"``) against max(1,000 ode extremals, 1,000 MC) at every time (extent ratio,
   branch-and-bound support bounds, containment margin; :func:`foss_fig6_nrho.measure`) and the
   pointwise error of the composed order-2 STT polynomial over the MC extent
   (:func:`foss_fig6_nrho.pointwise_errors`).

``--half`` widens the box (to look beyond the rounding), ``--reading`` runs the STT sweep under
another reading of point 2 above (``--reading "x1 in"``: x1 in units of the Earth-Moon distance),
``--stt-runs`` picks the runs (``o2_h60``, ``o2_h200``, ``o2_h400``).  Prints tables; writes
``OUT/foss_flyby_sensitivity[_halfH][_x1][_RUNS].json`` (per time: min / median / max over the x1;
per x1: perilune and a summary; ``--full`` keeps every x1's arrays).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from ocreach.problems.foss_ephemeris import EPOCH, MOON_RADIUS_KM, X0, flyby_model, perilune
from scipy.optimize import minimize
from scipy.stats import qmc

from ocreach.fileio import atomic_write_text
from ocreach.registry import get_problem
from ocreach.units import EARTH_MOON_FOSS

#: half width of the rounding box of the paper's two-digit x1 (``--half`` widens it to look beyond)
HALF = 0.005
#: the paper's epoch read as UTC, in TDB (TDB - UTC = 37 leap seconds + 32.184 s in 2024)
EPOCH_UTC = "2024-05-01 12:01:09.184"
#: the STT runs of ``--stt`` (foss_fig6_nrho.RUNS-style options; ball input fixed there)
STT_RUN_OPTIONS = {"o2_h60": dict(order=2, h_max=60), "o2_h200": dict(order=2, h_max=200),
                   "o2_h400": dict(order=2, h_max=400)}
#: the default selection (``--stt-runs``)
STT_RUNS = ("o2_h60", "o2_h200")
#: the target: extent within this factor of the truth's at every time
TARGET = 1.5


def box_points(n_sobol: int, half: float = HALF, seed: int = 0) -> tuple[np.ndarray, list[str]]:
    """Nominal x1, the 64 corners of ``x1 +- half`` and ``n_sobol`` scrambled Sobol points."""
    corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * 6, indexing="ij")).reshape(6, -1).T
    sob = qmc.Sobol(6, scramble=True, seed=seed).random(n_sobol) * 2 - 1 if n_sobol else np.zeros((0, 6))
    pts = np.vstack([np.zeros((1, 6)), corners, sob]) * half + X0
    kinds = ["nominal"] + ["corner"] * len(corners) + ["sobol"] * len(sob)
    return pts, kinds


def summary(d: np.ndarray, t: np.ndarray, interior: np.ndarray) -> dict:
    """Percentiles of the perilune distances ``d`` (km) and of the times ``t`` of the interior ones."""
    q = [0, 5, 25, 50, 75, 95, 100]
    return {"distance_km_percentiles": dict(zip(map(str, q), np.percentile(d, q).tolist())),
            "time_percentiles": dict(zip(map(str, q), np.percentile(t[interior], q).tolist()))
            if interior.any() else {},
            "interior": int(interior.sum()), "n": int(d.size),
            "below_moon_radius": int((d < MOON_RADIUS_KM).sum())}


def variants() -> dict:
    """Readings of the paper's setup: name -> (problem overrides of nrho-flyby or None for the
    CR3BP, transform of x1, model)."""
    du = EARTH_MOON_FOSS.length / 1e3  # km
    base = flyby_model()
    d_em = float(np.linalg.norm(base.cache["ephemeris"].position("moon", 0.0, "earth")))  # km at t0
    scale = d_em / du
    same = lambda X: X  # noqa: E731
    readings = {
        "paper (TDB, fixed DU)": ({}, same),
        "epoch read as UTC": ({"epoch": EPOCH_UTC}, same),
        "epoch - 1 day": ({"epoch": "2024-04-30 12:00:00"}, same),
        "epoch + 1 day": ({"epoch": "2024-05-02 12:00:00"}, same),
        f"x1 in units of d_EM(t0) = {d_em:.0f} km": ({}, lambda X: X * scale),
    }
    out = {name: (kw, tf, flyby_model(kw["epoch"]) if kw else base) for name, (kw, tf) in readings.items()}
    out[f"CR3BP (circular, DU = {du:,.0f} km)"] = (None, same, flyby_model(circular=True))
    return out


def extreme_perilune(model, start: np.ndarray, sign: float, half: float = HALF,
                     maxfev: int = 400) -> tuple[np.ndarray, float]:
    """x1 in the box with the largest (``sign = -1``) or smallest (``+1``) closest approach,
    bounded Powell search from ``start``."""
    def obj(z):
        return sign * float(perilune(model, X0 + half * np.clip(z, -1, 1))["distance_km"][0])

    z0 = np.clip((start - X0) / half, -1, 1)
    res = minimize(obj, z0, method="Powell", bounds=[(-1, 1)] * 6,
                   options={"maxfev": maxfev, "xtol": 1e-3, "ftol": 1e-6})
    z = np.clip(res.x, -1, 1)
    snapped = np.where(np.abs(z) > 0.999, np.sign(z), z)  # a corner found up to the tolerance
    best = min((z0, z, snapped), key=obj)
    return X0 + half * best, sign * obj(best)


def stt_sweep(pts: np.ndarray, extremals: int = 1000, overrides: dict | None = None,
              runs: tuple[str, ...] = STT_RUNS) -> list[dict]:
    """The STT runs of :data:`STT_RUNS` and the order-2 pointwise error for every x1 in ``pts``
    (``overrides``: further options of nrho-flyby, e.g. the epoch)."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from foss_fig6_nrho import measure, pointwise_errors, truth_data

    out = []
    for i, x in enumerate(pts):
        p = get_problem("nrho-flyby", x0=x.tolist(), **(overrides or {}))
        tr = truth_data(p, extremals)
        rec = {"x0": x.tolist(), "truth_extent": np.maximum(tr["ode_extent"], tr["mc_extent"]).tolist(),
               "pointwise_err_order2": pointwise_errors(p, tr["mc"], orders=(2,))["order2"]}
        for name in runs:
            r = measure(p, STT_RUN_OPTIONS[name], tr["D"], tr["support"], tr["ref"], divergence_factor=1e250)
            rec[name] = {k: r[k] for k in ("extent_ratio_lower", "extent_ratio_upper", "margin_over_extent", "error")
                         if k in r}
        out.append(rec)
        if i % 20 == 0:
            print(f"  stt sweep {i + 1}/{len(pts)}", flush=True)
    return out


def by_time(sw: list[dict], runs: tuple[str, ...] = STT_RUNS) -> dict:
    """Per time: min / median / max over the swept x1 of the extent ratios (lower, upper bounds),
    the margin, the order-2 pointwise error and the truth extent; and how many exceed TARGET."""
    def stats(a):
        a = np.asarray(a, float)
        return {"min": np.nanmin(a, axis=0).tolist(), "median": np.nanmedian(a, axis=0).tolist(),
                "max": np.nanmax(a, axis=0).tolist()}

    out = {"pointwise_err_order2": stats([r["pointwise_err_order2"] for r in sw]),
           "truth_extent": stats([r["truth_extent"] for r in sw])}
    for name in runs:
        ok = [r[name] for r in sw if "error" not in r[name]]
        out[name] = {"runs": len(ok), "errors": len(sw) - len(ok)}
        if ok:
            lo = np.array([r["extent_ratio_lower"] for r in ok])
            out[name].update(lower=stats(lo), upper=stats([r["extent_ratio_upper"] for r in ok]),
                             margin=stats([r["margin_over_extent"] for r in ok]),
                             n_lower_over_target=(lo > TARGET).sum(axis=0).tolist())
    return out


def compact(obj, digits: int = 5):
    """``obj`` with floats rounded to ``digits`` significant digits (a small JSON file); a
    non-finite float (``inf`` from :func:`first_time`: never) becomes None (JSON null: NaN and
    Infinity are not JSON)."""
    if isinstance(obj, float):
        return float(f"{obj:.{digits}g}") if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: compact(v, digits) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [compact(v, digits) for v in obj]
    return obj


def first_time(times: np.ndarray, values, limit: float) -> float:
    """First grid time (t > 0) with ``value > limit``; inf if none."""
    v = np.asarray(values, float)
    idx = np.flatnonzero(~(v <= limit))
    return float(times[1:][idx[0]]) if idx.size else float("inf")


def stt_rows(sw: list[dict], runs: tuple[str, ...], d: np.ndarray, tt: np.ndarray,
             times: np.ndarray) -> list[dict]:
    """One summary per swept x1: its perilune (``d`` km at ``tt`` TU), per run the largest extent
    ratios, the first times above :data:`TARGET`, the smallest margin and whether it passes (None
    for a run that failed), and the order-2 pointwise error (first time above 0.1, value at 1 TU)."""
    rows = []
    for i, rec in enumerate(sw):
        row = {"perilune_km": float(d[i]), "perilune_time": float(tt[i])}
        for name in runs:
            r = rec[name]
            if "error" in r:
                row[name] = None
                continue
            lo, hi = np.asarray(r["extent_ratio_lower"]), np.asarray(r["extent_ratio_upper"])
            mg = np.asarray(r["margin_over_extent"])
            row[name] = {"max_ratio_upper": float(np.nanmax(hi)), "max_ratio_lower": float(np.nanmax(lo)),
                         "first_t_lower_over_target": first_time(times, lo, TARGET),
                         "first_t_upper_over_target": first_time(times, hi, TARGET),
                         "min_margin": float(np.nanmin(mg)), "first_t_margin_negative": first_time(times, -mg, 0.0),
                         "passes": bool(np.all(hi <= TARGET) and np.all(mg >= 0))}
        row["first_t_pointwise_err_over_0.1"] = first_time(times, rec["pointwise_err_order2"], 0.1)
        row["pointwise_err_at_1"] = float(rec["pointwise_err_order2"][-1])
        rows.append(row)
    return rows


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sobol", type=int, default=256)
    ap.add_argument("--stt", action="store_true", help="also the STT runs for every sweep point")
    ap.add_argument("--extremals", type=int, default=1000)
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--stt-runs", default=",".join(STT_RUNS),
                    help=f"comma-separated STT runs of --stt, from {sorted(STT_RUN_OPTIONS)}")
    ap.add_argument("--full", action="store_true", help="keep every x1's STT arrays in the JSON")
    ap.add_argument("--half", type=float, default=HALF, help="half width of the box (default: the rounding)")
    ap.add_argument("--reading", default="paper", help="the reading of the paper for --stt: a name of "
                    "variants() starting with this text (e.g. 'x1 in units')")
    a = ap.parse_args(argv)
    pts, kinds = box_points(a.sobol, a.half)
    report: dict = {"x1": X0.tolist(), "half_width": a.half, "epoch": EPOCH, "load_average": os.getloadavg(),
                    "points": pts.tolist(), "kinds": kinds, "variants": {}}
    vs = variants()
    print(f"{'variant':42s} {'nominal km':>10s} {'t [TU]':>7s} | box: {'min':>7s} {'5%':>7s} {'median':>7s} "
          f"{'95%':>7s} {'max':>7s} km | perilune in (0,1) | hits Moon")
    for name, (_, tf, model) in vs.items():
        t0 = time.perf_counter()
        r = perilune(model, tf(pts))
        s = summary(r["distance_km"], r["time"], r["interior"])
        s.update(nominal_km=float(r["distance_km"][0]), nominal_time=float(r["time"][0]),
                 nominal_interior=bool(r["interior"][0]), seconds=time.perf_counter() - t0)
        if name.startswith("paper"):
            report["perilune"] = {k: v.tolist() for k, v in r.items()}
        report["variants"][name] = s
        pc = s["distance_km_percentiles"]
        print(f"{name:42s} {s['nominal_km']:10.0f} {s['nominal_time']:7.3f} | {pc['0']:12.0f} {pc['5']:7.0f} "
              f"{pc['50']:7.0f} {pc['95']:7.0f} {pc['100']:7.0f}    | {s['interior']:4d} / {s['n']} | "
              f"{s['below_moon_radius']}")
    base = vs["paper (TDB, fixed DU)"][2]
    d = np.asarray(report["perilune"]["distance_km"])
    tt = np.asarray(report["perilune"]["time"])
    far_x, far_d = extreme_perilune(base, pts[np.argmax(d)], -1.0, a.half)
    near_x, near_d = extreme_perilune(base, pts[np.argmin(d)], +1.0, a.half)
    med = int(np.argmin(np.abs(d - np.median(d))))
    reps = {"farthest": far_x, "median": pts[med], "closest": near_x}
    report["representatives"] = {}
    print("\nrepresentative x1 (paper epoch, fixed DU):")
    for name, x in reps.items():
        r = perilune(base, x)
        report["representatives"][name] = {"x0": x.tolist(), "distance_km": float(r["distance_km"][0]),
                                           "time": float(r["time"][0]), "interior": bool(r["interior"][0])}
        print(f"  {name:8s} perilune {r['distance_km'][0]:8.0f} km at {r['time'][0]:.3f} TU "
              f"(interior {bool(r['interior'][0])}): --x0 {','.join(f'{v:.6f}' for v in x)}")
    if a.stt:
        t0 = time.perf_counter()
        name = next((n for n in vs if n.startswith(a.reading)), None)
        if name is None or vs[name][0] is None:
            raise SystemExit(f"--reading {a.reading!r}: one of {[n for n in vs if vs[n][0] is not None]}")
        kw, tf, model = vs[name]
        report["stt_reading"] = name
        print(f"\nSTT sweep, reading {name!r}")
        pts = tf(pts)
        r = perilune(model, pts)
        d, tt = r["distance_km"], r["time"]
        runs = tuple(r for r in a.stt_runs.split(",") if r)
        bad = [r for r in runs if r not in STT_RUN_OPTIONS]
        if bad or not runs:
            raise SystemExit(f"--stt-runs {a.stt_runs!r}: names from {sorted(STT_RUN_OPTIONS)}")
        sw = stt_sweep(pts, a.extremals, kw, runs)
        report["stt_by_time"] = by_time(sw, runs)
        if a.full:
            report["stt_sweep"] = sw
        report["stt_sweep_seconds"] = time.perf_counter() - t0
        times = np.asarray(get_problem("nrho-flyby").grid)
        rows = stt_rows(sw, runs, d, tt, times)
        report["stt_summary"] = rows
        for name in runs:
            ok = [r for r in rows if r[name] is not None]
            npass = sum(r[name]["passes"] for r in ok)
            ft = np.array([r[name]["first_t_lower_over_target"] for r in ok])
            print(f"\n{name}: {npass} of {len(rows)} x1 within {TARGET}x at every time with no endpoint outside; "
                  f"first time the lower bound exceeds {TARGET}x: min {ft.min():.2f}, median {np.median(ft):.2f}, "
                  f"max {ft.max():.2f} TU; max ratio (lower) over time: min over the box "
                  f"{min(r[name]['max_ratio_lower'] for r in ok):.3g}")
        # by perilune distance
        order = np.argsort(d)
        print(f"\n{'perilune km':>12s} {'t_peri':>6s} | " + " | ".join(
            f"{n}: first t > {TARGET}x, max ratio" for n in runs) + " | order-2 err > 0.1 from, err at 1 TU")
        for i in order[:: max(1, len(order) // 25)].tolist() + [int(order[-1])]:
            row = rows[i]
            cells = []
            for n in runs:
                c = row[n]
                cells.append("error" if c is None else f"{c['first_t_lower_over_target']:5.2f} {c['max_ratio_lower']:9.3g}")
            print(f"{row['perilune_km']:12.0f} {row['perilune_time']:6.3f} | " + " | ".join(cells)
                  + f" | {row['first_t_pointwise_err_over_0.1']:5.2f} {row['pointwise_err_at_1']:9.3g}")
    out = Path(a.out)
    name = "foss_flyby_sensitivity" + ("" if a.half == HALF else f"_half{a.half:g}") + (
        "" if a.reading == "paper" else "_" + a.reading.split()[0].replace(" ", "_")) + (
        "" if a.stt_runs == ",".join(STT_RUNS) else "_" + a.stt_runs.replace(",", "_")) + ".json"
    atomic_write_text(out / name, json.dumps(compact(report), separators=(",", ":")))
    print(f"wrote {out / name}")
    return report


if __name__ == "__main__":
    main()
