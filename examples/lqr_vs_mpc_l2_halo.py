"""LQR vs nonlinear MPC station keeping on the L2 halo (Patel & Subbarao Tables 2-3, Fig. 3).

Runs the report (``ocreach report lqr-vs-mpc --problem l2-halo`` does the same) and, with
``--study``, a small sensitivity study: several seeds of the paper's scenario, an initial offset
10x larger (thrust saturation active), the frozen-time DARE LQR, and the MPC with the box thrust
set of Eq. 28 (inscribed in the ball).  Prints markdown tables (used in docs/validation.md).

Usage: ``python examples/lqr_vs_mpc_l2_halo.py [--out DIR] [--study] [--seeds 5]``.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

import ocreach
from ocreach.control import LQR, MPC, SimOptions, compare_controllers, reference_from_problem
from ocreach.control.report import PAPER_OFFSET_BOX, PAPER_Q, PAPER_R, lqr_vs_mpc_report


def _table(rows: list[tuple[str, dict]]) -> str:
    head = ("| case | controller | effort (DU/TU^2) | tracking error | delta-v (m/s) | "
            "max thrust ratio | time/step (ms) | fallbacks |\n| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    lines = [head]
    for case, res in rows:
        for name, r in res.items():
            m = r.metrics
            lines.append(f"| {case} | {name} | {m['effort']:.5g} | {m['tracking_error']:.5g} | "
                         f"{m['delta_v']:.4g} | {m['max_thrust_ratio']:.3f} | "
                         f"{1e3 * m['time_per_step']:.2f} | {m['fallbacks']} |")
    return "\n".join(lines)


def study(n_seeds: int = 5) -> str:
    prob = ocreach.get_problem("l2-halo")
    ref = reference_from_problem(prob, n_sub=2)
    Q, R = np.diag(PAPER_Q), np.diag(PAPER_R)
    box = np.asarray(PAPER_OFFSET_BOX)
    rows = []
    ratios = []
    for seed in range(n_seeds):
        lqr = LQR(Q, R)
        res = compare_controllers(prob, {"lqr": lqr, "mpc": MPC(Q, R, fallback=lqr)},
                                  SimOptions(offset_box=box, seed=seed, progress=False), reference=ref)
        rows.append((f"paper, seed {seed}", res))
        ratios.append((res["mpc"].metrics["effort"] / res["lqr"].metrics["effort"],
                       res["mpc"].metrics["tracking_error"] / res["lqr"].metrics["tracking_error"]))
    lqr = LQR(Q, R)
    res = compare_controllers(
        prob, {"lqr": lqr, "lqr-dare": LQR(Q, R, riccati="dare"), "mpc": MPC(Q, R, fallback=lqr),
               "mpc-box": MPC(Q, R, thrust_set="box", fallback=lqr)},
        SimOptions(offset_box=10 * box, seed=0, progress=False), reference=ref)
    rows.append(("10x offset, seed 0", res))
    lqr = LQR(Q, R)
    res = compare_controllers(
        prob, {"lqr-dare": LQR(Q, R, riccati="dare"), "mpc-box": MPC(Q, R, thrust_set="box", fallback=lqr)},
        SimOptions(offset_box=box, seed=0, progress=False), reference=ref)
    rows.append(("paper, seed 0", res))
    r = np.array(ratios)
    summary = (f"\nMPC/LQR over {n_seeds} seeds (paper scenario): effort ratio "
               f"{r[:, 0].min():.4f} .. {r[:, 0].max():.4f}, tracking-error ratio "
               f"{r[:, 1].min():.4f} .. {r[:, 1].max():.4f}\n")
    return _table(rows) + "\n" + summary


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/lqr-vs-mpc-l2-halo", help="report folder")
    ap.add_argument("--study", action="store_true", help="also run the sensitivity study")
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)
    data = lqr_vs_mpc_report(ocreach.get_problem("l2-halo"), args.out)
    for name in ("lqr", "mpc"):
        m = data[name]
        print(f"{name}: effort {m['effort']:.6g} DU/TU^2, tracking error {m['tracking_error']:.6g}, "
              f"delta-v {m['delta_v']:.4g} m/s, max thrust ratio {m['max_thrust_ratio']:.4f}, "
              f"{1e3 * m['time_per_step']:.2f} ms/step, fallbacks {m['fallbacks']}")
    print(f"report written to {args.out}/report.md")
    if args.study:
        print(study(args.seeds))
    return 0


if __name__ == "__main__":
    sys.exit(main())
