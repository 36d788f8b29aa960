"""Atomic outputs: every file and folder nerfedit writes is complete, absent, or explicitly partial.

- :func:`atomic_path` (files) and :func:`atomic_dir` (folders) write into a *staging* sibling named
  ``.NAME.nerfedit-staging.HOST.PID.RANDOM`` (files keep their suffix after it) and ``os.replace`` it onto the target
  on success; on any error — including ``KeyboardInterrupt`` and the SIGTERM that ``nerfedit`` turns into one — the
  staging entry is removed. The rename (and the cleanup) runs with SIGINT/SIGTERM deferred, so an interrupt never
  splits a replacement in two.
- A staging entry left by a process that died without cleaning up (SIGKILL, a crash, a power cut) is removed by the
  next write into the same folder (:func:`clean_stale`): one whose PID is not alive on this host. A replaced
  output parked during an ``--overwrite`` swap (``.NAME.nerfedit-staging-old.…``) is put back first when the target
  is missing.
- A *partial* output — kept on purpose so that work can resume — holds the marker file :data:`PARTIAL`
  (:func:`mark_partial`); readers refuse it (:func:`require_complete`), writers replace it only with ``overwrite``,
  and the cleanup never touches it.
- Staging entries are created with the modes of any other writer (``0o666``/``0o777`` less the umask), not
  ``tempfile``'s private ``0o600``/``0o700``.

See docs/reliability.md.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import signal
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

from nerfedit_plugin.io.faults import fault_point

STAGING = "nerfedit-staging"
"""The tag in the name of every staging file and folder."""
PARTIAL = ".nerfedit-partial"
"""The marker file of a partial (resumable, not complete) output folder."""

_HOST = re.sub(r"[^A-Za-z0-9-]", "-", socket.gethostname()) or "localhost"
_STAGED = re.compile(
    rf"^\.(?P<name>.+)\.{STAGING}(?P<old>-old)?\.(?P<host>[A-Za-z0-9-]+)\.(?P<pid>\d+)\.[0-9a-f]{{8}}(?:\.|$)"
)
_cleaned: set[Path] = set()

committed: list[Path] = []
"""Every output this process completed, in order (``nerfedit`` names those kept when it is interrupted)."""


def staging_name(name: str, suffix: str = "", old: bool = False) -> str:
    """A fresh staging name for the output ``name`` (``suffix`` appended, e.g. ``.ply``)."""
    tag = f"{STAGING}-old" if old else STAGING
    return f".{name}.{tag}.{_HOST}.{os.getpid()}.{secrets.token_hex(4)}{suffix}"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    if os.name != "posix":  # no harmless liveness probe (os.kill would terminate it): assume it runs
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def clean_stale(folder: str | os.PathLike) -> list[Path]:
    """Remove the staging entries in ``folder`` left by processes of this host that are no longer alive (and put
    back an output parked by an interrupted ``--overwrite`` swap). Returns the removed paths."""
    folder, removed = Path(folder), []
    try:
        entries = [entry.name for entry in os.scandir(folder) if entry.name.startswith(".") and STAGING in entry.name]
    except OSError:
        return removed
    for name in entries:
        match = _STAGED.match(name)
        if match is None or match["host"] != _HOST or _alive(int(match["pid"])):
            continue
        path = folder / name
        with _uninterrupted(), contextlib.suppress(OSError):
            if match["old"] and (path / match["name"]).is_dir() and not (folder / match["name"]).exists():
                os.replace(path / match["name"], folder / match["name"])
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            else:
                path.unlink()
            removed.append(path)
    return removed


def _clean_once(folder: Path) -> None:
    """:func:`clean_stale` for the files of a folder: once per process and folder (files are written by the many)."""
    key = folder.resolve()
    if key not in _cleaned:
        _cleaned.add(key)
        clean_stale(folder)


def _make_parent(path: Path) -> None:
    """Create ``path``'s folder; a path the OS refuses (a file where a folder must be, a name too long, no permission)
    is a :class:`NerfEditError` naming it."""
    from nerfedit_plugin.errors import NerfEditError

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.exists()  # raises for a name longer than the file system allows
    except OSError as exc:
        blocking = next((p for p in path.parents if p.is_file()), None)
        reason = f"{blocking} is a file, not a folder" if blocking is not None else exc.strerror or str(exc)
        raise NerfEditError(f"{path}: cannot write here ({reason})") from None


def _create(folder: Path, name: str, suffix: str = "", *, directory: bool, old: bool = False) -> Path:
    """Create a fresh staging file or folder (modes: those of any other writer, the umask applies)."""
    while True:
        path = folder / staging_name(name, suffix, old)
        try:
            if directory:
                os.mkdir(path, 0o777)
            else:
                os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            return path
        except FileExistsError:
            continue


@contextlib.contextmanager
def _uninterrupted() -> Iterator[None]:
    """Defer SIGINT/SIGTERM for the block (in the main thread; elsewhere signals do not interrupt anyway): a signal
    received meanwhile is handled by the previous handler when the block ends."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    signums = [signal.SIGINT, signal.SIGTERM]
    previous = {}
    for signum in signums:
        if signal.getsignal(signum) is not None:  # None: a handler installed outside Python, left alone
            previous[signum] = signal.signal(signum, lambda s, _: pending.append(s))
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        if pending:
            handler = previous.get(pending[0])
            if callable(handler):
                handler(pending[0], None)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(pending[0])


