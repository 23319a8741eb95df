"""Tubes, gauges, the event trigger and station keeping (Patel & Subbarao, NRHO station keeping),
checked against independent truth: facet enumeration and cvxpy (gauge), a hand-written trigger
trace, SciPy's solve_ivp (drift tubes, Delta-V)."""
from __future__ import annotations

import itertools
import json

import casadi as ca
import cvxpy as cp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import ocreach
from ocreach.control import MPC, reference_from_problem
from ocreach.control.stationkeeping.drift_tubes import drift_schedule
from ocreach.control.stationkeeping.event_mpc import EventTrigger, EventTriggeredMPC, trigger_signal
from ocreach.control.stationkeeping.metrics import delta_v_si, station_keeping_metrics
from ocreach.control.stationkeeping.runs import run_station_keeping
from ocreach.control.stationkeeping.tubes import (
    Tube,
    TubeSchedule,
    casadi_gauge_constraints,
    gauge,
    linear_drift_tube,
    reach_drift_tube,
)
from ocreach.errors import ProblemError

Q_PAPER = np.diag([1000.0] * 3 + [100.0] * 3)
R_PAPER = np.eye(3)


@pytest.fixture(scope="module")
def halo():
    return ocreach.get_problem("l2-halo")


@pytest.fixture(scope="module")
def halo_ref(halo):
    return reference_from_problem(halo)


# ----------------------------------------------------------------------------- gauge
def _facet_gauge(c, G, X):
    """Brute force: gauge = max over facets (n_i . r) / h(n_i), facets by generalised cross
    products of every (n-1)-subset of generators (written out here, independent of ocreach)."""
    n, q = G.shape
    normals = []
    for S in itertools.combinations(range(q), n - 1):
        M = G[:, S]
        nv = np.array([(-1) ** i * np.linalg.det(np.delete(M, i, axis=0)) for i in range(n)]) \
            if n > 1 else np.ones(1)
        if np.linalg.norm(nv) > 1e-12:
            normals += [nv, -nv]
    N = np.array(normals)
    h = np.abs(N @ G).sum(axis=1)
    return ((X - c) @ N.T / h).max(axis=1)


def _cvxpy_gauge(c, G, x):
    xi = cp.Variable(G.shape[1])
    prob = cp.Problem(cp.Minimize(cp.norm(xi, "inf")), [G @ xi == x - c])
    prob.solve(solver=cp.CLARABEL)
    return np.inf if prob.status == "infeasible" else float(prob.value)


def _casadi_gauge(c, G, x):
    """min t s.t. the CasADi constraint form x = c + G xi, -t <= xi <= t, solved with IPOPT."""
    xs = ca.MX(ca.DM(x))
    t = ca.MX.sym("t")
    form = casadi_gauge_constraints(ca.DM(c), G, xs, t)
    nlp = {"x": ca.vertcat(form.xi, t), "f": t, "g": form.g}
    S = ca.nlpsol("g", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False,
                                      "ipopt.sb": "yes", "ipopt.tol": 1e-12})
    q = G.shape[1]
    sol = S(lbg=form.lbg, ubg=form.ubg, lbx=np.r_[np.full(q, -np.inf), 0.0])
    assert S.stats()["success"]
    return float(sol["x"][-1])


@pytest.mark.parametrize("n,q", [(2, 2), (2, 5), (3, 4), (3, 7), (4, 6)])
def test_gauge_lp_and_casadi_form_agree_with_brute_force(n, q):
    rng = np.random.default_rng(10 * n + q)
    c = rng.standard_normal(n)
    G = rng.standard_normal((n, q))
    X = c + 2.0 * rng.standard_normal((40, n))
    lp = gauge(c, G, X)
    brute = _facet_gauge(c, G, X)
    assert np.allclose(lp, brute, rtol=1e-7, atol=1e-9)
    for i in range(3):
        assert _cvxpy_gauge(c, G, X[i]) == pytest.approx(lp[i], rel=1e-6)
        assert _casadi_gauge(c, G, X[i]) == pytest.approx(lp[i], rel=1e-6)
    # membership is gauge <= 1: the points c + G xi with |xi| <= 1 are inside
    xi = rng.uniform(-1, 1, (30, q))
    assert np.all(gauge(c, G, c + xi @ G.T) <= np.abs(xi).max(axis=1) + 1e-9)
    # scale invariance: a tiny zonotope (entries 1e-10, below HiGHS's absolute tolerances)
    tiny = gauge(1e-10 * c, 1e-10 * G, 1e-10 * X)
    assert np.allclose(tiny, brute, rtol=1e-7, atol=1e-9)
    # per-point zonotopes (K, n, q) in one batched call
    Gs = rng.standard_normal((5, n, q))
    one = np.array([gauge(c, Gs[k], X[k]) for k in range(5)])
    assert np.allclose(gauge(np.tile(c, (5, 1)), Gs, X[:5]), one)


def test_gauge_of_a_degenerate_zonotope_is_inf_off_its_hull():
    c = np.array([1.0, 2.0, 3.0])
    G = np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 0.0]])  # flat in z
    on = np.array([1.7, 2.4, 3.0])
    off = np.array([1.7, 2.4, 3.1])
    g = gauge(c, G, np.vstack([on, off]))
    assert g[1] == np.inf
    assert g[0] == pytest.approx(_cvxpy_gauge(c, G, on), rel=1e-6)


