"""Coordinates a problem can be propagated in, and the sound way back to the model's own.

A coordinate *spec* is a name with optional settings, ``"NAME"`` or ``"NAME:key=value,key=value"``
(``ocreach run earth-mars -m taylor --set coordinates=mee-longitude``, ``ocreach.reach(p, "taylor",
coordinates="mee")``, or the problem override ``--set problem.coordinates=mee``):

============================  =====================================================================
``cartesian``                 the model's own state (default; nothing is transformed)
``mee``                       modified equinoctial elements, time independent (two-body models)
``mee-longitude``             modified equinoctial elements, true longitude independent
``sundman``                   Sundman time transformation ``dt = r^k ds`` about a primary (CR3BP)
============================  =====================================================================

Settings every chart takes: ``pieces`` (most pieces a converted set may be split into, default
:data:`~ocreach.models.coordinates.convert.MAX_PIECES`), ``tol`` (relative size of the conversion's
quadratic term above which a set is split, default
:data:`~ocreach.models.coordinates.convert.SPLIT_TOL`).  Time-transformed charts also take ``steps``
(steps of the new independent variable per grid step of the problem, default 1) and ``margin``
(how far past the nominal end the new variable is propagated, as a fraction, default 0.15), and
``sundman`` takes ``k`` (exponent, default 1) and ``body`` (``moon`` or ``earth``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ocreach.errors import ProblemError, UnknownNameError
from ocreach.model import Model
from ocreach.models.coordinates.chart import Chart
from ocreach.models.coordinates.convert import MAX_PIECES, SPLIT_TOL, MapEnclosure
from ocreach.models.coordinates.mee import mee_chart, reference_longitude, two_body_fit

#: name -> one-line description (``ocreach methods`` and error messages list them)
COORDINATES: dict[str, str] = {
    "cartesian": "the model's own state (no transformation)",
    "mee": "modified equinoctial elements (Walker et al. 1985), time independent; two-body models",
    "mee-longitude": "modified equinoctial elements, true longitude as independent variable; "
                     "two-body models",
    "sundman": "Sundman time transformation dt = r^k ds about a primary (k = 1 default, body = "
               "moon); CR3BP models",
}
TIME_TRANSFORMED = ("mee-longitude", "sundman")
#: setting -> (default, kind, description)
SETTINGS: dict[str, tuple[Any, str, str]] = {
    "pieces": (MAX_PIECES, "count", "most pieces a set converted back may be split into (>= 1)"),
    "tol": (SPLIT_TOL, "positive", ("split a set before converting it back while the quadratic "
            "term exceeds tol times the linear part (> 0)")),
    "steps": (1.0, "positive", ("steps of the independent variable per grid step (time-"
              "transformed charts, > 0)")),
    "margin": (0.15, "nonnegative", ("propagate the independent variable this fraction past its "
               "nominal end (time-transformed charts, >= 0)")),
    "k": (1.0, "positive", "Sundman exponent: dt = r^k ds (sundman, in (0, 2])"),
    "body": ("moon", "body", "primary of the Sundman transformation: moon or earth (sundman)"),
    "form": ("simplified", "form", "dynamics of the elements: simplified (the chart's verified "
             "closed forms of the chain rule) or generated (the chain rule alone)"),
    "frame": ("auto", "frame", "control axes of the elements: rtn (radial / transverse / normal; "
              "ball control sets only), inertial (the model's), auto (rtn for a ball)"),
}
_OWN = {"cartesian": (), "mee": ("pieces", "tol", "frame", "form"),
        "mee-longitude": ("pieces", "tol", "steps", "margin", "frame", "form"),
        "sundman": ("pieces", "tol", "steps", "margin", "k", "body")}


@dataclass(frozen=True)
class CoordinateSpec:
    """A parsed coordinate spec: ``name`` and its settings (defaults filled in)."""

    name: str
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def time_transformed(self) -> bool:
        return self.name in TIME_TRANSFORMED

    def __str__(self) -> str:
        given = [f"{k}={v}" for k, v in self.settings.items() if v != SETTINGS[k][0]]
        return self.name + (":" + ",".join(given) if given else "")


def _setting(name: str, key: str, raw: Any) -> Any:
    _default, kind, desc = SETTINGS[key]
    choices = {"frame": ("auto", "rtn", "inertial"), "form": ("simplified", "generated"),
               "body": ("moon", "earth")}
    if kind in choices:
        val = str(raw).strip().lower()
        if val not in choices[kind]:
            raise ProblemError(f"coordinates {name!r}: {key} must be one of {list(choices[kind])}; "
                               f"got {raw!r}")
        return val
    try:
        val = float(raw)
    except (TypeError, ValueError):
        raise ProblemError(f"coordinates {name!r}: {key} must be a number ({desc}); "
                           f"got {raw!r}") from None
    ok = {"count": val >= 1 and val == int(val), "positive": val > 0,
          "nonnegative": val >= 0}[kind] and np.isfinite(val)
    if key == "k":
        ok = ok and val <= 2
    if not ok:
        raise ProblemError(f"coordinates {name!r}: {key} = {raw!r} is not allowed: {desc}")
    return int(val) if kind == "count" else val


def parse(spec: Any) -> CoordinateSpec:
    """Parse ``"NAME"`` / ``"NAME:key=value,..."`` (or a :class:`CoordinateSpec`); raise a clear
    :class:`ProblemError` for an unknown name or setting."""
    if isinstance(spec, CoordinateSpec):
        return spec
    if not isinstance(spec, str) or not spec.strip():
        raise ProblemError(f"coordinates must be a name, one of {sorted(COORDINATES)} (optionally "
                           f"NAME:key=value,...); got {spec!r}")
    name, _, rest = spec.strip().partition(":")
    name = name.strip().lower()
    if name not in COORDINATES:
        raise UnknownNameError(f"unknown coordinates {name!r}; allowed: {sorted(COORDINATES)}")
    allowed = _OWN[name]
    settings = {k: SETTINGS[k][0] for k in allowed}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, sep, raw = item.partition("=")
        key = key.strip()
        if not sep or key not in allowed:
            raise ProblemError(f"coordinates {name!r}: unknown setting {item!r}; allowed: "
                               f"{list(allowed) or 'none'} (as {name}:key=value,...)")
        settings[key] = _setting(name, key, raw.strip())
    return CoordinateSpec(name, settings)


def chart_for(spec: CoordinateSpec, model: Model, x0: np.ndarray, control_set: str = "ball") -> Chart:
    """The chart of ``spec`` for ``model`` (the initial state ``x0`` fixes angle branches, the
    control set's kind the control frame);
    :class:`ProblemError` if the coordinates do not fit the model.  Cached on the model, so its
    derived Functions and interval extensions are built once per model and chart."""
    if spec.name in ("mee", "mee-longitude"):
        ok, why = two_body_fit(model)
        if not ok:
            raise ProblemError(why)
        L_ref = reference_longitude(x0)
        frame = spec.settings["frame"]
        if frame == "rtn" and control_set != "ball":
            raise ProblemError(f"coordinates {spec.name!r}: frame=rtn rotates the controls, which "
                               f"keeps only a ball control set; this one is {control_set!r} (use "
                               f"frame=inertial)")
        rtn = frame == "rtn" or (frame == "auto" and control_set == "ball")
        simplified = spec.settings["form"] == "simplified"
        return model.cached(("chart", spec.name, L_ref, rtn, simplified), lambda: mee_chart(
            model, x0, longitude=spec.name == "mee-longitude", rtn=rtn, simplified=simplified))
    if spec.name == "sundman":
        from ocreach.models.coordinates.sundman import sundman_chart

        k, body = spec.settings["k"], spec.settings["body"]
        return model.cached(("chart", spec.name, k, body),
                            lambda: sundman_chart(model, k=k, body=body))
    raise ProblemError(f"coordinates {spec.name!r} have no chart (the model's own state)")


__all__ = ["COORDINATES", "Chart", "CoordinateSpec", "MapEnclosure", "chart_for", "parse"]
