"""Scene edits (``objects``) on a two-object scene standing on a floor slab, rendered with the exact ``mesh`` field:
the rest of the scene is untouched outside the edited object's footprint, copies render like the original moved,
overlaps resolve deterministically and are reported, edits of edits chain, bad specs fail cleanly."""

import json
import math

import numpy as np
import pytest
import torch
import trimesh
from scipy.ndimage import binary_dilation
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.scene_deformation import SceneDeformation, load_deformation
from nerfedit_plugin.data.cameras import Cameras, sphere_poses
from nerfedit_plugin.data.synthetic import colorize, render_mesh
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.mesh_field import MeshField
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.edit import Base, run_edit
from nerfedit_plugin.render.views import default_render_config, render_views
from nerfedit_plugin.training.metrics import psnr


def _part(mesh: trimesh.Trimesh, seed: int) -> SurfaceMesh:
    return colorize(SurfaceMesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)), seed, 2.0)


def _concat(parts: list[SurfaceMesh]) -> SurfaceMesh:
    offsets = np.cumsum([0] + [p.n_vertices for p in parts])
    return SurfaceMesh(
        np.concatenate([p.vertices for p in parts]),
        np.concatenate([p.faces + o for p, o in zip(parts, offsets)]),
        np.concatenate([p.vertex_colors for p in parts]),
    )


@pytest.fixture(scope="module")
def scene():
    """A box (x ≈ −0.4) and a cylinder (x ≈ +0.4) standing on a 2×2×0.1 floor slab (top at z = 0), vertex-coloured,
    watertight parts; 4 hemisphere cameras at 48 px."""
    box = trimesh.creation.box([0.3, 0.3, 0.4]).subdivide().subdivide()
    box.apply_translation([-0.4, 0.0, 0.2])
    cylinder = trimesh.creation.cylinder(radius=0.15, height=0.35, sections=24).subdivide()
    cylinder.apply_translation([0.4, 0.0, 0.175])
    floor = trimesh.creation.box([2.0, 2.0, 0.1])
    for _ in range(5):
        floor = floor.subdivide()
    floor.apply_translation([0.0, 0.0, -0.05])
    parts = [_part(box, 1), _part(cylinder, 2), _part(floor, 3)]
    mesh = _concat(parts)
    poses = sphere_poses(4, 2.6, center=(0.0, 0.0, 0.1), hemisphere=True, seed=3)
    cameras = Cameras.from_fov(poses, 48, 48, math.radians(50.0))
    return {"mesh": mesh, "parts": parts, "cameras": cameras, "field": MeshField.from_mesh(mesh)}


def gt(mesh: SurfaceMesh, cameras: Cameras) -> np.ndarray:
    return render_mesh(mesh, cameras, background=(1.0, 1.0, 1.0))[0]


def render(scene, deformation=None) -> np.ndarray:
    field = scene["field"]
    return np.stack(
        render_views(field, scene["cameras"], default_render_config(field), deformation=deformation, progress=False)
    )


def write_spec(tmp_path, spec: dict, name: str = "scene.json"):
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / name
    path.write_text(json.dumps(spec))
    return path


BOX = {"component": {"near": [-0.4, 0.0, 0.4]}}
CYLINDER = {"component": {"near": [0.4, 0.0, 0.35]}}


def edit(scene, tmp_path, spec, proxy_cache, **kwargs):
    from nerfedit_plugin.registry import DEFORMERS, discover

    deformer = discover(DEFORMERS).config_class(DEFORMERS, "arap")()
    path = write_spec(tmp_path, spec)
    return run_edit(scene["mesh"], deformer, path, tmp_path / "out", cache_dir=proxy_cache, **kwargs)


def moved(vertices, degrees, shift, centre):
    rotation = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    return (vertices - centre) @ rotation.T + centre + np.asarray(shift)


