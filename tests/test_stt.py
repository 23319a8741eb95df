"""STT polynomial-zonotope reachability (Foss et al. Algorithm 1) against independent truth:
exact polynomial evaluation, the set library's tensor maps, true propagation (DOP853), Monte Carlo
endpoints, and a direct-optimisation support function written here (CasADi + IPOPT)."""
from __future__ import annotations

import dataclasses

import casadi as ca
import numpy as np
import pytest

import ocreach
from ocreach.dynamics.flow import propagate, stt_polynomial
from ocreach.errors import ProblemError
from ocreach.geometry import hull_area, outline_area, points_in_polygons
from ocreach.problem import ControlSet
from ocreach.reach.mc import MonteCarlo
from ocreach.reach.stt import STTReach, fused_step
from ocreach.registry import get_problem
from ocreach.sets import Interval, PolyZonotope, PZUnion, new_ids, tensor_map
from ocreach.sets.polyzonotope import make_dependent


# ---------------------------------------------------------------------------- helpers
def direct_support(problem, dirs, dims, sub=4):
    """max d^T x(t_f) over piecewise-constant admissible controls (single shooting, RK4, IPOPT).

    Each direction is started from u = 0 and from the bang-bang guess of the previous optimum.
    Returns (values, optimal endpoints)."""
    m, K, g = problem.model, problem.n_segments, problem.grid
    U = ca.SX.sym("U", m.n_u, K)
    x = ca.SX(problem.x0)
    for k in range(K):
        h = (g[k + 1] - g[k]) / sub
        for _ in range(sub):
            def f(xx, k=k):
                return m.f_fun(xx, U[:, k], g[k], problem.params)
            k1 = f(x)
            k2 = f(x + h / 2 * k1)
            k3 = f(x + h / 2 * k2)
            k4 = f(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    d = ca.SX.sym("d", len(dims))
    if problem.control_set.kind == "box":
        gcon, lbg, ubg = ca.SX(0, 1), [], []
    else:
        gcon, lbg, ubg = ca.vec(ca.sum1(U ** 2)), -np.inf, 1.0
    S = ca.nlpsol("S", "ipopt", {"x": ca.vec(U), "p": d, "f": -ca.dot(d, x[list(dims)]), "g": gcon},
                  {"ipopt.print_level": 0, "print_time": 0, "ipopt.tol": 1e-9, "ipopt.sb": "yes"})
    xf = ca.Function("xf", [ca.vec(U)], [x])
    vals, pts = [], []
    for di in dirs:
        best, ok = None, False
        for u0 in (np.zeros(m.n_u * K), np.full(m.n_u * K, 0.3)):
            r = S(x0=u0, p=di, lbx=-1, ubx=1, lbg=lbg, ubg=ubg)
            if best is None or float(r["f"]) < float(best["f"]):
                best, ok = r, S.stats()["success"]
        assert ok, f"IPOPT failed on the best start for direction {di}"
        vals.append(-float(best["f"]))
        pts.append(np.asarray(xf(best["x"])).ravel()[list(dims)])
    return np.array(vals), np.array(pts)


def mc_endpoints(problem, kind, samples, seed=1):
    pm = dataclasses.replace(problem, control_set=ControlSet(kind, problem.model.n_u))
    return MonteCarlo(samples=samples, seed=seed, mix=(0.3, 0.2, 0.5)).solve(pm).points[-1]


def random_pz(rng, nz, h, p, q):
    E = (rng.random((p, h)) < 0.25) * rng.integers(1, 3, (p, h))
    return PolyZonotope(0.1 * rng.standard_normal(nz), rng.standard_normal((nz, h)),
                        rng.standard_normal((nz, q)), E, new_ids(p))


# ---------------------------------------------------------------------------- the step
@pytest.mark.parametrize("n, nz, order", [(2, 3, 3), (4, 6, 2), (3, 5, 3)])
def test_fused_step_equals_library_tensor_maps_and_polynomial(n, nz, order):
    rng = np.random.default_rng(order + nz)
    pz = random_pz(rng, nz, 25, 7, 0)
    phi = [rng.standard_normal((n,) + (nz,) * j) for j in range(1, order + 1)]
    F = fused_step(phi, pz, 10 ** 9)
    L = phi[0] @ pz
    for j in range(2, order + 1):
        L = L + tensor_map(phi[j - 1] / [1, 1, 2, 6][j], pz)
    alpha = rng.uniform(-1, 1, (9, pz.n_factors))
    exact = sum(stt_polynomial(phi, pz.evaluate(alpha)))   # Foss Eq. 13 evaluated point-wise
    Fe = F.evaluate(alpha[:, np.searchsorted(pz.id, F.id)] if F.n_factors < pz.n_factors else alpha)
    np.testing.assert_allclose(Fe, exact, atol=1e-10)
    np.testing.assert_allclose(L.evaluate(alpha), exact, atol=1e-10)
    # with reduction: a superset of the exact image, same as library reduce on the same set
    R = fused_step(phi, pz, 40)
    assert R.n_generators <= 40
    D = rng.standard_normal((40, n))
    pts = sum(stt_polynomial(phi, pz.sample(20000, rng, mode="extreme")))
    assert np.all(R.support(D) >= (pts @ D.T).max(axis=0) - 1e-9)
    np.testing.assert_allclose(R.support(D), L.reduce(40, "pca").support(D), rtol=1e-9, atol=1e-9)


def test_fused_step_with_independent_generators_is_sound():
    rng = np.random.default_rng(5)
    pz = random_pz(rng, 3, 30, 6, 5)
    phi = [rng.standard_normal((2,) + (3,) * j) for j in (1, 2, 3)]
    D = rng.standard_normal((60, 2))
    pts = sum(stt_polynomial(phi, pz.sample(40000, rng, mode="extreme")))
    for h in (10 ** 9, 30):
        R = fused_step(phi, pz, h)
        assert np.all(R.support(D) >= (pts @ D.T).max(axis=0) - 1e-9)


def test_make_dependent_is_exact_and_split_covers():
    rng = np.random.default_rng(2)
    pz = random_pz(rng, 2, 6, 3, 2)
    dep = make_dependent(pz)
    assert dep.n_independent == 0 and dep.n_dependent == 8
    a, b = rng.uniform(-1, 1, (50, 3)), rng.uniform(-1, 1, (50, 2))
    np.testing.assert_allclose(dep.evaluate(np.hstack([a, b])), pz.evaluate(a, b), atol=1e-12)


# ---------------------------------------------------------------------------- first step vs truth
def test_first_step_matches_true_propagation():
    """R_1 with the box input: the factor of the input is u itself, so evaluating the set at
    alpha = u must give the true endpoint up to the STT truncation error."""
    p = get_problem("vdp", t_final=0.2)
    r = ocreach.reach(p, "stt", order=3, h_max=50)
    S = r.sets[1]
    u = np.linspace(-1, 1, 9)[:, None]
    truth = propagate(p.model, np.tile(p.x0, (9, 1)), u[:, None, :], p.grid[:2], p=p.params)[:, -1]
    np.testing.assert_allclose(S.evaluate(u), truth, atol=1e-9)
    assert r.meta["evaluations"]["tensor_maps"] == 2
    assert set(r.meta["runtime"]) >= {"stt_generation", "tensor_maps"}


# ---------------------------------------------------------------------------- paper problems
@pytest.fixture(scope="module")
def vdp_result():
    p = get_problem("vdp")
    return p, ocreach.reach(p, "stt", order=3, h_max=200)


def test_vdp_covers_mc_and_area_within_1p5_of_true_hull(vdp_result):
    """Foss Sec. 3.1 (n = 3, h_max = 200).  True hull: convex hull of direct-optimisation optima
    (12 directions) and 2000 MC endpoints with the same (box) control set."""
    p, r = vdp_result
    S = r.sets[-1]
    assert isinstance(S, PolyZonotope) and S.n_generators <= 200
    end = mc_endpoints(p, "box", 2000)
    polys = S.outline((0, 1), pieces=64)
    assert points_in_polygons(end, polys).mean() >= 0.995
    th = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    dirs = np.c_[np.cos(th), np.sin(th)]
    h_true, opt_pts = direct_support(p, dirs, (0, 1))
    assert np.all(end @ dirs.T <= h_true[None] + 1e-6)          # the optimiser found the max
    width = h_true + direct_support(p, -dirs[:1], (0, 1))[0][0]
    assert np.all(S.support(dirs) >= h_true - 1e-3 * width[0])  # STT support over-approximates
    ratio = outline_area(polys) / hull_area(np.vstack([opt_pts, end]))
    assert 1.0 <= ratio <= 1.5


def test_dro_box_covers_mc_endpoints():
    """Foss Sec. 4.1 with the box input (n = 2, h_max = 400); MC with the same box controls."""
    p = get_problem("dro")
    r = ocreach.reach(p, "stt")
    assert r.meta["options"]["order"] == 2 and r.meta["input_set"] == "box"
    end = mc_endpoints(p, "box", 1500)
    for dims in ((0, 1), (2, 3)):
        polys = r.sets[-1].outline(dims, pieces=32)
        assert points_in_polygons(end[:, dims], polys).mean() >= 0.995
        ratio = outline_area(polys) / hull_area(end[:, dims])
        assert 1.0 < ratio < 4.0   # MC hull is an inner estimate; ratios: docs/validation/stt.md


def test_initial_set_and_splitting_cover_mc():
    """An uncertain initial box (converted to a PZ) on Van der Pol: both the plain run and the
    split run (per-part references) cover the MC endpoints; splitting shrinks the area
    (measured 5.9x -> 3.1x the MC hull, docs/validation/stt.md)."""
    base = get_problem("vdp")
    box = Interval(base.x0 - 0.1, base.x0 + 0.1)
    p = dataclasses.replace(base, initial_set=box)
    plain = ocreach.reach(p, "stt", order=2, h_max=100)
    split = ocreach.reach(p, "stt", order=2, h_max=100, split="factor", max_parts=4, split_tol=0.002)
    assert isinstance(split.sets[-1], PZUnion) and split.meta["evaluations"]["splits"] >= 1
    np.testing.assert_allclose(plain.sets[0].interval_hull().lo, box.lo, atol=1e-12)
    end = MonteCarlo(samples=1500, seed=3).solve(p).points[-1]
    area = {}
    for name, r in (("plain", plain), ("split", split)):
        polys = r.sets[-1].outline((0, 1), pieces=64)
        assert points_in_polygons(end, polys).mean() >= 0.995
        area[name] = outline_area(polys)
    assert area["split"] < 0.75 * area["plain"]


def test_tube_contains_dense_true_trajectories(tmp_path):
    p = get_problem("vdp", t_final=0.6)
    r = STTReach(order=2, h_max=60, tube_substeps=4).solve(p)
    assert len(r.tubes) == p.n_segments
    back = ocreach.load(r.save(tmp_path / "tube.npz"))          # tubes are saved and loaded
    np.testing.assert_allclose(back.tubes[2].support(np.eye(2)), r.tubes[2].support(np.eye(2)))
    assert ocreach.load(STTReach(order=1, h_max=20).solve(p).save(tmp_path / "n.npz")).tubes is None
    assert r.project([1]).tubes[0].dim == 1
    with pytest.raises(ProblemError, match="segment"):
        dataclasses.replace(r, tubes=r.tubes[:-1])
    rng = np.random.default_rng(0)
    u = p.control_set.sample_boundary(rng, (200, p.n_segments))
    _, _, dense = propagate(p.model, np.tile(p.x0, (200, 1)), u, p.grid, p=p.params, substeps=10)
    for k in range(p.n_segments):
        pts = dense[:, 10 * k:10 * k + 11].reshape(-1, 2)
        polys = r.tubes[k].outline((0, 1), pieces=64)
        assert points_in_polygons(pts, polys).mean() >= 0.999


@pytest.mark.parametrize("opts", [dict(order=4), dict(h_max=0), dict(input_set="disk"),
                                  dict(reduction="svd"), dict(split=(0, 1.0)), dict(split="x"),
                                  dict(tube_substeps=1), dict(engine="gpu"), dict(foo=1)])
def test_bad_options(opts):
    with pytest.raises(ProblemError):
        STTReach(**opts)


def test_divergence_is_reported_not_silent():
    """A large initial box on Van der Pol drives the order-3 STT image to overflow; the method
    must raise a SolverError naming the step instead of returning NaN/inf sets."""
    from ocreach.errors import SolverError

    base = get_problem("vdp")
    p = dataclasses.replace(base, initial_set=Interval(base.x0 - 0.8, base.x0 + 0.8))
    with pytest.raises(SolverError, match="step"):
        ocreach.reach(p, "stt", order=3, h_max=100)


# ---------------------------------------------------------------------------- compare on stt sets
def test_compare_coverage_uses_outline_pieces_not_the_zonotope_enclosure():
    """A thin band around a parabola, {(a, a^2 + 0.1 b)}: the point (0, 0.8) is outside (exactly:
    |y - x^2| <= 0.1), yet inside the zonotope enclosure that ``PolyZonotope.contains`` tests.
    The comparison's coverage must use the outline pieces; its area must be the union's, near the
    exact band area 0.4 (not the enclosure's 2 x 1.2)."""
    from ocreach.compare import _projected_estimate
    from ocreach.reach.result import ReachResult

    pz = PolyZonotope(np.zeros(2), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.1]]), None,
                      np.array([[1, 2, 0], [0, 0, 1]]), new_ids(2))
    assert pz.contains(np.array([0.0, 0.8]))              # the loose test this replaces
    res = ReachResult(times=[0.0], sets=[pz])
    _, area, contains = _projected_estimate(res, (0, 1))
    a = np.random.default_rng(0).uniform(-1, 1, (500, 2))
    band = np.c_[a[:, 0], a[:, 0] ** 2 + 0.1 * a[:, 1]]
    assert contains(band).all()
    assert not contains(np.array([[0.0, 0.8], [0.5, 0.6], [-0.5, -0.1]])).any()
    assert 0.4 <= area <= 0.6


