"""A disk cache of processed images (undistorted and/or downscaled frames), so a capture is processed once.

An entry is one ``.npz`` of float32/bool arrays, named by the SHA-256 of its sources (absolute path, size and
modification time of each file) and of the processing parameters, so an edited photo or another ``--downscale``
misses. Entries are written atomically; an unreadable entry is recomputed. The folder is ``$NERFEDIT_CACHE/images``,
else ``$XDG_CACHE_HOME/nerfedit/images`` (``~/.cache/nerfedit/images``); delete it at will.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from nerfedit_plugin.io.atomic import atomic_path

VERSION = 1
"""Bumped when the processing changes, so old entries miss."""


def cache_dir() -> Path:
    """The cache folder (see the module docstring)."""
    if "NERFEDIT_CACHE" in os.environ:
        return Path(os.environ["NERFEDIT_CACHE"]) / "images"
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "nerfedit" / "images"


def cache_key(sources: Sequence[Path | None], params) -> str:
    """Hex SHA-256 of the sources' identities (path, size, mtime; None for an absent source) and ``repr(params)``."""
    digest = hashlib.sha256(f"v{VERSION}|{params!r}".encode())
    for source in sources:
        if source is None:
            digest.update(b"|-")
            continue
        stat = Path(source).stat()
        digest.update(f"|{Path(source).resolve()}|{stat.st_size}|{stat.st_mtime_ns}".encode())
    return digest.hexdigest()


def cached(sources: Sequence[Path | None], params, compute: Callable[[], dict[str, np.ndarray]]) -> dict:
    """The arrays ``compute()`` returns for these ``sources`` and ``params``, from the cache when present."""
    path = cache_dir() / f"{cache_key(sources, params)}.npz"
    if path.is_file():
        try:
            with np.load(path) as entry:
                return {key: entry[key] for key in entry.files}
        except (OSError, ValueError):  # truncated or corrupt: recompute
            pass
    arrays = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        np.savez(stream, **arrays)
    return arrays
