"""Generated scenes: objects standing on a textured floor inside a textured background, the scene.json description
(exact ranges, source transforms), opaque images, and the ground truth of edits by moving, copying, removing and
deforming objects."""

import json
import os
import re

import numpy as np
import pytest
import yaml

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.data.datasets import load_dataset, read_image, read_transforms
from nerfedit_plugin.data.scene import (
    background_mesh,
    build_scene,
    floor_mesh,
    generate_scene,
    read_scene,
    scene_mesh,
)
from nerfedit_plugin.data.synthetic import (
    GenerateConfig,
    colorize,
    generate_dataset,
    render_mesh,
    render_mesh_views,
    to_generator_frame,
)
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh

SMALL = dict(n_train=3, n_val=1, n_test=2, resolution=32)
OBJECTS = ["sample:cow", "sample:bone", "sample:cow"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("scene") / "farm"
    return generate_scene(GenerateConfig(out=out, objects=OBJECTS, yaws=[0.0, 30.0, -20.0], seed=3, **SMALL))


@pytest.fixture(scope="module")
def scene(dataset):
    return read_scene(dataset)


def translation(x=0.0, y=0.0, z=0.0) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = x, y, z
    return matrix


def test_objects_stand_on_the_floor_side_by_side_and_the_box_holds_them(dataset, scene):
    assert [o.name for o in scene.objects] == ["cow", "bone", "cow_2"]
    boxes = [scene.part(o).vertices for o in scene.objects]
    for vertices, obj in zip(boxes, scene.objects):
        assert abs(vertices[:, 2].min()) < 1e-6  # on the floor
        assert np.array_equal(obj.box, [vertices.min(0), vertices.max(0)])
    for i in range(len(boxes)):
        for j in range(i):  # no two objects overlap (along x: side by side)
            assert boxes[i][:, 0].min() > boxes[j][:, 0].max()
    floor = scene.part(scene.floor).vertices
    assert (floor[:, 2] == 0).all() and np.isclose(floor[:, :2].max(), scene.floor.half_size) and len(floor) <= 1e5
    assert np.allclose(np.linalg.norm(scene.part(scene.background).vertices, axis=1), scene.background.radius)
    union = np.stack([np.min([o.box[0] for o in scene.objects], 0), np.max([o.box[1] for o in scene.objects], 0)])
    assert np.allclose(scene.aabb, union + [[-0.12], [0.12]]) and -0.15 < scene.aabb[0, 2] < -0.05
    for split in ("train", "val", "test"):
        assert np.allclose(json.loads((dataset / f"transforms_{split}.json").read_text())["aabb"], scene.aabb)
        assert np.allclose(load_dataset(dataset, split).scene_bbox.numpy(), scene.aabb)


def test_ranges_index_each_object_and_its_source_transform_maps_the_source(dataset, scene):
    mesh = SurfaceMesh.load(dataset / "mesh.ply")
    assert np.array_equal(mesh.vertices, scene.mesh.vertices) and np.array_equal(mesh.faces, scene.mesh.faces)
    for i, (obj, source) in enumerate(zip(scene.objects, OBJECTS)):
        raw = SurfaceMesh.load(source)
        part = scene.part(obj)
        assert np.array_equal(part.faces, raw.faces)  # the ranges hold exactly this object, in its own order
        moved = raw.vertices @ obj.source_transform[:3, :3].T + obj.source_transform[:3, 3]
        assert np.abs(moved - part.vertices).max() < 1e-6
        framed, _ = to_generator_frame(raw, "y")
        assert np.array_equal(part.vertex_colors, colorize(framed, 3 + i).vertex_colors)  # a seed per object
    assert scene.objects[0].vertex_range.start == 0 and scene.background.vertex_range.stop == len(mesh.vertices)
    assert not np.array_equal(scene.part(scene.objects[0]).vertex_colors, scene.part(scene.objects[2]).vertex_colors)


def test_images_are_fully_opaque_and_held_out_views_differ_from_training_views(dataset, scene):
    for split in ("train", "val", "test"):
        for path in sorted((dataset / split).glob("*.png")):
            rgb, alpha = read_image(path)
            assert (alpha == 1).all() and rgb.std() > 0.05
    train, test = (read_transforms(dataset / f"transforms_{s}.json").cameras.centers.numpy() for s in ("train", "test"))
    assert np.linalg.norm(train[:, None] - test[None], axis=-1).min() > 0.05
    centre = scene.aabb.mean(0)
    elevation = np.degrees(np.arcsin((train - centre)[:, 2] / np.linalg.norm(train - centre, axis=1)))
    assert (elevation > 15 - 1e-3).all() and (elevation < 65 + 1e-3).all()  # hemisphere: above the floor


def test_the_unedited_scene_mesh_renders_the_dataset_images(dataset, scene, tmp_path):
    mesh = scene_mesh(scene)
    assert np.array_equal(mesh.vertices, scene.mesh.vertices) and np.array_equal(mesh.faces, scene.mesh.faces)
    for path in render_mesh_views(mesh, dataset / "transforms_test.json", tmp_path / "gt"):
        ours, theirs = read_image(path), read_image(dataset / "test" / path.name)
        assert all(np.array_equal(a, b) for a, b in zip(ours, theirs))


def _where(part: SurfaceMesh, cameras) -> np.ndarray:
    """Pixels any sub-pixel ray of which hits ``part`` alone."""
    return render_mesh(part, cameras, supersample=2)[1] > 0


def test_moving_an_object_changes_only_the_pixels_where_it_was_or_went(dataset, scene, tmp_path):
    shift = translation(0.0, 0.35, 0.0)
    paths = render_mesh_views(scene_mesh(scene, {"bone": shift}), dataset / "transforms_test.json", tmp_path / "gt")
    cameras = read_transforms(dataset / "transforms_test.json").cameras
    bone = scene.part(scene.object("bone"))
    moved = bone.with_vertices(bone.vertices + shift[:3, 3])
    touched = _where(bone, cameras) | _where(moved, cameras)
    edited = np.stack([read_image(p)[0] for p in paths])
    rest = np.stack([read_image(dataset / "test" / p.name)[0] for p in paths])
    changed = (edited != rest).any(-1)
    assert changed.any() and not (changed & ~touched).any() and touched.mean() < 0.2
    # a deformation is given as the object's new vertex positions: the same translation that way is the same mesh
    as_positions = scene_mesh(scene, {"bone": moved.vertices})
    assert np.array_equal(as_positions.vertices, scene_mesh(scene, {"bone": shift}).vertices)


def test_a_copy_adds_geometry_and_a_removal_drops_it(dataset, scene, tmp_path):
    cow = scene.part(scene.object("cow"))
    copied = scene_mesh(scene, copies=[("cow", translation(0.0, -1.2, 0.0))])
    assert len(copied.vertices) == len(scene.mesh.vertices) + len(cow.vertices)
    assert np.array_equal(copied.vertices[-len(cow.vertices) :], cow.vertices + [0.0, -1.2, 0.0])
    assert np.array_equal(copied.vertex_colors[-len(cow.vertices) :], cow.vertex_colors)
    assert np.array_equal(copied.faces[: len(scene.mesh.faces)], scene.mesh.faces)
    removed = scene_mesh(scene, removed={"cow_2"})
    assert len(removed.vertices) == len(scene.mesh.vertices) - len(scene.part(scene.object("cow_2")).vertices)
    cameras = read_transforms(dataset / "transforms_test.json").cameras
    for mesh in (copied, removed):
        rgb = render_mesh(mesh, cameras, supersample=2)[0]
        assert np.abs(rgb - render_mesh(scene.mesh, cameras, supersample=2)[0]).max() > 0.1


@pytest.mark.parametrize(
    "edit, message",
    [
        (dict(moves={"horse": np.eye(4)}), r"moves\['horse'\]: unknown object 'horse' \(objects: cow, bone, cow_2\)"),
        (dict(moves={"cow": np.full((4, 4), np.nan)}), r"moves\['cow'\]: contains NaN or Inf"),
        (dict(moves={"cow": np.zeros((5, 3))}), r"moves\['cow'\]: expected a 4x4 transform or \(\d+, 3\) vertex"),
        (dict(moves={"cow": np.zeros((4, 4))}), r"moves\['cow'\]: last row must be \[0, 0, 0, 1\]"),
        (dict(copies=[("pig", np.eye(4))]), r"copies\[0\]: unknown object 'pig'"),
        (dict(removed={"cow", "hen"}), "removed: unknown object 'hen'"),
        (dict(moves={"cow": np.eye(4)}, removed={"cow"}), r"moves\['cow'\]: the object is also removed"),
    ],
)
def test_bad_edits_are_one_clear_error(scene, edit, message):
    with pytest.raises(NerfEditError, match=message):
        scene_mesh(scene, **edit)


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(objects=["sample:cow", "sample:teapot"]), r"objects\[1\]: sample:teapot: unknown sample mesh"),
        (dict(positions=[(0.0, 0.0)]), r"positions: expected none or 2 \(x, y\) pairs"),
        (dict(positions=[(0.0, 0.0), (0.3, 0.1)]), "positions: the boxes of objects 'cow' and 'bone' overlap"),
        (dict(yaws=[0.0, float("nan")]), "yaws: contains NaN or Inf"),
        (dict(object_size=0.0), "object_size: expected a positive length"),
        (dict(hemisphere=True), "hemisphere: a scene's cameras are chosen by --cameras"),
        (dict(mesh="sample:bunny", objects=[]), "objects: a scene needs at least one mesh"),
        (dict(radius=0.5), "radius: 0.5 puts the cameras inside"),
        (dict(background_radius=0.0), "background_radius: expected a positive length"),
        (dict(background_radius=2.0), "background_radius: the cameras stand up to .* outside the background sphere"),
    ],
)
def test_bad_scene_configs_are_rejected_before_writing(tmp_path, change, message):
    config = GenerateConfig(out=tmp_path / "out", **{**dict(objects=["sample:cow", "sample:bone"], **SMALL), **change})
    with pytest.raises(NerfEditError, match=message):
        generate_scene(config)
    assert not (tmp_path / "out").exists()


