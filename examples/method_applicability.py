"""Which methods run on which problems: `Method.applicable` against an actual run.

For every problem x method pair, asks ``applicable`` and, where it says yes, runs
``ocreach run PROBLEM -m METHOD`` (small sample counts, each in its own process with a time
limit) and records the outcome: ok, diverged (exit 3, truncated result kept), refused or failed
(exit 2, with the message) or timeout.  Usage::

    python examples/method_applicability.py [--problems vdp,dro] [--timeout 300]
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile

from ocreach.reach.base import available_methods, method_class
from ocreach.registry import get_problem, list_problems

SMALL = {"mc": ["samples=100"], "ode": ["samples=20"], "ffoe": ["samples=20"], "ole": ["samples=20"],
         "bvp": ["samples=20"]}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--problems", help="comma-separated ids (default: all)")
    ap.add_argument("--timeout", type=float, default=300.0)
    args = ap.parse_args()
    pids = args.problems.split(",") if args.problems else list(list_problems())
    counts: dict[str, int] = {}
    print("| problem | method | applicable | outcome |\n|---|---|---|---|")
    for pid in pids:
        p = get_problem(pid)
        for m in available_methods():
            ok, why = method_class(m).applicable(p)
            if not ok:
                outcome = "not run"
            else:
                cmd = [sys.executable, "-m", "ocreach.cli", "run", pid, "-m", m,
                       "--out", tempfile.mkdtemp(prefix="ocr-app-") + "/o"]
                for s in SMALL.get(m, []):
                    cmd += ["--set", s]
                try:
                    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
                    err = [ln for ln in proc.stderr.splitlines() if ln.startswith("error: ")]
                    outcome = {0: "ok", 3: "diverged"}.get(proc.returncode, f"exit {proc.returncode}")
                    if err:
                        outcome += ": " + err[-1][7:160]
                except subprocess.TimeoutExpired:
                    outcome = f"timeout > {args.timeout:g} s"
            key = ("yes " if ok else "no ") + outcome.split(":")[0]
            counts[key] = counts.get(key, 0) + 1
            print(f"| {pid} | {m} | {'yes' if ok else 'no: ' + why} | {outcome} |", flush=True)
    print("\n" + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
