"""The ARCH-COMP benchmarks of the category "Continuous and Hybrid Systems with Nonlinear
Dynamics" (NLN), 2020-2024, as bundled problems with their specifications as data.

Every constant is taken from the published repeatability packages and benchmark files (the
reports themselves, Geretti et al., ARCH-COMP20..24 NLN category reports, EPiC Series in
Computing 74, 80, 90, 96, 103, are not in the stored material this was written from); the source
of each is named where it is used, with the keys of :data:`SOURCES`.  Where the sources disagree,
the comment says how and which value is used.

Uncertain parameters are constant states (``b`` of CVDP23, ``a`` of PRDE20 P and I+P): their
derivative is 0 and their initial interval is part of the initial box.  The models have no
inputs; a one-dimensional control ``unused`` (box ``[-1, 1]``, no effect on ``f``) is declared
because every ocreach model has a control set.  The hybrid benchmarks (LOVO21, SPRE22) are
:class:`~ocreach.hybrid.HybridProblem` s.

Problem ids are ``arch-<benchmark>-<instance>`` (lower case); ``extra["arch"]`` holds the
ARCH-COMP benchmark and instance names and ``extra["verification"]`` the specs and measures
(:class:`ocreach.specs.Verification`).  ``ocreach arch`` runs them all (:mod:`ocreach.arch`).
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from ocreach.errors import ProblemError
from ocreach.hybrid import CLOCK, HybridAutomaton, HybridProblem, Location, Transition, time_window
from ocreach.model import Model
from ocreach.problem import Problem, time_grid
from ocreach.sets.interval import Interval
from ocreach.specs import (
    Attains,
    BoxVolume,
    Maximum,
    Safe,
    Unsafe,
    Verification,
    Width,
    box,
    ge,
    in_ball,
    le,
    linear,
    out_ball,
)

#: The stored sources every constant below comes from.
SOURCES = {
    "JR20": "JuliaReach/ARCH2020_NLN_RE (JuliaReach repeatability package, ARCH-COMP20 NLN), "
            "models/*/ (commit b895a37)",
    "JR23": "JuliaReach/ARCH2023_NLN_RE (ARCH-COMP23 NLN), models/*/ (commit 55a0d4a)",
    "JR24": "JuliaReach/ARCH2024_NLN_RE (ARCH-COMP24 NLN), models/*/ (commit 4bcb5a5)",
    "CORA": "TUMcps/CORA, examples/ARCHcompetition/nonlinear/benchmark_*_ARCH23_*.m and "
            "models/Cora/ (run by run_arch24_nln_category.m; commit 6cb7942)",
    "ARIADNE": "ariadne-cps/ariadne, experimental/examples/arch/*.hpp (CVDP20, CVDP23, LALO20, "
               "LOVO21, PRDE20, SPRE22)",
    "RA": "JuliaReach/ReachabilityAnalysis.jl, examples/*/ (text of the benchmark specifications: "
          "LaubLoomis, Quadrotor, ProductionDestruction, LotkaVolterraTangential)",
}

#: The ARCH-COMP benchmark names in suite order, with the reports that contain them (as the
#: packages above show: JR20 = 2020, CORA run_arch24 = 2024, JR23/JR24 = 2023/2024).
BENCHMARKS = {
    "CVDP20": "coupled Van der Pol, mu = 1 and 2 (2020-2022)",
    "CVDP23": "coupled Van der Pol, uncertain coupling b in [1, 3] (2023-2024)",
    "LALO20": "Laub-Loomis, 7-D (2020-2024)",
    "QUAD20": "quadrotor, 12-D (2020-2021)",
    "PRDE20": "production-destruction (2020-2022)",
    "ROBE21": "Robertson chemical reaction, stiff (2021-2024)",
    "LOVO21": "Lotka-Volterra with tangential crossing, hybrid (2021-2024)",
    "SPRE22": "spacecraft rendezvous, hybrid (2022-2024)",
}


def _model(name: str, states: list[str], f_of, params: dict[str, float] | None = None,
           description: str = "") -> Model:
    """A model without inputs: ``f_of(x: dict of SX, p: dict of SX) -> list of SX`` over named
    states; the control ``unused`` has no effect (every ocreach model has a control set)."""
    x = ca.SX.sym("x", len(states))
    u = ca.SX.sym("unused", 1)
    params = params or {}
    p = ca.SX.sym("p", len(params))
    xs = {n: x[i] for i, n in enumerate(states)}
    ps = {n: p[i] for i, n in enumerate(params)}
    f = ca.vertcat(*f_of(xs, ps))
    return Model.build(name, x, u, f, p=p, p_default=list(params.values()), state_names=states,
                       control_names=["unused"], param_names=list(params), control_set="box",
                       description=description)


def _problem(pid: str, benchmark: str, instance: str, model: Model, lo, hi, t_final: float,
             dt: float, verification: Verification, description: str, citation: str,
             options: dict | None = None, method: str = "taylor", **kw) -> Problem:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return Problem(
        id=pid, model=model, x0=0.5 * (lo + hi), grid=time_grid(t_final, dt),
        initial_set=Interval(lo, hi), description=description, citation=citation,
        method_options=options or {}, position_dims=(0, 1), velocity_dims=(0, 1),
        extra={"arch": _suite_entry(benchmark, instance, method, options),
               "verification": verification}, **kw)


def _suite_entry(benchmark: str, instance: str, method: str, options: dict | None) -> dict:
    """``extra["arch"]``: the ARCH-COMP names and the suite's guaranteed method (its options are
    the problem's ``method_options[method]``)."""
    if method not in (options or {}):
        raise ProblemError(f"ARCH instance {benchmark} {instance}: the suite method {method!r} has "
                           f"no options entry; entries: {sorted(options or {})}")
    return {"benchmark": benchmark, "instance": instance, "method": method}


