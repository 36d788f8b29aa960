"""Dataset loaders: Blender and nerfstudio files written from the same cameras load identically; compositing,
16-bit and alpha-less images, exact downscaling, nerfstudio splits and per-frame intrinsics, one clear error per
bad input (naming the file and key)."""

import json
import math

import numpy as np
import pytest
import skimage.io
import torch

from nerfedit_plugin.data.cameras import Cameras, generate_rays, sphere_poses
from nerfedit_plugin.data.datasets import (
    blender_transforms,
    block_mean,
    estimate_scene_bbox,
    load_dataset,
    nerfstudio_transforms,
    read_transforms,
    write_rgba,
)
from nerfedit_plugin.errors import NerfEditError

W, H, N = 12, 10, 4


def make_images(folder, n=N, seed=0):
    """Random straight-alpha RGBA PNGs; returns the 8-bit-decoded (rgb, alpha) arrays and relative names."""
    rng = np.random.default_rng(seed)
    rgbs, alphas, names = [], [], []
    for i in range(n):
        rgb, alpha = rng.random((H, W, 3)), rng.random((H, W))
        alpha[:2] = 0.0
        alpha[-2:] = 1.0
        (folder / "imgs").mkdir(parents=True, exist_ok=True)
        write_rgba(folder / "imgs" / f"f_{i}.png", rgb, alpha)
        rgbs.append(np.round(rgb * 255) / 255)
        alphas.append(np.round(alpha * 255) / 255)
        names.append(f"imgs/f_{i}")
    return np.stack(rgbs), np.stack(alphas), names


def write_json(path, data):
    path.write_text(json.dumps(data))
    return path


@pytest.fixture()
def scene(tmp_path):
    cameras = Cameras.from_fov(sphere_poses(N, 3.0, seed=1), W, H, 0.7)
    rgb, alpha, names = make_images(tmp_path)
    return tmp_path, cameras, rgb, alpha, names


def test_blender_and_nerfstudio_files_of_the_same_cameras_load_identically(scene):
    root, cameras, rgb, alpha, names = scene
    blender = blender_transforms(cameras, [f"./{n}" for n in names])  # Blender: no file extension
    del blender["w"], blender["h"]  # as in the original NeRF-synthetic files: size from the images
    for split in ("train", "val", "test"):
        write_json(root / f"transforms_{split}.json", blender)
    ns_root = root / "ns"
    ns_root.mkdir()
    write_json(ns_root / "transforms.json", nerfstudio_transforms(cameras, [f"../{n}.png" for n in names]))
    a = load_dataset(root, "val")
    b = load_dataset(ns_root / "transforms.json", "train")
    for ds in (a, b):
        assert (ds.cameras.width, ds.cameras.height) == (W, H)
        assert torch.equal(ds.cameras.c2w, cameras.c2w)
        for name in ("fx", "fy", "cx", "cy"):
            assert torch.allclose(getattr(ds.cameras, name), getattr(cameras, name), rtol=1e-6)
        assert torch.allclose(ds.alpha, torch.from_numpy(alpha).float())
        assert torch.equal(ds.images, a.images)
    assert a.split == "val" and a.image_paths[0].name == "f_0.png"
    # the principal-point ray of a loaded camera points along −z of its transform_matrix
    principal = torch.stack([a.cameras.cx, a.cameras.cy], 1)[:, None] - 0.5
    _, d = generate_rays(a.cameras, torch.arange(N)[:, None], principal)
    assert torch.allclose(d[:, 0], -cameras.c2w[:, :3, 2], atol=1e-6)


@pytest.mark.parametrize("background", [(1.0, 1.0, 1.0), (0.0, 0.0, 0.0), (0.2, 0.9, 0.4)])
def test_rgba_is_composited_over_the_chosen_background(scene, background):
    root, cameras, rgb, alpha, names = scene
    write_json(root / "transforms_train.json", blender_transforms(cameras, names))
    ds = load_dataset(root, background=background)
    expected = rgb * alpha[..., None] + np.asarray(background) * (1 - alpha[..., None])
    assert np.allclose(ds.images.numpy(), expected, atol=1e-6)
    assert ds.images.dtype == torch.float32 and ds.background == background
    assert torch.equal(ds.images[:, :2], torch.tensor(background).float().expand(N, 2, W, 3))  # alpha 0 rows


