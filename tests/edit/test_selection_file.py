"""Selection files: the same mesh gets the saved indices; another mesh of the same shape (re-extracted, the proxy)
gets the points near the saved positions; a moved mesh with ``frame: source`` gets them mapped back; bad files are one
clear error."""

import json

import numpy as np
import pytest
import trimesh

from nerfedit_plugin.edit.selection_file import read_selection, write_selection
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh


@pytest.fixture
def picked(capsule, tmp_path):
    """The capsule's top cap (z > 0.9) saved as a selection file."""
    indices = np.flatnonzero(capsule.vertices[:, 2] > 0.9)
    return write_selection(tmp_path / "top.selection.json", capsule, indices[::-1]), indices


def spec_of(path, **extra):
    return parse_edit_spec({"handles": [{"select": {"file": path.name}, "fixed": True}], **extra}, base_dir=path.parent)


def test_the_same_mesh_gets_the_saved_indices(capsule, picked):
    path, indices = picked
    selection = spec_of(path).handles[0].selection
    np.testing.assert_array_equal(selection.indices(capsule.vertices, "s"), indices)  # sorted, as saved
    saved = json.loads(path.read_text())
    assert saved["vertices"] == capsule.n_vertices and np.allclose(saved["points"], capsule.vertices[indices])


def test_another_mesh_of_the_shape_gets_the_points_near_the_saved_ones(capsule, picked):
    """The subdivided capsule (its vertices first, then edge midpoints): the saved vertices and the midpoints within
    half its clearance of a saved point (those between picked vertices, not those halfway to the unpicked ones),
    nothing else (brute force over every saved point)."""
    path, indices = picked
    vertices, faces = trimesh.remesh.subdivide(capsule.vertices, capsule.faces)
    finer = SurfaceMesh(vertices, faces)
    chosen = spec_of(path).handles[0].selection.indices(finer.vertices, "s")
    assert set(indices) <= set(chosen)
    saved = read_selection(path, "s")
    distance = np.linalg.norm(finer.vertices[:, None] - saved.points[None], axis=-1)  # brute force, all points
    np.testing.assert_array_equal(chosen, np.flatnonzero((distance <= 0.5 * saved.clearance).any(axis=1)))
    assert len(chosen) > len(indices)


def test_a_source_frame_selection_follows_the_mesh_moved_by_the_generator(capsule, picked):
    path, indices = picked
    matrix = np.diag([0.5, 0.5, 0.5, 1.0])
    matrix[:3, :3] = matrix[:3, :3] @ [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    matrix[:3, 3] = [0.1, -0.2, 0.3]
    moved = capsule.vertices @ matrix[:3, :3].T + matrix[:3, 3]
    spec = spec_of(path, frame="source").in_world(matrix)
    np.testing.assert_array_equal(spec.handles[0].selection.indices(moved, "s"), indices)


def test_bad_selection_files_are_one_clear_error(capsule, tmp_path):
    cases = {
        "missing.json": (None, "selection file not found"),
        "foreign.json": ({"format": "other"}, "not a nerfedit.selection file of version 1"),
        "short.json": ({"format": "nerfedit.selection", "version": 1, "indices": [1]}, "malformed"),
        "range.json": (
            {
                "format": "nerfedit.selection",
                "version": 1,
                "vertices": 3,
                "sha256": "x",
                "indices": [5],
                "points": [[0, 0, 0]],
                "spacing": 0.1,
            },
            "malformed",
        ),  # fmt: skip
    }
    for name, (content, message) in cases.items():
        if content is not None:
            (tmp_path / name).write_text(json.dumps(content))
        with pytest.raises(NerfEditError, match=rf"<edit spec>: handles\[0\]\.select\.file: .*{name}: {message}"):
            spec_of(tmp_path / name)
    with pytest.raises(NerfEditError, match="a selection needs vertex indices"):
        write_selection(tmp_path / "none.json", capsule, [capsule.n_vertices])
    assert not (tmp_path / "none.json").exists()


def test_an_edit_folder_keeps_the_selection_files_its_spec_names(capsule, tmp_path, proxy_cache):
    """`nerfedit edit` copies the spec with the selection files beside it (at their relative paths; a name with a
    ``..``, leaving the folder or passing through a link, becomes absolute in the copy): the copy in the edit folder
    selects the same vertices (the editor saves its selections beside the spec it writes)."""
    from deformers.arap import ArapConfig
    from nerfedit_plugin.edit.spec import load_edit_spec
    from nerfedit_plugin.pipeline.edit import run_edit

    folder = tmp_path / "spec"
    bottom, top = np.flatnonzero(capsule.vertices[:, 2] < -0.9), np.flatnonzero(capsule.vertices[:, 2] > 0.9)
    write_selection(folder / "edit.handle0.selection.json", capsule, bottom)
    write_selection(tmp_path / "shared" / "top.selection.json", capsule, top)
    (folder / "picks").mkdir()
    (folder / "picks" / "top.selection.json").symlink_to(tmp_path / "shared" / "top.selection.json")
    middle = np.flatnonzero(np.abs(capsule.vertices[:, 2] - 0.65) < 0.01)
    write_selection(tmp_path / "shared" / "middle.selection.json", capsule, middle)
    (tmp_path / "elsewhere" / "deep").mkdir(parents=True)
    (folder / "link").symlink_to(tmp_path / "elsewhere" / "deep")  # link/.. is elsewhere/, not the spec's folder
    low = np.flatnonzero(np.abs(capsule.vertices[:, 2] + 0.65) < 0.01)
    write_selection(tmp_path / "elsewhere" / "low.selection.json", capsule, low)
    handles = [
        {"select": {"file": "edit.handle0.selection.json"}, "fixed": True},
        {"select": {"file": "picks/top.selection.json"}, "transform": {"translate": [0.0, 0.1, 0.0]}},
        {"select": {"file": "../shared/middle.selection.json"}, "transform": {"translate": [0.0, 0.05, 0.0]}},
        {"select": {"file": "link/../low.selection.json"}, "transform": {"translate": [0.0, 0.02, 0.0]}},
    ]
    (tmp_path / "real").mkdir()
    (tmp_path / "real" / "edit.json").write_text(json.dumps({"handles": handles}))
    (folder / "edit.json").symlink_to(tmp_path / "real" / "edit.json")  # names resolve beside the link, as read
    out = tmp_path / "out"
    run_edit(capsule, ArapConfig(), folder / "edit.json", out, lift="knn3", cache_dir=proxy_cache)
    assert (out / "edit.handle0.selection.json").is_file() and (out / "picks" / "top.selection.json").is_file()
    written = json.loads((out / "edit.json").read_text())  # the name leaving the folder became absolute
    assert written["handles"][2]["select"]["file"] == str((tmp_path / "shared" / "middle.selection.json").resolve())
    assert written["handles"][3]["select"]["file"] == str((tmp_path / "elsewhere" / "low.selection.json").resolve())
    copy, original = load_edit_spec(out / "edit.json"), load_edit_spec(folder / "edit.json")
    assert len(copy.handles) == 4
    for a, b in zip(copy.handles, original.handles):
        np.testing.assert_array_equal(
            a.selection.indices(capsule.vertices, "c"), b.selection.indices(capsule.vertices, "o")
        )