# ----------------------------------------------------------------------------- trigger
def test_trigger_and_hysteresis_fire_exactly_at_the_crossings():
    """Gauge 0.5, rises above 1 at step 10, falls to <= beta = 0.7 from step 20 on; with m = 3 the
    thrust is on for steps 10..21 (release at the 3rd step inside: 22); a second excursion at 30
    (0.9 at 31 is above beta, so the count restarts), then off from 36."""
    g = np.full(45, 0.5)
    g[10:15] = 1.2
    g[15:20] = 0.8      # between beta and 1: stays on, count 0
    g[20:25] = 0.6
    g[30] = 1.0001
    g[31] = 0.65
    g[32] = 0.9         # resets the inside count
    g[33:] = 0.3
    on = trigger_signal(g, beta=0.7, m=3)
    expected = np.zeros(45, bool)
    expected[10:22] = True   # steps 20, 21 inside (count 1, 2), step 22 releases
    expected[30:35] = True   # 31 (1), 32 reset, 33 (1), 34 (2), 35 releases
    assert np.array_equal(on, expected)
    trig = EventTrigger(beta=0.7, m=3)
    for v in g:
        trig.update(v)
    assert trig.activations == 2
    # exactly 1 does not trigger (gauge > 1 means outside the closed tube)
    assert not trigger_signal([1.0, 1.0], beta=0.5, m=1).any()
    assert trigger_signal([0.2, 1.0 + 1e-12, 0.5], beta=0.5, m=1).tolist() == [False, True, False]


@pytest.mark.parametrize("kw", [{"beta": 1.0}, {"beta": 1.5}, {"beta": 0.0}, {"m": -1},
                                {"m": 0}, {"m": 2.5}, {"beta": float("nan")}])
def test_bad_trigger_options_raise(kw):
    with pytest.raises(ProblemError):
        EventTrigger(**kw)


# ----------------------------------------------------------------------------- tubes
def test_tube_validation_and_schedule_errors(halo_ref):
    c = np.zeros((5, 6))
    with pytest.raises(ProblemError, match="generators"):
        Tube(c, np.zeros((5, 5, 2)))
    with pytest.raises(ProblemError, match="generators"):
        Tube(c, np.zeros((4, 6, 2)))
    t = Tube(c, np.zeros((5, 6, 2)))
    with pytest.raises(ProblemError, match="dimension"):
        t.check_for(4, 0, 3)
    with pytest.raises(ProblemError, match="cover"):
        t.check_for(6, 0, 10)
    with pytest.raises(ProblemError, match="steps"):
        t.gauge(7, np.zeros(6))
    # a builder returning a too-short tube, a wrong-dimension tube
    M = halo_ref.n_steps
    short = TubeSchedule(lambda k: Tube(np.zeros((M - 1, 6)), np.zeros((M - 1, 6, 1)), k0=k), halo_ref,
                         phase=0)
    with pytest.raises(ProblemError, match="cover"):
        short.tube(0)
    wrong = TubeSchedule(lambda k: Tube(np.zeros((M + 1, 3)), np.zeros((M + 1, 3, 1)), k0=k),
                         halo_ref, phase=0)
    with pytest.raises(ProblemError, match="dimension"):
        wrong.tube(0)
    with pytest.raises(ProblemError, match="phase"):
        TubeSchedule(lambda k: None, halo_ref, phase=M)
    nonper = ocreach.control.natural_reference(halo_ref.model, halo_ref.X[0], halo_ref.dt, 20)
    with pytest.raises(ProblemError, match="periodic"):
        TubeSchedule(lambda k: None, nonper)


def test_schedule_refreshes_at_the_phase_and_windows_cross_it(halo, halo_ref):
    sched = drift_schedule(halo, halo_ref, membership="zonotope", phase=5, lookahead=4)
    M = halo_ref.n_steps
    assert sched.refresh_step(5) == 5 and sched.refresh_step(4) == 5 - M
    assert sched.refresh_step(5 + M) == 5 + M
    t_new = sched.tube(5 + M)
    assert t_new.k0 == 5 + M
    c, G = sched.window(M + 2, 4)  # steps M+3, M+4 from the old tube, M+5, M+6 from the new one
    z_new = t_new.zonotope(5 + M)
    assert np.allclose(c[2], z_new.c) and np.allclose(G[2, :, : z_new.n_generators], z_new.G)
    assert np.allclose(G[2], np.pad(z_new.G, ((0, 0), (0, G.shape[2] - z_new.n_generators))))
    # the refreshed tube starts at the initial set: its box is the paper's initial box
    assert np.allclose(np.abs(z_new.G).sum(axis=1), [1e-4] * 3 + [5e-4] * 3)
    # short tubes refreshed every 50 steps: built per phase, re-used a period later
    calls = []

    def build(k):
        calls.append(k)
        return linear_drift_tube(halo_ref, k, 55, 1e-5, 1e-7, halo.velocity_dims)

    short = TubeSchedule(build, halo_ref, phase=5, interval=50, lookahead=4)
    assert short.refresh_step(120) == 105 and short.tube(120).k0 == 105
    assert short.tube(130).k0 == 105 and calls == [105]  # cached
    assert short.tube(155).k0 == 155 and calls == [105, 155]
    assert short.refresh_step(5 + 7 * 50 + 3) == 355
    # refresh steps per period (intervals of different lengths), each tube exactly its interval
    lengths = []

    def exact(k):
        n = multi.next_refresh(k) - k
        lengths.append((k, n))
        return linear_drift_tube(halo_ref, k, n, 1e-5, 1e-7, halo.velocity_dims)

    multi = TubeSchedule(exact, halo_ref, phases=[100, 5, 40])
    assert multi.phase == 5 and multi.interval == M - 95
    assert [multi.refresh_step(k) for k in (4, 5, 39, 40, 99, 100, M + 4, M + 41)] == \
        [100 - M, 5, 5, 40, 40, 100, 100, M + 40]
    assert [multi.next_refresh(r) for r in (5, 40, 100, 100 - M)] == [40, 100, M + 5, 5]
    assert multi.refresh_steps(M + 6) == [100 - M, 5, 40, 100, M + 5]
    assert multi.tube(M + 50).k0 == M + 40 and len(multi.tube(M + 50)) == 60
    assert multi.tube(M + 99).gauge(M + 99, multi.tube(M + 99).centers[-1]) == 0.0
    with pytest.raises(ProblemError, match="either phases"):
        TubeSchedule(exact, halo_ref, phases=[5], interval=10)
    with pytest.raises(ProblemError, match="phases"):
        TubeSchedule(exact, halo_ref, phases=[M])
    with pytest.raises(ProblemError, match="phases"):
        TubeSchedule(exact, halo_ref, phases=[])
    with pytest.raises(ProblemError, match="adaptive"):
        drift_schedule(halo, halo_ref, source="linear", interval="adaptive")


