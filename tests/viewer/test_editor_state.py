"""The editor's state without a window: selections, handles, moves, undo/redo, the spec it saves (reproduced by
``nerfedit edit`` to 1e-9) for the arap, cage and skeleton backends, a saved spec opened again, picking through a
camera, and bad input (a message, nothing changed or written)."""

import json
import os

import numpy as np
import pytest

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.viewer.backends import editing_backend
from nerfedit_plugin.viewer.editor_state import EditorState
from nerfedit_plugin.viewer.picking import Picker, View

MESH = "sample:bone"


@pytest.fixture(scope="module")
def bone():
    return SurfaceMesh.load(MESH)


def _state(mesh, **kwargs):
    return EditorState(editing_backend("arap", mesh), **kwargs)


def _ends(mesh):
    """Vertices of the bone's two ends along its longest axis."""
    axis = int(np.argmax(np.ptp(mesh.vertices, axis=0)))
    x = mesh.vertices[:, axis]
    low, high = np.quantile(x, [0.08, 0.92])
    return np.flatnonzero(x <= low), np.flatnonzero(x >= high)


def _hold_ends(state, mesh) -> tuple[np.ndarray, np.ndarray]:
    """Make the mesh's two ends (:func:`_ends`) a fixed and a moving handle of ``state``; returns their vertices."""
    fixed, moving = _ends(mesh)
    state.select(fixed)
    state.mark(True)
    state.select(moving)
    state.mark(False)
    return fixed, moving


def _edited(mesh):
    state = _state(mesh)
    fixed, moving = _ends(mesh)
    state.select(fixed)
    state.mark(True)
    state.select(moving[:5])
    state.grow(0.02 * mesh.bbox_diagonal)
    state.mark(False)
    state.translate([0.0, 0.05 * mesh.bbox_diagonal, 0.0])
    state.rotate([0.0, 0.0, 1.0], 20.0)
    state.scale(1.1, pivot=mesh.vertices[moving].mean(0))
    return state


def test_moves_compose_into_the_spec_transform(bone):
    """The handle's composed moves equal the spec's transform applied to its rest points."""
    state = _edited(bone)
    handle = state.active
    rest = bone.vertices[handle.indices]
    expected = rest.copy()
    expected += [0.0, 0.05 * bone.bbox_diagonal, 0.0]
    pivot = handle.center + [0.0, 0.05 * bone.bbox_diagonal, 0.0]
    from scipy.spatial.transform import Rotation

    expected = pivot + Rotation.from_rotvec([0, 0, np.radians(20)]).apply(expected - pivot)
    scale_pivot = bone.vertices[_ends(bone)[1]].mean(0)
    expected = scale_pivot + 1.1 * (expected - scale_pivot)
    indices, targets = state.targets()
    assert np.allclose(targets[0][np.searchsorted(indices, handle.indices)], expected, atol=1e-12)


def test_saved_spec_reproduces_the_editor_exactly(bone, tmp_path):
    state = _edited(bone)
    preview = state.preview()
    assert state.backend.last_iterations <= state.backend.iterations
    converged, before, after, _ = state.converge()  # settle on release: the preview's solve finished
    assert after < before and np.abs(converged - preview).max() > 0
    settled = state.settle()
    assert np.abs(preview - settled[0]).max() < 0.05 * bone.bbox_diagonal  # the preview is close to the solve
    written = state.save(tmp_path / "edit.json")
    assert [p.name for p in written] == [
        "edit.handle0.selection.json",
        "edit.handle1.selection.json",
        "edit.json",
    ]
    spec = json.loads((tmp_path / "edit.json").read_text())
    assert spec["handles"][0] == {"select": {"file": "edit.handle0.selection.json"}, "fixed": True}
    assert len(load_edit_spec(tmp_path / "edit.json").handles) == 2
    assert np.abs(_reproduced(tmp_path, "arap", tmp_path / "edit.json") - state.deformed).max() <= 1e-9
    # indices instead of selection files: the same spec
    state.save(tmp_path / "inline.yaml", selection_files=False)
    inline = load_edit_spec(tmp_path / "inline.yaml")
    assert np.array_equal(inline.handle_targets(bone.vertices)[1], state.targets()[1])


