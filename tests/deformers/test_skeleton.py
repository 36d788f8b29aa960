"""The skeleton deformer end to end: skeleton JSON/BVH loading, forward kinematics, identity and rigid poses, the
candy-wrapper twist, frame interpolation, points off the surface, weight files, every bad-input class, the
example configs on the bunny, the registry entry point and the conformance kit."""

import json

import igl
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from deformers.skeleton import Skeleton, SkeletonConfig, SkeletonDeformer, closest_point_barycentrics
from nerfedit_plugin.edit.spec import load_edit_spec, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.samples import sample_mesh_path
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.testing import parametrize_with_checks

# A closed tube along z (radius 0.25, z ∈ [-1, 1], a vertex ring every 0.05 including z = 0) and a two-bone chain.
_Z = np.linspace(-1, 1, 41)
_TUBE = trimesh.creation.revolve(np.array([[0, -1], *[[0.25, z] for z in _Z], [0, 1]]), sections=24)
TUBE = SurfaceMesh(np.asarray(_TUBE.vertices), np.asarray(_TUBE.faces))
CHAIN = {
    "joints": [
        {"name": "lower", "parent": None, "head": [0, 0, -0.8]},
        {"name": "upper", "parent": "lower", "head": [0, 0, 0], "tail": [0, 0, 0.8]},
    ]
}
CHAIN_BVH = """HIERARCHY
ROOT lower
{
  OFFSET 0 0 -0.8
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT upper
  {
    OFFSET 0 0 0.8
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 0 0.8
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.1
0 0 0 0 0 0 0 0 0
0 0 0.5 0 0 0 0 45 0
0 0 1 0 0 0 0 90 0
"""


@pytest.fixture
def folder(tmp_path):
    (tmp_path / "chain.json").write_text(json.dumps(CHAIN))
    (tmp_path / "chain.bvh").write_text(CHAIN_BVH)
    return tmp_path


def bind(folder, spec, mesh=TUBE, **config):
    deformer = SkeletonConfig(**config).setup()
    deformer.bind(mesh, parse_edit_spec(spec, SkeletonDeformer.spec_keys, "edit.json", folder))
    return deformer


def pose(**joints):
    return {"skeleton": "chain.json", "pose": joints}


def radius(points):
    return np.linalg.norm(points[:, :2], axis=1)


# ---- skeleton model -------------------------------------------------------------------------------------------
def test_json_skeleton_default_tails_and_order(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(
        json.dumps(
            {
                "joints": [
                    {"name": "b", "parent": "a", "head": [1, 0, 0]},
                    {"name": "a", "parent": None, "head": [0, 0, 0]},
                    {"name": "c", "parent": "a", "head": [0, 1, 0]},
                    {"name": "solo", "parent": None, "head": [5, 5, 5]},
                ]
            }
        )
    )
    s = Skeleton.from_json(path)
    assert s.names == ("b", "a", "c", "solo") and list(s.parents) == [1, -1, 1, -1]
    assert np.allclose(s.tails[1], [0.5, 0.5, 0])  # mean head of the children
    assert np.array_equal(s.tails[0], s.heads[0]) and np.array_equal(s.tails[3], s.heads[3])  # leaves: point bones
    assert all(s.order.index(1) < s.order.index(k) for k in (0, 2))


def test_forward_kinematics_composes_down_the_hierarchy(tmp_path):
    path = tmp_path / "s.json"
    path.write_text(
        json.dumps(
            {
                "joints": [
                    {"name": "a", "parent": None, "head": [0, 0, 0]},
                    {"name": "b", "parent": "a", "head": [1, 0, 0]},
                    {"name": "c", "parent": "b", "head": [2, 0, 0]},
                ]
            }
        )
    )
    s = Skeleton.from_json(path)
    rz90 = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    rot = np.stack([rz90, rz90, np.eye(3)])[None]
    trans = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]], float)[None]
    g_rot, g_trans = s.forward_kinematics(rot, trans)
    heads = np.einsum("fjik,jk->fji", g_rot, s.heads) + g_trans
    # b turns about a (→ (0,1,0)) and lifts by 1; c turns about b by a further 90° and then with a.
    assert np.allclose(heads[0], [[0, 0, 0], [0, 1, 1], [-1, 1, 1]])
    assert np.allclose(g_rot[0, 2], rz90 @ rz90)