def _cr3bp_rhs(mu):
    def f(t, x, w):
        r1 = np.sqrt((x[0] + mu) ** 2 + x[1] ** 2 + x[2] ** 2)
        r2 = np.sqrt((x[0] - 1 + mu) ** 2 + x[1] ** 2 + x[2] ** 2)
        ax = 2 * x[4] + x[0] - (1 - mu) * (x[0] + mu) / r1**3 - mu * (x[0] - 1 + mu) / r2**3
        ay = -2 * x[3] + x[1] - (1 - mu) * x[1] / r1**3 - mu * x[1] / r2**3
        az = -(1 - mu) * x[2] / r1**3 - mu * x[2] / r2**3
        return np.r_[x[3:], ax + w[0], ay + w[1], az + w[2]]
    return f


def _worst_drift_gauge(halo, ref, scale, L, n_traj, seed):
    """Largest tube gauge of sampled drift trajectories.  The deviation from the nominal (xi = 0,
    w = 0) trajectory integrated the same way is added to the tube centre, so the integration
    error of the reference itself (~1e-11 DU, comparable to the W part of a small set) cancels."""
    G0 = scale * np.r_[1e-4, 1e-4, 1e-4, 5e-4, 5e-4, 5e-4]
    tube = linear_drift_tube(ref, 0, L, G0, 1e-7, halo.velocity_dims)
    assert not tube.guaranteed
    rhs = _cr3bp_rhs(halo.param("mu"))
    rng = np.random.default_rng(seed)

    def run(x0, ws):
        X = [x0]
        for k in range(L - 1):
            sol = solve_ivp(rhs, (ref.time(k), ref.time(k + 1)), X[-1], args=(ws[k],),
                            method="DOP853", rtol=1e-13, atol=1e-15)
            X.append(sol.y[:, -1])
        return np.array(X)

    nominal = run(ref.state(0), np.zeros((L, 3)))
    worst = 0.0
    for s in range(n_traj):
        xi = rng.choice([-1.0, 1.0], 6) if s < n_traj // 2 else rng.uniform(-1, 1, 6)
        X = run(ref.state(0) + G0 * xi, 1e-7 * rng.choice([-1.0, 1.0], (L, 3)))
        pts = tube.centers + (X - nominal)
        worst = max(worst, float(tube.gauge(np.arange(L), pts).max()))
    return worst


def test_linear_drift_tube_contains_sampled_drift_trajectories(halo, halo_ref):
    """Zero thrust, initial set and W: trajectories from corners and the inside of the initial
    set with per-step disturbance draws (independent SciPy DOP853 integration of the CR3BP written
    out here) stay in the linearised tube over 60 h of the L2 halo, up to the neglected
    second-order term: the linear tube is NOT guaranteed, so the excess over 1 must be small and
    shrink with the initial set (the paper's, and 1/100 of it)."""
    e_paper = _worst_drift_gauge(halo, halo_ref, 1.0, 61, 6, 3) - 1
    e_small = _worst_drift_gauge(halo, halo_ref, 1e-2, 61, 6, 3) - 1
    assert e_paper <= 5e-3       # paper's initial set: within 0.5 % of the tube
    assert e_small <= 1e-6       # 1/100 of it: the neglected second-order term vanishes
    assert e_small > -0.5        # the corners reach the boundary: the tube is not trivially large


def test_taylor_drift_tube_contains_every_sampled_drift_trajectory(halo, halo_ref):
    """The sound tube (``taylor``, zero thrust, the paper's initial set and W = 1e-7) over 30 h of
    the L2 halo: every sampled trajectory (corners and interior of the initial set, per-step
    disturbance corners; independent SciPy DOP853 integration) has zonotope gauge <= 1."""
    G0 = np.r_[1e-4, 1e-4, 1e-4, 5e-4, 5e-4, 5e-4]
    L = 31
    tube = reach_drift_tube(halo, halo_ref, 0, L, G0, 1e-7, "taylor")
    assert tube.guaranteed and len(tube) == L and tube.k0 == 0
    rhs = _cr3bp_rhs(halo.param("mu"))
    rng = np.random.default_rng(5)
    worst = 0.0
    for s in range(8):
        xi = rng.choice([-1.0, 1.0], 6) if s < 5 else rng.uniform(-1, 1, 6)
        X = [halo_ref.state(0) + G0 * xi]
        for k in range(L - 1):
            w = 1e-7 * rng.choice([-1.0, 1.0], 3)
            sol = solve_ivp(rhs, (halo_ref.time(k), halo_ref.time(k + 1)), X[-1], args=(w,),
                            method="DOP853", rtol=1e-12, atol=1e-14)
            X.append(sol.y[:, -1])
        worst = max(worst, float(tube.gauge(np.arange(L), np.array(X)).max()))
    assert worst <= 1.0
    assert worst > 0.3  # not trivially large


@pytest.fixture(scope="module")
def nrho():
    return ocreach.get_problem("nrho-9-2")


@pytest.fixture(scope="module")
def nrho_ref(nrho):
    return reference_from_problem(nrho)


