"""Command line: ``ocreach list | run | compare | report | bench`` plus registered commands.

Adding a command: write it in your own module with a ``register(subparsers) -> None`` function
(``subparsers.add_parser(...)`` and ``set_defaults(func=...)``; ``func(args) -> int``) and add the
module's dotted name to :data:`COMMAND_MODULES`.  Adding a report kind (``ocreach report KIND``): add
``"KIND": "module:function"`` to :data:`REPORT_KINDS`, with ``function(problem, out_dir, **options)
-> dict`` (the metrics printed as JSON).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
from pathlib import Path

from ocreach.errors import OcreachError, ProblemError, SolverError, check_count
from ocreach.interrupt import install as install_interrupt_handler
from ocreach.interrupt import interrupt_requested
from ocreach.interrupt import restore as restore_interrupt_handler
from ocreach.outdir import Stages, write_as_unit

#: Modules that add commands: each has ``register(subparsers) -> None``.  One line per module.
COMMAND_MODULES: list[str] = [
    "ocreach.arch.cli",
    "ocreach.custody.cli",
    "ocreach.sweep.cli",
]

#: Optional peers of each benchmark (``bench_NAME.py``): [(import name, pip name)].
BENCH_PEERS: dict[str, list[tuple[str, str]]] = {
    "mpc": [("do_mpc", "do-mpc")],
    "flow": [("heyoka", "heyoka")],
}

#: ``ocreach report KIND``: kind -> ``"module:function"`` with ``function(problem, out_dir, **opts) -> dict``.
REPORT_KINDS: dict[str, str] = {
    "lqr-vs-mpc": "ocreach.control.report:lqr_vs_mpc_report",
    "station-keeping": "ocreach.control.stationkeeping.report:station_keeping_report",
    "orbit-maintenance":
        "ocreach.control.stationkeeping.maintenance_report:orbit_maintenance_report",
}


class _Parser(argparse.ArgumentParser):
    """argparse that raises :class:`ProblemError` (naming the option) instead of exiting, so
    ``main([...])`` called in-process returns 2 with the message like every other bad input."""

    def error(self, message: str):  # type: ignore[override]
        raise ProblemError(f"{self.prog}: {message}")


def _parse_sets(items: list[str] | None, option: str = "--set") -> dict[str, str]:
    """``["h_max=400", "input_set=box"]`` -> ``{"h_max": "400", "input_set": "box"}`` (strings;
    converted later by each option's declared type, :func:`ocreach.options.coerce`)."""
    out: dict[str, str] = {}
    for item in items or []:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip():
            raise ProblemError(f"{option} expects KEY=VALUE; got {item!r}")
        out[key.strip()] = raw
    return out


def _split_options(values: dict) -> tuple[dict, dict]:
    """Split ``--set`` values into problem overrides and method options (``problem.NAME=``)."""
    prob, meth = {}, {}
    for k, v in values.items():
        (prob if k.startswith("problem.") else meth)[k.removeprefix("problem.")] = v
    return prob, meth


def _problem(spec: str, raw: dict[str, str]):
    """The problem ``spec`` (id, FILE.py or FILE.py:ID) with ``--set problem.KEY=VALUE`` overrides
    converted by the factory's declared parameter types."""
    from ocreach.options import coerce
    from ocreach.registry import get_problem, problem_factory

    _, factory = problem_factory(spec)
    return get_problem(spec, **coerce(raw, factory, "problem."))


def _method_options(name: str, raw: dict[str, str]) -> dict:
    from ocreach.options import coerce
    from ocreach.reach.base import method_class

    return coerce(raw, method_class(name).Options, f"{name} option ")


def _method(problem, name: str, raw: dict[str, str]):
    """Method ``name`` built with the problem's defaults and the CLI options (typed by its
    ``Options`` dataclass); options, applicability and memory are checked here, before any work."""
    from ocreach.reach.base import method_class

    method = method_class(name)(**{**problem.options_for(name), **_method_options(name, raw)})
    method.check_before(problem)
    return method


def _small(obj, limit: int = 16):
    """``meta`` for ``summary.json``: long arrays and lists replaced by a note (they are in the
    result file's ``meta_json``), so the summary stays small whatever the sample count."""
    if isinstance(obj, dict):
        return {str(k): _small(v, limit) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        if len(obj) > limit or sum(isinstance(v, (list, tuple)) for v in obj) * 4 > limit:
            return f"<{len(obj)} entries, in result.npz>"
        return [_small(v, limit) for v in obj]
    return obj


def _write_run(folder: Path, result, problem, method: str, mark: Stages) -> list[str]:
    """``result.npz``, one figure per projection plane and ``summary.json`` into ``folder``."""
    from ocreach.fileio import atomic_write_text, json_text, jsonable
    from ocreach.reach.plot import plot_projections_over_time

    result.save(folder / "result.npz")
    mark("saved")
    planes = list(problem.planes().values())
    if len(problem.position_dims) >= 3:  # spatial: the x-z view too (halo orbits live in it)
        planes.insert(1, (problem.position_dims[0], problem.position_dims[2]))
    names = ["result.npz"]
    for dims in planes:
        name = f"projection_{dims[0]}_{dims[1]}.png"
        plot_projections_over_time(result, problem, folder / name, dims=dims)
        names.append(name)
        mark(f"figure:{name}")
    summary = {"problem": problem.id, "method": method, "final_time": float(result.times[-1]),
               "truncated": bool(result.meta.get("truncated", False)),
               "meta": _small(jsonable(result.meta))}
    atomic_write_text(folder / "summary.json", json_text(summary))
    mark("summary")
    return names + ["summary.json"]


def cmd_list(args: argparse.Namespace) -> int:
    from ocreach.reach.base import available_methods, method_class
    from ocreach.registry import get_problem, list_problems

    methods = available_methods()
    print("Methods:")
    for name, desc in methods.items():
        print(f"  {name:8s} {desc}")
    print("\nProblems (methods that apply; `ocreach list --why` gives the reasons):")
    for pid, desc in list_problems().items():
        print(f"  {pid:32s} {desc}")
        p = get_problem(pid)
        fit = {m: method_class(m).applicable(p) for m in methods}
        print(f"  {'':32s} methods: {', '.join(m for m, (ok, _) in fit.items() if ok)}")
        if args.why:
            for m, (ok, why) in fit.items():
                if not ok:
                    print(f"  {'':32s}   not {m}: {why}")
    print("\nA problem file: ocreach run FILE.py[:ID] ...; method options: ocreach methods [NAME]")
    return 0


def cmd_methods(args: argparse.Namespace) -> int:
    from ocreach.options import describe_fields, format_fields
    from ocreach.reach.base import COMMON_OPTIONS, available_methods, method_class

    names = [args.name] if args.name else list(available_methods())
    for name in names:
        cls = method_class(name)
        print(f"{name}: {cls.description}")
        print(format_fields(describe_fields(cls.Options)))
        print()
    print("Options every method takes:")
    print(format_fields([{"name": key, "type": type(default).__name__, "default": repr(default),
                          "doc": text} for key, (default, text) in COMMON_OPTIONS.items()]))
    print("\n" + textwrap.fill("Set with --set KEY=VALUE (run) or --set METHOD.KEY=VALUE (compare); "
                               "booleans take true/false/1/0/yes/no/on/off; problem overrides are "
                               "--set problem.KEY=VALUE (see `ocreach problem ID`).", 100))
    return 0


def cmd_problem(args: argparse.Namespace) -> int:
    import inspect

    from ocreach.options import describe_fields, format_fields
    from ocreach.registry import problem_factory

    pid, factory = problem_factory(args.problem)
    doc = inspect.getdoc(factory) or ""
    summary = " ".join(doc.split("\n\n")[0].split())   # the docstring's first paragraph
    print(f"{pid}: {summary}")
    print(format_fields(describe_fields(factory)))
    from ocreach.models.coordinates import COORDINATES

    print(f"  coordinates : str = 'cartesian'\n      every problem: the coordinates the methods "
          f"propagate in, one of {sorted(COORDINATES)} (NAME:key=value,... for settings; "
          "ocreach.models.coordinates); results come back in the model's coordinates")
    return 0


def cmd_run(args: argparse.Namespace) -> int:
    from ocreach.outdir import OutputDir

    prob_raw, opt_raw = _split_options(_parse_sets(args.set))
    problem = _problem(args.problem, prob_raw)
    method = _method(problem, args.method, opt_raw)
    out = OutputDir(args.out or f"out/{problem.id}_{args.method}")
    mark = Stages()
    print(problem.summary())
    done: dict = {}

    def work() -> int | None:
        mark("solve")
        try:
            result = method.solve(problem)
        except SolverError as exc:
            if exc.partial is None:
                raise
            _write_run(out.path, exc.partial, problem, args.method, mark)
            kept = out.keep_partial(f"failed: {exc}")
            print(f"error: {exc}\n{out.describe_partial(kept)}", file=sys.stderr)
            return 3
        mark("solved")
        done.update(result=result, files=_write_run(out.path, result, problem, args.method, mark))
        return None

    rc = write_as_unit(out, mark, work)
    if rc is not None:
        return rc
    rt = done["result"].meta.get("runtime", {})
    print(f"{args.method}: runtime " + ", ".join(f"{k} {v:.3f} s" for k, v in rt.items()))
    print(f"wrote {out.target}: {', '.join(done['files'])}")
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from ocreach.compare import compare, write_comparison
    from ocreach.options import parse_literal
    from ocreach.outdir import OutputDir

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise ProblemError(f"--methods must name at least one method (comma-separated, e.g. "
                           f"mc,ode); got {args.methods!r}")
    if len(set(methods)) != len(methods):
        raise ProblemError(f"--methods names a method twice; got {args.methods!r}")
    prob_raw, opts = _split_options(_parse_sets(args.set))
    problem = _problem(args.problem, prob_raw)
    per_raw: dict[str, dict] = {m: {} for m in methods}
    for key, value in opts.items():
        name, _, opt = key.partition(".")
        if name not in per_raw or not opt:
            raise ProblemError(f"--set {key}={value!r}: compare options are METHOD.KEY=VALUE with "
                               f"METHOD one of {methods}, or problem.KEY=VALUE")
        per_raw[name][opt] = value
    for m in methods:  # every method's options checked before any work
        _method(problem, m, per_raw[m])
    per_method = {m: _method_options(m, per_raw[m]) for m in methods}
    truth = check_count("--truth-samples", parse_literal(args.truth_samples), 1)
    out = OutputDir(args.out or f"out/compare_{problem.id}")
    mark = Stages()
    done: dict = {}

    def work() -> int | None:
        mark("compare")
        cmp = compare(problem, methods, options=per_method, truth_samples=truth, out_dir=out.path,
                      stage=mark)
        mark("compared")
        print(problem.summary())
        print()
        print(cmp.table())
        write_comparison(cmp, out.path)
        mark("written")
        done["cmp"] = cmp
        if cmp.interrupted:
            kept = out.keep_partial("interrupted (Ctrl-C); the table covers the finished methods")
            print(f"\ninterrupted (Ctrl-C): {out.describe_partial(kept)}", file=sys.stderr)
            return 130
        return None

    rc = write_as_unit(out, mark, work)
    if rc is not None:
        return rc
    print(f"\nwrote {out.target}: comparison.md, metrics.json, overlay.png and one result per method")
    return 1 if done["cmp"].errors else 0


def cmd_report(args: argparse.Namespace) -> int:
    if args.kind not in REPORT_KINDS:
        raise OcreachError(f"unknown report {args.kind!r}; available: {sorted(REPORT_KINDS)}")
    import importlib

    mod_name, func_name = REPORT_KINDS[args.kind].split(":")
    report_fn = getattr(importlib.import_module(mod_name), func_name)
    from ocreach.options import coerce
    from ocreach.outdir import OutputDir, check_output_dir

    prob_raw, opt_raw = _split_options(_parse_sets(args.set))
    problem = _problem(args.problem, prob_raw)
    target = check_output_dir(args.out or f"out/report_{problem.id}")
    opts = coerce(opt_raw, report_fn)
    if getattr(args, "controllers", None):
        opts["controllers"] = args.controllers
    if getattr(args, "revolutions", None) is not None:
        opts["revolutions"] = args.revolutions
    if getattr(args, "plant", None):
        opts["plant"] = args.plant
    if getattr(args, "reference", None):
        opts["reference"] = args.reference
    for name in ("runs", "years", "workers", "dask_local"):
        if getattr(args, name, None) is not None:
            if args.kind != "orbit-maintenance":
                raise ProblemError(f"--{name.replace('_', '-')} is an option of the "
                                   f"orbit-maintenance report; got it with {args.kind!r}")
            opts[name] = getattr(args, name)
    if args.kind in ("station-keeping", "orbit-maintenance"):
        opts.setdefault("progress", True)
    check = getattr(report_fn, "check_arguments", None)
    if check is not None:  # every argument checked before the folder's temporary twin exists
        opts = {**check(problem, target, **opts), "as_unit": False}
    out = OutputDir(target)
    mark = Stages()
    done: dict = {}

    def work() -> None:
        mark("report")
        done["metrics"] = report_fn(problem, out.path, **opts)

    rc = write_as_unit(out, mark, work)
    if rc is not None:
        return rc
    print(json.dumps(done["metrics"], indent=2, default=str))
    files = done["metrics"].get("files") if isinstance(done["metrics"], dict) else None
    print(f"wrote {out.target}: " + (", ".join(files) if files else
                                     "report.md, report.html, metrics.json and figures"))
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    bench_dir = Path(__file__).resolve().parent.parent / "benchmarks"
    scripts = sorted(bench_dir.glob("bench_*.py"))
    if args.only:
        scripts = [s for s in scripts if any(o in s.stem for o in args.only.split(","))]
    if not scripts:
        raise ProblemError(f"--only {args.only!r} matches no benchmark in {bench_dir}; available: "
                           f"{[s.stem.removeprefix('bench_') for s in sorted(bench_dir.glob('bench_*.py'))]}")
    import importlib.util

    for s in scripts:  # optional peers checked before anything runs
        for module, pip_name in BENCH_PEERS.get(s.stem.removeprefix("bench_"), ()):
            if importlib.util.find_spec(module) is None:
                raise ProblemError(f"benchmark {s.stem} compares against {pip_name}, which is not "
                                   f"installed: pip install {pip_name}  (or pip install "
                                   f"'ocreach[bench]')")
    if not args.write:
        return _run_benchmarks(scripts, [])
    import os

    from ocreach.outdir import BENCH_DOC_ENV, StagedFiles

    doc = bench_dir.parent / "docs" / "benchmarks.md"
    with StagedFiles(doc.parent, "docs folder") as staged:  # checked before any benchmark runs
        env = {**os.environ, BENCH_DOC_ENV: str(staged.path(doc.name, seed=True))}
        rc = _run_benchmarks(scripts, ["--write"], env)
        if rc != 0:
            print(f"{doc} left unchanged: a benchmark failed (exit {rc}); nothing was written",
                  file=sys.stderr)
            return rc
        staged.commit()
    print(f"wrote {doc}: the sections of {len(scripts)} benchmark(s)")
    return 0


def _run_benchmarks(scripts: list[Path], extra: list[str], env: dict | None = None) -> int:
    rc = 0
    for s in scripts:
        print(f"== {s.name}")
        rc |= subprocess.call([sys.executable, str(s)] + extra, env=env)
    return rc


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="ocreach", description="Reachability and optimal control "
                 "of low-thrust spacecraft (CasADi).")
    ap.add_argument("--threads", type=int, default=None, metavar="N",
                    help="threads of the native batch kernels (default: $OCREACH_THREADS or all cores)")
    sub = ap.add_subparsers(dest="command", required=True, parser_class=_Parser)
    ls = sub.add_parser("list", help="list problems, methods and which methods apply to each problem")
    ls.add_argument("--why", action="store_true", help="say why a method does not apply")
    ls.set_defaults(func=cmd_list)

    mt = sub.add_parser("methods", help="list each method's options (defaults, types, meaning)")
    mt.add_argument("name", nargs="?", help="one method (default: all)")
    mt.set_defaults(func=cmd_methods)

    pr = sub.add_parser("problem", help="list a problem's overrides (--set problem.KEY=VALUE)")
    pr.add_argument("problem", help="problem id, FILE.py or FILE.py:ID")
    pr.set_defaults(func=cmd_problem)

    r = sub.add_parser("run", help="run one method on one problem",
                       epilog="Method options: `ocreach methods METHOD`; problem overrides: "
                              "`ocreach problem PROBLEM`.")
    r.add_argument("problem", help="problem id (see `ocreach list`), FILE.py or FILE.py:ID")
    r.add_argument("--method", "-m", required=True)
    r.add_argument("--out", help="output folder (default out/PROBLEM_METHOD)")
    r.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="method option, or problem.KEY=VALUE for a problem override")
    r.set_defaults(func=cmd_run)

    c = sub.add_parser("compare", help="compare methods on one problem")
    c.add_argument("problem", help="problem id, FILE.py or FILE.py:ID")
    c.add_argument("--methods", required=True, help="comma-separated, e.g. mc,ode")
    c.add_argument("--out", help="output folder (default out/compare_PROBLEM)")
    c.add_argument("--truth-samples", default="2000", help="Monte Carlo truth samples (integer >= 1)")
    c.add_argument("--set", action="append", metavar="METHOD.KEY=VALUE",
                   help="method option (ode.samples=200) or problem.KEY=VALUE")
    c.set_defaults(func=cmd_compare)

    rp = sub.add_parser("report", help="write a report (" + ", ".join(REPORT_KINDS) + ")")
    rp.add_argument("kind", help=" | ".join(REPORT_KINDS))
    rp.add_argument("--problem", default="l2-halo")
    rp.add_argument("--out")
    rp.add_argument("--set", action="append", metavar="KEY=VALUE")
    rp.add_argument("--controllers", help="station-keeping: e.g. event-mpc,tube-mpc,mpc,lqr; "
                    "orbit-maintenance: e.g. xaxis,target-point,corridor,tube-mpc,lqr")
    rp.add_argument("--revolutions", type=float, help="station-keeping: revolutions (default 10)")
    rp.add_argument("--plant", choices=["cr3bp", "ephemeris"],
                    help="station-keeping: true plant (default cr3bp; ephemeris: DE421 point "
                         "masses, the CR3BP as prediction model)")
    rp.add_argument("--reference", choices=["cr3bp", "ephemeris"],
                    help="station-keeping: reference orbit (default cr3bp; ephemeris: the orbit "
                         "corrected in the DE421 plant, needs --plant ephemeris; every controller, the tube "
                         "controllers on tubes about that orbit)")
    rp.add_argument("--runs", type=int, help="orbit-maintenance: Monte Carlo runs per controller "
                    "(default 100)")
    rp.add_argument("--years", type=float, help="orbit-maintenance: years per run (default 1)")
    rp.add_argument("--workers", type=int, help="orbit-maintenance: local worker processes "
                    "(default: the core count)")
    rp.add_argument("--dask-local", type=int, dest="dask_local", metavar="N",
                    help="orbit-maintenance: a Dask LocalCluster of N workers instead")
    rp.set_defaults(func=cmd_report)

    b = sub.add_parser("bench", help="run the benchmarks in benchmarks/")
    b.add_argument("--only", help="comma-separated substrings of benchmark names")
    b.add_argument("--write", action="store_true", help="update docs/benchmarks.md")
    b.set_defaults(func=cmd_bench)

    import importlib

    for mod_name in COMMAND_MODULES:
        importlib.import_module(mod_name).register(sub)
    return ap


def _interrupted_elsewhere(command: str | None) -> str:
    if command in ("run", "compare", "report", "custody"):
        return "interrupted (Ctrl-C) before the output folder was created; nothing kept"
    return f"interrupted (Ctrl-C){f' during {command!r}' if command else ''}"


def main(argv: list[str] | None = None) -> int:
    """Run one command; exit code 0 done, 1 compare with failed methods, 2 bad input or solver
    error (message on stderr), 3 a diverged run (partial result kept), 130 Ctrl-C."""
    previous = install_interrupt_handler()
    command = None
    try:
        args = build_parser().parse_args(argv)
        command = args.command
        from ocreach import parallel

        with parallel.settings(threads=args.threads):  # and the BLAS limit (ocreach.parallel)
            return int(args.func(args) or 0)
    except KeyboardInterrupt:  # run/compare handle their own output folders before this
        print(_interrupted_elsewhere(command), file=sys.stderr)
        return 130
    except OcreachError as exc:
        if interrupt_requested():
            print(_interrupted_elsewhere(command), file=sys.stderr)
            return 130
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `ocreach methods | head`: the reader left; no traceback at exit
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        restore_interrupt_handler(previous)


if __name__ == "__main__":
    sys.exit(main())