def test_closest_point_barycentrics_match_libigl():
    rng = np.random.default_rng(1)
    tri = rng.random((300, 3, 3))
    points = np.concatenate([rng.uniform(-0.5, 1.5, (297, 3)), tri[297:, 1]])  # last three: exactly on a corner
    bary = closest_point_barycentrics(points, tri[:, 0], tri[:, 1], tri[:, 2])
    assert (bary >= 0).all() and np.abs(bary.sum(1) - 1).max() < 1e-12
    closest = np.einsum("mk,mki->mi", bary, tri)
    for i in range(len(points)):
        _, _, expected = igl.point_mesh_squared_distance(points[i : i + 1], tri[i], np.array([[0, 1, 2]]))
        assert np.abs(closest[i] - expected[0]).max() < 1e-12
    assert np.array_equal(bary[297:], np.tile([0.0, 1.0, 0.0], (3, 1)))


# ---- deformation ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["dqs", "lbs"])
def test_identity_pose_is_identity(folder, method):
    d = bind(
        folder, pose(upper={"rotate": {"axis": [1, 0, 0], "degrees": 0}}, lower={"translate": [0, 0, 0]}), method=method
    )
    assert np.abs(d.deform()[0] - TUBE.vertices).max() < 1e-14


@pytest.mark.parametrize("method", ["dqs", "lbs"])
def test_root_pose_moves_everything_rigidly(folder, method):
    spec = pose(lower={"rotate": {"axis": [1, 2, 3], "degrees": 70}, "translate": [0.3, -0.2, 0.5]})
    out = bind(folder, spec, method=method).deform()[0]
    rot = Rotation.from_rotvec(np.array([1, 2, 3]) / np.sqrt(14) * np.radians(70)).as_matrix()
    head = np.array([0, 0, -0.8])
    expected = head + (TUBE.vertices - head) @ rot.T + [0.3, -0.2, 0.5]
    assert np.abs(out - expected).max() < 1e-12


def test_twist_keeps_radius_under_dqs_and_collapses_under_lbs(folder):
    """The candy wrapper: twist the upper bone 180° about its own axis."""
    spec = pose(upper={"rotate": {"axis": [0, 0, 1], "degrees": 180}})
    side = radius(TUBE.vertices) > 0.2
    middle = side & (np.abs(TUBE.vertices[:, 2]) < 1e-9)
    dqs = bind(folder, spec, method="dqs").deform()[0]
    assert np.abs(radius(dqs)[side] - 0.25).max() < 1e-12
    lbs = bind(folder, spec, method="lbs").deform()[0]
    assert radius(lbs)[middle].max() < 1e-9
    top = side & (TUBE.vertices[:, 2] > 0.9)  # far end follows the bone: rotated by 180°
    assert np.abs(lbs[top, :2] + TUBE.vertices[top, :2]).max() < 0.02


def test_frames_interpolate_from_rest_to_pose(folder):
    bend = {"upper": {"rotate": {"axis": [1, 0, 0], "degrees": 60}, "translate": [0, 0.2, 0]}}
    frames = bind(folder, {**pose(**bend), "frames": 3}).deform()
    assert frames.shape == (3, TUBE.n_vertices, 3)
    assert np.abs(frames[0] - TUBE.vertices).max() < 1e-14
    assert np.abs(frames[2] - bind(folder, pose(**bend)).deform()[0]).max() < 1e-12
    half = {"upper": {"rotate": {"axis": [1, 0, 0], "degrees": 30}, "translate": [0, 0.1, 0]}}
    assert np.abs(frames[1] - bind(folder, pose(**half)).deform()[0]).max() < 1e-12