def _check_dt(dt: float, t_final: float) -> None:
    if not (dt > 0 and t_final > 0):
        raise ProblemError(f"dt and t_final must be > 0; got dt={dt!r}, t_final={t_final!r}")


# =============================================================================== CVDP20 / CVDP23
def coupled_vanderpol(mu: float = 1.0, b_state: bool = False) -> Model:
    """Two Van der Pol oscillators coupled by ``b (x2 - x1)``:
    ``y1' = mu (1 - x1^2) y1 - x1 + b (x2 - x1)``, ``y2' = mu (1 - x2^2) y2 - x2 - b (x2 - x1)``
    (JR20 vanderpol.jl, b = 1; ARIADNE CVDP20.hpp writes it ``+ x2 - 2 x1``).  With ``b_state``
    the coupling is a constant state ``b' = 0`` (CVDP23: JR24 vanderpol.jl, CORA
    coupledVanDerPol_ARCH23.m, ARIADNE CVDP23.hpp)."""
    states = ["x1", "y1", "x2", "y2"] + (["b"] if b_state else [])

    def f(x, p):
        b = x["b"] if b_state else 1.0
        m = p["mu"]
        out = [x["y1"], m * (1 - x["x1"] ** 2) * x["y1"] - x["x1"] + b * (x["x2"] - x["x1"]),
               x["y2"], m * (1 - x["x2"] ** 2) * x["y2"] - x["x2"] - b * (x["x2"] - x["x1"])]
        return out + ([ca.SX(0.0)] if b_state else [])

    return _model("arch-cvdp" + ("-b" if b_state else ""), states, f, {"mu": mu},
                  "coupled Van der Pol oscillators")


def cvdp20(mu: float = 1.0, t_final: float | None = None, dt: float = 0.01) -> Problem:
    """CVDP20: coupled Van der Pol, mu = 1 (T = 7, y1, y2 < 2.75) or mu = 2 (T = 8, < 4.05)."""
    # initial boxes, horizons and bounds: ARIADNE CVDP20.hpp and JR20 vanderpol*.jl (JR20 writes
    # x2 in [1.55, 1.85] for mu = 1, which ARIADNE and the RA text do not; [1.25, 1.55] is used)
    cases = {1.0: ((1.25, 1.55), 7.0, 2.75), 2.0: ((1.55, 1.85), 8.0, 4.05)}
    if mu not in cases:
        raise ProblemError(f"mu must be 1 or 2 (the two CVDP20 instances); got {mu!r}")
    (xl, xh), T, ymax = cases[mu]
    T = T if t_final is None else float(t_final)
    _check_dt(dt, T)
    inst = f"mu{int(mu)}"
    ver = Verification(specs=(Unsafe(ge("y1", ymax)), Unsafe(ge("y2", ymax))))
    # suite: poly from 4 initial parts (one part and taylor end above the bound; see docs/arch.md)
    opts = {"taylor": {"order": 20, "max_parts": 64},
            "poly": {"initial_parts": 4, "max_parts": 64}}
    return _problem(f"arch-cvdp20-{inst}", "CVDP20", inst, coupled_vanderpol(mu),
                    [xl, 2.35, xl, 2.35], [xh, 2.45, xh, 2.45], T, dt, ver,
                    f"coupled Van der Pol, mu = {mu:g}, T = {T:g}, y1, y2 < {ymax:g} (ARCH CVDP20)",
                    "ARCH-COMP20 NLN (CVDP20); ARIADNE CVDP20.hpp, JR20", opts, method="poly")


