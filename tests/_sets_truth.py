"""Independent truths for the set tests (scipy LPs written here, not the library's code)."""
from fractions import Fraction as Fr

import numpy as np
from scipy.optimize import linprog


def lp_in_zonotope(c, G, x, tol=1e-7):
    """Is x in {c + G xi : |xi| <= 1}?  min ||e||_1 s.t. G xi + e+ - e- = x - c (scipy HiGHS)."""
    n, h = G.shape
    if h == 0:
        return bool(np.all(np.abs(x - c) <= tol))
    A = np.hstack([G, np.eye(n), -np.eye(n)])
    cost = np.r_[np.zeros(h), np.ones(2 * n)]
    bounds = [(-1, 1)] * h + [(0, None)] * (2 * n)
    # HiGHS's default feasibility tolerances (1e-7) put the optimum's residual at ~1e-9 even for
    # points exactly inside, above the callers' tolerances (a false "outside" for seed 15126 of
    # test_reduce_keeps_dependence_soundly); ask for 1e-10
    res = linprog(cost, A_eq=A, b_eq=x - c, bounds=bounds, method="highs",
                  options={"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10})
    assert res.status == 0
    return res.fun <= tol * max(1.0, np.abs(G).sum())


def lp_support(c, G, d):
    """max d.x over the zonotope by an LP over the factors."""
    h = G.shape[1]
    if h == 0:
        return float(d @ c)
    res = linprog(-(G.T @ d), bounds=[(-1, 1)] * h, method="highs")
    return float(d @ c - res.fun)


def exact_pz_value(pz, a, b, x):
    """``c + G m(a) + GI b - x`` in exact rational arithmetic."""
    out = []
    for i in range(pz.dim):
        v = Fr(float(pz.c[i])) - Fr(float(x[i]))
        for j in range(pz.n_dependent):
            m = Fr(1)
            for k in range(pz.n_factors):
                m *= Fr(float(a[k])) ** int(pz.E[k, j])
            v += Fr(float(pz.G[i, j])) * m
        for j in range(pz.n_independent):
            v += Fr(float(pz.GI[i, j])) * Fr(float(b[j]))
        out.append(v)
    return out
