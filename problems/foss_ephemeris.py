"""Foss, Rosengren & Biria (AMOS 2024) Sec. 4.2: NRHO Moon flyby in the ephemeris synodic model.

Earth-Moon synodic frame with Sun and Venus perturbations (Foss Eq. 6-7), epoch
2024-05-01 12:00:00 TDB, x1 = [0.91, -0.01, 0.16, 0.03, -0.08, 0.01], grid 0:0.05:1 TU,
1.1 mN on 14 kg, ``||u|| <= 1``; Algorithm 1 with n = 2, h_max = 60.

The paper gives x1 to two digits; ``x0`` and ``epoch`` run the scenario from another initial
state or epoch (``ocreach run nrho-flyby --set problem.x0=[...]``), and :func:`perilune` measures
the close approach of ballistic trajectories (docs/validation/stt-flyby.md, "Sensitivity to
the two-digit x1").
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ocreach.errors import ProblemError
from ocreach.model import Model
from ocreach.problem import Problem, time_grid
from ocreach.units import EARTH_MOON_FOSS

CITATION = "Foss, Rosengren & Biria, AMOS 2024, Sec. 4.2"
EPOCH = "2024-05-01 12:00:00"
BODIES = ("sun", "earth", "moon", "venus")
X0 = np.array([0.91, -0.01, 0.16, 0.03, -0.08, 0.01])
T_MAX_N = 1.1e-3
MASS_KG = 14.0
#: Moon's mean radius, km (a perilune below it is an impact; the model has point masses only)
MOON_RADIUS_KM = 1737.4


def check_x0(x0) -> np.ndarray:
    """``x0`` as a finite float vector of length 6 (synodic position and velocity, DU and DU/TU);
    raises :class:`ProblemError` naming ``x0`` otherwise."""
    try:
        arr = np.asarray(x0, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise ProblemError(f"x0 must be 6 numbers [x, y, z, vx, vy, vz] (DU, DU/TU); got {x0!r}") from None
    if arr.shape != (6,):
        raise ProblemError(f"x0 must be 6 numbers [x, y, z, vx, vy, vz] (DU, DU/TU); got shape "
                           f"{arr.shape}: {x0!r}")
    if not np.all(np.isfinite(arr)):
        raise ProblemError(f"x0 must be finite; got {x0!r}")
    return arr


def flyby_model(epoch: str | float | tuple[float, float] = EPOCH, t_final: float = 1.0, a_max: float = 0.0,
                circular: bool = False) -> Model:
    """The synodic ephemeris model of Foss Eq. 6-7 (Sun, Earth, Moon, Venus; fixed DU/TU of Foss
    Sec. 4) valid for ``t_final`` TU (plus 10 %) after ``epoch`` (TDB); ``circular=True``: the
    Earth-Moon circular stand-in (CR3BP check, Earth and Moon only)."""
    from ocreach.models.ephemeris import ephemeris_synodic

    units = EARTH_MOON_FOSS
    span_days = 1.1 * max(t_final, 0.1) * units.time / 86400.0
    bodies = ("earth", "moon") if circular else BODIES
    return ephemeris_synodic(bodies, epoch, span_days, a_max, units=units, circular=circular)


def nrho_flyby(t_final: float = 1.0, dt: float = 0.05, thrust: float = T_MAX_N, mass: float = MASS_KG,
               input_set: str = "ball", x0: Sequence[float] | None = None, epoch: str = EPOCH) -> Problem:
    """NRHO Moon flyby in the Sun-Earth-Moon-Venus ephemeris synodic model, 1 TU (Foss Sec. 4.2).

    Options: ``t_final`` (TU, default 1; a multiple of ``dt``), ``dt`` (TU, default 0.05),
    ``thrust`` (N), ``mass`` (kg; a_max = thrust / mass), ``input_set`` (``"box"`` or ``"ball"``:
    the thrust set of the ``stt`` method, Foss Eq. 16);
    ``x0``: initial state [x, y, z, vx, vy, vz] (DU, DU/TU; default the paper's two-digit x1);
    ``epoch``: TDB date of t = 0 (default the paper's 2024-05-01 12:00:00).
    """
    if input_set not in ("box", "ball"):  # the STT input set (Foss Eq. 16)
        raise ProblemError(f"input_set must be 'box' or 'ball'; got {input_set!r}")
    x1 = X0.copy() if x0 is None else check_x0(x0)
    units = EARTH_MOON_FOSS
    model = flyby_model(epoch, t_final, units.thrust_acceleration(thrust, mass))
    grid = time_grid(t_final, dt)
    start = "" if x0 is None else f", x0 = {np.array2string(x1, precision=6, separator=', ')}"
    return Problem(
        id="nrho-flyby", model=model, x0=x1, grid=grid, units=units,
        description=f"NRHO Moon flyby, ephemeris synodic model (Sun, Earth, Moon, Venus), epoch "
                    f"{epoch} TDB, T_max = {thrust * 1e3:g} mN, m = {mass:g} kg, {t_final:g} TU{start}",
        citation=CITATION, position_dims=(0, 1, 2), velocity_dims=(3, 4, 5),
        method_options={"stt": {"order": 2, "h_max": 60, "input_set": input_set}},
        extra={"thrust_N": thrust, "mass_kg": mass, "epoch": epoch, "bodies": list(BODIES),
               "x0": x1.tolist()},
    )


def moon_position(model: Model, t) -> np.ndarray:
    """Moon's position (DU) in the synodic frame of :func:`flyby_model` at model times ``t`` (TU),
    shape ``t.shape + (3,)``: on the +x axis at the Earth-Moon barycentre-to-Moon distance (the
    frame's x axis points Earth -> Moon and its origin is the barycentre, Foss Sec. 2.2.2)."""
    info = model.cache.get("frame", {})
    if info.get("kind") != "synodic":
        raise ProblemError(f"model {model.name} is not an ephemeris_synodic model")
    t = np.asarray(t, dtype=float)
    r = model.cache["ephemeris"].position("moon", t * info["tu"], "emb")
    out = np.zeros(t.shape + (3,))
    out[..., 0] = np.linalg.norm(r, axis=-1) / info["du_km"]
    return out


def perilune(model: Model, X0, t_final: float = 1.0, substeps: int = 400) -> dict[str, np.ndarray]:
    """Closest approach to the Moon of ballistic trajectories from ``X0`` (``(6,)`` or ``(N, 6)``)
    over ``[0, t_final]`` TU.

    The states are sampled every ``t_final / substeps`` TU (:func:`ocreach.dynamics.flow.propagate`); the
    minimum of the Moon distance is refined by the parabola through it and its two neighbours.
    Returns arrays (length N): ``distance_km`` and ``time`` (TU) of the minimum, and ``interior``:
    True if it is a perilune inside ``(0, t_final)`` (False: the distance still falls at
    ``t_final``, or rises from t = 0), in which case distance and time are those of the endpoint.
    """
    from ocreach.dynamics.flow import propagate

    X = np.atleast_2d(np.asarray(X0, dtype=float))
    substeps = int(substeps)
    if substeps < 4:
        raise ProblemError(f"substeps must be >= 4; got {substeps}")
    grid = np.array([0.0, float(t_final)])
    _, times, S = propagate(model, X, np.zeros((1, model.n_u)), grid, substeps=substeps)
    S = S.reshape(X.shape[0], times.size, model.n_x)
    du = model.cache["frame"]["du_km"]
    d = np.linalg.norm(S[:, :, :3] - moon_position(model, times)[None], axis=-1) * du
    i = np.argmin(d, axis=1)
    interior = (i > 0) & (i < times.size - 1)
    rows, mid = np.arange(len(i)), np.clip(i, 1, times.size - 2)
    a, b, c = d[rows, mid - 1], d[rows, mid], d[rows, mid + 1]
    curv = a - 2 * b + c
    fit = interior & (curv > 0)  # vertex of the parabola through the three samples
    s = 0.5 * (a - c) / np.where(fit, curv, 1.0)
    h = times[1] - times[0]
    dist = np.where(fit, b - 0.25 * (a - c) * s, d[rows, i])
    tmin = np.where(fit, times[i] + s * h, times[i])
    return {"distance_km": dist, "time": tmin, "interior": interior}


PROBLEMS = {"nrho-flyby": nrho_flyby}
