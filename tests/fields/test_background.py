"""The background model of the grid fields: the contraction, where its samples go, compositing in ray order with the
foreground, when it is on (``background: auto | color | field``), training on a generated scene and checkpoints."""

import dataclasses

import pytest
import torch

from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.errors import OptionError
from nerfedit_plugin.fields.background import GRID, BackgroundField, contract
from nerfedit_plugin.fields.nerf import NerfConfig, NerfField
from nerfedit_plugin.fields.neus import NeusConfig
from nerfedit_plugin.render.renderer import RenderConfig, render_image, render_rays

BOX = torch.tensor([[-0.5, -0.4, -0.1], [0.5, 0.4, 0.7]])


def test_contraction_keeps_the_box_and_squeezes_space_into_the_cube_monotonically_along_rays():
    g = torch.Generator().manual_seed(0)
    inside = BOX[0] + torch.rand(1000, 3, generator=g) * (BOX[1] - BOX[0])
    centre, half = BOX.mean(0), (BOX[1] - BOX[0]) / 2
    torch.testing.assert_close(contract(inside, BOX), (inside - centre) / half, atol=1e-6, rtol=0)
    far = torch.randn(1000, 3, generator=g) * torch.logspace(0, 8, 1000)[:, None]
    assert (contract(far, BOX).abs() <= 2.0).all()
    # along every ray the L∞ norm of the contracted point falls to its lowest and rises to 2, never backwards
    origins = torch.randn(200, 3, generator=g) * 3
    directions = torch.nn.functional.normalize(torch.randn(200, 3, generator=g), dim=-1)
    t = torch.cat([torch.linspace(0, 10, 400), torch.logspace(1, 7, 200)])
    norms = contract((origins[:, None] + t[:, None] * directions[:, None]).reshape(-1, 3), BOX)
    norms = norms.abs().amax(-1).view(200, -1)
    lowest = norms.argmin(1, keepdim=True)
    steps = norms.diff(dim=1)
    falling = torch.arange(steps.shape[1]) < lowest
    assert (steps[falling] <= 1e-6).all() and (steps[~falling] >= -1e-6).all()
    assert (norms[:, -1] > 1.99).all()


def test_samples_lie_outside_the_box_in_ray_order_and_cover_the_ray():
    """Before-box samples run from the camera to the box entry, after-box ones from the exit towards infinity; their
    bins' contracted lengths add up to the contracted length of the ray outside the box (as a chord sum)."""
    model = BackgroundField(BOX, 8, 8, n_before=24, n_after=40)
    g = torch.Generator().manual_seed(1)
    origins = torch.nn.functional.normalize(torch.randn(300, 3, generator=g), dim=-1) * 3.0
    directions = torch.nn.functional.normalize(torch.randn(300, 3, generator=g) * 0.4 - origins, dim=-1)
    from nerfedit_plugin.render.renderer import ray_box

    near, far = ray_box(origins, directions, BOX)
    hit = far > near
    assert 50 < hit.sum() < 250  # rays through the box and rays that miss it
    for stratified in (False, True):
        t, length, kind = model.samples(origins, directions, near, far, stratified)
        assert t.shape == length.shape == kind.shape == (300, 64) and (kind == GRID).all()
        assert (t.diff(dim=1) >= 0).all() and (length >= 0).all()
        points = origins[:, None] + t[..., None] * directions[:, None]
        assert (contract(points.reshape(-1, 3), BOX).abs().amax(-1) >= 1 - 1e-5).all()  # outside the box
        assert (t[hit, :24] <= near[hit, None] + 1e-5).all() and (t[hit, 24:] >= far[hit, None] - 1e-5).all()
    # down through the box centre from n₀ = 7.5 half sides: contracted lengths 1 − 1/n₀ before the box, 1 beyond
    origin, direction = torch.tensor([[0.0, 0.0, 3.3]]), torch.tensor([[0.0, 0.0, -1.0]])
    t, length, _ = model.samples(origin, direction, *ray_box(origin, direction, BOX), False)
    assert length[0, :24].sum().item() == pytest.approx(1 - 1 / 7.5, abs=1e-5)
    assert length[0, 24:].sum().item() == pytest.approx(1.0, abs=1e-3)


