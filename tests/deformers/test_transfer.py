"""The transfer deformer: exact oracles (identity, self-transfer, similarities), the correspondence fit, the
prefactored solve, matching regions across meshes, artifacts, example specs, bad input and the conformance kit."""

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh
from scipy.sparse.linalg import spsolve
from scipy.spatial.transform import Rotation

from deformers.transfer import TransferConfig, TransferDeformer, TransferSystem, correspondence, gradient_operator
from deformers.transfer.gradients import gradient_rows, to_unit, with_fourth_vertices
from nerfedit_plugin.data.sequences import bending_capsule, capsule, twisting_bar
from nerfedit_plugin.edit.spec import load_edit_spec, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh, unit_frame
from nerfedit_plugin.testing import default_mesh, parametrize_with_checks

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
SOURCE, POSES = bending_capsule(n_frames=4)  # 290 vertices
TARGET = capsule(count=(17, 9))  # the same shape, another connectivity (182 vertices)
MARKER_POINTS = [[0, 0, 0.75], [0, 0, -0.75], [0.25, 0, 0], [-0.25, 0, 0], [0, 0.25, 0], [0, -0.25, 0]]


def snap(mesh, points):
    return [int(np.argmin(np.linalg.norm(mesh.vertices - p, axis=1))) for p in points]


def markers(target=TARGET, points=MARKER_POINTS, placed=lambda p: p):
    return np.column_stack([snap(SOURCE, points), snap(target, [placed(np.asarray(p)) for p in points])])


def bind(edit, base_dir, rest=TARGET, config=None):
    deformer = (config or TransferConfig()).setup()
    deformer.bind(rest, parse_edit_spec(edit, TransferDeformer.spec_keys, "edit.json", base_dir))
    return deformer


@pytest.fixture
def source_files(tmp_path):
    """The bending capsule as ``rest.ply`` + ``poses.npz`` in tmp_path."""
    SOURCE.save(tmp_path / "rest.ply")
    np.savez(tmp_path / "poses.npz", frames=POSES)
    return {"source_rest": "rest.ply", "source_frames": "poses.npz"}


def similarity_error(out, reference):
    """Largest residual of the best similarity ``out ≈ s R reference + b`` (Umeyama), over the bbox diagonal."""
    a, b = reference - reference.mean(0), out - out.mean(0)
    u, sigma, vt = np.linalg.svd(a.T @ b)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rot, scale = (u @ d @ vt).T, float(np.trace(np.diag(sigma) @ d) / np.sum(a * a))
    return np.abs(scale * a @ rot.T - b).max() / np.linalg.norm(np.ptp(out, axis=0))


# ---- exact oracles ---------------------------------------------------------------------------------------------
def test_identity_pose_reproduces_the_target(source_files, tmp_path):
    edit = {**source_files, "source_frames": "rest.ply", "markers": markers().tolist()}
    out = bind(edit, tmp_path).deform()
    assert out.shape == (1, TARGET.n_vertices, 3) and np.abs(out[0] - TARGET.vertices).max() < 1e-10


def test_self_transfer_reproduces_the_source_poses(source_files, tmp_path):
    out = bind(source_files, tmp_path, rest=SOURCE).deform()
    assert out.shape == POSES.shape and np.abs(out - POSES).max() < 1e-10
    bar, twists = twisting_bar(n_frames=3)
    system = TransferSystem(bar, bar, np.column_stack([np.arange(len(bar.faces))] * 2))
    assert max(np.abs(system.transfer(pose) - pose).max() for pose in twists) < 1e-10


@pytest.mark.parametrize("scale", [0.5, 1.0, 3.0])
def test_similarity_poses_transfer_exactly_onto_another_mesh(scale):
    pairs = correspondence(SOURCE, TARGET, markers()).pairs
    system = TransferSystem(SOURCE, TARGET, pairs)
    rot = Rotation.from_rotvec([0.4, -0.9, 0.3]).as_matrix()
    out = system.transfer(scale * SOURCE.vertices @ rot.T + [2.0, -1.0, 0.5])
    expected = scale * TARGET.vertices @ rot.T
    assert np.abs((out - expected) - (out - expected).mean(0)).max() < 1e-10  # the target's own similarity
    assert similarity_error(out, TARGET.vertices) < 1e-12


