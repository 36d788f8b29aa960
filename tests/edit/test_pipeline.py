"""The user's pipeline through the CLI on real files, with the exact ``mesh`` field (no training error):
generate → train --field mesh → extract → edit --run → render --deformation → eval against ground truth
rendered from the deformed mesh; plus run-folder errors."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.data.synthetic import render_ground_truth
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.run import open_run

EDIT = {
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, -0.3]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.3], "max": [1, 1, 1]}}, "transform": {"translate": [0, 0.08, 0]}},
    ]
}


@pytest.fixture(scope="module")
def scene(capsule, tmp_path_factory):
    root = tmp_path_factory.mktemp("pipeline")
    capsule.save(root / "capsule.ply")
    assert (
        main(
            [
                "generate",
                "--out",
                str(root / "data"),
                "--mesh",
                str(root / "capsule.ply"),
                "--resolution",
                "48",
                "--n-train",
                "2",
                "--n-val",
                "1",
                "--n-test",
                "3",
                "--up-axis",
                "z",
            ]
        )
        == 0
    )
    (root / "edit.json").write_text(json.dumps(EDIT))
    return root


@pytest.fixture(scope="module")
def mesh_run(scene, tmp_path_factory):
    run = scene / "run"
    assert main(["train", "--field", "mesh", "--data", str(scene / "data" / "mesh.ply"), "--out", str(run)]) == 0
    assert main(["extract", "--run", str(run)]) == 0
    return run


def test_mesh_run_extracts_its_mesh_unchanged(scene, mesh_run):
    source, extracted = SurfaceMesh.load(scene / "data" / "mesh.ply"), open_run(mesh_run).mesh()
    assert np.array_equal(source.faces, extracted.faces)
    np.testing.assert_allclose(extracted.vertices, source.vertices, atol=1e-6)
    assert open_run(mesh_run).camera_distance() is None
    assert main(["extract", "--run", str(mesh_run)]) == 0  # a mesh field's run has its mesh.ply: nothing to do


def render(run, cameras, out, *options) -> None:
    """``nerfedit render`` of ``run`` from ``cameras`` into ``out`` (extra CLI ``options``); it must succeed."""
    assert main(["render", "--run", str(run), "--cameras", str(cameras), "--out", str(out), *map(str, options)]) == 0


def score(pred, gt) -> dict:
    """``nerfedit eval`` of the PNGs in ``pred`` against ``gt``: the mean metrics from its ``--json-out`` (a null
    PSNR, identical images, read as inf)."""
    json_out = Path(str(pred).rstrip("/") + ".json")
    assert main(["eval", "--pred", str(pred), "--gt", str(gt), "--json-out", str(json_out)]) == 0
    mean = json.loads(json_out.read_text())["mean"]
    return {**mean, "psnr": float("inf") if mean["psnr"] is None else mean["psnr"]}


def test_edited_render_matches_ground_truth_of_the_deformed_mesh(scene, mesh_run, monkeypatch):
    monkeypatch.setenv("NERFEDIT_CACHE", str(scene / "cache"))
    test_cameras = scene / "data" / "transforms_test.json"
    edit = ["--run", str(mesh_run), "--field", "mesh", "--edit", str(scene / "edit.json"), "--out", str(scene / "edit")]
    assert main(["edit", *edit, "--render-cameras", str(test_cameras)]) == 0
    deformed = SurfaceMesh.load(scene / "edit" / "deformed_mesh.ply")
    render_ground_truth(scene / "data" / "mesh.ply", deformed.vertices, test_cameras, scene / "gt")
    deformation = scene / "edit" / "deformation.npz"
    render(mesh_run, test_cameras, scene / "after", "--deformation", deformation, "--supersample", 2)
    edited = score(scene / "after", scene / "gt")
    assert edited["psnr"] > 33.0 and edited["ssim"] > 0.98, edited
    # `edit --render-cameras` rendered the same edit (one ray per pixel: aliased, so a looser bound)
    assert score(scene / "edit" / "renders", scene / "gt")["psnr"] > 25.0
    # the unedited field is not the edited one: its renders miss the ground truth of the edit
    render(mesh_run, test_cameras, scene / "before", "--supersample", 2)
    assert score(scene / "before", scene / "gt")["psnr"] < edited["psnr"] - 3.0


def test_unedited_mesh_field_render_reproduces_the_dataset(scene, mesh_run, tmp_path):
    render(mesh_run, scene / "data" / "transforms_test.json", tmp_path / "r", "--supersample", 2)
    assert score(tmp_path / "r", scene / "data" / "test")["psnr"] > 35.0


def test_run_errors_are_one_line(scene, mesh_run, tmp_path, capsys):
    assert main(["render", "--run", str(tmp_path), "--cameras", str(scene / "data"), "--out", str(tmp_path / "o")]) == 2
    assert "not a run folder" in capsys.readouterr().err
    assert (
        main(
            [
                "edit",
                "--run",
                str(mesh_run),
                "--field",
                "nerf",
                "--edit",
                str(scene / "edit.json"),
                "--out",
                str(tmp_path / "e"),
            ]
        )
        == 2
    )
    assert "holds a 'mesh' field" in capsys.readouterr().err
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "config.yml").write_text((mesh_run / "config.yml").read_text())
    (broken / "field.pt").write_bytes(b"not a checkpoint")
    assert main(["extract", "--run", str(broken)]) == 2
    assert "not a readable field checkpoint" in capsys.readouterr().err
    assert not (broken / "mesh.ply").exists()
    assert main(["train", "--field", "mesh", "--data", str(scene / "data"), "--out", str(tmp_path / "r")]) == 2
    assert "made from a model file" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    assert main(["eval", "--pred", str(tmp_path), "--gt", str(scene / "data" / "test")]) == 2
    assert "missing" in capsys.readouterr().err


def test_trained_run_records_its_data_relative_and_camera_distance(scene, tmp_path):
    config = [
        "--field-options.resolution",
        "16",
        "--field-options.upsample-steps",
        "--field-options.occupancy-resolution",
        "8",
        "--field-options.train.max-steps",
        "3",
        "--field-options.train.no-progress",
    ]
    assert main(["train", "--data", str(scene / "data"), "--out", str(tmp_path / "run"), *config]) == 0
    run = open_run(tmp_path / "run")
    assert run.backend == "nerf" and run.data == (scene / "data").resolve()
    assert not json.loads((tmp_path / "run" / "log.json").read_text())["eval"] == []
    assert run.camera_distance() == pytest.approx(2.5, rel=1e-3)  # the generator's camera radius
    field = run.field("cpu")
    assert field.grid.resolution == 16 and not torch.isnan(field.grid.table).any()


def test_animated_edit_renders_every_frame(scene, mesh_run, tmp_path, monkeypatch):
    monkeypatch.setenv("NERFEDIT_CACHE", str(scene / "cache"))
    (tmp_path / "anim.json").write_text(json.dumps({**EDIT, "frames": 2}))
    assert (
        main(["edit", "--run", str(mesh_run), "--edit", str(tmp_path / "anim.json"), "--out", str(tmp_path / "e")]) == 0
    )
    cameras, deformation = scene / "data" / "transforms_test.json", tmp_path / "e" / "deformation.npz"
    render(mesh_run, cameras, tmp_path / "r", "--deformation", deformation)
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == ["config.yml", "frame_0000", "frame_0001"]
    render(mesh_run, cameras, tmp_path / "one", "--deformation", deformation, "--frame", 1)
    for name in ("r_0.png", "r_1.png", "r_2.png"):  # --frame 1 renders what the full animation's frame 1 holds
        assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "r" / "frame_0001" / name).read_bytes()
    # frame 0 of "frames": 2 is the rest pose: it renders the unedited field
    render(mesh_run, cameras, tmp_path / "rest")
    assert score(tmp_path / "r" / "frame_0000", tmp_path / "rest")["psnr"] > 40.0
