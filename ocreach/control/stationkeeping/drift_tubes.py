"""Drift-tube schedules for event-triggered station keeping (Patel & Subbarao, "Station-keeping in
the near rectilinear halo orbit": a zero-thrust reachable tube about the reference from the initial
deviation set under the disturbance ``W``, refreshed at every apolune).

:func:`drift_schedule` builds the :class:`~ocreach.control.stationkeeping.tubes.TubeSchedule` of a periodic
reference from a linearised or a sound tube (``taylor``/``sdc``, optionally with the linear tube
where the method fails, or the adaptive partition of
:func:`~ocreach.control.stationkeeping.tubes.sound_drift_partition`, cached per process by
:func:`partition_key`); :func:`ephemeris_drift_schedule` the tubes along the ephemeris-corrected
reference; :func:`tube_log` says which tube was used per refresh.
"""
from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable
from typing import Any

import numpy as np

from ocreach.control.reference import TrackingReference
from ocreach.control.stationkeeping.ephemeris_plant import EphemerisPlant
from ocreach.control.stationkeeping.paper import PAPER_N, PAPER_W, paper_initial_set
from ocreach.control.stationkeeping.tubes import (
    ADAPTIVE_TUBE_OPTIONS,
    Tube,
    TubeSchedule,
    linear_drift_tube,
    linear_fallback,
    reach_drift_tube,
    refresh_phase,
    sound_drift_partition,
)
from ocreach.errors import ProblemError, SolverError

MEMBERSHIPS = ("zonotope", "box")
#: Tube sources: the linearised tube, a sound method, or a sound method with the linear tube
#: wherever it fails (each tube's source and guarantee are logged per refresh).
FALLBACK_SOURCES = ("taylor-or-linear", "sdc-or-linear")
TUBE_SOURCES = ("linear", "taylor", "sdc") + FALLBACK_SOURCES


def _initial_generators(problem, initial: Any) -> Any:
    """The tubes' initial deviation set: ``"paper"`` (Patel & Subbarao's ``G_pos``, ``G_vel``,
    :func:`~ocreach.control.stationkeeping.paper.paper_initial_set`) or the generators given."""
    if isinstance(initial, str):
        if initial != "paper":
            raise ProblemError(f"initial must be 'paper' or generators; got {initial!r}")
        return paper_initial_set(problem)
    return initial


def as_box(tube: Tube) -> Tube:
    """The tube's interval hulls as a tube (diagonal generators): the paper's Fig. 7 boxes."""
    hw = tube.half_widths()
    G = np.einsum("kn,nm->knm", hw, np.eye(tube.dim))
    return dataclasses.replace(tube, generators=G, source=f"interval hull of {tube.source}")


def _membership_wrap(membership: str) -> Callable[[Tube], Tube]:
    """The tube wrapper for ``membership`` (checked): :func:`as_box` for ``"box"``, else the
    identity."""
    if membership not in MEMBERSHIPS:
        raise ProblemError(f"membership must be one of {MEMBERSHIPS}; got {membership!r}")
    return as_box if membership == "box" else (lambda t: t)