def _batch_cr3bp_rhs(mu, w):
    """CR3BP written out here (independent of ocreach) for a batch: ``x`` is (6 N,), ``w`` (N, 3)
    the disturbance held over the step."""
    def f(t, x):
        X = x.reshape(-1, 6)
        r1 = np.sqrt((X[:, 0] + mu) ** 2 + X[:, 1] ** 2 + X[:, 2] ** 2)
        r2 = np.sqrt((X[:, 0] - 1 + mu) ** 2 + X[:, 1] ** 2 + X[:, 2] ** 2)
        ax = (2 * X[:, 4] + X[:, 0] - (1 - mu) * (X[:, 0] + mu) / r1**3
              - mu * (X[:, 0] - 1 + mu) / r2**3)
        ay = -2 * X[:, 3] + X[:, 1] - (1 - mu) * X[:, 1] / r1**3 - mu * X[:, 1] / r2**3
        az = -(1 - mu) * X[:, 2] / r1**3 - mu * X[:, 2] / r2**3
        return np.column_stack([X[:, 3:], ax + w[:, 0], ay + w[:, 1], az + w[:, 2]]).ravel()
    return f


def test_adaptive_sound_tubes_cross_the_nrho_perilune_and_contain_every_sampled_drift(nrho,
                                                                                       nrho_ref):
    """The guaranteed tubes of ``tube_interval="adaptive"`` across the 9:2 NRHO's perilune (steps
    72..84, perilune between 78 and 79): ``taylor`` from the paper's initial set stops a few steps
    after perilune, so the partition restarts it there, and every tube is guaranteed.  Every
    sampled zero-thrust drift trajectory -- all 64 vertices and 16 interior points of each
    tube's initial box, per-step disturbances at the corners of +-W, independent SciPy DOP853
    integration of the CR3BP -- has zonotope gauge <= 1 at every grid time of its tube."""
    from ocreach.control.stationkeeping.drift_tubes import ADAPTIVE_TUBE_OPTIONS
    from ocreach.control.stationkeeping.paper import paper_initial_set
    from ocreach.control.stationkeeping.tubes import sound_drift_partition

    G0 = paper_initial_set(nrho)
    tubes = sound_drift_partition(nrho, nrho_ref, 72, 85, G0, 1e-7, "taylor",
                                  **ADAPTIVE_TUBE_OPTIONS)
    assert len(tubes) >= 2  # one tube from step 72 cannot cross perilune
    assert tubes[0].k0 == 72 and tubes[-1].k_end == 84
    assert all(b.k0 == a.k_end + 1 for a, b in itertools.pairwise(tubes))  # contiguous
    assert all(t.guaranteed and "failure" in t.meta for t in tubes[:-1]) and tubes[-1].guaranteed
    mu = nrho.param("mu")
    rng = np.random.default_rng(11)
    vertices = np.array(list(itertools.product([-1.0, 1.0], repeat=6)))
    worst = []
    for tube in tubes:
        xi = np.vstack([vertices, rng.uniform(-1, 1, (16, 6))])
        X = nrho_ref.state(tube.k0) + xi * G0
        assert np.max(tube.gauge(np.full(len(X), tube.k0), X)) <= 1 + 1e-12  # vertices on it
        gam = []
        for k in range(tube.k0, tube.k_end):
            w = 1e-7 * rng.choice([-1.0, 1.0], (len(X), 3))
            sol = solve_ivp(_batch_cr3bp_rhs(mu, w), (nrho_ref.time(k), nrho_ref.time(k + 1)),
                            X.ravel(), method="DOP853", rtol=1e-12, atol=1e-14)
            assert sol.success
            X = sol.y[:, -1].reshape(-1, 6)
            gam.append(tube.gauge(np.full(len(X), k + 1), X))
        worst.append(float(np.max(gam)))
    # <= 1 up to the gauge LP's tolerance (HiGHS feasibility tolerance 1e-9)
    assert max(worst) <= 1.0 + 1e-8
    assert min(worst) > 0.3  # not trivially large


def test_sound_drift_partition_bad_input_and_budget(nrho, nrho_ref):
    """A range that is empty, a tube budget too small for perilune (taylor from step 72 stops at
    79, so one tube cannot cover 72..84), and the partial tube: its steps, its failure message."""
    from ocreach.control.stationkeeping.drift_tubes import ADAPTIVE_TUBE_OPTIONS
    from ocreach.control.stationkeeping.paper import paper_initial_set
    from ocreach.control.stationkeeping.tubes import sound_drift_partition
    from ocreach.errors import SolverError

    G0 = paper_initial_set(nrho)
    with pytest.raises(ProblemError, match="stop"):
        sound_drift_partition(nrho, nrho_ref, 10, 10, G0, 1e-7)
    with pytest.raises(ProblemError, match="start must be an integer >= 0; got 'x'"):
        sound_drift_partition(nrho, nrho_ref, "x", 10, G0, 1e-7)
    with pytest.raises(ProblemError, match="stop must be an integer >= 1; got 2.5"):
        sound_drift_partition(nrho, nrho_ref, 0, 2.5, G0, 1e-7)
    with pytest.raises(SolverError, match="max_tubes = 1"):
        sound_drift_partition(nrho, nrho_ref, 72, 85, G0, 1e-7, max_tubes=1,
                              **ADAPTIVE_TUBE_OPTIONS)
    part = reach_drift_tube(nrho, nrho_ref, 72, 14, G0, 1e-7, "taylor", partial=True,
                            **ADAPTIVE_TUBE_OPTIONS)
    assert part.k0 == 72 and part.k_end == 79 and part.guaranteed
    assert "cannot be enclosed" in part.meta["failure"]
    with pytest.raises(SolverError, match="cannot be enclosed"):
        reach_drift_tube(nrho, nrho_ref, 72, 14, G0, 1e-7, "taylor", **ADAPTIVE_TUBE_OPTIONS)


