"""Plots of reachability results: 2-D projections over time, overlays of several methods."""
from __future__ import annotations

from typing import Sequence

import numpy as np

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


def plot_projections_over_time(result, problem, path, dims: Sequence[int] = (0, 1),
                               every: int | None = None) -> None:
    """Write a PNG of the 2-D projection of ``result`` at several times (colour = time)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ocreach.reach.result import atomic_write_bytes

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
    ax.set_xlabel(axis_label(problem, dims[0]))
    ax.set_ylabel(axis_label(problem, dims[1]))
    ax.set_title(f"{problem.id}: {result.method} reachable set, dims {tuple(dims)}")
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
