"""Benchmarks of the set library against plain numpy / per-point cvxpy.

1. Order-2 tensor map (Foss et al. Eq. 21-22) of a 6-D polynomial zonotope with 400 dependent
   generators followed by PCA reduction back to 400 generators: ``ocreach.sets.tensor_map`` +
   ``reduce`` against the same math written here in plain numpy (full einsum over all h^2 pairs,
   exponent sums, ``np.unique(axis=1)`` merge, PCA box of the smallest generators).  Target <= 1.5x.
   And against a careful numpy reference of the same exact math (pairs i <= j, one
   int64 key per monomial, argsort + reduceat), interleaved runs, CPU time.  Target <= 1.0x.
2. Membership of 10,000 points in a 6-D zonotope with 50 generators in ONE call against one cvxpy
   (Clarabel) solve per point; the per-point loop is timed on 200 points and extrapolated.
   Target >= 10x.

``--write`` updates the ``## Sets`` section of docs/benchmarks.md.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from ocreach.fileio import replace_markdown_section
from ocreach.outdir import benchmarks_doc
from ocreach.sets import PolyZonotope, Zonotope, new_ids, points_in_zonotope, reduce, tensor_map

DOCS = benchmarks_doc(Path(__file__).resolve().parents[1] / "docs" / "benchmarks.md")


def _best(fn, reps: int) -> float:
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def _cpu(fn) -> float:
    t = time.process_time()
    fn()
    return time.process_time() - t


def make_pz(rng, n=6, h=400, p=12, deg=3) -> PolyZonotope:
    E = rng.integers(0, deg + 1, size=(p, 4 * h)) * (rng.uniform(size=(p, 4 * h)) < 0.25)
    E = np.unique(E[:, np.any(E, axis=0)], axis=1)
    E = E[:, rng.permutation(E.shape[1])[:h]]
    G = rng.normal(size=(n, h)) * np.exp(-0.01 * np.arange(h))
    return PolyZonotope(rng.normal(size=n), G, None, E, new_ids(p))


def numpy_reference(T, c, G, E, h_max):
    """Plain numpy: Eq. 22 over all pairs with the centre as a zero-exponent generator, merge, PCA."""
    n, h = G.shape
    Ga = np.hstack([c[:, None], G])
    Ea = np.hstack([np.zeros((E.shape[0], 1), int), E])
    Gt = np.einsum("iab,aj,bk->ijk", T, Ga, Ga).reshape(T.shape[0], -1)
    Et = (Ea[:, :, None] + Ea[:, None, :]).reshape(E.shape[0], -1)
    Eu, inv = np.unique(Et, axis=1, return_inverse=True)
    Gu = np.zeros((T.shape[0], Eu.shape[1]))
    np.add.at(Gu.T, inv.ravel(), Gt.T)
    const = ~np.any(Eu, axis=0)
    c_new = Gu[:, const].sum(axis=1)
    Gu, Eu = Gu[:, ~const], Eu[:, ~const]
    keep = np.zeros(Gu.shape[1], bool)
    keep[np.argsort(-np.linalg.norm(Gu, axis=0))[: h_max - n]] = True
    return _pca_reduce(c_new, Gu, Eu, keep)


def _pca_reduce(c_new, G, E, keep):
    """Both references' reduction: enclose the generators not in ``keep`` (all-even monomials:
    centre shift + half generator) and box them in their PCA frame."""
    Gd, Ed = G[:, ~keep], E[:, ~keep]
    even = np.all(Ed % 2 == 0, axis=0)
    c_new = c_new + 0.5 * Gd[:, even].sum(axis=1)
    Gr = np.hstack([0.5 * Gd[:, even], Gd[:, ~even]])
    U = np.linalg.svd(Gr @ Gr.T)[0]
    box = U * np.abs(U.T @ Gr).sum(axis=1)
    return c_new, G[:, keep], E[:, keep], box


def careful_reference(T, c, G, E, h_max):
    """Careful numpy: the symmetrised tensor contracted once, the pairs i <= j only
    (multiplicity 2 off the diagonal), one exact int64 key per monomial (mixed radix of the
    exponent rows), argsort + reduceat merge, then the same PCA reduction."""
    m, n = T.shape[0], G.shape[0]
    Ts = 0.5 * (T + T.transpose(0, 2, 1))
    Ga = np.hstack([c[:, None], G])
    Ea = np.hstack([np.zeros((E.shape[0], 1), np.int64), E])
    H = Ga.shape[1]
    i, j = np.triu_indices(H)
    B = np.matmul(Ga.T[None], Ts @ Ga)
    Gt = np.take(B.reshape(m, -1), i * H + j, axis=1) * np.where(i == j, 1.0, 2.0)
    base = 2 * Ea.max(axis=1) + 1
    assert np.prod(base.astype(float)) < 2.0 ** 62, "exponents do not fit one int64 key"
    ka = np.cumprod(np.r_[1, base[:-1]]) @ Ea
    keys = ka[i] + ka[j]
    order = np.argsort(keys)
    ks = keys[order]
    starts = np.flatnonzero(np.r_[True, ks[1:] != ks[:-1]])
    Gm = np.add.reduceat(np.take(Gt, order, axis=1), starts, axis=1)
    rep = order[starts]
    Em = Ea[:, i[rep]] + Ea[:, j[rep]]
    const = ~np.any(Em, axis=0)
    c_new = Gm[:, const].sum(axis=1)
    Gm, Em = Gm[:, ~const], Em[:, ~const]
    norms = np.linalg.norm(Gm, axis=0)
    keep = np.zeros(Gm.shape[1], bool)
    keep[np.argpartition(-norms, h_max - n - 1)[: h_max - n]] = True
    return _pca_reduce(c_new, Gm, Em, keep)


def bench_tensor_map(reps: int = 5) -> dict:
    rng = np.random.default_rng(0)
    pz = make_pz(rng)
    T = rng.normal(size=(6, 6, 6))
    ours = lambda: reduce(tensor_map(T, pz), 400, "pca")
    ref = lambda: numpy_reference(T, np.asarray(pz.c), np.asarray(pz.G), np.asarray(pz.E), 400)
    out = ours()
    c_ref, G_ref, E_ref, box = ref()
    # same enclosure: compare support functions of the two results in random directions
    D = rng.normal(size=(50, 6))
    s_ours = out.to_zonotope().support(D)
    ref_pz = PolyZonotope(c_ref, G_ref, box, E_ref, pz.id)
    s_ref = ref_pz.to_zonotope().support(D)
    careful = lambda: careful_reference(T, np.asarray(pz.c), np.asarray(pz.G), np.asarray(pz.E), 400)
    c_c, G_c, E_c, box_c = careful()
    s_careful = PolyZonotope(c_c, G_c, box_c, E_c, pz.id).to_zonotope().support(D)
    t_ours, t_ref = _best(ours, reps), _best(ref, reps)
    # ours and the careful reference interleaved (the machine is shared): medians of each
    t_o, t_c = [], []
    for _ in range(3 * reps):
        t_o.append(_cpu(ours))
        t_c.append(_cpu(careful))
    t_o, t_c = float(np.median(t_o)), float(np.median(t_c))
    return {"t_ours": t_ours, "t_ref": t_ref, "ratio": t_ours / t_ref, "h_out": out.n_generators,
            "support_rel_diff": float(np.max(np.abs(s_ours - s_ref) / np.abs(s_ref).clip(1e-9))),
            "t_ours_i": t_o, "t_careful": t_c, "n_interleaved": 3 * reps, "ratio_careful": t_o / t_c,
            "careful_rel_diff": float(np.max(np.abs(s_ours - s_careful) / np.abs(s_careful).clip(1e-9)))}


def bench_containment(n_points: int = 10_000, n_loop: int = 200) -> dict:
    import cvxpy as cp

    rng = np.random.default_rng(1)
    Z = Zonotope(rng.normal(size=6), rng.normal(size=(6, 50)))
    d = rng.normal(size=(n_points, 6))
    P = Z.c + (np.sign(d @ Z.G) @ Z.G.T) * rng.uniform(0.9, 1.1, size=(n_points, 1))  # near the boundary
    t = time.perf_counter()
    ours = points_in_zonotope(Z, P)
    t_ours = time.perf_counter() - t

    def one(x):
        xi = cp.Variable(50)
        prob = cp.Problem(cp.Minimize(0), [Z.G @ xi == x - Z.c, xi >= -1, xi <= 1])
        prob.solve(solver=cp.CLARABEL)
        return prob.status == "optimal"

    t = time.perf_counter()
    loop = np.array([one(x) for x in P[:n_loop]])
    t_loop = (time.perf_counter() - t) * n_points / n_loop
    return {"t_ours": t_ours, "t_loop_extrapolated": t_loop, "speedup": t_loop / t_ours,
            "agree": int(np.sum(loop == ours[:n_loop])), "n_loop": n_loop, "inside_frac": float(ours.mean())}


def section(tm: dict, ct: dict) -> str:
    return f"""## Sets

