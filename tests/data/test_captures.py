"""Captures: COLMAP workspaces (written by pycolmap from known cameras), nerfstudio capture files (distortion, masks,
applied_transform, sparse points, held-out split), normalisation round trips, foreground boxes, bad input, and a
tiny real structure-from-motion round trip."""

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import skimage.io
import torch

from nerfedit_plugin.data.bounds import foreground_box
from nerfedit_plugin.data.cameras import Cameras, orbit_poses, world_to_camera_from_opengl
from nerfedit_plugin.data.datasets import (
    EVAL_INTERVAL,
    load_dataset,
    nerfstudio_transforms,
    read_transforms,
)
from nerfedit_plugin.data.normalization import apply
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.training.trainer import _ray_pool

pycolmap = pytest.importorskip("pycolmap")

W, H, N = 32, 24, 12


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NERFEDIT_CACHE", str(tmp_path / "cache"))


def capture_cameras(n=N):
    """Cameras of a capture in an arbitrary frame: an orbit around (3, -1, 2), tilted (up = +y), scale 7."""
    c2w = orbit_poses(n, 2.0, (0, 0, 0), seed=3).double().numpy()
    tilt = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])  # z-up → y-up
    frame = np.diag([7.0, 7.0, 7.0, 1.0]) @ tilt
    frame[:3, 3] = [3.0, -1.0, 2.0]
    moved = frame @ c2w
    moved[:, :3, :3] /= 7.0
    return moved, frame


def write_workspace(root: Path, model="PINHOLE", params=(30.0, 30.0, 16.0, 12.0), n=N, drop=(), points=None):
    """A COLMAP workspace of random images with the cameras of :func:`capture_cameras`, written by pycolmap."""
    c2w, frame = capture_cameras(n)
    (root / "images").mkdir(parents=True)
    (root / "sparse" / "0").mkdir(parents=True)
    rng = np.random.default_rng(0)
    reconstruction = pycolmap.Reconstruction()
    reconstruction.add_camera_with_trivial_rig(
        pycolmap.Camera(model=model, width=W, height=H, params=list(params), camera_id=1)
    )
    for i in range(n):
        name = f"img_{i:02d}.png"
        skimage.io.imsave(root / "images" / name, rng.integers(0, 256, (H, W, 3), dtype=np.uint8), check_contrast=False)
        if i in drop:
            continue
        w2c = world_to_camera_from_opengl(c2w[i])
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(w2c[:3, :3]), w2c[:3, 3])
        reconstruction.add_image_with_trivial_frame(pycolmap.Image(name=name, camera_id=1, image_id=i + 1), pose)
    for p in np.zeros((0, 3)) if points is None else points:
        reconstruction.add_point3D(p, pycolmap.Track(), np.zeros(3, dtype=np.uint8))
    reconstruction.write(str(root / "sparse" / "0"))
    return c2w, frame


def test_colmap_workspace_is_read_oriented_centred_and_scaled(tmp_path):
    rng = np.random.default_rng(1)
    object_points = apply(capture_cameras()[1], rng.normal(scale=0.2, size=(300, 3)))
    stray = apply(capture_cameras()[1], rng.normal(scale=30.0, size=(10, 3)))  # outliers far away
    c2w, frame = write_workspace(tmp_path, points=np.concatenate([object_points, stray]))
    everything = read_transforms(tmp_path)
    source = np.asarray(everything.meta["source_transform"])
    # the recorded transform maps the capture's cameras onto the loaded ones (positions and axes)
    moved = Cameras(torch.from_numpy(c2w), 30.0, 30.0, 16.0, 12.0, W, H).transformed(source)
    assert torch.allclose(moved.c2w, everything.cameras.c2w, atol=1e-5)
    centres = everything.cameras.centers.double().numpy()
    assert np.abs(centres).max() == pytest.approx(1.0, abs=1e-5)  # the cameras fill the unit box
    ups = everything.cameras.c2w[:, :3, 1].double().numpy().mean(0)
    assert np.allclose(ups / np.linalg.norm(ups), [0, 0, 1], atol=1e-6)  # oriented: mean up is +z
    box = np.asarray(everything.meta["aabb"])
    world_points = apply(source, object_points)
    inside = ((world_points >= box[0]) & (world_points <= box[1])).all(1).mean()
    assert inside > 0.95 and (box[1] - box[0]).max() < 1.0  # the object (σ ≈ 0.1 here), not the outliers
    assert np.allclose(box.mean(0), 0.0, atol=1e-9)  # centred on the foreground
    # a mesh goes back to capture coordinates exactly
    vertices = rng.normal(size=(50, 3))
    assert np.allclose(apply(np.linalg.inv(source), apply(source, vertices)), vertices, atol=1e-12)
    # held-out split: every 8th image, sorted by name
    test = read_transforms(tmp_path, "test")
    assert [p.name for p in test.image_paths] == [f"img_{i:02d}.png" for i in range(0, N, EVAL_INTERVAL)]
    train = load_dataset(tmp_path, "train")
    assert len(train) == N - len(test.image_paths) and train.mask is None
    assert torch.allclose(train.scene_bbox, torch.tensor(box, dtype=torch.float32))


