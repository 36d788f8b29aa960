"""``nerfedit view --screenshot``: a real offscreen Open3D render of an edit (rest left, edit right), and its
errors; the turntable cameras and GIF writer of the renderer's image output."""

import json

import numpy as np
import pytest
import skimage.io
import torch
from PIL import Image

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.render.views import turntable_cameras, write_gif
from nerfedit_plugin.viewer.layers import edit_geometries

EDIT = {
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1.1], "max": [1, 1, -0.6]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.6], "max": [1, 1, 1.1]}}, "transform": {"translate": [0, 0.3, 0]}},
    ]
}


@pytest.fixture(scope="module")
def edit_dir(capsule, proxy_cache, tmp_path_factory):
    root = tmp_path_factory.mktemp("view")
    capsule.save(root / "capsule.ply")
    (root / "edit.json").write_text(json.dumps(EDIT))
    assert (
        main(
            [
                "edit",
                "--mesh",
                str(root / "capsule.ply"),
                "--edit",
                str(root / "edit.json"),
                "--out",
                str(root / "edit"),
                "--cache-dir",
                str(proxy_cache),
            ]
        )
        == 0
    )
    return root / "edit"


def test_layers_of_an_edit(edit_dir, capsule):
    import open3d as o3d

    kinds = [type(g) for g in edit_geometries(capsule, edit_dir)]
    assert kinds.count(o3d.geometry.TriangleMesh) == 2  # rest and deformed mesh
    assert o3d.geometry.LineSet in kinds and o3d.geometry.PointCloud in kinds  # deformed proxy, handles
    handles = next(g for g in edit_geometries(capsule, edit_dir, layers=["handles"]))
    selected = (capsule.vertices[:, 2] < -0.6) | (capsule.vertices[:, 2] > 0.6)
    assert len(handles.points) == selected.sum()
    deformed = edit_geometries(capsule, edit_dir, layers=["deformed"])[0]
    assert np.asarray(deformed.vertices)[:, 0].min() > capsule.vertices[:, 0].max()  # shifted to the right


def test_screenshot_renders_rest_and_edit_side_by_side(edit_dir, capsule, tmp_path):
    shot = tmp_path / "view.png"
    assert main(["view", "--edit", str(edit_dir), "--screenshot", str(shot), "--width", "320", "--height", "200"]) == 0
    image = skimage.io.imread(shot)[..., :3].astype(float)
    assert image.shape == (200, 320, 3)
    drawn = (np.abs(image - image[0, 0]).sum(-1) > 30).any(0)  # columns holding geometry
    assert drawn[:160].any() and drawn[160:].any()  # rest on the left, edit on the right


def test_screenshot_of_the_editor_state_shows_the_spec_settled(edit_dir, tmp_path, monkeypatch):
    """``view --mesh M --spec S --screenshot`` renders the editor's state offscreen: the rest mesh, and the spec
    settled beside it (the ``deformed_mesh.ply`` ``nerfedit edit`` wrote for S); without --spec the rest mesh alone,
    even where the editor's default ``edit.json`` exists."""
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.viewer.editor_state import EditorState
    from nerfedit_plugin.viewer.layers import settled_geometries

    mesh = edit_dir.parent / "capsule.ply"
    state = EditorState.open("arap", SurfaceMesh.load(mesh), edit_dir.parent / "edit.json")
    np.testing.assert_allclose(state.settled[0], SurfaceMesh.load(edit_dir / "deformed_mesh.ply").vertices, atol=1e-9)
    assert len(settled_geometries(state.mesh, None)) == 1 and len(settled_geometries(state.mesh, state.mesh)) == 2
    monkeypatch.chdir(tmp_path)
    (tmp_path / "edit.json").write_text((edit_dir.parent / "edit.json").read_text())  # the editor's default: not used
    size = ["--width", "320", "--height", "200"]
    assert main(["view", "--mesh", str(mesh), "--screenshot", "bare.png", *size]) == 0
    spec = ["--spec", str(edit_dir.parent / "edit.json")]
    assert main(["view", "--mesh", str(mesh), *spec, "--screenshot", "settled.png", *size]) == 0
    columns = [(np.abs(image - image[0, 0]).sum(-1) > 30).any(0) for image in map(pixels, ("bare.png", "settled.png"))]
    assert columns[0][100:220].any() and not columns[0][220:].any()  # the rest mesh alone, in the middle
    assert columns[1][:160].any() and columns[1][160:].any()  # rest on the left, the settled spec on the right
    assert main(["view", "--mesh", str(mesh), *spec, "--frame", "3", "--screenshot", "x.png"]) == 2
    assert not (tmp_path / "x.png").exists()


def pixels(path):
    return skimage.io.imread(path)[..., :3].astype(float)


