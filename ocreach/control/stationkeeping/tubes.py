"""Reachable-set tubes along a reference, zonotope gauges, and tube refresh (Patel & Subbarao Eq. 27).

A :class:`Tube` is one zonotope ``Z_j = {c_j + G_j xi : |xi|_inf <= 1}`` per control step
``k = k0 + j`` of a reference, e.g. the forward reachable set of the uncontrolled ("drift")
dynamics from an initial deviation set with a bounded disturbance -- the set
``R_sdc(t)`` of Patel & Subbarao's NRHO station keeping.

Membership is measured by the **gauge** (Minkowski functional) of the zonotope about its centre,

    gamma_Z(x) = min { t >= 0 : x in c + t G [-1, 1]^q } = min { |xi|_inf : G xi = x - c },

so ``x in Z`` iff ``gamma_Z(x) <= 1`` and ``x`` is in the ``beta``-shrunk tube iff
``gamma <= beta``.  It is a linear program (:func:`gauge`, HiGHS via SciPy, many points in one
block-diagonal LP); :func:`casadi_gauge_constraints` gives the same set as CasADi constraints
``x = c + G xi, -t <= xi_i <= t`` for an NLP (with ``t <= 1`` it is the tube constraint of Eq. 27).
A point off the affine hull of a degenerate zonotope has gauge ``inf``.

:class:`TubeSchedule` re-computes the tube at a fixed phase of a periodic reference (default: every
apolune, as in the paper: "At each apolune ... a tube of forward reachable sets") and answers
gauges and MPC windows across refreshes.  :func:`linear_drift_tube` builds a tube from the
reference's linearisation (STM ``A_k`` and the disturbance input matrix): cheap but **not a
guaranteed enclosure** (no remainder term); :func:`reach_drift_tube` uses the sound ``taylor`` /
``sdc`` methods of :mod:`ocreach.reach` and inherits their ``guaranteed`` flag.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.sparse as sp

from ocreach.control.reference import TrackingReference
from ocreach.control.simulate import _generator
from ocreach.errors import ProblemError, SolverError, check_count
from ocreach.sets.zonotope import Zonotope

#: points per block-diagonal gauge LP
GAUGE_CHUNK = 200
#: Sound-method options of the adaptive tubes (``tube_interval="adaptive"``), measured on nrho-9-2
#: with the paper's sets: 16 sub-steps per 1-h step keep the tube from perilune to the next
#: apolune within 1.32x of the linearised tube's box (4 sub-steps: 3.7x; 1: fails after 24
#: steps); the sub-step may be halved 10 times (at perilune ||A h||_inf of the unscaled CR3BP
#: exceeds what 40 Taylor terms of e^{Ah} bound at 6 halvings); no splitting (a union's zonotope
#: enclosure is looser than restarting the tube).
ADAPTIVE_TUBE_OPTIONS = {"substeps": 16, "max_halvings": 10, "split": False}


# ------------------------------------------------------------------------------------------------
# gauge
# ------------------------------------------------------------------------------------------------
def _gauge_lp(G: np.ndarray, R: np.ndarray) -> np.ndarray:
    """``min_xi |xi|_inf s.t. G_k xi = r_k`` for K points in ONE block-diagonal LP (HiGHS).

    ``G`` (K, r, q) full row rank per block, ``R`` (K, r).  Variables per point ``[xi (q), t]``,
    cost ``sum_k t_k``, ``G_k xi_k = r_k``, ``xi_k - t_k <= 0``, ``-xi_k - t_k <= 0``."""
    from scipy.optimize import linprog

    K, r, q = G.shape
    nv = q + 1
    eq = [sp.csr_matrix(np.hstack([G[k], np.zeros((r, 1))])) for k in range(K)]
    one = np.ones((q, 1))
    blk_ub = sp.csr_matrix(np.block([[np.eye(q), -one], [-np.eye(q), -one]]))
    A_eq = sp.block_diag(eq, format="csc")
    A_ub = sp.kron(sp.identity(K, format="csr"), blk_ub, format="csc")
    cost = np.tile(np.r_[np.zeros(q), 1.0], K)
    lb = np.tile(np.r_[np.full(q, -np.inf), 0.0], K)
    # HiGHS's default feasibility tolerance (1e-7) gave gauges up to 5.7e-7 too high on the NRHO
    # tubes (0.99999991 read as 1.00000043, a false excursion); 1e-9 is as tight as it solves
    # reliably (1e-10 failed with status 4 on a 64-point batch).
    res = linprog(cost, A_ub=A_ub, b_ub=np.zeros(2 * q * K), A_eq=A_eq, b_eq=R.ravel(),
                  bounds=np.column_stack([lb, np.full(nv * K, np.inf)]), method="highs",
                  options={"primal_feasibility_tolerance": 1e-9,
                           "dual_feasibility_tolerance": 1e-9})
    if res.status != 0:
        raise SolverError(f"gauge: HiGHS returned status {res.status} ({res.message}) for the "
                          f"batched gauge LP of {K} point(s)")
    return res.x.reshape(K, nv)[:, -1]


def gauge(centers: Any, generators: Any, points: Any, *, rtol: float = 1e-9) -> np.ndarray:
    """Gauge ``gamma_k = min{|xi|_inf : G_k xi = x_k - c_k}`` of K points in K zonotopes.

    ``centers`` (K, n) or (n,), ``generators`` (K, n, q) or (n, q) (broadcast), ``points`` (K, n)
    or (n,).  Returns (K,) (a float for a single point).  Points off the affine hull of their
    zonotope (distance > ``rtol`` times the zonotope's size) get ``inf``.  Square invertible
    generator blocks use the closed form ``|G^-1 (x - c)|_inf``; the rest one batched LP per
    ``GAUGE_CHUNK`` points.
    """
    X = np.asarray(points, dtype=float)
    single = X.ndim == 1
    X = np.atleast_2d(X)
    K, n = X.shape
    C = np.broadcast_to(np.asarray(centers, dtype=float), (K, n))
    G = np.asarray(generators, dtype=float)
    if G.ndim == 2:
        G = np.broadcast_to(G, (K,) + G.shape)
    if G.ndim != 3 or G.shape[:2] != (K, n):
        raise ProblemError(f"gauge: generators must have shape ({K}, {n}, q) or ({n}, q); got "
                           f"{np.shape(generators)}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(C)) and np.all(np.isfinite(G))):
        raise ProblemError("gauge: centers, generators and points must be finite")
    R = X - C
    out = np.full(K, np.inf)
    q = G.shape[2]
    if q == 0:
        out[np.all(R == 0, axis=1)] = 0.0
        return float(out[0]) if single else out
    U, s, _ = np.linalg.svd(G, full_matrices=False)  # (K, n, m), (K, m)
    scale = np.maximum(np.abs(G).sum(axis=(1, 2)), 1e-300)
    tol = rtol * np.maximum(s[:, :1], 1e-300)
    rank = (s > tol).sum(axis=1)
    for rk in np.unique(rank):
        idx = np.flatnonzero(rank == rk)
        if rk == 0:
            zero = np.linalg.norm(R[idx], axis=1) <= rtol * scale[idx]
            out[idx[zero]] = 0.0
            continue
        Ur = U[idx, :, :rk]  # (k, n, rk)
        Rr = np.einsum("kni,kn->ki", Ur, R[idx])
        off = np.linalg.norm(R[idx] - np.einsum("kni,ki->kn", Ur, Rr), axis=1) > rtol * scale[idx]
        on = idx[~off]
        if on.size == 0:
            continue
        Gr = np.einsum("kni,knq->kiq", U[on, :, :rk], G[on])
        Rr = Rr[~off]
        if rk == q:  # invertible in the range: unique factors
            xi = np.linalg.solve(Gr, Rr[..., None])[..., 0]
            out[on] = np.abs(xi).max(axis=1)
            continue
        # row equilibration: HiGHS's feasibility tolerances are absolute (1e-7), far above the
        # entries of a small tube (W parts ~1e-10 DU), so each row is scaled to max |G_ij| = 1
        row = np.abs(Gr).max(axis=2, keepdims=True)
        Gr, Rr = Gr / row, Rr / row[..., 0]
        for s0 in range(0, on.size, GAUGE_CHUNK):
            sl = slice(s0, s0 + GAUGE_CHUNK)
            out[on[sl]] = _gauge_lp(Gr[sl], Rr[sl])
    return float(out[0]) if single else out


@dataclass(frozen=True)
class CasadiGauge:
    """CasADi form of ``gamma_Z(x) <= t``: ``lbg <= g <= ubg`` in the variables ``xi`` (and ``t``)."""

    g: Any
    lbg: np.ndarray
    ubg: np.ndarray
    xi: Any


def casadi_gauge_constraints(c: Any, G: Any, x: Any, t: Any) -> CasadiGauge:
    """``x = c + G xi``, ``-t <= xi_i <= t`` as CasADi constraints (new symbol ``xi`` of ``x``'s type).

    ``c``, ``G`` numbers or symbols (``n``, ``n x q``); ``x`` an SX/MX column; ``t`` a number or a
    scalar symbol.  Minimising ``t`` subject to these gives :func:`gauge`; ``t = 1`` is the tube
    constraint of Patel & Subbarao Eq. 27, ``t = 1 + s`` with a penalised slack ``s >= 0`` its soft
    version (used by :class:`~ocreach.control.MPC` with ``tube_slack``).
    """
    import casadi as ca

    if not isinstance(x, (ca.SX, ca.MX)) or x.shape[1] != 1:
        raise ProblemError(f"casadi_gauge_constraints: x must be a CasADi SX/MX column; got "
                           f"{type(x).__name__} {getattr(x, 'shape', None)}")
    n = x.shape[0]
    Gm = G if isinstance(G, (ca.SX, ca.MX)) else ca.DM(np.asarray(G, float).reshape(n, -1))
    q = Gm.shape[1]
    xi = type(x).sym("xi", q)
    g = ca.vertcat(x - c - ca.mtimes(Gm, xi), xi - t, -xi - t)
    lbg = np.r_[np.zeros(n), np.full(2 * q, -np.inf)]
    ubg = np.r_[np.zeros(n), np.zeros(2 * q)]
    return CasadiGauge(g, lbg, ubg, xi)


# ------------------------------------------------------------------------------------------------
# tubes
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Tube:
    """Zonotope ``Z_j = (centers[j], generators[j])`` at reference step ``k = k0 + j``, ``j < len``.

    ``guaranteed`` says whether the sets enclose every admissible trajectory (a sound
    reachability method) or are an estimate (e.g. :func:`linear_drift_tube`); ``source`` names
    the method.  Generator counts are padded with zero columns to a common ``q``.
    """

    centers: np.ndarray
    generators: np.ndarray
    k0: int = 0
    guaranteed: bool = False
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        c = np.array(self.centers, dtype=float)
        G = np.array(self.generators, dtype=float)
        if c.ndim != 2 or c.shape[0] < 1:
            raise ProblemError(f"tube centers must have shape (length, n_x); got {c.shape}")
        if G.ndim != 3 or G.shape[:2] != c.shape:
            raise ProblemError(f"tube generators must have shape ({c.shape[0]}, {c.shape[1]}, q); "
                               f"got {G.shape}")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(G))):
            raise ProblemError("tube centers and generators must be finite")
        if int(self.k0) != self.k0:
            raise ProblemError(f"tube k0 (first reference step) must be an integer; got {self.k0!r}")
        c.flags.writeable = False
        G.flags.writeable = False
        object.__setattr__(self, "centers", c)
        object.__setattr__(self, "generators", G)
        object.__setattr__(self, "k0", int(self.k0))

    @classmethod
    def from_zonotopes(cls, zonotopes: list, k0: int = 0, **kw) -> Tube:
        """A tube from a list of :class:`~ocreach.sets.Zonotope` (one per step from ``k0``)."""
        if not zonotopes:
            raise ProblemError("Tube.from_zonotopes needs at least one zonotope")
        zs = [z.to_zonotope() for z in zonotopes]
        n = zs[0].dim
        if any(z.dim != n for z in zs):
            raise ProblemError(f"tube zonotopes must all have dimension {n}; got "
                               f"{sorted({z.dim for z in zs})}")
        q = max(z.n_generators for z in zs)
        G = np.zeros((len(zs), n, q))
        for j, z in enumerate(zs):
            G[j, :, : z.n_generators] = z.G
        return cls(np.stack([z.c for z in zs]), G, k0=k0, **kw)

    def __len__(self) -> int:
        return int(self.centers.shape[0])

    @property
    def dim(self) -> int:
        return int(self.centers.shape[1])

    @property
    def n_generators(self) -> int:
        return int(self.generators.shape[2])

    @property
    def k_end(self) -> int:
        """Last reference step covered."""
        return self.k0 + len(self) - 1

    def _j(self, k) -> np.ndarray:
        j = np.asarray(k) - self.k0
        if np.any(j < 0) or np.any(j >= len(self)):
            raise ProblemError(f"tube covers reference steps {self.k0}..{self.k_end}; got step(s) "
                               f"{np.atleast_1d(k).tolist()[:5]}")
        return j

    def zonotope(self, k: int) -> Zonotope:
        j = int(self._j(k))
        return Zonotope(self.centers[j], self.generators[j])

    def gauge(self, k, x) -> np.ndarray | float:
        """Gauge of ``x`` (n,) at step ``k``, or of ``x`` (K, n) at steps ``k`` (K,)."""
        j = self._j(k)
        return gauge(self.centers[j], self.generators[j], x)

    def shifted(self, k0: int) -> Tube:
        """The same sets from reference step ``k0`` (a tube about a periodic reference, whole
        periods later)."""
        return replace(self, k0=k0)

    def scaled(self, beta: float) -> Tube:
        """The tube shrunk (``beta < 1``) or grown about its centres: generators times ``beta``."""
        if not np.isfinite(beta) or beta <= 0:
            raise ProblemError(f"tube scale beta must be a finite number > 0; got {beta!r}")
        return Tube(self.centers, beta * self.generators, k0=self.k0, guaranteed=False,
                    source=f"{self.source} x {beta:g}", meta=self.meta)

    def half_widths(self) -> np.ndarray:
        """Interval-hull half widths ``sum_i |g_i|`` per step, (length, n)."""
        return np.abs(self.generators).sum(axis=2)

    def check_for(self, n_x: int, k_from: int, k_to: int) -> Tube:
        """Raise :class:`ProblemError` unless the tube has dimension ``n_x`` and covers
        ``k_from..k_to``."""
        if self.dim != n_x:
            raise ProblemError(f"tube has dimension {self.dim}; the model state has {n_x}")
        if self.k0 > k_from or self.k_end < k_to:
            raise ProblemError(f"tube covers reference steps {self.k0}..{self.k_end}; it must cover "
                               f"{k_from}..{k_to} (length {k_to - k_from + 1})")
        return self


def apolune_phase(reference: TrackingReference, secondary: tuple[float, ...] | None = None) -> int:
    """Reference step of the apolune: the largest distance from the secondary (CR3BP: the Moon at
    ``(1 - mu, 0, 0)``; ``mu`` is the model's parameter of that name)."""
    if not reference.periodic:
        raise ProblemError(f"the apolune phase needs a periodic reference; '{reference.name}' is not")
    return int(np.argmax(secondary_distance(reference, secondary, "apolune_phase")[:-1]))


def refresh_phase(reference: TrackingReference, phase: int | str) -> int:
    """The reference step ``phase`` names: ``"apolune"`` (:func:`apolune_phase`) or a step
    ``0..M-1`` of the periodic reference."""
    M = reference.n_steps
    p = apolune_phase(reference) if isinstance(phase, str) and phase == "apolune" else phase
    if isinstance(p, (str, bool)) or int(p) != p or not 0 <= int(p) < M:
        raise ProblemError(f"phase must be 'apolune' or a reference step 0..{M - 1}; got {phase!r}")
    return int(p)


def secondary_distance(reference: TrackingReference, secondary: tuple[float, ...] | None,
                       caller: str) -> np.ndarray:
    """Distance of every reference state from the secondary (default, CR3BP: the Moon at
    ``(1 - mu, 0, 0)``, ``mu`` the model's parameter of that name), (n_steps + 1,)."""
    if secondary is None:
        if "mu" not in reference.model.param_names:
            raise ProblemError(f"{caller}: give secondary=(x, y, z) for a model without 'mu'")
        mu = reference.model.param("mu", reference.params)
        secondary = (1.0 - mu, 0.0, 0.0)
    s = np.asarray(secondary, float)
    return np.linalg.norm(reference.X[:, : s.size] - s, axis=1)


class TubeSchedule:
    """Tubes refreshed at a fixed phase of a periodic reference.

    ``builder(k) -> Tube`` computes the tube that starts at reference step ``k`` (a refresh step).
    Refreshes happen at ``k = phase + i * every * M`` (``M`` steps per period; ``every`` in
    revolutions), or every ``interval`` steps if given (a short-horizon tube refreshed more often
    than once per revolution); the tube active at step ``k`` is the one of the last refresh
    ``<= k``.  Each tube must cover its refresh interval plus ``lookahead`` steps (MPC windows
    reach across the next refresh: the steps after it are constrained by the next tube).  With
    ``reuse=True`` (the builder depends only on the phase of the periodic reference, e.g. a tube
    about the reference) a tube is built once per phase and re-used, shifted by whole periods.
    ``phases`` (reference steps ``0..M-1``, instead of ``phase``/``every``/``interval``): refresh
    at each of these steps of every period, i.e. intervals of different lengths (short ones around
    perilune, see :func:`sound_drift_partition`).

    ``starts`` (a non-periodic reference, e.g. the ephemeris-corrected orbit; instead of
    ``phase``/``every``/``interval``/``phases``): the refresh steps along the whole reference,
    increasing from 0; the last tube covers up to ``end`` - 1 (default: the reference's last
    step).  Every tube is built once for its own stretch of the reference (no re-use).
    """

    def __init__(self, builder: Callable[[int], Tube], reference: TrackingReference, *,
                 phase: int | str = "apolune", every: int = 1, lookahead: int = 0,
                 reuse: bool = True, interval: int | None = None,
                 phases: Sequence[int] | None = None, starts: Sequence[int] | None = None,
                 end: int | None = None) -> None:
        self.starts: np.ndarray | None = None
        if starts is not None:
            self._init_starts(builder, reference, starts, end, phases, interval)
            return
        if not reference.periodic:
            raise ProblemError(f"tube refresh needs a periodic reference (a period to refresh on) "
                               f"or starts (refresh steps along it); '{reference.name}' has none")
        M = reference.n_steps
        self.reference = reference
        self.phase = refresh_phase(reference, phase)
        self.every = check_count("every (revolutions between refreshes)", every, 1)
        self.lookahead = check_count("lookahead", lookahead, 0)
        self.interval = (self.every * M if interval is None
                         else check_count("interval (steps between refreshes)", interval, 1))
        self.builder = builder
        self.reuse = reuse
        self._tubes: dict[int, Tube] = {}
        #: refresh offsets from ``phase`` within one period (None: every ``interval`` steps)
        self.offsets: np.ndarray | None = None
        if phases is not None:
            if interval is not None:
                raise ProblemError("give either phases (refresh steps per period) or interval "
                                   "(steps between refreshes), not both")
            ph = sorted({self._phase_step(p, M) for p in phases})
            if not ph:
                raise ProblemError("phases (refresh steps per period) must not be empty")
            self.phase = ph[0]
            self.offsets = np.array([p - ph[0] for p in ph], dtype=int)
            self.interval = int(np.diff(np.r_[self.offsets, M]).max())  # the longest interval

    def _init_starts(self, builder: Callable[[int], Tube], reference: TrackingReference,
                     starts: Sequence[int], end: int | None, phases: Any, interval: Any) -> None:
        """The non-periodic mode: refresh at ``starts`` (see the class docstring)."""
        if reference.periodic:
            raise ProblemError(f"starts (refresh steps along a non-periodic reference) needs a "
                               f"non-periodic reference; '{reference.name}' is periodic (use "
                               f"phase, interval or phases)")
        if phases is not None or interval is not None:
            raise ProblemError("give either starts (refresh steps along a non-periodic "
                               "reference) or phases/interval (a periodic one), not both")
        N = reference.n_steps
        end = N if end is None else check_count("end (step after the last tube step)", end, 2)
        if end > N:
            raise ProblemError(f"end (step after the last tube step) must be <= {N} (the "
                               f"reference's steps); got {end}")
        st = [check_count("starts (refresh steps)", r, 0) for r in starts]
        if not st or st[0] != 0 or st[-1] >= end or any(b <= a for a, b in zip(st, st[1:])):
            raise ProblemError(f"starts (refresh steps) must increase strictly from 0 and be < "
                               f"end = {end}; got {list(starts)[:10]}")
        self.reference, self.builder = reference, builder
        self.starts, self.end = np.array(st, dtype=int), int(end)
        self.phase, self.every, self.lookahead, self.reuse = 0, 1, 0, False
        self.offsets = None
        self.interval = int(np.diff(np.r_[self.starts, end]).max())  # the longest interval
        self._tubes = {}

    @staticmethod
    def _phase_step(p: Any, M: int) -> int:
        if isinstance(p, (bool, np.bool_)) or int(p) != p or not 0 <= int(p) < M:
            raise ProblemError(f"phases must be reference steps 0..{M - 1}; got {p!r}")
        return int(p)

    def refresh_step(self, k: int) -> int:
        """The refresh step at or before ``k`` (steps before the first phase use the one a period
        earlier, i.e. ``phase - interval``)."""
        if self.starts is not None:
            if not 0 <= int(k) < self.end:
                raise ProblemError(f"the tubes cover reference steps 0..{self.end - 1}; got "
                                   f"step {k}")
            return int(self.starts[np.searchsorted(self.starts, int(k), side="right") - 1])
        if self.offsets is None:
            return self.phase + ((int(k) - self.phase) // self.interval) * self.interval
        base = self._period_start(k)
        j = int(np.searchsorted(self.offsets, int(k) - base, side="right")) - 1
        return base + int(self.offsets[j])

    def _period_start(self, k: int) -> int:
        """The step of ``phase`` in the period containing step ``k`` (``phases`` mode)."""
        M = self.reference.n_steps
        return self.phase + ((int(k) - self.phase) // M) * M

    def next_refresh(self, r: int) -> int:
        """The refresh step after the refresh step ``r`` (non-periodic: ``end`` after the last)."""
        if self.starts is not None:
            j = int(np.searchsorted(self.starts, int(r), side="right"))
            return int(self.starts[j]) if j < self.starts.size else self.end
        if self.offsets is None:
            return int(r) + self.interval
        base = self._period_start(r)
        j = int(np.searchsorted(self.offsets, int(r) - base, side="right"))
        return base + (int(self.offsets[j]) if j < self.offsets.size else self.reference.n_steps)

    def refresh_steps(self, n_steps: int) -> list[int]:
        """Refresh steps whose intervals touch steps ``0..n_steps-1`` (the first may be < 0)."""
        out, r = [], self.refresh_step(0)
        while r < n_steps and (self.starts is None or r < self.end):
            out.append(r)
            r = self.next_refresh(r)
        return out

    def tube(self, k: int) -> Tube:
        """The tube active at step ``k``."""
        r = self.refresh_step(k)
        if r not in self._tubes:
            M = self.reference.n_steps
            base = next((b for b in self._tubes.values() if (b.k0 - r) % M == 0), None) \
                if self.reuse else None
            t = base.shifted(r) if base is not None else self._built(r)
            self._tubes[r] = t
        return self._tubes[r]

    def _built(self, r: int) -> Tube:
        """The builder's tube for refresh step ``r``, checked to cover its interval."""
        t = self.builder(r)
        if not isinstance(t, Tube):
            raise ProblemError(f"tube builder must return a Tube; got {type(t).__name__}")
        return t.check_for(self.reference.model.n_x, r, self.next_refresh(r) - 1 + self.lookahead)

    def is_refresh(self, k: int) -> bool:
        return self.refresh_step(k) == int(k)

    def gauge(self, k: int, x: np.ndarray) -> float:
        return float(self.tube(k).gauge(k, x))

    def window(self, k: int, n: int, beta: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """Sets at steps ``k+1..k+n`` for :meth:`MPC.set_tube`: ``(c (n, n_x), G (n, n_x, q))``;
        steps after a refresh come from the next tube (generators zero-padded to a common q),
        scaled by ``beta``."""
        steps = np.arange(k + 1, k + n + 1)
        tubes = [self.tube(int(s)) for s in steps]
        q = max(t.n_generators for t in tubes)
        nx = tubes[0].dim
        c = np.empty((n, nx))
        G = np.zeros((n, nx, q))
        for i, (s, t) in enumerate(zip(steps, tubes, strict=True)):
            j = int(t._j(s))
            c[i] = t.centers[j]
            G[i, :, : t.n_generators] = beta * t.generators[j]
        return c, G

    @property
    def n_generators(self) -> int:
        """Most generators of the tubes of one period (the MPC's tube constraint is sized by it)."""
        if self.starts is not None:
            return max(self.tube(int(r)).n_generators for r in self.starts)
        if self.offsets is None:
            return self.tube(self.phase).n_generators
        return max(self.tube(self.phase + int(o)).n_generators for o in self.offsets)


# ------------------------------------------------------------------------------------------------
# drift tubes
# ------------------------------------------------------------------------------------------------
def disturbance_input(reference: TrackingReference, velocity_dims: tuple[int, ...]) -> np.ndarray:
    """``Bw_k = d x_{k+1} / d w`` (M, n_x, n_w) for an acceleration ``w`` on ``velocity_dims`` held
    over each step, from the prediction model's ``B_k``: the control enters as ``f_u = E S`` (``E``
    selecting the velocity states, ``S`` constant), so ``Bw_k = B_k S^+``."""
    model = reference.model
    reference.linearize()
    fu = np.asarray(model.jac_fun(reference.X[0], reference.U[0], reference.t0,
                                  reference.params)[2])
    vel = list(velocity_dims)
    other = [i for i in range(model.n_x) if i not in vel]
    if other and np.any(fu[other] != 0):
        raise ProblemError("disturbance_input: the control must act on the velocity states only "
                           "(f_u = E S); this model's f_u has other rows")
    S = fu[vel]
    return reference.B @ np.linalg.pinv(S)


def linear_drift_tube(reference: TrackingReference, k0: int, length: int, initial: Any,
                      disturbance: Any, velocity_dims: tuple[int, ...], *,
                      order: float = 5.0) -> Tube:
    """Drift tube from the reference's linearisation (zero thrust): NOT a guaranteed enclosure.

    ``Z_0 = x_ref(k0) + G0 [-1, 1]^q0`` (``initial``: G0 as a scalar, diagonal or matrix), and
    ``Z_{j+1} = A_{k0+j} (Z_j - x_ref) + x_ref(k0+j+1) (+) Bw_{k0+j} W [-1, 1]^m`` (``A_k`` the STM
    of a step, ``Bw_k`` :func:`disturbance_input`, ``W`` = ``disturbance``), reduced to ``order``
    (Girard) when it has more generators.  ``length`` sets (``k0..k0+length-1``).  The
    linearisation neglects the second-order terms, so trajectories from the corners of a large
    initial set can leave it.
    """
    n = reference.model.n_x
    length = check_count("length (tube steps)", length, 1)
    reference.linearize()
    G0 = _generator("initial deviation set", initial, n)
    Wg = _generator("disturbance W", disturbance, len(velocity_dims))
    Bw = disturbance_input(reference, velocity_dims)
    idx = reference.gains_index(np.arange(k0, k0 + length))
    zs = []
    G = G0
    for j in range(length):
        k = k0 + j
        zs.append(Zonotope(reference.state(k), G))
        if j == length - 1:
            break
        i = idx[j]
        G = np.hstack([reference.A[i] @ G, Bw[i] @ Wg])
        if G.shape[1] > order * n:
            G = Zonotope(np.zeros(n), G).reduce(order).G
    return Tube.from_zonotopes(zs, k0=k0, guaranteed=False, source="linear (STM + W, no remainder)",
                               meta={"order": order, "initial": G0.tolist(), "W": Wg.tolist()})


def linear_fallback(lin: Tube, method: str, err: Exception) -> Tube:
    """The linear tube ``lin`` standing in for the sound ``method`` that failed with ``err``: not
    guaranteed, its source labelled, ``meta["fallback_reason"]`` the error on one line (at most
    300 characters)."""
    reason = " ".join(str(err).split())[:300]
    return replace(lin, guaranteed=False, source=f"{lin.source}; {method} failed",
                   meta={**lin.meta, "fallback_from": method, "fallback_reason": reason})


def _drift_problem(problem, reference: TrackingReference, k0: int, length: int, initial: Any):
    """The zero-thrust problem from ``x_ref(k0) + G0 [-1, 1]^q`` on the reference grid
    ``t_{k0} .. t_{k0+length-1}`` (``a_max`` = 1e-300), in the reference's model (the problem's
    for its periodic orbit; the plant's frame model for an ephemeris-corrected reference)."""
    model = reference.model  # the reference's own model (e.g. the ephemeris frame model)
    if "a_max" not in model.param_names:
        raise ProblemError(f"a sound drift tube needs a model with an 'a_max' thrust parameter; "
                           f"{model.name} has {list(model.param_names)}")
    p = np.array(reference.params, float)
    p[list(model.param_names).index("a_max")] = 1e-300
    x0 = reference.state(k0)
    G0 = _generator("initial deviation set", initial, model.n_x)
    return replace(
        problem, id=f"{problem.id}-drift", model=model, x0=x0.copy(), params=p, reference=None,
        grid=reference.time(np.arange(k0, k0 + length)), initial_set=Zonotope(x0, G0),
        method_options={})


def reach_drift_tube(problem, reference: TrackingReference, k0: int, length: int, initial: Any,
                     disturbance: float, method: str = "taylor", *, partial: bool = False,
                     **options) -> Tube:
    """Drift tube from a sound reachability method (``ocreach.reach(problem, "taylor" | "sdc")``).

    The problem is re-posed from ``x_ref(k0)`` on the reference grid ``t_{k0} .. t_{k0+length-1}``
    with the initial set ``x_ref(k0) + G0 [-1, 1]^q`` (``initial``: scalar, diagonal or matrix),
    the disturbance ``w`` (the box ``+-w`` on the velocity rates, Patel & Subbarao's ``W_gen = w
    I_3``) and the thrust parameter ``a_max`` set to 1e-300 (zero thrust up to a term far below
    rounding; the enclosure is of that problem, so it contains the drift).  Union results (split
    parts) are replaced by their zonotope enclosure.  The tube's ``guaranteed`` flag is the
    result's.  A method that cannot enclose the whole horizon (e.g. near perilune) raises its
    :class:`SolverError`; with ``partial=True`` the tube of the steps it did enclose is returned
    instead (shorter than ``length``, ``meta["failure"]`` the method's message).
    """
    from ocreach.reach.base import reach

    length = check_count("length (tube steps)", length, 2)
    drift = _drift_problem(problem, reference, k0, length, initial)
    failure = None
    try:
        res = reach(drift, method, disturbance=disturbance, **options)
    except SolverError as err:
        res = getattr(err, "partial", None)
        if not partial or res is None or not res.sets:
            raise
        failure = " ".join(str(err).split())
    zs = res.sets
    if zs is None or (failure is None and len(zs) != length):
        raise SolverError(f"{method} returned {0 if zs is None else len(zs)} sets; need {length}")
    meta = {"method": method, "options": dict(options),
            "flowpipe_hull": _flowpipe_hull(res.tubes)}
    if failure is not None:
        meta["failure"] = failure
    return Tube.from_zonotopes([z.to_zonotope() for z in zs], k0=k0,
                               guaranteed=bool(res.meta.get("guaranteed", False)),
                               source=f"{method} (sound reachability)", meta=meta)


def _flowpipe_hull(tubes: list | None) -> list[list[float]] | None:
    """``[lo, hi]`` of the interval hulls of a result's time-interval sets (every trajectory of
    the enclosed problem stays in them between the grid points), or None without them."""
    if not tubes:
        return None
    hulls = [s.interval_hull() for s in tubes]
    return [np.min([h.lo for h in hulls], axis=0).tolist(),
            np.max([h.hi for h in hulls], axis=0).tolist()]


def sound_drift_partition(problem, reference: TrackingReference, start: int, stop: int,
                          initial: Any, disturbance: float, method: str = "taylor", *,
                          max_tubes: int = 16, **options) -> list[Tube]:
    """Guaranteed drift tubes covering reference steps ``start .. stop - 1``, each restarted from
    the initial deviation set where the previous one stops.

    A sound method started from ``x_ref(r) + G0 [-1, 1]^q`` encloses the zero-thrust drift only up
    to where its first-order remainder can no longer be closed (on the 9:2 NRHO: a few steps after
    perilune from the apolune; docs/validation/station-keeping.md).  Greedily from ``r = start``:
    the tube from ``r`` (:func:`reach_drift_tube` with ``partial=True``) covers ``r .. r' - 1``,
    ``r'`` its last enclosed step, and the next tube starts at ``r'``; if that one cannot take a
    single step, the restart moves back a step (at most to ``r + 1``).  Returns the tubes (``k0`` =
    their refresh steps, each covering up to the next refresh); raises :class:`SolverError` if no
    restart makes progress or more than ``max_tubes`` tubes would be needed.
    """
    start, stop = check_count("start", start, 0), check_count("stop", stop, 1)
    if stop <= start:
        raise ProblemError(f"sound_drift_partition: stop ({stop}) must be > start ({start})")
    max_tubes = check_count("max_tubes", max_tubes, 1)

    def build(r: int) -> Tube:
        t = reach_drift_tube(problem, reference, r, stop - r + 1, initial, disturbance, method,
                             partial=True, **options)
        if not t.guaranteed:
            raise SolverError(f"{method} is not a guaranteed method here (tube from step {r})")
        return t

    tubes = [build(start)]
    while tubes[-1].k_end < stop:
        prev = tubes[-1]
        if len(tubes) >= max_tubes:
            raise SolverError(f"sound_drift_partition: more than max_tubes = {max_tubes} tubes "
                              f"needed for steps {start}..{stop - 1} ({method} stopped at step "
                              f"{prev.k_end})")
        for r in range(prev.k_end, prev.k0, -1):
            nxt = build(r)
            if nxt.k_end > r:
                break
        else:
            raise SolverError(f"sound_drift_partition: {method} cannot take a step from any "
                              f"restart in {prev.k0 + 1}..{prev.k_end}: "
                              f"{(prev.meta or {}).get('failure', '')[:300]}")
        tubes[-1] = _head(prev, r - prev.k0)
        tubes.append(nxt)
    tubes[-1] = _head(tubes[-1], stop - tubes[-1].k0)
    return tubes


def _head(tube: Tube, n: int) -> Tube:
    """The first ``n`` sets of ``tube`` (steps ``k0 .. k0 + n - 1``)."""
    return replace(tube, centers=tube.centers[:n], generators=tube.generators[:n])


__all__ = ["CasadiGauge", "Tube", "TubeSchedule", "apolune_phase", "casadi_gauge_constraints",
           "disturbance_input", "gauge", "linear_drift_tube", "linear_fallback", "reach_drift_tube",
           "refresh_phase", "secondary_distance", "sound_drift_partition"]