def test_moving_one_object_leaves_the_rest_of_the_scene_identical(scene, tmp_path, proxy_cache):
    """The box turns 30° and slides 0.15 along y on the floor. Outside the pixels where the ground truths of the edited
    and unedited scenes differ, the edited render equals the unedited one exactly — the cylinder, the floor (also
    inside the box's proxy margin) and the background; inside, it matches the ground truth."""
    box = scene["parts"][0]
    centre = box.vertices.mean(0)
    spec = {
        "objects": [
            {
                "name": "box",
                "select": BOX,
                "place": {"translate": [0, 0.15, 0], "rotate": {"axis": [0, 0, 1], "degrees": 30}},
            }
        ]
    }
    result = edit(scene, tmp_path, spec, proxy_cache)
    deformation = load_deformation(result.out / "deformation.npz")
    assert isinstance(deformation, SceneDeformation)
    report = result.report
    assert report["objects"][0]["surface"]["vertices"] == box.n_vertices and report["overlaps"] == []
    (obj,) = deformation.stages[0].objects  # its own region: none of the floor slab (z < 0) in its proxy's margin
    assert obj.rest_vertices[obj.tets].mean(1)[:, 2].min() > 0 > obj.rest_vertices[:, 2].min() - 1e-3
    edited_mesh = scene["mesh"].with_vertices(
        np.concatenate([moved(box.vertices, 30, [0, 0.15, 0], centre), scene["mesh"].vertices[box.n_vertices :]])
    )
    assert np.allclose(SurfaceMesh.load(result.out / "deformed_mesh.ply").vertices, edited_mesh.vertices, atol=1e-6)
    before, after = render(scene), render(scene, deformation)
    gt_before, gt_after = gt(scene["mesh"], scene["cameras"]), gt(edited_mesh, scene["cameras"])
    footprint = np.abs(gt_after - gt_before).max(-1) > 1e-6
    assert 0.02 < footprint.mean() < 0.5
    # grown by one pixel: the ownership boundary follows the object's base to within a bisected tet, not exactly
    footprint = np.stack([binary_dilation(f) for f in footprint])
    assert np.array_equal(after[~footprint], before[~footprint])
    assert psnr(after, gt_after) > 30.0


def test_a_copy_renders_like_the_original_moved_and_the_original_stays(scene, tmp_path, proxy_cache, capsys):
    """Through the command line (``nerfedit edit --mesh SCENE --edit SPEC``): the cylinder stays and a copy is
    placed elsewhere; the edited render matches the ground truth of the scene with the copy added."""
    from nerfedit_plugin.cli.app import main

    cylinder = scene["parts"][1]
    centre = cylinder.vertices.mean(0)
    place = {"translate": [-0.3, -0.55, 0], "rotate": {"axis": [0, 0, 1], "degrees": 45}}
    spec = write_spec(tmp_path, {"objects": [{"name": "cyl", "select": CYLINDER, "copies": [{"place": place}]}]})
    scene["mesh"].save(tmp_path / "scene.ply")
    argv = ["edit", "--mesh", str(tmp_path / "scene.ply"), "--edit", str(spec), "--out", str(tmp_path / "out")]
    assert main([*argv, "--cache-dir", str(proxy_cache)]) == 0
    assert "cyl#1" in capsys.readouterr().out  # the summary table lists the instances
    copy = SurfaceMesh(moved(cylinder.vertices, 45, [-0.3, -0.55, 0], centre), cylinder.faces, cylinder.vertex_colors)
    edited_mesh = _concat([scene["mesh"], copy])
    written = SurfaceMesh.load(tmp_path / "out" / "deformed_mesh.ply")
    assert written.n_vertices == edited_mesh.n_vertices
    assert np.allclose(written.vertices, edited_mesh.vertices, atol=1e-6)
    after = render(scene, load_deformation(tmp_path / "out" / "deformation.npz"))
    assert psnr(after, gt(edited_mesh, scene["cameras"])) > 30.0
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert [i["name"] for i in report["objects"][0]["instances"]] == ["cyl", "cyl#1"]


def test_overlapping_instances_are_reported_and_render_deterministically(scene, tmp_path, proxy_cache):
    """Copies of both objects placed on the same spot: the report names the overlap; renders repeat bit for bit."""
    spec = {
        "objects": [
            {"name": "box", "select": BOX, "copies": [{"place": {"translate": [0.4, -0.6, 0]}}]},
            {"name": "cyl", "select": CYLINDER, "copies": [{"place": {"translate": [-0.4, -0.6, 0]}}]},
        ]
    }
    with pytest.warns(UserWarning, match="overlap"):
        result = edit(scene, tmp_path, spec, proxy_cache)
    overlaps = result.report["overlaps"]
    assert [(o["first"], o["second"]) for o in overlaps] == [("box#1", "cyl#1")] and overlaps[0]["vertices"] > 0
    # where both copies' regions hold a point, the box's copy (listed first) maps it: into the box's rest region
    box = scene["parts"][0].vertices
    points = torch.as_tensor(np.random.default_rng(0).uniform(box.min(0), box.max(0), (4000, 3)) + [0.4, -0.6, 0])
    first = load_deformation(result.out / "deformation.npz").bend(points)
    again = load_deformation(result.out / "deformation.npz").bend(points)
    assert torch.equal(first.points, again.points) and torch.equal(first.tet, again.tet)
    into_box = np.abs(first.points.numpy() - points.numpy() + [0.4, -0.6, 0]).max(1) < 1e-4
    assert into_box.mean() > 0.99


