"""The ARCH-COMP benchmarks, hybrid automata and specifications against independent truth.

Truth: numpy right-hand sides written in ``tests/_arch_truth.py`` (not the project's CasADi
models), integrated by SciPy's DOP853 over the batch of samples; the automata's runs are rebuilt
from the dense output (crossing times by a scan and a per-sample terminal event), not by the
project's sampler.  A state is inside a set when its scaled gauge is <= 1 + 1e-9.  Every instance
checked here is one the suite reports verified, with >= 2,000 samples; the hybrid ones on short
horizons (the full-horizon checks are ``ocreach arch``, docs/arch.md).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from _arch_truth import (
    SC_K1,
    SC_K2,
    batch,
    coupled_vanderpol,
    first_root,
    laub_loomis,
    lotka_volterra,
    spacecraft,
    states_at,
)

import ocreach
from ocreach.errors import ProblemError
from ocreach.hybrid import HybridAutomaton, HybridProblem, Transition
from ocreach.reach.taylor import TaylorZonotope
from ocreach.sets.union import gauge, union_gauge
from ocreach.sets.zonotope import Zonotope
from ocreach.specs import (
    InBall,
    OutBall,
    Safe,
    Samples,
    Unsafe,
    check,
    check_samples,
    contract,
    ge,
    le,
    surely_disjoint,
)

TOL = 1 + 1e-9
N_TRUTH = 2000


def _rand_zonotope(rng, n=2, h=4, scale=1.0):
    return Zonotope(rng.normal(size=n), rng.normal(size=(n, h)) * scale)


# ------------------------------------------------------------------------------------------ specs
def test_cut_by_a_half_space_encloses_every_point_that_satisfies_it():
    rng = np.random.default_rng(1)
    for _ in range(200):
        Z = _rand_zonotope(rng, n=3, h=5)
        a = rng.normal(size=3)
        b = float(a @ Z.c + rng.uniform(-2, 2) * np.abs(Z.G.T @ a).sum())
        X = Z.sample(400, rng)
        keep = X @ a <= b
        C = contract(Z, a, b)
        if C is None:
            assert not keep.any()
            continue
        if keep.any():
            assert np.asarray(gauge(C, X[keep])).max() <= TOL


def test_ball_tests_and_cuts_are_sound():
    rng = np.random.default_rng(2)
    names = ("x", "y")
    for _ in range(150):
        Z = _rand_zonotope(rng, h=3, scale=0.3)
        c = rng.normal(size=2)
        r = rng.uniform(0.2, 2.0)
        X = Z.sample(600, rng)
        inside = np.linalg.norm(X - c, axis=1) <= r
        ib = InBall(names, tuple(c), r)
        ob = OutBall(names, tuple(c), r)
        if ib.surely_holds(Z, names):
            assert inside.all()
        if ib.surely_fails(Z, names):
            assert not inside.any()
        if ob.surely_holds(Z, names):
            assert not (np.linalg.norm(X - c, axis=1) < r - 1e-12).any()
        for con, mask in ((ib, inside), (ob, ~inside)):
            C = con.cut(Z, names)
            if C is None:
                assert not mask.any()
            elif mask.any():
                assert np.asarray(gauge(C, X[mask])).max() <= TOL


def test_disjointness_from_a_box_is_sound():
    rng = np.random.default_rng(3)
    names = ("x", "y")
    region = (ge("x", -0.5), le("x", 0.5), ge("y", -0.5), le("y", 0.5))
    for _ in range(150):
        Z = _rand_zonotope(rng, h=3, scale=0.5)
        X = Z.sample(600, rng)
        hit = (np.abs(X) <= 0.5).all(axis=1)
        if surely_disjoint(Z, region, names):
            assert not hit.any()


def test_statuses_windows_and_counter_examples():
    p = ocreach.get_problem("arch-lalo20-w001", t_final=2.0)
    names = p.model.state_names
    r = ocreach.reach(p, "taylor")
    assert check(Unsafe(ge("x4", 4.5)), r, names).status == "verified"
    # x4 starts near 2.4 and dips to ~1.75: never >= 1 is wrong everywhere -> proven violated
    assert check(Unsafe(ge("x4", 1.0)), r, names).status == "violated"
    # x4 <= 2.2 fails at t = 0 and t = 2 but holds on [0.2, 1.6]: the window decides
    assert check(Safe((le("x4", 2.2),)), r, names).status != "verified"
    assert check(Safe((le("x4", 2.2),), window=(0.2, 1.6)), r, names).status == "verified"
    # x4 >= 2.39 at t = 0: the time-point set lies wholly inside the unsafe set -> violated
    assert check(Unsafe(ge("x4", 2.3), window=(0.0, 0.0)), r, names).status == "violated"
    with pytest.raises(ProblemError, match="not a state"):
        check(Unsafe(ge("t", 1.0)), r, names)
    smp = Samples(p.grid, np.tile(np.linspace(1.0, 3.0, p.grid.size)[None, :, None], (5, 1, 7)), names)
    res = check_samples(Unsafe(ge("x4", 2.5)), smp)
    assert res.status == "violated" and res.counterexample["state"][3] >= 2.5
    assert res.counterexample["states"].shape == (p.grid.size, 7)
    assert check_samples(Unsafe(ge("x4", 9.0)), smp).status == "unknown"


# ------------------------------------------------------------------------------------------ automata
def _lv_loc(name):
    return ocreach.get_problem("arch-lovo21").automaton.location(name)


def test_automaton_definitions_are_checked():
    out, ins = _lv_loc("outside"), _lv_loc("inside")
    with pytest.raises(ProblemError, match="unknown location"):
        HybridAutomaton("a", (out,), (Transition("outside", "nowhere", (le("x", 1.0),)),))
    with pytest.raises(ProblemError, match="refers to"):
        HybridAutomaton("a", (out, ins), (Transition("outside", "inside", (le("speed", 1.0),)),))
    with pytest.raises(ProblemError, match="unique"):
        HybridAutomaton("a", (out, out))
    aut = HybridAutomaton("a", (out, ins))
    with pytest.raises(ProblemError, match="initial location"):
        HybridProblem(id="h", model=ins.model, x0=np.ones(3), grid=np.linspace(0, 1, 3),
                      automaton=aut, initial_location="outside")
    p = ocreach.get_problem("arch-lovo21", t_final=0.1)
    with pytest.raises(ProblemError, match="hybrid automaton"):
        TaylorZonotope().solve(p)
    with pytest.raises(ProblemError, match="does not follow hybrid"):
        ocreach.reach(p, "stt")


# ------------------------------------------------------------------------------------------ truth
def _initial(problem, rng, n):
    S = problem.initial_set
    lo, hi = np.asarray(S.lo), np.asarray(S.hi)
    nv = n // 4
    V = lo + (hi - lo) * rng.integers(0, 2, size=(nv, lo.size))
    U = lo + (hi - lo) * rng.uniform(size=(n - nv, lo.size))
    return np.vstack([V, U])


def test_lalo20_w001_is_verified_and_contains_independent_truth():
    p = ocreach.get_problem("arch-lalo20-w001")
    r = ocreach.reach(p, "taylor")
    ver = p.extra["verification"]
    assert [check(s, r, p.model.state_names).status for s in ver.specs] == ["verified"]
    X0 = _initial(p, np.random.default_rng(4), N_TRUTH)
    ks = np.unique(np.r_[np.arange(0, p.grid.size, 20), p.grid.size - 1])
    Xs = states_at(laub_loomis, X0, p.grid[ks])
    for k, X in zip(ks, Xs):
        assert np.asarray(union_gauge(r.sets[k], X)).max() <= TOL, f"escape at t = {p.grid[k]}"
        assert X[:, 3].max() < 4.5
    width = ver.measures[0].of_sets([r.sets[-1]], p.model.state_names)
    assert width >= np.ptp(Xs[-1][:, 3])


def test_a_run_that_stops_early_is_checked_against_the_truth_as_far_as_it_got():
    """CVDP20 mu = 2 with taylor stops near t = 3 (the remainder is no longer finite with every
    part in use): the row says unknown with the reason, the sets computed up to there hold the
    suite's 2,000 samples and 2,000 independent ones (numpy right-hand side, SciPy DOP853)."""
    from ocreach.arch.report import csv_text, markdown
    from ocreach.arch.suite import run_instance

    run, p, res = run_instance("arch-cvdp20-mu2", method="taylor", samples=N_TRUTH,
                               truth_stride=30, warmup=False)
    assert run.result == "unknown" and "cannot be enclosed" in run.error and run.stopped
    assert res.meta["truncated"] and 1.0 < run.computed_to < p.grid[-1]
    K = len(res.sets)
    assert run.computed_to == pytest.approx(p.grid[K - 1])
    tr = run.truth
    assert tr["escapes"] == 0 and tr["checked_to"] == run.computed_to
    ks = set(range(0, K, 30)) | {K - 1}  # the time-point sets there, the tubes after them
    assert tr["points_checked"] == N_TRUTH * (len(ks) + len(ks - {K - 1}))
    X0 = _initial(p, np.random.default_rng(9), N_TRUTH)
    ks = np.unique(np.r_[np.arange(0, K, 50), K - 1])
    Xs = states_at(coupled_vanderpol(2.0), X0, p.grid[ks])
    for k, X in zip(ks, Xs):
        assert np.asarray(union_gauge(res.sets[k], X)).max() <= TOL, f"escape at t = {p.grid[k]}"
    row = csv_text([run]).splitlines()[1].split(",")
    assert row[2] == "" and row[6:8] == ["taylor", f"{run.computed_to:.6g}"] and row[8] == "0"
    details = markdown([run], "test machine", N_TRUTH, "today")
    assert "specs not checked (the run stopped)" in details and "specs  s" not in details


