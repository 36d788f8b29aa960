"""``nerfedit edit``'s progress display: on a terminal one line per stage with bars where the work is countable;
off a terminal (pipes, files, these tests' captured output) nothing but what the command printed before."""

import io
import json
import re
from pathlib import Path

import pytest
from rich.console import Console

import nerfedit_plugin.cli.edit as cli_edit
from nerfedit_plugin.cli.app import main
from nerfedit_plugin.cli.progress import StageProgress

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
PROGRESS = re.compile("[⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏✓]|/200|factorising")  # spinners, done marks, counts, details


def test_edit_on_a_terminal_shows_every_stage_with_bars(tmp_path, monkeypatch, proxy_cache):
    terminal = io.StringIO()
    monkeypatch.setattr(cli_edit, "console", Console(file=terminal, force_terminal=True, width=140))
    out = tmp_path / "out"
    argv = ["edit", "--mesh", "sample:bunny", "--edit", str(CONFIGS / "arap_bunny_head.json"), "--out", str(out)]
    assert main([*argv, "--cache-dir", str(proxy_cache)]) == 0
    assert json.loads((out / "report.json").read_text())["frames"] == 1
    shown = re.sub(r"\x1b\[[0-9;?]*[a-zA-Z]", "", terminal.getvalue())
    for stage in ("load", "bind", "deform", "proxy", "lift", "write"):
        assert re.search(rf"✓ {stage}\b", shown), stage  # each stage is done before the next one starts
    assert re.search(r"deform +━*\S* +\d+/200 +\d:\d\d:\d\d frame 1/1 · iteration \d+", shown)
    assert "peak memory" in shown  # the report follows the display


def test_edit_off_a_terminal_prints_no_progress(tmp_path, capsule, capsys, proxy_cache):
    capsule.save(tmp_path / "capsule.ply")
    edit = {
        "handles": [
            {"select": {"box": {"min": [-1, -1, -1.1], "max": [1, 1, -0.9]}}, "fixed": True},
            {"select": {"box": {"min": [-1, -1, 0.9], "max": [1, 1, 1.1]}}, "transform": {"translate": [0.3, 0, 0]}},
        ]
    }
    (tmp_path / "edit.json").write_text(json.dumps(edit))
    argv = ["edit", "--mesh", str(tmp_path / "capsule.ply"), "--edit", str(tmp_path / "edit.json")]
    assert main([*argv, "--out", str(tmp_path / "out"), "--cache-dir", str(proxy_cache)]) == 0
    captured = capsys.readouterr()
    assert not PROGRESS.search(captured.out + captured.err)
    assert captured.out.lstrip().startswith("nerfedit edit →")


@pytest.mark.parametrize("prefix", ["", "demo: "])
def test_the_display_follows_the_stopwatch(prefix):
    """A stage is done when the next starts; a report sets its bar (or none: a spinner-only line)."""
    from nerfedit_plugin.timing import Stopwatch

    terminal = io.StringIO()
    with StageProgress(Console(file=terminal, force_terminal=True, width=100), prefix) as display:
        clock = Stopwatch(display.on_stage, on_progress=display.on_progress)
        with clock.stage("bind"):
            clock.progress(0, None, "factorising")
        with clock.stage("deform"):
            clock.progress(3, 4, "frame 1/1")
            tasks = display.display.tasks
            assert tasks[0].stop_time is not None and tasks[1].stop_time is None
            assert (tasks[0].fields["of"], tasks[0].fields["detail"]) == (None, "factorising")
            assert (tasks[1].fields["done"], tasks[1].fields["of"]) == (3, 4)
            assert [t.description for t in tasks] == [prefix + "bind", prefix + "deform"]
            display.display.refresh()
    shown = re.sub(r"\x1b\[[0-9;?]*[a-zA-Z]", "", terminal.getvalue())
    assert re.search(rf"✓ {prefix}bind +0:00:00 factorising", shown)
    assert re.search(rf"{prefix}deform +━+\S* +3/4 +0:00:00 frame 1/1", shown)
