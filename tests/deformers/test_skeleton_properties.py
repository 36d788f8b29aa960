"""Property tests (hypothesis) of skeleton inputs through the skeleton deformer's spec (``{"skeleton": ...,
"pose": {...}}``): generated skeleton JSON and BVH files bind; every mutation that is bad by construction (wrong
type, missing or unknown key, NaN/Inf/huge number, wrong shape, empty list, unknown joint, truncated or garbled file)
raises NerfEditError naming a file, never another exception."""

from __future__ import annotations

import copy
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tree_edits import nodes, replaced

from deformers.skeleton import SkeletonConfig, SkeletonDeformer
from deformers.skeleton.bvh import parse_bvh
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh

SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=list(HealthCheck), database=None)
SCALE = int(os.environ.get("NERFEDIT_PROPERTY_SCALE", "1"))  # multiply example counts for a deeper local run
HUGE = 10**400  # a JSON integer beyond float range

_ico = trimesh.creation.icosphere(subdivisions=1)
REST = SurfaceMesh(np.asarray(_ico.vertices), np.asarray(_ico.faces))

_NUMBER_BAD = ["30", None, [30], {}, True, math.nan, math.inf, -math.inf, HUGE]
_VECTOR_BAD = [["a", 0, 0], [0, 0], [0, 0, 0, 0], "0 0 0", None, {}, 1.0, [], [math.nan, 0, 0], [0, math.inf, 0]]
BAD_VALUES = {
    "vector": _VECTOR_BAD + [[HUGE, 0, 0]],
    "number": _NUMBER_BAD,
    "joints": [[], {}, None, "root"],
    "joint": [None, 1, "root", []],
    "name": ["", None, 3, ["a"], {}],
    "parent": [3, ["a"], {}, "no_such_joint", True],
    "pose": [[], "root", 1],
    "pose_item": [{}, [], None, 1, "x"],
    "rotate": [{}, [], None, {"axis": [0, 0, 0], "degrees": 10}, {"axis": [1, 0, 0]}, {"degrees": 10}],
    "path": [3, None, [], "", "missing.json", "a\x00b.json", "skeleton.txt"],
}
SCHEMA = {
    ("joints",): "joints",
    ("joints", "*"): "joint",
    ("joints", "*", "name"): "name",
    ("joints", "*", "parent"): "parent",
    ("joints", "*", "head"): "vector",
    ("joints", "*", "tail"): "vector",
}
SPEC_SCHEMA = {
    ("skeleton",): "path",
    ("pose",): "pose",
    ("pose", "*"): "pose_item",
    ("pose", "*", "translate"): "vector",
    ("pose", "*", "rotate"): "rotate",
    ("pose", "*", "rotate", "axis"): "vector",
    ("pose", "*", "rotate", "degrees"): "number",
}
CLOSED = {(), ("joints", "*"), ("pose", "*"), ("pose", "*", "rotate")}  # a spec's pose keys are joint names


def pattern(path: tuple) -> tuple:
    return tuple("*" if isinstance(p, int) or (i == 1 and path[0] == "pose") else p for i, p in enumerate(path))


# ---- good inputs ---------------------------------------------------------------------------------------------------
inner = st.floats(-0.4, 0.4)
vec3 = st.tuples(inner, inner, inner).map(list)


@st.composite
def tree(draw) -> tuple[list[str], list[int]]:
    """Joint names and parent indices (parents listed before children)."""
    n = draw(st.integers(1, 4))
    names = [f"j{i}" for i in range(n)]
    parents = [-1] + [draw(st.integers(-1, i - 1)) for i in range(1, n)]
    return names, parents


@st.composite
def skeleton_json(draw) -> dict:
    names, parents = draw(tree())
    joints = []
    for name, parent in zip(names, parents):
        joint = {"name": name, "head": draw(vec3)}
        if parent >= 0 or draw(st.booleans()):
            joint["parent"] = names[parent] if parent >= 0 else None
        if draw(st.booleans()):
            joint["tail"] = draw(vec3)
        joints.append(joint)
    return {"joints": joints}


@st.composite
def pose(draw, names: list[str]) -> dict:
    out = {}
    for name in draw(st.lists(st.sampled_from(names), unique=True, max_size=len(names))):
        item = {}
        keys = draw(st.sets(st.sampled_from(["rotate", "translate"]), min_size=1))
        if "rotate" in keys:
            axis = draw(st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3))
            item["rotate"] = {"axis": list(axis), "degrees": draw(st.floats(-180, 180) | st.integers(-360, 360))}
        if "translate" in keys:
            item["translate"] = draw(vec3)
        out[name] = item
    return out


