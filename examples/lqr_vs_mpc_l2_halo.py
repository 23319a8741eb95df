"""LQR vs nonlinear MPC station keeping on the L2 halo (Patel & Subbarao Tables 2-3, Fig. 3).

Runs the report (``ocreach report lqr-vs-mpc --problem l2-halo`` does the same) and, with
``--study``, a small sensitivity study: several seeds of the paper's scenario, an initial offset
10x larger (thrust saturation active), the frozen-time DARE LQR, and the MPC with the box thrust
set of Eq. 28 (inscribed in the ball).  Prints markdown tables (used in docs/validation/lqr-vs-mpc.md).

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


def _l2_point(prob) -> np.ndarray:
    """Collinear L2 point of the problem's CR3BP (root of the x-axis force balance)."""
    from scipy.optimize import brentq

    mu = float(prob.param("mu"))

    def gx(x):
        return x - (1 - mu) * (x + mu) / abs(x + mu) ** 3 - mu * (x - 1 + mu) / abs(x - 1 + mu) ** 3

    return np.array([brentq(gx, 1 - mu + 1e-3, 1.5), 0, 0, 0, 0, 0])


def _designs(Q, R, weights_in: str, l2=None, mpc: bool = True) -> dict:
    """The LQR designs compared with the MPC (same weights, same units)."""
    lqr = LQR(Q, R, weights_in=weights_in)
    out = {"lqr": lqr,
           "lqr_const": LQR(Q, R, riccati="constant", linearize_at=0, weights_in=weights_in)}
    if l2 is not None:
        out["lqr_const_L2"] = LQR(Q, R, riccati="constant", linearize_at=l2, weights_in=weights_in)
        out["lqr_dare"] = LQR(Q, R, riccati="dare", weights_in=weights_in)
    if mpc:
        out["mpc"] = MPC(Q, R, weights_in=weights_in, fallback=lqr)
    return out


def _ratio_summary(label: str, res_list: list[dict]) -> str:
    """LQR/MPC ratios (effort, tracking error) per LQR design, min..max over the runs."""
    lines = [f"\n{label}: LQR/MPC over {len(res_list)} seeds (paper: effort 9.80, tracking 1.67)"]
    for name in res_list[0]:
        if name == "mpc":
            continue
        e = [r[name].metrics["effort"] / r["mpc"].metrics["effort"] for r in res_list]
        t = [r[name].metrics["tracking_error"] / r["mpc"].metrics["tracking_error"] for r in res_list]
        lines.append(f"  {name}: effort {min(e):.4f} .. {max(e):.4f}, tracking error "
                     f"{min(t):.4f} .. {max(t):.4f}")
    return "\n".join(lines) + "\n"


def study(n_seeds: int = 5) -> str:
    """Which LQR design gives the paper's Table 2 gap? (docs/validation/lqr-vs-mpc.md)."""
    prob = ocreach.get_problem("l2-halo")
    ref = reference_from_problem(prob, n_sub=2)
    Q, R = np.diag(PAPER_Q), np.diag(PAPER_R)
    box = np.asarray(PAPER_OFFSET_BOX)
    l2 = _l2_point(prob)
    rows, text = [], []
    for weights_in, tag in (("acceleration", "R on accel."), ("normalised", "R on throttle")):
        runs = []
        for seed in range(n_seeds):
            res = compare_controllers(
                prob, _designs(Q, R, weights_in, l2 if seed == 0 else None),
                SimOptions(offset_box=box, seed=seed, progress=False), reference=ref)
            rows.append((f"{tag}, seed {seed}", res))
            runs.append({k: v for k, v in res.items() if k in ("lqr", "lqr_const", "mpc")})
        text.append(_ratio_summary(f"{tag}, one period", runs))
    for weights_in, tag in (("acceleration", "R on accel."), ("normalised", "R on throttle")):
        res = compare_controllers(prob, _designs(Q, R, weights_in),
                                  SimOptions(offset_box=box, seed=0, n_steps=5 * ref.n_steps,
                                             progress=False), reference=ref)
        rows.append((f"{tag}, 5 periods, seed 0", res))
        for name, r in res.items():
            e = np.linalg.norm(r.X - r.X_ref, axis=1)[:: ref.n_steps]
            text.append(f"{tag}, 5 periods, {name}: state error at period ends "
                        + ", ".join(f"{v:.2e}" for v in e))
    lqr = LQR(Q, R)
    res = compare_controllers(
        prob, {"lqr": lqr, "lqr_dare": LQR(Q, R, riccati="dare"),
               "lqr_const": LQR(Q, R, riccati="constant"), "mpc": MPC(Q, R, fallback=lqr),
               "mpc-box": MPC(Q, R, thrust_set="box", fallback=lqr)},
        SimOptions(offset_box=10 * box, seed=0, progress=False), reference=ref)
    rows.append(("R on accel., 10x offset, seed 0", res))
    return _table(rows) + "\n" + "\n".join(text) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/lqr-vs-mpc-l2-halo", help="report folder")
    ap.add_argument("--study", action="store_true", help="also run the sensitivity study")
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)
    data = lqr_vs_mpc_report(ocreach.get_problem("l2-halo"), args.out)
    for name in ("lqr", "lqr_const", "mpc"):
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