`python benchmarks/bench_sets.py` (median of 5 runs for the tensor map, one run for containment),
`OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}`, load average {os.getloadavg()[0]:.1f} on the 2 cores when it started.

| benchmark | ocreach | peer | ratio | target |
|---|---|---|---|---|
| order-2 tensor map of a 6-D PZ (400 dep. generators, 12 factors) + PCA reduction to 400 | {tm['t_ours'] * 1e3:.1f} ms | plain numpy einsum + `np.unique` merge + PCA: {tm['t_ref'] * 1e3:.1f} ms | {tm['ratio']:.2f}x time | <= 1.5x |
| same, CPU time, interleaved with the peer (median of {tm['n_interleaved']}) | {tm['t_ours_i'] * 1e3:.1f} ms | careful numpy (pairs i <= j, one int64 key per monomial, argsort + reduceat, same PCA): {tm['t_careful'] * 1e3:.1f} ms | **{tm['ratio_careful']:.2f}x** time | <= 1.0x |
| 10,000 points in a 6-D zonotope with 50 generators (points near the boundary, {ct['inside_frac'] * 100:.0f} % inside) | {ct['t_ours']:.2f} s, one call | one cvxpy + Clarabel solve per point: {ct['t_loop_extrapolated']:.1f} s (timed on {ct['n_loop']} points, extrapolated) | {ct['speedup']:.0f}x faster | >= 10x |