def _record(path: Path) -> None:
    if STAGING not in str(path):  # written inside a staging folder: part of an output, not one
        committed.append(path)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """Yield a staging path in ``path``'s folder; on success it replaces ``path``, on error it is removed.

    The staging name keeps ``path``'s suffix so writers that choose a format by suffix behave.
    """
    path = Path(path)
    _make_parent(path)
    _clean_once(path.parent)
    tmp = _create(path.parent, path.stem, path.suffix, directory=False)
    try:
        yield str(tmp)
        fault_point("atomic.file.staged")
        with _uninterrupted():
            os.replace(tmp, path)
            _record(path)
    except BaseException:
        with _uninterrupted(), contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)


@contextlib.contextmanager
def atomic_dir(
    path: str | os.PathLike, overwrite: bool = False, keep_partial: bool = False, resume: bool | None = None
) -> Iterator[Path]:
    """Yield a staging folder beside ``path``; on success it becomes ``path``, on error it is removed.

    An existing non-empty ``path`` (or a partial one) is an error unless ``overwrite`` (then it is replaced only
    after success). Stale staging entries of dead processes beside ``path`` are removed first. With
    ``keep_partial``, a staging folder marked partial (:func:`mark_partial`) when the error strikes becomes ``path``
    instead of being removed — when nothing is at ``path`` (a previous output is never replaced by a partial one).
    With ``resume``, a partial output at ``path`` becomes the staging folder (the writer continues it); ``None`` (the
    default) says the writer cannot resume, so the error on a partial output does not offer it.
    """
    from nerfedit_plugin.errors import NerfEditError

    path = Path(path)
    _make_parent(path)
    if path.exists() and not path.is_dir():
        raise NerfEditError(f"{path}: exists and is not a folder")
    resuming = bool(resume) and path.is_dir() and is_partial(path)
    if path.is_dir() and any(path.iterdir()) and not overwrite and not resuming:
        if is_partial(path):
            how = (
                "pass --overwrite to replace it"
                if resume is None
                else "pass --resume to continue it or --overwrite to replace it"
            )
            raise NerfEditError(f"{path}: a partial output (it holds {PARTIAL}); {how}")
        raise NerfEditError(f"{path}: output folder exists and is not empty (pass --overwrite to replace it)")
    clean_stale(path.parent)
    stage = _create(path.parent, path.name, directory=True)
    old = None
    try:
        if resuming:  # inside the try: a signal right after the move puts the partial output back
            with _uninterrupted():
                os.replace(path, stage)
        yield stage
        fault_point("atomic.dir.staged")
        with _uninterrupted():
            if path.is_dir():
                old = _create(path.parent, path.name, directory=True, old=True)
                os.replace(path, old / path.name)
                fault_point("atomic.dir.swap")
            os.replace(stage, path)
            _record(path)
            fault_point("atomic.dir.committed")
    except BaseException:
        with _uninterrupted():
            if old is not None and (old / path.name).is_dir() and not path.exists():
                os.replace(old / path.name, path)  # the swap failed half-way: the previous output goes back
            if (keep_partial or resuming) and stage.is_dir() and is_partial(stage) and not _occupied(path):
                os.replace(stage, path)
                _record(path)
            shutil.rmtree(stage, ignore_errors=True)
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _occupied(path: Path) -> bool:
    """Something is at ``path`` (an empty folder is not something)."""
    return path.exists() and not (path.is_dir() and not any(path.iterdir()))


def mark_partial(folder: str | os.PathLike, info: dict | None = None) -> Path:
    """Mark ``folder`` as a partial output (write :data:`PARTIAL`, JSON ``info``, e.g. what is done): write it
    before anything else of the folder, and remove it last, once the folder is complete."""
    marker = Path(folder) / PARTIAL
    write_text(marker, json.dumps(info or {}))
    return marker


def clear_partial(folder: str | os.PathLike) -> None:
    """Remove the :data:`PARTIAL` marker: the last step of completing a folder that was marked partial."""
    with contextlib.suppress(FileNotFoundError):
        os.unlink(Path(folder) / PARTIAL)


def partial_info(folder: str | os.PathLike) -> dict | None:
    """The JSON info of ``folder``'s :data:`PARTIAL` marker (``None`` when it has none or it is unreadable)."""
    try:
        info = json.loads((Path(folder) / PARTIAL).read_text())
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) else None


def is_partial(folder: str | os.PathLike) -> bool:
    """Whether ``folder`` is a partial output (holds :data:`PARTIAL`)."""
    return (Path(folder) / PARTIAL).exists()


def require_complete(folder: str | os.PathLike, what: str = "output") -> None:
    """Raise a :class:`~nerfedit_plugin.errors.NerfEditError` when ``folder`` is a partial output."""
    from nerfedit_plugin.errors import NerfEditError

    if is_partial(folder):
        raise NerfEditError(
            f"{folder}: a partial {what}, not a complete one (it holds {PARTIAL}: it was interrupted); "
            "write it again with --overwrite"
        )
