"""STT splitting on Van der Pol with an uncertain initial box (docs/validation/stt.md).

    python examples/stt_split_vdp.py

For x0 +- 0.1 and x0 +- 0.3 (h_max = 100; order 2, and order 3 at +- 0.1) prints, per option set,
the warm runtime (second run), the number of parts at the end, the share of 6000 Monte Carlo
endpoints inside the union of the parts' outlines, and the outline area over the MC hull; first
the load average and the BLAS/OpenMP thread variables (runtimes depend on both).  The unsplit
order-2 run diverges at x0 +- 0.3 (the method raises SolverError).
"""
from __future__ import annotations

import dataclasses
import os
import time

from ocreach.errors import SolverError
from ocreach.geometry import hull_area, outline_area, points_in_polygons
from ocreach.reach.mc import MonteCarlo
from ocreach.reach.stt import STTReach
from ocreach.registry import get_problem
from ocreach.sets import Interval

CASES = {
    0.1: [dict(order=2), dict(order=2, split="factor", max_parts=2, split_tol=0.002),
          dict(order=2, split="factor", max_parts=4, split_tol=0.002),
          dict(order=2, split="factor", max_parts=8, split_tol=0.002),
          dict(order=2, split="box", max_parts=8, split_tol=0.002),
          dict(order=3), dict(order=3, split="factor", max_parts=8, split_tol=0.002)],
    0.3: [dict(order=2), dict(order=2, split="factor", max_parts=16), dict(order=2, split="box", max_parts=16),
          dict(order=2, split="factor", max_parts=32)],
}


def main() -> None:
    threads = {v: os.environ.get(v) for v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    print(f"load average {os.getloadavg()}, threads {threads}")
    base = get_problem("vdp")
    for width, rows in CASES.items():
        p = dataclasses.replace(base, initial_set=Interval(base.x0 - width, base.x0 + width))
        end = MonteCarlo(samples=6000, seed=3).solve(p).points[-1]
        for opts in rows:
            m = STTReach(h_max=100, **opts)
            try:
                m.solve(p)
                t0 = time.perf_counter()
                r = m.solve(p)
                dt = time.perf_counter() - t0
            except SolverError as exc:
                print(f"+-{width} {opts}: SolverError: {exc}")
                continue
            polys = r.sets[-1].outline((0, 1), pieces=64)
            print(f"+-{width} {opts}: warm {dt:.2f} s, parts {r.meta['parts'][-1]}, "
                  f"covered {100 * points_in_polygons(end, polys).mean():.1f} %, "
                  f"area / MC hull {outline_area(polys) / hull_area(end):.2f}")


if __name__ == "__main__":
    main()