def test_deform_points_off_the_surface(folder):
    bend = pose(upper={"rotate": {"axis": [1, 0, 0], "degrees": 50}})
    d = bind(folder, bend)
    assert np.abs(d.deform_points(TUBE.vertices, 0) - d.deform()[0]).max() < 1e-12
    axis = np.column_stack([np.zeros((9, 2)), np.linspace(-0.8, 0.8, 9)])
    w = d.point_weights(axis)
    assert np.allclose(w.sum(1), 1) and (w[0, 0] > 0.95) and (w[-1, 1] > 0.95)
    # an axis point takes the weights of its nearest surface point: here the whole ring at its height agrees
    ring = np.flatnonzero(np.isclose(TUBE.vertices[:, 2], 0.4) & (radius(TUBE.vertices) > 0.2))
    assert np.allclose(d.point_weights(np.array([[0, 0, 0.4]])), d.weights[ring[0]])
    rigid = bind(folder, pose(lower={"rotate": {"axis": [0, 1, 0], "degrees": 40}, "translate": [1, 0, 0]}))
    rot = Rotation.from_euler("y", 40, degrees=True).as_matrix()
    probe = np.random.default_rng(0).uniform(-1.5, 1.5, (50, 3))
    expected = [0, 0, -0.8] + (probe - [0, 0, -0.8]) @ rot.T + [1, 0, 0]
    assert np.abs(rigid.deform_points(probe, 0) - expected).max() < 1e-12
    with pytest.raises(IndexError):
        d.deform_points(probe, 1)


def test_weights_file_replaces_heat_weights(folder):
    owner = (TUBE.vertices[:, 2] > 0).astype(int)
    np.save(folder / "w.npy", np.eye(2)[owner] * 3.0)  # rows are renormalised
    spec = {**pose(upper={"rotate": {"axis": [1, 0, 0], "degrees": 90}}), "weights": "w.npy"}
    out = bind(folder, spec).deform()[0]
    assert np.array_equal(out[owner == 0], TUBE.vertices[owner == 0])
    rot = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    assert np.abs(out[owner == 1] - TUBE.vertices[owner == 1] @ rot.T).max() < 1e-12


def test_bvh_clip_is_the_animation(folder):
    d = bind(folder, {"skeleton": "chain.bvh"})
    frames = d.deform()
    assert frames.shape == (3, TUBE.n_vertices, 3)  # frames = 1 (default): every BVH frame
    assert np.abs(frames[0] - TUBE.vertices).max() < 1e-14
    # the last BVH frame (root up by 1, upper joint 90° about x) is the same pose written for the JSON chain
    same = pose(lower={"translate": [0, 0, 1]}, upper={"rotate": {"axis": [1, 0, 0], "degrees": 90}})
    assert np.abs(frames[2] - bind(folder, same).deform()[0]).max() < 1e-12
    resampled = bind(folder, {"skeleton": "chain.bvh", "frames": 5}).deform()
    assert resampled.shape[0] == 5 and np.abs(resampled[[0, 2, 4]] - frames).max() < 1e-12
    posed = bind(folder, {"skeleton": "chain.bvh", "pose": {"lower": {"translate": [0, 0, 2]}}}).deform()
    assert posed.shape[0] == 1 and np.abs(posed[0] - TUBE.vertices - [0, 0, 2]).max() < 1e-14


def test_write_artifacts_saves_the_weights(folder, tmp_path):
    d = bind(folder, pose(upper={"rotate": {"axis": [1, 0, 0], "degrees": 10}}))
    d.write_artifacts(tmp_path / "out")
    saved = np.load(tmp_path / "out" / "skin_weights.npy")
    assert np.array_equal(saved, d.weights) and np.allclose(saved.sum(1), 1)


# ---- bad input ----------------------------------------------------------------------------------------------------
def _skeleton_error(folder, joints, match):
    (folder / "bad.json").write_text(json.dumps({"joints": joints}))
    with pytest.raises(NerfEditError, match=match) as err:
        bind(folder, {"skeleton": "bad.json", "pose": {}})
    assert "bad.json" in str(err.value)


def test_bad_skeletons(folder):
    head = [0, 0, 0]
    _skeleton_error(
        folder,
        [
            {"name": "a", "parent": "b", "head": head},
            {"name": "b", "parent": "a", "head": head},
            {"name": "r", "parent": None, "head": head},
        ],
        "parent cycle a → b → a",
    )
    _skeleton_error(folder, [{"name": "a", "parent": "a", "head": head}], "parent cycle a → a")
    _skeleton_error(
        folder, [{"name": "a", "parent": "ghost", "head": head}], r"joints\[0\].parent: unknown joint 'ghost'"
    )
    _skeleton_error(
        folder,
        [{"name": "a", "parent": None, "head": head}, {"name": "a", "parent": None, "head": head}],
        r"joints\[1\]: duplicate joint name 'a'",
    )
    _skeleton_error(folder, [{"name": "a", "parent": None}], r"joints\[0\].head: missing")
    _skeleton_error(folder, [{"name": "a", "parent": None, "head": [0, 0]}], r"joints\[0\].head: expected 3 numbers")
    _skeleton_error(folder, [{"name": "a", "parent": None, "head": head, "tip": head}], r"joints\[0\].tip: unknown key")
    _skeleton_error(folder, [], "joints: expected a non-empty list")
    (folder / "broken.json").write_text('{"joints": [')
    with pytest.raises(NerfEditError, match="broken.json: cannot parse skeleton JSON"):
        bind(folder, {"skeleton": "broken.json", "pose": {}})
    (folder / "rig.txt").write_text("")
    with pytest.raises(NerfEditError, match=r"rig.txt: unknown skeleton format '.txt'"):
        bind(folder, {"skeleton": "rig.txt", "pose": {}})


