"""Lens models against pycolmap (every supported camera model, distortion included), the OpenCV ↔ OpenGL conversion,
and undistortion of images."""

import numpy as np
import pytest
import torch

from nerfedit_plugin.data.cameras import (
    OPENCV_TO_OPENGL,
    Cameras,
    generate_rays,
    opengl_from_world_to_camera,
    world_to_camera_from_opengl,
)
from nerfedit_plugin.data.lens import COLMAP_MODELS, Lens
from nerfedit_plugin.data.undistort import undistort_image
from nerfedit_plugin.errors import NerfEditError

pycolmap = pytest.importorskip("pycolmap")

PARAMS = {
    "SIMPLE_PINHOLE": [80.0, 41.0, 29.5],
    "PINHOLE": [80.0, 84.0, 41.0, 29.5],
    "SIMPLE_RADIAL": [80.0, 41.0, 29.5, -0.12],
    "RADIAL": [80.0, 41.0, 29.5, -0.12, 0.03],
    "OPENCV": [80.0, 84.0, 41.0, 29.5, -0.12, 0.03, 0.004, -0.006],
}


@pytest.mark.parametrize("model", COLMAP_MODELS)
def test_projection_matches_pycolmap(model):
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(-0.5, 0.5, (200, 2)), rng.uniform(0.8, 3.0, 200)])
    camera = pycolmap.Camera(model=model, width=80, height=60, params=PARAMS[model])
    lens = Lens.from_colmap(model, PARAMS[model], "test")
    expected = np.asarray(camera.img_from_cam(points))
    assert np.abs(lens.project(points) - expected).max() < 1e-3
    assert lens.distorted == (model not in ("SIMPLE_PINHOLE", "PINHOLE"))


def test_unsupported_model_names_the_camera():
    with pytest.raises(NerfEditError, match=r"cameras.bin: camera 3: camera model FISHEYE is not supported"):
        Lens.from_colmap("FISHEYE", [1.0] * 6, "cameras.bin: camera 3")


def test_opencv_opengl_round_trip_and_projection():
    rng = np.random.default_rng(1)
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    w2c = np.eye(4)
    w2c[:3, :3], w2c[:3, 3] = rotation, rng.normal(size=3)
    c2w = opengl_from_world_to_camera(w2c)
    assert np.allclose(world_to_camera_from_opengl(c2w), w2c, atol=1e-12)
    assert np.allclose(OPENCV_TO_OPENGL @ OPENCV_TO_OPENGL, np.eye(4))
    # a world point seen by the OpenCV camera projects to a pixel whose OpenGL ray passes through it
    lens = Lens(70.0, 72.0, 33.0, 27.0)
    point_cam = np.array([0.2, -0.1, 2.0])
    world = np.linalg.solve(w2c, np.append(point_cam, 1.0))[:3]
    pixel = lens.project(point_cam)
    cameras = Cameras(torch.from_numpy(c2w[None]), lens.fx, lens.fy, lens.cx, lens.cy, 64, 48)
    origin, direction = generate_rays(cameras, 0, torch.tensor(pixel - 0.5)[None])
    along = world - origin[0].double().numpy()
    assert np.linalg.norm(np.cross(along, direction[0].double().numpy())) < 1e-5


def test_undistortion_recovers_the_pinhole_image():
    lens = Lens(*PARAMS["OPENCV"][:4], k1=-0.12, k2=0.03, p1=0.004, p2=-0.006)
    height, width = 60, 80

    def pattern(uv):  # a smooth image of normalised coordinates
        return np.stack([0.5 + 0.4 * np.sin(5 * uv[..., 0]), 0.5 + 0.4 * np.cos(4 * uv[..., 1])], axis=-1)

    ys, xs = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    pixels = np.stack([xs, ys], axis=-1)
    pinhole = pattern(lens.pixel_to_normalized(pixels))
    # the distorted photo: pixel p shows the scene at undistort(K⁻¹ p) — found by inverting distort numerically
    undistorted = lens.pixel_to_normalized(pixels)
    target = undistorted.copy()
    for _ in range(50):
        undistorted += target - lens.distort(undistorted)
    photo = pattern(undistorted).astype(np.float32)
    out, valid = undistort_image(photo, lens)
    assert valid[height // 2, width // 2] and valid.mean() > 0.9
    assert np.abs(out - pinhole)[valid].max() < 0.02
