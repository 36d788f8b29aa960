"""``nerfedit export``: the files of an exported edit hold the analytic ground truth of a known deformation, load as
a new run that renders the same pixels as the edited run, and bad requests are one clear error."""

import json
from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest
import scipy.linalg
import torch
import trimesh
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.cli import main
from nerfedit_plugin.data.cameras import look_at
from nerfedit_plugin.fields.splats.files import read_ply, read_splat, write_ply
from nerfedit_plugin.fields.splats.model import synthetic_model
from nerfedit_plugin.fields.splats.projection import covariances
from nerfedit_plugin.fields.splats.sh_rotation import rotate_sh
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets

TURN = Rotation.from_rotvec([0.2, 0.5, -0.4]).as_matrix()
MOTIONS = [  # frame 0 rigid, frame 1 affine (stretch and shear)
    (TURN, np.array([0.1, 0.0, -0.2])),
    (TURN @ np.array([[1.3, 0.2, 0.0], [0.0, 0.9, 0.0], [0.1, 0.0, 1.1]]), np.array([0.0, 0.3, 0.1])),
]


@pytest.fixture(scope="module")
def edited(tmp_path_factory):
    """A splat run of a degree-3 model and a two-frame deformation.npz of known affine motions over its box."""
    root = tmp_path_factory.mktemp("export")
    model = synthetic_model(800, 3, seed=11, radius=0.7)
    write_ply(model, root / "model.ply")
    assert main(["train", "--field", "splats", "--data", str(root / "model.ply"), "--out", str(root / "run")]) == 0
    vertices, tets = kuhn_grid(3, np.full(3, -1.0), np.full(3, 1.0))
    frames = np.stack([vertices @ a.T + b for a, b in MOTIONS])
    DeformationField(vertices, orient_tets(vertices, tets), frames).save(root / "deformation.npz")
    c2w = look_at(torch.tensor([[2.4, 1.0, 0.8], [-1.2, 2.0, -0.6]]), torch.zeros(2, 3))
    frames_json = [{"file_path": f"./r_{i}", "transform_matrix": m.tolist()} for i, m in enumerate(c2w)]
    (root / "cameras.json").write_text(json.dumps({"camera_angle_x": 0.8, "w": 40, "h": 40, "frames": frames_json}))
    return root, model


def test_the_exported_frames_are_the_analytic_motion_of_the_model(edited, capsys):
    root, model = edited
    out = root / "all"
    assert (
        main(["export", "--run", str(root / "run"), "--deformation", str(root / "deformation.npz"), "--out", str(out)])
        == 0
    )
    assert "writing 2 files of" in capsys.readouterr().out
    report = json.loads((out / "export.json").read_text())
    assert [f["file"] for f in report["files"]] == ["frame_0000.ply", "frame_0001.ply"]
    rest = covariances(*(torch.from_numpy(a).double() for a in (model.quats, model.log_scales))).numpy()
    for (matrix, shift), entry in zip(MOTIONS, report["files"]):
        moved = read_ply(out / entry["file"])
        assert entry["gaussians"] == len(moved) == len(model) and entry["deformation"]["moved"] == len(model)
        assert np.allclose(moved.means, model.means @ matrix.T + shift, atol=2e-6)
        cov = covariances(*(torch.from_numpy(a).double() for a in (moved.quats, moved.log_scales))).numpy()
        assert np.allclose(cov, matrix @ rest @ matrix.T, atol=1e-6)
        polar = torch.from_numpy(scipy.linalg.polar(matrix)[0]).expand(len(model), 3, 3)
        assert np.allclose(moved.sh, rotate_sh(torch.from_numpy(model.sh).double(), polar).numpy(), atol=1e-5)
        assert np.array_equal(moved.opacities, model.opacities)


def test_an_export_made_a_run_renders_the_pixels_of_the_edited_run(edited):
    root, model = edited
    run, cameras = str(root / "run"), str(root / "cameras.json")
    npz = str(root / "deformation.npz")
    assert main(["export", "--run", run, "--deformation", npz, "--frame", "1", "--out", str(root / "one")]) == 0
    assert sorted(p.name for p in (root / "one").iterdir()) == ["config.yml", "export.json", "point_cloud.ply"]
    assert (
        main(
            [
                "train",
                "--field",
                "splats",
                "--data",
                str(root / "one" / "point_cloud.ply"),
                "--out",
                str(root / "again"),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "render",
                "--run",
                run,
                "--cameras",
                cameras,
                "--deformation",
                npz,
                "--frame",
                "1",
                "--out",
                str(root / "bent"),
            ]
        )
        == 0
    )
    assert main(["render", "--run", str(root / "again"), "--cameras", cameras, "--out", str(root / "plain")]) == 0
    for name in ("r_0.png", "r_1.png"):
        bent, plain = iio.imread(root / "bent" / name), iio.imread(root / "plain" / name)
        assert (bent < 250).mean() > 0.1 and np.array_equal(bent, plain)
    assert (
        main(
            [
                "export",
                "--run",
                run,
                "--deformation",
                npz,
                "--frame",
                "1",
                "--format",
                "splat",
                "--out",
                str(root / "s"),
            ]
        )
        == 0
    )
    assert np.allclose(
        read_splat(root / "s" / "point_cloud.splat").means, read_ply(root / "one" / "point_cloud.ply").means
    )


def test_bad_exports_are_one_clear_error(edited, tmp_path, capsys):
    root, _ = edited
    assert main(["export", "--run", str(root / "run"), "--frame", "1", "--out", str(tmp_path / "x")]) == 2
    assert "--frame: needs --deformation" in capsys.readouterr().err
    npz = str(root / "deformation.npz")
    assert (
        main(["export", "--run", str(root / "run"), "--deformation", npz, "--frame", "5", "--out", str(tmp_path / "x")])
        == 2
    )
    assert "frame 5 is out of range" in capsys.readouterr().err
    mesh = tmp_path / "box.ply"
    trimesh.creation.box().export(mesh)
    assert (
        main(
            [
                "train",
                "--field",
                "mesh",
                "--data",
                str(mesh),
                "--field-options.color",
                "0.5",
                "0.5",
                "0.5",
                "--out",
                str(tmp_path / "m"),
            ]
        )
        == 0
    )
    capsys.readouterr()
    assert main(["export", "--run", str(tmp_path / "m"), "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "a 'mesh' run has no primitives to export" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_an_export_that_would_not_fit_on_the_disk_stops_after_the_first_file(edited, tmp_path, monkeypatch, capsys):
    root, _ = edited
    from nerfedit_plugin.pipeline import export

    monkeypatch.setattr(export.shutil, "disk_usage", lambda path: SimpleNamespace(free=1000))
    npz = str(root / "deformation.npz")
    assert main(["export", "--run", str(root / "run"), "--deformation", npz, "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "export: 2 files of" in err and "0.00 GB free" in err and "--frame" in err
    assert list(tmp_path.iterdir()) == []  # nothing left behind
