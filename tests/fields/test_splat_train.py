"""Training splats: the rasteriser's gradient against autograd of a brute-force torch compositor, density control
(clone, split, prune, opacity reset) with the optimiser's state kept aligned, the start from a capture's sparse
points, and ``nerfedit train --field splats`` on a generated dataset, rendered, evaluated and written as a PLY."""

import json
import math

import numpy as np
import pytest
import torch

from nerfedit_plugin.cli import main
from nerfedit_plugin.data.cameras import look_at
from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.fields.splats import densify
from nerfedit_plugin.fields.splats.backward import rasterize
from nerfedit_plugin.fields.splats.field import SplatsField
from nerfedit_plugin.fields.splats.files import read_splats
from nerfedit_plugin.fields.splats.model import synthetic_model
from nerfedit_plugin.fields.splats.projection import NEAR, colors, covariances, project, view_matrix
from nerfedit_plugin.fields.splats.training import NAMES, SplatRecipe, initial_model, ssim
from nerfedit_plugin.pipeline.run import open_run
from nerfedit_plugin.render.renderer import RenderConfig
from tests.data.test_captures import write_workspace

W, H, INTRINSICS = 40, 32, (38.0, 41.0, 21.3, 15.3)


def brute_force(means2d, conics, rgb, opacity, depths, background):
    """Every pixel, every Gaussian in depth order: the compositing rule (skip below 1/255, α ≤ 0.99, stop before
    T < 1e-4) in differentiable torch."""
    order = torch.argsort(depths, stable=True)
    order = order[depths[order] > NEAR]
    grid = torch.arange(H, dtype=means2d.dtype) + 0.5, torch.arange(W, dtype=means2d.dtype) + 0.5
    ys, xs = torch.meshgrid(*grid, indexing="ij")
    T = torch.ones(H, W, dtype=means2d.dtype)
    C = torch.zeros(H, W, 3, dtype=means2d.dtype)
    done = torch.zeros(H, W, dtype=torch.bool)
    for g in order.tolist():
        dx, dy = xs - means2d[g, 0], ys - means2d[g, 1]
        a, b, c = conics[g]
        power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy
        alpha = torch.clamp(opacity[g] * torch.exp(power), max=0.99)
        use = (power <= 0) & (alpha >= 1 / 255) & ~done
        stop = use & (T * (1 - alpha) < 1e-4)
        done, use = done | stop, use & ~stop
        alpha = torch.where(use, alpha, torch.zeros_like(alpha))
        C = C + (alpha * T)[..., None] * rgb[g]
        T = T * (1 - alpha)
    return C + T[..., None] * torch.tensor(background, dtype=C.dtype)


def _image(params, c2w, compositor, background):
    means, quats, log_scales, logits, sh = params
    p = project(means, covariances(quats, log_scales), *view_matrix(c2w), INTRINSICS, W, H)
    rgb, opacity = colors(sh, means, c2w[:3, 3]), torch.sigmoid(logits)
    if compositor == "brute force":
        return brute_force(p.means2d, p.conics, rgb, opacity, p.depths, background)
    variances = p.covars2d.diagonal(0, 1, 2)
    image, _ = rasterize(p.means2d.float(), p.conics.float(), variances, rgb.float(), opacity.float(), p.depths,
                         W, H, background)  # fmt: skip
    return image.double()


