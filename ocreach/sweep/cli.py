"""``ocreach sweep SPEC --out DIR [...]``, ``ocreach sweep status DIR``, ``ocreach sweep collect DIR``."""
from __future__ import annotations

import argparse
import sys

from ocreach.sweep.errors import SweepError


def cmd_sweep(args: argparse.Namespace) -> int:
    from ocreach.sweep.collect import format_status, status, write_table

    if args.target in ("status", "collect"):
        if not args.dir:
            raise SweepError(f"usage: ocreach sweep {args.target} DIR")
        if args.target == "status":
            st = status(args.dir)
            print(format_status(st))
            return 0 if st["failed"] == 0 else 1
        for p in write_table(args.dir, args.format):
            print(f"wrote {p}")
        return 0
    if args.dir:
        raise SweepError(f"unexpected argument {args.dir!r}; the output folder is --out DIR")
    if not args.out:
        raise SweepError("ocreach sweep SPEC needs --out DIR (new, or the folder of an earlier run "
                         "of the same spec to resume it)")
    from ocreach.sweep.run import run_sweep
    from ocreach.sweep.spec import load_spec

    spec = load_spec(args.target)
    print(f"sweep {spec.name or args.target!r}: {len(spec)} task(s)", file=sys.stderr)
    summary = run_sweep(spec, args.out, workers=args.workers, scheduler=args.scheduler,
                        dask_local=args.dask_local, serial=args.serial,
                        retry_failed=args.retry_failed, max_in_flight=args.max_in_flight,
                        limit=args.limit, chunk=args.chunk, progress=not args.no_progress)
    print(summary.line())
    return 0 if summary.failed == 0 else 1


def register(subparsers) -> None:
    """Add ``sweep`` to the ``ocreach`` command line."""
    s = subparsers.add_parser(
        "sweep", help="run a sweep spec (process pool or Dask), resumable; or status|collect DIR",
        description="ocreach sweep SPEC --out DIR runs (or resumes) the spec; "
                    "ocreach sweep status DIR and ocreach sweep collect DIR [--format csv,parquet] "
                    "read a sweep folder.  See docs/sweep.md.")
    s.add_argument("target", help="a spec file (.json/.toml), or 'status' / 'collect'")
    s.add_argument("dir", nargs="?", help="the sweep folder (for status / collect)")
    s.add_argument("--out", help="output folder (re-use it to resume)")
    ex = s.add_mutually_exclusive_group()
    ex.add_argument("--workers", type=int, help="local worker processes (default: the core count)")
    ex.add_argument("--dask-local", type=int, metavar="N", help="a Dask LocalCluster of N workers")
    ex.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="a running Dask scheduler")
    ex.add_argument("--serial", action="store_true", help="run in this process, one at a time")
    s.add_argument("--retry-failed", action="store_true", help="run failed tasks again")
    s.add_argument("--max-in-flight", type=int, help="chunks submitted at once (default 2 x workers)")
    s.add_argument("--limit", type=int, help="stop after this many new tasks")
    s.add_argument("--chunk", type=int, help="tasks sent to a worker together (default: auto, "
                   "1 to 16)")
    s.add_argument("--no-progress", action="store_true", help="no progress bar")
    s.add_argument("--format", default="csv", help="collect: csv, parquet or csv,parquet")
    s.set_defaults(func=cmd_sweep)
