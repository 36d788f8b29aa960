"""A headless ``nerfedit view --screenshot`` prints only its result (no EGL/Mesa noise dressed as our error), and the
view's up direction: the default front turns with it, runs of generated data are z-up."""

import os
import stat
import subprocess
import sys

import numpy as np
import pytest

from nerfedit_plugin.data.cameras import Cameras, sphere_poses
from nerfedit_plugin.data.datasets import world_up
from nerfedit_plugin.viewer.layers import DEFAULT_FRONT, _rotate_y_to, ensure_runtime_dir


def test_a_headless_screenshot_prints_no_error(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("XDG_RUNTIME_DIR", "DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run(
        [sys.executable, "-m", "nerfedit_plugin.cli.app", "view", "--mesh", "sample:bone"]
        + ["--screenshot", str(tmp_path / "bone.png"), "--width", "64", "--height", "48"],
        capture_output=True,
        text=True,
        env={**env, "COLUMNS": "200"},
    )
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "bone.png").is_file()
    assert "error" not in result.stderr.lower() and "XDG_RUNTIME_DIR" not in result.stderr, result.stderr


def test_runtime_dir_is_made_private_only_when_unusable(tmp_path, monkeypatch):
    good = tmp_path / "good"
    good.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(good))
    ensure_runtime_dir()
    assert os.environ["XDG_RUNTIME_DIR"] == str(good)
    for bad in (tmp_path / "missing", tmp_path):  # absent; readable by others
        tmp_path.chmod(0o755)
        monkeypatch.setenv("XDG_RUNTIME_DIR", str(bad))
        ensure_runtime_dir()
        made = os.environ["XDG_RUNTIME_DIR"]
        assert made != str(bad) and stat.S_IMODE(os.stat(made).st_mode) == 0o700
    monkeypatch.delenv("XDG_RUNTIME_DIR")
    ensure_runtime_dir()
    assert os.path.isdir(os.environ["XDG_RUNTIME_DIR"])


@pytest.mark.parametrize("up", [(0, 1, 0), (0, 0, 1), (0, -1, 0), (1, 0, 0)])
def test_the_default_front_turns_with_up(up):
    up = np.asarray(up, dtype=float)
    front = _rotate_y_to(up, DEFAULT_FRONT)
    assert np.isclose(np.linalg.norm(front), np.linalg.norm(DEFAULT_FRONT))
    assert np.isclose(front @ up, DEFAULT_FRONT[1])  # the same elevation above the horizon
    if up[2] == 1:
        assert np.allclose(front, (0.3, -1.0, 0.2))  # a y-up mesh's front is -y in the generator's z-up world


def test_world_up_of_generated_cameras_is_z():
    for hemisphere in (False, True):
        poses = sphere_poses(6, 2.5, hemisphere=hemisphere, seed=3)
        assert world_up(Cameras.from_fov(poses, 8, 8, 0.8)) == (0.0, 0.0, 1.0)
