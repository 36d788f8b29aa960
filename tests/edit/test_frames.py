"""Edit specs in the source frame: ``frame: source`` handles are mapped onto the rest mesh by the similarity the
generator records, so a spec written for a sample mesh edits the same part of a run made from it."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError

SPEC = {
    "frame": "source",
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, -0.3]}}, "fixed": True},
        {"select": {"indices": [3, 7]}, "transform": {"translate": [0.1, 0, 0]}},
        {
            "select": {"sphere": {"center": [0.1, 0.2, 0.5], "radius": 0.45}},
            "transform": {"rotate": {"axis": [0, 1, 1], "degrees": 40, "center": [0, 0, 0.4]}, "scale": 1.2},
        },
        {
            "select": {"box": {"min": [-1, 0.3, -1], "max": [1, 1, 1]}},
            "transform": {"rotate": {"axis": [1, 0, 0], "degrees": -20}, "translate": [0, 0, 0.1]},
        },
    ],
    "frames": 3,
}


def similarity(seed):
    rng = np.random.default_rng(seed)
    matrix = np.eye(4)
    matrix[:3, :3] = rng.uniform(0.3, 3.0) * Rotation.random(random_state=seed).as_matrix()
    matrix[:3, 3] = rng.normal(size=3)
    return matrix


@pytest.mark.parametrize("seed", range(3))
def test_a_source_spec_on_moved_points_moves_its_targets_alike(seed):
    """For any similarity M: the spec mapped by M, on the points moved by M, selects the same points and sends them
    to the M-image of its targets on the points as they were (every frame, pivots by centroid or given)."""
    points = np.random.default_rng(seed).uniform(-1, 1, size=(400, 3))
    matrix = similarity(seed)
    moved = points @ matrix[:3, :3].T + matrix[:3, 3]
    spec = parse_edit_spec(SPEC, source="s.json")
    idx, targets = spec.handle_targets(points)  # unmapped: source frame = the points' frame
    placed = spec.in_world(matrix)
    assert placed.frame == "world"
    idx_moved, targets_moved = placed.handle_targets(moved)
    np.testing.assert_array_equal(idx_moved, idx)
    np.testing.assert_allclose(targets_moved, targets @ matrix[:3, :3].T + matrix[:3, 3], atol=1e-12)


def test_world_specs_are_left_as_they_are_and_bad_frames_are_errors():
    world = parse_edit_spec({**SPEC, "frame": "world"})
    assert world.in_world(similarity(0)) is world
    assert parse_edit_spec({k: v for k, v in SPEC.items() if k != "frame"}).frame == "world"
    with pytest.raises(NerfEditError, match=r"s.json: frame: expected one of \['world', 'source'\], got 'body'"):
        parse_edit_spec({**SPEC, "frame": "body"}, source="s.json")
    shear = np.eye(4)
    shear[0, 1] = 0.5
    for bad in (shear, -np.eye(4), np.full((4, 4), np.nan), np.eye(3)):
        with pytest.raises(NerfEditError, match="s.json: frame: the source-to-world transform is not a similarity"):
            parse_edit_spec(SPEC, source="s.json").in_world(bad)


def test_the_bunny_config_edits_the_runs_bunny_as_it_edits_the_sample(tmp_path):
    """``configs/arap_bunny_ears.json`` (written for ``sample:bunny``) on a run made from the generated bunny dataset
    (rotated y-up → z-up and normalised), mapped by the run's source transform as ``nerfedit edit --run`` maps it:
    the same vertices move, to the generator's image of where they move on the sample (ARAP is
    similarity-equivariant; 1e-6 × bbox for the solver's tolerance)."""
    from pathlib import Path

    from deformers.arap import ArapConfig
    from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset
    from nerfedit_plugin.fields.mesh_field import MeshFieldConfig
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.pipeline.train import train_run

    config = Path(__file__).resolve().parents[2] / "configs" / "arap_bunny_ears.json"
    data = generate_dataset(GenerateConfig(out=tmp_path / "data", n_train=1, n_val=1, n_test=1, resolution=8))
    run, _ = train_run("mesh", MeshFieldConfig(), data / "mesh.ply", tmp_path / "run")
    matrix = run.source_transform()
    np.testing.assert_array_equal(matrix, json.loads((data / "transforms_train.json").read_text())["source_transform"])
    spec = parse_edit_spec({**json.loads(config.read_text()), "frames": 1})  # its last frame
    assert spec.frame == "source"
    moved = {}
    for name, mesh, placed in (
        ("run", run.mesh(), spec.in_world(matrix)),
        ("sample", SurfaceMesh.load("sample:bunny"), spec),
    ):
        deformer = ArapConfig().setup()
        deformer.bind(mesh, placed)
        moved[name] = deformer.deform()[-1]
    rest = run.mesh().vertices
    assert np.abs(moved["run"] - rest).max() > 0.02  # the ears moved
    expected = moved["sample"] @ matrix[:3, :3].T + matrix[:3, 3]
    np.testing.assert_allclose(moved["run"], expected, atol=1e-6 * run.mesh().bbox_diagonal)


def test_edit_exports_its_deformed_meshes_in_the_capture_frame(capsule_flow, proxy_cache, tmp_path):
    """``nerfedit edit --run RUN --frame capture`` also writes every deformed mesh in the capture's (here: the
    generator's source) coordinates: the run's source transform maps them back onto the edit's own meshes."""
    from nerfedit_plugin.cli.app import main
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.pipeline.run import open_run

    argv = ["edit", "--run", capsule_flow / "run", "--edit", capsule_flow / "edit.json", "--out", tmp_path / "edit"]
    assert main([str(a) for a in [*argv, "--cache-dir", proxy_cache, "--frame", "capture"]]) == 0
    matrix = open_run(capsule_flow / "run").source_transform()
    assert not np.allclose(matrix, np.eye(4))  # the generator normalised the capsule
    names = sorted(p.name for p in (tmp_path / "edit").glob("deformed_mesh*.ply"))
    assert len(names) == 3 and sorted(p.name for p in (tmp_path / "edit" / "capture").iterdir()) == names
    for name in names:
        world = SurfaceMesh.load(tmp_path / "edit" / name).vertices
        capture = SurfaceMesh.load(tmp_path / "edit" / "capture" / name).vertices
        np.testing.assert_allclose(capture @ matrix[:3, :3].T + matrix[:3, 3], world, atol=1e-5)
    assert main(["edit", "--mesh", "sample:bunny", "--edit", str(capsule_flow / "edit.json"), "--out",
                 str(tmp_path / "e2"), "--frame", "capture"]) == 2  # fmt: skip