# ---- correspondence --------------------------------------------------------------------------------------------
def test_markers_are_satisfied_and_every_phase_brings_the_source_closer():
    pairs_of_markers = markers()
    corr = correspondence(SOURCE, TARGET, pairs_of_markers)
    np.testing.assert_allclose(corr.fitted[pairs_of_markers[:, 0]], TARGET.vertices[pairs_of_markers[:, 1]], atol=1e-12)
    distances = np.asarray(corr.distances)
    assert len(distances) == len(TransferConfig().closest_weights)
    assert np.all(np.diff(distances) < 0), distances
    assert distances[-1] < 0.1 * distances[0] and distances[-1] < 1e-3  # in target bbox diagonals
    covered = np.zeros(len(TARGET.faces), dtype=bool)
    covered[corr.pairs[:, 1]] = True
    assert covered.all() and len(np.unique(corr.pairs[:, 0])) == len(SOURCE.faces)


def test_same_connectivity_needs_no_markers():
    corr = correspondence(SOURCE, SOURCE.with_vertices(2.0 * SOURCE.vertices), np.zeros((0, 2), dtype=np.int64))
    np.testing.assert_array_equal(corr.pairs, np.column_stack([np.arange(len(SOURCE.faces))] * 2))


def test_matching_regions_of_two_meshes_of_one_shape_move_alike():
    """Bend transferred onto a remeshed capsule: each target vertex moves as the source surface point under it.
    Measured (worst frame): mean error 1.2 %, max 3.1 % of the largest source displacement."""
    system = TransferSystem(SOURCE, TARGET, correspondence(SOURCE, TARGET, markers()).pairs)
    triangle, bary = raycast.closest_points(raycast.raycasting_scene(SOURCE.vertices, SOURCE.faces), TARGET.vertices)
    for pose in POSES[1:]:
        expected = np.einsum("pkd,pk->pd", pose[SOURCE.faces[triangle]], bary)
        error = (
            np.linalg.norm(system.transfer(pose) - expected, axis=1)
            / np.linalg.norm(pose - SOURCE.vertices, axis=1).max()
        )
        assert error.mean() < 0.02 and error.max() < 0.05, (error.mean(), error.max())


# ---- the solve -------------------------------------------------------------------------------------------------
def test_prefactored_solve_equals_a_fresh_solve_of_the_full_system():
    """Factor once, solve per pose = solving the normal equations with every fourth vertex kept (scipy, afresh)."""
    pairs = correspondence(SOURCE, TARGET, markers()).pairs
    system = TransferSystem(SOURCE, TARGET, pairs)
    src = to_unit(SOURCE.vertices, unit_frame(SOURCE.vertices))
    tgt_frame = unit_frame(TARGET.vertices)
    op_s, _ = gradient_operator(src, SOURCE.faces)
    op_t, _ = gradient_operator(to_unit(TARGET.vertices, tgt_frame), TARGET.faces)
    a = op_t[gradient_rows(pairs[:, 1])]
    used = np.concatenate([np.arange(TARGET.n_vertices), TARGET.n_vertices + np.unique(pairs[:, 1])])[1:]  # pin 0
    for pose in POSES[1:]:
        unit_pose = to_unit(pose, unit_frame(SOURCE.vertices))
        c = (op_s @ with_fourth_vertices(unit_pose, SOURCE.faces))[gradient_rows(pairs[:, 0])]
        a_used = sp.csc_matrix(a[:, used])
        fresh = np.column_stack([spsolve((a_used.T @ a_used).tocsc(), a_used.T @ c[:, d]) for d in range(3)])
        fresh = tgt_frame[0] + tgt_frame[1] * fresh[: TARGET.n_vertices - 1]
        ours = system.transfer(pose)[1:]
        assert np.abs((ours - fresh) - (ours - fresh).mean(0)).max() < 1e-9  # equal up to the pinned translation


def test_sequence_frames_equal_single_pose_binds(source_files, tmp_path):
    out = bind(source_files, tmp_path, rest=SOURCE).deform()
    np.savez(tmp_path / "one.npz", frames=POSES[2:3])
    single = bind({**source_files, "source_frames": "one.npz"}, tmp_path, rest=SOURCE).deform()
    np.testing.assert_allclose(single[0], out[2], rtol=0, atol=1e-12)


def test_one_pose_with_frames_is_interpolated_from_the_source_rest(source_files, tmp_path):
    np.savez(tmp_path / "one.npz", frames=POSES[-1:])
    out = bind({**source_files, "source_frames": "one.npz", "frames": 3}, tmp_path, rest=SOURCE).deform()
    np.testing.assert_allclose(out[[0, 2]], [SOURCE.vertices, POSES[-1]], rtol=0, atol=1e-10)