def _reproduced(tmp_path, deformer, spec):
    """The deformed mesh `nerfedit edit` writes for ``spec`` on the bone."""
    out = tmp_path / f"out-{deformer}"
    assert main(["edit", "--mesh", MESH, "--deformer", deformer, "--edit", str(spec), "--out", str(out)]
                + ["--lift", "closest-point"]) == 0  # fmt: skip
    return SurfaceMesh.load(out / "deformed_mesh.ply").vertices


def test_an_opened_spec_keeps_editing(bone, tmp_path):
    """A saved spec (selection files, a rotation about a pivot that is not the centroid) opens with the same handles:
    the same targets at every frame of an animation, and editing goes on."""
    state = _edited(bone)
    state.rotate([1.0, 0.0, 0.0], 15.0, pivot=bone.vertices[0])
    state.set_frames(4)
    state.save(tmp_path / "edit.json")
    opened = EditorState.open("arap", bone, tmp_path / "edit.json")
    assert opened.frames == 4 and opened.active is not None and len(opened.handles) == 2
    assert np.array_equal(opened.targets()[0], state.targets()[0])
    assert np.abs(opened.targets()[1] - state.targets()[1]).max() <= 1e-12
    opened.translate([0.0, 0.0, 0.01])  # editing goes on: a move, undone
    opened.undo()
    assert np.abs(opened.targets()[1] - state.targets()[1]).max() <= 1e-12


def test_cage_backend_moves_cage_vertices_and_saves_a_reproducible_spec(bone, tmp_path):
    """With the cage deformer the handles are cage vertices; the preview (the bound coordinates) is the exact pose,
    undo/redo restore it, and `nerfedit edit --deformer cage` reproduces it to 1e-9 from the saved spec."""
    state = EditorState(editing_backend("cage", bone))
    cage = state.backend.points
    assert state.backend.what == "cage vertices" and len(cage) < bone.n_vertices
    axis = int(np.argmax(np.ptp(cage, axis=0)))
    state.select(np.flatnonzero(cage[:, axis] >= np.quantile(cage[:, axis], 0.8)))
    state.grow(0.05 * bone.bbox_diagonal)  # along the cage's edges
    state.mark(False)
    lift = [0.0, 0.0, 0.0]
    lift[(axis + 1) % 3] = 0.1 * bone.bbox_diagonal
    state.translate(lift)
    state.preview()
    moved = state.deformed.copy()
    state.rotate([1.0, 0.0, 0.0], 20.0)
    state.preview()
    turned = state.deformed.copy()
    assert np.abs(turned - moved).max() > 1e-3 * bone.bbox_diagonal
    state.undo()
    assert np.array_equal(state.preview(), moved)
    state.redo()
    assert np.array_equal(state.preview(), turned)
    assert np.abs(state.settle()[0] - turned).max() <= 1e-9  # the preview is the deformer's own pose
    state.save(tmp_path / "cage.json")
    spec = json.loads((tmp_path / "cage.json").read_text())
    assert spec["cage"] == "auto" and spec["handles"][0]["select"] == {"file": "cage.handle0.selection.json"}
    assert np.abs(_reproduced(tmp_path, "cage", tmp_path / "cage.json") - state.deformed).max() <= 1e-9
    opened = EditorState.open("cage", bone, tmp_path / "cage.json")
    assert np.abs(opened.preview() - turned).max() <= 1e-12