def cvdp23(t_final: float = 7.0, dt: float = 0.01) -> Problem:
    """CVDP23: coupled Van der Pol, mu = 1, uncertain coupling b in [1, 3], T = 7, y1, y2 < 2.75."""
    # JR24 vanderpol.jl (vanderpolN2_b, b = interval(1, 3)), ARIADNE CVDP23.hpp, CORA
    # benchmark_nonlinear_reach_ARCH23_vanDerPol.m ("original interval for x1,y1,x2,y2:
    # [1.25;2.35]..[1.55;2.45]; original interval for b: 1 to 3")
    _check_dt(dt, t_final)
    ver = Verification(specs=(Unsafe(ge("y1", 2.75)), Unsafe(ge("y2", 2.75))))
    opts = {"taylor": {"order": 20, "max_parts": 256}, "poly": {"max_parts": 64}}
    return _problem("arch-cvdp23", "CVDP23", "", coupled_vanderpol(1.0, b_state=True),
                    [1.25, 2.35, 1.25, 2.35, 1.0], [1.55, 2.45, 1.55, 2.45, 3.0], t_final, dt, ver,
                    "coupled Van der Pol, mu = 1, b in [1, 3] as a constant state, T = 7 (ARCH CVDP23)",
                    "ARCH-COMP23/24 NLN (CVDP23); JR24, CORA, ARIADNE CVDP23.hpp", opts,
                    method="poly")


# =============================================================================== LALO20
LALO_X0 = (1.2, 1.05, 1.5, 2.4, 1.0, 0.1, 0.45)  # JR24 laubloomis.jl, CORA, ARIADNE LALO20.hpp


def laub_loomis() -> Model:
    """Laub-Loomis (CORA laubLoomis.m, ARIADNE LALO20.hpp, RA LaubLoomis.jl).  The last equation
    is ``x7' = 1.8 x6 - 1.5 x2 x7`` in CORA, ARIADNE and the ARCH-COMP20 report as quoted by
    autokoopman's lalo20.py; JR20/JR24 laubloomis.jl write 1.6 (1.5 is used)."""
    def f(x, p):
        x1, x2, x3, x4, x5, x6, x7 = (x[f"x{i}"] for i in range(1, 8))
        return [1.4 * x3 - 0.9 * x1, 2.5 * x5 - 1.5 * x2, 0.6 * x7 - 0.8 * x2 * x3,
                2 - 1.3 * x3 * x4, 0.7 * x1 - x4 * x5, 0.3 * x1 - 3.1 * x6, 1.8 * x6 - 1.5 * x2 * x7]

    return _model("arch-laub-loomis", [f"x{i}" for i in range(1, 8)], f,
                  description="Laub-Loomis enzymatic network")


def lalo20(W: float = 0.01, t_final: float = 20.0, dt: float = 0.05) -> Problem:
    """LALO20: Laub-Loomis, box of half-width W about x0, T = 20, x4 < 4.5 (W = 0.1: x4 < 5),
    final width of x4."""
    # W, T and bounds: JR24 laubloomis_benchmark.jl, ARIADNE LALO20.hpp, RA LaubLoomis.jl
    cases = {0.01: ("W001", 4.5), 0.05: ("W005", 4.5), 0.1: ("W01", 5.0)}
    if W not in cases:
        raise ProblemError(f"W must be 0.01, 0.05 or 0.1 (the LALO20 instances); got {W!r}")
    inst, bound = cases[W]
    _check_dt(dt, t_final)
    x0 = np.array(LALO_X0)
    ver = Verification(specs=(Unsafe(ge("x4", bound)),), measures=(Width((("x4", 1.0),)),))
    opts = {"taylor": {"order": 20, "max_parts": 64}, "poly": {"max_parts": 64}}
    return _problem(f"arch-lalo20-{inst.lower()}", "LALO20", inst, laub_loomis(), x0 - W, x0 + W,
                    t_final, dt, ver, f"Laub-Loomis, W = {W:g}, T = {t_final:g}, x4 < {bound:g} "
                    "(ARCH LALO20)", "ARCH-COMP20-24 NLN (LALO20); JR24, CORA, ARIADNE", opts,
                    method="poly")