def scene_field(fg_density: float, fg_rgb, bg_rgb, bg_where) -> NerfField:
    """A nerf field with a background model: constant foreground density (optical thickness per cell) and colour;
    the background opaque with colour ``bg_rgb`` at contracted points where ``bg_where(points)`` holds, else
    empty."""
    config = NerfConfig(resolution=16, upsample_steps=(), occupancy_resolution=0, background="field")
    config = dataclasses.replace(config, background_resolution=32, background_samples=(32, 32))
    field = config.setup(scene_bbox=BOX)
    logit = lambda c: torch.logit(torch.tensor(c))  # noqa: E731
    with torch.no_grad():
        field.grid.table[:, 0] = fg_density
        field.grid.table[:, 1:] = logit(fg_rgb)
        vertices = field.background.grid.vertex_points().reshape(-1, 3)
        field.background.grid.table[:, 0] = torch.where(bg_where(vertices), 30.0, -30.0)
        field.background.grid.table[:, 1:] = logit(bg_rgb)
    return field


def test_compositing_follows_the_ray_before_the_box_inside_it_then_beyond_it():
    """Rays from +x through the box: background content beyond the box shows through an empty foreground; an
    opaque foreground hides it; background content between the camera and the box hides the foreground."""
    origins = torch.tensor([[3.0, 0.05, 0.3], [3.0, -0.1, 0.2]])
    directions = torch.tensor([[-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    config = RenderConfig(n_samples=64, background=(1.0, 0.0, 1.0))
    fg, bg = (0.2, 0.6, 0.3), (0.7, 0.3, 0.1)
    cases = [
        (-30.0, lambda p: p[:, 0] < -1.3, bg),  # empty box, background behind it
        (30.0, lambda p: p[:, 0] < -1.3, fg),  # opaque box in front of the background
        (30.0, lambda p: p[:, 0] > 1.3, bg),  # background between the camera and the box
        (-30.0, lambda p: p[:, 0] > 5.0, (1.0, 0.0, 1.0)),  # nothing: the render config's colour
    ]
    for density, where, expected in cases:
        out = render_rays(scene_field(density, fg, bg, where), origins, directions, config)
        torch.testing.assert_close(out.rgb, torch.tensor(expected).expand(2, 3), atol=1e-4, rtol=0)


def test_an_empty_background_model_composites_like_the_constant_colour(tiny_scene):
    """``background="color"`` is the constant-colour path (no model, nothing else changes); a background model
    with no density gives the same images (up to the summation order of the composite)."""
    test = load_dataset(tiny_scene, "test")
    plain = NerfConfig.tiny(background="color").setup(scene_bbox=test.scene_bbox)
    with torch.no_grad():
        plain.grid.table.normal_(0.0, 2.0, generator=torch.Generator().manual_seed(2))
    assert plain.background_model() is None and not any("background" in key for key in plain.state_dict())
    empty = NerfConfig.tiny(background="field").setup(scene_bbox=test.scene_bbox)
    empty.load_state_dict(plain.state_dict(), strict=False)
    with torch.no_grad():
        empty.background.grid.table[:, 0] = -200.0
    config = RenderConfig(n_samples=48, background=(0.2, 0.4, 0.6))
    torch.testing.assert_close(
        render_image(empty, test.cameras, 0, config), render_image(plain, test.cameras, 0, config)
    )


def test_auto_turns_the_model_on_when_the_content_runs_out_of_the_frame(tiny_scene):
    """Opaque images, and images with alpha whose covered pixels reach the border (a floor running out of the
    frame, transparent beyond it), get the background model; an object framed whole does not."""
    transparent = load_dataset(tiny_scene, "train")
    opaque = dataclasses.replace(transparent, alpha=torch.ones_like(transparent.alpha))
    floor = dataclasses.replace(transparent, alpha=transparent.alpha.clone())
    floor.alpha[:, -8:] = 1.0  # the bottom quarter of every view covered: 46 of the 124 border pixels
    assert not transparent.opaque and opaque.opaque and dataclasses.replace(transparent, alpha=None).opaque
    assert transparent.border_coverage == 0.0 and opaque.border_coverage == 1.0 and not floor.opaque
    assert floor.border_coverage == pytest.approx(46 / 124)
    for cls in (NerfConfig, NeusConfig):
        trainer = cls.tiny().train
        for dataset, expected in ((transparent, "color"), (opaque, "field"), (floor, "field")):
            field = cls.tiny().setup(scene_bbox=transparent.scene_bbox)
            used = field.prepare_background(dataset, trainer)
            assert field.config.background == expected
            assert (field.background_model() is not None) == (expected == "field")
            assert used.foreground_margin == (-1 if expected == "field" else trainer.foreground_margin)
    with pytest.raises(OptionError, match="background"):
        NerfConfig(background="sky")
    with pytest.raises(OptionError, match="background_resolution"):
        NerfConfig(background_resolution=65)


@pytest.fixture(scope="module")
def tiny_floor_scene(tmp_path_factory):
    """A 32×32 generated scene (the cow on the textured floor inside the textured background; 8 train, 2 test)."""
    from nerfedit_plugin.data.scene import generate_scene
    from nerfedit_plugin.data.synthetic import GenerateConfig

    out = tmp_path_factory.mktemp("tiny-floor") / "scene"
    config = GenerateConfig(out=out, objects=["sample:cow"], resolution=32, n_train=8, n_val=1, n_test=2)
    return generate_scene(dataclasses.replace(config, supersample=1))


@pytest.fixture(scope="module")
def tiny_transparent_floor(tmp_path_factory):
    """The cow on the generated floor with no background sphere: transparent beyond the floor's edge (a
    film-transparent render of an object on a floor), 32×32, 8 train, 2 test."""
    from nerfedit_plugin.data.scene import generate_scene
    from nerfedit_plugin.data.synthetic import GenerateConfig

    out = tmp_path_factory.mktemp("tiny-transparent-floor") / "scene"
    config = GenerateConfig(out=out, objects=["sample:cow"], resolution=32, n_train=8, n_val=1, n_test=2)
    return generate_scene(dataclasses.replace(config, supersample=1, background=False))


def test_a_floor_with_alpha_gets_the_background_model_and_beats_the_constant_colour(tiny_transparent_floor):
    """Images with alpha whose floor runs out of the frame: ``auto`` turns the model on, the far sphere stays off
    (transparent pixels see no layer), and training beats the constant colour of object datasets."""
    train, test = load_dataset(tiny_transparent_floor, "train"), load_dataset(tiny_transparent_floor, "test")
    assert not train.opaque and train.border_coverage > 0.2
    scores = {}
    for background in ("color", "auto"):
        config = NerfConfig.tiny(seconds=120.0, background=background)
        config.train.max_steps, config.train.clock = 40, "cpu"
        field = config.setup(scene_bbox=train.scene_bbox)
        scores[background] = field.fit(train, eval_dataset=test)["eval"][-1][1]
    assert field.config.background == "field" and not bool(field.background.far.active)
    assert scores["auto"] > scores["color"] + 1.0, scores


def test_training_on_a_scene_beats_the_constant_colour_and_the_model_round_trips(tiny_floor_scene, tmp_path):
    from nerfedit_plugin.fields.checkpoint import load_field

    train, test = load_dataset(tiny_floor_scene, "train"), load_dataset(tiny_floor_scene, "test")
    assert train.opaque
    scores = {}
    for background in ("color", "auto"):
        config = NerfConfig.tiny(seconds=120.0, background=background)  # the step budget binds
        config.train.max_steps, config.train.clock = 40, "cpu"  # CPU seconds: load does not eat the budget
        field = config.setup(scene_bbox=train.scene_bbox)
        scores[background] = field.fit(train, eval_dataset=test)["eval"][-1][1]
    assert field.config.background == "field"
    assert scores["auto"] > scores["color"] + 1.0, scores
    field.save(tmp_path / "field.pt")
    loaded = load_field(tmp_path / "field.pt")
    assert loaded.config.background == "field"
    torch.testing.assert_close(loaded.background.grid.table, field.background.grid.table, atol=0, rtol=0)
    config = RenderConfig(n_samples=48)
    torch.testing.assert_close(
        render_image(loaded, test.cameras, 0, config), render_image(field, test.cameras, 0, config)
    )