def test_skeleton_backend_turns_joints_and_saves_a_reproducible_spec(bone, tmp_path):
    """With the skeleton deformer a handle is one joint, turned about its head; the preview is the skinned pose, the
    saved pose is reproduced by `nerfedit edit --deformer skeleton` to 1e-9, and the spec opens again."""
    axis = int(np.argmax(np.ptp(bone.vertices, axis=0)))
    low, high = bone.vertices[:, axis].min(), bone.vertices[:, axis].max()
    centre = bone.vertices.mean(0)
    heads = [centre.copy() for _ in range(3)]
    for head, x in zip(heads, (low, 0.5 * (low + high), high)):
        head[axis] = x
    joints = [
        {"name": "lower", "parent": None, "head": heads[0].tolist()},
        {"name": "upper", "parent": "lower", "head": heads[1].tolist(), "tail": heads[2].tolist()},
    ]
    (tmp_path / "bone.skeleton.json").write_text(json.dumps({"joints": joints}))
    state = EditorState(editing_backend("skeleton", bone, {"skeleton": tmp_path / "bone.skeleton.json"}))
    with pytest.raises(NerfEditError, match="one moving joint"):
        state.select([0, 1])
        state.mark(False)
    state.select([1], mode="replace")
    with pytest.raises(NerfEditError, match="one moving joint"):
        state.mark(True)
    with pytest.raises(NerfEditError, match="no surface to grow along"):
        state.grow(0.1)
    state.mark(False)
    with pytest.raises(NerfEditError, match="do not scale"):
        state.scale(1.1)
    bend = [0.0, 0.0, 0.0]
    bend[(axis + 1) % 3] = 1.0
    state.rotate(bend, 30.0)
    state.preview()
    assert np.allclose(state.posed_points[1], heads[1])  # turned about its own head
    assert np.abs(state.deformed - bone.vertices).max() > 0.05 * bone.bbox_diagonal
    assert np.abs(state.settle()[0] - state.deformed).max() <= 1e-9
    state.save(tmp_path / "pose.json")
    spec = json.loads((tmp_path / "pose.json").read_text())
    assert spec["skeleton"] == "bone.skeleton.json" and set(spec["pose"]) == {"upper"}
    assert np.abs(_reproduced(tmp_path, "skeleton", tmp_path / "pose.json") - state.deformed).max() <= 1e-9
    opened = EditorState.open("skeleton", bone, tmp_path / "pose.json")
    assert np.abs(opened.preview() - state.deformed).max() <= 1e-9


def test_undo_redo_and_a_drag_is_one_step(bone):
    state = _state(bone)
    fixed, moving = _hold_ends(state, bone)
    state.translate([0.01, 0, 0])
    for _ in range(5):
        state.translate([0.01, 0, 0], record=False)  # the rest of a drag
    assert np.allclose(state.active.translate, [0.06, 0, 0])
    state.undo()
    assert np.allclose(state.active.translate, 0)
    state.redo()
    assert np.allclose(state.active.translate, [0.06, 0, 0])
    for _ in range(3):  # the move, the moving handle, its selection
        state.undo()
    assert len(state.handles) == 1 and not len(state.selection)
    state.undo()
    assert not state.handles and np.array_equal(state.selection, fixed)
    with pytest.raises(NerfEditError, match="nothing to redo"):
        state.select([0])
        state.redo()


def test_geodesic_grow_follows_the_surface(bone):
    state = _state(bone)
    start = int(np.argmax(bone.vertices[:, 0]))
    state.select([start])
    state.grow(0.05 * bone.bbox_diagonal)
    grown = state.selection
    assert start in grown and 1 < len(grown) < bone.n_vertices
    euclid = np.linalg.norm(bone.vertices[grown] - bone.vertices[start], axis=1)
    assert euclid.max() <= 0.05 * bone.bbox_diagonal + 1e-12  # a geodesic ball lies inside the euclidean one