def test_an_edit_of_an_edit_must_be_on_the_run_its_base_was_made_on(tmp_path):
    """`nerfedit edit --run R --base B`: B's config.yml must record the run R (the chained deformation bends R's
    field); an edit of a mesh, or of another run, is one error naming both."""
    import yaml

    from nerfedit_plugin.errors import NerfEditError

    base = tmp_path / "base"
    base.mkdir()
    (base / "deformation.npz").write_bytes(b"")
    (base / "deformed_mesh.ply").write_bytes(b"")
    for run in ("run_a", "run_b"):
        (tmp_path / run).mkdir()
    (base / "config.yml").write_text(yaml.safe_dump({"mesh": None, "run": str(tmp_path / "run_a")}))
    Base.of(base).check_run(tmp_path / "run_a")
    with pytest.raises(NerfEditError, match=f"an edit of the run {tmp_path / 'run_a'}, not of --run"):
        Base.of(base).check_run(tmp_path / "run_b")
    (base / "config.yml").write_text(yaml.safe_dump({"mesh": "in/sphere.obj", "run": None}))
    with pytest.raises(NerfEditError, match="an edit of the mesh in/sphere.obj, not of --run"):
        Base.of(base).check_run(tmp_path / "run_a")
    # an edit of an edit made without --run: its own base decides; a moved run or no record at all is trusted
    chained = tmp_path / "chained"
    chained.mkdir()
    (chained / "deformation.npz").write_bytes(b"")
    (chained / "deformed_mesh.ply").write_bytes(b"")
    (chained / "config.yml").write_text(yaml.safe_dump({"mesh": None, "run": None, "base": str(base)}))
    with pytest.raises(NerfEditError, match=f"--base {chained}: an edit of the mesh in/sphere.obj"):
        Base.of(chained).check_run(tmp_path / "run_a")
    (base / "config.yml").write_text(yaml.safe_dump({"run": str(tmp_path / "moved_away")}))
    Base.of(chained).check_run(tmp_path / "run_b")
    (base / "config.yml").write_text(yaml.safe_dump({"deformer": "arap", "edit": "e.json"}))  # the demo's record
    Base.of(chained).check_run(tmp_path / "run_b")
    assert Base.of(chained / "deformation.npz").folder == chained  # the folder's deformation.npz names it too
    with pytest.raises(NerfEditError, match=f"--base {tmp_path / 'nope'}: no such edit folder"):
        Base.of(tmp_path / "nope")
    with pytest.raises(NerfEditError, match=f"--base {tmp_path / 'run_a'}: not an edit folder"):
        Base.of(tmp_path / "run_a")


def test_a_scene_edit_folder_keeps_the_selection_files_its_spec_names(scene, tmp_path, proxy_cache):
    """The spec copy of a scene edit reads as the original: the object's selection file (inside the spec's folder)
    is copied beside it, the file its edit's handle names outside the folder becomes absolute, and the copy selects
    the same object and handle vertices."""
    from nerfedit_plugin.edit.objects import load_objects_spec
    from nerfedit_plugin.edit.selection_file import write_selection

    box = scene["parts"][0]
    box_idx = np.arange(box.n_vertices)
    write_selection(tmp_path / "spec" / "sel" / "box.selection.json", scene["mesh"], box_idx)
    top = box_idx[box.vertices[:, 2] > 0.35]
    write_selection(tmp_path / "shared" / "top.selection.json", scene["mesh"], top)
    handles = [
        {"select": {"box": {"min": [-1, -1, -0.1], "max": [1, 1, 0.05]}}, "fixed": True},
        {"select": {"file": "../shared/top.selection.json"}, "transform": {"translate": [0.05, 0, 0]}},
    ]
    spec = {"objects": [{"name": "box", "select": {"file": "sel/box.selection.json"}, "edit": {"handles": handles}}]}
    result = edit(scene, tmp_path / "spec", spec, proxy_cache)
    assert (result.out / "sel" / "box.selection.json").is_file()
    written = json.loads((result.out / "scene.json").read_text())
    absolute = written["objects"][0]["edit"]["handles"][1]["select"]["file"]
    assert absolute == str((tmp_path / "shared" / "top.selection.json").resolve())
    from nerfedit_plugin.registry import DEFORMERS, discover

    arap = discover(DEFORMERS).config_class(DEFORMERS, "arap")()
    copy, original = (load_objects_spec(p, arap) for p in (result.out / "scene.json", tmp_path / "spec" / "scene.json"))
    np.testing.assert_array_equal(copy.resolve(scene["mesh"])[0], original.resolve(scene["mesh"])[0])
    a, b = (s.objects[0].instances[0].edit.handles[1].selection for s in (copy, original))
    np.testing.assert_array_equal(a.indices(box.vertices, "c"), b.indices(box.vertices, "o"))