def test_compare_notes_a_different_input_set():
    from ocreach.compare import Comparison
    from ocreach.reach.result import ReachResult

    p = get_problem("vdp", t_final=0.2)
    res = ReachResult(times=p.grid, sets=[PolyZonotope(p.x0)] * p.grid.size, meta={"input_set": "ball"})
    cmp = Comparison(problem=p, results={"stt": res}, metrics={}, truth=np.zeros((0, 2)))
    assert "'ball' input set" in cmp.table()
    res.meta["input_set"] = p.control_set.kind
    assert cmp.notes() == []


@pytest.mark.parametrize("engine", ["fused", "library"])
def test_overflowing_reduction_raises_solver_error(engine):
    """Generators ~1e160 are finite, but the PCA reduction's G G^T overflows and numpy's SVD fails
    (nrho-flyby with dt = 0.025 hit this as a bare LinAlgError): it must be the SolverError of a
    diverged propagation."""
    from ocreach.errors import SolverError
    from ocreach.reach.base import Timer
    from ocreach.reach.stt import stt_step

    rng = np.random.default_rng(1)
    pz = random_pz(rng, 3, 30, 5, 0)
    phi = [1e160 * rng.standard_normal((3, 3)), rng.standard_normal((3, 3, 3))]
    with pytest.raises(SolverError, match="diverged"):
        stt_step(phi, pz, 10, "pca", engine, Timer(), {"tensor_maps": 0, "reductions": 0})


