"""The editor's state without a window: selections, handles, moves, undo/redo, the spec it saves (reproduced by
``nerfedit edit`` to 1e-9), picking through a camera, and bad input (a message, nothing changed or written)."""

import json
import os

import numpy as np
import pytest

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.viewer.editor_state import EditorState
from nerfedit_plugin.viewer.picking import Picker, View

MESH = "sample:bone"


@pytest.fixture(scope="module")
def bone():
    return SurfaceMesh.load(MESH)


def _state(mesh, **kwargs):
    return EditorState(mesh, discover(DEFORMERS).config_class(DEFORMERS, "arap")(), **kwargs)


def _ends(mesh):
    """Vertices of the bone's two ends along its longest axis."""
    axis = int(np.argmax(np.ptp(mesh.vertices, axis=0)))
    x = mesh.vertices[:, axis]
    low, high = np.quantile(x, [0.08, 0.92])
    return np.flatnonzero(x <= low), np.flatnonzero(x >= high)


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
    assert state.last_result.iterations <= state.preview_iterations
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
    out = tmp_path / "out"
    assert main(["edit", "--mesh", MESH, "--deformer", "arap", "--edit", str(tmp_path / "edit.json")]
                + ["--out", str(out), "--lift", "closest-point"]) == 0  # fmt: skip
    reproduced = SurfaceMesh.load(out / "deformed_mesh.ply").vertices
    assert np.abs(reproduced - state.deformed).max() <= 1e-9
    # indices instead of selection files: the same spec
    state.save(tmp_path / "inline.yaml", selection_files=False)
    inline = load_edit_spec(tmp_path / "inline.yaml")
    assert np.array_equal(inline.handle_targets(bone.vertices)[1], state.targets()[1])


def test_undo_redo_and_a_drag_is_one_step(bone):
    state = _state(bone)
    fixed, moving = _ends(bone)
    state.select(fixed)
    state.mark(True)
    state.select(moving)
    state.mark(False)
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
    motion = camera.plane_motion(centre, 10.0, 0.0)
    moved_pixel = camera.project((centre + motion)[None])[0][0]
    assert np.allclose(moved_pixel - camera.project(centre[None])[0][0], [10.0, 0.0], atol=1e-6)
