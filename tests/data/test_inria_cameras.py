"""The INRIA 3D Gaussian Splatting trainer's ``cameras.json`` as ``--cameras``: written here the way its
``camera_to_JSON`` writes it (``Rt = [Rᵀ | T]`` from COLMAP's world-to-camera, then ``inv(Rt)``'s rotation and
centre), read back as the same OpenGL cameras; a folder holding it is a camera source; bad entries get one error."""

import json
import math

import numpy as np
import pytest
import torch

from nerfedit_plugin.data.cameras import sphere_poses, world_to_camera_from_opengl
from nerfedit_plugin.data.datasets import read_transforms
from nerfedit_plugin.errors import NerfEditError

WIDTH, HEIGHT, FOV_X = 64, 48, 0.9


def inria_entries(c2w: np.ndarray) -> list[dict]:
    """cameras.json entries of OpenGL cameras, following the INRIA trainer's arithmetic."""
    entries = []
    for i, pose in enumerate(c2w):
        w2c = world_to_camera_from_opengl(pose)  # COLMAP's cam_from_world
        R, T = w2c[:3, :3].T, w2c[:3, 3]  # the trainer's Camera.R (transposed) and Camera.T
        Rt = np.zeros((4, 4))
        Rt[:3, :3], Rt[:3, 3], Rt[3, 3] = R.transpose(), T, 1.0
        W2C = np.linalg.inv(Rt)
        fov_y = 2 * math.atan(HEIGHT / WIDTH * math.tan(FOV_X / 2))
        entries.append(
            {
                "id": i,
                "img_name": f"{i:05d}",
                "width": WIDTH,
                "height": HEIGHT,
                "position": W2C[:3, 3].tolist(),
                "rotation": [row.tolist() for row in W2C[:3, :3]],
                "fy": HEIGHT / (2 * math.tan(fov_y / 2)),
                "fx": WIDTH / (2 * math.tan(FOV_X / 2)),
            }
        )
    return entries


@pytest.fixture
def poses() -> np.ndarray:
    return sphere_poses(5, 3.0, (0.2, -0.1, 0.3), seed=2).double().numpy()


def test_cameras_json_reads_as_the_cameras_it_was_written_from(tmp_path, poses):
    (tmp_path / "cameras.json").write_text(json.dumps(inria_entries(poses)))
    for source in (tmp_path / "cameras.json", tmp_path):  # the file, or the trainer's output folder
        transforms = read_transforms(source)
        cameras = transforms.cameras
        assert np.allclose(cameras.c2w.double().numpy(), poses, atol=1e-6)
        assert (cameras.width, cameras.height) == (WIDTH, HEIGHT)
        focal = WIDTH / (2 * math.tan(FOV_X / 2))
        assert torch.allclose(cameras.fx, torch.full((5,), focal)) and torch.allclose(cameras.fy, cameras.fx)
        assert torch.all(cameras.cx == WIDTH / 2) and torch.all(cameras.cy == HEIGHT / 2)
        assert [p.name for p in transforms.image_paths] == [f"{i:05d}" for i in range(5)]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda e: e.pop("fx"), r"\[1\]\.fx: missing key"),
        (lambda e: e.update(rotation=[[2, 0, 0], [0, 1, 0], [0, 0, 1]]), r"\[1\]\.rotation: not orthonormal"),
        (lambda e: e.update(position=[0, 0]), r"\[1\]\.rotation/position: expected a 3x3 matrix and 3 numbers"),
        (lambda e: e.update(width=32), r"\[1\]\.width/height: image size 32x48 differs from 64x48"),
        (lambda e: e.update(fy="wide"), r"\[1\]\.fy: expected a finite number"),
    ],
)
def test_a_bad_entry_is_one_error_naming_it(tmp_path, poses, change, message):
    entries = inria_entries(poses)
    change(entries[1])
    (tmp_path / "cameras.json").write_text(json.dumps(entries))
    with pytest.raises(NerfEditError, match=message):
        read_transforms(tmp_path / "cameras.json")