def test_pruned_third_order_products_stay_sound():
    """The fused step's shortcut (order-3 products with a tiny norm bound skip the merge and go
    into the reduction's box) only runs with > 50,000 products: 70 generators of decaying size.
    The pruned set must still contain the exact image (Eq. 13 on extreme samples) and stay close
    to the unpruned one."""
    rng = np.random.default_rng(7)
    pz = random_pz(rng, 3, 70, 8, 0)
    pz = PolyZonotope(pz.c, pz.G * 0.8 ** np.arange(70), None, pz.E, pz.id)
    phi = [rng.standard_normal((2,) + (3,) * j) for j in (1, 2, 3)]
    counts = {"tensor_maps": 0, "reductions": 0}
    pruned = fused_step(phi, pz, 40, counts=counts, prune=1e-3)
    assert counts["pruned"] > 0
    full = fused_step(phi, pz, 40, prune=0.0)
    D = rng.standard_normal((60, 2))
    pts = sum(stt_polynomial(phi, pz.sample(40000, rng, mode="extreme")))
    hp, hf = pruned.support(D), full.support(D)
    assert np.all(hp >= (pts @ D.T).max(axis=0) - 1e-9)
    np.testing.assert_allclose(hp, hf, rtol=0.05)


# ---------------------------------------------------------------------------- chunked order 3
def _decaying_pz(rng, h, q):
    pz = random_pz(rng, 3, h, 8, q)
    return PolyZonotope(pz.c, pz.G * 0.8 ** np.arange(h), 0.01 * pz.GI, pz.E, pz.id)


