"""The C compiler call and the on-disk cache of compiled libraries.

Everything ocreach caches on disk lives under one root, ``$OCREACH_CACHE_DIR`` (default
``~/.cache/ocreach``): shared libraries in ``<root>/jit``, solved CUT rules in
``<root>/cut_rules`` (:mod:`ocreach.dynamics.quadrature`).  A library's file name carries a hash of its
sources, the compiler and the flags, so a cached file is never stale.

Concurrency: several processes (or hosts sharing the cache over a network file system) may build
the same kernel at once.  Each builds in its own private temporary directory, copies the result
into the cache under a temporary name unique to it (host name, process id and a random part),
and publishes it with one atomic ``os.replace``; readers only ever see a complete library (the
builds are byte-identical, so whichever rename lands last is as good as the first).  No locks
(``flock`` is unreliable on network file systems), no partially written file under a final name.
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import secrets
import shutil
import socket
import subprocess
import tempfile
import warnings
from pathlib import Path

import casadi as ca

from ocreach.native.codegen import generate_c

__all__ = ["COMPILE_ERRORS", "cache_dir", "compile_function", "compile_source", "jit_enabled",
           "load_library", "opt_flags", "write_atomic"]

#: What a failed C build raises (no compiler or a failing one: RuntimeError; unwritable cache or a
#: library that will not load: OSError).  Callers fall back to CasADi's VM or NumPy on these and
#: only these, so a programming error in a kernel builder is not hidden behind a warning.
COMPILE_ERRORS: tuple[type[BaseException], ...] = (RuntimeError, OSError)


def jit_enabled() -> bool:
    """True unless C compilation is switched off (environment ``OCREACH_JIT=0``)."""
    return os.environ.get("OCREACH_JIT", "1") not in ("0", "false", "no")


def cache_dir(kind: str = "jit") -> Path:
    """``<root>/<kind>`` with root ``$OCREACH_CACHE_DIR`` (default ``~/.cache/ocreach``):
    ``"jit"`` holds the compiled libraries, ``"cut_rules"`` the CUT rules."""
    root = os.environ.get("OCREACH_CACHE_DIR")
    base = Path(root) if root else Path.home() / ".cache" / "ocreach"
    return base / kind


def _temp_name(path: Path) -> Path:
    """A name next to ``path`` that no other process or host uses at the same time."""
    host = "".join(c if c.isalnum() else "-" for c in socket.gethostname())[:40] or "host"
    return path.with_name(f".{path.name}.{host}.{os.getpid()}.{secrets.token_hex(6)}.tmp")


def write_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` through a unique temporary name and ``os.replace`` (atomic)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def _compiler() -> str:
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        raise RuntimeError("no C compiler found (set CC)")
    return cc


def compile_source(name: str, sources: dict[str, bytes], main: str, flags: tuple[str, ...]) -> Path:
    """Compile C ``sources`` (file name -> bytes; ``main`` is the translation unit) into a shared
    library cached on disk by a hash of sources, compiler and flags; returns its path.

    Raises ``RuntimeError`` if there is no compiler or it fails, ``OSError`` if the cache cannot
    be written (both in :data:`COMPILE_ERRORS`).
    """
    cc = _compiler()
    digest = hashlib.sha256()
    for key in sorted(sources):
        digest.update(key.encode() + b"\0" + sources[key] + b"\0")
    digest.update(" ".join((cc, *flags)).encode())
    lib = cache_dir("jit") / f"{name}_{digest.hexdigest()[:20]}.so"
    if lib.exists():
        return lib
    lib.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="ocreach-cc-") as tmp:
        for key, text in sources.items():
            Path(tmp, key).write_bytes(text)
        # relative names and cwd = the build folder: the library does not depend on where it was built
        proc = subprocess.run([cc, *flags, "-shared", "-fPIC", "-o", "lib.so", main, "-lm"],
                              cwd=tmp, capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{cc} failed on {name}: {proc.stderr[-2000:]}")
        write_atomic(lib, Path(tmp, "lib.so").read_bytes())
    return lib


def load_library(path: Path) -> ctypes.CDLL:
    """The shared library at ``path`` (ctypes releases the GIL while its functions run)."""
    return ctypes.CDLL(str(path))


def opt_flags(source_size: int) -> tuple[str, ...]:
    """Optimisation level: ``-O2`` for ordinary sources; huge generated sources (order-3 STTs of
    the spatial CR3BP, ~1.5 MB of straight-line C) take minutes at -O1/-O2, so they get ``-O0``
    (seconds).  ``OCREACH_JIT_FLAGS`` overrides (space separated)."""
    env = os.environ.get("OCREACH_JIT_FLAGS")
    if env:
        return tuple(env.split())
    return ("-O0",) if source_size > 400_000 else ("-O2",)


def compile_function(fun: ca.Function, flags: tuple[str, ...] = ("-O2",)) -> ca.Function:
    """Compile ``fun`` to C (cached on disk by source hash) and load it as a CasADi external.

    Returns ``fun`` unchanged (with a warning) if compilation is disabled or fails.
    """
    if not jit_enabled():
        return fun
    try:
        lib = compile_source(fun.name(), {"gen.c": generate_c([fun])}, "gen.c", flags)
        return ca.external(fun.name(), str(lib))
    except COMPILE_ERRORS as exc:  # compiler missing or failing: the VM gives the same numbers
        warnings.warn(f"ocreach.native: compiling {fun.name()} failed ({exc}); "
                      "using CasADi's interpreted VM instead", RuntimeWarning, stacklevel=2)
        return fun