def test_the_background_sphere_can_be_brought_close_as_a_room(tmp_path):
    scene = build_scene(GenerateConfig(out=tmp_path, objects=["sample:cow"], background_radius=5.0))
    vertices = scene.part(scene.background).vertices
    assert scene.background.radius == 5.0
    np.testing.assert_allclose(np.linalg.norm(vertices, axis=1), 5.0, rtol=1e-6)


@pytest.mark.parametrize("option", [dict(floor=False), dict(cameras="arc"), dict(yaws=[10.0])])
def test_scene_options_without_objects_are_rejected(tmp_path, option):
    with pytest.raises(NerfEditError, match=f"{next(iter(option))}: an option of scenes; give the scene's meshes"):
        generate_dataset(GenerateConfig(out=tmp_path / "out", mesh="sample:bone", **SMALL, **option))


def _corrupt(dataset, tmp_path, change) -> str:
    """read_scene's error for a copy of ``dataset``'s scene.json changed by ``change(doc)``."""
    copy = tmp_path / "copy"
    copy.mkdir()
    os.symlink(dataset / "mesh.ply", copy / "mesh.ply")
    doc = json.loads((dataset / "scene.json").read_text())
    change(doc)
    (copy / "scene.json").write_text(json.dumps(doc))
    with pytest.raises(NerfEditError) as error:
        read_scene(copy)
    assert str(error.value).startswith(str(copy / "scene.json"))
    return str(error.value)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(version=2), "version: expected 1, got 2"),
        (lambda d: d.update(format="blender"), "format: expected 'nerfedit-scene'"),
        (lambda d: d["objects"][1].pop("faces"), r"objects\[1\].faces: expected \[start, stop\]"),
        (lambda d: d["objects"][1].update(name="cow"), r"objects\[1\].name: expected a unique non-empty name"),
        (lambda d: d["objects"][0]["source_transform"][0].__setitem__(0, None), r"objects\[0\].source_transform"),
        (lambda d: d["objects"][1]["vertices"].__setitem__(0, 5), r"objects\[1\].vertices: starts at 5, not where"),
        (lambda d: d["floor"].update(half_size=-1), "floor.half_size: expected a positive number"),
        (lambda d: d.pop("aabb"), "aabb: missing"),
        (lambda d: d.update(background=None), r"floor: the parts cover \d+ vertices, the mesh has \d+"),
    ],
)
def test_read_scene_names_the_file_and_key_of_a_bad_description(dataset, tmp_path, change, message):
    assert re.search(message, _corrupt(dataset, tmp_path, change))


