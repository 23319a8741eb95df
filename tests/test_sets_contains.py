"""Containment answers against independent LPs written in the test (scipy.optimize.linprog)."""
import casadi as ca
import cvxpy as cp
import numpy as np
from _sets_truth import lp_in_zonotope, lp_support
from hypothesis import given, settings
from hypothesis import strategies as st

from ocreach.sets import (
    Ellipsoid,
    Interval,
    PolyZonotope,
    Zonotope,
    points_in_zonotope,
    zonotope_in_interval,
    zonotope_in_zonotope,
)

SET = settings(max_examples=30, deadline=None)


def boundary_points(Z, rng, k, eps):
    """Points at distance ~eps outside (eps > 0) / inside (eps < 0) of vertices of Z."""
    d = rng.normal(size=(k, Z.dim))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    V = Z.c + np.sign(d @ Z.G) @ Z.G.T
    return np.where(eps > 0, V + eps * d, Z.c + (1 + eps) * (V - Z.c))


@SET
@given(st.integers(0, 10**6), st.sampled_from(["auto", "lp"]))
def test_points_in_zonotope_match_linprog(seed, method):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 5))
    h = int(rng.integers(n, 9)) if seed % 3 else int(rng.integers(0, n + 1))  # also rank-deficient cases
    Z = Zonotope(rng.normal(size=n), rng.normal(size=(n, h)))
    pts = np.vstack([Z.sample(10, rng), Z.sample(5, rng) + rng.normal(size=(5, n)),
                     boundary_points(Z, rng, 8, 1e-3), boundary_points(Z, rng, 8, -1e-3)])
    got = points_in_zonotope(Z, pts, method=method)
    want = np.array([lp_in_zonotope(Z.c, Z.G, x) for x in pts])
    assert np.array_equal(got, want)


def test_points_in_zonotope_many_generators_uses_certificates_and_lp():
    rng = np.random.default_rng(2)
    Z = Zonotope(rng.normal(size=5), rng.normal(size=(5, 30)))  # C(30, 4) > facet limit
    pts = np.vstack([boundary_points(Z, rng, 40, 1e-3), boundary_points(Z, rng, 40, -1e-3), Z.sample(40, rng)])
    got = Z.contains(pts)
    want = np.array([lp_in_zonotope(Z.c, Z.G, x) for x in pts])
    assert np.array_equal(got, want)
    assert got[:40].sum() == 0 and got[40:].all()


@SET
@given(st.integers(0, 10**6))
def test_zonotope_in_zonotope(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 4))
    Z2 = Zonotope(rng.normal(size=n), rng.normal(size=(n, int(rng.integers(n, n + 4)))))
    # inside by construction: a scaled linear image of Z2's factors
    S = rng.uniform(-1, 1, size=(Z2.n_generators, 3))
    S /= max(1.0, np.abs(S).sum(axis=1).max()) * 1.05
    Zin = Zonotope(Z2.c + 0.01 * Z2.G @ rng.uniform(-1, 1, Z2.n_generators), Z2.G @ S * 0.9)
    assert zonotope_in_zonotope(Zin, Z2, method="lp")
    assert zonotope_in_zonotope(Zin, Z2, method="vertex")
    # random candidate: exact answer = all vertices inside (checked by linprog)
    Zr = Zonotope(Z2.c + 0.3 * rng.normal(size=n), 0.4 * rng.normal(size=(n, 3)))
    want = all(lp_in_zonotope(Z2.c, Z2.G, v) for v in Zr.vertices())
    assert zonotope_in_zonotope(Zr, Z2, method="vertex") == want
    assert zonotope_in_zonotope(Zr, Z2, method="auto") == want
    if zonotope_in_zonotope(Zr, Z2, method="lp"):  # sufficient condition must never be wrong
        assert want
    I = Z2.interval_hull()
    assert zonotope_in_interval(Z2, I)
    assert not zonotope_in_interval(Z2 + np.full(n, 1e-3), I)


def test_containment_constraints_cvxpy():
    rng = np.random.default_rng(0)
    Z = Zonotope(rng.normal(size=3), rng.normal(size=(3, 5)))
    d = rng.normal(size=3)
    lo, hi = Z.c - np.abs(Z.G).sum(axis=1), Z.c + np.abs(Z.G).sum(axis=1)
    # truths written here: LP over the factors, box corner, ellipsoid closed form, and the PZ
    # {(a1^2, a2, a3)} whose zonotope enclosure is the box [0, 1] x [-1, 1]^2
    for S, want in [(Z, lp_support(Z.c, Z.G, d)), (Z.interval_hull(), d @ np.where(d > 0, hi, lo)),
                    (Ellipsoid([0, 1, 0], np.diag([1.0, 2.0, 3.0])), d[1] + np.sqrt(d @ np.diag([1.0, 2.0, 3.0]) @ d)),
                    (PolyZonotope([0, 0, 0], np.eye(3), None, [[2, 0, 0], [0, 1, 0], [0, 0, 1]], None),
                     max(d[0], 0.0) + abs(d[1]) + abs(d[2]))]:
        x = cp.Variable(3)
        cons, _ = S.containment_constraints(x)
        prob = cp.Problem(cp.Maximize(d @ x), cons)
        prob.solve(solver=cp.CLARABEL)
        assert np.isclose(prob.value, want, rtol=1e-6, atol=1e-6)


