"""Plots of reachability results: 2-D projections over time, overlays of several methods."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.errors import OcreachError
from ocreach.geometry import convex_hull_polygon


def _axes(ax):
    if ax is None:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(6, 5))
    return ax


def axis_label(problem, dim: int) -> str:
    """``"x [DU]"``-style label from the model's state names and unit labels (``state_units``)."""
    if problem is None:
        return f"x{dim}"
    model = problem.model
    unit = model.state_units[dim] if dim < len(model.state_units) else ""
    return f"{model.state_names[dim]} [{unit}]" if unit else model.state_names[dim]


def time_label(problem, t: float) -> str:
    """``"t = 3 TU"`` (the unit from the problem's units, if any)."""
    units = getattr(problem, "units", None)
    return f"t = {t:.3g}" + (f" {units.time_label}" if units is not None else "")


BODY_STYLE = {"earth": ("tab:blue", "Earth"), "moon": ("0.45", "Moon"), "sun": ("gold", "Sun"),
              "venus": ("tab:orange", "Venus")}


def body_tracks(problem, times=None) -> dict[str, np.ndarray]:
    """Positions of the attracting bodies in the problem's state coordinates, ``{name: (T, 3)}``.

    CR3BP models: Earth at ``(-mu, 0, 0)`` and Moon at ``(1 - mu, 0, 0)``.  Inertial ephemeris
    models: every modelled body relative to the origin body, from the fitted DE421 ephemeris, over
    ``times`` (default: the problem grid; time 0 is the epoch).  Synodic ephemeris models: the
    instantaneous Earth and Moon positions.  Other models: no bodies.
    """
    model = problem.model
    times = problem.grid if times is None else np.asarray(times, dtype=float)
    if model.name.startswith("cr3bp"):
        mu = model.param("mu", problem.params)
        one = np.ones((times.size, 1))
        return {"earth": one * [-mu, 0.0, 0.0], "moon": one * [1.0 - mu, 0.0, 0.0]}
    frame = model.cache.get("frame")
    eph = model.cache.get("ephemeris")
    if not frame or eph is None or model.units is None:
        return {}
    t_s = times * model.units.time
    if frame.get("kind") == "inertial":
        du_km = model.units.length / 1e3
        return {b: eph.position(b, t_s, frame["central"], frame=frame["axes"]) / du_km
                for b in frame["bodies"] if b != frame["central"] and b != "sun"} | (
            {frame["central"]: np.zeros((times.size, 3))})
    if frame.get("kind") == "synodic":
        from ocreach.models.ephemeris import inertial_to_synodic

        out = {}
        for b in ("earth", "moon"):
            r = eph.position(b, t_s, "ssb")
            v = eph.velocity(b, t_s, "ssb")
            out[b] = np.array([inertial_to_synodic(model, t, ri, vi)[:3]
                               for t, ri, vi in zip(times, r, v)])
        return out
    return {}


def draw_bodies(ax, problem, dims: Sequence[int], times=None) -> None:
    """Mark the attracting bodies (and, if they move, their tracks) in a 2-D projection."""
    dims = list(dims)
    if any(d > 2 for d in dims):
        return  # not a position plane
    try:
        tracks = body_tracks(problem, times)
    except (OcreachError, OSError, ValueError) as exc:  # an ephemeris query failed: say so on the figure
        ax.text(0.01, 0.01, f"bodies not drawn: {exc}", transform=ax.transAxes, fontsize=6)
        return
    lim = ax.dataLim
    (x0, y0), (x1, y1) = lim.min, lim.max
    pad_x, pad_y = max(x1 - x0, 1e-12), max(y1 - y0, 1e-12)
    hidden = []
    for name, xyz in tracks.items():
        color, label = BODY_STYLE.get(name, ("k", name.title()))
        pts = xyz[:, dims]
        px, py = pts[-1]
        if not (x0 - pad_x <= px <= x1 + pad_x and y0 - pad_y <= py <= y1 + pad_y):
            hidden.append(label)  # far outside the data: drawing it would shrink the sets to dots
            continue
        if np.ptp(pts, axis=0).max() > 0:
            ax.plot(pts[:, 0], pts[:, 1], "-", color=color, lw=0.8, alpha=0.7)
        ax.plot(*pts[-1], "o", color=color, ms=7, mec="k", label=label)
    if hidden:
        ax.text(0.99, 0.01, "out of view: " + ", ".join(hidden), transform=ax.transAxes,
                ha="right", fontsize=7, color="0.3")


