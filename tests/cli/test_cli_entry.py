"""``nerfedit`` itself: the overview without/with --help (fast: no subcommand imported), and interrupts in-process
(the signal handlers of ``main``, the one line naming what was kept, the deferred commit)."""

import dataclasses
import inspect
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nerfedit_plugin.cli import app
from nerfedit_plugin.cli.app import COMMANDS, Interrupted, _first_sentence, command, description, interrupts_raise, main
from nerfedit_plugin.cli.common import Command
from nerfedit_plugin.io import atomic
from nerfedit_plugin.io.atomic import STAGING, atomic_dir


def test_no_arguments_prints_the_overview_to_stderr_and_exits_2(capsys):
    assert main([]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith("usage: nerfedit {train,")
    for name in COMMANDS:
        assert f"  {name:<8}  {description(name)}\n" in err


@pytest.mark.parametrize("flag", ["--help", "-h"])
def test_help_prints_the_same_overview_and_exits_0(capsys, flag):
    assert main([flag]) == 0
    out, err = capsys.readouterr()
    assert err == "" and out.strip() == app.overview()
    assert "  train     Train a field backend on a dataset" in out


def test_descriptions_are_the_first_sentence_of_each_args_docstring():
    for name in COMMANDS:
        doc = " ".join(inspect.getdoc(command(name).args).split())
        line = description(name)
        assert line.endswith(".") and 20 < len(line) <= 120, (name, line)
        assert doc.startswith(line[:-1]), (name, line)
        assert line.count("(") == line.count(")"), (name, line)
    assert _first_sentence("W" * 100 + " (x: " + "y" * 30 + ". More.") == "W" * 100 + "."
    assert description("demo") == "The whole pipeline on the built-in bunny scene, on the CPU."


def test_help_imports_no_subcommand_torch_or_tyro():
    code = (
        "import sys\nfrom nerfedit_plugin.cli import main\nassert main(['--help']) == 0\n"
        "heavy = {'torch', 'tyro', 'rich', 'numpy'} | {'nerfedit_plugin.cli.' + m for m in "
        "('train', 'extract', 'edit', 'render', 'evaluate', 'view', 'generate', 'demo', 'plugins', 'common')}\n"
        "assert not heavy & set(sys.modules), heavy & set(sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr


def test_sigterm_raises_interrupted_in_the_block_and_handlers_come_back():
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(Interrupted) as raised, interrupts_raise():
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # interrupted long before
    assert raised.value.signum == signal.SIGTERM and isinstance(raised.value, KeyboardInterrupt)
    assert signal.getsignal(signal.SIGTERM) is before


def test_an_ignored_signal_stays_ignored():
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with interrupts_raise():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_signal_during_a_commit_waits_for_its_end(tmp_path):
    with pytest.raises(Interrupted), interrupts_raise(), atomic._uninterrupted():
        os.kill(os.getpid(), signal.SIGTERM)
        (tmp_path / "after-the-signal").write_text("still written")
    assert (tmp_path / "after-the-signal").read_text() == "still written"


@dataclasses.dataclass
class TwoFolders:
    """Write one folder, then get interrupted while writing the second."""

    out: Path


def write_then_get_terminated(args: TwoFolders) -> None:
    with atomic_dir(args.out / "first") as stage:
        (stage / "a").write_text("a")
    with atomic_dir(args.out / "second") as stage:
        (stage / "b").write_text("b")
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)


def test_the_one_line_names_what_was_kept(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(app, "command", lambda name: Command(name, TwoFolders, write_then_get_terminated))
    assert main(["train", "--out", str(tmp_path)]) == 143
    err = capsys.readouterr().err
    assert err == f"nerfedit train: interrupted (SIGTERM); kept (complete): {tmp_path / 'first'}\n"
    assert [p.name for p in tmp_path.iterdir()] == ["first"] and STAGING not in err


def interrupted_inside_a_library(args: TwoFolders) -> None:
    """What numba's dispatcher and an interrupted import do: the interrupt becomes the context of their own error."""
    try:
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)
    except Interrupted:
        raise SystemError("CPUDispatcher(<function cell_lists>) returned a result with an exception set") from None


def test_an_interrupt_a_library_wrapped_is_still_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(app, "command", lambda name: Command(name, TwoFolders, interrupted_inside_a_library))
    assert main(["render", "--out", str(tmp_path)]) == 143
    assert capsys.readouterr().err == "nerfedit render: interrupted (SIGTERM); nothing written\n"


def test_after_the_command_the_console_script_ignores_signals(tmp_path):
    """A signal while the interpreter shuts down after a committed output must not fail the command (exit 0)."""
    code = (
        "import os, signal, sys, time\n"
        "from nerfedit_plugin.cli.app import main\n"
        "sys.argv = ['nerfedit', 'plugins']\n"
        "code = main()\n"
        "os.kill(os.getpid(), signal.SIGINT); os.kill(os.getpid(), signal.SIGTERM); time.sleep(0.2)\n"
        "sys.exit(code)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr


def swallow_the_interrupt(args: TwoFolders) -> None:
    """What trimesh's optional imports do (``except BaseException``), then a committed output."""
    try:
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(5)
    except BaseException:
        pass
    with atomic_dir(args.out / "first") as stage:
        (stage / "a").write_text("a")


def test_an_interrupt_a_library_swallowed_still_ends_the_command_as_interrupted(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(app, "command", lambda name: Command(name, TwoFolders, swallow_the_interrupt))
    assert main(["generate", "--out", str(tmp_path)]) == 130
    err = capsys.readouterr().err
    assert err == f"nerfedit generate: interrupted (SIGINT); kept (complete): {tmp_path / 'first'}\n"


def test_error_lines_print_paths_verbatim(capsys):
    """rich would turn ``:fire:`` into an emoji and ``[x]`` into markup; a message names files exactly."""
    from nerfedit_plugin.cli.common import print_error

    print_error("in/scan:fire:v2.ply: [nan, 0.0] A:B:STEP")
    assert capsys.readouterr().err == "error: in/scan:fire:v2.ply: [nan, 0.0] A:B:STEP\n"