def test_nrho_station_keeping_uses_guaranteed_tubes_and_says_so_per_refresh(nrho):
    """nrho-9-2's default station-keeping tube (``problem.extra``): taylor, refreshed where it
    stops; over 0.6 revolutions every refresh interval is logged as guaranteed, in the settings
    and in each controller's metrics, and the intervals tile the run."""
    assert nrho.extra["station_keeping"] == {"tube_source": "taylor", "tube_interval": "adaptive",
                                             "anticipate": True}
    run = run_station_keeping(nrho, controllers=("lqr",), revolutions=0.6)
    s = run.settings
    tubes = s["tubes"]
    assert s["refresh_steps_per_rev"] == [t["refresh_step"] for t in tubes]
    assert len(tubes) >= 3 and tubes[0]["steps"][0] == 0 and tubes[-1]["steps"][1] == s["n_steps"]
    assert all(a["steps"][1] == b["steps"][0] for a, b in itertools.pairwise(tubes))
    assert all(t["guaranteed"] and t["source"].startswith("interval hull of taylor")
               for t in tubes)
    assert s["tube_guaranteed"] is True and run.metrics["lqr"]["tube_guaranteed"] is True
    # the LQR from the paper's offset stays in the (large) guaranteed tubes
    assert run.metrics["lqr"]["max_gauge"] <= 1.0


def test_anticipating_trigger_fires_before_the_gate_on_the_predicted_drift(nrho, nrho_ref):
    """``anticipate=True``: at step 40 (deep inside the large apolune tube) a state whose drift
    misses the initial box of the next refresh (step 76 of the guaranteed schedule) by 1.5x
    triggers the MPC; without anticipation it does not.  The predicted gauge is checked against the drift
    integrated independently (SciPy DOP853, the CR3BP written out here): the linear prediction is
    an estimate, within 2 % here."""
    sched = drift_schedule(nrho, nrho_ref, source="taylor", interval="adaptive",
                           tube_options=None)
    k, r = 40, sched.next_refresh(sched.refresh_step(40))
    assert r == 76 and sched.refresh_step(k) == 0
    box = sched.tube(r).half_widths()[0]
    nrho_ref.linearize()
    Phi = np.eye(6)
    for i in range(k, r):  # the reference's one-step STMs (RK4 variational, 32 substeps)
        Phi = nrho_ref.A[i] @ Phi
    v = np.linalg.svd(Phi)[2][0]  # the most amplified direction, scaled to land at 1.5x the box
    x = nrho_ref.state(k) + 1.5 * v / np.abs(Phi @ v / box).max()
    assert sched.gauge(k, x) < 0.1  # deep inside the current (apolune) tube
    sol = solve_ivp(_batch_cr3bp_rhs(nrho.param("mu"), np.zeros((1, 3))),
                    (nrho_ref.time(k), nrho_ref.time(r)), x, method="DOP853", rtol=1e-12,
                    atol=1e-14)
    g_true = sched.gauge(r, sol.y[:, -1])
    ctl = {a: EventTriggeredMPC(Q_PAPER, R_PAPER, sched, n_p=4, anticipate=a).setup(nrho_ref,
                                                                                      "ball")
           for a in (False, True)}
    assert ctl[True].predicted_gauge(k, x) == pytest.approx(1.5, rel=1e-9)
    assert g_true == pytest.approx(1.5, rel=2e-2)
    u_plain, u_ant = ctl[False].control(k, x), ctl[True].control(k, x)
    assert not ctl[False].active[-1] and np.all(u_plain == 0)
    assert ctl[True].active[-1] and np.linalg.norm(u_ant) > 0
    assert ctl[True].gauges[-1] == ctl[False].gauges[-1]  # the logged gauge is the tube's
    with pytest.raises(ProblemError, match="anticipate"):
        EventTriggeredMPC(Q_PAPER, R_PAPER, sched, anticipate="yes")
    # refreshes every 24 steps (not a divisor of the period): the same phase, another distance to
    # the next refresh, so another transition matrix
    every24 = drift_schedule(nrho, nrho_ref, source="linear", interval=24, lookahead=0)
    ant = EventTriggeredMPC(Q_PAPER, R_PAPER, every24, n_p=4, anticipate=True)
    M = nrho_ref.n_steps
    for kk in (10, 10 + M):
        rr = every24.next_refresh(every24.refresh_step(kk))
        P = np.eye(6)
        for i in range(kk, rr):
            P = nrho_ref.A[i % M] @ P
        xx = nrho_ref.state(kk) + 1e-6
        want = every24.gauge(rr, nrho_ref.state(rr) + P @ (xx - nrho_ref.state(kk)))
        assert ant.predicted_gauge(kk, xx) == pytest.approx(want, rel=1e-12)
    steps_to_go = [every24.next_refresh(every24.refresh_step(kk)) - kk for kk in (10, 10 + M)]
    assert steps_to_go[0] != steps_to_go[1]


# ----------------------------------------------------------------------------- Delta-V
def test_delta_v_in_si_from_thrust_mass_and_time_unit(halo):
    """Paper: T_max = 0.1 N, m0 = 1000 kg -> 1e-4 m/s^2; t* = 375200 s.  Full thrust for 10 steps
    of 1 h is 3.6 m/s; half thrust 1.8 m/s."""
    prob = halo  # same spacecraft as nrho-9-2 (0.1 N, 1000 kg, Patel units)
    a = prob.param("a_max")
    assert a * prob.units.acceleration == pytest.approx(0.1 / 1000.0, rel=1e-12)
    dt = 3600.0 / 375200.0
    U = np.tile([0.6, 0.0, 0.8], (10, 1))
    assert delta_v_si(U, a, dt, prob.units).sum() == pytest.approx(10 * 3600 * 1e-4, rel=1e-12)
    assert delta_v_si(0.5 * U, a, dt, prob.units).sum() == pytest.approx(1.8, rel=1e-12)