# ---- inspection and reuse --------------------------------------------------------------------------------------
def test_artifacts_overlay_and_saved_correspondence(source_files, tmp_path):
    edit = {**source_files, "markers": markers().tolist()}
    deformer = bind(edit, tmp_path)
    written = deformer.write_artifacts(tmp_path / "out")
    assert [p.name for p in written] == ["transfer_correspondence.npz", "transfer_source.ply", "transfer_target.ply"]
    coloured = SurfaceMesh.load(tmp_path / "out" / "transfer_target.ply")
    assert len(coloured.faces) == len(TARGET.faces) and coloured.vertex_colors is not None
    (overlay,) = TransferDeformer.overlays(tmp_path / "out", 0)
    assert overlay.layer == "correspondence" and overlay.rest.n_vertices == 3 * len(SOURCE.faces)
    again = bind({**source_files, "correspondence": "out/transfer_correspondence.npz"}, tmp_path)
    np.testing.assert_array_equal(again.deform(), deformer.deform())
    twisting_bar(n_frames=1)[0].save(tmp_path / "bar.ply")
    other = {"source_rest": "bar.ply", "source_frames": "bar.ply", "correspondence": "out/transfer_correspondence.npz"}
    with pytest.raises(NerfEditError, match=r"edit.json: correspondence: .*other faces than those of source_rest"):
        bind(other, tmp_path)


@pytest.mark.parametrize(
    ("spec", "target"),
    [("transfer_capsule_bend.json", "capsule_rest.ply"), ("transfer_capsule_to_remeshed.json", "capsule_remeshed.ply")],
)
def test_example_specs(spec, target):
    assert sorted(p.name for p in CONFIGS.glob("transfer*.json")) == [
        "transfer_capsule_bend.json",
        "transfer_capsule_to_remeshed.json",
    ]
    rest = SurfaceMesh.load(CONFIGS / "transfer" / target)
    deformer = TransferConfig().setup()
    deformer.bind(rest, load_edit_spec(CONFIGS / spec, deformer.spec_keys))
    out = deformer.deform()
    assert out.shape == (6, rest.n_vertices, 3) and np.abs(out[0] - rest.vertices).max() < 1e-9
    top = rest.vertices[:, 2] > 0.6
    assert np.all(out[-1][top, 1] < -0.5)  # the top bent 90° about x towards −y


# ---- bad input -------------------------------------------------------------------------------------------------
def test_bad_input_names_the_file_and_key(source_files, tmp_path):
    small = SurfaceMesh.from_trimesh(trimesh.creation.icosphere(subdivisions=1))
    small.save(tmp_path / "small.ply")
    with pytest.raises(
        NerfEditError, match=r"^edit.json: source_frames: .*small.ply: 42 vertices, source_rest has 290$"
    ):
        bind({**source_files, "source_frames": ["rest.ply", "small.ply"]}, tmp_path, rest=SOURCE)
    swapped = SOURCE.faces.copy()
    swapped[5] = swapped[5, [0, 2, 1]]
    SurfaceMesh(SOURCE.vertices, swapped).save(tmp_path / "flipped.ply")
    with pytest.raises(NerfEditError, match=r"flipped.ply: connectivity differs from source_rest: face 5 is"):
        bind({**source_files, "source_frames": "flipped.ply"}, tmp_path, rest=SOURCE)
    with pytest.raises(NerfEditError, match=r"edit.json: source_frames: pattern 'poses/\*.obj' matches no file"):
        bind({**source_files, "source_frames": "poses/*.obj"}, tmp_path)
    with pytest.raises(
        NerfEditError, match=r"edit.json: markers\[1\]\[1\]: vertex 999 out of range \(the rest mesh has"
    ):
        bind({**source_files, "markers": [[0, 0], [1, 999]]}, tmp_path)
    with pytest.raises(NerfEditError, match=r"markers\[0\]\[0\]: vertex -1 out of range"):
        bind({**source_files, "markers": [[-1, 0]]}, tmp_path)
    np.savez(tmp_path / "bad.npz", frames=POSES[:, :10])
    with pytest.raises(NerfEditError, match=r"bad.npz: poses of shape \(4, 10, 3\), expected \(frames, 290, 3\)"):
        bind({**source_files, "source_frames": "bad.npz"}, tmp_path)
    with pytest.raises(NerfEditError, match=r"edit.json: frames: 3 frames but source_frames gives 4 poses"):
        bind({**source_files, "frames": 3}, tmp_path, rest=SOURCE)
    with pytest.raises(NerfEditError, match=r"edit.json: markers: .*need(s)? markers"):
        bind(source_files, tmp_path)  # other connectivity, no markers