def test_foreground_box_without_points_comes_from_the_frustums():
    c2w, _ = capture_cameras()
    cameras = Cameras(torch.from_numpy(c2w), 30.0, 30.0, 16.0, 12.0, W, H)
    box = foreground_box(cameras)
    centre = np.array([3.0, -1.0, 2.0])
    assert np.linalg.norm(box.mean(0) - centre) < 0.5 and (box[1] - box[0]).min() > 0


def test_distorted_colmap_model_is_undistorted_once_and_cached(tmp_path):
    write_workspace(tmp_path / "ws", model="OPENCV", params=(30.0, 30.0, 16.0, 12.0, 0.2, 0.05, 0.001, 0.002))
    first = load_dataset(tmp_path / "ws", "train")
    assert first.mask is not None and not first.mask.all()  # pincushion: the corners have no source pixel
    cached = list((tmp_path / "cache" / "images").glob("*.npz"))
    assert len(cached) == len(first)
    again = load_dataset(tmp_path / "ws", "train")
    assert torch.equal(again.images, first.images) and torch.equal(again.mask, first.mask)
    half = load_dataset(tmp_path / "ws", "train", downscale=2)
    assert half.images.shape[1:3] == (H // 2, W // 2)
    assert len(list((tmp_path / "cache" / "images").glob("*.npz"))) == 2 * len(first)


def write_nerfstudio(root: Path, n=N, **extra):
    c2w, frame = capture_cameras(n)
    (root / "images").mkdir(parents=True)
    rng = np.random.default_rng(2)
    names = [f"images/f_{i:02d}.png" for i in range(n)]
    for name in names:
        skimage.io.imsave(root / name, rng.integers(0, 256, (H, W, 3), dtype=np.uint8), check_contrast=False)
    cameras = Cameras(torch.from_numpy(c2w), 30.0, 31.0, 16.0, 12.0, W, H)
    data = nerfstudio_transforms(cameras, names)
    data.update(extra)
    (root / "transforms.json").write_text(json.dumps(data))
    return data


def test_nerfstudio_capture_with_masks_distortion_and_applied_transform(tmp_path):
    applied = [[0.0, 1.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]]  # ns-process-data's swap
    data = write_nerfstudio(tmp_path, applied_transform=applied, k1=-0.05, p2=0.001)
    (tmp_path / "masks").mkdir()
    mask = np.full((H, W), 255, np.uint8)
    mask[:, : W // 2] = 0  # the left half is ignored
    skimage.io.imsave(tmp_path / "masks" / "m.png", mask, check_contrast=False)
    for frame in data["frames"]:
        frame["mask_path"] = "masks/m.png"
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    train = load_dataset(tmp_path, "train")
    assert train.mask is not None and not train.mask[:, :, : W // 2 - 1].any() and train.mask[:, 4:-4, -4].all()
    pool = _ray_pool(train, 3)
    columns = pool % W
    assert len(pool) == int(train.mask.sum()) and (columns >= W // 2 - 1).all()  # masked pixels are never drawn
    # the capture frame is COLMAP's: the file's poses mapped back by applied_transform⁻¹, then normalised
    source = np.asarray(read_transforms(tmp_path).meta["source_transform"])
    c2w, _ = capture_cameras()
    applied4 = np.vstack([applied, [0, 0, 0, 1]])
    colmap = Cameras(torch.from_numpy(c2w), 30.0, 31.0, 16.0, 12.0, W, H).transformed(np.linalg.inv(applied4))
    assert torch.allclose(colmap.transformed(source).c2w, read_transforms(tmp_path).cameras.c2w, atol=1e-5)


def test_held_out_split_only_for_files_of_enough_frames(tmp_path):
    write_nerfstudio(tmp_path / "a")
    assert len(read_transforms(tmp_path / "a", "test").image_paths) == len(range(0, N, EVAL_INTERVAL))
    write_nerfstudio(tmp_path / "b", n=4)
    assert len(read_transforms(tmp_path / "b", "test").image_paths) == 4


BAD = [
    (lambda root: __import__("shutil").rmtree(root / "sparse"), "no COLMAP model in sparse/0"),
    (lambda root: (root / "images" / "img_03.png").unlink(), "'img_03.png' is registered but"),
]


@pytest.mark.parametrize("break_it, message", BAD)
def test_bad_workspaces(tmp_path, break_it, message):
    write_workspace(tmp_path)
    break_it(tmp_path)
    with pytest.raises(NerfEditError, match=message):
        load_dataset(tmp_path)


def test_bad_camera_model_registration_and_masks(tmp_path):
    write_workspace(tmp_path / "fisheye", model="OPENCV_FISHEYE", params=(30.0, 30.0, 16.0, 12.0, 0.1, 0, 0, 0))
    with pytest.raises(NerfEditError, match=r"cameras\.bin: camera 1: camera model OPENCV_FISHEYE is not supported"):
        read_transforms(tmp_path / "fisheye")
    write_workspace(tmp_path / "few", drop=range(2, N))
    with pytest.raises(NerfEditError, match="2 registered image"):
        read_transforms(tmp_path / "few")
    write_workspace(tmp_path / "part", drop=(5,))
    with pytest.warns(UserWarning, match=f"{N - 1} of the {N} images"):
        assert len(read_transforms(tmp_path / "part").image_paths) == N - 1
    data = write_nerfstudio(tmp_path / "ns")
    skimage.io.imsave(tmp_path / "ns" / "small.png", np.zeros((H // 2, W), np.uint8), check_contrast=False)
    data["frames"][2]["mask_path"] = "small.png"
    (tmp_path / "ns" / "transforms.json").write_text(json.dumps(data))
    with pytest.raises(NerfEditError, match=rf"small\.png: mask is {W}x{H // 2} but its image f_02\.png is {W}x{H}"):
        load_dataset(tmp_path / "ns", "train")
    data["frames"][2].pop("mask_path")
    data.update(camera_angle_x=2.0)
    (tmp_path / "ns" / "transforms.json").write_text(json.dumps(data))
    with pytest.raises(NerfEditError, match="disagree: give one intrinsics convention"):
        read_transforms(tmp_path / "ns")


def test_tiny_structure_from_motion_round_trip(tmp_path, capfd):
    """Real COLMAP (pycolmap) on rendered images alone; the recovered cameras match the true ones. COLMAP's INFO log
    (hundreds of lines) stays quiet, and its log level is restored after."""
    import re

    import pycolmap

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    import bench_capture

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        workspace, truth, size = bench_capture.make_capture(tmp_path, views=16, resolution=192)
        bench_capture.reconstruct(workspace)
        errors = bench_capture.camera_errors(workspace, truth, size)
    assert errors["registered"] == 16
    assert errors["rotation_deg_max"] < 1.0 and errors["centre_error_max"] < 0.01
    assert not re.search(r"^I\d{8} ", capfd.readouterr().err, re.MULTILINE) and pycolmap.logging.minloglevel == 0