def test_floor_and_background_are_textured_everywhere_and_deterministic():
    floor, background = floor_mesh(seed=1), background_mesh(18.0, seed=1)
    assert np.array_equal(floor.vertex_colors, floor_mesh(seed=1).vertex_colors)
    assert not np.array_equal(floor.vertex_colors, floor_mesh(seed=2).vertex_colors)
    for mesh in (floor, background):
        colors = mesh.vertex_colors
        assert np.array_equal(np.round(colors * 255) / 255, colors) and colors.std(0).min() > 0.05
    # the floor's light cells differ from one another (no period): brightness of cell centres
    centres = np.isclose(np.mod(floor.vertices[:, :2] - 0.125, 0.5), 0).all(1)
    assert np.unique(np.round(floor.vertex_colors[centres].sum(1), 2)).size > 100
    normals = np.cross(
        *(background.vertices[background.faces[:, k]] - background.vertices[background.faces[:, 0]] for k in (1, 2))
    )
    assert (np.einsum("fd,fd->f", normals, background.vertices[background.faces[:, 0]]) < 0).all()  # faces inwards


def test_generate_scene_through_the_cli_records_its_options(tmp_path, capsys):
    out = tmp_path / "data"
    argv = ["generate", "--out", str(out), "--objects", "sample:bone", "sample:cow", "--cameras", "arc"]
    argv += [
        "--no-background",
        "--radius",
        "3",
        "--resolution",
        "16",
        "--n-train",
        "2",
        "--n-val",
        "1",
        "--n-test",
        "1",
    ]
    assert main(argv) == 0
    doc = json.loads((out / "scene.json").read_text())
    assert doc["background"] is None and [o["name"] for o in doc["objects"]] == ["bone", "cow"]
    config = yaml.safe_load((out / "config.yml").read_text())
    assert config["objects"] == ["sample:bone", "sample:cow"] and config["cameras"] == "arc"
    centers = read_transforms(out / "transforms_train.json").cameras.centers.numpy() - np.mean(doc["aabb"], axis=0)
    assert np.allclose(np.linalg.norm(centers, axis=1), 3.0, atol=1e-5) and (centers[:, 1] < 0).all()  # in front
    assert main(["generate", "--load-config", str(out), "--out", str(tmp_path / "again")]) == 0
    assert (tmp_path / "again" / "test" / "r_0.png").read_bytes() == (out / "test" / "r_0.png").read_bytes()
    capsys.readouterr()
    assert main(["generate", "--out", str(tmp_path / "bad"), "--objects", "sample:cow", "sample:teapot"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "objects[1]: sample:teapot: unknown sample mesh" in err
    assert not (tmp_path / "bad").exists()
