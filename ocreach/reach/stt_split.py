"""Splitting of STT reachable sets where the STT polynomial is not valid over a whole part.

Foss, Rosengren & Biria (AMOS 2024) name splitting as future work (Sec. 5): one STT expansion
about one reference is a local approximation, and on a close flyby its truncation error exceeds
the set (docs/validation.md, "STT reachability").  A split part is propagated about its own
reference trajectory with its own STTs (:meth:`ocreach.reach.stt.STTReach.solve`); the set at a
time is the union of the parts (:class:`ocreach.reach.stt.PZUnion`).

This module holds the two pieces of that rule:

* :func:`truncation_error`: the STT polynomial (Foss Eq. 13) evaluated on extreme samples of the
  step's set ``dZ_k = dR_k x U_k`` against the true flow of the same samples over the step, as a
  fraction of the part's image; a part is split when it exceeds the tolerance ``split_tol``.
* :func:`split_factor` (exact) and :func:`split_axis` (an enclosure) cut a part's deviation set
  in two; each half is re-centred on its own reference state.

``split_factor`` halves the dependent factor with the largest order-2 contribution: the halves'
union equals the part.  It shrinks the part only along that factor's generators, so it pays off
when few factors carry the set (an uncertain initial box); after many reductions the extent is a
sum of many comparable generators and halving one barely changes it.  ``split_axis`` halves the
part along its principal axis ``v`` (in the coordinates scaled by the part's interval-hull
radii): ``dR`` is enclosed by the segment ``v [lo, hi]`` plus the projection ``(I - v l^T) dR``
(``l`` the dual of ``v``), so each half is half as long along ``v``; the union of the halves
contains the part but is larger (the "cylinder" loses the correlation of ``v`` with the rest).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ocreach.errors import ProblemError

if TYPE_CHECKING:
    from ocreach.sets import PolyZonotope

#: how a part is split (``STTReach.Options.split``)
SPLIT_MODES = ("factor", "axis")
#: extreme samples of ``dZ_k`` on which the truncation error is measured
ERROR_SAMPLES = 24


def check_split_options(split: Any, max_parts: Any, split_tol: Any) -> tuple[str | None, int, float]:
    """Validate ``split``, ``max_parts`` and ``split_tol`` (clear :class:`ProblemError` otherwise)."""
    if isinstance(split, (tuple, list)) or (isinstance(split, str) and "," in split):
        raise ProblemError(f"split={split!r}: the (max_parts, threshold) form was replaced; give "
                           f"split='factor' or 'axis', max_parts=N and split_tol=TOL")
    if split in ("none", "off", ""):
        split = None
    if split is not None and split not in SPLIT_MODES:
        raise ProblemError(f"split must be one of {SPLIT_MODES} or None; got {split!r}")
    try:
        parts = int(max_parts)
        if parts != max_parts and not (isinstance(max_parts, str) and str(parts) == max_parts.strip()):
            raise ValueError
    except (TypeError, ValueError):
        raise ProblemError(f"max_parts must be an integer >= 1; got {max_parts!r}") from None
    if parts < 1:
        raise ProblemError(f"max_parts must be an integer >= 1; got {max_parts!r}")
    try:
        tol = float(split_tol)
    except (TypeError, ValueError):
        raise ProblemError(f"split_tol must be a number in (0, inf); got {split_tol!r}") from None
    if not (tol > 0 and np.isfinite(tol)):
        raise ProblemError(f"split_tol must be a number in (0, inf); got {split_tol!r}")
    return split, parts, tol


def truncation_error(phi: list[np.ndarray], dZ: PolyZonotope, flow: Any, n_x: int,
                     samples: int = ERROR_SAMPLES, seed: int = 0) -> float:
    """Pointwise error of the STT polynomial over one step, relative to the part's image.

    ``phi``: the step's STTs ``Phi_k^(j)`` about the part's reference (Foss Eq. 13); ``dZ``: the
    step's set ``dR_k x U_k`` (deviations); ``flow(dz)``: the true deviation at ``t_{k+1}`` of the
    samples ``dz`` (N, n_z) (their states and controls propagated over the step, minus the
    reference).  Returns ``max_s ||p(dz_s) - flow(dz_s)|| / max_s ||flow(dz_s)||`` over
    ``samples`` extreme samples (factors at +-1) of ``dZ``: an estimate (samples, not a bound) of
    how far the truncated expansion is from the true flow, in units of the part's size.
    """
    from ocreach.reach.stt import stt_polynomial

    S = dZ.sample(samples, np.random.default_rng(seed), mode="extreme")
    poly = sum(stt_polynomial(phi, S))
    true = flow(S)
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
    from ocreach.reach.stt import make_dependent

    dep = make_dependent(dR)
    if phi2 is None:
        return dep.split()
    g = (dep.E > 0).astype(float) @ np.abs(dep.G).T  # (factors, n_x)
    gz = np.zeros((g.shape[0], phi2.shape[1]))
    gz[:, : g.shape[1]] = g
    q = np.linalg.norm(np.einsum("iab,ra,rb->ri", phi2, gz, gz, optimize=True), axis=1)
    return dep.split(int(dep.id[int(np.argmax(q))]))


def principal_axis(dR: PolyZonotope) -> tuple[np.ndarray, np.ndarray]:
    """``(v, l)``: the principal axis ``v`` of ``dR``'s generators in the coordinates scaled by its
    interval-hull radii, and its dual ``l`` (``l . v = 1``, ``l`` orthogonal to ``v``'s complement
    in the scaled coordinates)."""
    Z = dR.to_zonotope()
    ih = Z.interval_hull()
    s = 0.5 * (np.asarray(ih.hi) - np.asarray(ih.lo))
    s = np.where(s > 0, s, 1.0)
    U, _, _ = np.linalg.svd(np.asarray(Z.G) / s[:, None], full_matrices=False)
    vs = U[:, 0]
    return s * vs, vs / s


def split_axis(dR: PolyZonotope) -> tuple[PolyZonotope, PolyZonotope]:
    """Halves of an enclosure of ``dR`` along its principal axis (not exact: contains ``dR``).

    ``dR = c + D`` is enclosed by ``c + v [lo, hi] + (I - v l^T) D`` (every point ``x`` of ``D`` is
    ``v (l . x) + (I - v l^T) x`` with ``l . x`` in ``[lo, hi]``, the support of ``D`` along
    ``+-l``); the halves take ``[lo, mid]`` and ``[mid, hi]`` as a fresh factor.
    """
    from ocreach.sets import PolyZonotope, new_ids

    v, l = principal_axis(dR)
    D = dR - dR.c
    hi = float(D.support(l))
    lo = -float(D.support(-l))
    P = np.eye(dR.dim) - np.outer(v, l)
    rest = (P @ D) + dR.c
    hw = 0.25 * (hi - lo)
    out = []
    for mid in (lo + hw, hi - hw):
        seg = PolyZonotope(v * mid, (v * hw)[:, None], None, np.ones((1, 1), dtype=np.int64), new_ids(1))
        out.append(rest + seg)
    return out[0], out[1]