@pytest.mark.parametrize("method", ["taylor", "poly"])
def test_initial_parts_cover_the_initial_set_and_the_truth(method):
    p = ocreach.get_problem("arch-lalo20-w01", t_final=1.0)
    r = ocreach.reach(p, method, initial_parts=4)
    assert len(r.sets[0].parts) == 4
    X0 = _initial(p, np.random.default_rng(10), N_TRUTH)
    ks = np.array([0, 5, p.grid.size - 1])
    Xs = states_at(laub_loomis, X0, p.grid[ks])
    for k, X in zip(ks, Xs):  # poly: the zonotope enclosures of its polynomial zonotopes
        assert _in_sets([q.to_zonotope() for q in r.sets[k].parts], X).all(), \
            f"escape at t = {p.grid[k]}"
    for bad, msg in (({"initial_parts": 0}, "initial_parts must be an integer >= 1"),
                     ({"initial_parts": 5, "max_parts": 4}, "initial_parts must be <= max_parts")):
        with pytest.raises(ProblemError, match=msg):
            ocreach.reach(p, method, **bad)


def test_a_hybrid_flowpipe_that_stops_early_holds_the_runs_up_to_where_it_got():
    """Steps of 0.4 inside the Lotka-Volterra circle with no halving: a later branch cannot be
    enclosed; the partial flowpipe says up to when it holds every run, and 2,000 runs through
    the automaton are inside it up to then."""
    from ocreach.arch.truth import hybrid_truth
    from ocreach.errors import SolverError

    p = ocreach.get_problem("arch-lovo21", t_final=1.2)
    with pytest.raises(SolverError, match="cannot be enclosed") as info:
        ocreach.reach(p, "taylor", max_halvings=0, hybrid={"dt": {"inside": 0.4}})
    part = info.value.partial
    until = part.meta["valid_until"]
    assert part.meta["truncated"] and "cannot be enclosed" in part.meta["failure"]
    assert 0.3 < until < 1.2
    tr = hybrid_truth(p, part, samples=N_TRUTH, stride=4)
    assert tr.escapes == 0 and tr.checked_to == until and tr.points > N_TRUTH


