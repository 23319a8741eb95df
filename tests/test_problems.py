"""Tests of the Patel & Subbarao scenarios (l2-halo, nrho-9-2, earth-mars) and the DRO reference:
they build, validate, match the paper's numbers converted independently here, and reject bad overrides."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from ocreach.errors import ProblemError
from ocreach.problem import Reference
from ocreach.registry import get_problem, list_problems

T_STAR = 375200.0            # s (Patel & Subbarao)
L_STAR = 3.844e8             # m
AU = 1.495978707e11          # m
GM_SUN = 1.32712440018e20    # m^3/s^2
TU_SUN = np.sqrt(AU**3 / GM_SUN)


def cr3bp_rhs(mu):
    def f(_t, s):
        x, y, z, vx, vy, vz = s
        r1 = np.sqrt((x + mu) ** 2 + y**2 + z**2)
        r2 = np.sqrt((x - 1 + mu) ** 2 + y**2 + z**2)
        return [vx, vy, vz,
                x + 2 * vy - (1 - mu) * (x + mu) / r1**3 - mu * (x - 1 + mu) / r2**3,
                y - 2 * vx - (1 - mu) * y / r1**3 - mu * y / r2**3,
                -(1 - mu) * z / r1**3 - mu * z / r2**3]
    return f


def test_listed_with_descriptions():
    table = list_problems()
    for pid in ("l2-halo", "nrho-9-2", "earth-mars", "dro"):
        assert pid in table and len(table[pid]) > 20


def test_l2_halo():
    p = get_problem("l2-halo")
    assert p.id == "l2-halo" and p.model.n_x == 6 and p.control_set.kind == "ball"
    assert p.param("mu") == 0.01215
    # a_max = T/m in model units: 0.1 N / 1000 kg * t*^2 / l*
    assert p.param("a_max") == pytest.approx(0.1 / 1000 * T_STAR**2 / L_STAR, rel=1e-12)
    assert isinstance(p.reference, Reference)
    np.testing.assert_array_equal(p.x0, p.reference.x0)
    np.testing.assert_allclose(p.x0, [1.1720, 0, -0.0862, 0, -0.1880, 0], atol=5e-5)
    # grid: one period in ~1 h steps, ending exactly at the period
    assert p.grid[0] == 0 and p.grid[-1] == pytest.approx(p.reference.period, abs=1e-14)
    assert np.allclose(np.diff(p.grid) * T_STAR, 3600, rtol=3e-3)
    # the reference is periodic under an independent integration
    sol = solve_ivp(cr3bp_rhs(0.01215), (0, p.reference.period), p.x0, method="DOP853",
                    rtol=1e-13, atol=1e-13)
    assert np.linalg.norm(sol.y[:, -1] - p.x0) < 1e-9
    assert p.extra["isp_s"] == 3000 and p.citation


def test_nrho_9_2():
    p = get_problem("nrho-9-2")
    assert p.grid[-1] * T_STAR == pytest.approx(76 * 3600, rel=1e-12)
    assert p.grid.size == 77
    assert p.reference.period * T_STAR / 86400 == pytest.approx(2 * 29.530589 / 9, rel=1e-6)
    assert p.x0[2] < 0


def test_earth_mars():
    p = get_problem("earth-mars")
    km = np.array([-140699693, -51614428, 980, 9.774596, -28.07828, 4.337725e-4])
    np.testing.assert_allclose(p.x0[:3] * AU / 1e3, km[:3], rtol=1e-12)
    np.testing.assert_allclose(p.x0[3:] * AU / TU_SUN / 1e3, km[3:], rtol=1e-12)
    assert np.linalg.norm(p.x0[:3]) == pytest.approx(1.0, abs=0.02)     # Earth's distance
    assert p.param("mu") == 1.0
    assert p.param("a_max") == pytest.approx(0.3 / 1000 * TU_SUN**2 / AU, rel=1e-12)
    assert p.grid.size == 201 and p.grid[-1] * TU_SUN == pytest.approx(200 * 86400, rel=1e-12)
    assert "2007-04-10" in str(p.extra["departure_epoch"])
    assert get_problem("earth-mars", t_days=300).grid.size == 301


def test_overrides():
    p = get_problem("l2-halo", thrust=0.2, dt=0.05, t_final=1.0)
    assert p.param("a_max") == pytest.approx(0.2 / 1000 * T_STAR**2 / L_STAR, rel=1e-12)
    assert p.grid[-1] == 1.0 and p.grid.size == 21


@pytest.mark.parametrize("pid,kw", [
    ("l2-halo", {"thrust": 0.0}), ("l2-halo", {"thrust": -0.1}), ("nrho-9-2", {"thrust": 0}),
    ("earth-mars", {"thrust": -1}), ("l2-halo", {"mass": 0}), ("l2-halo", {"dt": -1}),
    ("l2-halo", {"dt": 10.0, "t_final": 1.0}), ("earth-mars", {"t_days": 0}),
    ("nrho-9-2", {"isp": float("nan")}), ("l2-halo", {"warp": 9}),
])
def test_bad_overrides(pid, kw):
    with pytest.raises(ProblemError):
        get_problem(pid, **kw)


def test_dro_reference():
    p = get_problem("dro")
    ref = p.reference
    assert ref is not None and ref.x0[0] == 0.2765 and abs(ref.x0[3] - 2.1379) < 1e-3
    assert 6.0 < ref.period < 6.5
    # problem state itself is still the paper's
    np.testing.assert_array_equal(p.x0, [0.2765, 0, 0, 2.1379])


def test_patel_subbarao_initial_set_option_is_checked():
    with pytest.raises(ProblemError, match="initial_set must be one of"):
        get_problem("nrho-9-2", initial_set="bogus")
    assert get_problem("nrho-9-2", initial_set="point").initial_set is None