# =============================================================================== QUAD20
def quadrotor() -> Model:
    """The quadrotor of Beard (2008) with PD height / roll / pitch control, u = (1, 0, 0)
    (JR20 quadrotor.jl, RA Quadrotor.jl): g = 9.81, R = 0.1, l = 0.5, M_rotor = 0.1, M = 1,
    m = M + 4 M_rotor, J_x = J_y = 2/5 M R^2 + 2 l^2 M_rotor, J_z = 2/5 M R^2 + 4 l^2 M_rotor,
    F = m g - 10 (x3 - u1) + 3 x6, tau_phi = -(x7 - u2) - x10, tau_theta = -(x8 - u3) - x11,
    tau_psi = 0."""
    g, R, l, Mr, M = 9.81, 0.1, 0.5, 0.1, 1.0
    m = M + 4 * Mr
    Jx = 0.4 * M * R**2 + 2 * l**2 * Mr
    Jy = Jx
    Jz = 0.4 * M * R**2 + 4 * l**2 * Mr
    u1, u2, u3 = 1.0, 0.0, 0.0

    def f(x, p):
        x1, x2, x3, x4, x5, x6, x7, x8, x9, x10, x11, x12 = (x[f"x{i}"] for i in range(1, 13))
        F = m * g - 10 * (x3 - u1) + 3 * x6
        tphi = -(x7 - u2) - x10
        ttheta = -(x8 - u3) - x11
        tpsi = 0.0
        s7, c7, s8, c8, s9, c9 = ca.sin(x7), ca.cos(x7), ca.sin(x8), ca.cos(x8), ca.sin(x9), ca.cos(x9)
        t8 = s8 / c8
        return [c8 * c9 * x4 + (s7 * s8 * c9 - c7 * s9) * x5 + (c7 * s8 * c9 + s7 * s9) * x6,
                c8 * s9 * x4 + (s7 * s8 * s9 + c7 * c9) * x5 + (c7 * s8 * s9 - s7 * c9) * x6,
                s8 * x4 - s7 * c8 * x5 - c7 * c8 * x6,
                x12 * x5 - x11 * x6 - g * s8,
                x10 * x6 - x12 * x4 + g * c8 * s7,
                x11 * x4 - x10 * x5 + g * c8 * c7 - F / m,
                x10 + s7 * t8 * x11 + c7 * t8 * x12,
                c7 * x11 - s7 * x12,
                s7 / c8 * x11 + c7 / c8 * x12,
                (Jy - Jz) / Jx * x11 * x12 + tphi / Jx,
                (Jz - Jx) / Jy * x10 * x12 + ttheta / Jy,
                (Jx - Jy) / Jz * x10 * x11 + tpsi / Jz]

    return _model("arch-quadrotor", [f"x{i}" for i in range(1, 13)], f,
                  description="quadrotor with PD height, roll and pitch control")


def quad20(delta: float = 0.4, t_final: float = 5.0, dt: float = 0.01) -> Problem:
    """QUAD20: quadrotor, positions and velocities in [-delta, delta], T = 5; x3 < 1.4 always,
    x3 > 0.9 for t >= 1, x3 in [0.98, 1.02] at t = 5 (the goals are stated for delta = 0.4; the
    other instances measure scalability, RA Quadrotor.jl; JR20 checks all three)."""
    cases = {0.1: "d01", 0.4: "d04", 0.8: "d08"}  # JR20 quadrotor_benchmark.jl
    if delta not in cases:
        raise ProblemError(f"delta must be 0.1, 0.4 or 0.8 (the QUAD20 instances); got {delta!r}")
    _check_dt(dt, t_final)
    T = float(t_final)
    d = np.array([delta] * 6 + [0.0] * 6)
    specs = [Unsafe(ge("x3", 1.4))]
    if T >= 1.0:
        specs.append(Unsafe(le("x3", 0.9), window=(1.0, T)))
    if T == 5.0:
        specs.append(Safe(box({"x3": (0.98, 1.02)}), window=(5.0, 5.0)))
    ver = Verification(specs=tuple(specs), measures=(Width((("x3", 1.0),)),))
    opts = {"taylor": {"order": 10, "max_parts": 64}}
    inst = cases[delta]
    return _problem(f"arch-quad20-{inst}", "QUAD20", inst, quadrotor(), -d, d, T, dt, ver,
                    f"quadrotor, delta = {delta:g}, T = {T:g} (ARCH QUAD20)",
                    "ARCH-COMP20/21 NLN (QUAD20); JR20, RA Quadrotor.jl", opts)


# =============================================================================== PRDE20
def production_destruction(a_state: bool) -> Model:
    """``x' = -x y / (1 + x)``, ``y' = x y / (1 + x) - a y``, ``z' = a y`` (JR20 prod_destruct.jl,
    CORA prodDes.m / prodDesParam.m, ARIADNE PRDE20.hpp); a = 0.3, or a constant state."""
    states = ["x", "y", "z"] + (["a"] if a_state else [])

    def f(x, p):
        a = x["a"] if a_state else p["a"]
        r = x["x"] * x["y"] / (1 + x["x"])
        return [-r, r - a * x["y"], a * x["y"]] + ([ca.SX(0.0)] if a_state else [])

    return _model("arch-prod-destruct" + ("-a" if a_state else ""), states, f,
                  {} if a_state else {"a": 0.3}, "production-destruction (Michaelis-Menten)")