def test_the_view_is_upright_for_a_mesh_in_a_generated_dataset(capsule_flow, tmp_path):
    """A generated dataset's mesh.ply is z-up (the generator's world), as its runs are; a mesh elsewhere has no
    known up (the view's default y)."""
    from nerfedit_plugin.pipeline.run import data_up

    assert data_up(capsule_flow / "data" / "mesh.ply") == (0.0, 0.0, 1.0)
    (tmp_path / "loose.ply").write_bytes((capsule_flow / "data" / "mesh.ply").read_bytes())
    assert data_up(tmp_path / "loose.ply") is None


def test_view_errors(edit_dir, tmp_path, capsys):
    assert (
        main(["view", "--edit", str(tmp_path), "--mesh", "sample:bone", "--screenshot", str(tmp_path / "a.png")]) == 2
    )
    assert "not an edit folder" in capsys.readouterr().err
    run = tmp_path / "run"  # a run folder has a config.yml too, of `nerfedit train`
    run.mkdir()
    (run / "config.yml").write_text("field: mesh\n")
    (run / "field.pt").write_bytes(b"")
    assert main(["view", "--edit", str(run), "--screenshot", str(tmp_path / "a.png")]) == 2
    assert "run: not an edit folder (no deformation.npz; a run folder" in capsys.readouterr().err
    assert main(["view", "--edit", str(edit_dir), "--show", "tets", "--screenshot", str(tmp_path / "a.png")]) == 2
    assert "unknown layer" in capsys.readouterr().err
    assert not (tmp_path / "a.png").exists()


def test_turntable_cameras_circle_the_box_and_look_at_its_centre():
    box = torch.tensor([[-1.0, -0.5, 0.0], [1.0, 0.5, 2.0]])
    cameras = turntable_cameras(box, 8, 16, distance=3.0)
    centre = box.mean(0)
    eyes = cameras.c2w[:, :3, 3]
    radius = float(torch.linalg.norm(box[1] - box[0]) / 2)
    torch.testing.assert_close(torch.linalg.norm(eyes - centre, dim=1), torch.full((8,), 3.0 * radius))
    forward = -cameras.c2w[:, :3, 2]
    torch.testing.assert_close(forward, torch.nn.functional.normalize(centre - eyes, dim=1), atol=1e-6, rtol=0)
    assert torch.allclose(eyes[:, 2], eyes[0, 2])  # one height: a circle


def test_gif_holds_every_frame(tmp_path):
    frames = [np.full((8, 8, 3), v, dtype=np.float32) for v in (0.0, 0.5, 1.0)]
    with Image.open(write_gif(tmp_path / "t.gif", frames)) as gif:
        assert gif.n_frames == 3
        gif.seek(1)
        assert abs(np.asarray(gif.convert("RGB")).astype(int).mean() - 128) <= 1


def test_cage_handles_are_drawn_on_the_cage(capsule, proxy_cache, tmp_path):
    """A cage spec's handles select cage vertices, so the viewer resolves them on the rest cage, not on the mesh."""
    capsule.save(tmp_path / "capsule.ply")
    (tmp_path / "cage.json").write_text(json.dumps({"cage": "auto", **EDIT}))
    assert (
        main(
            [
                "edit",
                "--mesh",
                str(tmp_path / "capsule.ply"),
                "--deformer",
                "cage",
                "--edit",
                str(tmp_path / "cage.json"),
                "--out",
                str(tmp_path / "edit"),
                "--cache-dir",
                str(proxy_cache),
            ]
        )
        == 0
    )
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    cage = SurfaceMesh.load(tmp_path / "edit" / "cage_rest.ply")
    (handles,) = edit_geometries(capsule, tmp_path / "edit", layers=["handles"])
    selected = (np.abs(cage.vertices[:, 2]) > 0.6) & (np.abs(cage.vertices[:, 2]) <= 1.1)
    assert len(handles.points) == selected.sum() < len(capsule.vertices)


def test_a_script_with_an_unknown_step_is_refused_before_the_window_opens(tmp_path, monkeypatch, capsys):
    """Every step kind of the editor's docstring passes the check; a misspelt step (or a key a step does not take)
    is one error naming the script and the step, before any window (here no display server exists at all)."""
    from nerfedit_plugin.viewer.editor import SCRIPT_STEPS, check_script

    check_script([{kind: 1} for kind in SCRIPT_STEPS] + [{"brush": [[1, 2]], "radius": 4}], "s.json")
    monkeypatch.setenv("DISPLAY", ":987")  # none there: the check must come first
    for bad in ({"pik": [1]}, {"pick": [1], "radius": 3}):
        (tmp_path / "s.json").write_text(json.dumps([{"pick": [0]}, bad]))
        assert main(["view", "--mesh", "sample:bone", "--script", str(tmp_path / "s.json")]) == 2
        assert f"s.json: step 1 {json.dumps(bad)}: unknown step (expected one of pick, " in capsys.readouterr().err