def drift_schedule(problem, reference: TrackingReference, *, initial: Any = "paper",
                   disturbance: Any = PAPER_W, membership: str = "box", phase: int | str = "apolune",
                   every: int = 1, lookahead: int = PAPER_N, source: str = "linear",
                   order: float = 5.0, tube_options: dict | None = None,
                   interval: int | str | None = None) -> TubeSchedule:
    """Drift tubes (zero thrust) about the reference, refreshed at ``phase`` every ``every``
    revolutions; each covers its interval plus ``lookahead`` steps.

    ``source``: ``"linear"`` (:func:`~ocreach.control.stationkeeping.tubes.linear_drift_tube`, not guaranteed),
    ``"taylor"`` / ``"sdc"`` (:func:`~ocreach.control.stationkeeping.tubes.reach_drift_tube`, guaranteed; with
    ``tube_options`` for the method, and ``interval`` for tubes shorter than a revolution; a
    method that cannot enclose the interval raises), or ``"taylor-or-linear"`` /
    ``"sdc-or-linear"`` (the sound tube where the method succeeds, else the linear one, its
    ``meta["fallback_reason"]`` the method's error).  :func:`tube_log` lists which was used.
    ``interval="adaptive"`` (with ``"taylor"`` / ``"sdc"``): guaranteed tubes over every whole
    revolution, each restarted from the initial set where the previous one stops
    (:func:`~ocreach.control.stationkeeping.tubes.sound_drift_partition`: on the NRHO a short tube across
    perilune); computed once for one period from ``phase`` and re-used, shifted, every period.
    ``membership``: ``"zonotope"`` (exact gauge of the set) or
    ``"box"`` (its interval hull).
    """
    wrap = _membership_wrap(membership)
    G0 = _initial_generators(problem, initial)
    if isinstance(interval, str):
        if interval != "adaptive" or source not in ("taylor", "sdc"):
            raise ProblemError(f"interval must be a number of steps, None (every revolution) or "
                               f"'adaptive' (with tube source 'taylor' or 'sdc'); got "
                               f"{interval!r} with source {source!r}")
        return _adaptive_schedule(problem, reference, G0, disturbance, source, wrap, phase,
                                  tube_options or {})
    length = (every * reference.n_steps if interval is None else int(interval)) + lookahead + 1

    def linear(k: int) -> Tube:
        return linear_drift_tube(reference, k, length, G0, disturbance, problem.velocity_dims,
                                 order=order)

    def sound(k: int, method: str) -> Tube:
        return reach_drift_tube(problem, reference, k, length, G0, disturbance, method,
                                **(tube_options or {}))

    if source == "linear":
        build = linear
    elif source in ("taylor", "sdc"):
        def build(k: int) -> Tube:
            return sound(k, source)
    elif source in FALLBACK_SOURCES:
        method = source.split("-")[0]

        def build(k: int) -> Tube:
            try:
                return sound(k, method)
            except SolverError as err:  # e.g. taylor stops before perilune on the NRHO
                return linear_fallback(linear(k), method, err)
    else:
        raise ProblemError(f"tube source must be one of {list(TUBE_SOURCES)}; got {source!r}")
    return TubeSchedule(lambda k: wrap(build(k)), reference, phase=phase, every=every,
                        lookahead=lookahead, reuse=True, interval=interval)


#: adaptive tube partitions of this process, by :func:`partition_key` (they are deterministic:
#: several runs on the same reference, e.g. one per plant, compute them once)
_PARTITIONS: dict[str, list[Tube]] = {}


def partition_key(problem, reference: TrackingReference, phase: int, G0: Any, disturbance: Any,
                  method: str, options: dict) -> str:
    """Everything :func:`~ocreach.control.stationkeeping.tubes.sound_drift_partition` depends on, hashed: the
    model it runs on (the reference's, :func:`~ocreach.control.stationkeeping.tubes._drift_problem`), the
    parameters, the reference states and times, the sets, the method and options.
    Arrays enter by dtype, shape and bytes (:func:`_hash_value`), never by ``repr``, which numpy
    shortens with ``...`` for large arrays (two different arrays would share a key)."""
    h = hashlib.sha256()
    _hash_value(h, (reference.model.name, reference.model.n_x, problem.model.name, problem.id,
                    problem.control_set.kind, phase, method, options, disturbance))
    for a in (reference.X, reference.time(np.arange(reference.n_steps + 1)), reference.params,
              problem.params, G0):
        _hash_value(h, np.asarray(a, float))
    return h.hexdigest()


def _hash_value(h: Any, value: Any) -> None:
    """Feed ``value`` into the hash ``h`` unambiguously: numeric numpy arrays, scalars, lists and
    tuples by dtype, shape and the bytes of the data; dicts by their items sorted by key; other
    sequences item by item; anything else by its ``repr`` (with its length, so no two values run
    together)."""
    if isinstance(value, dict):
        h.update(b"dict %d;" % len(value))
        for k in sorted(value, key=repr):
            _hash_value(h, k)
            _hash_value(h, value[k])
        return
    if isinstance(value, (np.ndarray, np.generic, list, tuple)):
        try:
            a = np.asarray(value)
        except ValueError:  # ragged
            a = None
        if a is not None and a.dtype.kind in "biufc":  # numbers (strings: item by item)
            a = np.ascontiguousarray(a)
            h.update(f"array {a.dtype.str} {a.shape};".encode())
            h.update(a.tobytes())
            return
        if isinstance(value, (np.ndarray, np.generic)):  # strings or objects: as Python values
            _hash_value(h, value.tolist())
            return
        h.update(b"seq %d;" % len(value))
        for v in value:
            _hash_value(h, v)
        return
    r = repr(value).encode()
    h.update(b"repr %d;" % len(r))
    h.update(r)


