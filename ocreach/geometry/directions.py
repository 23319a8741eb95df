"""Terminal directions ``z-hat`` for support-function sampling (shared by ffoe, ole and bvp).

Patel & Scheeres Eq. 12 maximise ``z-hat . x^N``; the directions are swept over the unit sphere of
the full state or of a chosen subspace (``dims``, e.g. position only, as Foss et al. Sec. 4.1 do).
Two and three dimensional subspaces get deterministic, evenly spread directions (angles
``theta_j = 2 pi j / N`` in a plane, a Fibonacci lattice on the 2-sphere); higher dimensions get
seeded Gaussian samples normalised to the sphere.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ocreach.errors import ProblemError

DIMS_ALIASES = ("position", "velocity", "all")


def resolve_dims(dims, problem) -> tuple[int, ...]:
    """State indices of the direction subspace: an alias in :data:`DIMS_ALIASES` or indices.

    Raises :class:`ProblemError` for indices outside ``[0, n_x)``, repeats or an empty list.
    """
    n_x = problem.model.n_x
    if dims is None or (isinstance(dims, str) and dims == "position"):
        out = tuple(problem.position_dims)
    elif isinstance(dims, str) and dims == "velocity":
        out = tuple(problem.velocity_dims)
    elif isinstance(dims, str) and dims == "all":
        out = tuple(range(n_x))
    elif isinstance(dims, str):
        try:
            out = tuple(int(v) for v in dims.replace("(", "").replace(")", "").split(",") if v.strip())
        except ValueError:
            raise ProblemError(f"dims must be one of {DIMS_ALIASES} or state indices in [0, {n_x}); "
                               f"got {dims!r}") from None
    else:
        try:
            out = tuple(int(v) for v in np.atleast_1d(np.asarray(dims)).ravel())
        except (TypeError, ValueError):
            raise ProblemError(f"dims must be one of {DIMS_ALIASES} or state indices; got {dims!r}") from None
    if len(out) == 0:
        raise ProblemError(f"dims must name at least one state index in [0, {n_x}); got {dims!r}")
    bad = [d for d in out if not 0 <= d < n_x]
    if bad:
        raise ProblemError(f"dims {list(out)} out of range: indices must be in [0, {n_x}) for model "
                           f"{problem.model.name} (states {list(problem.model.state_names)}); got {bad}")
    if len(set(out)) != len(out):
        raise ProblemError(f"dims must not repeat an index; got {list(out)}")
    return out


def plane_directions(samples: int, theta0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """``N`` evenly spaced unit vectors of a plane and their angles ``theta_j = theta0 + 2 pi j / N``."""
    theta = theta0 + 2.0 * np.pi * np.arange(samples) / samples
    return np.stack([np.cos(theta), np.sin(theta)], axis=1), theta


def fibonacci_sphere(samples: int) -> np.ndarray:
    """``N`` nearly uniform unit vectors of the 2-sphere (Fibonacci lattice)."""
    i = np.arange(samples) + 0.5
    z = 1.0 - 2.0 * i / samples
    phi = np.pi * (1.0 + 5.0**0.5) * i
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def random_sphere(rng: np.random.Generator, samples: int, dim: int) -> np.ndarray:
    """Uniform random unit vectors of ``R^dim``."""
    g = rng.standard_normal((samples, dim))
    return g / np.linalg.norm(g, axis=1, keepdims=True)


def sample_directions(n_x: int, dims: Sequence[int], samples: int, seed: int | None = 0,
                      random: bool = False) -> np.ndarray:
    """Unit directions ``(samples, n_x)`` supported on ``dims`` (zero elsewhere).

    Deterministic spreads for 1-3 dimensional subspaces unless ``random``; seeded Gaussian
    directions otherwise.  A 1-D subspace gives ``+e`` and ``-e`` alternately.
    """
    samples = int(samples)
    if samples < 1:
        raise ProblemError(f"samples must be >= 1; got {samples}")
    d = len(dims)
    if random or d > 3:
        sub = random_sphere(np.random.default_rng(seed), samples, d)
    elif d == 1:
        sub = np.where(np.arange(samples) % 2 == 0, 1.0, -1.0)[:, None]
    elif d == 2:
        sub = plane_directions(samples)[0]
    else:
        sub = fibonacci_sphere(samples)
    out = np.zeros((samples, n_x))
    out[:, list(dims)] = sub
    return out


def continuation_order(directions: np.ndarray) -> np.ndarray:
    """A path through the directions (greedy nearest neighbour from the first) for continuation."""
    n = directions.shape[0]
    order = [0]
    left = np.ones(n, dtype=bool)
    left[0] = False
    for _ in range(n - 1):
        cos = directions[left] @ directions[order[-1]]
        idx = np.flatnonzero(left)[int(np.argmax(cos))]
        order.append(idx)
        left[idx] = False
    return np.asarray(order)
