"""Interrupts of real ``nerfedit`` processes: SIGINT/SIGTERM give one line, exit 130/143, no traceback, no staging
folder left, and the previous output at the same path (``--overwrite``) intact.

The signal is sent once the process is inside the work, never after a fixed sleep: ``train`` announces the start of
its training loop on stderr (a driver wraps the trainer's progress context), ``generate`` is caught once its staging
folder exists.
"""

import os
import selectors
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nerfedit_plugin.io.atomic import STAGING

MARK = "nerfedit-test: training"
DRIVER = f"""
import sys
from nerfedit_plugin.training import trainer
enter = trainer._Progress.__enter__
def announce(self):
    print({MARK!r}, file=sys.stderr, flush=True)
    return enter(self)
trainer._Progress.__enter__ = announce
from nerfedit_plugin.cli.app import main
sys.exit(main())
"""
TIMEOUT = 180.0


def start(*argv: str) -> subprocess.Popen:
    def default_signals() -> None:  # a background job of a non-interactive shell starts with SIGINT ignored
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    return subprocess.Popen(
        [sys.executable, "-c", DRIVER, *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signals,
        env={**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "200"},
    )


def wait_for_line(proc: subprocess.Popen, mark: str) -> list[str]:
    """stderr lines up to the one holding ``mark`` (fails if the process ends first or after ``TIMEOUT``)."""
    lines, deadline = [], time.monotonic() + TIMEOUT
    with selectors.DefaultSelector() as selector:
        selector.register(proc.stderr, selectors.EVENT_READ)
        while time.monotonic() < deadline:
            if selector.select(timeout=1.0):
                line = proc.stderr.readline()
                assert line, f"exited {proc.wait()} before {mark!r}: {''.join(lines)}"
                lines.append(line)
                if mark in line:
                    return lines
    proc.kill()
    pytest.fail(f"no {mark!r} within {TIMEOUT} s")


def wait_for_staging(proc: subprocess.Popen, parent: Path) -> Path:
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline and proc.poll() is None:
        staged = [p for p in parent.iterdir() if STAGING in p.name]
        if staged:
            return staged[0]
        time.sleep(0.02)
    proc.kill()
    pytest.fail(f"no staging folder in {parent} (exit code {proc.poll()})")


def previous_output(out: Path) -> dict:
    """A previous output at ``out`` (what ``--overwrite`` would replace only after success); its files' bytes."""
    out.mkdir()
    (out / "config.yml").write_text("previous: good\n")
    (out / "field.pt").write_bytes(b"\x00previous good bytes")
    return {p.name: p.read_bytes() for p in out.iterdir()}


def assert_interrupted(proc: subprocess.Popen, signum: int, before: list[str], parent: Path) -> str:
    _, err = proc.communicate(timeout=TIMEOUT)
    assert proc.returncode == 128 + signum, err
    lines = err.splitlines()
    assert len(lines) == 1 and "Traceback" not in err, before + lines
    assert "interrupted" in lines[0] and signal.Signals(signum).name in lines[0]
    assert not [p for p in parent.iterdir() if STAGING in p.name]
    return lines[0]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_training_writes_nothing_and_keeps_the_previous_run(tiny_scene, tmp_path, signum):
    good = previous_output(tmp_path / "run")
    proc = start(
        "train",
        "--data",
        str(tiny_scene),
        "--out",
        str(tmp_path / "run"),
        "--overwrite",
        "--device",
        "cpu",
        "--field-options.train.max-seconds",
        "600",
        "--field-options.train.batch-rays",
        "64",
    )
    before = wait_for_line(proc, MARK)
    proc.send_signal(signum)
    line = assert_interrupted(proc, signum, before, tmp_path)
    assert line.endswith("nothing written")
    assert {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir()} == good
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_interrupted_staged_write_removes_its_staging_folder(tmp_path, signum):
    good = previous_output(tmp_path / "scene")
    proc = start(
        "generate",
        "--out",
        str(tmp_path / "scene"),
        "--overwrite",
        "--mesh",
        "sample:cow",
        "--resolution",
        "64",
        "--n-train",
        "400",
        "--supersample",
        "1",
    )
    stage = wait_for_staging(proc, tmp_path)
    assert stage.name.startswith(f".scene.{STAGING}.") and f".{proc.pid}." in stage.name
    proc.send_signal(signum)
    line = assert_interrupted(proc, signum, [], tmp_path)
    assert line.endswith("nothing written") and not stage.exists()
    assert {p.name: p.read_bytes() for p in (tmp_path / "scene").iterdir()} == good


EARLY = """
import importlib.abc, os, signal, sys
class Interrupt(importlib.abc.MetaPathFinder):  # the signal arrives while the command line loads
    def find_spec(self, name, path=None, target=None):
        if name == {module!r}:
            os.kill(os.getpid(), signal.{signal})
        return None
sys.meta_path.insert(0, Interrupt())
sys.argv = ["nerfedit", "plugins"]
from nerfedit_plugin.cli import main
sys.exit(main())
"""


@pytest.mark.parametrize(
    "module, signame", [("nerfedit_plugin.cli.app", "SIGINT"), ("nerfedit_plugin.io.atomic", "SIGTERM")]
)
def test_a_signal_while_the_command_line_loads_is_one_line(module, signame):
    """The console script's handlers come first: a signal before the command's own (the command line's imports,
    about 30 ms) ends it like a later interrupt, not with Python's traceback."""
    done = subprocess.run(
        [sys.executable, "-c", EARLY.format(module=module, signal=signame)], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 128 + getattr(signal, signame), done.stderr
    assert done.stderr == f"nerfedit: interrupted ({signame}) while starting; nothing was written\n"
