"""Fault injection: every named fault point of the write paths, struck in this process (``raise``, a deferred
SIGTERM) and in real ``nerfedit`` processes (SIGKILL, SIGTERM). After each, every output is complete and valid,
absent, or marked partial; a previous good output is intact; and the next write leaves no staging entry behind."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from nerfedit_plugin.cli.app import interrupts_raise, main
from nerfedit_plugin.io import faults
from nerfedit_plugin.io.atomic import PARTIAL, STAGING, atomic_dir, atomic_path, is_partial, mark_partial
from nerfedit_plugin.io.faults import POINTS, InjectedFault, fault_point
from nerfedit_plugin.pipeline.run import open_run


@pytest.fixture
def armed(monkeypatch):
    """Arm ``NERFEDIT_FAULT`` in this process (hit counts start afresh)."""
    monkeypatch.setattr(faults, "_hits", {})
    return lambda value: monkeypatch.setenv(faults.VARIABLE, value)


def staged(folder):
    return sorted(p.name for p in folder.iterdir() if STAGING in p.name)


def contents(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def write_folder(path, text, overwrite=False, keep_partial=False, partial=False):
    with atomic_dir(path, overwrite, keep_partial=keep_partial) as stage:
        if partial:
            mark_partial(stage, {"done": 1})
        (stage / "data.txt").write_text(text)


# ---- in this process -------------------------------------------------------------------------------------------
def test_unarmed_points_do_nothing_and_a_bad_variable_names_itself(armed):
    fault_point("atomic.file.staged")
    armed("atomic.file.staged:explode")
    with pytest.raises(ValueError, match="NERFEDIT_FAULT.*explode"):
        fault_point("atomic.file.staged")
    armed("no.such.point")
    with pytest.raises(ValueError, match="no.such.point"):
        fault_point("render.frame")


def test_a_file_write_failing_before_its_rename_keeps_the_previous_file(armed, tmp_path):
    target = tmp_path / "mesh.ply"
    target.write_text("previous")
    armed("atomic.file.staged@2")
    with atomic_path(target) as tmp:  # the first hit passes
        open(tmp, "w").write("first")
    with pytest.raises(InjectedFault, match="atomic.file.staged"), atomic_path(target) as tmp:
        open(tmp, "w").write("second")
    assert target.read_text() == "first" and staged(tmp_path) == []


@pytest.mark.parametrize("point", ["atomic.dir.staged", "atomic.dir.swap"])
def test_a_folder_write_failing_before_its_commit_keeps_the_previous_output(armed, tmp_path, point):
    write_folder(tmp_path / "out", "previous")
    armed(point)
    with pytest.raises(InjectedFault, match=point):
        write_folder(tmp_path / "out", "new", overwrite=True)
    assert contents(tmp_path / "out") == {"data.txt": b"previous"} and staged(tmp_path) == []


def test_a_folder_write_failing_where_nothing_was_leaves_nothing(armed, tmp_path):
    armed("atomic.dir.staged")
    with pytest.raises(InjectedFault):
        write_folder(tmp_path / "out", "new")
    assert list(tmp_path.iterdir()) == []


def test_a_failure_after_the_commit_leaves_the_new_output_complete(armed, tmp_path):
    write_folder(tmp_path / "out", "previous")
    armed("atomic.dir.committed")
    with pytest.raises(InjectedFault):
        write_folder(tmp_path / "out", "new", overwrite=True)
    assert contents(tmp_path / "out") == {"data.txt": b"new"} and staged(tmp_path) == []


def test_a_sigterm_during_the_swap_waits_for_its_end(armed, tmp_path):
    write_folder(tmp_path / "out", "previous")
    armed("atomic.dir.swap:term")
    with pytest.raises(KeyboardInterrupt), interrupts_raise():
        write_folder(tmp_path / "out", "new", overwrite=True)
    assert contents(tmp_path / "out") == {"data.txt": b"new"} and staged(tmp_path) == []


def test_keep_partial_keeps_a_marked_stage_only_where_nothing_was(armed, tmp_path):
    write_folder(tmp_path / "good", "previous")
    armed("atomic.dir.staged")
    with pytest.raises(InjectedFault):
        write_folder(tmp_path / "out", "half", keep_partial=True, partial=True)
    assert is_partial(tmp_path / "out") and staged(tmp_path) == []
    assert json.loads((tmp_path / "out" / PARTIAL).read_text()) == {"done": 1}
    faults._hits.clear()
    with pytest.raises(InjectedFault):
        write_folder(tmp_path / "good", "half", overwrite=True, keep_partial=True, partial=True)
    assert contents(tmp_path / "good") == {"data.txt": b"previous"} and staged(tmp_path) == []
    faults._hits.clear()
    with pytest.raises(InjectedFault):  # an unmarked stage is not kept
        write_folder(tmp_path / "plain", "half", keep_partial=True)
    assert not (tmp_path / "plain").exists()


# ---- real nerfedit processes -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def flow(capsule_flow, tmp_path_factory):
    """A copy of the session's capsule flow (these tests replace its edit), with a render of the run."""
    import shutil

    root = tmp_path_factory.mktemp("faults") / "flow"
    shutil.copytree(capsule_flow, root, symlinks=True)
    argv = ["render", "--run", root / "run", "--cameras", root / "data", "--out", root / "renders"]
    assert main([str(a) for a in argv]) == 0
    return root


