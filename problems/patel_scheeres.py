"""Scenarios of Patel & Scheeres, "Rapidly and automatically estimating reachability of electric
propulsion spacecraft" (2022), Sec. 6, cases 1-5.

Dynamics: Eq. 11 (Sun, Earth and Moon point masses from DE421, Earth-centred ECLIPJ2000 axes,
inverse mass ``n``), :func:`ocreach.models.ephemeris.ephemeris_inertial`.  Isp 3000 s, 200
segments of 7200 s (``-7200 s`` for the controllability cases 3 and 5), initial mass 1000 kg.
Epochs are TDB seconds past J2000 as the paper gives them (Fig. 1, 2, 6).  Units: DU = 384400 km,
TU such that ``mu_earth = 1`` (about 3.75e5 s), mass unit 1000 kg (so ``n(0) = 1``).

Cases 4 and 5 add an initial position uncertainty on a sphere of 500 km / 5000 km (Eq. 21-23) as an
:class:`~ocreach.sets.ellipsoid.Ellipsoid` ``initial_set`` (degenerate in velocity and mass), which
ffoe/ole/bvp turn into the transversality offset of Eq. 23.

Note: the paper used DE440 and SPICE; DE421 differs from DE440 by metres for the Moon over these
epochs, far below what the figures resolve.
"""
from __future__ import annotations

import numpy as np

from ocreach.errors import ProblemError, check_positive
from ocreach.problem import Problem

CITATION = "Patel & Scheeres 2022"
#: the options paragraph of every case's docstring (read by ``ocreach problem ID``)
OPTIONS_DOC = ("Options: ``thrust`` (N, the maximum thrust T_max), ``epoch_s`` (TDB seconds past "
               "J2000 of t = 0), ``segments`` (the number of grid steps), ``segment_s`` (s, the "
               "step; negative for a controllable set){sigma}.")
SIGMA_DOC = ", ``sigma_km`` (km, the radius of the initial position sphere)"
ISP_S = 3000.0
MASS_KG = 1000.0
SEGMENTS = 200
SEGMENT_S = 7200.0
BODIES = ("sun", "earth", "moon")

#: (epoch, TDB seconds past J2000; x0 in km, km/s, kg) of Fig. 1, 2 and 6.
CASE1 = (64.1, [0.0, 210820.0, 0.0, 0.753136347, 0.0, 0.0, 1000.0])
CASE2 = (1072864.169, [-379476.0, 0.0, 0.0, 0.0, -0.561354689, 0.0, 1000.0])
CASE3 = (2512864.169, [-314562.64, -329219.31, 237676.53, 0.5262560, -0.65552567495712999,
                       0.1763679, 1000.0])

_OPTIONS = {"ffoe": {"samples": 100, "dims": "position"},
            "ole": {"samples": 100, "dims": "position"},
            "mc": {"samples": 500},
            "taylor": {"growth_tol": 0.1}}  # 2 h steps through perigee: halved where needed


def _case(pid: str, epoch_s: float, state, thrust: float, *, segments: int, segment_s: float,
          sigma_km: float = 0.0, description: str, figures: str) -> Problem:
    from ocreach.ephemeris import epoch_from_et
    from ocreach.models.ephemeris import ephemeris_inertial, inertial_state_from_si

    check_positive("thrust (T_max, N)", thrust)
    if int(segments) < 1:
        raise ProblemError(f"segments must be >= 1; got {segments!r}")
    if not np.isfinite(segment_s) or segment_s == 0:
        raise ProblemError(f"segment_s must be a non-zero number of seconds; got {segment_s!r}")
    if not np.isfinite(epoch_s):
        raise ProblemError(f"epoch_s must be finite TDB seconds past J2000; got {epoch_s!r}")
    span_days = segments * segment_s / 86400.0
    model = ephemeris_inertial(BODIES, "earth", epoch_from_et(epoch_s), span_days, thrust, ISP_S,
                               MASS_KG, frame="eclipj2000")
    state = np.asarray(state, dtype=float)
    x0 = inertial_state_from_si(model, state[:3], state[3:6], state[6])
    units = model.units
    grid = np.arange(segments + 1) * (segment_s / units.time)
    initial_set = None
    if sigma_km > 0:
        from ocreach.sets.ellipsoid import Ellipsoid

        r = sigma_km * 1e3 / units.length
        initial_set = Ellipsoid(x0, np.diag([r * r] * 3 + [0.0] * 4))
    return Problem(
        id=pid, model=model, x0=x0, grid=grid, units=units, initial_set=initial_set,
        description=f"{description}; T_max = {thrust:g} N, Isp {ISP_S:g} s, {segments} x "
                    f"{segment_s:g} s, epoch ET {epoch_s} s",
        citation=f"{CITATION}, {figures}", position_dims=(0, 1, 2), velocity_dims=(3, 4, 5),
        method_options={k: dict(v) for k, v in _OPTIONS.items()},
        extra={"epoch_et_s": epoch_s, "thrust_N": thrust, "isp_s": ISP_S, "mass_kg": state[6],
               "sigma_km": sigma_km, "segment_s": segment_s, "bodies": BODIES,
               "frame": "eclipj2000", "central": "earth"},
    )


