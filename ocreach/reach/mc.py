"""Monte Carlo reachability: random admissible piecewise-constant controls, one vectorised batch.

The samples are true trajectories, so their endpoints are inner points of the reachable set; their
convex hull under-approximates the convex hull of the set.  Control laws are mixed so that both the
interior and the boundary are visited:

* ``random``   – an independent uniform sample of the control set on every segment;
* ``constant`` – one boundary control (full thrust, fixed direction) held on every segment;
* ``bang``     – an independent boundary control (full thrust, random direction) on every segment.

For problems with a :class:`~ocreach.problem.StochasticSpec` (Gaussian initial state and Gaussian
controls) the method samples those distributions instead, as Jain et al. do.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ocreach.errors import ProblemError
from ocreach.problem import Problem
from ocreach.reach.base import _BYTES, _COPIES, Method, SamplingOptions, Timer, requirements
from ocreach.reach.result import ReachResult

LAWS = ("random", "constant", "bang")


def sample_controls(problem: Problem, samples: int, rng: np.random.Generator,
                    mix: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Admissible normalised controls ``(samples, K, n_u)`` and the law index of each sample."""
    K = problem.n_segments
    cs = problem.control_set
    share = np.asarray(mix, dtype=float) / np.sum(mix) * samples
    counts = np.floor(share).astype(int)
    # the remainder goes to the largest fractional parts, never to a law whose fraction is 0
    order = np.argsort(-(share - counts) - (share > 0))
    counts[order[:samples - counts.sum()]] += 1
    law = np.repeat(np.arange(3), counts)
    u = np.empty((samples, K, cs.dim))
    n_r, n_c, n_b = counts
    u[:n_r] = cs.sample(rng, (n_r, K))
    u[n_r:n_r + n_c] = cs.sample_boundary(rng, (n_c, 1))
    u[n_r + n_c:] = cs.sample_boundary(rng, (n_b, K))
    return u, law


def initial_states(problem: Problem, samples: int, rng: np.random.Generator) -> np.ndarray:
    """Initial states: the nominal ``x0``, or samples of ``problem.initial_set`` when given."""
    if problem.initial_set is None:
        return np.tile(problem.x0, (samples, 1))
    x0 = np.asarray(problem.initial_set.sample(samples, rng), dtype=float)
    if x0.shape != (samples, problem.model.n_x):
        raise ProblemError(f"initial_set.sample returned shape {x0.shape}; "
                           f"expected ({samples}, {problem.model.n_x})")
    return x0