def _adaptive_schedule(problem, reference: TrackingReference, G0: Any, disturbance: Any,
                       method: str, wrap: Callable[[Tube], Tube], phase: int | str,
                       options: dict) -> TubeSchedule:
    """Guaranteed tubes over one period from ``phase``, refreshed where the sound method stops
    (:func:`~ocreach.control.stationkeeping.tubes.sound_drift_partition`), re-used every period.  MPC windows that
    cross a refresh take the next tube's sets, so no tube needs a lookahead."""
    M = reference.n_steps
    p0 = refresh_phase(reference, phase)
    opts = {**ADAPTIVE_TUBE_OPTIONS, **options}
    key = partition_key(problem, reference, p0, G0, disturbance, method, opts)
    tubes = _PARTITIONS.get(key)
    if tubes is None:
        tubes = sound_drift_partition(problem, reference, p0, p0 + M, G0, disturbance,
                                      method, **opts)
        if len(_PARTITIONS) >= 8:
            _PARTITIONS.pop(next(iter(_PARTITIONS)))
        _PARTITIONS[key] = tubes
    by_phase = {t.k0 % M: wrap(t) for t in tubes}

    def build(k: int) -> Tube:
        return by_phase[k % M].shifted(k)

    return TubeSchedule(build, reference, phases=sorted(by_phase), reuse=True)


def tube_log(schedule: TubeSchedule, n_steps: int) -> list[dict[str, Any]]:
    """Which tube was used when: one entry per refresh interval touching steps ``0..n_steps-1``
    (``refresh_step``, the steps ``[first, end)`` it was active for, the same in revolutions,
    ``source``, ``guaranteed``, and ``fallback_reason`` when a sound method failed and the
    linear tube stood in)."""
    M = schedule.reference.revolution_steps
    out = []
    for r in schedule.refresh_steps(n_steps):
        t = schedule.tube(r)
        a, b = max(r, 0), min(schedule.next_refresh(r), n_steps)
        out.append({"refresh_step": int(r), "steps": [int(a), int(b)],
                    "revolutions": [a / M, b / M], "source": t.source,
                    "guaranteed": bool(t.guaranteed),
                    "fallback_reason": (t.meta or {}).get("fallback_reason")})
    return out


def ephemeris_drift_schedule(problem, ref: TrackingReference, initial: Any, disturbance: Any,
                             membership: str, phase: Any, source: str, interval: Any,
                             options: dict | None, source_given: bool, n_p: int,
                             plant: EphemerisPlant) -> TubeSchedule:
    """Drift tubes along the ephemeris-corrected reference
    (:func:`~ocreach.control.stationkeeping.ephemeris_tubes.along_reference_schedule`: refreshed at every
    apolune and where the sound method stops, nothing re-used).  A sound source taken from the
    problem's defaults (not given) becomes ``"<method>-or-linear"``: guaranteed where the method
    encloses, the linearised tube (labelled) where it cannot.  The sound method runs on the
    plant's frame model restricted to each interval (:meth:`EphemerisPlant.frame_model_on`: the
    same function there up to a rigorously bounded difference added to W, re-expanded on the
    window without the ``if_else`` between DE421 fit pieces: docs/intervals.md)."""
    from ocreach.control.stationkeeping.ephemeris_tubes import along_reference_schedule

    wrap = _membership_wrap(membership)
    if phase != "apolune":
        raise ProblemError(f"phase along the ephemeris-corrected reference must be 'apolune' (the "
                           f"tubes restart at every apolune); got {phase!r}")
    if interval not in (None, "adaptive"):
        raise ProblemError(f"tube_interval along the ephemeris-corrected reference must be None "
                           f"or 'adaptive' (every apolune and where the sound method stops); "
                           f"got {interval!r}")
    if not source_given and source in ("taylor", "sdc"):
        source = f"{source}-or-linear"
    G0 = _initial_generators(problem, initial)
    # the run's steps and the last MPC window (n_p steps after the last solve)
    end = min(ref.n_steps, ref.n_default + n_p + 1)
    return along_reference_schedule(problem, ref, G0, disturbance, source, wrap=wrap,
                                    options=options, end=end, model_on=plant.frame_model_on)


__all__ = ["ADAPTIVE_TUBE_OPTIONS", "FALLBACK_SOURCES", "MEMBERSHIPS", "TUBE_SOURCES", "as_box",
           "drift_schedule", "ephemeris_drift_schedule", "partition_key", "tube_log"]
