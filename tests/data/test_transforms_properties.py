"""Property tests (hypothesis) of ``read_transforms``: generated Blender and nerfstudio transforms files parse;
every mutation that is bad by construction (missing key, wrong type, NaN/Inf/huge number, wrong matrix shape,
empty frame list, out-of-range angle or size, truncated or garbled file) raises NerfEditError naming the file."""

from __future__ import annotations

import copy
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import skimage.io
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from tree_edits import nodes, replaced

from nerfedit_plugin.data.datasets import read_transforms
from nerfedit_plugin.errors import NerfEditError

SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=list(HealthCheck), database=None)
SCALE = int(os.environ.get("NERFEDIT_PROPERTY_SCALE", "1"))  # multiply example counts for a deeper local run
HUGE = 10**400  # a JSON integer beyond float range
W, H = 6, 4  # size of the PNGs on disk

_NUMBER_BAD = ["1", None, [1.0], {}, True, math.nan, math.inf, -math.inf, HUGE]
BAD_VALUES = {
    "angle": _NUMBER_BAD + [0, -0.5, math.pi, 4.0],
    "focal": _NUMBER_BAD + [0, -10.0],
    "size": _NUMBER_BAD + [0, -4, 2.5],
    "number": _NUMBER_BAD,
    "matrix": [
        None,
        "eye",
        3.0,
        [],
        [[1, 0, 0, 0]],
        [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0]],
        [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 2]],
        [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        [[math.nan, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        [[1, 0, 0, math.inf], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        [[1, 0, 0, HUGE], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        [[1, 0, 0, "x"], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
        [[True, 0, 0, 0], [0, True, 0, 0], [0, 0, True, 0], [0, 0, 0, True]],
        {"rows": 4},
    ],
    "file_path": [None, 3, "", [], {}, True, "x" * 5000],
    "frames": [[], {}, None, "frames", 1],
    "frame": [None, 1, "x", []],
    "camera_model": ["OPENCV_FISHEYE", "EQUIRECTANGULAR", 3],
    "distortion": ["0", None, math.nan, HUGE],
    "top": [[], None, "x", 1],
}
# Keys whose deletion breaks a good file (w/h are read from the image when missing, so they are not).
REQUIRED = {("frames",), ("frames", "*", "transform_matrix"), ("frames", "*", "file_path")}


def schema(fmt: str) -> dict:
    out = {
        ("frames",): "frames",
        ("frames", "*"): "frame",
        ("frames", "*", "transform_matrix"): "matrix",
        ("frames", "*", "file_path"): "file_path",
        ("w",): "size",
        ("h",): "size",
    }
    if fmt == "blender":
        out[("camera_angle_x",)] = "angle"
    else:
        out.update({(k,): "focal" for k in ("fl_x", "fl_y")})
        out.update({(k,): "number" for k in ("cx", "cy")})
        out.update({("frames", "*", k): "focal" for k in ("fl_x", "fl_y")})
        out.update({(k,): "distortion" for k in ("k1", "p1")})
        out[("camera_model",)] = "camera_model"
    return out


def pattern(path: tuple) -> tuple:
    return tuple("*" if isinstance(p, int) else p for p in path)


# ---- good files ----------------------------------------------------------------------------------------------------
@st.composite
def c2w(draw) -> list:
    """A camera-to-world matrix: random rotation (from a quaternion), random position; 3x4 or 4x4."""
    quat = draw(st.tuples(*[st.floats(-1.0, 1.0)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1))
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(quat).as_matrix()
    matrix[:3, 3] = draw(st.tuples(*[st.floats(-5.0, 5.0)] * 3))
    return matrix[: draw(st.sampled_from([3, 4]))].tolist()


@st.composite
def transforms(draw, fmt: str) -> dict:
    """A good transforms dict whose frames name the PNGs on disk (Blender paths may omit ``.png``)."""
    n = draw(st.integers(1, 3))
    frames = []
    for i in range(n):
        name = f"./images/r_{i}" if fmt == "blender" and draw(st.booleans()) else f"images/r_{i}.png"
        frames.append({"file_path": name, "transform_matrix": draw(c2w())})
    meta = {"frames": frames}
    if fmt == "blender":
        meta["camera_angle_x"] = draw(st.floats(0.1, 3.0))
        if draw(st.booleans()):
            meta.update(w=W, h=H)  # else read from the first image
    else:
        meta.update(
            fl_x=draw(st.floats(1.0, 100.0)),
            fl_y=draw(st.floats(1.0, 100.0)),
            cx=draw(st.floats(0.0, W)),
            cy=draw(st.floats(0.0, H)),
            w=W,
            h=H,
        )
        if draw(st.booleans()):
            meta.update(camera_model="OPENCV", k1=0.0, p1=0.0)
        if n > 1 and draw(st.booleans()):  # per-frame override (other frames still use the global fl_x)
            frames[0]["fl_x"] = draw(st.floats(1.0, 100.0))
    return meta


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("transforms-props")
    (root / "images").mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        skimage.io.imsave(root / "images" / f"r_{i}.png", rng.integers(0, 256, (H, W, 4), dtype=np.uint8))
    return root


def write(workdir: Path, raw: bytes, name: str) -> Path:
    folder = Path(tempfile.mkdtemp(dir=workdir))
    (folder / "images").symlink_to(workdir / "images")
    (folder / name).write_bytes(raw)
    return folder / name


FILE_NAMES = {"blender": "transforms_train.json", "nerfstudio": "transforms.json"}


# ---- properties ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("fmt", ["blender", "nerfstudio"])
@settings(max_examples=30 * SCALE, **SETTINGS)
@given(data=st.data())
def test_good_transforms_parse(workdir, fmt, data):
    meta = data.draw(transforms(fmt))
    path = write(workdir, json.dumps(meta).encode(), FILE_NAMES[fmt])
    for target in (path, path.parent):  # the file, or its dataset folder
        out = read_transforms(target, "train")
        assert len(out.cameras) == len(meta["frames"]) == len(out.image_paths)
        assert (out.cameras.width, out.cameras.height) == (W, H)
        assert all(p.is_file() for p in out.image_paths)


@pytest.mark.parametrize("fmt", ["blender", "nerfstudio"])
@settings(max_examples=60 * SCALE, **SETTINGS)
@given(data=st.data())
def test_bad_transforms_raise_nerfediterror_naming_the_file(workdir, fmt, data):
    good = data.draw(transforms(fmt))
    kinds = schema(fmt)
    candidates = [("value", path, kinds[pattern(path)]) for path, _ in nodes(good) if pattern(path) in kinds]
    candidates += [("delete", path, None) for path, _ in nodes(good) if pattern(path) in REQUIRED]
    if fmt == "blender":
        candidates += [("delete", ("camera_angle_x",), None), ("value", ("camera_angle_y",), "angle")]
    else:
        candidates += [("value", (key,), kinds[(key,)]) for key in ("k1", "p1", "camera_model") if key not in good]
        candidates.append(("delete", ("fl_x",), None))
    candidates.append(("top", (), "top"))
    op, path, kind = data.draw(st.sampled_from(candidates))
    if op == "top":
        bad = data.draw(st.sampled_from(BAD_VALUES["top"]))
    elif op == "delete":
        bad = replaced(good, path, None, delete=True)
        if path == ("fl_x",):
            bad["frames"] = [{k: v for k, v in f.items() if k != "fl_x"} for f in bad["frames"]]
    else:  # every bad value of the kind, so that each example covers them all
        bad = [replaced(good, path, copy.deepcopy(value)) for value in BAD_VALUES[kind]]
    for item in bad if isinstance(bad, list) and op == "value" else [bad]:
        path_ = write(workdir, json.dumps(item).encode(), FILE_NAMES[fmt])
        with pytest.raises(NerfEditError) as info:
            read_transforms(path_, "train")
            pytest.fail(f"accepted a bad transforms file ({op} {path}): {item}")
        assert str(path_) in str(info.value) or str(path_.parent) in str(info.value), str(info.value)


@pytest.mark.parametrize("fmt", ["blender", "nerfstudio"])
@settings(max_examples=60 * SCALE, **SETTINGS)
@given(data=st.data())
def test_garbled_transforms_never_crash(workdir, fmt, data):
    raw = json.dumps(data.draw(transforms(fmt))).encode()
    cut = data.draw(st.integers(0, len(raw) - 1))
    truncated = data.draw(st.booleans())
    raw = raw[:cut] if truncated else raw[:cut] + data.draw(st.binary(min_size=1, max_size=4)) + raw[cut + 1 :]
    path = write(workdir, raw, FILE_NAMES[fmt])
    try:
        read_transforms(path, "train")
    except NerfEditError as exc:
        assert str(path) in str(exc) or str(path.parent) in str(exc), str(exc)
    else:
        assert not truncated, "a truncated JSON file parsed"


GOOD = {"camera_angle_x": 0.7, "frames": [{"file_path": "images/r_0", "transform_matrix": np.eye(4).tolist()}]}


@pytest.mark.parametrize(
    "text, message",
    [
        (json.dumps(GOOD).replace('"camera_angle_x": 0.7', '"camera_angle_x": ' + "9" * 5000), "cannot read JSON"),
        (json.dumps(GOOD).replace("images/r_0", "x" * 5000), r"frames\[0\]\.file_path: invalid path"),
        (json.dumps(GOOD).replace("1.0", "true"), r"frames\[0\]\.transform_matrix: .* booleans"),
    ],
    ids=["an integer of 5000 digits", "a file name too long for the file system", "booleans in the matrix"],
)
def test_edge_values_name_the_file_and_key(workdir, text, message):
    file = write(workdir, text.encode(), "transforms_train.json")
    with pytest.raises(NerfEditError, match=rf"^{file}: {message}"):
        read_transforms(file)