@pytest.mark.parametrize("opaque", [False, True])
def test_gradient_matches_autograd_of_a_brute_force_compositor(opaque):
    """d(Σ w · image)/d(every parameter) through the EWA projection and SH colours: the numba backward (float32
    compositor) against torch autograd of the brute-force compositor (float64); Gaussians of every size, some behind
    the camera, and (``opaque``) pixels that stop early."""
    model = synthetic_model(120, 1, seed=int(opaque), scale=(0.02, 0.25))
    if opaque:
        model.opacities[:] = 5.0
    c2w = look_at(torch.tensor([[1.6, -1.0, 0.8]]), torch.zeros(1, 3))[0].double()
    weights = torch.randn(H, W, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    background = (0.2, 0.5, 0.9)
    gradients = {}
    for compositor in ("brute force", "numba"):
        params = [torch.from_numpy(a).double().requires_grad_() for a in model.arrays()]
        image = _image(params, c2w, compositor, background)
        gradients[compositor] = torch.autograd.grad((image * weights).sum(), params)
    for name, got, expected in zip(NAMES, gradients["numba"], gradients["brute force"]):
        assert float(expected.norm()) > 0, name
        assert float((got - expected).norm() / expected.norm()) < 1e-5, name


def test_ssim_is_one_for_equal_images_and_falls_with_noise():
    image = torch.rand(24, 20, 3, generator=torch.Generator().manual_seed(0))
    noise = torch.randn(24, 20, 3, generator=torch.Generator().manual_seed(1))
    values = [float(ssim(image, (image + level * noise).clamp(0, 1))) for level in (0.0, 0.05, 0.2)]
    assert values[0] == pytest.approx(1.0, abs=1e-6) and values[0] > values[1] > values[2]


def _field_with_state(n=50):
    """A field of ``n`` Gaussians and an Adam optimiser after two steps (non-zero, distinct moments per row)."""
    field = SplatsField.from_model(synthetic_model(n, 1, seed=2))
    optimizer = torch.optim.Adam([getattr(field, name) for name in NAMES], lr=0.01)
    for step in range(2):
        optimizer.zero_grad()
        sum(((getattr(field, name) * (1 + step)) ** 2).sum() for name in NAMES).backward()
        optimizer.step()
    return field, optimizer


def _moments(field, optimizer, name):
    return optimizer.state[getattr(field, name)]["exp_avg"], optimizer.state[getattr(field, name)]["exp_avg_sq"]


def test_prune_removes_exactly_the_marked_gaussians_and_their_moments():
    field, optimizer = _field_with_state()
    before = {name: (getattr(field, name).detach().clone(), *_moments(field, optimizer, name)) for name in NAMES}
    remove = torch.zeros(50, dtype=torch.bool)
    remove[[0, 7, 8, 49]] = True
    densify.prune(field, optimizer, NAMES, remove)
    assert field.n_gaussians == 46
    for name in NAMES:
        values, m1, m2 = before[name]
        assert torch.equal(getattr(field, name).detach(), values[~remove])
        assert all(torch.equal(a, b[~remove]) for a, b in zip(_moments(field, optimizer, name), (m1, m2)))
        assert any(p is getattr(field, name) for group in optimizer.param_groups for p in group["params"])
    optimizer.step()  # the optimiser runs on the new parameters


def test_clone_duplicates_the_marked_gaussians_with_fresh_moments():
    field, optimizer = _field_with_state()
    before = {name: (getattr(field, name).detach().clone(), *_moments(field, optimizer, name)) for name in NAMES}
    marked = torch.zeros(50, dtype=torch.bool)
    marked[[3, 30]] = True
    densify.clone(field, optimizer, NAMES, marked)
    assert field.n_gaussians == 52
    for name in NAMES:
        values, m1, m2 = before[name]
        assert torch.equal(getattr(field, name).detach(), torch.cat([values, values[[3, 30]]]))
        for moment, old in zip(_moments(field, optimizer, name), (m1, m2)):
            assert torch.equal(moment[:50], old) and not moment[50:].any()


def test_split_replaces_each_marked_gaussian_by_a_pair_with_its_mean():
    field, optimizer = _field_with_state()
    before = {name: getattr(field, name).detach().clone() for name in NAMES}
    moments = _moments(field, optimizer, "means")
    marked = torch.zeros(50, dtype=torch.bool)
    marked[[1, 2, 40]] = True
    densify.split(field, optimizer, NAMES, marked, torch.Generator().manual_seed(0))
    assert field.n_gaussians == 53
    kept, children = slice(0, 47), slice(47, 53)
    means = field.means.detach()
    assert torch.equal(means[kept], before["means"][~marked])
    pairs = means[children].reshape(2, 3, 3)  # [first children, second children]
    torch.testing.assert_close(pairs.mean(0), before["means"][marked], rtol=0, atol=1e-6)  # the mixture's mean
    assert (pairs[0] != pairs[1]).all()
    shrink = before["log_scales"][marked].repeat(2, 1) - math.log(densify.SPLIT_SHRINK)
    torch.testing.assert_close(field.log_scales.detach()[children], shrink)
    for name in ("quats", "opacities", "sh"):
        assert torch.equal(
            getattr(field, name).detach()[children],
            before[name][marked].repeat_interleave(1, 0).repeat((2,) + (1,) * (before[name].ndim - 1)),
        )
    new = _moments(field, optimizer, "means")
    assert torch.equal(new[0][kept], moments[0][~marked]) and not new[0][children].any()


def test_opacity_reset_caps_the_opacities_and_zeroes_their_moments():
    field, optimizer = _field_with_state()
    logits = field.opacities.detach().clone()
    densify.reset_opacity(field, optimizer, 0.01)
    assert torch.equal(field.opacities.detach(), torch.clamp(logits, max=math.log(0.01 / 0.99)))
    assert all(not m.any() for m in _moments(field, optimizer, "opacities"))


def test_a_capture_starts_from_its_sparse_points(tmp_path):
    rng = np.random.default_rng(0)
    _, frame = write_workspace(tmp_path, points=rng.normal(scale=0.3, size=(200, 3)) @ np.eye(3))
    train = load_dataset(tmp_path, "train")
    assert train.points is not None and train.points.shape == (200, 3)
    model = initial_model(train.scene_bbox, train.points.numpy(), SplatRecipe(sh_degree=2), seed=0)
    assert np.array_equal(model.means, train.points.numpy()) and model.degree == 2
    random = initial_model(train.scene_bbox, None, SplatRecipe(init_gaussians=300), seed=0)
    lo, hi = train.scene_bbox.numpy()
    assert len(random) == 300 and ((random.means >= lo) & (random.means <= hi)).all()
    centre = np.array([0.1, 0.2, 0.3])
    scene = initial_model(train.scene_bbox, None, SplatRecipe(init_gaussians=300, far_gaussians=50), 0, (centre, 4.0))
    assert np.array_equal(scene.means[:300], random.means)  # opaque images: the box, then the surroundings
    assert np.allclose(np.linalg.norm(scene.means[300:] - centre, axis=1), 4.0, atol=1e-5) and len(scene) == 350


def test_train_splats_on_a_dataset_then_render_evaluate_and_write_a_ply(tiny_scene, tmp_path):
    """``nerfedit train --field splats`` on the 32×32 cow: the held-out PSNR rises far above the start; the run
    records its rasterisation mode, renders and evaluates like any run, and its model written as an INRIA PLY loads
    back to the same render."""
    run_dir, images = tmp_path / "run", tmp_path / "images"
    options = ["--field-options.train.max-seconds", "8", "--field-options.train.eval-every-seconds", "0",
               "--field-options.recipe.densify-from", "50", "--field-options.recipe.densify-every", "50",
               "--field-options.rasterize-mode", "antialiased"]  # fmt: skip
    assert main(["train", "--field", "splats", "--data", str(tiny_scene), "--out", str(run_dir), *options]) == 0
    run = open_run(run_dir)
    log = json.loads((run_dir / "log.json").read_text())
    assert run.source == "dataset" and run.config["field_config"]["rasterize_mode"] == "antialiased"
    assert log["eval"][-1][1] > log["eval"][0][1] + 8.0 and log["gaussians"] != 5000  # density control ran
    assert sorted(p.name for p in run_dir.iterdir()) == ["config.yml", "field.pt", "log.json"]
    assert main(["render", "--run", str(run_dir), "--cameras", str(tiny_scene), "--out", str(images)]) == 0
    assert (
        main(["eval", "--pred", str(images), "--gt", str(tiny_scene / "test"), "--json-out", str(tmp_path / "e.json")])
        == 0
    )
    measured = json.loads((tmp_path / "e.json").read_text())
    assert measured["mean"]["psnr"] == pytest.approx(log["eval"][-1][1], abs=0.5)  # PNG rounding of the render
    assert main(["export", "--run", str(run_dir), "--out", str(tmp_path / "export")]) == 0
    field = run.field("cpu")
    loaded = SplatsField.from_model(read_splats(tmp_path / "export" / "point_cloud.ply"), field.config)
    test = load_dataset(tiny_scene, "test")
    for i in range(len(test)):
        torch.testing.assert_close(loaded.render(test.cameras, i, RenderConfig()), field.render(test.cameras, i,
                                   RenderConfig()), rtol=0, atol=1e-6)  # fmt: skip
