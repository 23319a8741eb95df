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
from ocreach.sets.contains import certified_in_zonotope
from ocreach.sets.union import ZonotopeUnion, gauge, union_gauge

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
@given(st.integers(0, 10**6))
def test_lp_free_certificates_and_union_gauge_match_linprog(seed):
    """``certified_in_zonotope`` (and ``gauge(lp="certificates")``) never call a point inside
    that the independent LP puts outside; ``gauge(lp=False)`` decides like the LP; the union
    gauge (certificates, membership in the parts whose box holds the point, exact gauges for
    the rest) is <= 1 exactly for the points some part contains."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 5))
    parts = [Zonotope(rng.normal(size=n), rng.normal(size=(n, int(rng.integers(n, 3 * n + 2)))))
             for _ in range(int(rng.integers(1, 4)))]
    pts = np.vstack([np.vstack([Z.sample(6, rng), boundary_points(Z, rng, 4, 1e-3),
                                boundary_points(Z, rng, 4, -1e-3)]) for Z in parts]
                    + [rng.normal(size=(6, n)) * 3])
    want = np.array([[lp_in_zonotope(Z.c, Z.G, x) for x in pts] for Z in parts])
    for Z, w in zip(parts, want):
        cert = certified_in_zonotope(Z, pts)
        assert not np.any(cert & ~w)
        assert np.array_equal(np.atleast_1d(gauge(Z, pts, lp="certificates")) <= 1.0, cert)
        assert np.array_equal(np.atleast_1d(gauge(Z, pts, lp=False)) <= 1.0, w)
        assert np.array_equal(np.atleast_1d(gauge(Z, pts, lp="membership-lp")) <= 1.0, w)
    g = np.atleast_1d(union_gauge(ZonotopeUnion(parts), pts))
    assert np.array_equal(g <= 1.0 + 1e-9, want.any(axis=0))


def test_lp_free_certificates_with_many_generators():
    """Beyond the facet limit the certificates decide alone: never inside for an outside point,
    and most interior samples proven inside."""
    rng = np.random.default_rng(3)
    Z = Zonotope(rng.normal(size=5), rng.normal(size=(5, 30)))  # C(30, 4) > facet limit
    pts = np.vstack([boundary_points(Z, rng, 40, 1e-3), Z.c + 0.5 * (Z.sample(40, rng) - Z.c)])
    cert = certified_in_zonotope(Z, pts)
    assert not cert[:40].any() and cert[40:].mean() > 0.9


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


def _awkward_zonotope(rng, kind: str) -> Zonotope:
    """Generators whose facet normals are hard to compute in floating point: a nearly parallel
    pair, a tiny generator, or a flat zonotope made full-dimensional by a tiny generator."""
    n = int(rng.integers(3, 5))
    h = int(rng.integers(n, n + 4))
    G = rng.normal(size=(n, h))
    if kind == "parallel":
        G[:, 1] = G[:, 0] * rng.uniform(0.2, 2) + 10.0 ** -rng.uniform(6, 15) * rng.normal(size=n)
    elif kind == "tiny":
        G[:, -1] *= 10.0 ** -rng.uniform(8, 16)
    else:  # flat: the first n - 1 rows span the set, the tiny last generator the last axis
        G[-1] = 0.0
        G = np.hstack([G, 10.0 ** -rng.uniform(8, 16) * np.eye(n)[:, -1:]])
        Q = np.linalg.qr(rng.normal(size=(n, n)))[0]
        G = Q @ G
    return Zonotope(rng.normal(size=n) * 10.0 ** rng.uniform(-1, 3), G)


@SET
@given(st.integers(0, 10**6), st.sampled_from(["parallel", "tiny", "flat"]),
       st.sampled_from([1e-7, 1e-11]))
def test_facet_path_inside_is_a_proof_on_awkward_generators(seed, kind, tol):
    """An inside verdict of the facet path (``points_in_zonotope``, ``certified_in_zonotope``,
    the gauge's first pass) is a proof within the tolerance even where the facet normals are
    ill-conditioned: no point outside by more than the tolerance (moved out from the support
    point along its direction ``d``, so ``d.x - h(d)`` proves the distance) is called inside;
    clearly interior points are inside by the independent LP (linprog at 1e-10), by
    ``points_in_zonotope`` and by the union gauge."""
    rng = np.random.default_rng(seed)
    Z = _awkward_zonotope(rng, kind)
    n = Z.dim
    atol = tol * max(1.0, float(np.abs(Z.G).sum()), float(np.abs(Z.c).max()))
    d = rng.normal(size=(40, n))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    V = Z.c + np.sign(d @ Z.G) @ Z.G.T
    far = np.linalg.norm(Z.G, axis=0).sum()
    out = V + d * (atol * 10.0 ** rng.uniform(0.5, 3, size=(40, 1)))
    out = np.vstack([out, V + d * far])  # far out, e.g. along a flat set's plane
    assert np.all(np.einsum("ij,ij->i", np.vstack([d, d]), out - Z.c)
                  - np.abs(np.vstack([d, d]) @ Z.G).sum(axis=1) > atol)
    inner = Z.c + (1 - 1e-3) * (V - Z.c)
    assert not certified_in_zonotope(Z, out, tol=tol).any()
    assert not np.atleast_1d(points_in_zonotope(Z, out, tol=tol)).any()
    if tol == 1e-11:  # the gauge's own tolerance (CERT_TOL) on the row-scaled set
        for lp in ("certificates", False):
            assert np.all(np.atleast_1d(gauge(Z, out, lp=lp)) > 1.0)
    # inside: by the LP, by the membership test at the LP's resolution (a set thinner than the
    # facet test's margin leaves every point to the LP) and, unless the set is thinner than the
    # rounding of the points (flat, or a tiny generator among n), by the truth checks' gauge
    # (exact, no tolerance)
    assert all(lp_in_zonotope(Z.c, Z.G, x) for x in inner)
    assert np.atleast_1d(points_in_zonotope(Z, inner, tol=1e-7)).all()
    if np.linalg.svd(Z.G, compute_uv=False).min() > 1e-6 * np.abs(Z.G).max():
        assert np.all(np.atleast_1d(union_gauge(Z, inner)) <= 1.0 + 1e-9)


def test_flat_zonotope_with_a_tiny_generator_does_not_swallow_its_plane():
    """A zonotope spanning a plane of R^3 plus a generator of 1e-14 across it: the facets through
    the tiny generator have cross products ~1e-14 of the others; dropping them as degenerate left
    only the two faces of the plane, and a point 20 times outside was reported inside (gauge 1)."""
    Q = np.linalg.qr(np.random.default_rng(4).normal(size=(3, 3)))[0]
    Z = Zonotope(np.zeros(3), Q @ np.array([[1.0, 0.3, -0.5, 0], [0.2, 1.0, 0.7, 0],
                                            [0, 0, 0, 1e-14]]))
    far = Q @ np.array([30.0, -20.0, 0.0])
    assert not lp_in_zonotope(Z.c, Z.G, far)
    assert not points_in_zonotope(Z, far) and not certified_in_zonotope(Z, far[None])[0]
    assert gauge(Z, far) > 20 and union_gauge(ZonotopeUnion([Z]), far) > 20
    # two generators at an angle of 1e-13: their facet's normal is not computable
    Z2 = Zonotope(np.zeros(3), np.array([[1.0, 1.0, 0], [0, 1e-13, 0], [0, 0, 1.0]]))
    top = np.array([0.0, 0.0, 5.0])
    assert not points_in_zonotope(Z2, top) and not certified_in_zonotope(Z2, top[None])[0]


def test_gauge_lp_argument_is_checked():
    """``lp=False`` is the exact membership test (no gauge LP), as it always was; an unknown
    value is an error, not a silent weaker test."""
    import pytest

    from ocreach.errors import SetError

    Z = Zonotope(np.zeros(2), np.array([[1.0, 0.5], [0.0, 1.0]]))
    x = np.array([[0.2, 0.1], [3.0, 0.0]])
    assert np.atleast_1d(gauge(Z, x, lp=False)).tolist() == [1.0, np.inf]
    assert np.atleast_1d(gauge(Z, x))[1] == pytest.approx(3.0)
    for bad in ("membership", 1, None):
        with pytest.raises(SetError, match="lp must be True, False, 'membership-lp' or"):
            gauge(Z, x, lp=bad)


@SET
@given(st.integers(0, 10_000))
def test_union_gauge_within_settles_only_points_whose_gauge_is_below_it(seed):
    """``union_gauge(..., within=w)``: a point reported <= w has an exact gauge <= w (it is an
    upper bound, never below the exact gauge by more than rounding), a point whose exact gauge
    exceeds w keeps its exact value, and the points on a part's boundary (gauge exactly 1, the
    vertex states of the truth checks) are all reported <= w."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 5))
    parts = [Zonotope(rng.normal(size=n), rng.normal(size=(n, int(rng.integers(n, 3 * n + 2)))))
             for _ in range(int(rng.integers(1, 3)))]
    w = 1 + 1e-9
    pts = []
    for Z in parts:
        d = rng.normal(size=(5, n))
        V = Z.c + np.sign(d @ Z.G) @ Z.G.T  # vertices: gauge 1 in Z
        for s in (0.5, 1.0, 1 + 3e-10, 1 + 1e-7, 1.5):
            pts.append(Z.c + s * (V - Z.c))
    pts = np.vstack(pts + [rng.normal(size=(5, n)) * 3])
    U = ZonotopeUnion(parts)
    exact = np.atleast_1d(union_gauge(U, pts, exact=True))
    g = np.atleast_1d(union_gauge(U, pts, within=w))
    assert np.all(g >= exact * (1 - 1e-9) - 1e-12)
    clear = np.abs(exact - w) > 1e-10  # not within rounding of the threshold itself
    assert np.array_equal((g <= w)[clear], (exact <= w)[clear])
    above = exact > w + 1e-10
    assert np.allclose(g[above], exact[above], rtol=1e-9)
    assert np.all(g[exact <= 1.0 + 1e-12] <= w)


def test_union_gauge_within_is_checked():
    import pytest

    from ocreach.errors import SetError

    Z = Zonotope(np.zeros(2), np.eye(2))
    for bad in (1.0, 0.5, float("nan"), float("inf")):
        with pytest.raises(SetError, match="within must be a finite number > 1"):
            union_gauge(Z, np.zeros(2), within=bad)
