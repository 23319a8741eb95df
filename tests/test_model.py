"""Model layer: derivative tensors against finite differences, SDC identity, control law, errors."""
import casadi as ca
import numpy as np
import pytest

from ocreach import Model, ProblemError
from ocreach.models import cr3bp, twobody, vanderpol
from ocreach.units import EARTH_MOON_FOSS, Units


def _fd_jacobian(fun, z, h=1e-6):
    cols = [(fun(z + h * e) - fun(z - h * e)) / (2 * h) for e in np.eye(z.size)]
    return np.stack(cols, axis=-1)


@pytest.mark.parametrize("model,z0", [
    (cr3bp(0.01215, a_max=0.05), np.array([1.1, 0.02, -0.08, 0.01, -0.19, 0.02, 0.3, -0.2, 0.5])),
    (vanderpol(), np.array([0.5, -0.3, 0.7])),
    (twobody(a_max=0.01), np.array([1.0, 0.1, 0.05, -0.1, 1.0, 0.02, 0.1, 0.2, -0.3])),
])
def test_tensors_match_finite_differences(model, z0):
    nx = model.n_x
    T = model.tensors(z0[:nx], z0[nx:], order=3)
    F = lambda z, j: model.tensors(z[:nx], z[nx:], order=3)[j]
    for j in (1, 2, 3):
        num = _fd_jacobian(lambda z: F(z, j - 1), z0, h=1e-5)
        scale = max(1.0, np.abs(T[j]).max())
        assert np.abs(num - T[j]).max() < 1e-5 * scale, f"order {j}"
    # augmented rows (u' = 0) are zero (Foss Eq. 12)
    assert np.all(T[1][nx:] == 0) and np.all(T[2][nx:] == 0)


def test_tensors_are_symmetric():
    m = cr3bp(0.0122, planar=True, a_max=0.03)
    T = m.tensors([0.3, 0.1, 0.2, 2.0], [0.5, 0.5], order=3)
    assert np.allclose(T[2], np.swapaxes(T[2], 1, 2))
    assert np.allclose(T[3], np.transpose(T[3], (0, 2, 1, 3)))
    assert np.allclose(T[3], np.transpose(T[3], (0, 3, 2, 1)))


def test_sdc_factor_mean_value_identity():
    """Patel & Subbarao Eq. 17-18: f(x) = f(x0) + A(x; x0)(x - x0); Eq. 19 derivative by FD."""
    m = cr3bp(0.01215, a_max=0.05)
    x = np.array([1.12, 0.03, -0.07, 0.01, -0.17, 0.02])
    x0 = np.array([1.10, 0.0, -0.08, 0.0, -0.18, 0.0])
    u = np.array([0.2, 0.1, -0.3])
    A, dA = m.sdc_fun()(x, x0, u, 0.0, m.p_default)
    lhs = m(x0, u) + np.asarray(A) @ (x - x0)
    assert np.allclose(lhs, m(x, u), atol=1e-12, rtol=1e-10)
    dA = np.asarray(dA).reshape(6, 6, 6, order="F")
    num = _fd_jacobian(lambda xx: np.asarray(m.sdc_fun()(xx, x0, u, 0.0, m.p_default)[0]), x)
    assert np.abs(num - dA).max() < 1e-6 * max(1, np.abs(dA).max())


def test_vdp_sdc_about_origin_is_exact():
    m = vanderpol()
    x = np.array([0.7, -0.4])
    A, _ = m.sdc_fun()(x, np.zeros(2), [0.0], 0.0, m.p_default)
    assert np.allclose(np.asarray(A) @ x, m(x, [0.0]), atol=1e-14)


def test_optimal_control_law():
    m = cr3bp(0.0122, planar=True, a_max=0.03)
    lam = ca.SX.sym("lam", 4)
    f = ca.Function("u", [m.x, lam, m.p], [m.optimal_control_expression(lam)])
    l = np.array([0.3, -0.2, 0.6, 0.8])
    u = np.asarray(f(np.zeros(4), l, m.p_default)).ravel()
    assert np.allclose(u, -l[2:] / np.linalg.norm(l[2:]))
    v = vanderpol()
    lv = ca.SX.sym("lam", 2)
    fv = ca.Function("u", [v.x, lv, v.p], [v.optimal_control_expression(lv)])
    assert float(fv([0, 0], [0.1, 0.5], v.p_default)) == -1.0
    assert float(fv([0, 0], [0.1, -0.5], v.p_default)) == 1.0
    assert m.control_affine and v.control_affine
    fb = ca.Function("ub", [m.x, lam, m.p], [m.optimal_control_expression(lam, kind="box")])
    assert np.array_equal(np.asarray(fb(np.zeros(4), l, m.p_default)).ravel(), [-1.0, -1.0])
    with pytest.raises(ProblemError, match="bounded control set"):
        m.optimal_control_expression(lam, kind="free")


def test_variable_mass_model_consumes_mass():
    units = Units(length=3.844e8, time=375200.0)
    m = cr3bp(0.01215, variable_mass=True, thrust=0.1, isp=3000, units=units)
    x = np.array([1.1, 0, -0.08, 0, -0.19, 0, 1 / 1000.0])
    xdot = m(x, [1.0, 0, 0])
    # dn/dt = T n^2 / c in model time units; in SI: 0.1 / (9.80665 * 3000) / 1000^2 per second
    expected = 0.1 / (9.80665 * 3000) / 1000**2 * units.time
    assert np.isclose(xdot[6], expected, rtol=1e-9)
    # thrust acceleration T n in model units equals 1e-4 m/s^2
    accel = (xdot[3:6] - m(x, [0, 0, 0])[3:6])[0] * units.acceleration
    assert np.isclose(accel, 1e-4, rtol=1e-9)


def test_units_foss_thrust_acceleration():
    a = EARTH_MOON_FOSS.thrust_acceleration(1.1e-3, 14.0)
    assert np.isclose(a, 1.1e-3 / 14 / (3.825e8 / 3.724e5**2))
    with pytest.raises(ProblemError, match="thrust_newton"):
        EARTH_MOON_FOSS.thrust_acceleration(0.0, 14.0)


def test_model_errors():
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    with pytest.raises(ProblemError, match="f must be a column"):
        Model.build("bad", x, u, ca.vertcat(x[0], x[1], u))
    with pytest.raises(ProblemError, match="control_set"):
        Model.build("bad", x, u, ca.vertcat(x[1], u), control_set="disk")
    with pytest.raises(ProblemError, match="p_default"):
        Model.build("bad", x, u, ca.vertcat(x[1], u), p=ca.SX.sym("p", 2), p_default=[1.0])
    with pytest.raises(ProblemError, match="mu"):
        cr3bp(0.7)
    m = vanderpol()
    with pytest.raises(ProblemError, match="order"):
        m.tensor_fun(4)
    with pytest.raises(ProblemError, match="unknown parameter"):
        m.params({"gravity": 1.0})