@pytest.mark.parametrize("method", ["pca", "girard"])
@pytest.mark.parametrize("q", [0, 4])
def test_chunked_order3_equals_unchunked_to_round_off(method, q):
    """Order-3 products formed in blocks of 7 (merged whenever more wait, pruned ones boxed from
    their Gram matrix and a second pass) give the set of one block holding everything: the same
    centre, generators, exponents and identifiers up to round-off -- with pruning on (> 50,000
    products) and off -- and the exact image (Eq. 13 on samples) stays inside."""
    rng = np.random.default_rng(11 + q)
    pz = _decaying_pz(rng, 75, q)
    phi = [rng.standard_normal((2,) + (3,) * j) for j in (1, 2, 3)]
    pts = sum(stt_polynomial(phi, pz.sample(20000, rng, mode="extreme")))
    D = rng.standard_normal((40, 2))
    for prune in (1e-3, 0.0):
        counts = {"tensor_maps": 0, "reductions": 0}
        one = fused_step(phi, pz, 40, method, counts=counts, prune=prune, chunk=10 ** 9)
        assert (counts["pruned"] > 0) == (prune > 0)
        tiny = fused_step(phi, pz, 40, method, prune=prune, chunk=7)
        for a, b in [(one.c, tiny.c), (one.G, tiny.G), (one.GI, tiny.GI)]:
            np.testing.assert_allclose(b, a, rtol=1e-11, atol=1e-13 * np.abs(one.G).max())
        np.testing.assert_array_equal(tiny.E, one.E)
        np.testing.assert_array_equal(tiny.id, one.id)
        assert np.all(tiny.support(D) >= (pts @ D.T).max(axis=0) - 1e-9)


def test_chunked_order3_memory_stays_bounded():
    """240 generators: 2.4 M order-3 products, 38 MB as one (2, N) array (the pre-chunking code
    materialised several such arrays).  With blocks of 2**14 products the traced peak of the
    step stays below a quarter of that one array."""
    import tracemalloc

    rng = np.random.default_rng(3)
    pz = _decaying_pz(rng, 240, 0)
    phi = [rng.standard_normal((2,) + (3,) * j) for j in (1, 2, 3)]
    H = 1 + pz.n_generators
    one_array = 2 * 8 * H * (H + 1) * (H + 2) // 6
    tracemalloc.start()
    try:
        fused_step(phi, pz, 100, chunk=2 ** 14)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < one_array / 4, (peak, one_array)


def test_chunk_option_is_checked():
    with pytest.raises(ProblemError, match="chunk"):
        STTReach(chunk=-1)
    assert STTReach(chunk=5000).options.chunk == 5000