# ----------------------------------------------------------------------------- closed loop
def test_event_triggered_mpc_keeps_the_state_in_the_tube_or_reports_each_excursion(halo, halo_ref):
    """Short closed loop on the L2 halo from an offset outside the initial set (2x the paper's
    box): the trigger fires at step 0, the soft tube-constrained MPC brings the state into the
    shrunk tube, the thrust goes off; every step with gauge > 1 while thrust is off is reported,
    and the metrics' activations match the trigger's."""
    sched = drift_schedule(halo, halo_ref, membership="box", phase=0, lookahead=10)
    ctl = EventTriggeredMPC(Q_PAPER, R_PAPER, sched, trigger=EventTrigger(0.7, 2), n_p=10,
                            max_cpu_time=5.0).setup(halo_ref, "ball")
    off = 2.0 * np.r_[1e-4, -1e-4, 1e-4, -5e-4, 5e-4, 5e-4]
    opt = ocreach.control.SimOptions(n_steps=40, x0_offset=off, disturbance=1e-7, seed=1,
                                     n_sub=halo_ref.n_sub, progress=False)
    res = ocreach.control.simulate(halo_ref, ctl, control_set_kind="ball",
                                   velocity_dims=halo.velocity_dims, options=opt)
    met, gam = station_keeping_metrics(res, halo_ref, sched, halo, ctl)
    on = np.asarray(ctl.active)
    assert on[0] and gam[0] > 1
    assert met["activations"] == ctl.trigger.activations >= 1
    assert not on[-1]  # released
    # the controller's gauges are those of the true state (no navigation error)
    assert np.allclose(ctl.gauges, gam[:-1], rtol=1e-6)
    # excursions with thrust off are exactly the reported ones
    off_steps = np.flatnonzero(~np.r_[on, False] & (gam > 1))
    assert met["excursion_steps"] == off_steps.tolist()
    assert met["excursions_off"] == off_steps.size
    # released only after m = 2 steps with gauge <= beta
    rel = np.flatnonzero(on[:-1] & ~on[1:])[0] + 1
    assert np.all(gam[rel - 1: rel + 1] <= 0.7) and gam[rel - 2] > 0.7
    # thrust only while on; applied thrust within the ball
    assert np.all(np.linalg.norm(res.U_applied[~on], axis=1) == 0)
    assert np.all(np.linalg.norm(res.U_applied, axis=1) <= 1 + 1e-9)
    assert met["delta_v_mps"] > 0 and met["solver_failures"] == 0


def test_station_keeping_bad_inputs(halo):
    with pytest.raises(ProblemError, match="controllers"):
        run_station_keeping(halo, controllers=("pid",), revolutions=0.1)
    with pytest.raises(ProblemError, match="revolutions"):
        run_station_keeping(halo, controllers=("lqr",), revolutions=-1)
    with pytest.raises(ProblemError, match="beta"):
        run_station_keeping(halo, controllers=("event-mpc",), revolutions=0.05, beta=1.2)
    with pytest.raises(ProblemError, match="periodic reference"):
        run_station_keeping(ocreach.get_problem("earth-mars"), controllers=("lqr",))
    with pytest.raises(ProblemError, match="anticipate"):
        run_station_keeping(halo, controllers=("lqr",), revolutions=0.05, anticipate="no")
    with pytest.raises(ProblemError, match="tube_slack"):
        MPC(Q_PAPER, R_PAPER, tube=6, tube_slack=-1.0)
    with pytest.raises(ProblemError, match="tube_slack needs"):
        MPC(Q_PAPER, R_PAPER, tube_slack=1.0)


def test_station_keeping_report_writes_files_with_metrics_per_controller(tmp_path):
    """``ocreach report station-keeping`` on a short l2-halo run: files written, one metrics entry
    per controller with the required keys, text computed from the run."""
    from ocreach.cli import main

    rc = main(["report", "station-keeping", "--problem", "l2-halo", "--controllers",
               "event-mpc,tube-mpc,lqr", "--revolutions", "0.06", "--out", str(tmp_path),
               "--set", "n_p=6", "--set", "progress=False"])
    assert rc == 0
    data = json.loads((tmp_path / "metrics.json").read_text())
    keys = ("revolutions", "delta_v_mps", "delta_v_per_rev_mps", "activations", "duty_cycle",
            "max_gauge_off", "max_deviation_km", "time_per_step_ms", "solver_failures")
    for name in ("event-mpc", "tube-mpc", "lqr"):
        assert all(k in data[name] for k in keys), name
    assert "mpc" not in data
    assert data["settings"]["tube_guaranteed"] is False
    md = (tmp_path / "report.md").read_text()
    assert "NOT a guaranteed enclosure" in md
    assert f"{data['lqr']['delta_v_mps']:.4g} m/s" in md
    for f in ("report.html", "trajectory.png", "projections.png", "gauge.png", "thrust.png",
              "delta_v.png"):
        assert (tmp_path / f).stat().st_size > 0
    # lqr is on every step: duty cycle 1, one activation
    assert data["lqr"]["duty_cycle"] == 1.0 and data["lqr"]["activations"] == 1
    # the tube MPC's terminal set is reported
    assert data["tube-mpc"]["terminal_set"]["robustly_invariant"] is True
    assert "robustly invariant" in md


def test_defect_correction_makes_the_prediction_exact_on_the_reference(halo_ref):
    """With one RK4 substep the prediction from x_ref is off the reference (the MPC thrusts to
    fight its model error); with the defect correction it is exact there: zero thrust, plan on
    the reference."""
    x = halo_ref.state(3)
    plain = MPC(Q_PAPER, R_PAPER, n_p=6, n_c=6, prediction_substeps=1).setup(halo_ref, "ball")
    corr = MPC(Q_PAPER, R_PAPER, n_p=6, n_c=6, prediction_substeps=1,
               defect_correction=True).setup(halo_ref, "ball")
    u_plain, u_corr = plain.control(3, x), corr.control(3, x)
    assert corr.fallbacks == plain.fallbacks == 0
    assert np.linalg.norm(u_corr) <= 1e-9
    assert np.abs(corr._X_abs - halo_ref.state(np.arange(4, 10))).max() <= 1e-12
    assert np.linalg.norm(u_plain) > 1e3 * max(np.linalg.norm(u_corr), 1e-12)


