"""Drift tubes along a non-periodic reference (the ephemeris-corrected NRHO), for event-triggered
and tube MPC on the DE421 plant.

The periodic schedule of :func:`~ocreach.control.stationkeeping.drift_tubes.drift_schedule` computes the
tubes of one period and re-uses them shifted; an ephemeris-corrected orbit
(:mod:`ocreach.control.stationkeeping.ephemeris_reference`) repeats no period, so here every tube is computed for
its own stretch of the reference, in the reference's own model (the plant's dynamics in the CR3BP
frame, :meth:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant.frame_model`):

* the run is cut at every apolune of the reference (:func:`apolune_steps`; Patel & Subbarao: "At
  each apolune ... a tube of forward reachable sets"), the first interval starting at step 0;
* on each interval the sound method is restarted from the initial deviation set where it stops
  (:func:`~ocreach.control.stationkeeping.tubes.sound_drift_partition`, the rule of the periodic
  ``tube_interval="adaptive"`` schedule), and the tubes are guaranteed;
* where the sound method cannot enclose the interval (it fails, or refuses the model), the
  ``*-or-linear`` sources use the linearised tube of that interval
  (:func:`~ocreach.control.stationkeeping.tubes.linear_drift_tube`, NOT guaranteed), its
  ``meta["fallback_reason"]`` the method's message, so metrics.json says per refresh interval
  which tube was used (:func:`~ocreach.control.stationkeeping.drift_tubes.tube_log`).

The frame model of a long run joins two DE421 fit pieces in time with ``if_else``
(:mod:`ocreach.ephemeris`): ``taylor`` accepts a switch on time alone but fails on a step across
it, and the interval bounds of the pieces' degree-48 basis over a step are loose, so the sound
method runs per interval on ``model_on(t_a - dt, t_b + dt)``
(:meth:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant.frame_model_on`: the same function on
that window as one polynomial without the ``if_else``, also where the window reaches across
the blend of two pieces, up to a difference bounded rigorously and added to the disturbance:
:func:`with_model_error`, :func:`checked_model_error`; docs/intervals.md "Ephemeris positions
over a time interval").
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from ocreach.control.reference import TrackingReference
from ocreach.control.stationkeeping.tubes import (
    ADAPTIVE_TUBE_OPTIONS,
    Tube,
    TubeSchedule,
    linear_drift_tube,
    linear_fallback,
    secondary_distance,
    sound_drift_partition,
)
from ocreach.errors import ProblemError, SolverError, check_count

#: tube sources accepted along a non-periodic reference
SOURCES = ("linear", "taylor", "sdc", "taylor-or-linear", "sdc-or-linear")


def apolune_steps(reference: TrackingReference, secondary: tuple[float, ...] | None = None
                  ) -> np.ndarray:
    """Steps of the apolunes of a multi-revolution reference: the largest distance from the
    secondary (``(1 - mu, 0, 0)`` for a model with ``mu``) in each window of one revolution
    centred on the previous apolune's next expected one, starting from the largest distance in
    the first revolution.  Returns the increasing steps (those within a quarter revolution of the
    reference's end are kept: the caller decides)."""
    M = reference.revolution_steps
    d = secondary_distance(reference, secondary, "apolune_steps")
    N = d.size
    out = [int(np.argmax(d[: min(M, N)]))]
    while True:
        lo, hi = out[-1] + M // 2, out[-1] + (3 * M) // 2
        if lo >= N:
            break
        out.append(lo + int(np.argmax(d[lo: min(hi, N)])))
    return np.unique(np.array(out, dtype=int))


def refresh_starts(reference: TrackingReference, end: int) -> list[int]:
    """Refresh steps ``0, a_1, a_2, ...``: step 0 and every apolune ``a_i`` at least a quarter
    revolution after the previous refresh and before ``end``."""
    M = reference.revolution_steps
    starts = [0]
    for a in apolune_steps(reference):
        if a - starts[-1] >= M // 4 and a < end - 1:
            starts.append(int(a))
    return starts


def sound_reference(reference: TrackingReference, a: int, b: int, method: str,
                    model_on: Callable[[float, float], Any] | None) -> TrackingReference:
    """The reference with the model the sound method runs on over steps ``a .. b``: its own, or
    ``model_on(t_a - dt, t_b + dt)`` (the same function on that time interval up to its bounded
    difference, without the ``if_else`` between ephemeris fit pieces, e.g.
    :meth:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant.frame_model_on`).  Raises
    :class:`ProblemError` saying why the method cannot run on it."""
    from ocreach.reach.taylor import check_smooth

    model = reference.model
    if model_on is not None:
        t_a, t_b = float(reference.time(a)), float(reference.time(b))
        model = model_on(t_a - reference.dt, t_b + reference.dt)
    try:
        check_smooth(model)
    except ProblemError as err:
        raise ProblemError(f"{method} refuses the model: " + " ".join(str(err).split())) from err
    if model is reference.model:
        return reference
    return dataclasses.replace(reference, model=model, A=None, B=None, cache={})


def with_model_error(problem, disturbance: Any, model_error: dict | None) -> Any:
    """The disturbance ``W`` plus the bound on the window model's acceleration error
    (``model_error["acceleration"]``, a 2-norm, so a box of that radius on the velocity rates,
    :meth:`~ocreach.control.stationkeeping.ephemeris_plant.EphemerisPlant.frame_model_on`): a number ``w``
    becomes ``w + e``, any other disturbance the zonotope sum.  Unchanged without an error."""
    if model_error is None or model_error["acceleration"] == 0.0:
        return disturbance
    e = float(model_error["acceleration"])
    if disturbance is not None and np.ndim(disturbance) == 0 and not hasattr(disturbance, "dim"):
        return float(disturbance) + e
    from ocreach.reach.taylor import disturbance_zonotope
    from ocreach.sets import Zonotope

    n = problem.model.n_x
    box = np.zeros((n, len(problem.velocity_dims)))
    box[list(problem.velocity_dims), np.arange(box.shape[1])] = e
    W = disturbance_zonotope(problem, disturbance)
    if W is None:
        return Zonotope(np.zeros(n), box)
    return Zonotope(W.c, np.hstack([W.G, box]))


def checked_model_error(tube: Tube, model_error: dict | None) -> Tube:
    """``tube`` with ``meta["model_error"]``, after checking that its sound method's flowpipe
    (``meta["flowpipe_hull"]``, every trajectory between the grid points) stays within
    ``model_error["radius"]`` of the Moon, where the window model's error bound holds; raises
    :class:`SolverError` if it does not (or cannot be checked)."""
    if model_error is None:
        return tube
    hull = (tube.meta or {}).get("flowpipe_hull")
    if hull is None:
        raise SolverError(f"tube from step {tube.k0}: no flowpipe to check the window model's "
                          f"error bound against")
    centre = np.asarray(model_error["centre"], float)
    lo, hi = np.asarray(hull[0][:3]) - centre, np.asarray(hull[1][:3]) - centre
    far = float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi)))) * (1 + 1e-9)
    if not far < model_error["radius"]:
        raise SolverError(f"tube from step {tube.k0} reaches {far:.6g} DU from the Moon; the "
                          f"window model's error bound holds within {model_error['radius']:.6g}")
    info = {"acceleration": float(model_error["acceleration"]),
            "radius": float(model_error["radius"]), "max_distance": far,
            "position_km": dict(model_error["position_km"])}
    return dataclasses.replace(tube, meta={**tube.meta, "model_error": info})


