"""The result every reachability method returns, and its file format.

A :class:`ReachResult` holds, per time of the grid, either a set object (``sets[k]``) or boundary
samples (``points[k]``, shape ``(m, n_x)``).  Sample-based methods also keep ``controls``
(normalised, ``(samples, segments, n_u)``) so every sample can be re-simulated, and
``trajectories`` (``(samples, len(times), n_x)``).
"""
from __future__ import annotations

import dataclasses
import io
import json
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ocreach.errors import OcreachError, ProblemError, SolverError
from ocreach.fileio import atomic_write_bytes, jsonable

#: Version 2: sets and tubes as arrays + JSON (version 1 pickled them and is refused).
FORMAT_VERSION = 2


@dataclass(repr=False)
class ReachResult:
    """Reachable-set estimate on a time grid (DESIGN.md contract)."""

    times: np.ndarray
    sets: list[Any] | None = None
    points: list[np.ndarray] | None = None
    controls: np.ndarray | None = None
    trajectories: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    #: optional reachable tubes, one set per segment [t_k, t_{k+1}] (``len(times) - 1`` entries)
    tubes: list[Any] | None = None

    def __post_init__(self) -> None:
        self.times = np.asarray(self.times, dtype=float)
        if self.sets is None and self.points is None:
            raise ProblemError("ReachResult needs sets or points")
        for name, seq in (("sets", self.sets), ("points", self.points)):
            if seq is not None and len(seq) != self.times.size:
                raise ProblemError(f"ReachResult.{name} must have one entry per time "
                                   f"({self.times.size}); got {len(seq)}")
        if self.points is not None:
            bad = [k for k, pts in enumerate(self.points) if not np.all(np.isfinite(pts))]
            if bad:  # no silent NaN: a method that produced them has failed
                k = bad[0]
                msg = (f"ReachResult.points must be finite; time indices {bad[:10]} (of "
                       f"{self.times.size}, first t = {self.times[k]:g}) hold NaN or inf "
                       f"(method {self.meta.get('method', '?')!r})")
                partial = None
                if k >= 1:
                    partial = dataclasses.replace(self, points=self.points[:k],
                                                  times=self.times[:k]).truncated(k, msg)
                raise SolverError(msg, partial=partial)
        if self.tubes is not None and len(self.tubes) != self.times.size - 1:
            raise ProblemError(f"ReachResult.tubes must have one entry per segment "
                               f"({self.times.size - 1}); got {len(self.tubes)}")

    def truncated(self, n: int, reason: str) -> ReachResult:
        """The first ``n`` times of this result, flagged ``meta["truncated"] = True`` with
        ``meta["truncated_reason"] = reason`` (the partial result of a failed run)."""
        m = max(n - 1, 0)
        return ReachResult(
            times=self.times[:n],
            sets=None if self.sets is None else list(self.sets[:n]),
            points=None if self.points is None else list(self.points[:n]),
            controls=self.controls if self.controls is None else self.controls[:, :m],
            trajectories=None if self.trajectories is None else self.trajectories[:, :n],
            meta={**self.meta, "truncated": True, "truncated_reason": reason},
            tubes=None if self.tubes is None else list(self.tubes[:m]),
        )

    @classmethod
    def from_trajectories(cls, times: Any, trajectories: np.ndarray, *,
                          controls: np.ndarray | None = None,
                          meta: dict[str, Any] | None = None) -> ReachResult:
        """A sample-based result: ``points[k] = trajectories[:, k]`` for ``trajectories`` of shape
        ``(samples, len(times), n_x)`` (the samples at each time are views, not copies)."""
        traj = np.asarray(trajectories)
        if traj.ndim != 3:
            raise ProblemError(f"trajectories must have shape (samples, times, n_x); got {traj.shape}")
        return cls(times=times, points=[traj[:, k] for k in range(traj.shape[1])], controls=controls,
                   trajectories=traj, meta={} if meta is None else meta)

    # ------------------------------------------------------------------ queries
    @property
    def method(self) -> str:
        return str(self.meta.get("method", "?"))

    @property
    def n_x(self) -> int:
        if self.points is not None:
            return int(np.asarray(self.points[-1]).shape[-1])
        return int(self.sets[-1].dim)

    def _index(self, k: int) -> int:
        n = self.times.size
        if isinstance(k, (bool, np.bool_)) or not isinstance(k, (int, np.integer)) or not -n <= k < n:
            raise ProblemError(f"time index k must be an integer in [{-n}, {n}); got {k!r}")
        return k % n

    def _dims(self, dims: Sequence[int] | None) -> list[int] | None:
        if dims is None:
            return None
        n = self.n_x
        try:
            out = [int(i) for i in dims if not isinstance(i, (bool, float, str))]
        except (TypeError, ValueError):
            out = []
        if (not out or len(out) != len(list(dims)) or len(set(out)) != len(out)
                or not all(0 <= i < n for i in out)):
            raise ProblemError(f"dims must be distinct state indices in [0, {n}); got {dims!r}")
        return out

    def points_at(self, k: int = -1, dims: Sequence[int] | None = None) -> np.ndarray:
        """Samples at time index ``k`` (boundary points, or samples of the set)."""
        k = self._index(k)
        dims = self._dims(dims)
        if self.points is not None:
            pts = np.asarray(self.points[k])
        else:
            pts = self.sets[k].sample(2000, np.random.default_rng(0), mode="extreme")
        return pts if dims is None else pts[:, list(dims)]

    def support(self, d, k: int = -1, dims: Sequence[int] | None = None) -> float | np.ndarray:
        """Support function ``max_{x in R_k} d^T x`` (restricted to ``dims`` if given).

        For set results this is the set's support function (an upper bound where the set
        over-approximates); for sample results the max over the samples.  ``d`` may be one
        direction ``(n,)`` or many ``(m, n)``.
        """
        k = self._index(k)
        d = _directions(d)
        dims = self._dims(dims)
        if self.points is not None:
            pts = self.points_at(k, dims)
            if d.shape[-1] != pts.shape[-1]:
                raise ProblemError(f"direction d must have length {pts.shape[-1]}; got {d.shape}")
            return np.max(pts @ d.T, axis=0) if d.ndim == 2 else float(np.max(pts @ d))
        s = self.sets[k] if dims is None else self.sets[k].project(list(dims))
        if d.ndim == 2:  # every set type takes a batch of directions (one vectorised call)
            return np.asarray(s.support(d), dtype=float)
        return float(s.support(d))

    def project(self, dims: Sequence[int]) -> ReachResult:
        """The result restricted to the state components ``dims``."""
        dims = list(dims)
        return ReachResult(
            times=self.times,
            sets=None if self.sets is None else [s.project(dims) for s in self.sets],
            points=None if self.points is None else [np.asarray(p)[:, dims] for p in self.points],
            controls=self.controls,
            trajectories=None if self.trajectories is None else self.trajectories[..., dims],
            meta={**self.meta, "projected_dims": dims},
            tubes=None if self.tubes is None else [s.project(dims) for s in self.tubes],
        )

    # ------------------------------------------------------------------ plotting
    def plot(self, ax=None, dims: Sequence[int] = (0, 1), k: int | Sequence[int] = -1, **kw):
        """Plot the 2-D projection at time index/indices ``k`` (convex hull of samples or set outline)."""
        from ocreach.reach.plot import plot_result

        return plot_result(self, ax=ax, dims=dims, k=k, **kw)

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> Path:
        """Write the result to ``path`` (``.npz``) atomically; read it back with :func:`load`.

        The file holds arrays and JSON only (no pickle): ``schema``, ``format_version``, ``times``,
        ``points`` (concatenated, with ``n_points``; omitted with ``points_from_trajectories`` when
        they are the columns of ``trajectories``), each set and tube as its defining arrays
        (described by ``sets_json`` / ``tubes_json``, see :mod:`ocreach.sets.serialize`),
        ``controls``, ``trajectories`` and ``meta_json``.
        """
        from ocreach.sets.serialize import to_arrays

        arrays: dict[str, np.ndarray] = {"schema": np.array(SCHEMA), "times": self.times,
                                          "format_version": np.array(FORMAT_VERSION)}
        if self.points is not None and self._points_are_trajectories():
            arrays["points_from_trajectories"] = np.array(True)  # not stored twice
        elif self.points is not None:
            arrays["n_points"] = np.array([len(p) for p in self.points])
            arrays["points"] = np.concatenate([np.asarray(p, dtype=float) for p in self.points])
        for name, seq in (("sets", self.sets), ("tubes", self.tubes)):
            if seq is None:
                continue
            descs = []
            for k, s in enumerate(seq):
                desc, arrs = to_arrays(s, f"{name}.{k}")
                descs.append(desc)
                arrays.update(arrs)
            arrays[f"{name}_json"] = np.array(json.dumps(descs))
        if self.controls is not None:
            arrays["controls"] = self.controls
        if self.trajectories is not None:
            arrays["trajectories"] = self.trajectories
        arrays["meta_json"] = np.array(json.dumps(jsonable(self.meta)))
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        return atomic_write_bytes(path, buf.getvalue())

    def _points_are_trajectories(self) -> bool:
        """Whether ``points[k] == trajectories[:, k]`` for every k (then only one is written)."""
        tr = self.trajectories
        if tr is None or tr.ndim != 3 or tr.shape[1] != len(self.points):
            return False
        return all(np.array_equal(np.asarray(p), tr[:, k]) for k, p in enumerate(self.points))

    def __repr__(self) -> str:
        """A short description (``print(result)`` must not dump the arrays)."""
        what = (f"{len(self.sets)} sets ({type(self.sets[-1]).__name__})" if self.sets is not None
                else f"{len(self.points)} point clouds ({len(self.points[-1])} samples at the end)")
        flags = [f for f in ("guaranteed", "truncated") if self.meta.get(f)]
        t = self.times
        return (f"ReachResult(method={self.method!r}, problem={self.meta.get('problem', '?')!r}, "
                f"t={t[0]:g}..{t[-1]:g} ({t.size} times), {what}"
                + (f", tubes={len(self.tubes)}" if self.tubes is not None else "")
                + (f", {', '.join(flags)}" if flags else "") + ")")


