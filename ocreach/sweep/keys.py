"""Task keys: a stable hash of a task's canonical JSON and the package versions.

The key names a task in the log and its result file; the same task under the same versions has
the same key in every process, on every host and in every run, so a re-run skips it.
"""
from __future__ import annotations

import hashlib
import json
import platform
from functools import cache
from typing import Any

#: packages whose version changes numerical results (part of every key)
VERSIONED = ("ocreach", "casadi", "numpy", "scipy")
KEY_LENGTH = 24  # hex digits (96 bits)


def canonical_json(obj: Any) -> str:
    """Compact JSON with sorted keys and no NaN: the same data always gives the same text."""
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def digest(obj: Any) -> str:
    """SHA-256 (hex) of :func:`canonical_json` of ``obj``."""
    return hashlib.sha256(canonical_json(obj).encode("ascii")).hexdigest()


@cache
def versions() -> dict[str, str]:
    """Versions of the packages in :data:`VERSIONED` and of Python."""
    from importlib import metadata

    out = {}
    for name in VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = str(getattr(__import__(name), "__version__", "unknown"))
    out["python"] = platform.python_version()
    return out


def task_key(task: dict[str, Any], package_versions: dict[str, str] | None = None) -> str:
    """The key of a normalised task (:func:`ocreach.sweep.spec.normalize_task`)."""
    vers = versions() if package_versions is None else package_versions
    return digest({"task": task, "versions": vers})[:KEY_LENGTH]