def elliptic_earth(thrust: float = 0.01, epoch_s: float = CASE1[0], segments: int = SEGMENTS,
                   segment_s: float = SEGMENT_S) -> Problem:
    """Case 1: elliptic Earth orbit, 0.01 N, Sun-Earth-Moon DE421, 200 x 7200 s (Patel & Scheeres Fig. 1)."""
    return _case("elliptic-earth", epoch_s, CASE1[1], thrust, segments=segments, segment_s=segment_s,
                 description="case 1: elliptic Earth orbit, no significant multi-body effects",
                 figures="Sec. 6.1, Fig. 1")


def lunar_flyby(thrust: float = 0.02, epoch_s: float = CASE2[0], segments: int = SEGMENTS,
                segment_s: float = SEGMENT_S) -> Problem:
    """Case 2: lunar flyby reachable set, 0.02 N, 200 x 7200 s (Patel & Scheeres Fig. 2-5)."""
    return _case("lunar-flyby", epoch_s, CASE2[1], thrust, segments=segments, segment_s=segment_s,
                 description="case 2: close lunar flyby (reachable set)", figures="Sec. 6.2, Fig. 2-5")


def lunar_flyby_backward(thrust: float = 0.02, epoch_s: float = CASE3[0], segments: int = SEGMENTS,
                         segment_s: float = -SEGMENT_S) -> Problem:
    """Case 3: case 2 backward from its end, controllable set, -7200 s segments (Patel & Scheeres Fig. 6)."""
    return _case("lunar-flyby-backward", epoch_s, CASE3[1], thrust, segments=segments,
                 segment_s=segment_s, description="case 3: lunar flyby run backward (controllable set)",
                 figures="Sec. 6.3, Fig. 6")


def lunar_flyby_uncertain(thrust: float = 0.02, sigma_km: float = 500.0, epoch_s: float = CASE2[0],
                          segments: int = SEGMENTS, segment_s: float = SEGMENT_S) -> Problem:
    """Case 4: case 2 with the initial position on a 500 km sphere (Patel & Scheeres Fig. 7-8)."""
    check_positive("sigma_km", sigma_km)
    return _case("lunar-flyby-uncertain", epoch_s, CASE2[1], thrust, segments=segments,
                 segment_s=segment_s, sigma_km=sigma_km,
                 description=f"case 4: lunar flyby, initial position on a {sigma_km:g} km sphere",
                 figures="Sec. 6.4, Fig. 7-8")


def lunar_flyby_backward_uncertain(thrust: float = 0.02, sigma_km: float = 5000.0,
                                   epoch_s: float = CASE3[0], segments: int = SEGMENTS,
                                   segment_s: float = -SEGMENT_S) -> Problem:
    """Case 5: case 3 with the position on a 5000 km sphere (Patel & Scheeres Fig. 9-11)."""
    check_positive("sigma_km", sigma_km)
    return _case("lunar-flyby-backward-uncertain", epoch_s, CASE3[1], thrust, segments=segments,
                 segment_s=segment_s, sigma_km=sigma_km,
                 description=f"case 5: backward lunar flyby, position on a {sigma_km:g} km sphere",
                 figures="Sec. 6.5, Fig. 9-11")


for _f in (elliptic_earth, lunar_flyby, lunar_flyby_backward):
    _f.__doc__ += "\n\n    " + OPTIONS_DOC.format(sigma="")
for _f in (lunar_flyby_uncertain, lunar_flyby_backward_uncertain):
    _f.__doc__ += "\n\n    " + OPTIONS_DOC.format(sigma=SIGMA_DOC)

PROBLEMS = {
    "elliptic-earth": elliptic_earth,
    "lunar-flyby": lunar_flyby,
    "lunar-flyby-backward": lunar_flyby_backward,
    "lunar-flyby-uncertain": lunar_flyby_uncertain,
    "lunar-flyby-backward-uncertain": lunar_flyby_backward_uncertain,
}
