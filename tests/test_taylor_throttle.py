"""The guaranteed methods on problems that failed early with their default options.

* Mass flow ``dn/dt = T_max n^2 ||u|| / c`` (Patel & Scheeres Eq. 11; elliptic-earth, lunar-flyby,
  lunar-flyby-uncertain): ``||u||`` has no second derivative at ``u = 0`` (the builders'
  ``sqrt(|u|^2 + 1e-30)`` has ``1e15`` there), so ``taylor``'s interval Hessian over the control
  box made the remainder loop diverge on the first step.  ``taylor`` and ``poly`` now step the
  throttle-relaxed model (``relax_throttle``); ``sdc`` cannot take a state-dependent input matrix
  and refuses before any work, naming the rows.
* dro (0.1 TU grid steps): one step of the linearisation about a single point charged the curvature
  of the step's own motion to the remainder (100 times the thrust), and the next step could not be
  enclosed; the step-size control ``growth_tol`` halves such steps.

Truth: the soundness harness (``ocreach.testing``: SciPy DOP853 from vertices, interior points and
constant / bang-bang / random / directed inputs, every grid time and the step midpoints), on a
numpy right-hand side written here for the variable-mass CR3BP (the true ``||u||``, not the
model's regularised one).
"""
from __future__ import annotations

import numpy as np
import pytest

import ocreach
from ocreach.errors import ProblemError
from ocreach.models.cr3bp import cr3bp
from ocreach.problem import Problem
from ocreach.reach.sdc import SDCZonotope
from ocreach.testing.harness import Case, bundled_cases, run_method
from ocreach.units import Units

MU = 0.01215
UNITS = Units(length=3.844e8, time=3.75e5, mass=1.0, name="earth-moon")


def mass_cr3bp_rhs(mu: float, T: float, c: float):
    """Spatial CR3BP with thrust ``T n u`` and inverse mass ``n' = T n^2 ||u|| / c`` (numpy)."""
    def rhs(t: float, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        x, y, z, vx, vy, vz, n = X.T
        r1 = np.sqrt((x + mu) ** 2 + y**2 + z**2)
        r2 = np.sqrt((x - 1 + mu) ** 2 + y**2 + z**2)
        ax = x + 2 * vy - (1 - mu) * (x + mu) / r1**3 - mu * (x - 1 + mu) / r2**3
        ay = y - 2 * vx - (1 - mu) * y / r1**3 - mu * y / r2**3
        az = -(1 - mu) * z / r1**3 - mu * z / r2**3
        a = T * n
        return np.column_stack([vx, vy, vz, ax + a * U[:, 0], ay + a * U[:, 1], az + a * U[:, 2],
                                T * n**2 * np.linalg.norm(U, axis=1) / c])
    return rhs


def mass_case(control_set: str) -> Case:
    """20 N on 1000 kg (so the mass row moves visibly in 3 steps of 2 h), 0.02 DU box of
    initial positions, the control set ``"ball"`` or ``"box"`` (``||u|| <= sqrt(3)``)."""
    from ocreach.sets.zonotope import Zonotope

    model = cr3bp(MU, variable_mass=True, thrust=20.0, isp=3000.0, units=UNITS,
                  control_set=control_set)
    x0 = np.array([0.8, 0.1, 0.02, 0.05, 0.3, 0.01, 1e-3])
    G = np.zeros((7, 3))
    G[:3, :3] = 1e-3 * np.eye(3)
    grid = np.arange(4) * (7200.0 / UNITS.time)
    p = Problem(id=f"mass-cr3bp-{control_set}", model=model, x0=x0, grid=grid,
                initial_set=Zonotope(x0, G), position_dims=(0, 1, 2), velocity_dims=(3, 4, 5))
    T, c = (model.param(k, p.params) for k in ("T_max", "c_ex"))
    return Case(label=p.id, problem=p, rhs=mass_cr3bp_rhs(MU, T, c), kind="generated")


@pytest.mark.parametrize("control_set", ["ball", "box"])
def test_taylor_encloses_the_mass_flow(control_set):
    out = run_method("taylor", mass_case(control_set), n_samples=120, seed=1)
    assert out.status == "complete", out.line()      # was: step 0 cannot be enclosed
    assert out.escapes == 0 and out.sets_checked == 4 and out.tubes_checked == 3, out.line()


def test_taylor_throttle_bound_follows_the_control_set():
    """The throttle reaches ``||u|| = sqrt(3)`` at the box's corners (1 on the ball); the step
    runs on the relaxed model with one more input."""
    for kind, top in (("ball", "[0, 1.000000000001"), ("box", "[0, 1.73205080757")):
        res = ocreach.reach(mass_case(kind).problem, "taylor")
        assert top in res.meta["input_enclosure"] and res.meta["input_set"] == kind
        assert res.sets[-1].dim == 7 and res.meta["guaranteed"] is True


def test_poly_encloses_the_mass_flow():
    out = run_method("poly", mass_case("ball"), n_samples=60, seed=2)
    assert out.status == "complete" and out.escapes == 0, out.line()


def test_sdc_refuses_the_mass_flow_naming_the_rows():
    p = mass_case("ball").problem
    ok, why = SDCZonotope.applicable(p)
    assert not ok and "n (on n, ux, uy, uz)" in why and "taylor" in why
    with pytest.raises(ProblemError, match=r"does not apply.*vx \(on n\).*Use taylor"):
        ocreach.reach(p, "sdc")


@pytest.mark.parametrize("method", ["taylor", "sdc"])
def test_dro_default_options_are_enclosed(method):
    case = bundled_cases(steps=4, ids=["dro"])[0]
    out = run_method(method, case, n_samples=60, seed=0)
    assert out.status == "complete", out.line()      # was: step 1 (taylor) / 2 (sdc) failed
    assert out.escapes == 0 and out.sets_checked == 5, out.line()


def test_growth_tol_is_checked():
    for bad in (0.0, -1.0, float("nan"), "x"):
        with pytest.raises(ProblemError, match="growth_tol must be"):
            ocreach.reach(ocreach.get_problem("vdp", t_final=0.2), "taylor", growth_tol=bad)