def _least_norm_inside(Z, P: np.ndarray) -> np.ndarray:
    """Rows of ``P`` proved inside ``Z``: the least-norm factors ``xi`` of ``G xi = x - c`` with
    ``|xi| <= 1`` and a residual at rounding level (a sufficient test, no LP)."""
    G = np.asarray(Z.G)
    R = P - Z.c
    xi = np.linalg.lstsq(G, R.T, rcond=None)[0]
    res = np.abs(G @ xi - R.T).max(axis=0)
    scale = 1e-9 * (1 + np.abs(G).sum(axis=1).max())
    return (np.abs(xi).max(axis=0) <= 1.0 - 1e-9) & (res <= scale)


def _in_pieces(res, loc: str, X: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per row, True if ``(x, t)`` lies in some piece of location ``loc`` covering time ``t``:
    first the least-norm factor test on every candidate piece (narrowest time range first), then
    the membership certificate with its LP, then the exact LP gauge (<= TOL) for the rows still
    open."""
    P = np.column_stack([X, t])
    ok = np.zeros(P.shape[0], dtype=bool)
    pcs = sorted((pc for pc in res.pieces if pc.location == loc and pc.t_hi >= t.min() - 1e-9
                  and pc.t_lo <= t.max() + 1e-9), key=lambda pc: pc.t_hi - pc.t_lo)
    boxes = [pc.set.interval_hull() for pc in pcs]

    order = np.argsort(t, kind="stable")
    ts = t[order]

    def candidates(pc, I):  # rows in the piece's time range and box (outside the box: not in it)
        a = np.searchsorted(ts, pc.t_lo - 1e-9, side="left")
        b = np.searchsorted(ts, pc.t_hi + 1e-9, side="right")
        idx = order[a:b]
        idx = idx[~ok[idx]]
        Q = P[idx]
        inb = np.all((Q >= I.lo - 1e-9 * (1 + np.abs(I.lo))) & (Q <= I.hi + 1e-9 * (1 + np.abs(I.hi))),
                     axis=1)
        return idx[inb]

    for test in (_least_norm_inside,
                 lambda Z, Q: np.atleast_1d(gauge(Z, Q, lp=False)) <= 1.0):
        for pc, I in zip(pcs, boxes):
            idx = candidates(pc, I)
            if idx.size:
                ok[idx[test(pc.set, P[idx])]] = True
    # the exact LP gauge of the rows still open, batched per piece (a row within TOL of a
    # piece lies in its box widened as in candidates)
    for pc, I in zip(pcs, boxes):
        idx = candidates(pc, I)
        if idx.size:
            ok[idx[np.atleast_1d(union_gauge(pc.set, P[idx], exact=True)) <= TOL]] = True
    return ok


def _in_sets(sets, P: np.ndarray) -> np.ndarray:
    """Per row of ``P``, True if it lies in one of ``sets`` (certificates, then exact LPs)."""
    ok = np.zeros(P.shape[0], dtype=bool)
    for Z in sets:
        idx = np.flatnonzero(~ok)
        if idx.size:
            ok[idx[np.atleast_1d(gauge(Z, P[idx], lp=False)) <= 1.0]] = True
    for Z in sets:  # the exact LP gauges of the rows still open, batched per set
        idx = np.flatnonzero(~ok)
        if idx.size:
            ok[idx[np.atleast_1d(union_gauge(Z, P[idx], exact=True)) <= TOL]] = True
    return ok


def test_lotka_volterra_hybrid_contains_independent_truth():
    T = 1.2  # the first (tangential) passage: enter, time inside, exit
    p = ocreach.get_problem("arch-lovo21", t_final=T)
    res = ocreach.reach(p, "taylor")
    assert res.meta["guaranteed"] and not res.meta["truncated"]
    X0 = _initial(p, np.random.default_rng(5), N_TRUTH)[:, :2]
    at = batch(lotka_volterra, X0, T)
    r2 = 0.161**2

    def g_in(X):
        return (X[:, 0] - 1) ** 2 + (X[:, 1] - 1) ** 2 - r2

    t_in, x_in = first_root(at, lotka_volterra, g_in, T, 600)
    ent = np.flatnonzero(np.isfinite(t_in))
    assert 0 < ent.size < N_TRUTH  # near tangency: some runs enter the circle, some do not
    # the exit: the first root of -g after the entry, from the entry state
    at_in = batch(lotka_volterra, x_in[ent], T)
    dt_out, x_out = first_root(at_in, lotka_volterra, lambda X: -g_in(X), T, 600)
    assert np.isfinite(dt_out).all()
    t_out = np.full(N_TRUTH, np.inf)
    t_out[ent] = t_in[ent] + dt_out
    per_loc = {"inside": ([], []), "outside": ([], [])}
    for t in p.grid[::6]:
        X = at(float(t))
        inside = (t >= t_in) & (t < t_out)
        cnt = np.clip(np.minimum(t, t_out) - t_in, 0, None)
        S = np.column_stack([X, cnt])
        for loc, m in (("inside", inside), ("outside", ~inside)):
            per_loc[loc][0].append(S[m])
            per_loc[loc][1].append(np.full(m.sum(), float(t)))
    for loc, (Ss, ts) in per_loc.items():  # every state of a location in one call
        S, tt = np.vstack(Ss), np.concatenate(ts)
        if tt.size:
            ok = _in_pieces(res, loc, S, tt)
            assert ok.all(), f"{(~ok).sum()} escapes in {loc}, first at t = {tt[~ok].min():.3g}"
    # the jump states: on the circle, before (source) and after (target) the jump
    en = np.column_stack([x_in[ent], np.zeros(ent.size)])
    assert _in_pieces(res, "inside", en, t_in[ent]).all()
    assert _in_pieces(res, "outside", en, t_in[ent]).all()
    ex = np.column_stack([x_out, dt_out])
    assert _in_pieces(res, "outside", ex, t_out[ent]).all()
    assert _in_pieces(res, "inside", ex, t_out[ent]).all()
    # final sets at T hold the runs at T, in the location they end in (outside, cnt = time inside)
    cnt_T = np.where(np.isfinite(t_in), np.minimum(t_out, T) - t_in, 0.0)
    fin = np.column_stack([at(T), cnt_T, np.full(N_TRUTH, T)])
    assert _in_sets([Z for loc, Z, _ in res.finals if loc == "outside"], fin).all()
    assert {(), ("enter", "exit")} <= set(res.final_paths())


def test_spacecraft_hybrid_is_verified_and_contains_independent_truth():
    kw = dict(t_final=40.0, x_lo=-135.0, x_hi=-125.0, y_lo=-45.0, y_hi=-35.0, abort_lo=15.0,
              abort_hi=20.0)
    p = ocreach.get_problem("arch-spre22", **kw)
    res = ocreach.reach(p, "taylor")
    ver = p.extra["verification"]
    assert [check(s, res).status for s in ver.specs] == ["verified"] * 3
    rng = np.random.default_rng(6)
    N = N_TRUTH
    X0 = _initial(p, rng, N)
    # abort times: uniform in the window, a fifth at each end
    u = rng.uniform(size=N)
    t_ab = np.where(u < 0.2, 15.0, np.where(u < 0.4, 20.0, rng.uniform(15.0, 20.0, N)))
    appr = batch(spacecraft(SC_K1), X0, 20.0)
    t_c, x_c = first_root(appr, spacecraft(SC_K1), lambda X: -X[:, 0] - 100.0, 20.0, 400)
    attempts = t_c < t_ab
    # the abort state: from the attempt after the crossing, or from the approach
    x_ab = np.empty_like(X0)
    for s in np.flatnonzero(~attempts):
        x_ab[s] = appr(t_ab[s])[s]
    ia = np.flatnonzero(attempts)
    att = batch(spacecraft(SC_K2), x_c[ia], 20.0)
    dur = t_ab[ia] - t_c[ia]
    for j, s in enumerate(ia):
        x_ab[s] = att(dur[j])[j]
    abo = batch(spacecraft(None), x_ab, 40.0 - 15.0)
    checks = {"approaching": [], "attempt": [], "aborting": []}
    for tl in np.linspace(0.0, 20.0, 41):  # approach: global time = local time
        m = tl < np.minimum(t_c, t_ab)
        checks["approaching"].append((appr(tl)[m], np.full(m.sum(), tl)))
    for sl in np.linspace(0.0, 5.0 + 1e-9, 21):  # attempt, local time after the crossing
        m = sl <= dur
        checks["attempt"].append((att(sl)[m], t_c[ia][m] + sl))
    for sl in np.linspace(0.0, 25.0, 51):  # aborting, local time after the abort
        m = t_ab + sl <= 40.0
        checks["aborting"].append((abo(sl)[m], t_ab[m] + sl))
    for loc, lst in checks.items():  # all states of a location in one call (one test per piece)
        X = np.vstack([X for X, _ in lst])
        t = np.concatenate([t for _, t in lst])
        ok = _in_pieces(res, loc, X, t)
        assert ok.all(), f"{(~ok).sum()} escapes in {loc}, first near t = {t[~ok].min():.3g}"
        if loc == "attempt":
            assert (np.hypot(X[:, 2], X[:, 3]) <= 3.3).all()
            assert (np.abs(X[:, 1]) <= -X[:, 0] * math.tan(math.radians(20))).all()
        if loc == "aborting":
            assert not ((np.abs(X[:, 0]) <= 2) & (np.abs(X[:, 1]) <= 2)).any()
    # the crossing states are in the attempt's initial sets
    assert _in_pieces(res, "attempt", x_c[ia], t_c[ia]).all()
    assert {("attempt", "abort"), ("abort",)} <= set(res.final_paths())


def test_hybrid_sampler_follows_the_automaton_like_the_independent_truth():
    p = ocreach.get_problem("arch-lovo21")
    X0 = _initial(p, np.random.default_rng(7), 200)
    hs = ocreach.reach(p, "mc", samples=200, seed=7)
    assert hs.meta["blocked"] == 0
    from ocreach.reach.hybrid import simulate_hybrid

    sim = simulate_hybrid(p, x0=X0)
    at = batch(lotka_volterra, X0[:, :2], p.t_final)
    assert np.abs(sim.final[:, :2] - at(p.t_final)).max() < 1e-7
    r2 = 0.161**2
    ts = np.linspace(0, p.t_final, 3641)
    inside = np.array([((at(t)[:, 0] - 1) ** 2 + (at(t)[:, 1] - 1) ** 2) <= r2 for t in ts])
    crossings = (np.diff(inside.astype(int), axis=0) != 0).sum(axis=0)
    assert [len(q) for q in sim.paths] == crossings.tolist()
    cnt = inside[:-1].sum(axis=0) * (ts[1] - ts[0])
    assert np.abs(sim.final[:, 2] - cnt).max() < 2e-3


# ------------------------------------------------------------------------------------------ command
def test_arch_command_writes_the_suite_files(tmp_path, capsys):
    from ocreach.cli import main

    out = tmp_path / "arch"
    assert main(["arch", "--only", "lalo20-w001", "--samples", "50", "--truth-stride", "20",
                 "--workers", "1", "--out", str(out)]) == 0
    csv = (out / "arch.csv").read_text().splitlines()
    assert csv[0] == ("benchmark,instance,result,time,accuracy,timesteps,method,computed_to,"
                      "truth_escapes,truth_points")
    row = csv[1].split(",")
    # the suite's method; computed to T = 20; 50 samples at 21 grid times in the sets there and
    # at the middle of the 20 steps after them in the tubes, none outside
    assert row[:3] == ["LALO20", "W001", "1"]
    assert row[6:] == ["poly", "20", "0", str(50 * (21 + 20))]
    assert "| LALO20 | W001 | poly | verified |" in (out / "arch.md").read_text()
    assert (out / "LALO20.png").stat().st_size > 1000
    assert "1/1 verified" in capsys.readouterr().out
    from ocreach.arch.suite import arch_ids

    with pytest.raises(ProblemError, match="matches no ARCH instance"):
        arch_ids("nosuch")
    assert arch_ids("LALO20") == ["arch-lalo20-w001", "arch-lalo20-w005", "arch-lalo20-w01"]


def test_arch_command_bad_input_exits_2_naming_the_allowed_values(tmp_path, capsys):
    from ocreach.cli import main

    out = tmp_path / "bad"
    assert main(["arch", "--only", "nosuch", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--only 'nosuch' matches no ARCH instance" in err
    assert "LALO20" in err and "lalo20-w001" in err and "spre22" in err
    assert main(["arch", "--only", "lalo20-w001", "--samples", "-1", "--out", str(out)]) == 2
    assert "--samples must be an integer >= 0; got -1" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------------------------------ harness
def test_soundness_harness_checks_hybrid_flowpipes_through_the_automaton():
    """The harness's truth through an automaton (ocreach.testing.truth.hybrid_truth) follows the
    same jumps as the independent runs here, finds no escape from the taylor flowpipe and catches
    the flowpipe shrunk by 10 %."""
    import dataclasses

    from ocreach.testing import bundled_cases
    from ocreach.testing.harness import Outcome, check_hybrid
    from ocreach.testing.truth import hybrid_truth

    p = ocreach.get_problem("arch-lovo21", t_final=1.2)
    tr = hybrid_truth(p, 40, seed=8)
    assert tr.failure == "" and tr.blocked == 0
    # every recorded (x, y) is the independent run's state at its time, from the same start
    start = tr.times == p.grid[0]  # each run's first state (the runs are recorded in order)
    at = batch(lotka_volterra, tr.points[start, :2], 1.2)
    lab = np.cumsum(start) - 1
    for k in range(0, tr.times.size, 37):
        assert np.abs(tr.points[k, :2] - at(float(tr.times[k]))[lab[k]]).max() < 1e-7
    (case,) = bundled_cases(steps=30, ids=["arch-lovo21"])
    truth = case.hybrid_truth(45, 0, (0.5,))
    for method in ("poly", "taylor"):  # poly: polynomial zonotopes cut through their enclosures
        res = ocreach.reach(case.problem, method)
        ok = Outcome(method, case.label, "bundled", "complete")
        check_hybrid(res, truth, ok)
        assert ok.points_checked == truth.points.shape[0] > 0 and ok.escapes == 0, ok.line()
    # a partial flowpipe is checked up to where every run is enclosed
    cut = dataclasses.replace(res, meta={**res.meta, "valid_until": 0.1})
    part = Outcome("taylor", case.label, "bundled", "partial")
    check_hybrid(cut, truth, part)
    assert 0 < part.points_checked == (truth.times <= 0.1 + 1e-9).sum() < truth.times.size
    shrunk = dataclasses.replace(res, pieces=[dataclasses.replace(
        pc, set=Zonotope(pc.set.c, 0.9 * pc.set.G)) for pc in res.pieces])
    bad = Outcome("taylor", case.label, "bundled", "complete")
    check_hybrid(shrunk, truth, bad)
    assert bad.escapes > 0


def test_hybrid_truth_checks_the_tubes_between_grid_times():
    """A flowpipe that holds the runs at the grid times only (a small box around the sampled
    states at each grid time, nothing between) is caught: the hybrid truth also checks every
    run at the middle of each grid step."""
    from ocreach.arch.truth import hybrid_truth
    from ocreach.reach.hybrid import HybridResult, simulate_hybrid
    from ocreach.specs import Piece

    p = ocreach.get_problem("arch-lovo21", t_final=0.1)
    hs = simulate_hybrid(p, samples=40, seed=3)
    smp = hs.samples
    G = p.grid.size
    names = (*p.automaton.state_names, "t")
    pieces = []
    for k in range(G):
        for loc in set(smp.locations[:, k]):
            X = smp.states[smp.locations[:, k] == loc, k]
            lo = np.r_[X.min(axis=0), p.grid[k]] - 1e-6
            hi = np.r_[X.max(axis=0), p.grid[k]] + 1e-6
            pieces.append(Piece(Zonotope((lo + hi) / 2, np.diag((hi - lo) / 2)), float(p.grid[k]),
                                float(p.grid[k]), names, loc))
    fake = HybridResult(names=names, pieces=pieces, finals=[], branches=[],
                        meta={"valid_until": p.t_final})
    tr = hybrid_truth(p, fake, samples=40, seed=3)
    assert tr.points == 40 * (2 * G - 1) + (smp.times.shape[1] - G) * 40
    assert tr.escapes == 40 * (G - 1)  # every midpoint state, no grid-time state
    t = tr.escape_example["time"]
    assert min(abs(t - 0.5 * (p.grid[:-1] + p.grid[1:]))) < 1e-12


def test_a_row_is_not_verified_when_cut_short_or_contradicted_by_the_truth():
    """The verdict of a row: sets that stop short of the horizon prove nothing after it, and a
    sampled state outside the guaranteed sets, or a sampled counter-example of a verified spec,
    takes the row out of ``verified`` with the reason."""
    import dataclasses

    from ocreach.arch.report import _label
    from ocreach.arch.suite import InstanceRun, _contradictions, _verdict
    from ocreach.specs import check

    p = ocreach.get_problem("arch-lalo20-w001", t_final=0.5)
    r = ocreach.reach(p, "taylor")
    specs = [check(s, r, p.model.state_names) for s in p.extra["verification"].specs]
    row = InstanceRun(p.id, "LALO20", "W001", "taylor")
    assert _verdict(p, r, specs, row) == "verified"
    short = dataclasses.replace(r, times=r.times[:-1], sets=r.sets[:-1], tubes=r.tubes[:-1])
    assert _verdict(p, short, specs, row) == "unknown"
    cut = dataclasses.replace(r, meta={**r.meta, "truncated": True})
    assert _verdict(p, cut, specs, row) == "unknown"
    for truth, why in (({"escapes": 3, "escape_example": {"time": 0.1}, "violations": {}},
                        "3 sampled state"),
                       ({"escapes": 0, "violations": {"x4": {"detail": "x4 = 4.6"}}},
                        "contradicts the verification: x4: x4 = 4.6")):
        row = InstanceRun(p.id, "LALO20", "W001", "taylor", result="verified", truth=truth)
        _contradictions(row)
        assert row.result == "unknown" and why in row.error
        assert _label(row) == "W001 (unknown)"  # not drawn as a run that stopped
    ok = InstanceRun(p.id, "LALO20", "W001", "taylor", result="verified",
                     truth={"escapes": 0, "violations": {}})
    _contradictions(ok)
    assert ok.result == "verified" and ok.error == ""