def test_bad_input_is_a_message_and_changes_nothing(bone, tmp_path):
    state = _state(bone)
    with pytest.raises(NerfEditError, match="no surface under the cursor"):
        state.select([])
    state.select(np.arange(bone.n_vertices))
    with pytest.raises(NerfEditError, match="covers the whole mesh"):
        state.mark(False)
    assert not state.handles
    state.clear_selection()
    with pytest.raises(NerfEditError, match="no moving handle"):
        state.translate([1, 0, 0])
    # a moving handle alone: said, and the mesh moves rigidly
    state.select(_ends(bone)[1])
    assert "no fixed handle" in state.mark(False)
    state.translate([0.1, 0.0, 0.0])
    surface = np.unique(bone.faces)  # the sample has unreferenced vertices, which ARAP leaves where they are
    assert np.allclose(state.settle()[0][surface], bone.vertices[surface] + [0.1, 0.0, 0.0], atol=1e-6)
    # a read-only place: an error before anything is written, an existing spec left as it was
    (tmp_path / "edit.json").write_text("keep")
    read_only = tmp_path / "ro"
    read_only.mkdir()
    read_only.chmod(0o500)
    target = read_only if os.geteuid() != 0 else tmp_path / "missing" / "sub"  # root writes anywhere: a missing folder
    with pytest.raises(NerfEditError, match="cannot write into"):
        state.save(target / "edit.json")
    with pytest.raises(NerfEditError, match="cannot write into"):
        state.save("/proc/nerfedit-editor/edit.json")
    assert (tmp_path / "edit.json").read_text() == "keep" and not list(read_only.iterdir())


def test_a_deformer_without_an_editor_backend_is_refused_by_name(bone, tmp_path):
    """``mesh`` declares no backend (``Deformer.editor`` None): one error naming it, for a new edit and a saved spec."""
    with pytest.raises(NerfEditError, match="deformer 'mesh' offers no editor backend"):
        editing_backend("mesh", bone)
    (tmp_path / "edit.json").write_text(json.dumps({"deformed": "edited.ply"}))
    with pytest.raises(NerfEditError, match="deformer 'mesh' offers no editor backend"):
        EditorState.open("mesh", bone, tmp_path / "edit.json")


def test_picking_through_a_camera(bone):
    """A vertex projected to a pixel is picked back (when in front), a box picks the visible vertices in it, a drag
    of the view plane keeps its anchor under the cursor, and empty space picks nothing."""
    centre = bone.vertices.mean(0)
    eye = centre + np.array([0.0, 0.0, 2.0 * bone.bbox_diagonal])
    view = np.eye(4)
    view[:3, 3] = -eye  # camera looks along -z from eye
    f, near = 1.0 / np.tan(np.radians(30)), 0.01
    projection = np.array([[f * 0.75, 0, 0, 0], [0, f, 0, 0], [0, 0, -1, -2 * near], [0, 0, -1, 0]])
    camera = View(view, projection, 400, 300)
    picker = Picker(bone.vertices, bone.faces)
    front = int(np.argmax(bone.vertices[:, 2]))
    pixel, depth = camera.project(bone.vertices[[front]])
    assert depth[0] > 0
    picked = picker.click(camera, *pixel[0])
    assert (
        picked is not None and np.linalg.norm(bone.vertices[picked] - bone.vertices[front]) < 0.02 * bone.bbox_diagonal
    )
    assert picker.click(camera, 0, 0) is None
    boxed = picker.box(camera, (0, 0), (400, 300))
    assert 0 < len(boxed) < bone.n_vertices  # the back is hidden
    joints = Picker(bone.vertices[[front, 0]], None)  # points without a surface (skeleton joints): nothing hides them
    assert joints.click(camera, *(pixel[0] + 3.0)) == 0 and joints.click(camera, 0, 0) is None
    motion = camera.plane_motion(centre, 10.0, 0.0)
    moved_pixel = camera.project((centre + motion)[None])[0][0]
    assert np.allclose(moved_pixel - camera.project(centre[None])[0][0], [10.0, 0.0], atol=1e-6)