def test_edit_of_an_edit_chains_the_deformations(scene, tmp_path, proxy_cache):
    """Slide the box by 0.1 along y, then edit that result: slide it by 0.1 along x. Rendering the chained
    deformation.npz matches the ground truth of both moves."""
    box = scene["parts"][0]
    first = edit(
        scene,
        tmp_path / "one",
        {"objects": [{"name": "box", "select": BOX, "place": {"translate": [0, 0.1, 0]}}]},
        proxy_cache,
    )
    base = Base.of(first.out)
    second_spec = write_spec(
        tmp_path,
        {
            "objects": [
                {
                    "name": "box",
                    "select": {"component": {"near": [-0.4, 0.1, 0.4]}},
                    "place": {"translate": [0.1, 0, 0]},
                }
            ]
        },
        "two.json",
    )
    from nerfedit_plugin.registry import DEFORMERS, discover

    deformer = discover(DEFORMERS).config_class(DEFORMERS, "arap")()
    second = run_edit(base.mesh(), deformer, second_spec, tmp_path / "two", cache_dir=proxy_cache, base=base)
    chained = load_deformation(second.out / "deformation.npz")
    assert len(chained.stages) == 2 and second.report["base"]["frame"] == 0
    edited_mesh = scene["mesh"].with_vertices(
        np.concatenate([box.vertices + [0.1, 0.1, 0.0], scene["mesh"].vertices[box.n_vertices :]])
    )
    assert psnr(render(scene, chained), gt(edited_mesh, scene["cameras"])) > 30.0


@pytest.mark.parametrize(
    "objects, message",
    [
        ([{"select": {"box": {"min": [5, 5, 5], "max": [6, 6, 6]}}}], r"objects\[0\]\.select\.box: selects no points"),
        (
            [{"select": {"box": {"min": [-9, -9, -9], "max": [9, 9, 9]}}}],
            r"objects\[0\]\.select\.box: selects every vertex",
        ),
        (
            [{"select": BOX}, {"name": "again", "select": {"sphere": {"center": [-0.55, -0.15, 0.4], "radius": 0.1}}}],
            r"objects\[1\]\.select\.sphere: shares \d+ vertices with objects\[0\]",
        ),
        (
            [{"select": BOX, "copies": [{"place": {"translate": [float("nan"), 0, 0]}}]}],
            r"objects\[0\]\.copies\[0\]\.place\.translate: contains NaN",
        ),
        (
            [{"select": BOX, "deformer": "no-such", "edit": {"handles": []}}],
            r"objects\[0\]\.deformer: unknown deformer 'no-such'",
        ),
        (
            [{"select": BOX, "remove": True, "place": {"translate": [1, 0, 0]}}],
            r"objects\[0\]: a removed object has no edit",
        ),
        ([{"name": "a", "select": BOX}, {"name": "a", "select": CYLINDER}], r"objects\[1\]\.name: 'a' is used twice"),
    ],
)
def test_bad_scene_specs_fail_before_any_work(scene, tmp_path, proxy_cache, objects, message):
    with pytest.raises(NerfEditError, match=message):
        edit(scene, tmp_path, {"objects": objects}, proxy_cache)
    assert not (tmp_path / "out").exists()


def test_vacated_fill_copies_neighbouring_floor_over_the_footprint(scene, tmp_path, proxy_cache):
    """The box is removed with ``vacated: fill``: floor points of its old footprint map sideways onto the floor
    beside it (by at least the footprint's width), points above the floor slab there stay empty, the cylinder and
    the floor elsewhere are untouched."""
    spec = {"objects": [{"name": "box", "select": BOX, "remove": True, "vacated": "fill"}]}
    result = edit(scene, tmp_path, spec, proxy_cache)
    deformation = load_deformation(result.out / "deformation.npz")
    assert [i.name for i in deformation.stages[0].instances] == ["box~fill"]
    rng = np.random.default_rng(2)
    footprint = rng.uniform([-0.53, -0.13], [-0.27, 0.13], (500, 2))  # the box stood on [-0.55, -0.25] × [-0.15, 0.15]
    floor = torch.as_tensor(np.column_stack([footprint, np.full(500, 0.002)]))
    bent = deformation.bend(floor)
    assert (bent.tet >= 0).all() and not bent.empty.any()
    shift = (bent.points.double() - floor).numpy()
    assert np.allclose(shift, shift[0], atol=1e-5) and np.linalg.norm(shift[0]) >= 0.3  # one translation …
    assert abs(shift[0, 2]) < 0.01 * np.linalg.norm(shift[0])  # … along the floor (its fitted plane)
    above = floor + torch.tensor([0, 0, 0.2], dtype=torch.float64)
    assert deformation.bend(above).empty.all()
    elsewhere = torch.tensor([[0.4, 0.0, 0.2], [0.8, 0.8, 0.001], [0.0, -0.8, 0.001]], dtype=torch.float64)
    untouched = deformation.bend(elsewhere)
    assert not untouched.empty.any() and torch.equal(untouched.points, elsewhere.float())
    report = result.report["objects"][0]
    assert report["vacated"] == "fill" and report["fill"]["instance"] == "box~fill" and report["fill"]["tets"] > 0


