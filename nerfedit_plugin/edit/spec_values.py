"""Checks of edit-spec values shared by the spec, its selections and the deformers' own keys: each returns the
value it validated or raises the error of a bad entry, :func:`spec_error` (``"<source>: <key>: <problem>"``)."""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from nerfedit_plugin.errors import NerfEditError


def spec_error(source: str, key: str, problem: str) -> NerfEditError:
    """The error for a bad spec entry: ``"<source>: <key>: <problem>"`` (``source`` the file, ``key`` its dotted
    path, e.g. ``handles[0].select.box.min``)."""
    return NerfEditError(f"{source}: {key}: {problem}")


def check_keys(obj: Any, allowed: Iterable[str], source: str, key: str, required: Iterable[str] = ()) -> dict:
    """``obj`` itself if it is a mapping whose keys are all ``allowed`` and include every ``required`` one, else
    :func:`spec_error` naming the first offending key (``key`` "" for the top level)."""
    if not isinstance(obj, dict):
        raise spec_error(source, key, f"expected a mapping, got {type(obj).__name__}")
    allowed = set(allowed)
    for name in obj:
        if name not in allowed:
            raise spec_error(
                source, f"{key}.{name}" if key else str(name), f"unknown key (expected one of {sorted(allowed)})"
            )
    for name in required:
        if name not in obj:
            raise spec_error(source, f"{key}.{name}" if key else name, "missing")
    return obj


def vector(value: Any, source: str, key: str, n: int = 3) -> np.ndarray:
    """``value`` (a list of ``n`` finite numbers, not booleans) → (n,) float64, else :func:`spec_error` naming
    ``key``."""
    if isinstance(value, (list, tuple)) and any(isinstance(item, bool) for item in value):
        raise spec_error(source, key, f"expected {n} numbers, got {value!r}")
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an integer beyond float range
        raise spec_error(source, key, f"expected {n} numbers, got {value!r}") from None
    if arr.shape != (n,):
        raise spec_error(source, key, f"expected {n} numbers, got {value!r}")
    if not np.isfinite(arr).all():
        raise spec_error(source, key, "contains NaN or Inf")
    return arr


def number(value: Any, source: str, key: str, positive: bool = False) -> float:
    """``value`` (a finite int or float, not a bool; > 0 with ``positive``) → float, else :func:`spec_error`
    naming ``key``."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise spec_error(source, key, f"expected a number, got {value!r}")
    try:
        value = float(value)
    except OverflowError:  # an integer beyond float range
        raise spec_error(source, key, "is too large") from None
    if not math.isfinite(value):
        raise spec_error(source, key, "is NaN or Inf")
    if positive and value <= 0:
        raise spec_error(source, key, f"must be > 0, got {value}")
    return float(value)


def resolve_path(base_dir: Path, value: Any, source: str, key: str) -> Path:
    """``base_dir / value`` resolved; a name the OS cannot represent (a NUL byte, longer than the file system
    allows) is a spec error naming ``key``."""
    try:
        resolved = (base_dir / value).resolve()
        resolved.is_file()
    except (OSError, ValueError) as exc:
        raise spec_error(source, key, f"invalid file path {value!r:.200} ({exc!s:.200})") from None
    return resolved
