"""An edit of a splat run through the command line: ``nerfedit edit --run RUN --mesh MESH`` with ARAP handles over
two frames, then ``nerfedit render --deformation --frame`` draws the Gaussians the forward map moved."""

import json

import imageio.v3 as iio
import numpy as np
import torch
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.cli import main
from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.fields.splats.deform import deform_model
from nerfedit_plugin.fields.splats.files import write_ply
from nerfedit_plugin.fields.splats.model import SplatModel, synthetic_model
from nerfedit_plugin.pipeline.run import open_run
from nerfedit_plugin.render.renderer import RenderConfig


def test_an_arap_edit_of_a_splat_run_renders_the_moved_gaussians(tmp_path, capsule, proxy_cache):
    model = synthetic_model(6000, 3, seed=8, radius=1.0, scale=(0.01, 0.03))
    p = model.means.astype(np.float64)
    inside = np.hypot(p[:, 0], p[:, 1]) ** 2 + (p[:, 2] - np.clip(p[:, 2], -0.65, 0.65)) ** 2 < 0.3**2
    model = SplatModel(*(a[inside] for a in model.arrays()))
    write_ply(model, tmp_path / "model.ply")
    capsule.save(tmp_path / "capsule.ply")
    turn = {"axis": [1, 0, 0], "degrees": 30, "center": [0, 0, 0.5]}
    spec = {
        "handles": [
            {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, -0.6]}}, "fixed": True},
            {"select": {"box": {"min": [-1, -1, 0.6], "max": [1, 1, 1]}}, "transform": {"rotate": turn}},
        ],
        "frames": 2,
    }
    (tmp_path / "bend.json").write_text(json.dumps(spec))
    c2w = look_at(torch.tensor([[2.6, 0.4, 0.5]]), torch.zeros(1, 3))
    frames = [{"file_path": "./side", "transform_matrix": c2w[0].tolist()}]
    (tmp_path / "cameras.json").write_text(json.dumps({"camera_angle_x": 0.8, "w": 48, "h": 48, "frames": frames}))
    run, edit = str(tmp_path / "run"), tmp_path / "edit"
    assert main(["train", "--field", "splats", "--data", str(tmp_path / "model.ply"), "--out", run]) == 0
    args = ["edit", "--run", run, "--mesh", str(tmp_path / "capsule.ply"), "--deformer", "arap"]
    assert (
        main([*args, "--edit", str(tmp_path / "bend.json"), "--out", str(edit), "--cache-dir", str(proxy_cache)]) == 0
    )
    npz = str(edit / "deformation.npz")
    out = tmp_path / "renders"
    assert (
        main(
            [
                "render",
                "--run",
                run,
                "--cameras",
                str(tmp_path / "cameras.json"),
                "--deformation",
                npz,
                "--frame",
                "1",
                "--out",
                str(out),
            ]
        )
        == 0
    )

    deformation = DeformationField.load(npz)
    moved, report = deform_model(model, deformation, 1)
    assert report.moved > 0.9 * len(model) and report.inverted == 0
    top, bottom = model.means[:, 2] > 0.62, model.means[:, 2] < -0.62
    rigid = Rotation.from_euler("x", 30, degrees=True).apply(model.means[top] - [0, 0, 0.5]) + [0, 0, 0.5]
    assert np.abs(moved.means[top] - rigid).max() < 0.02  # the handle's rotation carries its Gaussians
    assert np.abs(moved.means[bottom] - model.means[bottom]).max() < 0.01  # the fixed handle keeps them
    field = open_run(run).field("cpu")
    camera = Cameras.from_fov(c2w, 48, 48, 0.8)
    expected = field.render(camera, 0, RenderConfig(), deformation=deformation, frame=1).numpy()
    written = iio.imread(out / "side.png")[..., :3].astype(np.float32) / 255
    assert np.abs(written - expected).max() <= 0.5 / 255 + 1e-6
    assert np.abs(expected - field.render(camera, 0, RenderConfig()).numpy()).max() > 0.3  # it moved
