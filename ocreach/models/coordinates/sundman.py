"""Sundman time transformation ``dt = r^k ds`` about a primary of the CR3BP (Sundman 1912).

The state is unchanged (``z = x``); the independent variable becomes the fictitious time ``s``
with ``dt/ds = r^k``, ``r`` the distance to the chosen primary (the Moon by default): the steps in
``s`` are steps in ``t`` that shrink near the primary as ``r^k``, the transformed dynamics
``dx/ds = r^k f`` lose ``k`` powers of the ``1 / r^2`` singularity (``k = 1``: the classical
transformation, ``k = 3/2``: the intermediate anomaly; ``k = 2`` makes the Kepler term bounded).
The time is a state, so the sets at the problem's grid times are cut out of the ``s``-tubes
(:func:`ocreach.models.coordinates.convert.slice_at`).  A method then steps by ``s``, i.e. with
steps in time proportional to ``r^k`` -- what an adaptive step-size control would do near
perilune, decided once from the geometry.
"""
from __future__ import annotations

import casadi as ca

from ocreach.errors import ProblemError
from ocreach.model import Model
from ocreach.models.coordinates.chart import Chart

CITATION = ("K. F. Sundman, \"Memoire sur le probleme des trois corps\", Acta Math. 36 (1912); "
            "V. Szebehely, Theory of Orbits (1967), Ch. 3")


def cr3bp_fit(model: Model) -> tuple[bool, str]:
    """``(True, "")`` if ``model`` is a CR3BP model (rotating barycentric frame, parameter mu)."""
    if not model.name.startswith("cr3bp") or "mu" not in model.param_names:
        return False, (f"the Sundman transformation about a primary needs a CR3BP model (primaries "
                       f"at (-mu, 0, 0) and (1 - mu, 0, 0), parameter mu); model {model.name!r} "
                       f"is not one")
    return True, ""


def sundman_chart(model: Model, *, k: float = 1.0, body: str = "moon") -> Chart:
    """``dt = r^k ds``, ``r`` the distance to ``body`` (``"moon"`` or ``"earth"``) of a CR3BP model."""
    ok, why = cr3bp_fit(model)
    if not ok:
        raise ProblemError(why)
    if not 0 < k <= 2:
        raise ProblemError(f"sundman: k must be in (0, 2]; got {k!r}")
    mu = model.p[model.param_names.index("mu")]
    planar = model.name.startswith("cr3bp-planar")
    x = model.x
    xb = 1 - mu if body == "moon" else -mu
    d = 2 if planar else 3
    rel = ca.vertcat(x[0] - xb, *[x[i] for i in range(1, d)])
    r = ca.norm_2(rel)
    z = ca.SX.sym("x", model.n_x)
    return Chart(
        name="sundman", model=model, z=z, phi=x, psi=z, names=model.state_names,
        units=model.state_units, valid_x=ca.vertcat(r), valid_z=ca.substitute(ca.vertcat(r), x, z),
        valid_why=f"the transformation is singular at the centre of the {body}",
        time_scale=r**k, s_name="s", s_unit=f"TU/DU^{k:g}",
        description=f"Sundman time transformation dt = r^{k:g} ds about the {body}",
        citation=CITATION)