class MonteCarlo(Method):
    """Monte Carlo truth: random admissible controls (random, constant and bang-bang laws)."""

    name = "mc"
    description = "Monte Carlo: random admissible piecewise-constant controls (inner samples)"

    @dataclass
    class Options(SamplingOptions):
        """:class:`~ocreach.reach.base.SamplingOptions` with 1000 samples, and the mix of laws."""

        #: number of sampled trajectories, integer >= 1
        samples: int = 1000
        #: fractions of the random / constant / bang-bang control laws (three numbers >= 0)
        mix: tuple = (0.4, 0.2, 0.4)
        #: stochastic problems: also keep every sample's states on ~200 grid times and its
        #: controls on every segment (memory samples * (200 n_x + K n_u) * 8 bytes); by default
        #: only the report and final times are kept, with the sample mean and std at every grid
        #: time in meta; deterministic problems always keep full histories
        histories: bool = False

        def __post_init__(self) -> None:
            super().__post_init__()
            try:
                mix = np.asarray(self.mix, dtype=float)
            except (TypeError, ValueError):
                mix = np.full(0, np.nan)
            if mix.shape != (3,) or not np.all(np.isfinite(mix)) or np.any(mix < 0) or mix.sum() <= 0:
                raise ProblemError(f"mix must be three finite non-negative fractions for the laws "
                                   f"{LAWS}, not all zero; got {self.mix!r}")
            self.mix = tuple(float(v) for v in mix)

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        return (True, "") if problem.stochastic is not None else requirements(problem, bounded=True)

    def solve(self, problem: Problem) -> ReachResult:
        if problem.stochastic is not None:
            return self._solve_stochastic(problem)
        from ocreach.dynamics.flow import propagate

        opt = self.options
        rng = np.random.default_rng(opt.seed)
        timer = Timer()
        with timer("sampling"):
            u, law = sample_controls(problem, opt.samples, rng, opt.mix)
            x0 = initial_states(problem, opt.samples, rng)
        with timer("propagation"):
            traj = propagate(problem.model, x0, u, problem.grid, p=problem.params,
                             rtol=opt.rtol, atol=opt.atol)
        meta = self.base_meta(problem, timer.times)
        meta["control_law"] = law
        meta["control_laws"] = list(LAWS)
        return ReachResult.from_trajectories(problem.grid, traj, controls=u, meta=meta)

    def _stochastic_times(self, problem: Problem) -> np.ndarray:
        """Grid times at which the stochastic Monte Carlo keeps every sample's state: the start,
        the problem's ``extra["report_times"]``, the final time and, with ``histories``, ~200
        evenly spaced grid times."""
        grid = problem.grid
        keep = {0, grid.size - 1}
        if self.options.histories:
            keep |= set(range(0, grid.size, max(1, int(np.ceil((grid.size - 1) / 200)))))
        for t in problem.extra.get("report_times", ()):
            keep.add(int(np.argmin(np.abs(grid - t))))
        return grid[sorted(keep)]

    def memory_estimate(self, problem: Problem) -> float:
        """Deterministic problems: the base estimate (full histories).  Stochastic problems:
        what :meth:`_solve_stochastic` keeps (states at :meth:`_stochastic_times`, controls on
        every segment with ``histories``) plus the working states and controls of one step,
        ``x 8 B x 4 copies``; it used to charge full histories, refusing 100,000 shuttle samples
        (~0.2 GB in use) as 51 GB."""
        if problem.stochastic is None:
            return super().memory_estimate(problem)
        m = problem.model
        per_sample = self._stochastic_times(problem).size * m.n_x + 16 * (m.n_x + m.n_u)
        if self.options.histories:
            per_sample += (problem.grid.size - 1) * m.n_u
        return float(self.options.samples) * per_sample * _BYTES * _COPIES

    def _solve_stochastic(self, problem: Problem) -> ReachResult:
        """Jain et al.'s Monte Carlo: Gaussian x0 and fresh Gaussian controls at every step.

        States are kept at the start, the problem's ``extra["report_times"]`` and the final time;
        with ``histories`` also at ~200 evenly spaced grid times, with every sample's controls
        (a 2000-step horizon with 100,000 samples would otherwise need several GB).  The sample
        mean and std at every grid time are in ``meta["grid_mean"]`` / ``meta["grid_std"]``.
        """
        import dataclasses

        from ocreach.dynamics.stochastic_mc import stochastic_monte_carlo

        defaults = {f.name: f.default for f in dataclasses.fields(self.Options)}
        ignored = [k for k in ("mix", "rtol", "atol") if getattr(self.options, k) != defaults[k]]
        if ignored:
            raise ProblemError(f"option(s) {ignored} do not apply to the stochastic problem "
                               f"{problem.id!r} (Gaussian x0 and controls, the problem's own step "
                               "map); allowed: samples, seed, histories")
        times = self._stochastic_times(problem)
        timer = Timer()
        with timer("propagation"):
            out = stochastic_monte_carlo(problem, samples=self.options.samples,
                                         seed=self.options.seed, times=times,
                                         keep_controls=self.options.histories)
        traj = np.asarray(out["trajectories"])
        meta = self.base_meta(problem, timer.times)
        meta["stochastic"] = True
        meta["grid_mean"], meta["grid_std"] = out["grid_mean"], out["grid_std"]
        meta["controls_note"] = ("controls are the sampled physical controls on every grid segment"
                                 if self.options.histories else
                                 "controls not kept (option histories=True keeps them)")
        return ReachResult.from_trajectories(np.asarray(out["times"]), traj,
                                             controls=out.get("controls"), meta=meta)