def prde20(case: str = "I", t_final: float = 100.0, dt: float = 0.1) -> Problem:
    """PRDE20: production-destruction, T = 100, x, y, z >= 0 and 10 in x + y + z at T, volume of
    the final box (x, y, z); case I (x0 in [9.5, 10]), P (a in [0.296, 0.304]), IP (both)."""
    # JR20 prod_destruct.jl (x0 = 9.98 in case P, where ARIADNE PRDE20.hpp writes 10; 9.98 keeps
    # x + y + z = 10) and ARIADNE: I+P is x0 in [9.7, 10], a in [0.298, 0.302] (the RA text
    # writes [9.5, 10] and [0.296, 0.304], the "variation" its note mentions; JR20/ARIADNE used)
    cases = {"I": ([9.5, 0.01, 0.01], [10.0, 0.01, 0.01]),
             "P": ([9.98, 0.01, 0.01, 0.296], [9.98, 0.01, 0.01, 0.304]),
             "IP": ([9.7, 0.01, 0.01, 0.298], [10.0, 0.01, 0.01, 0.302])}
    if case not in cases:
        raise ProblemError(f"case must be one of {sorted(cases)}; got {case!r}")
    _check_dt(dt, t_final)
    lo, hi = cases[case]
    T = float(t_final)
    ver = Verification(specs=(Safe(box({"x": (0, math.inf), "y": (0, math.inf),
                                         "z": (0, math.inf)}), window=(T, T)),
                              Attains((("x", 1.0), ("y", 1.0), ("z", 1.0)), 10.0, window=(T, T))),
                       measures=(BoxVolume(("x", "y", "z")),))
    # suite: poly; with the uncertain a, from 2 initial parts (x(T) ~ 1e-9 must be proven > 0)
    opts = {"taylor": {"order": 20, "max_parts": 64},
            "poly": {"initial_parts": 1 if case == "I" else 2, "max_parts": 64}}
    return _problem(f"arch-prde20-{case.lower()}", "PRDE20", case,
                    production_destruction(case != "I"), lo, hi, T, dt, ver,
                    f"production-destruction, case {case}, T = {T:g} (ARCH PRDE20)",
                    "ARCH-COMP20 NLN (PRDE20); JR20, ARIADNE PRDE20.hpp", opts, method="poly")


# =============================================================================== ROBE21
ROBERTSON_CASES = {"1": (0.4, 1e2, 1e3), "2": (0.4, 1e3, 1e5), "3": (0.4, 1e3, 1e7)}  # JR24, CORA


def robertson(alpha: float, beta: float, gamma: float) -> Model:
    """``x' = -alpha x + beta y z``, ``y' = alpha x - beta y z - gamma y^2``, ``z' = gamma y^2``
    (JR24 robertson.jl, CORA Robertson_case*.m)."""
    def f(x, p):
        a, b, g = p["alpha"], p["beta"], p["gamma"]
        return [-a * x["x"] + b * x["y"] * x["z"], a * x["x"] - b * x["y"] * x["z"] - g * x["y"] ** 2,
                g * x["y"] ** 2]

    return _model("arch-robertson", ["x", "y", "z"], f,
                  {"alpha": alpha, "beta": beta, "gamma": gamma}, "Robertson chemical reaction")


def robe21(case: str = "1", t_final: float = 40.0, dt: float | None = None) -> Problem:
    """ROBE21: Robertson, x0 = (1, 0, 0), T = 40, width of x + y + z at T (cases 1-3: beta,
    gamma = (1e2, 1e3), (1e3, 1e5), (1e3, 1e7); alpha = 0.4)."""
    if case not in ROBERTSON_CASES:
        raise ProblemError(f"case must be one of {sorted(ROBERTSON_CASES)}; got {case!r}")
    T = float(t_final)
    dt = {"1": 0.05, "2": 0.05, "3": 0.05}[case] if dt is None else dt
    _check_dt(dt, T)
    ver = Verification(measures=(Width((("x", 1.0), ("y", 1.0), ("z", 1.0)), "width of x+y+z"),))
    # suite: poly for case 1 (taylor's remainder loop stops closing at t = 29.95), taylor else
    opts = {"taylor": {"order": 20, "max_parts": 1, "max_halvings": 12}, "poly": {}}
    return _problem(f"arch-robe21-{case}", "ROBE21", case, robertson(*ROBERTSON_CASES[case]),
                    [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], T, dt, ver,
                    f"Robertson, case {case} (alpha, beta, gamma = {ROBERTSON_CASES[case]}), "
                    f"T = {T:g} (ARCH ROBE21)", "ARCH-COMP21-24 NLN (ROBE21); JR24, CORA", opts,
                    method="poly" if case == "1" else "taylor")


# =============================================================================== LOVO21
def lotka_volterra(inside: bool) -> Model:
    """``x' = 3 x - 3 x y``, ``y' = x y - y`` with the counter ``cnt' = 1`` inside the circle and 0
    outside (ARIADNE LOVO21.hpp: alpha = beta = 3, gamma = delta = 1; CORA lotkaVolterra.m; RA
    LotkaVolterraTangential)."""
    def f(x, p):
        return [3 * x["x"] - 3 * x["x"] * x["y"], x["x"] * x["y"] - x["y"],
                ca.SX(1.0 if inside else 0.0)]

    return _model("arch-lotka-volterra-" + ("in" if inside else "out"), ["x", "y", "cnt"], f,
                  description="Lotka-Volterra with a time counter inside the circle")


