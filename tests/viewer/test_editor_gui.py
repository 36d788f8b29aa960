"""The editor window under a virtual display, driven by a script: pick vertices, move a handle, save; the screenshot
after the move differs from the rest pose's where the handle moved, and the saved spec reproduces the editor; a cage
edit saved and opened again (``--spec``) shows the same view; a third-party deformer (docs/examples/twist) is edited
through the backend it declares."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
import skimage.io

from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.viewer.backends import editing_backend

MESH = "sample:bone"
XVFB = shutil.which("xvfb-run")


def _editor(tmp_path, steps: list[dict], *options: str, site=None) -> subprocess.CompletedProcess:
    """Run ``nerfedit view --mesh MESH --script`` (the steps) under Xvfb, with the plugins installed in ``site`` on
    the path; it must end cleanly."""
    script = tmp_path / f"steps{len(list(tmp_path.glob('steps*.json')))}.json"
    script.write_text(json.dumps(steps))
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    if site is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(site), *filter(None, [env.get("PYTHONPATH")])])
    result = subprocess.run(
        [XVFB, "-a", "-s", "-screen 0 1280x800x24", sys.executable, "-m", "nerfedit_plugin.cli.app", "view"]
        + ["--mesh", MESH, "--script", str(script), *options],
        capture_output=True,
        text=True,
        env=env,
        timeout=240,
    )
    assert result.returncode == 0, result.stderr[-2000:]
    return result


def _image(path):
    return skimage.io.imread(path)[..., :3].astype(int)


needs_xvfb = pytest.mark.skipif(
    XVFB is None, reason="no xvfb-run (apt-get install xvfb libvulkan1 mesa-vulkan-drivers)"
)


@needs_xvfb
def test_a_scripted_edit_moves_the_view_and_saves_a_reproducible_spec(tmp_path):
    bone = SurfaceMesh.load(MESH)
    axis = int(np.argmax(np.ptp(bone.vertices, axis=0)))
    x = bone.vertices[:, axis]
    fixed = np.flatnonzero(x <= np.quantile(x, 0.1)).tolist()
    moving = np.flatnonzero(x >= np.quantile(x, 0.9)).tolist()
    shift = [0.0, 0.0, 0.0]
    shift[(axis + 1) % 3] = 0.15 * bone.bbox_diagonal
    steps = [
        {"screenshot": str(tmp_path / "rest.png")},
        {"click": [2, 2]},  # empty space: a message, the editor goes on
        {"pick": fixed},
        {"mark": "fixed"},
        {"pick": moving},
        {"mark": "moving"},
        {"translate": shift},
        {"drag": [5, 0]},
        {"save": str(tmp_path / "edit.json")},
        {"screenshot": str(tmp_path / "moved.png")},
        {"save": "/proc/nerfedit-editor/edit.json"},  # a read-only place: a message, nothing written
        {"quit": True},
    ]
    result = _editor(tmp_path, steps)
    assert "pick: no surface under the cursor" in result.stderr
    assert "save: cannot write into /proc/nerfedit-editor" in result.stderr
    rest, moved = _image(tmp_path / "rest.png"), _image(tmp_path / "moved.png")
    changed = np.abs(rest - moved).sum(-1) > 30
    assert changed.mean() > 0.002, "the move left the view unchanged"
    spec = json.loads((tmp_path / "edit.json").read_text())
    assert spec["handles"][1]["select"] == {"file": "edit.handle1.selection.json"}
    assert spec["handles"][1]["transform"]["translate"][(axis + 1) % 3] > 0.1 * bone.bbox_diagonal


@needs_xvfb
def test_a_cage_edit_saved_and_opened_again_shows_the_same_view(tmp_path):
    """--deformer cage: cage vertices picked and moved change the view; the saved spec, opened with --spec, shows it."""
    bone = SurfaceMesh.load(MESH)
    cage = editing_backend("cage", bone).points
    axis = int(np.argmax(np.ptp(cage, axis=0)))
    end = np.flatnonzero(cage[:, axis] >= np.quantile(cage[:, axis], 0.8)).tolist()
    shift = [0.0, 0.0, 0.0]
    shift[(axis + 1) % 3] = 0.15 * bone.bbox_diagonal
    steps = [
        {"screenshot": str(tmp_path / "rest.png")},
        {"pick": end},
        {"mark": "moving"},
        {"translate": shift},
        {"save": str(tmp_path / "cage.json")},
        {"screenshot": str(tmp_path / "moved.png")},
        {"quit": True},
    ]
    _editor(tmp_path, steps, "--deformer", "cage")
    rest, moved = _image(tmp_path / "rest.png"), _image(tmp_path / "moved.png")
    assert (np.abs(rest - moved).sum(-1) > 30).mean() > 0.002, "the cage move left the view unchanged"
    assert json.loads((tmp_path / "cage.json").read_text())["cage"] == "auto"
    steps = [{"screenshot": str(tmp_path / "opened.png")}, {"quit": True}]
    result = _editor(tmp_path, steps, "--deformer", "cage", "--spec", str(tmp_path / "cage.json"))
    assert "1 handle(s) loaded" in " ".join(result.stdout.split())  # (the console wraps lines)
    assert (np.abs(_image(tmp_path / "opened.png") - moved).sum(-1) > 30).mean() < 0.002


@needs_xvfb
def test_a_third_party_deformer_is_edited_through_the_backend_it_declares(tmp_path, twist_site):
    """--deformer twist, installed as its own distribution: its one handle turned about the twist axis saves the turn
    as the spec's degrees and shows the twisted mesh; the saved spec, opened with --spec, shows the same view."""
    bone = SurfaceMesh.load(MESH)
    axis = np.eye(3)[np.argmax(np.ptp(bone.vertices, axis=0))].tolist()  # the backend's axis: the longest side
    steps = [
        {"screenshot": str(tmp_path / "rest.png")},
        {"pick": [0]},
        {"mark": "moving"},
        {"rotate": {"axis": axis, "degrees": 75.0}},
        {"save": str(tmp_path / "twist.json")},
        {"screenshot": str(tmp_path / "twisted.png")},
        {"quit": True},
    ]
    _editor(tmp_path, steps, "--deformer", "twist", site=twist_site)
    twist = json.loads((tmp_path / "twist.json").read_text())["twist"]
    assert twist["axis"] == pytest.approx(axis) and twist["degrees"] == pytest.approx(75.0)
    rest, twisted = _image(tmp_path / "rest.png"), _image(tmp_path / "twisted.png")
    assert (np.abs(twisted - twisted[0, 0]).sum(-1) > 30).mean() > 0.01, "the view is blank (all background)"
    assert (np.abs(rest - twisted).sum(-1) > 30).mean() > 0.002, "the twist left the view unchanged"
    steps = [{"screenshot": str(tmp_path / "opened.png")}, {"quit": True}]
    result = _editor(tmp_path, steps, "--deformer", "twist", "--spec", str(tmp_path / "twist.json"), site=twist_site)
    assert "1 handle(s) loaded" in " ".join(result.stdout.split())
    assert (np.abs(_image(tmp_path / "opened.png") - twisted).sum(-1) > 30).mean() < 0.002
