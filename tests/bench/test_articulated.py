"""The articulated subject of bench/bench_paper.py: its surface, and its rig driven by the ``skeleton`` deformer."""

import json

import numpy as np
import pytest
from articulated import JOINTS, POSE, build_subject, pose_axis, subject_sdf
from scipy.spatial.transform import Rotation

from deformers.skeleton import SkeletonConfig
from nerfedit_plugin.data.synthetic import normalize
from nerfedit_plugin.edit.spec import load_edit_spec


@pytest.fixture(scope="module")
def subject():
    return build_subject(cell=0.015)


def bind(subject, folder, pose: dict | None = None):
    """The skeleton deformer bound to the subject's mesh with ``pose`` (default: the subject's fixed pose)."""
    spec = subject.write(folder)
    if pose is not None:
        spec.write_text(json.dumps({"skeleton": "skeleton.json", "pose": pose}))
    rig = SkeletonConfig().setup()
    rig.bind(subject.mesh, load_edit_spec(spec, rig.spec_keys))
    return rig


def test_the_pose_is_the_one_fixed_before_any_score():
    degrees = {joint: degrees for joint, (degrees, _) in POSE.items()}
    assert degrees == {
        "shoulder.L": 45.0,
        "elbow.L": 60.0,
        "shoulder.R": 40.0,
        "elbow.R": 30.0,
        "hip.L": 30.0,
        "knee.L": 45.0,
        "hip.R": 35.0,
        "knee.R": 50.0,
        "neck": 30.0,
    }
    assert all(30.0 <= d <= 60.0 for d in degrees.values())


def test_surface_is_one_watertight_part_in_the_generator_frame(subject):
    mesh = subject.mesh
    surface = mesh.to_trimesh()
    assert surface.is_watertight and surface.volume > 0  # closed, faces wound outwards
    assert len(surface.split(only_watertight=False)) == 1
    assert mesh.vertex_colors is not None
    np.testing.assert_allclose(normalize(mesh).vertices, mesh.vertices, atol=1e-7)  # the generator keeps it
    high, low = mesh.vertices.max(0), mesh.vertices.min(0)
    assert high[2] - low[2] == pytest.approx(1.0)  # height 1, z up
    assert 3000 < mesh.n_vertices < 10000  # this lattice; the bench's default one gives ~25k
    assert 20000 < build_subject().mesh.n_vertices < 30000


def test_skeleton_lies_inside_the_subject(subject):
    """Every bone's head and tail (design units) is in the body: the bones drive the parts they sit in."""
    ends = np.array([end for _, head, tail in JOINTS.values() for end in (head, tail)])
    assert (subject_sdf(ends) <= 1e-12).all()  # the head bone ends at the top of the head
    names = [joint["name"] for joint in subject.skeleton["joints"]]
    assert names == list(JOINTS) and set(POSE) == set(names) - {"root"}


def test_rest_pose_is_identity(subject, tmp_path):
    rest = {joint: {"rotate": {"axis": [1.0, 0.0, 0.0], "degrees": 0.0}} for joint in POSE}
    rig = bind(subject, tmp_path / "rig", rest)
    np.testing.assert_allclose(rig.deform()[0], subject.mesh.vertices, atol=1e-12)
    points = np.random.default_rng(0).uniform(-0.5, 0.5, (50, 3))
    np.testing.assert_allclose(rig.deform_points(points, 0), points, atol=1e-12)


def test_rigid_pose_of_all_bones_is_a_rigid_motion(subject, tmp_path):
    """Turning and moving the root turns and moves every bone with it (children follow their parent)."""
    axis, degrees, shift = np.array([0.3, -0.5, 0.8]), 37.0, np.array([0.1, -0.2, 0.05])
    pose = {"root": {"rotate": {"axis": axis.tolist(), "degrees": degrees}, "translate": shift.tolist()}}
    rig = bind(subject, tmp_path / "rig", pose)
    head = np.asarray(subject.skeleton["joints"][0]["head"])
    rot = Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(degrees)).as_matrix()
    expected = (subject.mesh.vertices - head) @ rot.T + head + shift
    np.testing.assert_allclose(rig.deform()[0], expected, atol=1e-9)
    assert np.linalg.norm(rig.deform()[0] - subject.mesh.vertices, axis=1).min() > 1e-3  # it did move


@pytest.mark.parametrize("joint", list(POSE))
def test_each_joint_bends_by_its_angle_towards_its_direction(subject, tmp_path, joint):
    rig = bind(subject, tmp_path / "rig")
    names = rig.skeleton.names
    j = names.index(joint)
    parent = rig.skeleton.parents[j]
    relative = rig.rot[0, parent].T @ rig.rot[0, j]  # the joint's own turn, in its parent's frame
    assert np.degrees(Rotation.from_matrix(relative).magnitude()) == pytest.approx(POSE[joint][0], abs=1e-9)
    bone = rig.skeleton.tails[j] - rig.skeleton.heads[j]
    turned = relative @ bone
    cosine = bone @ turned / (np.linalg.norm(bone) * np.linalg.norm(turned))
    assert np.degrees(np.arccos(np.clip(cosine, -1, 1))) == pytest.approx(POSE[joint][0], abs=1e-6)  # axis ⟂ bone
    toward = {"forward": -1.0, "backward": 1.0}.get(POSE[joint][1])
    moved = turned - bone
    if toward is None:  # outward: away from the torso in x
        assert np.sign(moved[0]) == np.sign(rig.skeleton.heads[j][0]) and abs(moved[1]) < 1e-12
    else:
        assert np.sign(moved[1]) == toward
    axis = pose_axis(joint, POSE[joint][1])
    assert abs(axis @ bone) < 1e-12  # a hinge across the bone
    np.testing.assert_allclose(Rotation.from_matrix(relative).as_rotvec(), np.radians(POSE[joint][0]) * axis, atol=1e-9)


def test_posed_limbs_end_where_the_bones_go(subject, tmp_path):
    """The skin follows the bones: the vertex nearest each limb's tail at rest lands near the posed tail."""
    rig = bind(subject, tmp_path / "rig")
    posed = rig.deform()[0]
    for limb in ("elbow.L", "elbow.R", "knee.L", "knee.R"):
        j = rig.skeleton.names.index(limb)
        tail = rig.skeleton.tails[j]
        nearest = np.argmin(np.linalg.norm(subject.mesh.vertices - tail, axis=1))
        posed_tail = rig.rot[0, j] @ tail + rig.trans[0, j]
        assert np.linalg.norm(posed[nearest] - posed_tail) < 0.06  # within the limb's radius (~0.045)
        assert np.linalg.norm(posed_tail - tail) > 0.05  # and the limb really moved