def test_downscale_is_the_block_mean_and_halves_intrinsics(tmp_path):
    w, h = 13, 11  # odd sizes: the partial last block is cropped
    rng = np.random.default_rng(3)
    image = rng.random((h, w, 4))
    (tmp_path / "a").mkdir()
    write_rgba(tmp_path / "a" / "x.png", image[..., :3], image[..., 3])
    cameras = Cameras(sphere_poses(1, 2.0), 20.0, 22.0, 6.1, 5.3, w, h)
    write_json(tmp_path / "transforms.json", nerfstudio_transforms(cameras, ["a/x.png"]))
    full = load_dataset(tmp_path, "test", background=(0.3, 0.3, 0.3))
    half = load_dataset(tmp_path, "test", background=(0.3, 0.3, 0.3), downscale=2)
    assert (half.cameras.width, half.cameras.height) == (6, 5)
    assert torch.allclose(half.cameras.fx, torch.tensor([10.0]))
    assert torch.allclose(half.cameras.cy, torch.tensor([2.65]))
    blocks = full.images[0, :10, :12].reshape(5, 2, 6, 2, 3).mean((1, 3))
    assert torch.allclose(half.images[0], blocks, atol=1e-6)
    assert torch.allclose(half.alpha[0], full.alpha[0, :10, :12].reshape(5, 2, 6, 2).mean((1, 3)), atol=1e-6)
    assert np.array_equal(block_mean(np.arange(16.0).reshape(4, 4), 2), [[2.5, 4.5], [10.5, 12.5]])


def test_sixteen_bit_and_alpha_less_images(tmp_path):
    rng = np.random.default_rng(4)
    grey16 = rng.integers(0, 65536, size=(H, W), dtype=np.uint16)
    rgb8 = rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)
    skimage.io.imsave(tmp_path / "a.png", grey16, check_contrast=False)
    skimage.io.imsave(tmp_path / "b.png", rgb8, check_contrast=False)
    cameras = Cameras.from_fov(sphere_poses(2, 2.0), W, H, 0.8)
    write_json(tmp_path / "transforms_train.json", blender_transforms(cameras, ["a", "b"]))
    ds = load_dataset(tmp_path)
    assert ds.alpha is None
    assert torch.allclose(ds.images[0], torch.from_numpy(grey16 / 65535.0).float()[..., None].expand(H, W, 3))
    assert torch.allclose(ds.images[1], torch.from_numpy(rgb8 / 255.0).float())


def test_nerfstudio_splits_and_per_frame_intrinsics(scene):
    root, cameras, _, _, names = scene
    cameras.fx[2] = 17.0  # a different lens on frame 2: written as a per-frame override
    cameras.cy[3] = 3.5
    data = nerfstudio_transforms(cameras, [f"{n}.png" for n in names])
    assert data["frames"][2]["fl_x"] == 17.0 and "fl_x" not in data["frames"][1]
    write_json(root / "transforms.json", data)
    everything = read_transforms(root)
    assert torch.allclose(everything.cameras.fx, cameras.fx) and torch.allclose(everything.cameras.cy, cameras.cy)
    assert len(load_dataset(root, "test")) == N  # no split information: every split is all frames
    data["train_filenames"] = [f"{n}.png" for n in names[:3]]
    data["test_filenames"] = [f"./{names[3]}.png"]
    write_json(root / "transforms.json", data)
    assert len(load_dataset(root, "train")) == 3
    test = load_dataset(root, "test")
    assert len(test) == 1 and float(test.cameras.cy[0]) == 3.5
    del data["train_filenames"], data["test_filenames"]
    for i, frame in enumerate(data["frames"]):
        frame["split"] = "val" if i % 2 else "train"
    write_json(root / "transforms.json", data)
    val = load_dataset(root, "val")
    assert [p.name for p in val.image_paths] == ["f_1.png", "f_3.png"]
    with pytest.raises(NerfEditError, match="no frames belong to split 'test'"):
        load_dataset(root, "test")


def test_scene_bbox_from_aabb_key_or_estimated_from_the_cameras(scene):
    root, _, _, _, names = scene
    center, radius, fov = torch.tensor([0.5, -0.2, 0.3]), 3.0, 0.7
    cameras = Cameras.from_fov(sphere_poses(N, radius, center.tolist()), W, H, fov)
    bbox = estimate_scene_bbox(cameras)
    half = radius * math.sin(math.atan(0.5 * H / float(cameras.fy[0])))  # the vertical FOV is the smaller one
    assert torch.allclose(bbox.mean(0), center, atol=1e-5)
    assert torch.allclose((bbox[1] - bbox[0]) / 2, torch.full((3,), half), atol=1e-5)
    data = {**blender_transforms(cameras, names), "aabb": [[-1, -2, -3], [1, 2, 3]]}
    write_json(root / "transforms_train.json", data)
    assert torch.equal(load_dataset(root).scene_bbox, torch.tensor([[-1.0, -2, -3], [1, 2, 3]]))