def nerfedit(*argv, fault=None):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "200"}
    env.pop(faults.VARIABLE, None)
    if fault:
        env[faults.VARIABLE] = fault
    argv = [sys.executable, "-m", "nerfedit_plugin.cli.app", *map(str, argv)]
    return subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300)


def test_every_fault_point_is_in_a_write_path():
    package = Path(faults.__file__).parents[1]
    sources = "".join(path.read_text() for path in package.rglob("*.py") if path.name != "faults.py")
    for name in POINTS:
        assert f'fault_point("{name}")' in sources, name


def test_an_edit_killed_in_its_overwrite_swap_is_put_back_by_the_next_write(flow, proxy_cache, tmp_path):
    before = contents(flow / "edit")
    argv = ["edit", "--run", flow / "run", "--edit", flow / "edit.json", "--out", flow / "edit",
            "--cache-dir", proxy_cache, "--overwrite"]  # fmt: skip
    killed = nerfedit(*argv, fault="atomic.dir.swap:kill")
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert not (flow / "edit").exists() and len(staged(flow)) == 2  # parked previous + the new stage
    again = nerfedit(*argv, fault="atomic.dir.staged:raise")  # the next write into the folder (and it fails too)
    assert again.returncode != 0 and "injected fault" in again.stderr
    assert contents(flow / "edit") == before and staged(flow) == []
    assert nerfedit(*argv).returncode == 0
    assert sorted(contents(flow / "edit")) == sorted(before) and staged(flow) == []


def test_a_render_killed_after_its_first_frame_leaves_nothing_and_the_next_render_cleans_up(flow, tmp_path):
    argv = ["render", "--run", flow / "run", "--cameras", flow / "data", "--deformation",
            flow / "edit" / "deformation.npz", "--out", tmp_path / "frames"]  # fmt: skip
    killed = nerfedit(*argv, fault="render.frame@1:kill")
    assert killed.returncode == -signal.SIGKILL
    assert not (tmp_path / "frames").exists() and len(staged(tmp_path)) == 1
    done = nerfedit(*argv)
    assert done.returncode == 0, done.stderr
    assert staged(tmp_path) == [] and sorted(p.name for p in (tmp_path / "frames").iterdir()) == [
        "config.yml", "frame_0000", "frame_0001", "frame_0002"]  # fmt: skip


def test_a_render_terminated_between_frames_keeps_them_and_resume_finishes_it(flow, tmp_path):
    out = tmp_path / "frames"
    argv = ["render", "--run", flow / "run", "--cameras", flow / "data", "--deformation",
            flow / "edit" / "deformation.npz", "--out", out]  # fmt: skip
    termed = nerfedit(*argv, fault="render.frame@2:term")
    assert termed.returncode == 128 + signal.SIGTERM
    assert termed.stderr.strip().splitlines() == [f"nerfedit render: interrupted (SIGTERM); kept (partial): {out}"]
    assert sorted(os.listdir(out)) == [PARTIAL, "frame_0000", "frame_0001"] and staged(tmp_path) == []
    kept = {name: contents(out / name) for name in ("frame_0000", "frame_0001")}
    refused = nerfedit(*argv)
    assert refused.returncode == 2 and "pass --resume" in refused.stderr
    other = nerfedit(*argv, "--resume", "--frame", "0:2")  # other frames: the images would mix two settings
    assert other.returncode == 2 and "made with other settings" in other.stderr
    assert sorted(os.listdir(out)) == [PARTIAL, "frame_0000", "frame_0001"]
    resumed = nerfedit(*argv, "--resume", fault="render.frame@2:kill")  # a kill would strike at the 2nd new frame
    assert resumed.returncode == 0, resumed.stderr
    assert sorted(os.listdir(out)) == ["config.yml", "frame_0000", "frame_0001", "frame_0002"]
    assert {name: contents(out / name) for name in kept} == kept and staged(tmp_path) == []


def test_a_train_interrupted_after_a_checkpoint_keeps_a_partial_run_that_readers_refuse(tiny_scene, tmp_path):
    out = tmp_path / "run"
    argv = ["train", "--data", tiny_scene, "--out", out, "--device", "cpu", "--field-options.train.max-seconds", 600,
            "--field-options.train.batch-rays", 64, "--field-options.train.checkpoint-every-seconds", 0.01]  # fmt: skip
    termed = nerfedit(*argv, fault="train.checkpoint:term")
    assert termed.returncode == 128 + signal.SIGTERM, termed.stderr
    assert termed.stderr.strip().splitlines() == [f"nerfedit train: interrupted (SIGTERM); kept (partial): {out}"]
    assert staged(tmp_path) == [] and {"field.pt", "config.yml", PARTIAL} <= set(os.listdir(out))
    progress = json.loads((out / PARTIAL).read_text())
    assert progress["steps"] >= 1 and progress["train_seconds"] > 0
    with pytest.raises(Exception, match="partial"):
        open_run(out)
    render = nerfedit("render", "--run", out, "--cameras", tiny_scene, "--out", tmp_path / "renders")
    assert render.returncode == 2 and "partial" in render.stderr
    refused = nerfedit(*argv)
    assert refused.returncode == 2 and "partial output" in refused.stderr
    killed = nerfedit(*argv, "--overwrite", fault="train.checkpoint@2:kill")
    assert killed.returncode == -signal.SIGKILL
    assert is_partial(out) and len(staged(tmp_path)) == 1  # the kill left its stage; the partial run is as it was
    assert json.loads((out / PARTIAL).read_text()) == progress