def _directions(d: Any) -> np.ndarray:
    """``d`` as a float array of one ``(n,)`` or many ``(m, n)`` finite, non-zero directions."""
    try:
        arr = np.asarray(d, dtype=float)
    except (TypeError, ValueError):
        raise ProblemError(f"direction d must be an array of numbers; got {d!r}") from None
    if arr.ndim not in (1, 2) or arr.shape[-1] == 0 or arr.size == 0:
        raise ProblemError(f"direction d must have shape (n,) or (m, n); got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ProblemError(f"direction d must be finite; got {d!r}")
    if np.any(np.all(arr == 0, axis=-1)):
        raise ProblemError(f"direction d must be non-zero (a zero direction has no support); got {d!r}")
    return arr


#: What ``schema`` holds in a result file (with ``format_version``).
SCHEMA = "ocreach.ReachResult"
_EXPECTED = (f"an ocreach result file (.npz written by ReachResult.save, schema {SCHEMA!r}, "
             f"format_version {FORMAT_VERSION})")


def load(path: str | Path) -> ReachResult:
    """Read a result written by :meth:`ReachResult.save`.

    Only arrays and JSON are read (``allow_pickle=False``; sets are rebuilt by
    :mod:`ocreach.sets.serialize` from registered types only).  Anything else -- a text file, a
    truncated or foreign ``.npz``, a file of an older format with pickled sets -- raises one
    :class:`ProblemError` naming the file and what was expected.
    """
    path = Path(path)
    if not path.is_file():
        raise ProblemError(f"result file {str(path)!r} does not exist")
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic != b"PK\x03\x04":
        raise ProblemError(f"result file {str(path)!r} is not a .npz archive; expected {_EXPECTED}")
    try:
        with np.load(path, allow_pickle=False) as z:
            return _read(z, path)
    except OcreachError as exc:  # a malformed set descriptor or set arrays: name the file
        if str(path) in str(exc):
            raise
        raise ProblemError(f"result file {str(path)!r}: {exc}; expected {_EXPECTED}") from None
    except (OSError, ValueError, KeyError, IndexError, TypeError, EOFError,
            zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise ProblemError(f"result file {str(path)!r} is damaged or not an ocreach result "
                           f"({type(exc).__name__}: {exc}); expected {_EXPECTED}") from None


def _read(z: Any, path: Path) -> ReachResult:
    from ocreach.sets.serialize import from_arrays

    names = set(z.files)
    if "sets_pickle" in names or "tubes_pickle" in names:
        raise ProblemError(f"result file {str(path)!r} was written by an older ocreach that stored "
                           "sets as pickles; it is not read (unpickling runs code from the file). "
                           "Re-run the method to write the current format")
    if "schema" not in names or str(z["schema"]) != SCHEMA or "times" not in names:
        raise ProblemError(f"result file {str(path)!r} is a .npz without an ocreach result in it "
                           f"(members {sorted(names)[:8]}); expected {_EXPECTED}")
    version = int(z["format_version"])
    if version != FORMAT_VERSION:
        raise ProblemError(f"result file {str(path)!r} has format_version {version}; this ocreach "
                           f"reads version {FORMAT_VERSION}"
                           + (" (upgrade ocreach)" if version > FORMAT_VERSION else ""))
    points = None
    if "points_from_trajectories" in names:
        traj = z["trajectories"]
        points = [traj[:, k] for k in range(traj.shape[1])]
    elif "points" in names:
        split = np.cumsum(z["n_points"])[:-1]
        points = np.split(z["points"], split)
    seqs = {}
    for name in ("sets", "tubes"):
        if f"{name}_json" in names:
            descs = json.loads(str(z[f"{name}_json"]))
            if not isinstance(descs, list):
                raise ProblemError(f"result file {str(path)!r}: {name}_json must be a list")
            seqs[name] = [from_arrays(d, z) for d in descs]
    meta = json.loads(str(z["meta_json"]))
    if not isinstance(meta, dict):
        raise ProblemError(f"result file {str(path)!r}: meta_json must be a JSON object")
    return ReachResult(
        times=z["times"], sets=seqs.get("sets"), points=points,
        controls=z["controls"] if "controls" in names else None,
        trajectories=z["trajectories"] if "trajectories" in names else None,
        meta=meta, tubes=seqs.get("tubes"),
    )