@pytest.mark.parametrize(
    "joints, match",
    [
        ({"elbow": {"translate": [0, 0, 1]}}, "edit.json: pose.elbow: unknown joint"),
        ({"upper": {"rotate": {"axis": [0, 0, 0], "degrees": 5}}}, r"pose.upper.rotate.axis: is the zero vector"),
        ({"upper": {"rotate": {"axis": [0, 0, 1]}}}, r"pose.upper.rotate.degrees: missing"),
        ({"upper": {"rotate": {"axis": [0, 0, 1], "degrees": "9"}}}, r"pose.upper.rotate.degrees: expected a finite"),
        (
            {"upper": {"rotate": {"axis": [0, 0, 1], "degrees": 9, "center": [0, 0, 0]}}},
            r"pose.upper.rotate.center: unknown",
        ),
        ({"upper": {"translate": [0, float("nan"), 0]}}, r"pose.upper.translate: contains NaN"),
        ({"upper": {"scale": 2}}, r"pose.upper.scale: unknown key"),
        ({"upper": {}}, r"pose.upper: empty transform"),
    ],
)
def test_bad_poses(folder, joints, match):
    with pytest.raises(NerfEditError, match=match):
        bind(folder, pose(**joints))


def test_missing_pose_bad_bvh_and_bad_weights(folder):
    with pytest.raises(NerfEditError, match="edit.json: pose: missing"):
        bind(folder, {"skeleton": "chain.json"})
    (folder / "bad.bvh").write_text(CHAIN_BVH.replace("0 0 0.5 0 0 0 0 45 0", "0 0 0.5 0 0 0 0 45"))
    with pytest.raises(NerfEditError, match=r"bad.bvh:20: expected 9 channel values, got 8"):
        bind(folder, {"skeleton": "bad.bvh"})
    for name, weights, match in [
        ("short.npy", np.ones((5, 2)), r"short.npy: weights shape \(5, 2\), expected \(986, 2\)"),
        ("wide.npy", np.ones((TUBE.n_vertices, 3)), r"expected \(986, 2\)"),
        (
            "neg.npy",
            np.where(np.arange(2) == 0, -1.0, 1.0) * np.ones((TUBE.n_vertices, 1)),
            "negative weight at vertex 0",
        ),
        ("zero.npy", np.zeros((TUBE.n_vertices, 2)), "vertex 0 has all-zero weights"),
        ("nan.npy", np.full((TUBE.n_vertices, 2), np.nan), "must be finite"),
    ]:
        np.save(folder / name, weights)
        with pytest.raises(NerfEditError, match=match):
            bind(folder, {**pose(upper={"translate": [0, 0, 1]}), "weights": name})
    (folder / "junk.npy").write_text("not numpy")
    with pytest.raises(NerfEditError, match="junk.npy: cannot read weights"):
        bind(folder, {**pose(upper={"translate": [0, 0, 1]}), "weights": "junk.npy"})
    with pytest.raises(NerfEditError, match="heat_bones: must be >= 1"):
        bind(folder, pose(upper={"translate": [0, 0, 1]}), heat_bones=0)


# ---- examples, registry, conformance ---------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def bunny():
    return SurfaceMesh.load(sample_mesh_path("bunny"))