def test_a_large_mesh_is_edited_on_its_coarse_level(bone):
    """Multiresolution (forced here, as above the threshold): each preview solves the coarse level and shows the fine
    surface it carries, handle vertices on their targets; the settle on release lands where the edit's own
    multiresolution solve does."""
    from deformers.arap import ArapConfig

    config = ArapConfig(multiresolution="on", coarse_vertices=bone.n_vertices // 3)
    state = EditorState(editing_backend("arap", bone, config=config))
    assert state.backend.level is not None and state.backend.level.coarse.n_vertices < bone.n_vertices // 2
    _hold_ends(state, bone)
    state.translate([0.0, 0.1 * bone.bbox_diagonal, 0.0])
    preview = state.preview()
    indices, targets = state.targets()
    assert preview.shape == bone.vertices.shape and np.array_equal(preview[indices], targets[0])
    converged, before, after, _ = state.converge()
    assert after < before and np.array_equal(converged[indices], targets[0])
    settled = state.settle()[0]
    assert np.abs(converged - settled).max() < 1e-3 * bone.bbox_diagonal


def _fresh(state):
    """The state's spec parsed afresh from its data, resolved by :meth:`EditSpec.handle_targets`."""
    from nerfedit_plugin.edit.spec import parse_edit_spec

    spec = parse_edit_spec(state.spec_data(), state.backend.spec_keys, "<editor>")
    return spec.handle_targets(state.backend.points, state.backend.faces)


def test_the_drag_spec_equals_the_spec_parsed_afresh(bone):
    """The spec a drag reuses (index selections parsed, and resolved, once per handle set) gives the handle points and
    targets of its data parsed and resolved afresh, through moves, a new handle, an overlapping one and undo."""
    state = _state(bone)
    fixed, moving = _hold_ends(state, bone)
    checks = [
        lambda: state.translate([0.01, 0.02, 0.0]),
        lambda: state.translate([0.01, 0.0, 0.0], record=False),
        lambda: state.rotate([0.0, 1.0, 0.0], 15.0, record=False),
        lambda: state.scale(1.1, record=False),
        lambda: (state.select(moving[: len(moving) // 2]), state.mark(False)),  # overlaps: the last listed wins
        lambda: state.translate([0.0, 0.0, 0.03]),
        lambda: state.set_frames(4),
        state.undo,
        state.undo,
    ]
    for change in checks:
        change()
        for _ in range(2):  # the second call reuses the resolution
            indices, targets = state.targets()
            expected_indices, expected_targets = _fresh(state)
            assert np.array_equal(indices, expected_indices) and np.array_equal(targets, expected_targets)


def test_drag_previews_on_the_coarse_level_keep_handles_exact(bone):
    state = _coarse_drag(bone)
    for _ in range(3):
        state.translate([0.0, 0.02 * bone.bbox_diagonal, 0.0], record=False)
        preview = state.preview()
        indices, targets = _fresh(state)
        assert np.array_equal(preview[indices], targets[0])


def test_the_shown_mesh_takes_the_positions_rounded_once_and_owns_them(bone):
    from nerfedit_plugin.viewer.editor import _mesh, _set_positions

    shown = _mesh(bone.vertices, bone.faces, (0.7, 0.7, 0.7))
    moved = bone.vertices + 0.01
    _set_positions(shown, moved, normals=False)
    expected = moved.astype(np.float32)
    moved += 1.0  # the caller's array is not the mesh's
    np.testing.assert_array_equal(shown.vertex.positions.numpy(), expected)


def _coarse_drag(bone):
    """An editor on the bone forced onto the multiresolution path, its ends the fixed and the moving handle."""
    from deformers.arap import ArapConfig

    config = ArapConfig(multiresolution="on", coarse_vertices=bone.n_vertices // 3)
    state = EditorState(editing_backend("arap", bone, config=config))
    _hold_ends(state, bone)
    return state


def test_a_drag_on_the_coarse_level_shows_it_with_its_handles_on_their_targets(bone):
    """During a drag above the threshold the shown surface is the coarse level as solved: its faces, the coarse
    handles (fixed and moving, together the solver's) exactly on their coarse targets; the mesh is left as posed."""
    state = _coarse_drag(bone)
    rest = state.deformed.copy()
    backend, level = state.backend, state.backend.level
    for _ in range(3):
        state.translate([0.0, 0.02 * bone.bbox_diagonal, 0.0], record=False)
        live = state.preview_drag()
        assert live is state.live and live.faces is level.coarse.faces
        assert live.vertices.shape == level.coarse.vertices.shape
        multires = backend.solver(state.targets()[0])
        indices, targets = _fresh(state)
        coarse_targets = multires.coarse_targets(targets)[0]
        assert np.array_equal(np.union1d(live.fixed, live.moving), multires.fixed)
        assert len(live.moving) and not np.intersect1d(live.fixed, live.moving).size
        assert np.array_equal(live.vertices[multires.fixed], coarse_targets)
        moved = np.isin(live.moving, level.owner[_ends(bone)[1]])
        assert moved.all()
    assert np.array_equal(state.deformed, rest)


def test_the_release_after_a_coarse_drag_shows_the_fine_surface_the_settled_solve_gives(bone):
    """Release after live coarse moves = release after the same moves previewed on the fine surface (today's drag):
    the same coarse solves, so the same converged fine surface, bit for bit, handle vertices on their targets."""
    live_state, fine_state = _coarse_drag(bone), _coarse_drag(bone)
    for _ in range(3):
        for state in (live_state, fine_state):
            state.translate([0.0, 0.02 * bone.bbox_diagonal, 0.0], record=False)
        live_state.preview_drag()
        fine_state.preview()
    expected = fine_state.converge()
    done = live_state.converge()
    shown = live_state.released(done)
    assert live_state.live is None and shown is live_state.deformed
    np.testing.assert_array_equal(shown, expected[0])
    assert done[1:] == expected[1:]
    indices, targets = _fresh(live_state)
    assert np.array_equal(shown[indices], targets[0])


def test_the_default_drag_hook_shows_the_mesh_as_the_preview_poses_it(bone):
    """A backend that does not override ``preview_drag`` (the direct ARAP path, the cage backend) shows the mesh
    during a drag exactly as :meth:`EditorState.preview` poses it; the release keeps it."""
    from nerfedit_plugin.edit.editing import EditingBackend

    for name in ("arap", "cage"):
        dragged, previewed = (EditorState(editing_backend(name, bone)) for _ in range(2))
        assert type(dragged.backend).preview_drag is EditingBackend.preview_drag or name == "arap"
        for state in (dragged, previewed):
            points = state.backend.points
            state.select(np.flatnonzero(points[:, 1] >= np.quantile(points[:, 1], 0.8)))
            state.mark(False)
        for _ in range(2):
            for state in (dragged, previewed):
                state.translate([0.01, 0.0, 0.0], record=False)
            shown = dragged.preview_drag()
            assert dragged.live is None and shown is dragged.deformed
            np.testing.assert_array_equal(shown, previewed.preview())
        assert dragged.released(None) is dragged.deformed


def test_a_live_view_of_a_backend_without_converge_is_replaced_by_the_preview_on_release(bone):
    """The contract's release for a backend whose drag shows a live view and whose previews are exact (``converge``
    None; the cage's bound coordinates): the mesh as ``preview`` poses it."""
    from nerfedit_plugin.edit.editing import LiveView

    state = EditorState(editing_backend("cage", bone))
    backend = state.backend
    points = backend.points
    state.select(np.flatnonzero(points[:, 1] >= np.quantile(points[:, 1], 0.8)))
    state.mark(False)
    state.translate([0.0, 0.0, 0.02])
    empty = np.zeros(0, dtype=np.int64)
    backend.preview_drag = lambda spec, frame, deformed: LiveView(points[:3], np.array([[0, 1, 2]]), empty, empty)
    before = state.deformed.copy()
    assert isinstance(state.preview_drag(), LiveView) and np.array_equal(state.deformed, before)
    assert state.converge() is None
    shown = state.released(None)
    assert state.live is None and not np.array_equal(shown, before)
    np.testing.assert_array_equal(shown, backend.preview(state.spec(), state.frame, before))
