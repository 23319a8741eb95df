"""``ocreach arch [--only NAME] [--out DIR] [--samples N] [--workers N]``: the ARCH-COMP NLN
suite."""
from __future__ import annotations

import argparse
import datetime
import sys

from ocreach.errors import check_count


def cmd_arch(args: argparse.Namespace) -> int:
    import time

    from ocreach.arch.report import Writer
    from ocreach.arch.suite import arch_ids, machine, run_suite, summary_line
    from ocreach.interrupt import interrupt_requested
    from ocreach.outdir import OutputDir

    t_start = time.perf_counter()
    ids = arch_ids(args.only)
    samples = check_count("--samples", args.samples, 0)
    stride = check_count("--truth-stride", args.truth_stride, 1)
    workers = check_count("--workers", args.workers if args.workers is not None else _cores(), 1)
    out = OutputDir(args.out or "out/arch")
    date = datetime.date.today().isoformat()
    writer = Writer(out, machine(), samples, date, figures=not args.no_figures, order=ids)
    writer.workers = workers
    writer.load["start"] = _load()
    try:
        rows = run_suite(ids, method=args.method, samples=samples, truth_stride=stride,
                         workers=workers, progress=lambda s: print(s, file=sys.stderr, flush=True),
                         on_done=writer.add)
        t_fig = time.perf_counter()
        writer.timing["suite (wall)"] = t_fig - t_start
        writer.write_figures()
        writer.timing["figures (wall)"] = time.perf_counter() - t_fig
        writer.timing["total (wall)"] = time.perf_counter() - t_start
        writer.load["end"] = _load()
        writer.write_tables()
    except BaseException as exc:
        kept = out.keep_partial(f"{type(exc).__name__}: {exc}")
        print(out.describe_partial(kept), file=sys.stderr)
        raise
    if interrupt_requested():
        kept = out.keep_partial("interrupted")
        print(out.describe_partial(kept), file=sys.stderr)
        return 130
    target = out.commit()
    print(summary_line(rows) + f"; {writer.timing['total (wall)']:.0f} s wall on {workers} "
          f"worker(s)")
    figs = f" and {len(writer.by_bench)} figure(s)" if writer.figures else " (no figures)"
    print(f"wrote {target}/arch.csv, arch.md, results.json{figs}")
    return 0


def _load() -> list[float]:
    import os

    return [round(x, 2) for x in os.getloadavg()] if hasattr(os, "getloadavg") else []


def _cores() -> int:
    import os

    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def register(subparsers) -> None:
    """Add the ``arch`` command to the ``ocreach`` CLI."""
    a = subparsers.add_parser("arch", help="the ARCH-COMP NLN benchmarks: verify, time, measure, "
                                           "check against sampled truth")
    a.add_argument("--only", help="benchmarks or instances, comma-separated (e.g. LALO20, "
                                  "lalo20-w001, spre22)")
    a.add_argument("--out", help="output folder (default out/arch)")
    a.add_argument("--samples", type=int, default=2000,
                   help="sampled-truth trajectories per instance (0: no truth check)")
    a.add_argument("--truth-stride", type=int, default=1,
                   help="check the samples at every N-th grid time (and the last)")
    a.add_argument("--method", default=None, choices=["taylor", "sdc", "poly"],
                   help="guaranteed method for every instance (default: each instance's method "
                        "of the suite definition, problems/arch.py)")
    a.add_argument("--workers", type=int, default=None,
                   help="instances run at once on a process pool (default: the cores available; "
                        "1: in this process)")
    a.add_argument("--no-figures", action="store_true")
    a.set_defaults(func=cmd_arch)
