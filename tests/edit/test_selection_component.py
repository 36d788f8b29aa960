"""The ``component`` selection: the connected part of the rest mesh nearest a point, after dropping the floor, on a
generated floor with two boxes standing on it and a floater; in the source frame; its errors."""

import numpy as np
import pytest
from scene_meshes import floor_scene
from scipy.spatial.transform import Rotation

from deformers.arap import ArapConfig, ArapDeformer
from nerfedit_plugin.edit.selection import parse_selection
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.cleanup import drop_floaters

SCENE = floor_scene()
TOP_OF_BOX_0 = [-0.6, -0.45, 0.42]  # just above the first box's lid
DEFAULT_LIMIT = f"{0.05 * SCENE.mesh.bbox_diagonal:.4g}".replace(".", r"\.")  # 5 % of the bounding-box diagonal


def spec(component, frame="world"):
    handle = {"select": {"component": component}, "fixed": True}
    return parse_edit_spec({"handles": [handle], "frame": frame}, source="e.json")


def selected(component, mesh=SCENE.mesh):
    return spec(component).handle_targets(mesh.vertices, mesh.faces)[0]


def test_drop_plane_picks_exactly_one_box():
    np.testing.assert_array_equal(selected({"near": TOP_OF_BOX_0, "drop_plane": True}), SCENE.boxes[0])
    np.testing.assert_array_equal(selected({"near": [0.45, 0.3, 0.2], "drop_plane": True}), SCENE.boxes[1])


def test_without_drop_plane_the_box_is_one_part_with_the_floor():
    expected = np.sort(np.concatenate([SCENE.floor, *SCENE.boxes]))
    np.testing.assert_array_equal(selected({"near": TOP_OF_BOX_0}), expected)


def test_the_floater_is_a_part_unless_min_faces_skips_it():
    corner = [0.7, -0.7, 0.6]
    np.testing.assert_array_equal(selected({"near": corner}), SCENE.floater)
    far = {"near": corner, "min_faces": 5, "max_distance": 1.0}  # the floater has 4 faces: the floor is nearest
    np.testing.assert_array_equal(selected(far), np.sort(np.concatenate([SCENE.floor, *SCENE.boxes])))


def test_source_frame():
    """Handles in the source frame: the rest mesh is the scene moved by a similarity, ``near`` stays put."""
    matrix = np.eye(4)
    matrix[:3, :3] = 2.5 * Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    matrix[:3, 3] = [3.0, -1.0, 7.0]
    world = SCENE.mesh.vertices @ matrix[:3, :3].T + matrix[:3, 3]
    edit = spec({"near": TOP_OF_BOX_0, "drop_plane": True, "max_distance": 0.1}, frame="source").in_world(matrix)
    np.testing.assert_array_equal(edit.handle_targets(world, SCENE.mesh.faces)[0], SCENE.boxes[0])


def test_parse_selection_is_public():
    selection = parse_selection({"component": {"near": TOP_OF_BOX_0}}, "e.json", "select", ".")
    assert selection.kind == "component" and selection.key == "select.component"
    np.testing.assert_array_equal(selection.indices(SCENE.mesh.vertices, "e.json", SCENE.mesh.faces)[:3], [0, 1, 2])


def test_arap_moves_one_box_and_keeps_the_floor():
    mesh = drop_floaters(SCENE.mesh, 0.1)  # a free floater would leave ARAP without a constraint there
    edit = parse_edit_spec(
        {
            "handles": [
                {"select": {"box": {"min": [-2, -2, -0.01], "max": [2, 2, 0.01]}}, "fixed": True},
                {
                    "select": {"component": {"near": TOP_OF_BOX_0, "drop_plane": True}},
                    "transform": {"translate": [0, 0, 0.1]},
                },
            ]
        }
    )
    deformer = ArapDeformer(ArapConfig())
    deformer.bind(mesh, edit)
    moved = deformer.deform()[-1]
    np.testing.assert_allclose(moved[SCENE.boxes[0]], mesh.vertices[SCENE.boxes[0]] + [0, 0, 0.1], atol=1e-9)
    np.testing.assert_array_equal(moved[SCENE.floor], mesh.vertices[SCENE.floor])


@pytest.mark.parametrize(
    ("component", "message"),
    [
        ({"drop_plane": True}, "e.json: handles[0].select.component.near: missing"),
        ({"near": [0, 0]}, "e.json: handles[0].select.component.near: expected 3 numbers"),
        ({"near": [0, 0, 0], "drop_plane": 1}, "e.json: handles[0].select.component.drop_plane: expected true or"),
        ({"near": [0, 0, 0], "plane_distance": 0.1}, "component.plane_distance: applies only with drop_plane: true"),
        ({"near": [0, 0, 0], "drop_plane": True, "plane_distance": 0}, "component.plane_distance: must be > 0"),
        ({"near": [0, 0, 0], "max_distance": -1}, "component.max_distance: must be > 0"),
        ({"near": [0, 0, 0], "min_faces": 0}, "component.min_faces: expected an integer >= 1, got 0"),
        ({"near": [0, 0, 0], "min_faces": True}, "component.min_faces: expected an integer >= 1, got True"),
        ({"near": [0, 0, 0], "radius": 1}, "e.json: handles[0].select.component.radius: unknown key"),
    ],
)
def test_malformed_component_is_rejected_on_parsing(component, message):
    with pytest.raises(NerfEditError, match=message.replace("[", r"\[").replace("]", r"\]")):
        spec(component)


@pytest.mark.parametrize(
    ("component", "message"),
    [
        ({"near": [0, 0, 0.2]}, rf"near: the nearest vertex is 0\.2 away, more than max_distance {DEFAULT_LIMIT}$"),
        (
            {"near": [0, 0, 0.2], "max_distance": 0.15},
            r"near: the nearest vertex is 0\.2 away, more than max_distance 0\.15$",
        ),
        ({"near": [0, 0, 0.01], "drop_plane": True}, "near: the nearest vertex lies on the dropped plane"),
        ({"near": [0, 0, 0], "min_faces": 10**6}, "near: the mesh has no part of 1000000 faces or more"),
    ],
)
def test_unresolvable_component_names_the_key(component, message):
    with pytest.raises(NerfEditError, match=r"^e\.json: handles\[0\]\.select\.component\." + message):
        selected(component)


def test_component_without_faces_is_a_clear_error():
    with pytest.raises(NerfEditError, match=r"e\.json: handles\[0\]\.select\.component: needs the rest mesh's faces"):
        spec({"near": TOP_OF_BOX_0}).handle_targets(SCENE.mesh.vertices)