def interval_tubes(problem, reference: TrackingReference, a: int, b: int, G0: Any,
                   disturbance: Any, source: str, options: dict,
                   model_on: Callable[[float, float], Any] | None = None) -> list[Tube]:
    """Tubes covering steps ``a .. b - 1``: the sound partition (``taylor`` / ``sdc``, on
    :func:`sound_reference`), or the linear tube (``linear``, or the fallback of
    ``*-or-linear`` with the reason)."""
    method = source.split("-")[0]
    if source != "linear":
        try:
            sound_ref = sound_reference(reference, a, b, method, model_on)
        except SolverError as err:  # the window model's error bound cannot be computed there
            if source == method:
                raise
            failure = err
        except ProblemError as err:
            if source == method:
                raise ProblemError(f"tube source {source!r} cannot enclose the drift along "
                                   f"'{reference.name}' at steps {a}..{b}: {err}; use "
                                   f"{method + '-or-linear'!r} (linearised tube where it "
                                   f"cannot) or 'linear'") from err
            failure = err
        else:
            model_error = sound_ref.model.cache.get("window_error")
            try:
                # max_tubes: one per step unless the options cap it (as in the periodic schedule)
                tubes = sound_drift_partition(problem, sound_ref, a, b, G0,
                                              with_model_error(problem, disturbance, model_error),
                                              method, **{"max_tubes": b - a, **options})
                return [checked_model_error(t, model_error) for t in tubes]
            except SolverError as err:
                if source == method:
                    raise
                failure = err
    lin = linear_drift_tube(reference, a, b - a, G0, disturbance, problem.velocity_dims)
    if source == "linear":
        return [lin]
    return [linear_fallback(lin, method, failure)]


def along_reference_schedule(problem, reference: TrackingReference, G0: Any, disturbance: Any,
                             source: str, *, wrap=lambda t: t, options: dict | None = None,
                             end: int | None = None,
                             model_on: Callable[[float, float], Any] | None = None
                             ) -> TubeSchedule:
    """A :class:`~ocreach.control.stationkeeping.tubes.TubeSchedule` of drift tubes along the non-periodic
    ``reference`` up to step ``end`` - 1 (default: its last step), refreshed at step 0, at every
    apolune and where the sound method stops (module docstring).  ``wrap`` maps each tube (e.g.
    to its interval hull); ``model_on``: the sound method's model per interval
    (:func:`sound_reference`).  All tubes are computed here, once."""
    if reference.periodic:
        raise ProblemError(f"along_reference_schedule is for a non-periodic reference; "
                           f"'{reference.name}' is periodic (use drift_schedule)")
    if source not in SOURCES:
        raise ProblemError(f"tube source along a non-periodic reference must be one of "
                           f"{list(SOURCES)}; got {source!r}")
    end = reference.n_steps if end is None else check_count("end (step after the last tube step)",
                                                            end, 2)
    if not 2 <= end <= reference.n_steps:
        raise ProblemError(f"end (step after the last tube step) must be in 2..{reference.n_steps}; "
                           f"got {end}")

    opts = {**ADAPTIVE_TUBE_OPTIONS, **(options or {})}
    starts = refresh_starts(reference, end)
    tubes: dict[int, Tube] = {}
    for a, b in zip(starts, starts[1:] + [end], strict=True):
        for t in interval_tubes(problem, reference, a, b, G0, disturbance, source, opts,
                                model_on):
            tubes[t.k0] = wrap(t)
    return TubeSchedule(tubes.__getitem__, reference, starts=sorted(tubes), end=end)


__all__ = ["SOURCES", "along_reference_schedule", "apolune_steps", "checked_model_error",
           "interval_tubes", "refresh_starts", "sound_reference", "with_model_error"]
