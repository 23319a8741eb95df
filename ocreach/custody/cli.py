"""``ocreach custody PROBLEM --observer ... --fov DEG ...`` (Tucker et al. custody; see
:mod:`ocreach.custody.report`)."""
from __future__ import annotations

import argparse
import sys

from ocreach.errors import ProblemError


def _floats(text: str, name: str) -> list[float]:
    try:
        vals = [float(v) for v in str(text).split(",") if v.strip()]
    except ValueError:
        raise ProblemError(f"{name} must be comma-separated numbers; got {text!r}") from None
    if not vals:
        raise ProblemError(f"{name} must name at least one number; got {text!r}")
    return vals


def cmd_custody(args: argparse.Namespace) -> int:
    from ocreach.custody.report import CUSTODY_PROBLEMS, analyse, markdown_table, write_outputs
    from ocreach.outdir import OutputDir, Stages, check_output_dir, write_as_unit

    problems = list(CUSTODY_PROBLEMS) if args.problem == "all" else \
        [p.strip() for p in args.problem.split(",") if p.strip()]
    fovs = _floats(args.fov, "--fov")
    horizons = _floats(args.horizons, "--horizons") if args.horizons else None
    controls = ["box", "ball"] if args.control_set == "both" else [args.control_set]
    observers = [o.strip() for o in args.observer.split(";") if o.strip()]
    name = "all" if args.problem == "all" else problems[0]
    target = check_output_dir(args.out or f"out/custody_{name}")
    out = OutputDir(target)
    mark = Stages()
    done: dict = {}

    def work() -> None:
        mark("analyse")
        cases, per_problem = analyse(problems, observers, fovs, fov_shape=args.fov_shape,
                                     p_required=args.p, horizons=horizons, control_sets=controls,
                                     tol_days=args.tol, step_days=args.step, samples=args.samples,
                                     epoch=args.epoch, mc_samples=args.mc,
                                     progress=lambda s: print(s, file=sys.stderr))
        mark("write")
        paths = write_outputs(cases, per_problem, out.path, figures=not args.no_figures,
                              p_required=args.p)
        done.update(cases=cases, figures=len(paths["figures"]))

    rc = write_as_unit(out, mark, work)
    if rc is not None:
        return rc
    print(markdown_table(done["cases"]))
    print(f"wrote {out.target}: custody.json, custody.md and {done['figures']} figure(s)")
    return 0


def register(subparsers) -> None:
    """Add the ``custody`` command to the ``ocreach`` CLI."""
    c = subparsers.add_parser("custody", help="telescope custody horizon of a manoeuvring object (Tucker et al.)")
    c.add_argument("problem", help="custody-l1 ... custody-l5, custody-gateway, a comma list, or 'all'")
    c.add_argument("--observer", default="geocentre",
                   help="geocentre | L1..L5 | ground:LAT,LON,ALT (deg, deg, km) | orbit:PROBLEM; several with ';'")
    c.add_argument("--fov", required=True, help="full field-of-view angle(s) in deg, in (0, 180), e.g. 0.5,1,2,6")
    c.add_argument("--fov-shape", default="circle", choices=["circle", "square"])
    c.add_argument("--p", type=float, default=0.95, help="required custody probability in (0, 1]")
    c.add_argument("--horizons", help="report horizons in days (default: the problem's, 1,5 or 1,2,3)")
    c.add_argument("--control-set", default="box", choices=["box", "ball", "both"])
    c.add_argument("--tol", type=float, default=0.01, help="bisection tolerance of the horizon (days)")
    c.add_argument("--step", type=float, default=0.5, help="scan step of the horizon bracket (days)")
    c.add_argument("--samples", type=int, default=40, help="bvp directions per horizon")
    c.add_argument("--epoch", default="2026-01-01", help="epoch of t = 0 for ground sites (TDB date)")
    c.add_argument("--mc", type=int, default=0, help="Monte Carlo endpoints per horizon to check the balls")
    c.add_argument("--no-figures", action="store_true")
    c.add_argument("--out", help="output folder (default out/custody_PROBLEM)")
    c.set_defaults(func=cmd_custody)
