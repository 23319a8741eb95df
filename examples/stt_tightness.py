"""Tightness of the STT sets measured with the exact polynomial-zonotope queries.

    python examples/stt_tightness.py [--problem dro|vdp] [--input ball|box] [--order 2] [--h-max 400]
                                     [--reduction pca|girard] [--pruned-box exact|bound]
                                     [--ball-input auto|zonotope|zonotope-coarse|pz] [--dirs 64] [--mc 20000]
                                     [--out docs/figures] [--tag _h800] [--reduce-group parallel]

Truth: the support function of the true reachable set by direct multiple shooting
(:func:`ocreach.reach.direct.transcription_support`, piecewise-constant controls on the grid, the
problem's control set or the chosen input set) in ``--dirs`` directions per plane, cached in
``OUT/stt_truth_<problem>_<input>.json``; Monte Carlo endpoints (``--mc``) for coverage.
STT: support lower/upper bounds from branch and bound on the set's own factors
(:func:`ocreach.sets.pz_exact.support_bounds`), hull-area bounds (inner polygon of witnesses,
outer polygon of upper bounds), membership of every MC endpoint (witness / certificate).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

import ocreach
from ocreach.fileio import atomic_write_text
from ocreach.geometry import circle_directions, polygon_area
from ocreach.problem import ControlSet
from ocreach.reach.mc import MonteCarlo
from ocreach.registry import get_problem
from ocreach.sets.pz_exact import hull_polygons, membership, support_bounds


def truth_support(problem, planes, dirs, path: Path) -> dict:
    from ocreach.reach.direct import transcription_support

    if path.exists():
        return json.loads(path.read_text())
    out = {}
    for tag, dims in planes.items():
        vals = []
        for d in dirs:
            z = np.zeros(problem.model.n_x)
            z[list(dims)] = d
            vals.append(transcription_support(problem, z))
        out[tag] = vals
        print(f"truth {tag}: {len(vals)} directions")
    atomic_write_text(path, json.dumps(out))
    return out


def halfplane_area(D, h):
    from scipy.optimize import linprog

    from ocreach.sets.pz_exact import _halfplane_polygon

    # Chebyshev centre of {x : D x <= h} as the interior point
    res = linprog(np.r_[0, 0, -1], A_ub=np.c_[D, np.linalg.norm(D, axis=1)], b_ub=h,
                  bounds=[(None, None), (None, None), (0, None)])
    inner_pt = res.x[:2]
    return polygon_area(_halfplane_polygon(D, h, inner_pt))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problem", default="dro")
    ap.add_argument("--input", default="ball")
    ap.add_argument("--order", type=int, default=2)
    ap.add_argument("--h-max", type=int, default=400)
    ap.add_argument("--reduction", default="pca")
    ap.add_argument("--pruned-box", default="bound", choices=("exact", "bound"))
    ap.add_argument("--ball-input", default="auto")
    ap.add_argument("--dirs", type=int, default=64)
    ap.add_argument("--mc", type=int, default=20000)
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--tag", default="", help="appended to the output file name (e.g. _h800)")
    ap.add_argument("--reduce-group", default=None, help="stt's reduce_group option (e.g. parallel)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    p = get_problem(a.problem)
    if p.control_set.kind != a.input:
        p = dataclasses.replace(p, control_set=ControlSet(a.input, p.model.n_u))
    planes = {k: list(v) for k, v in p.planes().items()}
    dirs = circle_directions(a.dirs)
    truth = truth_support(p, planes, dirs, out / f"stt_truth_{a.problem}_{a.input}.json")
    opts = dict(order=a.order, h_max=a.h_max, input_set=a.input, reduction=a.reduction,
                ball_input=a.ball_input, pruned_box=a.pruned_box, reduce_group=a.reduce_group)
    ocreach.reach(p, "stt", **opts)  # warm-up
    t0, c0 = time.perf_counter(), time.process_time()
    res = ocreach.reach(p, "stt", **opts)
    runtime, cpu = time.perf_counter() - t0, time.process_time() - c0
    mc = MonteCarlo(samples=a.mc, seed=11, mix=(0.3, 0.2, 0.5)).solve(p).points[-1]
    S = res.sets[-1]
    report = {"problem": a.problem, "input": a.input, "options": opts, "runtime_warm_s": runtime,
              "runtime_warm_cpu_s": cpu, "load_average": os.getloadavg()}
    for tag, dims in planes.items():
        P = S.project(dims)
        ht = np.asarray(truth[tag])
        ht = np.maximum(ht, (mc[:, dims] @ dirs.T).max(axis=0))      # MC can only raise a lower bound
        width = ht + ht[(np.arange(dirs.shape[0]) + dirs.shape[0] // 2) % dirs.shape[0]]
        t0 = time.perf_counter()
        sb = support_bounds(P, dirs)
        t_sb = time.perf_counter() - t0
        enc = np.asarray(P.support(dirs))
        inner, outer, _ = hull_polygons(P, (0, 1), n_dirs=256)
        true_area = halfplane_area(dirs, ht)
        mem = membership(P, mc[:, dims])
        report[tag] = {
            "support_lower_excess_max": float(np.max((sb.lower - ht) / width)),
            "support_upper_excess_max": float(np.max((sb.upper - ht) / width)),
            "support_upper_excess_mean": float(np.mean((sb.upper - ht) / width)),
            "support_lower_min": float(np.min((sb.lower - ht) / width)),
            "enclosure_excess_max": float(np.max((enc - ht) / width)),
            "gap_max": float(np.max(sb.gap / width)),
            "support_query_s": t_sb,
            "area_lower": polygon_area(inner), "area_upper": polygon_area(outer),
            "true_hull_area_outer_64": true_area,
            "area_ratio_lower": polygon_area(inner) / true_area,
            "area_ratio_upper": polygon_area(outer) / true_area,
            "mc_inside_witness": int(np.sum(mem.inside)), "mc_outside_certified": int(np.sum(mem.outside)),
            "mc_undecided": int(np.sum(mem.status == 0)), "mc_samples": int(mc.shape[0]),
        }
        print(tag, json.dumps(report[tag], indent=1))
    print(f"stt runtime (warm): {runtime:.3f} s")
    atomic_write_text(out / f"stt_tightness_{a.problem}_{a.input}"
                      f"{'-' + a.ball_input if a.input == 'ball' else ''}_o{a.order}"
                      f"{'' if a.reduction == 'pca' else '_' + a.reduction}"
                      f"{'' if a.pruned_box == 'exact' or a.order < 3 else '_bound'}{a.tag}.json", json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
