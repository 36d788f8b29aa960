"""The splats field: the conformance kit (primitives variant), the scene box, the run made from a splat file and
rendered through ``nerfedit render --cameras``, and Gaussians moved by a deformation's forward map."""

import json
import math

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.cli import main
from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.fields.splats.field import SplatsConfig, SplatsField
from nerfedit_plugin.fields.splats.files import write_ply
from nerfedit_plugin.fields.splats.model import SplatModel, synthetic_model
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets
from nerfedit_plugin.pipeline.run import open_run
from nerfedit_plugin.render.renderer import RenderConfig
from nerfedit_plugin.testing import parametrize_with_checks


def kit_model(folder):
    """A degree-3 model of 300 Gaussians inside the kit's box."""
    path = folder / "model.ply"
    write_ply(synthetic_model(300, 3, seed=5, radius=0.7), path)
    return path


@parametrize_with_checks([SplatsConfig(), SplatsConfig(rasterize_mode="antialiased")], model=kit_model)
def test_conformance(check):
    check()


def test_scene_box_ignores_far_background_gaussians():
    model = synthetic_model(2000, 0, seed=1, radius=1.0)
    model.means[:10] *= 1000.0  # a capture's far background
    box = SplatsField.from_model(model, SplatsConfig(box_percentile=1.0, padding=0.0)).scene_bbox.numpy()
    assert (np.abs(box) < 1.0).all() and (np.abs(box) > 0.7).all()


def _transforms(path, c2w: torch.Tensor, size: int, angle: float) -> None:
    frames = [{"file_path": f"./r_{i}", "transform_matrix": m.tolist()} for i, m in enumerate(c2w)]
    path.write_text(json.dumps({"camera_angle_x": angle, "w": size, "h": size, "frames": frames}))


def test_train_from_a_splat_file_then_render_with_cameras(tmp_path):
    write_ply(synthetic_model(500, 1, seed=3), tmp_path / "point_cloud.ply")
    assert (
        main(
            ["train", "--field", "splats", "--data", str(tmp_path / "point_cloud.ply"), "--out", str(tmp_path / "run")]
        )
        == 0
    )
    run = open_run(tmp_path / "run")
    assert run.source == "model" and sorted(p.name for p in run.path.iterdir()) == ["config.yml", "field.pt"]
    c2w = look_at(torch.tensor([[2.0, 1.0, 1.0], [-1.5, 1.5, 0.5]]), torch.zeros(2, 3))
    _transforms(tmp_path / "transforms.json", c2w, 32, 0.8)
    out = tmp_path / "images"
    assert (
        main(["render", "--run", str(run.path), "--cameras", str(tmp_path / "transforms.json"), "--out", str(out)]) == 0
    )
    field = run.field("cpu")
    cameras = Cameras.from_fov(c2w, 32, 32, 0.8)
    for i in range(2):
        written = iio.imread(out / f"r_{i}.png")[..., :3].astype(np.float32) / 255
        expected = field.render(cameras, i, RenderConfig()).numpy()
        assert np.abs(written - expected).max() <= 0.5 / 255 + 1e-6


def test_a_rigid_deformation_moves_the_gaussians():
    """Turning the proxy about z by 30° and shifting it renders as the model turned and shifted (degree 0: the colour
    does not depend on the direction, so the unrotated SH play no part)."""
    model = synthetic_model(400, 0, seed=4, radius=0.6)
    turn = Rotation.from_euler("z", 30, degrees=True)
    shift = np.array([0.1, -0.05, 0.2])
    vertices, tets = kuhn_grid(2, np.full(3, -1.0), np.full(3, 1.0))
    deformation = DeformationField(vertices, orient_tets(vertices, tets), (turn.apply(vertices) + shift)[None])
    quats = (turn * Rotation.from_quat(model.quats[:, [1, 2, 3, 0]])).as_quat()[:, [3, 0, 1, 2]]
    moved = SplatModel(
        (turn.apply(model.means) + shift).astype(np.float32),
        quats.astype(np.float32),
        model.log_scales,
        model.opacities,
        model.sh,
    )
    camera = Cameras.from_fov(look_at(torch.tensor([[2.2, 1.1, 0.8]]), torch.zeros(1, 3)), 48, 48, 0.9)
    bent = SplatsField.from_model(model).render(camera, 0, RenderConfig(), deformation=deformation)
    expected = SplatsField.from_model(moved).render(camera, 0, RenderConfig())
    assert bent.shape == (48, 48, 3) and float((bent - expected).abs().max()) < 2e-3


