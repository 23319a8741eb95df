"""Write the 1,000-object cislunar catalog of ``examples/sweep_catalog.json``.

Objects are spread over four groups, all in the Earth-Moon CR3BP (mu = 0.01215, units of Patel &
Subbarao) and generated with :mod:`ocreach.orbits`:

* DRO: members of the planar distant-retrograde family, continued in ``x0`` from the Foss et al.
  Sec. 4.1 state and corrected by :func:`ocreach.orbits.correct_symmetric`;
* halo: members of the southern L2 halo family through the Patel & Subbarao state, continued in
  ``z0`` (:func:`ocreach.orbits.continue_family`);
* NRHO: the 9:2 NRHO (:func:`ocreach.orbits.nrho_9_2`) and its neighbours in ``z0``;
* Lagrange: the five Lagrange points (:func:`ocreach.orbits.lagrange_points`) at rest.

Each object sits at a random phase of its orbit (one unpowered propagation per member with
:func:`ocreach.propagate`) plus a seeded Gaussian perturbation (orbits: 50 km, 0.5 m/s per axis;
Lagrange points: 500 km, 5 m/s).  Run::

    python examples/sweep_catalog.py            # writes examples/sweep_catalog/catalog.csv
    ocreach sweep examples/sweep_catalog.json --out out/sweep_catalog
    ocreach sweep collect out/sweep_catalog
"""
from __future__ import annotations

import argparse
import io
from pathlib import Path

import numpy as np

from ocreach import propagate
from ocreach.fileio import atomic_write_text
from ocreach.models import cr3bp
from ocreach.orbits import continue_family, correct_symmetric, lagrange_points, nrho_9_2
from ocreach.units import EARTH_MOON_PATEL

MU = 0.01215
HERE = Path(__file__).resolve().parent
COUNTS = {"DRO": 300, "halo": 300, "NRHO": 250, "Lagrange": 150}
SIGMA = {"orbit": (50e3, 0.5), "Lagrange": (500e3, 5.0)}  # (m, m/s) per axis


def families() -> dict[str, list[tuple[np.ndarray, float]]]:
    """``{group: [(x0 (6,), period), ...]}`` of the corrected family members."""
    planar, spatial = cr3bp(MU, planar=True), cr3bp(MU)
    dro = correct_symmetric(planar, [0.2765, 0.0, 0.0, 2.1379], fix="x", family="DRO")
    dros = [dro] + continue_family(planar, dro, "x", np.linspace(0.30, 0.60, 7))
    halo = correct_symmetric(spatial, [1.1720, 0.0, -0.0862, 0.0, -0.1880, 0.0], fix="z")
    halos = continue_family(spatial, halo, "z", [-0.07, -0.05, -0.03]) + [halo] + \
        continue_family(spatial, halo, "z", [-0.09, -0.095, -0.10, -0.105, -0.11])
    nrho = nrho_9_2(MU, EARTH_MOON_PATEL)
    nrhos = continue_family(spatial, nrho, "z", nrho.x0[2] + np.array([0.004, 0.008])) + [nrho] + \
        continue_family(spatial, nrho, "z", nrho.x0[2] - np.array([0.004, 0.008]))
    embed = lambda o: np.array([o.x0[0], o.x0[1], 0.0, o.x0[2], o.x0[3], 0.0])  # noqa: E731
    return {"DRO": [(embed(o), o.period) for o in dros],
            "halo": [(np.array(o.x0), o.period) for o in halos],
            "NRHO": [(np.array(o.x0), o.period) for o in nrhos]}


def catalog(seed: int = 15) -> list[tuple[str, str, int, float, np.ndarray]]:
    """``[(name, family, member, phase, state_SI (6,))]`` of every object."""
    rng = np.random.default_rng(seed)
    u = EARTH_MOON_PATEL
    model = cr3bp(MU)
    out = []
    for fam, members in families().items():
        n = COUNTS[fam]
        which = np.arange(n) % len(members)
        phases = rng.uniform(0.0, 1.0, n)
        for m, (x0, period) in enumerate(members):
            idx = np.flatnonzero(which == m)
            grid = np.linspace(0.0, period, 257)
            traj = propagate(model, x0[None], np.zeros((1, 256, model.n_u)), grid)[0]
            k = np.minimum((phases[idx] * 256).astype(int), 256)
            for i, kk in zip(idx, k):
                out.append((f"{fam.lower()}-{i:04d}", fam, m, float(phases[i]), traj[kk]))
    L = lagrange_points(MU)
    for i in range(COUNTS["Lagrange"]):
        out.append((f"l{i % 5 + 1}-{i:04d}", "Lagrange", i % 5, 0.0, np.concatenate([L[i % 5], np.zeros(3)])))
    rows = []
    for name, fam, m, ph, x in out:
        if fam == "Lagrange":
            sig_r, sig_v = SIGMA["Lagrange"]
        else:
            sig_r, sig_v = SIGMA["orbit"]
        si = np.concatenate([x[:3] * u.length + rng.normal(0.0, sig_r, 3),
                             x[3:] * u.velocity + rng.normal(0.0, sig_v, 3)])
        rows.append((name, fam, m, ph, si))
    return rows


def write(path: Path, rows) -> Path:
    buf = io.StringIO()
    buf.write("# cislunar catalog for examples/sweep_catalog.json, written by examples/sweep_catalog.py\n"
              "# Earth-Moon CR3BP rotating barycentric frame, mu = 0.01215\n")
    buf.write("name,family,member,phase,x[km],y[km],z[km],vx[km/s],vy[km/s],vz[km/s]\n")
    for name, fam, m, ph, si in rows:
        vals = ",".join(f"{v / 1e3:.12g}" for v in si)
        buf.write(f"{name},{fam},{m},{ph:.4f},{vals}\n")
    return atomic_write_text(path, buf.getvalue())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE / "sweep_catalog" / "catalog.csv"))
    ap.add_argument("--seed", type=int, default=15)
    args = ap.parse_args()
    rows = catalog(args.seed)
    print(f"wrote {write(Path(args.out), rows)}: {len(rows)} objects "
          + ", ".join(f"{k} {v}" for k, v in COUNTS.items()))


if __name__ == "__main__":
    main()
