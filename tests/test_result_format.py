"""The result file format: arrays + JSON only."""
from __future__ import annotations

import io
import json
import pickle
import zipfile

import numpy as np
import pytest

import ocreach
from ocreach.errors import ProblemError
from ocreach.reach.result import ReachResult, load
from ocreach.sets import Ellipsoid, Interval, MatrixZonotope, PolyZonotope, PZUnion, Zonotope
from ocreach.sets.serialize import registered_types
from ocreach.sets.union import ZonotopeUnion


def _sets(rng):
    pz = PolyZonotope(rng.normal(size=3), rng.normal(size=(3, 4)), rng.normal(size=(3, 2)),
                      np.array([[1, 0, 2, 1], [0, 1, 1, 3]]), [17, 4])
    A = rng.normal(size=(3, 3))
    return {
        "Interval": Interval([-1.0, 0.0, 2.0], [1.0, 0.5, 3.0]),
        "Zonotope": Zonotope(rng.normal(size=3), rng.normal(size=(3, 5))),
        "PolyZonotope": pz,
        "Ellipsoid": Ellipsoid(rng.normal(size=3), A @ A.T),
        "MatrixZonotope": MatrixZonotope(rng.normal(size=(3, 3)), rng.normal(size=(2, 3, 3))),
        "PZUnion": PZUnion([pz, PolyZonotope(np.zeros(3), np.eye(3))]),
        "ZonotopeUnion": ZonotopeUnion([Zonotope(rng.normal(size=3), rng.normal(size=(3, 2))),
                                        Zonotope(np.zeros(3), np.eye(3))]),
    }


_FIELDS = {"Interval": ("lo", "hi"), "Zonotope": ("c", "G"), "PolyZonotope": ("c", "G", "GI", "E", "id"),
           "Ellipsoid": ("q", "Q"), "MatrixZonotope": ("C", "G")}


def _same(a, b):
    assert type(a) is type(b)
    if isinstance(a, (PZUnion, ZonotopeUnion)):
        assert len(a.parts) == len(b.parts)
        for p, q in zip(a.parts, b.parts):
            _same(p, q)
        return
    for f in _FIELDS[type(a).__name__]:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), f


def test_every_registered_type_is_covered():
    assert set(registered_types()) == set(_sets(np.random.default_rng(0)))


@pytest.mark.parametrize("kind", sorted(_FIELDS) + ["PZUnion"])
def test_round_trip_is_identical_for_every_set_type(tmp_path, kind):
    s = _sets(np.random.default_rng(1))[kind]
    times = np.linspace(0.0, 1.0, 3)
    r = ReachResult(times=times, sets=[s, s, s], tubes=[s, s],
                    meta={"method": "x", "options": {"a": 1}, "truncated": False})
    q = load(r.save(tmp_path / "r.npz"))
    assert np.array_equal(q.times, times) and q.meta == r.meta
    for a, b in zip(r.sets + r.tubes, q.sets + q.tubes):
        _same(a, b)


def test_round_trip_points_controls_trajectories(tmp_path):
    rng = np.random.default_rng(2)
    traj = rng.normal(size=(7, 4, 2))
    r = ReachResult.from_trajectories(np.arange(4.0), traj, controls=rng.normal(size=(7, 3, 1)),
                                      meta={"method": "mc"})
    q = load(r.save(tmp_path / "r.npz"))
    with np.load(tmp_path / "r.npz") as z:  # points are the trajectories' columns: stored once
        assert "points" not in z.files and "points_from_trajectories" in z.files
    assert np.array_equal(q.trajectories, traj) and np.array_equal(q.controls, r.controls)
    for a, b in zip(r.points, q.points):
        assert np.array_equal(a, b)


def test_file_holds_no_pickle(tmp_path):
    s = _sets(np.random.default_rng(3))
    r = ReachResult(times=np.arange(len(s), dtype=float), sets=list(s.values()), meta={"method": "x"})
    path = r.save(tmp_path / "r.npz")
    with np.load(path, allow_pickle=False) as z:  # every member readable without pickle
        for name in z.files:
            assert z[name].dtype != object


