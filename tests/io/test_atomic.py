"""The output-folder convention of ``nerfedit_plugin.io.atomic``: complete, absent or explicitly partial; staging
entries named by their writer's PID, stale ones removed on the next write; modes that follow the umask."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io import atomic
from nerfedit_plugin.io.atomic import (
    PARTIAL,
    STAGING,
    atomic_dir,
    atomic_path,
    clean_stale,
    is_partial,
    mark_partial,
    require_complete,
    write_text,
)
from nerfedit_plugin.pipeline.run import open_run


@pytest.fixture(scope="module")
def dead_pid() -> int:
    """The PID of a process that has exited (and been reaped)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def staged(parent: Path, name: str, pid: int, *, old: bool = False, suffix: str = "") -> Path:
    """A staging name as another process would have made it (this host, ``pid``)."""
    ours = atomic.staging_name(name, suffix, old)
    return parent / ours.replace(f".{os.getpid()}.", f".{pid}.", 1)


def test_staging_entries_carry_the_writers_pid_and_vanish_on_success(tmp_path):
    seen = []
    with atomic_dir(tmp_path / "out") as stage:
        seen.append(stage.name)
        with atomic_path(stage / "mesh.ply") as tmp:
            seen.append(Path(tmp).name)
            Path(tmp).write_text("ply")
    assert seen[0].startswith(f".out.{STAGING}.") and f".{os.getpid()}." in seen[0]
    assert seen[1].startswith(f".mesh.{STAGING}.") and seen[1].endswith(".ply")  # the suffix stays last
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["mesh.ply"]


def test_an_error_removes_the_staging_folder_and_keeps_the_previous_output(tmp_path):
    write_text(tmp_path / "out" / "a.txt", "previous")
    with pytest.raises(KeyboardInterrupt), atomic_dir(tmp_path / "out", overwrite=True) as stage:
        (stage / "a.txt").write_text("new")
        raise KeyboardInterrupt
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    assert (tmp_path / "out" / "a.txt").read_text() == "previous"


def test_stale_staging_entries_of_dead_processes_go_on_the_next_write(tmp_path, dead_pid):
    stale_dir = staged(tmp_path, "good", dead_pid)
    stale_dir.mkdir()
    (stale_dir / "field.pt").write_bytes(b"half")
    stale_file = staged(tmp_path, "log", dead_pid, suffix=".json")
    stale_file.write_text("{")
    live = tmp_path / atomic.staging_name("busy")  # this process's: a write in progress
    live.mkdir()
    other_host = tmp_path / f".good.{STAGING}.elsewhere-host.{dead_pid}.0123abcd"  # shared file systems
    other_host.mkdir()
    unrelated = tmp_path / ".good.not-ours"
    unrelated.mkdir()
    with atomic_dir(tmp_path / "next") as stage:
        (stage / "x").write_text("x")
    assert not stale_dir.exists() and not stale_file.exists()
    assert live.is_dir() and other_host.is_dir() and unrelated.is_dir()
    assert clean_stale(tmp_path) == []


def test_a_previous_output_parked_by_an_interrupted_swap_is_put_back(tmp_path, dead_pid):
    parked = staged(tmp_path, "run", dead_pid, old=True)
    (parked / "run").mkdir(parents=True)
    (parked / "run" / "config.yml").write_text("good")
    stage = staged(tmp_path, "run", dead_pid)
    stage.mkdir()
    assert sorted(clean_stale(tmp_path)) == sorted([parked, stage])
    assert [p.name for p in tmp_path.iterdir()] == ["run"] and (tmp_path / "run" / "config.yml").read_text() == "good"


def test_a_partial_folder_is_left_alone_refused_by_readers_and_replaced_only_with_overwrite(tmp_path, dead_pid):
    run = tmp_path / "run"
    mark_partial(run, {"steps": 100})
    (run / "field.pt").write_bytes(b"checkpoint at step 100")
    (run / "config.yml").write_text("field: nerf\ndata: .\n")
    assert is_partial(run) and clean_stale(tmp_path) == [] and sorted(p.name for p in run.iterdir())[0] == PARTIAL
    with pytest.raises(NerfEditError, match="partial run folder"):
        open_run(run)
    with pytest.raises(NerfEditError, match="partial"):
        require_complete(run)
    with pytest.raises(NerfEditError, match="a partial output .*; pass --overwrite to replace it$"), atomic_dir(run):
        pass  # a writer that cannot resume (train) does not offer --resume
    with pytest.raises(NerfEditError, match="pass --resume to continue it or"), atomic_dir(run, resume=False):
        pass
    with atomic_dir(run, overwrite=True) as stage:
        (stage / "config.yml").write_text("complete")
    assert not is_partial(run) and [p.name for p in run.iterdir()] == ["config.yml"]


@pytest.fixture(params=[0o022, 0o077])
def umask(request):
    previous = os.umask(request.param)
    yield request.param
    os.umask(previous)


def test_modes_follow_the_umask(tmp_path, umask):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    (tmp_path / "plain").mkdir()
    write_text(tmp_path / "atomic.txt", "x")
    with atomic_dir(tmp_path / "folder") as stage:
        with atomic_path(stage / "inner.txt") as tmp:
            Path(tmp).write_text("x")
        (stage / "sub").mkdir()

    def mode(path):
        return path.stat().st_mode & 0o777

    assert mode(tmp_path / "atomic.txt") == mode(plain) == 0o666 & ~umask
    assert mode(tmp_path / "folder" / "inner.txt") == 0o666 & ~umask
    assert mode(tmp_path / "folder") == mode(tmp_path / "plain") == mode(tmp_path / "folder" / "sub") == 0o777 & ~umask


def test_completed_outputs_are_recorded_but_not_the_files_inside_a_staging_folder(tmp_path):
    since = len(atomic.committed)
    with atomic_dir(tmp_path / "out") as stage:
        write_text(stage / "inside.txt", "x")
    write_text(tmp_path / "alone.txt", "x")
    assert atomic.committed[since:] == [tmp_path / "out", tmp_path / "alone.txt"]


@pytest.mark.parametrize("writer", ["dir", "path"])
def test_an_output_the_os_refuses_is_one_error_naming_it(tmp_path, writer):
    """A file where a folder must be, or a name longer than the file system allows: a NerfEditError naming the
    path, nothing written."""
    (tmp_path / "afile").write_text("x")
    open_output = atomic_dir if writer == "dir" else atomic_path
    with pytest.raises(NerfEditError, match="afile is a file, not a folder"):
        with open_output(tmp_path / "afile" / "out"):
            pass
    with pytest.raises(NerfEditError, match="cannot write here"):
        with open_output(tmp_path / ("a" * 300)):
            pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]