@st.composite
def bvh_text(draw) -> tuple[str, list[str]]:
    """A BVH file (1–3 joints, 0–3 frames) and its joint names."""
    names, parents = draw(tree())
    names = [f"Bone_{i}" for i in range(len(names))]
    channels = []
    for j in range(len(names)):
        rot = draw(st.permutations(["Zrotation", "Xrotation", "Yrotation"]))
        channels.append((["Xposition", "Yposition", "Zposition"] if j == 0 else []) + rot)
    children = {j: [k for k in range(len(names)) if parents[k] == j] for j in range(len(names))}
    lines = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "  " * depth
        lines.append(f"{pad}{'ROOT' if j == 0 else 'JOINT'} {names[j]}")
        lines.append(f"{pad}{{")
        off = draw(st.tuples(*[st.floats(-0.3, 0.3)] * 3)) if j else (0.0, 0.0, 0.0)
        lines.append(f"{pad}  OFFSET {off[0]:.6f} {off[1]:.6f} {off[2]:.6f}")
        lines.append(f"{pad}  CHANNELS {len(channels[j])} {' '.join(channels[j])}")
        for k in children[j]:
            emit(k, depth + 1)
        if not children[j]:
            lines.append(f"{pad}  End Site")
            lines.append(f"{pad}  {{")
            lines.append(f"{pad}    OFFSET 0.0 0.1 0.0")
            lines.append(f"{pad}  }}")
        lines.append(f"{pad}}}")

    # joint 0 is the only root: re-parent other roots under it (parents precede children)
    for j in range(1, len(names)):
        if parents[j] < 0:
            parents[j] = 0
    children = {j: [k for k in range(len(names)) if parents[k] == j] for j in range(len(names))}
    emit(0, 0)
    n_frames = draw(st.integers(1, 3))
    n_channels = sum(len(c) for c in channels)
    lines += ["MOTION", f"Frames: {n_frames}", "Frame Time: 0.033333"]
    for _ in range(n_frames):
        values = draw(st.lists(st.floats(-30, 30), min_size=n_channels, max_size=n_channels))
        lines.append(" ".join(f"{v:.4f}" for v in values))
    return "\n".join(lines) + "\n", names


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("skeleton-props")


def bind(folder: Path, spec: dict, weights_joints: int | None = None):
    """Bind the skeleton deformer (given weights, when ``weights_joints``, skip the bone-heat solve)."""
    if weights_joints is not None:
        np.save(folder / "weights.npy", np.ones((REST.n_vertices, weights_joints)))
        spec = {**spec, "weights": "weights.npy"}
    source = str(folder / "edit.json")
    edit = parse_edit_spec(spec, SkeletonDeformer.spec_keys, source, folder)
    deformer = SkeletonConfig(visibility=False).setup()
    deformer.bind(REST, edit)
    return deformer


def names_a_file(exc: NerfEditError, folder: Path) -> None:
    assert str(folder) in str(exc), str(exc)


# ---- properties ----------------------------------------------------------------------------------------------------
@settings(max_examples=40 * SCALE, **SETTINGS)
@given(skel=skeleton_json(), data=st.data())
def test_good_skeleton_json_binds(workdir, skel, data):
    folder = Path(tempfile.mkdtemp(dir=workdir))
    (folder / "skeleton.json").write_text(json.dumps(skel))
    names = [j["name"] for j in skel["joints"]]
    heat = data.draw(st.booleans())
    deformer = bind(folder, {"skeleton": "skeleton.json", "pose": data.draw(pose(names))}, None if heat else len(names))
    assert deformer.weights.shape == (REST.n_vertices, len(names))
    assert np.isfinite(deformer.deform()).all()


@settings(max_examples=40 * SCALE, **SETTINGS)
@given(clip=bvh_text(), data=st.data())
def test_good_bvh_binds(workdir, clip, data):
    text, names = clip
    folder = Path(tempfile.mkdtemp(dir=workdir))
    (folder / "walk.bvh").write_text(text)
    spec = {"skeleton": "walk.bvh"}
    if data.draw(st.booleans()):
        spec["pose"] = data.draw(pose(names))
    if data.draw(st.booleans()):
        spec["frames"] = data.draw(st.integers(1, 4))
    deformer = bind(folder, spec, len(names))
    assert np.isfinite(deformer.deform()).all()