#: guard circle: centre (1, 1), radius 0.161 (ARIADNE LOVO21.hpp, CORA lotkaVolterra.m, JR24)
LOVO_CENTER, LOVO_RADIUS = {"x": 1.0, "y": 1.0}, 0.161


def lovo_automaton() -> HybridAutomaton:
    """Two locations with urgent transitions on the circle: outside -> inside when
    ``(x-1)^2 + (y-1)^2 <= r^2``, inside -> outside when ``>= r^2``; invariants are the
    complements; resets the identity (ARIADNE LOVO21.hpp, CORA lotkaVolterra.m)."""
    disk = in_ball(LOVO_CENTER, LOVO_RADIUS)
    ring = out_ball(LOVO_CENTER, LOVO_RADIUS)
    out = Location("outside", lotka_volterra(False), invariant=(ring,))
    ins = Location("inside", lotka_volterra(True), invariant=(disk,))
    return HybridAutomaton("lotka-volterra", (out, ins), (
        Transition("outside", "inside", (disk,), label="enter"),
        Transition("inside", "outside", (ring,), label="exit")))


def lovo21(t_final: float = 3.64, dt: float = 0.01, eps: float = 0.012) -> HybridProblem:
    """LOVO21: Lotka-Volterra, x0 in [1.3 - eps, 1.3 + eps], y0 = 1, eps = 0.012, T = 3.64; final
    sets with one and with two crossings of the circle; area of the final box (x, y), largest cnt."""
    # eps, T: ARIADNE LOVO21.hpp, CORA benchmark_hybrid_reach_ARCH23_lotkaVolterra.m, JR24
    # (RA's text quotes the earlier eps = 0.008)
    _check_dt(dt, t_final)
    aut = lovo_automaton()
    T = float(t_final)
    lo, hi = np.array([1.3 - eps, 1.0, 0.0]), np.array([1.3 + eps, 1.0, 0.0])
    # no safety spec: ARIADNE LOVO21.hpp counts as verified that the final sets show both 2 and 4
    # jumps (one and two crossings of the circle); JR24 and CORA verify nothing ("validation =
    # ones") and report the area of the final box (the bound cnt < 0.2 of the RA text belongs to
    # the earlier LOVO20, radius 0.15, eps = 0.008)
    ver = Verification(measures=(BoxVolume(("x", "y")), Maximum((("cnt", 1.0),), "max cnt")),
                       extra={"final_jump_counts": (2, 4)},
                       notes="verified when the final sets show runs with 2 and with 4 jumps")
    # suite: poly (a tighter final box than taylor's, both verify)
    opts = {"taylor": {"order": 20, "max_parts": 1}, "poly": {"order": 20},
            "hybrid": {"clusters": 1, "enclose": "pca"}}
    return HybridProblem(
        id="arch-lovo21", model=aut.location("outside").model, x0=0.5 * (lo + hi),
        grid=time_grid(T, dt, fit=True), initial_set=Interval(lo, hi), automaton=aut,
        initial_location="outside", position_dims=(0, 1), velocity_dims=(0, 1),
        description=f"Lotka-Volterra with tangential crossing of the circle r = 0.161, "
                    f"eps = {eps:g}, T = {T:g} (ARCH LOVO21)",
        citation="ARCH-COMP21-24 NLN (LOVO21); ARIADNE LOVO21.hpp, CORA, JR24",
        method_options=opts,
        extra={"arch": _suite_entry("LOVO21", "", "poly", opts), "verification": ver})


# =============================================================================== SPRE22
#: mu [m^3/min^2], r [m], m_c [kg] and the gains K1 (approaching), K2 (attempt) over
#: (x, y, vx, vy): JR24 spacecraft.jl, ARIADNE SPRE22.hpp, CORA dynamics_*.m (the same values,
#: folded into the coefficients)
SPRE_MU = 3.986e14 * 60.0**2
SPRE_R = 42164.0e3
SPRE_MC = 500.0
SPRE_K1 = ((-28.8287, 0.1005, -1449.9754, 0.0046), (-0.087, -33.2562, 0.00462, -1451.5013))
SPRE_K2 = ((-288.0288, 0.1312, -9614.9898, 0.0), (-0.1312, -288.0, 0.0, -9614.9883))


