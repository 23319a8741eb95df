"""Command line: ``ocreach list | run | compare | report | bench``."""
from __future__ import annotations

import argparse
import ast
import json
import subprocess
import sys
from pathlib import Path

from ocreach.errors import OcreachError


def _parse_sets(items: list[str] | None) -> dict:
    """``["h_max=400", "input_set=box"]`` -> ``{"h_max": 400, "input_set": "box"}``."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise OcreachError(f"--set expects key=value; got {item!r}")
        key, raw = item.split("=", 1)
        try:
            out[key.strip()] = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            out[key.strip()] = raw
    return out


def _split_options(values: dict) -> tuple[dict, dict]:
    """Split ``--set`` values into problem overrides and method options (``problem.NAME=``)."""
    prob, meth = {}, {}
    for k, v in values.items():
        (prob if k.startswith("problem.") else meth)[k.removeprefix("problem.")] = v
    return prob, meth


def cmd_list(args: argparse.Namespace) -> int:
    from ocreach.problem import list_problems
    from ocreach.reach.base import available_methods

    print("Problems:")
    for pid, desc in list_problems().items():
        print(f"  {pid:32s} {desc}")
    print("Methods:")
    for name, desc in available_methods().items():
        print(f"  {name:32s} {desc}")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from ocreach.plot import plot_projections_over_time
    from ocreach.problem import get_problem
    from ocreach.reach.base import reach
    from ocreach.reach.result import atomic_write_text, jsonable

    prob_over, opts = _split_options(_parse_sets(args.set))
    problem = get_problem(args.problem, **prob_over)
    print(problem.summary())
    result = reach(problem, args.method, **opts)
    out = Path(args.out or f"out/{problem.id}_{args.method}")
    out.mkdir(parents=True, exist_ok=True)
    result.save(out / "result.npz")
    planes = list(problem.planes().values())
    if len(problem.position_dims) >= 3:  # spatial: the x-z view too (halo orbits live in it)
        planes.insert(1, (problem.position_dims[0], problem.position_dims[2]))
    for dims in planes:
        plot_projections_over_time(result, problem, out / f"projection_{dims[0]}_{dims[1]}.png",
                                   dims=dims)
    summary = {"problem": problem.id, "method": args.method, "meta": result.meta,
               "final_time": float(result.times[-1])}
    atomic_write_text(out / "summary.json", json.dumps(jsonable(summary), indent=2))
    rt = result.meta.get("runtime", {})
    print(f"{args.method}: runtime " + ", ".join(f"{k} {v:.3f} s" for k, v in rt.items()))
    print(f"wrote {out}/result.npz, summary.json and {len(planes)} figure(s)")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from ocreach.compare import compare, write_comparison
    from ocreach.problem import get_problem

    prob_over, opts = _split_options(_parse_sets(args.set))
    problem = get_problem(args.problem, **prob_over)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    per_method: dict[str, dict] = {m: {} for m in methods}
    for key, value in opts.items():
        name, _, opt = key.partition(".")
        if name not in per_method or not opt:
            raise OcreachError(f"--set {key}={value!r}: compare options are METHOD.KEY=VALUE with "
                               f"METHOD one of {methods}, or problem.KEY=VALUE")
        per_method[name][opt] = value
    out = args.out or f"out/compare_{problem.id}"
    cmp = compare(problem, methods, options=per_method, truth_samples=args.truth_samples,
                  out_dir=out)
    print(problem.summary())
    print()
    print(cmp.table())
    paths = write_comparison(cmp, out)
    print(f"\nwrote {paths['table']}, {paths['metrics']} and {paths['figure']}")
    if cmp.interrupted:
        print("interrupted; the finished methods are in the table and files above", file=sys.stderr)
        return 130
    return 1 if cmp.errors else 0


def cmd_report(args: argparse.Namespace) -> int:
    if args.kind != "lqr-vs-mpc":
        raise OcreachError(f"unknown report {args.kind!r}; available: ['lqr-vs-mpc']")
    from ocreach.control.report import lqr_vs_mpc_report
    from ocreach.problem import get_problem

    prob_over, opts = _split_options(_parse_sets(args.set))
    problem = get_problem(args.problem, **prob_over)
    out = Path(args.out or f"out/report_{problem.id}")
    metrics = lqr_vs_mpc_report(problem, out, **opts)
    print(json.dumps(metrics, indent=2, default=str))
    print(f"wrote {out}/report.md, report.html, metrics.json and figures")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    bench_dir = Path(__file__).resolve().parent.parent / "benchmarks"
    scripts = sorted(bench_dir.glob("bench_*.py"))
    if args.only:
        scripts = [s for s in scripts if any(o in s.stem for o in args.only.split(","))]
    if not scripts:
        raise OcreachError(f"no benchmark scripts found in {bench_dir}")
    rc = 0
    for s in scripts:
        print(f"== {s.name}")
        cmd = [sys.executable, str(s)] + (["--write"] if args.write else [])
        rc |= subprocess.call(cmd)
    return rc


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="ocreach", description="Reachability and optimal control "
                                 "of low-thrust spacecraft (CasADi).")
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="list problems and methods").set_defaults(func=cmd_list)

    r = sub.add_parser("run", help="run one method on one problem")
    r.add_argument("problem", help="problem id (see `ocreach list`) or a .py file")
    r.add_argument("--method", "-m", required=True)
    r.add_argument("--out", help="output folder (default out/PROBLEM_METHOD)")
    r.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="method option, or problem.KEY=VALUE for a problem override")
    r.set_defaults(func=cmd_run)

    c = sub.add_parser("compare", help="compare methods on one problem")
    c.add_argument("problem")
    c.add_argument("--methods", required=True, help="comma-separated, e.g. mc,ode")
    c.add_argument("--out", help="output folder (default out/compare_PROBLEM)")
    c.add_argument("--truth-samples", type=int, default=2000)
    c.add_argument("--set", action="append", metavar="METHOD.KEY=VALUE",
                   help="method option (ode.samples=200) or problem.KEY=VALUE")
    c.set_defaults(func=cmd_compare)

    rp = sub.add_parser("report", help="write a report (lqr-vs-mpc)")
    rp.add_argument("kind", help="lqr-vs-mpc")
    rp.add_argument("--problem", default="l2-halo")
    rp.add_argument("--out")
    rp.add_argument("--set", action="append", metavar="KEY=VALUE")
    rp.set_defaults(func=cmd_report)

    b = sub.add_parser("bench", help="run the benchmarks in benchmarks/")
    b.add_argument("--only", help="comma-separated substrings of benchmark names")
    b.add_argument("--write", action="store_true", help="update docs/benchmarks.md")
    b.set_defaults(func=cmd_bench)
    from ocreach.sweep.cli import register as register_sweep
    register_sweep(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted; finished files are kept", file=sys.stderr)
        return 130
    except OcreachError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