def test_casadi_containment_zonotope_qp():
    rng = np.random.default_rng(1)
    Z = Zonotope(rng.normal(size=2), rng.normal(size=(2, 4)))
    x = ca.MX.sym("x", 2)
    cc = Z.casadi_containment(x)
    d = np.array([0.3, -1.0])
    nlp = {"x": ca.vertcat(x, cc.xi), "f": -ca.dot(ca.DM(d), x), "g": cc.g}
    solver = ca.nlpsol("s", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False})
    lbx = np.r_[-np.inf, -np.inf, cc.lbxi]
    ubx = np.r_[np.inf, np.inf, cc.ubxi]
    sol = solver(lbx=lbx, ubx=ubx, lbg=cc.lbg, ubg=cc.ubg)
    assert solver.stats()["success"]
    assert np.isclose(-float(sol["f"]), Z.support(d), rtol=1e-6)
    I = Interval([0, 0], [1, 2])
    ci = I.casadi_containment(ca.SX.sym("y", 2))
    assert np.allclose(ci.ubg, [1, 2]) and ci.xi is None


def test_thin_zonotope_acute_vertex_not_inside_by_tolerance():
    """Near an acute vertex a point far outside violates every facet by less than the tolerance;
    membership must still follow the distance to the set (independent LP)."""
    Z = Zonotope([0.0, 0.0], [[1.0, 1.0], [0.0, 1e-6]])  # vertex (2, 1e-6) with angle ~1e-6
    pts = np.array([[2.05, 1e-6], [2.3, 1e-6], [2.0, 1e-6], [1.0, 0.5e-6], [-2.05, -1e-6]])
    want = np.array([lp_in_zonotope(Z.c, Z.G, x) for x in pts])
    assert want.tolist() == [False, False, True, True, False]
    for method in ("auto", "halfspace", "lp"):
        assert points_in_zonotope(Z, pts, method=method).tolist() == want.tolist()


@SET
@given(st.integers(0, 10_000), st.sampled_from([1e-12, 1e-6, 1e-2, 0.5]))
def test_classify_zonotope_decides_points_of_known_membership(seed, rel):
    """Three-way membership (``ocreach.sets.pz_witness.classify_zonotope``) of points whose
    membership is known: support points ``c + G sign(G^T d)`` (vertices: every factor on a face)
    moved towards the centre by ``rel`` of their offset are inside, moved out along ``d`` by more
    than the tolerance they are outside; every point is decided, and a union is inside where a
    part is."""
    from ocreach.sets.pz_witness import classify_zonotope
    from ocreach.sets.union import ZonotopeUnion

    rng = np.random.default_rng(seed)
    n, h = int(rng.integers(1, 6)), int(rng.integers(1, 40))
    Z = Zonotope(rng.normal(size=n), rng.normal(size=(n, h)) * rng.uniform(0.01, 1, h))
    d = rng.normal(size=(60, n))
    V = Z.c + np.sign(d @ Z.G) @ Z.G.T
    eps = 1e-9 * (1 + np.abs(V).max())
    inner = Z.c + (1 - rel) * (V - Z.c)
    outer = V + (2 * eps + rel) * np.sign(d)      # d^T x beyond the support by 2 eps |d|_1 at least
    v_in = classify_zonotope(Z, inner, eps)
    v_out = classify_zonotope(Z, outer, eps)
    assert v_in.inside.all() and not v_in.outside.any()
    assert v_out.outside.all() and not v_out.inside.any()
    far = Zonotope(Z.c + 10 * np.abs(Z.G).sum(), Z.G)
    v_u = classify_zonotope(ZonotopeUnion([far, Z]), np.vstack([inner, outer]), eps)
    assert v_u.inside[: len(inner)].all() and v_u.outside[len(inner):].all()


@SET
@given(st.integers(0, 10_000))
def test_lp_membership_rejects_points_beyond_its_tolerance(seed):
    """The LP path reports inside only points within its tolerance: support points of zonotopes
    of many generators and large coordinates, moved out along ``sign(d)`` so that their Euclidean
    distance to the set exceeds the tolerance (at HiGHS's default feasibility tolerance the LP
    accepted such points, up to ~3x beyond it)."""
    rng = np.random.default_rng(seed)
    n, h = int(rng.integers(2, 8)), int(rng.integers(8, 120))
    G = rng.normal(size=(n, h)) * rng.uniform(1e-3, 1, h) * 10 ** rng.uniform(-2, 4)
    Z = Zonotope(rng.normal(size=n) * 10 ** rng.uniform(-2, 6), G)
    tol = 10 ** rng.uniform(-11, -7)
    atol = tol * max(1.0, float(np.abs(G).sum()), float(np.abs(Z.c).max()))
    d = rng.normal(size=(40, n))
    V = Z.c + np.sign(d @ G) @ G.T
    # d.(x - V) = k atol |d|_1 >= k atol |d|_2: the Euclidean distance to Z is at least k atol
    out = V + rng.uniform(1.05, 4, (40, 1)) * atol * np.sign(d)
    assert not points_in_zonotope(Z, out, tol=tol, method="lp").any()
    inner = Z.c + (1 - 1e-6) * (V - Z.c)
    assert points_in_zonotope(Z, inner, tol=tol, method="lp").all()
