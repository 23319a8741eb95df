"""STT polynomial-zonotope reachability (Foss, Rosengren & Biria, AMOS 2024, Algorithm 1).

The dynamics with inputs are written for the augmented state ``z = [x; u]`` (Foss Eq. 12) and
discretised on the problem's grid by state-transition tensors integrated once along the reference
(control 0, the centre of the input set; Eq. 11-13, :func:`ocreach.dynamics.flow.stt`).  One step maps the
deviation set through the STT polynomial (Eq. 18-19)::

    dZ_k     = dR_k x U_k                                  (Eq. 17, U_k with fresh identifiers)
    dR_{k+1} = (+)_{j=1..n} 1/j! Phi_k^(j) [x] dZ_k        (tensor maps, Eq. 21-22)
    dR_{k+1} = Reduce(dR_{k+1}, h_max)   if it has more than h_max generators (PCA, Kopetzki 2017)
    R_{k+1}  = dR_{k+1} + phi(t_{k+1})

Every operation is exact on polynomial zonotopes except the reduction, so ``R_k`` is the exact image
of the STT polynomial map up to the reduction; it is *not* a guaranteed enclosure of the true
reachable set (the STT truncation error is not bounded, Foss Sec. 5).

Beyond the paper (documented in docs/stt.md):

* **splitting** (``split="factor" | "box"``, ``max_parts``, ``split_tol``;
  :mod:`ocreach.reach.stt_split`): before a step the truncation error of each part's STT
  polynomial is estimated against the true flow of extreme samples of ``dZ_k``; parts above
  ``split_tol`` (relative to the part's image) are split, worst first, while fewer than
  ``max_parts`` exist, and each half gets its own reference trajectory started at its centre (one
  extra STT integration per part and segment).  The set at a time is then a
  :class:`ocreach.sets.PZUnion`; ``meta["parts"]`` counts the parts per time,
  ``meta["truncation_error"]`` the largest estimate per step.
* **reachable tube** (``tube_substeps=s``): for each segment the sets at ``s - 1`` interior times
  are computed by second-order STTs from ``t_k`` to ``t_k + i dt / s`` applied to ``dZ_k`` (the
  control is held on the segment, so the map is exact in the same sense), and each is bloated by
  a box of half-width ``dt/(2s) * max |f|`` (the speed estimated on the extreme samples of the
  neighbouring sets, times 1.5) to cover the motion between sampled times.  ``result.tubes[k]``
  is the union over the segment ``[t_k, t_{k+1}]``.
* directional STTs (Boone & McMahon) are not implemented: STT generation is below 5 % of the
  runtime on all three problems (see docs/benchmarks.md), so they would not pay off.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.dynamics.flow import stt_polynomial
from ocreach.errors import ProblemError, SetError, SolverError, check_count, check_tolerances
from ocreach.problem import ControlSet, Problem
from ocreach.reach.base import Method, Timer, requirements
from ocreach.reach.result import ReachResult
from ocreach.reach.stt_split import PartStep, check_split_options
from ocreach.sets.polyzonotope import make_dependent
from ocreach.sets.pz_union import PZUnion
from ocreach.sets.reduce import GROUPS as REDUCE_GROUPS  # the reduce_group values

if TYPE_CHECKING:
    from ocreach.sets import PolyZonotope

INPUT_SETS = ("box", "ball")
BALL_INPUTS = ("auto", "zonotope", "zonotope-coarse", "pz", "pz-compact")
PRUNED_BOXES = ("exact", "bound")
#: the default ``pruned_box`` (the only value ``engine="library"`` accepts: it prunes nothing)
PRUNED_BOX_DEFAULT = "bound"
#: generators of the zonotope ball input per input dimension, ``ball_input="zonotope"``: support
#: over the unit sphere (exact, :func:`ocreach.sets.zonotope_support_range`) in [1, 1.03] in 2-D
#: (regular 16-gon, <= 1.0196) and 3-D (30 spread directions, <= 1.0269); 4-D 24 spread directions
#: (<= 1.099: no 4-D zonotope within 3 % was found); other dimensions 2 n (axes + random
#: directions, loose: [1, 2.75] in 4-D).  Measured in docs/validation/stt-tightness.md.
BALL_ZONOTOPE_GENERATORS = {2: 8, 3: 30, 4: 24}
#: ``ball_input="zonotope-coarse"``: 2-D regular 12-gon (<= 1.0353), 3-D dodecahedral axes
#: (<= 1.0954), 4-D 16 spread directions (<= 1.147)
BALL_ZONOTOPE_GENERATORS_COARSE = {2: 6, 3: 10, 4: 16}
#: ``ball_input="auto"`` (default) per input dimension, chosen by measurement
#: (docs/validation/stt-tightness.md, "Ball input within 3 % of the ball"): 2-D the 3 % zonotope
#: (tighter dro sets, ~1.2x runtime); 3-D and 4-D the coarse zonotope: the 3 %-tight inputs (the
#: 30-generator zonotope, the compact PZ) give tighter sets while few reductions have happened but
#: looser ones once the reduction boxes the input generators (nrho-flyby h_max 60, 10 steps: +108 %
#: for the compact PZ against +39 %; elliptic-earth 40 steps: +558 % against +208 %; the 4-D test
#: model likewise); the cube-to-ball PZ (48 generators in 3-D) is looser throughout
BALL_INPUT_AUTO = {2: "zonotope", 3: "zonotope-coarse", 4: "zonotope-coarse"}
#: ``ball_input="auto"`` in the other dimensions: 1-D the interval, 5-D and up the compact PZ of
#: :mod:`ocreach.sets.ball_pz` (support in [1, 1.03]; not measured on a problem, chosen because
#: the only zonotope there is the loose 2 n one; in 4-D the compact PZ beat that one up to 10
#: steps but lost to it at 15 (+90 % / +144 % against +64 % / +76 %, h_max 400 / 200), so for
#: long horizons in 5-D and up this default is unverified)
BALL_INPUT_AUTO_ND = "pz-compact"
REDUCTIONS = ("pca", "girard")
DIVERGED = ("STT set propagation diverged: the image of the set under the STT polynomial overflowed "
            "(the set is far outside the region where the truncated expansion is valid); use a "
            "smaller set or horizon, a lower order, or splitting")


# ============================================================================ helpers
@functools.lru_cache(maxsize=16)
def _ball_zonotope(n: int, k: int):
    """:func:`ocreach.sets.unit_ball_zonotope` (immutable, so one per ``(n, k)``: every step of every
    part uses the same input set, only its identifiers are fresh)."""
    from ocreach.sets import unit_ball_zonotope

    return unit_ball_zonotope(n, k)


def input_pz(kind: str, n_u: int, n_throttle: int = 0, ball: str = "pz") -> PolyZonotope:
    """The input set as a polynomial zonotope with fresh identifiers (Foss Alg. 1 line 4).

    ``"box"``: ``[-1, 1]^n_u`` (exact, one factor per component); ``"ball"`` with ``ball="pz"``:
    the unit ball by Foss Eq. 16 (n_u = 2; :func:`ocreach.sets.unit_ball_pz`, a slight outer
    approximation; n_u = 3..5 the cube-to-ball polynomial, beyond the compact PZ); with
    ``ball="pz-compact"``: :func:`ocreach.sets.ball_pz.compact_ball_pz` (few factors, low degree,
    support <= 1.03 in every dimension; 10 / 16 generators in 3-D / 4-D); with
    ``ball="zonotope"``: the outer zonotope :func:`ocreach.sets.unit_ball_zonotope` with
    :data:`BALL_ZONOTOPE_GENERATORS` generators (``ball="zonotope-coarse"``:
    :data:`BALL_ZONOTOPE_GENERATORS_COARSE`; ``ball="auto"``: per dimension
    :data:`BALL_INPUT_AUTO`, else :data:`BALL_INPUT_AUTO_ND`), one linear factor each (looser as
    a set, but its zonotope enclosure is itself, so a reduction that boxes it loses nothing more;
    docs/stt.md, "Ball input").
    ``n_throttle = 1`` appends the relaxed throttle ``s in [-1, 1]`` of
    :meth:`ocreach.model.Model.throttle_relaxed` (own fresh factor).
    """
    from ocreach.sets import PolyZonotope, new_ids, unit_ball_pz

    def box(m: int) -> PolyZonotope:
        return PolyZonotope(np.zeros(m), np.eye(m), None, np.eye(m, dtype=np.int64), new_ids(m))

    if kind == "box":
        U = box(n_u)
    elif kind == "ball" and ball == "auto":
        return input_pz(kind, n_u, n_throttle, BALL_INPUT_AUTO.get(n_u, BALL_INPUT_AUTO_ND))
    elif kind == "ball" and ball in ("zonotope", "zonotope-coarse") and n_u > 1:
        table = BALL_ZONOTOPE_GENERATORS if ball == "zonotope" else BALL_ZONOTOPE_GENERATORS_COARSE
        Z = _ball_zonotope(n_u, table.get(n_u, 2 * n_u))
        U = PolyZonotope.from_zonotope(Z, new_ids(Z.G.shape[1]))
    elif kind == "ball" and ball == "pz-compact":
        from ocreach.sets.ball_pz import compact_ball_pz

        U = compact_ball_pz(n_u)                       # fresh identifiers
    elif kind == "ball":
        if ball not in BALL_INPUTS:
            raise ProblemError(f"ball_input must be one of {BALL_INPUTS}; got {ball!r}")
        U = unit_ball_pz(n_u)                          # fresh identifiers (n_u or more factors)
    else:
        raise ProblemError(f"input_set must be one of {INPUT_SETS}; got {kind!r}")
    return U.cartesian(box(n_throttle)) if n_throttle else U


def _point_pz(c: np.ndarray):
    from ocreach.sets import PolyZonotope

    return PolyZonotope(np.asarray(c, float))


def nonlinearity_index(phi: Sequence[np.ndarray], dZ: PolyZonotope, samples: int = 64, seed: int = 0) -> float:
    """``max_s ||order-n term|| / max_s ||linear term||`` over extreme samples of ``dZ``.

    Small values mean the STT polynomial is nearly linear over the set, i.e. the set is well
    inside the region where a truncated expansion is trustworthy; it grows like the set size.
    """
    if len(phi) < 2:
        return 0.0
    S = dZ.sample(samples, np.random.default_rng(seed), mode="extreme")
    terms = stt_polynomial(phi, S)
    lin = float(np.max(np.linalg.norm(terms[0], axis=1)))
    top = float(np.max(np.linalg.norm(terms[-1], axis=1)))
    return top / lin if lin > 0 else (0.0 if top == 0 else math.inf)


def stt_step(phi: Sequence[np.ndarray], dZ: PolyZonotope, h_max: int, method: str, engine: str,
             timer: Timer, counts: dict[str, int], chunk: int = 0,
             pruned_box: str = "exact", group: str | None = None) -> PolyZonotope:
    """``Reduce((+)_j 1/j! Phi^(j) [x] dZ, h_max)`` (Foss Eq. 18-19, Alg. 1 lines 6-9).

    ``engine="library"``: the set library's ``tensor_map`` per order, exact sums and
    ``reduce_pz``; ``engine="fused"``: :func:`fused_step` (same set, faster; ``chunk`` bounds
    its memory, ``pruned_box`` chooses how its pruned order-3 products are boxed).  ``group``: how
    the reduction encloses the removed dependent monomials (``reduce_pz``'s option).
    """
    if engine == "fused":
        return fused_step(phi, dZ, h_max, method, timer, counts, chunk=chunk, pruned_box=pruned_box,
                          group=group)
    from ocreach.sets import tensor_map
    from ocreach.sets.reduce import reduce_pz

    with timer("tensor_maps"):
        out = phi[0] @ dZ
        for j in range(2, len(phi) + 1):
            out = out + tensor_map(phi[j - 1] / math.factorial(j), dZ)
    counts["tensor_maps"] += 1
    if out.n_generators > h_max:
        with timer("reductions"):
            try:
                out = reduce_pz(out, h_max, method, group)
            except np.linalg.LinAlgError as exc:
                raise SolverError(f"{DIVERGED} ({exc})") from exc
        counts["reductions"] += 1
    return out


# ---------------------------------------------------------------------------- fused step
_COMBO_CACHE: dict[int, tuple[np.ndarray, ...]] = {}


def _combos(H: int) -> tuple[np.ndarray, ...]:
    """Pairs ``(i, j, mult)`` with ``i <= j`` over ``H`` generators (cached; order 3 is formed in
    blocks by :mod:`ocreach.reach.stt_products`)."""
    if H not in _COMBO_CACHE:
        i, j = np.triu_indices(H)
        _COMBO_CACHE[H] = (i, j, np.where(i == j, 1.0, 2.0))
        if len(_COMBO_CACHE) > 8:
            _COMBO_CACHE.pop(next(iter(_COMBO_CACHE)))
    return _COMBO_CACHE[H]


def _bitmask(B: np.ndarray) -> np.ndarray:
    """Rows of a boolean matrix (H, r) packed into uint64 words (H, ceil(r/64))."""
    H, r = B.shape
    W = max(1, -(-r // 64))
    pad = np.zeros((H, W * 64), dtype=bool)
    pad[:, :r] = B
    return np.packbits(pad, axis=1, bitorder="little").view(np.uint64).reshape(H, W)


def fused_step(phi: Sequence[np.ndarray], dZ: PolyZonotope, h_max: int, method: str = "pca",
               timer: Timer | None = None, counts: dict[str, int] | None = None,
               prune: float = 1e-3, chunk: int = 0, pruned_box: str = "exact",
               group: str | None = None) -> PolyZonotope:
    """``Reduce((+)_j 1/j! Phi^(j) [x] dZ, h_max)`` in one vectorised pass (Foss Eq. 18, 21-22).

    Same result as the set library's ``tensor_map`` per order, exact sum and ``reduce_pz`` (checked
    in tests/test_stt.py), but faster: (1) all orders are generated together over the augmented
    generator list ``[c, G, GI]`` (Eq. 22 with the centre as a zero-exponent generator) -- order 3
    in blocks of at most ``chunk`` products (:mod:`ocreach.reach.stt_products`; 0 = the default
    from its memory budget), so memory stays bounded; (2) equal monomials are merged by the
    library's linear monomial hash (kept products are merged whenever more than ``chunk`` and
    more than have been merged wait, so merging stays O(N log N)); (3) the reduction is applied *before* any exponent matrix is formed:
    the classification a removed generator needs (constant, all-even, contains an independent
    factor) comes from XOR/OR of packed parity/support bit masks of the product's (at most
    three) generators, and the exponent matrix is built only for the kept generators.
    Independent generators are treated as in ``tensor_map`` (temporary factors, every product
    containing one becomes independent; all-even ones shift the centre by half).
    ``prune``, ``pruned_box``: see :func:`_fused_generate` (0 = merge every product).
    ``group``: as in ``reduce_pz`` (None: every removed monomial enclosed on its own).
    ``timer`` gets the phases ``tensor_maps`` (generation and merging) and ``reductions``.
    """
    timer = timer or Timer()
    with np.errstate(over="ignore", invalid="ignore"):
        with timer("tensor_maps"):
            out = _fused_generate(phi, dZ, h_max, prune, chunk, absum=method == "girard",
                                  pruned_box=pruned_box)
        Gm, pruned = out[0], out[-1]
        # |G| > 1e150: G G^T of the PCA reduction overflows (SVD fails) -- the same divergence
        big = Gm.size and np.abs(Gm).max() > 1e150
        if not np.all(np.isfinite(Gm)) or big or (pruned is not None and not np.all(np.isfinite(pruned.gram))):
            raise SolverError(DIVERGED)
        with timer("reductions"):
            try:
                res = _fused_reduce(dZ, h_max, method, *out, group=group)
            except np.linalg.LinAlgError as exc:
                raise SolverError(f"{DIVERGED} ({exc})") from exc
    if counts is not None:
        counts["tensor_maps"] += 1
        counts["reductions"] += int(res[1])
        counts["pruned"] = counts.get("pruned", 0) + (pruned.count if pruned is not None else 0)
    return res[0]


def _fused_generate(phi, dZ, h_max: int = 0, prune: float = 0.0, chunk: int = 0, absum: bool = False,
                    pruned_box: str = "exact"):
    """Generators, merged, of ``sum_j 1/j! Phi^(j)[x]dZ`` with their classification bits.

    Every product is named by three indices into the augmented generators (index 0, the centre,
    has exponent 0 and pads the lower orders).  With ``prune > 0`` and many order-3 products,
    every product whose norm bound ``mult ||T3||_F |g_i| |g_j| |g_k|`` is below ``prune`` times
    the ``h_max``-th largest order-1/2 generator is not merged but goes into the reduction's box
    (through :class:`ocreach.reach.stt_products.Order3Products`, returned as ``pruned``): sound
    (a sum of boxed generators is enclosed by the box of the parts), it only skips sorting the
    tiny ones.  ``pruned_box="exact"`` forms every pruned product for the exact box of them,
    ``"bound"`` never forms them and bounds them (looser box, time ~ the kept products):
    :func:`ocreach.reach.stt_products.order3_products`.
    """
    from ocreach.reach.stt_products import (
        PRUNE_MIN_PRODUCTS,
        default_chunk,
        n_products,
        order3_products,
    )
    from ocreach.sets.polyzonotope import monomial_keys, sym_tensor

    n_ord = len(phi)
    p, h, q = dZ.n_factors, dZ.n_dependent, dZ.n_independent
    n = phi[0].shape[0]
    chunk = int(chunk) if chunk and chunk > 0 else default_chunk(n)
    Ga = np.hstack([dZ.c[:, None], dZ.G, dZ.GI])
    H = Ga.shape[1]
    Ea = np.zeros((p + q, H), dtype=np.int64)
    Ea[:p, 1:1 + h] = dZ.E
    Ea[p:, 1 + h:] = np.eye(q, dtype=np.int64)
    ka = monomial_keys(Ea)
    par = _bitmask((Ea % 2 == 1).T)
    sup = _bitmask((Ea > 0).T)
    bmask = _bitmask(np.arange(p + q)[None, :] >= p)[0]
    zero = np.zeros(H, dtype=np.int64)
    cols, tris = [phi[0] @ Ga], [np.vstack([np.arange(H), zero, zero])]
    if n_ord >= 2:
        T2 = sym_tensor(phi[1]) / 2.0
        i, j, mult = _combos(H)
        B = np.matmul(Ga.T[None], T2 @ Ga)                     # (n, H, H)
        cols.append(B.reshape(n, -1)[:, i * H + j] * mult)
        tris.append(np.vstack([i, j, np.zeros(i.size, dtype=np.int64)]))
    pruned = None
    if n_ord >= 3:
        thr = 0.0
        if prune > 0 and n_products(H) > PRUNE_MIN_PRODUCTS and h_max > 0:
            small = np.concatenate([np.linalg.norm(c, axis=0) for c in cols])
            thr = prune * np.partition(small, -min(h_max, small.size))[-min(h_max, small.size)]
        prod = order3_products(sym_tensor(phi[2]) / 6.0, Ga, thr, chunk, pruned_box)
        merged, waiting = 0, sum(t.shape[1] for t in tris)
        for vals, tri in prod.kept(absum):
            cols.append(vals)
            tris.append(tri)
            waiting += tri.shape[1]
            if waiting > max(chunk, merged):    # merge what waits (memory ~ 2x the merged set)
                G, tri = _merge_products(cols, tris, ka)
                cols, tris, merged, waiting = [G], [tri], tri.shape[1], 0
        pruned = prod if prod.count else None
    Gm, tri = _merge_products(cols, tris, ka)
    # classification of the merged monomials from their generators (bit masks)
    PAR = par[tri[0]] ^ par[tri[1]] ^ par[tri[2]]
    SUP = sup[tri[0]] | sup[tri[1]] | sup[tri[2]]
    const = ~np.any(SUP, axis=1)
    has_b = np.any(SUP & bmask, axis=1)
    even = ~np.any(PAR, axis=1)
    return Gm, tri, const, has_b, even, Ea, pruned


def _merge_products(cols, tris, ka):
    """Merge products with equal monomials (hash of ``E_i + E_j + E_k`` = sum of the keys)."""
    from ocreach.sets.polyzonotope import merge_monomials

    G, tri = np.hstack(cols), np.hstack(tris)
    k0, k1 = np.ascontiguousarray(ka[:, 0]), np.ascontiguousarray(ka[:, 1])
    keys = np.stack([k0[tri[0]] + k0[tri[1]] + k0[tri[2]], k1[tri[0]] + k1[tri[1]] + k1[tri[2]]], axis=1)
    Gm, rep = merge_monomials(G, keys)
    return Gm, np.take(tri, rep, axis=1)


def _fused_reduce(dZ, h_max, method, Gm, tri, const, has_b, even, Ea, pruned, group=None):
    """Reduction (as ``reduce_pz``) before the exponent matrix is formed; see :func:`fused_step`."""
    from ocreach.sets import PolyZonotope
    from ocreach.sets.reduce import box_generators, enclose_removed, regroup_drop

    p = dZ.n_factors
    n = Gm.shape[0]
    c = Gm[:, const].sum(axis=1)
    # independent products: all-even ones range over [0, 1]
    be = has_b & even
    c = c + 0.5 * Gm[:, be].sum(axis=1)
    Gb = np.where(be[None, :], 0.5, 1.0) * Gm
    dep = ~(const | has_b)
    ind = has_b
    cand = np.flatnonzero(dep | ind)
    Gc = Gb[:, cand]
    norms = np.linalg.norm(Gc, axis=0)
    keep_mask = np.ones(cand.size, dtype=bool)
    if cand.size > h_max or pruned is not None:
        n_keep = max(h_max - n, 0)
        keep_mask[:] = False
        if n_keep:
            keep_mask[np.argpartition(-norms, n_keep - 1)[:n_keep]] = True
    keep_mask = regroup_drop(Gc, dep[cand], keep_mask, group)
    kept, removed = cand[keep_mask], cand[~keep_mask]
    kd = kept[dep[kept]]
    ki = kept[ind[kept]]
    rd = removed[dep[removed]]
    ri = removed[ind[removed]]
    # removed dependent monomials: zonotope enclosure (all-even -> centre shift + half generator)
    if group is None:
        rde = rd[even[rd]]
        c = c + 0.5 * Gm[:, rde].sum(axis=1)
        Grem = np.hstack([0.5 * Gm[:, rde], Gm[:, rd[~even[rd]]], Gb[:, ri]])
    else:  # the exponents of the removed monomials too, for their grouped enclosure
        t = tri[:, rd]
        shift, Gz = enclose_removed(Gm[:, rd], Ea[:p, t[0]] + Ea[:p, t[1]] + Ea[:p, t[2]], group)
        c = c + shift
        Grem = np.hstack([Gz, Gb[:, ri]])
    GI = np.hstack([Gb[:, ki], box_generators(Grem, method, pruned)])
    # exponent matrix of the kept dependent monomials only
    t = tri[:, kd]
    E = Ea[:p, t[0]] + Ea[:p, t[1]] + Ea[:p, t[2]]
    used = np.any(E > 0, axis=1)
    return PolyZonotope._own(c, Gm[:, kd], GI, E if used.all() else E[used], dZ.id[used]), removed.size > 0


@dataclass
class _Part:
    """One piece of the reachable set: its reference state at ``t_k`` and deviation set."""

    x_ref: np.ndarray
    dR: Any
    nominal: bool = True  # True while the reference is the problem's nominal (precomputed STTs)
    depth: int = 0
    dZ: Any = None        # dR x U of the current step (for the tube)


# ============================================================================ method
class STTReach(Method):
    """Polynomial-zonotope propagation through state-transition tensors (Foss Algorithm 1)."""

    name = "stt"
    description = "STT polynomial-zonotope propagation (Foss et al. Algorithm 1), optional splitting"

    @dataclass
    class Options:
        """Options of the STT propagation of sparse polynomial zonotopes (Foss et al.,
        Algorithm 1) and of its extensions (splitting, fused engine, grouped reduction)."""

        #: STT order n, 1, 2 or 3
        order: int = 2
        #: most generators (dependent + independent) per part after each step, >= 1
        h_max: int = 200
        #: "box" or "ball" (None: the problem's control set)
        input_set: str | None = None
        #: representation of a ball input: "auto" (per input dimension, BALL_INPUT_AUTO:
        #: "zonotope" in 2-D, "zonotope-coarse" in 3-D and 4-D, chosen by measurement; the
        #: interval in 1-D, "pz-compact" from 5-D, not measured), "zonotope" (outer zonotope, 8
        #: generators in 2-D and 30 in 3-D within 3 % of the ball, 24 in 4-D within 9.9 %),
        #: "zonotope-coarse" (6 / 10 / 16 generators in 2-D / 3-D / 4-D, within 3.5 / 9.6 /
        #: 14.7 %), "pz" (Foss Eq. 16 in 2-D, the cube-to-ball polynomial in 3-D to 5-D) or
        #: "pz-compact" (products of small polynomial balls, within 3 % in every dimension);
        #: docs/stt.md
        ball_input: str = "auto"
        #: order reduction: "pca" (Kopetzki et al., as Foss) or "girard"
        reduction: str = "pca"
        #: how a part is split where the STT polynomial is not valid over it
        #: (ocreach.reach.stt_split): "factor" (exact: halves the dependent factor with the
        #: largest order-2 contribution), "box" (halves an enclosure: the split_keep largest
        #: generators plus the PCA box of the rest); None: Algorithm 1 as is.  Before each step
        #: the truncation error of every part is estimated on extreme samples; parts above
        #: split_tol are split, worst first, while fewer than max_parts exist
        split: str | None = None
        #: the largest number of parts, >= 1
        max_parts: int = 16
        #: the truncation-error tolerance of a part, a fraction of its image
        split_tol: float = 0.01
        #: generators a "box" split keeps before boxing the rest (0: the PCA parallelotope;
        #: chosen on nrho-flyby, docs/validation/stt-flyby.md)
        split_keep: int = 30
        #: > 1 computes the reachable tube with that many sub-intervals per step (0: no tube)
        tube_substeps: int = 0
        #: "fused" (fused_step) or "library" (the set library's tensor_map + exact sum +
        #: reduce_pz); the same set up to how the fused engine boxes the products it prunes
        engine: str = "fused"
        #: before each step turn the independent generators left by earlier reductions into
        #: dependent ones with fresh factors (exact), so that their products keep their
        #: dependence; False: the paper's plain Cartesian product
        lift_independent: bool = False
        #: order-3 products the fused engine forms at once (peak memory about chunk (11 n + 2)
        #: * 8 bytes plus the kept products); 0: from a 128 MB budget per block; changes only
        #: round-off
        chunk: int = 0
        #: how the fused engine boxes the order-3 products it prunes (engine="fused", order=3,
        #: steps with more than PRUNE_MIN_PRODUCTS products): "bound" bounds them per generator
        #: pair without forming them (0.05-0.14 % more hull area on vdp), "exact" forms every one
        #: (1.5x the time at h_max 200, 4x at 800; docs/stt.md)
        pruned_box: str = PRUNED_BOX_DEFAULT
        #: how a reduction encloses the dependent monomials it removes: None (Foss, Kochdumper &
        #: Althoff) each on its own; "parallel" the nearly parallel ones together by the range
        #: of their scalar polynomial (ocreach.sets.reduce.enclose_removed); "parallel-drop"
        #: also removes a whole group the ranking splits; docs/validation/stt-tightness.md
        reduce_group: str | None = None
        #: relative tolerance of the integrator of the STT generation
        rtol: float = 1e-10
        #: absolute tolerance of the integrator of the STT generation
        atol: float = 1e-12

        def __post_init__(self) -> None:
            if self.order not in (1, 2, 3):
                raise ProblemError(f"order must be 1, 2 or 3; got {self.order!r}")
            self.h_max = check_count("h_max", self.h_max, 1)
            if self.input_set is not None and self.input_set not in INPUT_SETS:
                raise ProblemError(f"input_set must be one of {INPUT_SETS} or None; got {self.input_set!r}")
            if self.ball_input not in BALL_INPUTS:
                raise ProblemError(f"ball_input must be one of {BALL_INPUTS}; got {self.ball_input!r}")
            if self.reduction not in REDUCTIONS:
                raise ProblemError(f"reduction must be one of {REDUCTIONS}; got {self.reduction!r}")
            self.split, self.max_parts, self.split_tol = check_split_options(
                self.split, self.max_parts, self.split_tol)
            self.split_keep = check_count("split_keep", self.split_keep, 0)
            self.tube_substeps = check_count("tube_substeps", self.tube_substeps, 0)
            if self.tube_substeps == 1:
                raise ProblemError(f"tube_substeps must be 0 (off) or >= 2; got {self.tube_substeps!r}")
            if self.engine not in ("fused", "library"):
                raise ProblemError(f"engine must be 'fused' or 'library'; got {self.engine!r}")
            self.chunk = check_count("chunk", self.chunk, 0)
            if self.pruned_box not in PRUNED_BOXES:
                raise ProblemError(f"pruned_box must be one of {PRUNED_BOXES}; got {self.pruned_box!r}")
            if self.engine == "library" and self.pruned_box != PRUNED_BOX_DEFAULT:
                raise ProblemError(
                    f"pruned_box={self.pruned_box!r} applies to engine='fused' only; engine='library' "
                    "forms and merges every order-3 product, so it prunes none: use engine='fused' "
                    f"or leave pruned_box at its default {PRUNED_BOX_DEFAULT!r}")
            if self.reduce_group not in REDUCE_GROUPS:
                raise ProblemError(f"reduce_group must be one of {REDUCE_GROUPS}; got {self.reduce_group!r}")
            self.rtol, self.atol = check_tolerances(self.rtol, self.atol)
            self.lift_independent = bool(self.lift_independent)

    @classmethod
    def applicable(cls, problem: Problem) -> tuple[bool, str]:
        ok, why = requirements(problem, bounded=True)
        return ok, why and why + " (or give input_set='box'/'ball')"

    def applicable_with_options(self, problem: Problem) -> tuple[bool, str]:
        return (True, "") if self.options.input_set is not None else self.applicable(problem)

    # ------------------------------------------------------------------ solve
    def solve(self, problem: Problem) -> ReachResult:
        from ocreach.dynamics.flow import stt as stt_flow
        from ocreach.reach.guard import check_step

        opt = self.options
        model = problem.model
        kind = opt.input_set or problem.control_set.kind
        if kind not in INPUT_SETS:
            raise ProblemError(f"method 'stt' needs a 'box' or 'ball' input set; the problem's control "
                               f"set is {problem.control_set.kind!r} and input_set={opt.input_set!r}")
        # ||u|| (mass flow) has no expansion at the reference control u = 0: expand the relaxed
        # dynamics with the throttle as an extra input instead (Model.throttle_relaxed), up to
        # the largest ||u|| of the input set (sqrt(n_u) at a corner of the box)
        self._model = smodel = model.throttle_relaxed(ControlSet(kind, model.n_u).max_norm())
        n_thr = smodel.n_u - model.n_u
        if opt.h_max < model.n_x:
            raise ProblemError(f"h_max must be >= n_x = {model.n_x}; got {opt.h_max}")
        grid = problem.grid
        K = grid.size - 1
        timer = Timer()
        counts = {"tensor_maps": 0, "reductions": 0, "splits": 0, "part_stts": 0}
        with timer("stt_generation"):
            ref = stt_flow(smodel, problem.x0, np.zeros((K, smodel.n_u)), grid, opt.order,
                           p=problem.params, rtol=opt.rtol, atol=opt.atol)
        self._ref = ref
        with timer("other"):
            if problem.initial_set is not None:
                from ocreach.sets import to_polyzonotope

                dR0 = to_polyzonotope(problem.initial_set) - problem.x0
            else:
                dR0 = _point_pz(np.zeros(model.n_x))
        parts = [_Part(problem.x0.copy(), dR0)]
        sets: list[Any] = [self._assemble(parts)]
        tube: list[Any] = []
        eta_hist = np.zeros(K)
        err_hist = np.zeros(K)
        gens = np.zeros(K + 1, dtype=int)
        gens[0] = sets[0].n_generators
        for k in range(K):
            pending, new_parts, done = parts, [], []
            while pending:  # breadth first: split the worst parts while the budget lasts
                with timer("other"):
                    U = [input_pz(kind, model.n_u, n_thr, opt.ball_input) for _ in pending]
                prepared = []
                for part, Uk in zip(pending, U):
                    phi, x1 = self._segment_phi(part, k, problem, timer, counts)
                    with timer("other"):
                        dR = make_dependent(part.dR) if opt.lift_independent else part.dR
                        dZ = dR.cartesian(Uk)
                    prepared.append(PartStep(part, phi, x1, dZ))
                if opt.split is not None:
                    with timer("splitting"):
                        errs = self._truncation_errors(prepared, k, problem)
                        for rec, err in zip(prepared, errs):
                            rec.err = err
                            eta_hist[k] = max(eta_hist[k], nonlinearity_index(rec.phi, rec.dZ))
                    err_hist[k] = max(err_hist[k], max(errs))
                room = opt.max_parts - len(new_parts) - len(pending)
                worst = sorted((i for i, rec in enumerate(prepared)
                                if rec.err > opt.split_tol and rec.part.dR.n_generators > 0),
                               key=lambda i: -prepared[i].err)[:max(room, 0)]
                pending = []
                for i, rec in enumerate(prepared):
                    part, phi, x1, dZ = rec.part, rec.phi, rec.x1, rec.dZ
                    if i in worst:
                        with timer("splitting"):
                            pending.extend(self._split(part, phi))
                        counts["splits"] += 1
                        continue
                    try:
                        dR1 = stt_step(phi, dZ, opt.h_max, opt.reduction, opt.engine, timer, counts, opt.chunk,
                                       opt.pruned_box, opt.reduce_group)
                    except (SolverError, SetError) as exc:
                        raise SolverError(f"stt: step {k} (t = {grid[k]:g} -> {grid[k + 1]:g}) failed: {exc}") from exc
                    new_parts.append(_Part(x1, dR1, part.nominal, part.depth))
                    part.dZ = dZ  # kept for the tube
                    done.append(part)
            if opt.tube_substeps:
                with timer("tube"):
                    tube.append(self._tube_segment(problem, k, parts_with_dz=done, new=new_parts))
            parts = new_parts
            with timer("other"):
                sets.append(self._assemble(parts))
                check_step(self, problem, sets, tube)  # stops a diverging run (reach/guard.py)
            gens[k + 1] = sets[-1].n_generators
        meta = self.base_meta(problem, timer.times)
        meta["evaluations"] = counts
        meta["input_set"] = kind
        meta["throttle_relaxed"] = bool(n_thr)
        meta["generators"] = gens
        meta["parts"] = [len(s.parts) if isinstance(s, PZUnion) else 1 for s in sets]
        if opt.split is not None:
            meta["nonlinearity_index"] = eta_hist
            meta["truncation_error"] = err_hist
        meta["reference"] = ref.states
        return ReachResult(times=grid, sets=sets, meta=meta, tubes=tube if opt.tube_substeps else None)

    # ------------------------------------------------------------------ pieces
    def _segment_phi(self, part: _Part, k: int, problem: Problem, timer: Timer,
                     counts) -> tuple[list[np.ndarray], np.ndarray]:
        """``Phi_k^(j)`` about the part's reference: precomputed for the nominal reference, else one
        STT integration of the segment from the part's own reference state."""
        if part.nominal:
            return [ph[k] for ph in self._ref.phi], self._ref.states[k + 1]
        from ocreach.dynamics.flow import stt as stt_flow

        opt = self.options
        with timer("stt_generation"):
            r = stt_flow(self._model, part.x_ref, np.zeros((1, self._model.n_u)),
                         problem.grid[k:k + 2], opt.order, p=problem.params, rtol=opt.rtol, atol=opt.atol)
        counts["part_stts"] += 1
        return [ph[0] for ph in r.phi], r.states[-1]

    def _truncation_errors(self, prepared: list[PartStep], k: int, problem: Problem) -> list[float]:
        """Sampled truncation error of each part's step (:func:`ocreach.reach.stt_split.truncation_error`):
        the samples of all parts are propagated over ``[t_k, t_{k+1}]`` (held controls) in one batch."""
        from ocreach.dynamics.flow import propagate
        from ocreach.reach.stt_split import error_samples, truncation_error

        opt, n_x = self.options, problem.model.n_x
        S = [error_samples(rec.dZ, seed=k) for rec in prepared]
        X0 = np.vstack([rec.part.x_ref + s[:, :n_x] for rec, s in zip(prepared, S)])
        Uc = np.vstack([s[:, n_x:] for s in S])[:, None, :]
        X1 = propagate(self._model, X0, Uc, problem.grid[k:k + 2], p=problem.params, rtol=opt.rtol,
                       atol=opt.atol)[:, -1]
        ends = np.cumsum([len(s) for s in S])[:-1]
        return [truncation_error(rec.phi, s, x - rec.x1)
                for rec, s, x in zip(prepared, S, np.split(X1, ends))]

    def _split(self, part: _Part, phi: list[np.ndarray]) -> list[_Part]:
        """Split the part's deviation set in two (``options.split``: exact along a factor, or the
        halves of a PCA-reduced enclosure) and re-centre each half on its own reference state."""
        from ocreach.reach.stt_split import split_box, split_factor

        phi2 = phi[1] if len(phi) >= 2 else None
        opt = self.options
        halves = split_box(part.dR, phi2, opt.split_keep) if opt.split == "box" else split_factor(part.dR, phi2)
        out = []
        for half in halves:
            ih = half.interval_hull()
            centre = 0.5 * (np.asarray(ih.lo) + np.asarray(ih.hi))
            out.append(_Part(part.x_ref + centre, half - centre, nominal=False, depth=part.depth + 1))
        return out

    @staticmethod
    def _assemble(parts: list[_Part]):
        sets = [p.dR + p.x_ref for p in parts]
        return sets[0] if len(sets) == 1 else PZUnion(sets)

    def _tube_segment(self, problem: Problem, k: int, parts_with_dz, new) -> Any:
        """Union of the sets at the interior times of segment k, bloated to cover the motion
        between sampled times (see the module docstring)."""
        from ocreach.dynamics.flow import stt as stt_flow
        from ocreach.sets import Zonotope

        opt = self.options
        s = opt.tube_substeps
        model = problem.model
        t0, t1 = problem.grid[k], problem.grid[k + 1]
        sub = np.linspace(t0, t1, s + 1)
        pieces = []
        for part in parts_with_dz:
            dZ = part.dZ
            for i in range(1, s):
                r = stt_flow(self._model, part.x_ref, np.zeros((1, self._model.n_u)), [t0, sub[i]],
                             min(opt.order, 2),
                             p=problem.params, rtol=opt.rtol, atol=opt.atol)
                S = stt_step([ph[0] for ph in r.phi], dZ, opt.h_max, opt.reduction, opt.engine, Timer(),
                             {"tensor_maps": 0, "reductions": 0}, group=opt.reduce_group)
                pieces.append(S + r.states[-1])
        ends = [p.dR + p.x_ref for p in parts_with_dz] + [p.dR + p.x_ref for p in new]
        pieces = ends[: len(parts_with_dz)] + pieces + ends[len(parts_with_dz):]
        # speed bound on extreme samples of all pieces (x, and the input set's extreme controls)
        rng = np.random.default_rng(k)
        X = np.vstack([p.sample(200, rng, mode="extreme") for p in pieces])
        kind = opt.input_set or problem.control_set.kind
        Uc = ControlSet(kind, model.n_u).sample_boundary(rng, (X.shape[0],))
        F = np.asarray(model.f_fun.map(X.shape[0])(X.T, Uc.T, t0, problem.params)).T
        half = 1.5 * (t1 - t0) / (2 * s) * np.max(np.abs(F), axis=0)
        box = Zonotope(np.zeros(model.n_x), np.diag(half))
        return PZUnion([p + box for p in pieces])