def test_unmatched_target_triangles_are_reported(source_files, tmp_path):
    """A target with a second part far from the source: its triangles find no source triangle."""
    far = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    both = SurfaceMesh(
        np.concatenate([TARGET.vertices, np.asarray(far.vertices) + [2.0, 0, 0]]),
        np.concatenate([TARGET.faces, np.asarray(far.faces) + TARGET.n_vertices]),
    )
    edit = {**source_files, "markers": markers(both).tolist()}
    with pytest.raises(
        NerfEditError, match=r"^edit.json: markers: the correspondence leaves 80 of 440 target triangles"
    ):
        bind(edit, tmp_path, rest=both)


def test_config_options_are_validated():
    with pytest.raises(NerfEditError, match="TransferConfig.closest_weights"):
        TransferConfig(closest_weights=())
    with pytest.raises(NerfEditError, match="TransferConfig.match_distance"):
        TransferConfig(match_distance=float("nan"))


# ---- conformance kit -------------------------------------------------------------------------------------------
KIT_REST = default_mesh()  # icosphere ellipsoid, 162 vertices
_uv = trimesh.creation.uv_sphere(radius=1.0, count=[16, 12])
KIT_SOURCE = SurfaceMesh(np.asarray(_uv.vertices) * [0.4, 0.5, 1.0], np.asarray(_uv.faces))  # other connectivity
AXES = [[0, 0, 1.0], [0, 0, -1.0], [0.4, 0, 0], [-0.4, 0, 0], [0, 0.5, 0], [0, -0.5, 0]]


@parametrize_with_checks(
    TransferConfig(),
    rest=KIT_REST,
    edit={"source_rest": "src.ply", "source_frames": "poses.npz", "markers": [[p, p] for p in AXES], "frames": 2},
    rigid_edit={"source_rest": "src.ply", "source_frames": "rigid.ply", "markers": [[p, p] for p in AXES]},
)
def test_conformance_kit(check, tmp_path):
    KIT_SOURCE.save(tmp_path / "src.ply")
    v = KIT_SOURCE.vertices
    bent = v + np.column_stack([0.3 * v[:, 2] ** 2, np.zeros(len(v)), 0.1 * v[:, 2]])
    np.savez(tmp_path / "poses.npz", frames=np.stack([v, bent]))
    rot = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix()
    KIT_SOURCE.with_vertices(v @ rot.T + [0.2, 0.1, -0.3]).save(tmp_path / "rigid.ply")
    check(base_dir=tmp_path)


def test_spec_file_round_trip(source_files, tmp_path):
    (tmp_path / "edit.json").write_text(json.dumps({**source_files, "markers": markers().tolist()}))
    spec = load_edit_spec(tmp_path / "edit.json", TransferDeformer.spec_keys)
    deformer = TransferConfig().setup()
    deformer.bind(TARGET, spec)
    assert deformer.deform().shape == (4, TARGET.n_vertices, 3)


def test_registered_as_entry_point():
    from nerfedit_plugin.registry import DEFORMERS, discover

    assert discover().config_class(DEFORMERS, "transfer") is TransferConfig


@pytest.mark.parametrize("name", ["transfer_capsule_bend.json", "transfer_capsule_to_remeshed.json"])
def test_example_sequences_lift_without_inverted_tets(name, tmp_path, proxy_cache):
    """``nerfedit edit`` of each example spec onto its target: every lifted frame is free of inverted tets."""
    from nerfedit_plugin.cli.app import main

    spec = json.loads((CONFIGS / name).read_text())
    mesh = CONFIGS / "transfer" / ("capsule_remeshed.ply" if "remeshed" in name else "capsule_rest.ply")
    argv = ["edit", "--mesh", mesh, "--deformer", "transfer", "--edit", CONFIGS / name, "--out", tmp_path / "edit",
            "--cache-dir", proxy_cache]  # fmt: skip
    assert main([str(a) for a in argv]) == 0
    report = json.loads((tmp_path / "edit" / "report.json").read_text())
    assert len(report["per_frame"]) == report["frames"] > 1 and spec["source_frames"]
    assert all(frame["inverted_tets"] == 0 for frame in report["per_frame"])