def spacecraft(mode: str) -> Model:
    """Planar relative motion of a chaser near a target on a circular orbit with the nonlinear
    gravity term, ``vx' = n^2 x + 2 n vy + mu/r^2 - mu/r_c^3 (r + x) + ux/m_c``,
    ``vy' = n^2 y - 2 n vx - mu/r_c^3 y + uy/m_c``, ``r_c = sqrt((r + x)^2 + y^2)``,
    ``n = sqrt(mu / r^3)``, ``u = K s`` in approaching and attempt, ``u = 0`` in aborting (JR24
    spacecraft.jl, ARIADNE SPRE22.hpp; CORA's dynamics_*.m write ``(r + x)^2 - y^2`` under the
    root, a sign typo of the original SpaceEx model that changes f by < 1e-9 relative here)."""
    K = {"approaching": SPRE_K1, "attempt": SPRE_K2, "aborting": None}
    if mode not in K:
        raise ProblemError(f"mode must be one of {sorted(K)}; got {mode!r}")
    mu, r, mc = SPRE_MU, SPRE_R, SPRE_MC
    n = math.sqrt(mu / r**3)
    gains = K[mode]

    def f(s, p):
        x, y, vx, vy = s["x"], s["y"], s["vx"], s["vy"]
        rc = ca.sqrt((r + x) ** 2 + y**2)
        ux = uy = 0.0
        if gains is not None:
            ux = sum(k * v for k, v in zip(gains[0], (x, y, vx, vy)))
            uy = sum(k * v for k, v in zip(gains[1], (x, y, vx, vy)))
        return [vx, vy, n**2 * x + 2 * n * vy + mu / r**2 - mu / rc**3 * (r + x) + ux / mc,
                n**2 * y - 2 * n * vx - mu / rc**3 * y + uy / mc]

    return _model(f"arch-spacecraft-{mode}", ["x", "y", "vx", "vy"], f,
                  description=f"spacecraft rendezvous, {mode} mode (m, m/min, min)")


def spre_automaton(abort: tuple[float, float] = (120.0, 150.0), x_attempt: float = -100.0
                   ) -> HybridAutomaton:
    """approaching -> attempt (urgent, x >= -100), approaching / attempt -> aborting (permissive,
    t in [120, 150]); invariants x <= -100 and t <= 150 (approaching), x >= -100 and t <= 150
    (attempt), none (aborting); identity resets (ARIADNE SPRE22.hpp, CORA
    rendezvous_nonlinear_passive_nondet.m, JR24 spacecraft.jl)."""
    t0, t1 = abort
    appr = Location("approaching", spacecraft("approaching"),
                    invariant=(le("x", x_attempt), le(CLOCK, t1)))
    att = Location("attempt", spacecraft("attempt"), invariant=(ge("x", x_attempt), le(CLOCK, t1)))
    abo = Location("aborting", spacecraft("aborting"))
    return HybridAutomaton("spacecraft-rendezvous", (appr, att, abo), (
        Transition("approaching", "attempt", (ge("x", x_attempt),), label="attempt"),
        Transition("approaching", "aborting", time_window(t0, t1), urgent=False, label="abort"),
        Transition("attempt", "aborting", time_window(t0, t1), urgent=False, label="abort")))


#: line-of-sight half-angle [deg]: 20 in JR24 spacecraft.jl (tand(20)) and CORA (pi/9); 30 in
#: JR20 (SPRE20) and ARIADNE SPRE22.hpp (pi/6).  The stricter 20 is used.
SPRE_LOS_DEG = 20.0
#: speed bound in attempt [m/min]: 0.055 m/s = 3.3 m/min (JR24, ARIADNE, CORA's octagon inside it)
SPRE_VMAX = 3.3
#: half-side of the target box in aborting [m]: 2 in JR24, 1 in CORA (interval([-1;-1],[1;1])),
#: 0.2 in JR20 and ARIADNE.  The largest (strictest) 2 is used.
SPRE_TARGET = 2.0