def test_an_empty_field_says_so():
    field = SplatsConfig().setup(scene_bbox=torch.tensor([[-1.0] * 3, [1.0] * 3]))
    camera = Cameras.from_fov(look_at(torch.tensor([[2.0, 0, 0]]), torch.zeros(1, 3)), 8, 8, math.radians(40))
    with pytest.raises(Exception, match="no Gaussians loaded"):
        field.render(camera, 0, RenderConfig())


def test_a_nerfstudio_export_with_its_dataparser_transforms_renders_from_the_dataset_cameras(tmp_path, capsys):
    """ns-export keeps the Gaussians in nerfstudio's normalised frame ``x ↦ s(Rx + t)``: with its
    dataparser_transforms.json the run renders cameras of the dataset's own frame (``--frame-of-cameras capture``) as
    the model in that frame renders them (a pinhole image is unchanged when scene and camera are scaled together)."""
    model = synthetic_model(500, 0, seed=4)
    rotation = Rotation.from_rotvec([0.3, -0.2, 0.9]).as_matrix()
    scale, shift = 0.4, np.array([0.2, -0.1, 0.05])
    normalised = SplatModel(
        scale * (model.means @ rotation.T + shift),
        np.concatenate([Rotation.from_matrix(rotation).as_quat()[None, [3, 0, 1, 2]]] * len(model)),
        model.log_scales + np.log(scale),
        model.opacities,
        model.sh,
    )
    normalised = SplatModel(
        normalised.means,
        (
            Rotation.from_quat(normalised.quats[:, [1, 2, 3, 0]]) * Rotation.from_quat(model.quats[:, [1, 2, 3, 0]])
        ).as_quat()[:, [3, 0, 1, 2]],
        *normalised.arrays()[2:],
    ).astype(np.float32)
    write_ply(model, tmp_path / "data_frame.ply")
    write_ply(normalised, tmp_path / "splat.ply")
    record = {"transform": np.column_stack([rotation, shift]).tolist(), "scale": scale}
    (tmp_path / "dataparser_transforms.json").write_text(json.dumps(record))
    train = ["train", "--field", "splats", "--data"]
    main([*train, str(tmp_path / "data_frame.ply"), "--out", str(tmp_path / "plain")])
    dataparser = ["--dataparser-transforms", str(tmp_path / "dataparser_transforms.json")]
    main([*train, str(tmp_path / "splat.ply"), "--out", str(tmp_path / "export"), *dataparser])
    assert np.allclose(open_run(tmp_path / "export").source_transform()[:3], scale * np.column_stack([rotation, shift]))
    c2w = look_at(torch.tensor([[2.0, 1.0, 1.0], [-1.5, 1.5, 0.5]]), torch.zeros(2, 3))
    _transforms(tmp_path / "transforms.json", c2w, 32, 0.8)
    cameras = ["--cameras", str(tmp_path / "transforms.json")]
    main(["render", "--run", str(tmp_path / "plain"), *cameras, "--out", str(tmp_path / "a")])
    main(
        [
            "render",
            "--run",
            str(tmp_path / "export"),
            *cameras,
            "--frame-of-cameras",
            "capture",
            "--out",
            str(tmp_path / "b"),
        ]
    )
    for i in range(2):
        a, b = (iio.imread(tmp_path / d / f"r_{i}.png").astype(np.int16) for d in ("a", "b"))
        assert np.abs(a - b).max() <= 2, np.abs(a - b).max()
    assert main([*train, str(tmp_path / "transforms.json"), "--out", str(tmp_path / "bad"), *dataparser]) != 0
    assert not (tmp_path / "bad").exists()
    assert "--dataparser-transforms" in capsys.readouterr().err