def test_faces_joining_a_moved_object_to_the_rest_are_dropped_from_the_scene_mesh():
    """A strip of 4 quads; the object is its last two columns of vertices, joined to the rest by faces. Moved away,
    those faces are left out of ``deformed_mesh.ply`` (they would span the move); at rest, or moved less than the
    faces' size, every face stays."""
    from types import SimpleNamespace

    from nerfedit_plugin.edit.objects import _scene_frames

    vertices = np.stack([np.repeat(np.arange(5.0), 2), np.tile([0.0, 1.0], 5), np.zeros(10)], 1)
    quads = [(2 * i, 2 * i + 2, 2 * i + 3, 2 * i + 1) for i in range(4)]
    mesh = SurfaceMesh(vertices, np.array([f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))]))
    idx = np.arange(6, 10)  # x = 3, 4: the last quad, joined to the rest by the third
    part = mesh.submesh(np.isin(np.arange(10), idx))[0]
    spec = SimpleNamespace(objects=[SimpleNamespace(removed=False)])
    for shift, faces in ((0.0, 8), (0.1, 8), (3.0, 6)):  # at rest and bent a little in place, nothing is dropped
        placed = [[SimpleNamespace(surface=(part.vertices + [0.0, 0.0, shift])[None])]]
        (scene,) = _scene_frames(mesh, [idx], [part], spec, placed, 1)
        assert len(scene.faces) == faces
        assert np.linalg.norm(np.diff(scene.vertices[scene.faces], axis=1), axis=2).max() < 1.5


def test_a_scene_edit_reruns_bit_for_bit_from_its_config_with_an_empty_cache(scene, tmp_path, monkeypatch):
    """Each object's proxy as built is kept in the folder (objects/NAME/proxy.npz) and config.yml names the folder
    as --proxy-from: a re-run draws no new pytetwild proxy and gives the same deformation.npz."""
    from nerfedit_plugin.cli.app import main

    scene["mesh"].save(tmp_path / "scene.ply")
    handles = [
        {"select": {"box": {"min": [-1, -1, -0.1], "max": [1, 1, 0.05]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.35], "max": [1, 1, 1]}}, "transform": {"translate": [0.05, 0, 0]}},
    ]
    spec = {
        "objects": [
            {"name": "box", "select": BOX, "edit": {"handles": handles}},
            {"name": "cylinder", "select": CYLINDER, "place": {"translate": [0, 0.2, 0]}},
        ]
    }
    path = write_spec(tmp_path, spec)
    monkeypatch.setenv("NERFEDIT_CACHE", str(tmp_path / "cache-a"))
    assert main(["edit", "--mesh", str(tmp_path / "scene.ply"), "--edit", str(path), "--out", str(tmp_path / "a")]) == 0
    assert {p.parent.name for p in (tmp_path / "a" / "objects").glob("*/proxy.npz")} == {"box", "cylinder"}
    monkeypatch.setenv("NERFEDIT_CACHE", str(tmp_path / "cache-b"))
    assert main(["edit", "--load-config", str(tmp_path / "a" / "config.yml"), "--out", str(tmp_path / "b")]) == 0
    assert (tmp_path / "b" / "deformation.npz").read_bytes() == (tmp_path / "a" / "deformation.npz").read_bytes()
    assert not (tmp_path / "cache-b").exists() or not any((tmp_path / "cache-b").iterdir())
    changed = write_spec(tmp_path / "other", {"objects": [{"name": "box", "select": CYLINDER}]})
    args = ["--mesh", str(tmp_path / "scene.ply"), "--edit", str(changed), "--proxy-from", str(tmp_path / "a")]
    assert main(["edit", *args, "--out", str(tmp_path / "c")]) == 2  # another surface under the name: refused