def spre22(t_final: float = 200.0, dt: float = 0.2, dt_attempt: float = 0.05,
           x_lo: float = -925.0, x_hi: float = -875.0, y_lo: float = -425.0, y_hi: float = -375.0,
           abort_lo: float = 120.0, abort_hi: float = 150.0) -> HybridProblem:
    """SPRE22: spacecraft rendezvous, x in [-925, -875], y in [-425, -375], vx, vy in [0, 5]
    (m, m/min), T = 200 min; in attempt the line-of-sight cone (half-angle 20 deg) and speed
    <= 3.3 m/min, in aborting the target box |x|, |y| <= 2 m is never entered."""
    # initial set, horizon, abort window: JR24 spacecraft.jl, CORA benchmark_hybrid_reach_ARCH23_
    # spacecraft.m, ARIADNE SPRE22.hpp (vx, vy in [0, 5]; SPRE20 of JR20 had vx = vy = 0)
    _check_dt(dt, t_final)
    aut = spre_automaton((abort_lo, abort_hi))
    lo = np.array([x_lo, y_lo, 0.0, 0.0])
    hi = np.array([x_hi, y_hi, 5.0, 5.0])
    tan = math.tan(math.radians(SPRE_LOS_DEG))
    los = (linear({"x": tan, "y": -1.0}, 0.0), linear({"x": tan, "y": 1.0}, 0.0))  # |y| <= -x tan
    ver = Verification(specs=(
        Safe(los, locations=("attempt",), name=f"line of sight: |y| <= -x tan {SPRE_LOS_DEG:g} deg in attempt"),
        Safe((in_ball({"vx": 0.0, "vy": 0.0}, SPRE_VMAX),), locations=("attempt",),
             name=f"speed <= {SPRE_VMAX:g} m/min in attempt"),
        Unsafe(box({"x": (-SPRE_TARGET, SPRE_TARGET), "y": (-SPRE_TARGET, SPRE_TARGET)}),
               locations=("aborting",), name=f"target |x|, |y| <= {SPRE_TARGET:g} m avoided in aborting")))
    # suite: taylor, the abort guard sets (every state of approaching and attempt over t in
    # [120, 150]) in 60 groups; with 10 or 40 the aborting sets are not proven outside the target
    # box (docs/arch.md)
    opts = {"taylor": {"order": 10, "max_parts": 1},
            "hybrid": {"dt": {"attempt": dt_attempt}, "clusters": {"abort": 60}, "enclose": "pca"}}
    return HybridProblem(
        id="arch-spre22", model=aut.location("approaching").model, x0=0.5 * (lo + hi),
        grid=time_grid(t_final, dt), initial_set=Interval(lo, hi), automaton=aut,
        initial_location="approaching", position_dims=(0, 1), velocity_dims=(2, 3),
        description="spacecraft rendezvous with abort, T = 200 min (ARCH SPRE22)",
        citation="ARCH-COMP22-24 NLN (SPRE22); JR24, CORA, ARIADNE SPRE22.hpp; Chan & Mitra, ARCH 2017",
        method_options=opts,
        extra={"arch": _suite_entry("SPRE22", "", "taylor", opts), "verification": ver})


# =============================================================================== registry
#: the options paragraph of every instance's docstring (read by ``ocreach problem ID``)
OPTIONS_DOC = ("Options: ``t_final`` (the benchmark's time unit{unit}; default the instance's "
               "horizon T), ``dt`` (the grid step, same unit{dt}){more}.")
SPRE_MORE = (", ``dt_attempt`` (min, the grid step in the attempt mode), ``x_lo`` (m, the lower "
             "x of the initial box), ``x_hi`` (m, its upper x), ``y_lo`` (m, its lower y), "
             "``y_hi`` (m, its upper y), ``abort_lo`` (min, the earliest abort), ``abort_hi`` "
             "(min, the latest abort)")
for _f, _unit, _dt, _more in ((cvdp20, "", "", ""), (cvdp23, "", "", ""), (lalo20, "", "", ""),
                              (quad20, "", "", ""), (prde20, "", "", ""),
                              (robe21, "", "; default 0.05", ""),
                              (lovo21, "", "", ", ``eps`` (the half-width of the initial x interval)"),
                              (spre22, ": min", "", SPRE_MORE)):
    _f.__doc__ += "\n\n    " + OPTIONS_DOC.format(unit=_unit, dt=_dt, more=_more)


def _fix(factory, **kw):
    def make(**over):
        return factory(**{**kw, **over})
    make.__doc__ = factory.__doc__
    make.__name__ = factory.__name__
    import inspect
    sig = inspect.signature(factory)
    make.__signature__ = sig.replace(parameters=[p for n, p in sig.parameters.items() if n not in kw])
    return make


PROBLEMS = {
    "arch-cvdp20-mu1": _fix(cvdp20, mu=1.0),
    "arch-cvdp20-mu2": _fix(cvdp20, mu=2.0),
    "arch-cvdp23": cvdp23,
    "arch-lalo20-w001": _fix(lalo20, W=0.01),
    "arch-lalo20-w005": _fix(lalo20, W=0.05),
    "arch-lalo20-w01": _fix(lalo20, W=0.1),
    "arch-quad20-d01": _fix(quad20, delta=0.1),
    "arch-quad20-d04": _fix(quad20, delta=0.4),
    "arch-quad20-d08": _fix(quad20, delta=0.8),
    "arch-prde20-i": _fix(prde20, case="I"),
    "arch-prde20-p": _fix(prde20, case="P"),
    "arch-prde20-ip": _fix(prde20, case="IP"),
    "arch-robe21-1": _fix(robe21, case="1"),
    "arch-robe21-2": _fix(robe21, case="2"),
    "arch-robe21-3": _fix(robe21, case="3"),
    "arch-lovo21": lovo21,
    "arch-spre22": spre22,
}