Tensor map: both results have {tm['h_out']} generators and the same enclosure (support functions agree
to {tm['support_rel_diff']:.1e} relative).  ocreach contracts the symmetrised tensor once over the pairs
i <= j and merges equal monomials with a linear 128-bit hash of the exponent columns instead of
`np.unique(axis=1)`; every merged column is then compared exactly with its group's representative
(a collision would fall back to `np.unique`), at a cost within timing noise; when the exponents fit
(the product of the bases `2 max + 1` per factor below 2^62, as here) it uses one exact int64 key per
monomial instead (argsort + reduceat, no re-check; support functions agree with the careful reference
to {tm['careful_rel_diff']:.1e}).  Containment: exact certificates (least-norm factors / separating directions from a
vectorised Frank-Wolfe run) decide about half of these near-boundary points; the rest go to block-diagonal LPs (HiGHS, 100 points
per LP); the answers agree with the per-point cvxpy loop on {ct['agree']}/{ct['n_loop']} points.
"""


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="update the Sets section of docs/benchmarks.md")
    args = ap.parse_args(argv)
    tm = bench_tensor_map()
    print(f"tensor map + PCA reduce: ocreach {tm['t_ours'] * 1e3:.1f} ms, numpy {tm['t_ref'] * 1e3:.1f} ms, "
          f"ratio {tm['ratio']:.2f} (target <= 1.5); support rel. diff {tm['support_rel_diff']:.1e}")
    print(f"tensor map + PCA reduce vs careful numpy (interleaved): ocreach {tm['t_ours_i'] * 1e3:.1f} ms, "
          f"careful {tm['t_careful'] * 1e3:.1f} ms, ratio {tm['ratio_careful']:.2f} (target <= 1.0); "
          f"support rel. diff {tm['careful_rel_diff']:.1e}")
    ct = bench_containment()
    print(f"10k points in zonotope: ocreach {ct['t_ours']:.2f} s, per-point cvxpy {ct['t_loop_extrapolated']:.1f} s "
          f"(extrapolated from {ct['n_loop']}), speedup {ct['speedup']:.0f}x (target >= 10); "
          f"agree {ct['agree']}/{ct['n_loop']}")
    text = section(tm, ct)
    if args.write:
        replace_markdown_section(DOCS, text)
        print(f"wrote ## Sets to {DOCS}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