def _frame(names, **extra):
    return {"file_path": names[0], "transform_matrix": np.eye(4).tolist(), **extra}


BAD_INPUTS = [
    # (mutation of a valid Blender file, expected message fragment)
    (lambda d, n: d.pop("frames"), "transforms_train.json: key 'frames': missing"),
    (lambda d, n: d.update(frames=[]), "key 'frames': expected a non-empty list"),
    (lambda d, n: d["frames"][1].pop("file_path"), "frames[1].file_path: missing key"),
    (lambda d, n: d["frames"][1].pop("transform_matrix"), "frames[1].transform_matrix: missing key"),
    (lambda d, n: d["frames"][2].update(transform_matrix=np.eye(3).tolist()), "frames[2].transform_matrix: expected"),
    (lambda d, n: d["frames"][2].update(transform_matrix=[[1, 2], [3]]), "frames[2].transform_matrix"),
    (lambda d, n: d["frames"][0].update(transform_matrix=(2 * np.eye(4)).tolist()), "frames[0].transform_matrix"),
    (lambda d, n: d.pop("camera_angle_x"), "missing key 'fl_x' (nerfstudio) or 'camera_angle_x'"),
    (lambda d, n: d.update(camera_angle_x="wide"), "camera_angle_x: expected a finite number"),
    (lambda d, n: d.update(k1=0.1), "k1: lens distortion is not supported"),
    (lambda d, n: d.update(camera_model="OPENCV_FISHEYE"), "camera_model: 'OPENCV_FISHEYE' is not supported"),
    (lambda d, n: d["frames"][3].update(file_path="imgs/missing"), "frames[3].file_path: image"),
    (lambda d, n: d.update(w=W + 1), "f_0.png: image is 12x10 but transforms_train.json says w=13, h=10"),
    (lambda d, n: d["frames"][1].update(h=H + 2), "frames[1]: image size 12x12 differs"),
    (lambda d, n: d.update(aabb=[[0, 0, 0], [1, -1, 1]]), "aabb: expected"),
]


@pytest.mark.parametrize("mutate, message", BAD_INPUTS)
def test_bad_inputs_name_the_file_and_key(scene, mutate, message):
    root, cameras, _, _, names = scene
    data = blender_transforms(cameras, names)
    mutate(data, names)
    write_json(root / "transforms_train.json", data)
    with pytest.raises(NerfEditError) as info:
        load_dataset(root)
    assert message in str(info.value)


def test_bad_files_and_options(scene):
    root, cameras, _, _, names = scene
    with pytest.raises(NerfEditError, match="nowhere: dataset not found"):
        load_dataset(root / "nowhere")
    with pytest.raises(NerfEditError, match="no transforms_val.json or transforms.json"):
        load_dataset(root, "val")
    (root / "transforms_train.json").write_text("{not json")
    with pytest.raises(NerfEditError, match="transforms_train.json: cannot read JSON"):
        load_dataset(root)
    write_json(root / "transforms_train.json", blender_transforms(cameras, names))
    (root / "imgs" / "f_2.png").write_bytes(b"garbage")
    with pytest.raises(NerfEditError, match=r"f_2.png: not a readable image \(unknown format or corrupt data\)"):
        load_dataset(root)
    with pytest.raises(NerfEditError, match="split: expected one of"):
        load_dataset(root, "training")
    with pytest.raises(NerfEditError, match="downscale: expected a positive integer"):
        load_dataset(root, downscale=1.5)
    with pytest.raises(NerfEditError, match="background: expected 3 numbers"):
        load_dataset(root, background=(1, 1))
    with pytest.raises(NerfEditError, match="downscale: factor 16 exceeds"):
        load_dataset(root, downscale=16)
    del_size = {k: v for k, v in blender_transforms(cameras, ["imgs/none"]).items() if k != "w"}
    write_json(root / "transforms_test.json", del_size)
    with pytest.raises(NerfEditError, match="missing key 'w' and image .*none.png not found"):
        read_transforms(root / "transforms_test.json")