def test_navigation_error_is_seeded_bounded_and_only_seen_by_the_controller(halo_ref):
    from ocreach.control.stationkeeping.runs import NavigationError

    class Recorder:
        name = "rec"

        def setup(self, ref, kind):
            self.seen = []
            return self

        def reset(self):
            self.seen = []

        def control(self, k, x):
            self.seen.append(np.array(x))
            return np.zeros(3)

    sigma = np.r_[1e-6] * np.ones(6)
    runs = []
    for _ in range(2):
        rec = Recorder()
        nav = NavigationError(rec, sigma, seed=4).setup(halo_ref, "ball")
        nav.reset()
        x = halo_ref.state(0)
        for k in range(20):
            nav.control(k, x)
        runs.append(np.array(rec.seen) - x)
    assert np.array_equal(runs[0], runs[1])               # seeded
    assert np.all(np.abs(runs[0]) <= sigma) and np.abs(runs[0]).max() > 0.5e-6
    with pytest.raises(ProblemError, match="navigation"):
        NavigationError(Recorder(), -1.0)


def test_tube_log_says_per_refresh_which_tube_was_used(halo, halo_ref, monkeypatch):
    """``taylor-or-linear``: the real sound tube where taylor succeeds (first 30-step interval of
    the L2 halo), the linear tube where it fails (forced for the second interval, as taylor fails
    at the NRHO's perilune); the log and the report sentences name each, with the reason."""
    import ocreach.control.stationkeeping.drift_tubes as sk
    from ocreach.control.stationkeeping.paper import PAPER_W, paper_initial_set
    from ocreach.control.stationkeeping.report import tube_lines
    from ocreach.errors import SolverError

    real = sk.reach_drift_tube
    sched = drift_schedule(halo, halo_ref, source="taylor-or-linear", interval=30, lookahead=2,
                           membership="zonotope")
    first = sched.phase

    def flaky(problem, reference, k0, *a, **kw):
        if k0 != first:
            raise SolverError("taylor: interval Hessian unbounded at step 12 (test)")
        return real(problem, reference, k0, *a, **kw)

    monkeypatch.setattr(sk, "reach_drift_tube", flaky)
    log = sk.tube_log(sched, first + 60)
    assert [e["refresh_step"] for e in log][-2:] == [first, first + 30]
    a, b = log[-2], log[-1]
    assert a["guaranteed"] and a["source"].startswith("taylor") and a["fallback_reason"] is None
    assert not b["guaranteed"] and b["source"].startswith("linear")
    assert "step 12" in b["fallback_reason"]
    # the stand-in is exactly the linear tube of that interval
    lin = linear_drift_tube(halo_ref, first + 30, 33, paper_initial_set(halo), PAPER_W,
                            halo.velocity_dims)
    tb = sched.tube(first + 30)
    assert np.array_equal(tb.centers, lin.centers) and np.array_equal(tb.generators, lin.generators)
    text = tube_lines(log[-2:])
    assert "GUARANTEED" in text[0] and "LINEARISED" in text[1] and "step 12" in text[1]
    with pytest.raises(ProblemError, match="tube source must be one of"):
        drift_schedule(halo, halo_ref, source="taylor-or-guess")


def test_partition_key_tells_apart_large_arrays_that_differ_only_in_the_middle(halo, halo_ref):
    """The adaptive-partition cache key hashes arrays by dtype, shape and bytes: numpy's ``repr``
    elides the middle of a large array, so a key built from ``repr`` gave two different
    disturbances (or array options) the same key and the cache the wrong tubes."""
    from ocreach.control.stationkeeping.drift_tubes import partition_key
    from ocreach.control.stationkeeping.paper import paper_initial_set

    a = np.full(2000, 1e-7)
    b = a.copy()
    b[1000] = 2e-7
    assert repr(a) == repr(b)  # what the old key saw

    def key(W, options):
        return partition_key(halo, halo_ref, 0, paper_initial_set(halo), W, "taylor", options)

    assert key(a, {}) != key(b, {})
    assert key(1e-7, {"weights": a}) != key(1e-7, {"weights": b})
    assert key(a, {}) != key(a.reshape(1000, 2), {})  # same bytes, another shape
    assert key(a, {"substeps": 16}) == key(a.copy(), {"substeps": 16})  # same values, same key
    # the partition runs on the reference's model (e.g. a plant's frame model), so it is in the key
    import dataclasses

    other = dataclasses.replace(halo_ref, model=dataclasses.replace(halo_ref.model, name="other"))
    assert partition_key(halo, other, 0, paper_initial_set(halo), a, "taylor", {}) != key(a, {})