@pytest.mark.parametrize("name, n_frames", [("skeleton_bunny_pose.json", 1), ("skeleton_bunny_bvh.json", 5)])
def test_example_configs_on_the_bunny(bunny, name, n_frames):
    from pathlib import Path

    spec = load_edit_spec(Path(__file__).parents[2] / "configs" / name, SkeletonDeformer.spec_keys)
    d = SkeletonConfig().setup()
    d.bind(bunny, spec)
    frames = d.deform()
    assert frames.shape == (n_frames, bunny.n_vertices, 3) and np.isfinite(frames).all()
    moved = np.linalg.norm(frames - bunny.vertices, axis=2).max()
    assert 0.01 * bunny.bbox_diagonal < moved < 0.5 * bunny.bbox_diagonal
    assert np.allclose(d.weights.sum(1), 1) and (d.weights >= 0).all()
    assert np.bincount(d.weights.argmax(1), minlength=len(d.skeleton.names)).min() > 100  # every bone leads a region


def test_entry_point_is_registered():
    assert discover().config_class(DEFORMERS, "skeleton") is SkeletonConfig


BOTH = [SkeletonConfig(method="dqs"), SkeletonConfig(method="lbs")]


@parametrize_with_checks(
    BOTH,
    rest=TUBE,
    edit={**pose(upper={"rotate": {"axis": [1, 0, 0], "degrees": 45}}), "frames": 2},
    rigid_edit={**pose(lower={"rotate": {"axis": [1, 1, 0], "degrees": 35}, "translate": [0.2, 0, -0.1]}), "frames": 2},
    bad_edits=[pose(elbow={"translate": [0, 0, 1]}), {"skeleton": "chain.json"}],
)
def test_conformance_kit_json_pose(check, folder):
    check(base_dir=folder)


@parametrize_with_checks(
    BOTH,
    rest=TUBE,
    edit={"skeleton": "chain.bvh", "frames": 3},
    identity_edit={"skeleton": "chain.bvh", "pose": {"lower": {"translate": [0, 0, 0]}}},
    rigid_edit={"skeleton": "chain.bvh", "pose": {"lower": {"rotate": {"axis": [0, 1, 0], "degrees": 30}}}},
)
def test_conformance_kit_bvh_clip(check, folder):
    check(base_dir=folder)


# ---- multiresolution -------------------------------------------------------------------------------------------------
def test_bone_heat_on_a_coarse_level(folder, tmp_path):
    """Bone heat solved on a clustering of the tube to ~300 vertices and blended to its 986: rows still sum to 1 and
    are non-negative, a root pose is still rigid, a bend lands near the direct bind's; a coarse level of the mesh's
    own size gives the direct weights exactly; a second bind reads the level from the bind cache."""
    from nerfedit_plugin.edit.deformer import BindCache, mesh_digest

    spec = pose(upper={"rotate": {"axis": [1, 0, 0], "degrees": 60}})
    direct = bind(folder, spec)
    assert direct.report() == {"weights": "bone heat", "path": "direct"}
    coarse = bind(folder, spec, multiresolution="on", coarse_vertices=300)
    report = coarse.report()
    assert report["path"] == "multiresolution" and 270 <= report["coarse"]["vertices"] <= 330
    assert np.allclose(coarse.weights.sum(1), 1, atol=1e-12) and (coarse.weights >= 0).all()
    error = np.linalg.norm(coarse.deform()[0] - direct.deform()[0], axis=1)
    assert error.max() < 0.05 * TUBE.bbox_diagonal and error.mean() < 0.01 * TUBE.bbox_diagonal
    rigid = pose(lower={"rotate": {"axis": [1, 2, 3], "degrees": 70}, "translate": [0.3, -0.2, 0.5]})
    np.testing.assert_allclose(
        bind(folder, rigid, multiresolution="on", coarse_vertices=300).deform()[0], bind(folder, rigid).deform()[0],
        atol=1e-12,
    )  # fmt: skip
    whole = bind(folder, spec, multiresolution="on", coarse_vertices=TUBE.n_vertices)
    np.testing.assert_array_equal(whole.weights, direct.weights)
    cache = BindCache(tmp_path / "cache", mesh_digest(TUBE))
    runs = []
    for _ in range(2):
        deformer = SkeletonConfig(multiresolution="on", coarse_vertices=300).setup()
        deformer.bind_cache = cache
        deformer.bind(TUBE, parse_edit_spec(spec, SkeletonDeformer.spec_keys, "edit.json", folder))
        runs.append((deformer.report()["coarse"]["cached"], deformer.weights))
    assert [hit for hit, _ in runs] == [False, True]
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
