"""Reproduce Foss et al. Fig. 1: the polynomial zonotope of Eq. 15 (and the Eq. 16 unit-disk PZ).

    PZ = < [[2, 3, 0, 1], [0, 2, 4, 2]], [[0, 1, 0, 2], [0, 0, 2, 1]], [1, 2] >
       = { [2, 0] + [3, 2] a1 + [0, 4] a2^2 + [1, 2] a1^2 a2 : a1, a2 in [-1, 1] }

The first column of the paper's G (exponent 0) is the centre.  Left: the set drawn as the union of
the zonotope enclosures of 256 split pieces (outer approximation), its one-piece zonotope
enclosure, and 20,000 sampled points (uniform factors) as a check.  Right: Eq. 16 against the unit
circle.  Writes docs/figures/foss_eq15_polyzonotope.png.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ocreach.sets import PolyZonotope, unit_ball_pz

OUT = Path(__file__).resolve().parents[1] / "docs" / "figures" / "foss_eq15_polyzonotope.png"


def eq15() -> PolyZonotope:
    G_paper = np.array([[2, 3, 0, 1], [0, 2, 4, 2]], float)
    E_paper = np.array([[0, 1, 0, 2], [0, 0, 2, 1]])
    return PolyZonotope(np.zeros(2), G_paper, None, E_paper, [1, 2]).compact()


def main() -> None:
    pz = eq15()
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    ax = axes[0]
    pz.to_zonotope().plot(ax, facecolor="none", edgecolor="gray", linestyle="--", alpha=1.0,
                          label="zonotope enclosure")
    pz.plot(ax, pieces=256, facecolor="tab:blue", alpha=0.6, label="PZ (256 split pieces)")
    pts = pz.sample(20000, np.random.default_rng(0))
    ax.plot(pts[:, 0], pts[:, 1], ",", color="k", alpha=0.3, label="samples")
    ax.set_title("Foss et al. Eq. 15 polynomial zonotope")
    ax.set_xlabel("$x_1$")
    ax.set_ylabel("$x_2$")
    ax.set_aspect("equal")
    ax.legend(loc="upper left", fontsize=8)

    ax = axes[1]
    ball = unit_ball_pz(2)
    ball.plot(ax, pieces=256, facecolor="tab:orange", alpha=0.6, label="Eq. 16 PZ")
    t = np.linspace(0, 2 * np.pi, 400)
    ax.plot(np.cos(t), np.sin(t), "k-", lw=1, label="unit circle")
    ax.set_title("Foss et al. Eq. 16 unit-disk polynomial zonotope")
    ax.set_aspect("equal")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=120)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