class _Evil:
    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))  # unpickling would create the marker file


def _evil_file(tmp_path, marker, **extra):
    payload = np.frombuffer(pickle.dumps([_Evil(marker)]), dtype=np.uint8)
    path = tmp_path / "evil.npz"
    np.savez(path, times=np.arange(1.0), format_version=np.array(1), sets_pickle=payload,
             meta_json=np.array("{}"), **extra)
    return path


def test_pickle_bearing_file_is_refused_without_running_it(tmp_path):
    marker = tmp_path / "pwned"
    for extra in ({}, {"schema": np.array("ocreach.ReachResult")}):
        path = _evil_file(tmp_path, marker, **extra)
        with pytest.raises(ProblemError, match="pickle") as exc:
            ocreach.load(path)
        assert str(path) in str(exc.value)
        assert not marker.exists()
    # an object array (pickle inside the .npy member) is refused as well
    path = tmp_path / "obj.npz"
    np.savez(path, schema=np.array("ocreach.ReachResult"), format_version=np.array(2),
             times=np.array([_Evil(marker)], dtype=object), meta_json=np.array("{}"))
    with pytest.raises(ProblemError, match="obj.npz"):
        ocreach.load(path)
    assert not marker.exists()


def _write(path, data: bytes):
    path.write_bytes(data)
    return path


def test_load_refuses_foreign_and_damaged_files(tmp_path):
    good = ReachResult(times=np.arange(2.0), sets=[Interval([0], [1])] * 2, meta={"method": "x"})
    raw = good.save(tmp_path / "good.npz").read_bytes()
    buf = io.BytesIO()
    np.savez(buf, a=np.zeros(3))
    cases = {
        "text": _write(tmp_path / "t.npz", b"hello, I am text\n"),
        "truncated": _write(tmp_path / "trunc.npz", raw[: len(raw) // 2]),
        "empty": _write(tmp_path / "empty.npz", b""),
        "wrong_npz": _write(tmp_path / "wrong.npz", buf.getvalue()),
    }
    # a result whose set descriptor names an unknown type, and one from a future version
    for name, mutate in (("unknown_type", lambda d: d.update(sets_json=np.array(json.dumps(
            [{"type": "os.system", "arrays": {}}] * 2)))),
                         ("future", lambda d: d.update(format_version=np.array(99))),
                         ("bad_meta", lambda d: d.update(meta_json=np.array("[1, 2")))):
        with np.load(tmp_path / "good.npz") as z:
            d = {k: z[k] for k in z.files}
        mutate(d)
        cases[name] = tmp_path / f"{name}.npz"
        np.savez(cases[name], **d)
    for name, path in cases.items():
        with pytest.raises(ProblemError) as exc:
            load(path)
        msg = str(exc.value)
        assert str(path) in msg, name
    assert zipfile.is_zipfile(tmp_path / "good.npz")


def test_print_result_is_short():
    traj = np.zeros((5000, 50, 6))
    r = ReachResult.from_trajectories(np.arange(50.0), traj, meta={"method": "mc", "problem": "p"})
    assert len(repr(r)) < 300 and "mc" in repr(r)


def test_json_text_is_strict_json():
    """Output files hold strict JSON: NaN and infinities (numpy or Python, nested) become null,
    numpy values become Python values, and a strict parser reads the text back."""
    from ocreach.fileio import json_text

    obj = {"a": float("nan"), "b": [np.float64(np.inf), -np.inf, 1.5], "c": {"d": np.array([1.0, np.nan])},
           "e": np.int64(3), 4: "four"}

    def refuse(name):
        raise ValueError(name)

    back = json.loads(json_text(obj), parse_constant=refuse)
    assert back == {"a": None, "b": [None, None, 1.5], "c": {"d": [1.0, None]}, "e": 3, "4": "four"}