def test_tube_mpc_terminal_set_gives_recursive_feasibility_in_closed_loop(halo, halo_ref):
    """Robust tube MPC with hard tightened constraints and the LQR terminal set on the L2 halo
    (offset in 0.8x the paper's box, N = 6, W = 1e-7 per step): the terminal set is robustly invariant
    (setup check), every solve succeeds and meets its constraints, and -- the recursive-feasibility
    argument checked independently of IPOPT -- at every next step the shifted plan with the LQR
    law appended, rolled out by the prediction model from the new measured state, satisfies the
    tightened box, thrust and terminal constraints of the new problem."""
    from ocreach.control.lqr import LQR
    from ocreach.control.simulate import SimOptions, simulate
    from ocreach.control.stationkeeping.paper import PAPER_W, paper_initial_set
    from ocreach.control.stationkeeping.tube_mpc import TubeMPC

    N = 6  # short enough that the terminal set binds from this offset (asserted below)
    sched = drift_schedule(halo, halo_ref, lookahead=N)
    lqr = LQR(Q_PAPER, R_PAPER).setup(halo_ref, "ball")
    tm = TubeMPC(Q_PAPER, R_PAPER, sched, disturbance=PAPER_W, velocity_dims=halo.velocity_dims,
                 n_p=N, tube_slack=None, fallback=lqr).setup(halo_ref, "ball")
    assert tm.terminal_robust and tm.terminal_contraction < 1
    assert tm.terminal_disturbance < (1 - tm.terminal_contraction) * np.sqrt(tm.terminal_alpha)

    class Check:
        """Wraps the tube MPC: after each solve, checks the plan and the candidate of the
        previous solve at the current state."""

        name = "tube-mpc"

        def __init__(self):
            self.cand_worst = -np.inf
            self.plan_worst = -np.inf
            self.prev = None

        def setup(self, ref, kind):
            return self

        def reset(self):
            tm.reset()
            self.prev = None

        def violation(self, k, x0, U):
            F = halo_ref.discretization.F
            c, _, hw, r = tm._tightened_sets(k)
            X, xi = [], x0
            for i in range(N):
                xi = np.asarray(F(xi, U[i], halo_ref.time(k + i), halo_ref.params)).ravel()
                X.append(xi)
            X = np.array(X)
            box = np.max((np.abs(X - c) - hw) / hw)  # <= 0 inside
            thr = np.max(np.linalg.norm(U, axis=1) / r) - 1.0
            d = X[-1] - halo_ref.state(k + N)
            term = float(d @ tm.terminal_matrix(k) @ d) - 1.0
            self.term_max = max(getattr(self, "term_max", -1.0), term)
            return max(box, thr, term)

        def control(self, k, x):
            if self.prev is not None:  # the candidate built from the previous solve
                plan, d_end = self.prev
                u_app = -lqr.K[halo_ref.gains_index(k - 1 + N)] @ d_end
                cand = np.vstack([plan[1:], u_app])
                self.cand_worst = max(self.cand_worst, self.violation(k, x, cand))
            u = tm.control(k, x)
            assert tm.fallbacks == 0, tm.events
            plan = tm.mpc.plan.copy()
            self.plan_worst = max(self.plan_worst, self.violation(k, x, plan))
            self.prev = (plan, tm.mpc._X_abs[-1] - halo_ref.state(k + N))
            return u

    chk = Check()
    opt = SimOptions(n_steps=40, offset_box=0.8 * paper_initial_set(halo), disturbance=PAPER_W,
                     seed=4, n_sub=halo_ref.n_sub, progress=False)
    simulate(halo_ref, chk, control_set_kind="ball", velocity_dims=halo.velocity_dims,
             options=opt)
    assert chk.term_max > -1e-4  # the terminal constraint is active in some solve
    assert chk.plan_worst <= 1e-6  # IPOPT's plans meet their constraints
    assert chk.cand_worst <= 1e-6, chk.cand_worst  # the candidates are feasible (measured -0.055)


def test_mpc_terminal_set_bad_input(halo_ref):
    plain = MPC(Q_PAPER, R_PAPER, n_p=3, n_c=3).setup(halo_ref, "ball")
    with pytest.raises(ProblemError, match="terminal_set=True"):
        plain.set_terminal_set(np.eye(6))
    term = MPC(Q_PAPER, R_PAPER, n_p=3, n_c=3, terminal_set=True).setup(halo_ref, "ball")
    with pytest.raises(ProblemError, match="needs set_terminal_set"):
        term.control(0, halo_ref.state(0))
    with pytest.raises(ProblemError, match="finite 6x6"):
        term.set_terminal_set(np.eye(5))


def test_tube_guarantee_counts_tubes_reached_only_by_the_last_predictions():
    """A tube refreshed after the run's last step but inside the last MPC horizon constrains the
    last plans, so it counts for ``tube_guaranteed`` (review finding: the log stopped at the run's
    last step and a linearised tube there went unreported)."""
    from types import SimpleNamespace

    from ocreach.control.stationkeeping.runs import run_tube_logs, tubes_enclose_plant

    class Stub:  # refreshes every 10 steps; the tube refreshed at step 30 is linearised
        reference = SimpleNamespace(revolution_steps=100)

        def refresh_steps(self, n):
            return list(range(0, n, 10))

        def next_refresh(self, r):
            return r + 10

        def tube(self, r):
            return SimpleNamespace(source="linear" if r == 30 else "taylor", guaranteed=r != 30,
                                   meta={})

    tubes, beyond = run_tube_logs(Stub(), 25, 4)  # last plan reaches step 28: no tube at 30
    assert [e["refresh_step"] for e in tubes] == [0, 10, 20] and beyond == []
    assert tubes_enclose_plant(tubes + beyond, "cr3bp", "cr3bp") is True
    tubes, beyond = run_tube_logs(Stub(), 25, 15)  # reaches step 39: the tube at 30
    assert [e["refresh_step"] for e in beyond] == [30] and not beyond[0]["guaranteed"]
    assert tubes_enclose_plant(tubes + beyond, "cr3bp", "cr3bp") is False
    assert run_tube_logs(None, 25, 15) == ([], [])


def test_tube_mpc_floor_is_a_fraction_of_the_tube_itself(halo, halo_ref):
    """An exhausted tightened half width is ``MIN_FRACTION`` of the tube's own half width,
    bit for bit (it was re-derived as ``(hw - margin) + margin``, which a large margin rounds)."""
    from ocreach.control.stationkeeping.paper import PAPER_W
    from ocreach.control.stationkeeping.tube_mpc import MIN_FRACTION, TubeMPC

    N = 4
    sched = drift_schedule(halo, halo_ref, lookahead=N)
    tm = TubeMPC(Q_PAPER, R_PAPER, sched, disturbance=PAPER_W, velocity_dims=halo.velocity_dims,
                 n_p=N, terminal_set=False).setup(halo_ref, "ball")
    tm.state_margin = tm.state_margin + 1e3  # consume every state constraint
    _, hw, r = tm.tightened(5)
    _, G = sched.window(5, N)
    np.testing.assert_array_equal(hw, MIN_FRACTION * np.abs(G).sum(axis=2))
    assert tm.tightening_exhausted == hw.size and np.all(r <= 1.0)