@settings(max_examples=200 * SCALE, **SETTINGS)
@given(skel=skeleton_json(), data=st.data())
def test_bad_skeleton_json_or_pose_raises_nerfediterror(workdir, skel, data):
    names = [j["name"] for j in skel["joints"]]
    spec = {"skeleton": "skeleton.json", "pose": data.draw(pose(names))}
    targets = [("skeleton", p) for p, _ in nodes(skel)] + [("spec", p) for p, _ in nodes(spec)]
    targets += [("skeleton", ()), ("spec", ())]
    which, path = data.draw(st.sampled_from(targets))
    tree_, schema = (skel, SCHEMA) if which == "skeleton" else (spec, SPEC_SCHEMA)
    kind = schema.get(pattern(path))
    ops = ["unknown"] if pattern(path) in CLOSED else []
    ops += ["value"] if kind in BAD_VALUES else []
    ops += ["delete"] if which == "skeleton" and path and path[-1] in ("joints", "name", "head") else []
    ops += ["unknown_joint"] if which == "spec" and path == ("pose",) else []
    if not ops:
        return
    op = data.draw(st.sampled_from(ops))
    if op == "unknown":
        bads = [replaced(tree_, path + ("bogus_key",), 1)]
    elif op == "unknown_joint":
        bads = [replaced(tree_, path + ("no_such_joint",), {"translate": [0, 0, 0]})]
    elif op == "delete":
        bads = [replaced(tree_, path, None, delete=True)]
    else:
        values = BAD_VALUES[kind]
        if kind == "parent":  # a joint that is its own parent: a cycle
            values = values + [path and skel["joints"][path[1]]["name"]]
        bads = [replaced(tree_, path, copy.deepcopy(v)) for v in values]
    if which == "skeleton" and op != "value" and path == ():
        bads.append([skel])  # top level not a mapping
    for bad in bads:
        folder = Path(tempfile.mkdtemp(dir=workdir))
        skel_, spec_ = (bad, spec) if which == "skeleton" else (skel, bad)
        (folder / "skeleton.json").write_text(json.dumps(skel_))
        (folder / "skeleton.txt").write_text("")
        with pytest.raises(NerfEditError) as info:
            bind(folder, spec_, len(names))
            pytest.fail(f"accepted bad input ({which} {op} {path}): skeleton {skel_}, spec {spec_}")
        names_a_file(info.value, folder)


@settings(max_examples=100 * SCALE, **SETTINGS)
@given(clip=bvh_text(), data=st.data())
def test_bad_bvh_raises_nerfediterror_naming_the_file(workdir, clip, data):
    """Truncation (any strict prefix of lines) or a non-numeric / non-finite number token is always bad."""
    text, names = clip
    lines = text.splitlines()
    numeric = [
        (i, k)
        for i, line in enumerate(lines)
        for k, tok in enumerate(line.split())
        if tok.lstrip("-").replace(".", "", 1).isdigit() and not line.startswith("Frame Time")
    ]
    if data.draw(st.booleans()):
        bad = lines[: data.draw(st.integers(0, len(lines) - 1))]
    else:
        i, k = data.draw(st.sampled_from(numeric))
        words = lines[i].split()
        words[k] = data.draw(st.sampled_from(["x", "nan", "inf", "-inf", "1e999", "1,5", ""]))
        if not words[k] and lines[i].startswith(("Frames", "CHANNELS")):
            words[k] = "x"
        bad = lines[:i] + [" ".join(words)] + lines[i + 1 :]
    folder = Path(tempfile.mkdtemp(dir=workdir))
    (folder / "walk.bvh").write_text("\n".join(bad) + "\n")
    with pytest.raises(NerfEditError) as info:
        parse_bvh(folder / "walk.bvh")
        bind(folder, {"skeleton": "walk.bvh"}, len(names))
        pytest.fail("accepted a bad BVH file:\n" + "\n".join(bad))
    names_a_file(info.value, folder)


@settings(max_examples=150 * SCALE, **SETTINGS)
@given(clip=bvh_text(), skel=skeleton_json(), data=st.data())
def test_garbled_skeleton_files_never_crash(workdir, clip, skel, data):
    """Random bytes spliced into a BVH or skeleton JSON: binds, or NerfEditError naming a file."""
    use_bvh = data.draw(st.booleans())
    name = "walk.bvh" if use_bvh else "skeleton.json"
    raw = (clip[0] if use_bvh else json.dumps(skel)).encode()
    cut = data.draw(st.integers(0, len(raw) - 1))
    raw = raw[:cut] + data.draw(st.binary(min_size=0, max_size=4)) + raw[cut + data.draw(st.integers(0, 8)) :]
    folder = Path(tempfile.mkdtemp(dir=workdir))
    (folder / name).write_bytes(raw)
    names = clip[1] if use_bvh else [j["name"] for j in skel["joints"]]
    spec = {"skeleton": name} if use_bvh else {"skeleton": name, "pose": {names[0]: {"translate": [0.1, 0, 0]}}}
    try:
        bind(folder, spec, len(names))
    except NerfEditError as exc:
        names_a_file(exc, folder)
