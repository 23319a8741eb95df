"""Splitting of STT reachable sets where the STT polynomial is not valid over a whole part.

Foss, Rosengren & Biria (AMOS 2024) name splitting as future work (Sec. 5): one STT expansion
about one reference is a local approximation, and on a close flyby its truncation error exceeds
the set (docs/validation/stt.md).  A split part is propagated about its own
reference trajectory with its own STTs (:meth:`ocreach.reach.stt.STTReach.solve`); the set at a
time is the union of the parts (:class:`ocreach.sets.PZUnion`).

This module holds the two pieces of that rule:

* :func:`truncation_error`: the STT polynomial (Foss Eq. 13) evaluated on extreme samples of the
  step's set ``dZ_k = dR_k x U_k`` against the true flow of the same samples over the step, as a
  fraction of the part's image; a part is split when it exceeds the tolerance ``split_tol``.
* :func:`split_factor` (exact) and :func:`split_box` (an enclosure) cut a part's deviation set
  in two; each half is re-centred on its own reference state.

``split_factor`` halves the dependent factor with the largest order-2 contribution: the halves'
union equals the part.  It shrinks the part only along that factor's generators, so it pays off
when few factors carry the set (an uncertain initial box); after many steps the extent is a sum
of many comparable generators (on nrho-flyby at 0.7 TU the largest of 200 carries 2.9 % of it)
and halving one barely changes it.  ``split_box`` first reduces the part to its ``keep`` largest
generators plus the PCA box of the rest (the sound reduction) and halves that exactly: more
compact parts, at the price of the box (docs/validation/stt-flyby.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.dynamics.flow import stt_polynomial
from ocreach.errors import ProblemError, check_count
from ocreach.sets.polyzonotope import make_dependent

if TYPE_CHECKING:
    from ocreach.sets import PolyZonotope


@dataclass
class PartStep:
    """One part's step in the split loop of :meth:`ocreach.reach.stt.STTReach.solve`: the part,
    its step's STTs ``phi`` about its reference, the reference state ``x1`` at ``t_(k+1)``, the
    step's set ``dZ = dR_k x U_k`` and the sampled truncation error ``err``
    (:func:`truncation_error`; 0 until measured)."""

    part: Any
    phi: list
    x1: np.ndarray
    dZ: Any
    err: float = 0.0


#: how a part is split (``STTReach.Options.split``)
SPLIT_MODES = ("factor", "box")
#: extreme samples of ``dZ_k`` on which the truncation error is measured
ERROR_SAMPLES = 24


def check_split_options(split: Any, max_parts: Any, split_tol: Any) -> tuple[str | None, int, float]:
    """Validate ``split``, ``max_parts`` and ``split_tol`` (clear :class:`ProblemError` otherwise;
    ``split_keep`` is a count checked by the caller)."""
    if isinstance(split, (tuple, list)) or (isinstance(split, str) and "," in split):
        raise ProblemError(f"split={split!r}: the (max_parts, threshold) form was replaced; give "
                           f"split='factor' or 'box', max_parts=N and split_tol=TOL")
    if split in ("none", "off", ""):
        split = None
    if split is not None and split not in SPLIT_MODES:
        raise ProblemError(f"split must be one of {SPLIT_MODES} or None; got {split!r}")
    parts = check_count("max_parts", max_parts, 1)
    try:
        tol = float(split_tol)
    except (TypeError, ValueError):
        raise ProblemError(f"split_tol must be a number in (0, inf); got {split_tol!r}") from None
    if not (tol > 0 and np.isfinite(tol)):
        raise ProblemError(f"split_tol must be a number in (0, inf); got {split_tol!r}")
    return split, parts, tol


def error_samples(dZ: PolyZonotope, samples: int = ERROR_SAMPLES, seed: int = 0) -> np.ndarray:
    """``samples`` extreme samples (factors at +-1) of a step's set ``dZ_k = dR_k x U_k``, (N, n_z):
    the deviations at which :func:`truncation_error` compares the STT polynomial with the flow."""
    return dZ.sample(samples, np.random.default_rng(seed), mode="extreme")


def truncation_error(phi: list[np.ndarray], S: np.ndarray, true: np.ndarray) -> float:
    """Pointwise error of the STT polynomial over one step, relative to the part's image.

    ``phi``: the step's STTs ``Phi_k^(j)`` about the part's reference (Foss Eq. 13); ``S``: sampled
    deviations ``dz`` (N, n_z) of the step's set (:func:`error_samples`); ``true``: the true
    deviations at ``t_{k+1}`` of the same samples (their states and held controls propagated over
    the step, minus the reference), (N, n_x).  Returns ``max_s ||p(dz_s) - true_s|| / max_s
    ||true_s - mean(true)||``: an estimate (samples, not a bound) of how far the truncated expansion
    is from the true flow, in units of the part's size.
    """
    poly = sum(stt_polynomial(phi, S))
    size = float(np.max(np.linalg.norm(true - true.mean(axis=0), axis=1)))
    err = float(np.max(np.linalg.norm(poly - true, axis=1)))
    if not np.isfinite(err):
        return float("inf")
    return err / size if size > 0 else (0.0 if err == 0 else float("inf"))


def split_factor(dR: PolyZonotope, phi2: np.ndarray | None = None) -> tuple[PolyZonotope, PolyZonotope]:
    """Exact split of ``dR`` along the dependent factor with the largest order-2 contribution.

    Independent generators are first turned into dependent factors (exact).  The factor ``r`` is
    chosen by ``max_r ||Phi2[g_r, g_r]||`` with ``g_r`` the sum of the absolute generators that
    contain it (padded with zero controls); without ``phi2`` by the largest generator norm
    (:meth:`PolyZonotope.split`'s default).  The union of the halves equals ``dR``.
    """
    dep = make_dependent(dR)
    if phi2 is None:
        return dep.split()
    g = (dep.E > 0).astype(float) @ np.abs(dep.G).T  # (factors, n_x)
    gz = np.zeros((g.shape[0], phi2.shape[1]))
    gz[:, : g.shape[1]] = g
    q = np.linalg.norm(np.einsum("iab,ra,rb->ri", phi2, gz, gz, optimize=True), axis=1)
    return dep.split(int(dep.id[int(np.argmax(q))]))


def split_box(dR: PolyZonotope, phi2: np.ndarray | None = None, keep: int = 0) -> tuple[PolyZonotope, PolyZonotope]:
    """Halves of a PCA-reduced enclosure of ``dR`` (not exact: their union contains ``dR``).

    ``dR`` is reduced to ``n + keep`` generators by the sound PCA reduction (Kopetzki et al. 2017,
    as :meth:`PolyZonotope.reduce`): the ``keep`` largest generators stay, the others are boxed in
    their principal frame (``keep = 0``: the PCA parallelotope of ``dR``).  That set is split
    exactly by :func:`split_factor`.  The parts are more compact than exact halves of a set with
    many comparable generators; the price is the box, smaller the more generators are kept
    (measured on nrho-flyby in docs/validation/stt-flyby.md).
    """
    return split_factor(dR.reduce(dR.dim + int(keep), "pca"), phi2)