def plot_result(result, ax=None, dims: Sequence[int] = (0, 1), k: int | Sequence[int] = -1,
                color=None, label: str | None = None, show_points: bool = True,
                show_trajectories: bool = False, **kw):
    """Plot the 2-D projection of ``result`` at time index/indices ``k``.

    Set results draw the set's outline (``set.plot``); sample results draw the convex hull of the
    samples and, optionally, the samples and the trajectories.
    """
    ax = _axes(ax)
    dims = list(dims)
    ks = [k] if np.isscalar(k) else list(k)
    label = label if label is not None else result.method
    for i, kk in enumerate(ks):
        lab = label if i == 0 else None
        if result.sets is not None:
            s = result.sets[kk]
            s.plot(ax, dims=tuple(dims), color=color, label=lab, **kw)
            continue
        pts = np.asarray(result.points[kk])[:, dims]
        if show_points:
            ax.plot(pts[:, 0], pts[:, 1], ".", ms=2, color=color, alpha=0.5)
        poly = convex_hull_polygon(pts)
        if poly is not None:
            closed = np.vstack([poly, poly[:1]])
            ax.plot(closed[:, 0], closed[:, 1], "-", color=color, label=lab, **kw)
    if show_trajectories and result.trajectories is not None:
        tr = result.trajectories[..., dims]
        for j in range(min(tr.shape[0], 100)):
            ax.plot(tr[j, :, 0], tr[j, :, 1], "-", lw=0.4, color=color, alpha=0.3)
    return ax


def save_figure(fig, path: str | Path, *, dpi: int = 120, palette: bool = False, **savefig_kw: Any) -> Path:
    """Write ``fig`` as PNG to ``path`` atomically and close it (``savefig_kw`` go to
    ``Figure.savefig``, e.g. ``bbox_inches="tight"``).

    ``palette``: store an 8-bit PNG with an adaptive 256-colour palette (Pillow's fast octree,
    optimised deflate) instead of 32-bit RGBA: about a quarter of the bytes for line and scatter
    plots, for figures committed to the repository."""
    import io

    import matplotlib.pyplot as plt

    from ocreach.fileio import atomic_write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, **savefig_kw)
    plt.close(fig)
    data = buf.getvalue()
    if palette:
        from PIL import Image

        small = io.BytesIO()  # method 2 = FASTOCTREE (keeps the alpha channel)
        Image.open(io.BytesIO(data)).quantize(colors=256, method=2).save(small, format="png", optimize=True,
                                                                         dpi=(dpi, dpi))
        data = small.getvalue()
    return atomic_write_bytes(path, data)


def dims_are_position(problem, dims: Sequence[int]) -> bool:
    return all(d in problem.position_dims for d in dims)


def plot_projections_over_time(result, problem, path, dims: Sequence[int] = (0, 1),
                               every: int | None = None) -> None:
    """Write a PNG of the 2-D projection of ``result`` at several times (colour = time)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt


    n = result.times.size
    if every:
        ks = list(range(every, n, every))
        if not ks or ks[-1] != n - 1:
            ks.append(n - 1)
    else:  # about six evenly spaced times ending at the last one (no near-duplicate last pair)
        ks = sorted(set(np.linspace(0, n - 1, min(n, 7)).round().astype(int).tolist()) - {0})
    fig, ax = plt.subplots(figsize=(6.5, 5.5))
    cmap = plt.get_cmap("viridis")
    if result.trajectories is not None:
        tr = result.trajectories[..., list(dims)]
        for j in range(min(tr.shape[0], 60)):
            ax.plot(tr[j, :, 0], tr[j, :, 1], "-", lw=0.3, color="0.6", alpha=0.5)
    for i, k in enumerate(ks):
        plot_result(result, ax=ax, dims=dims, k=k, color=cmap(i / max(1, len(ks) - 1)),
                    label=time_label(problem, result.times[k]), show_points=result.points is not None)
    ax.plot(*problem.x0[list(dims)], "k*", ms=9, label="x0")
    if dims_are_position(problem, dims):
        draw_bodies(ax, problem, dims, result.times)
    ax.set_xlabel(axis_label(problem, dims[0]))
    ax.set_ylabel(axis_label(problem, dims[1]))
    ax.set_title(f"{problem.id}: {result.method} reachable set, dims {tuple(dims)}")
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path)
