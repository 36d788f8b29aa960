"""Placing rest points through a scene edit (``SceneDeformation.place``, the forward map of splats): what lands at a
point is what ray bending shows there — moved and copied objects carry their region, removed and vacated regions
are emptied, moved content hides what was at its new place — and a chain places through both edits."""

import numpy as np
import torch

from nerfedit_plugin.bending.maps import PlacementMap
from nerfedit_plugin.bending.scene_deformation import Instance, SceneDeformation, SceneObject, Stage
from nerfedit_plugin.fields.splats.deform import deform_model
from nerfedit_plugin.fields.splats.model import synthetic_model
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets


def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    vertices, tets = kuhn_grid(2, np.asarray(lo, dtype=float), np.asarray(hi, dtype=float))
    return vertices, orient_tets(vertices, tets)


def scene() -> SceneDeformation:
    """A moves by +0.9 in y (onto background), B stays and is copied 0.9 up in z, C is removed."""
    a, b, c = (
        box([-1, -0.3, 0], [-0.4, 0.3, 0.6]),
        box([0.3, -0.3, 0], [0.9, 0.3, 0.6]),
        box([-0.3, -1, 0], [0.3, -0.6, 0.5]),
    )
    objects = [SceneObject("a", *a), SceneObject("b", *b), SceneObject("c", *c)]
    instances = [
        Instance("a", 0, (a[0] + [0, 0.9, 0])[None]),
        Instance("b", 1, b[0][None]),
        Instance("b copy", 1, (b[0] + [0, 0, 0.9])[None], vacates=False),
    ]
    return SceneDeformation([Stage(objects, instances)], dtype=torch.float64)


def points(n: int, seed: int = 0) -> torch.Tensor:
    return torch.from_numpy(np.random.default_rng(seed).uniform([-1.2, -1.2, -0.2], [1.2, 1.2, 1.7], (n, 3)))


def test_what_lands_at_a_point_is_what_ray_bending_shows_there():
    deformation = scene()
    assert isinstance(deformation, PlacementMap)
    x = points(20000)
    placed = deformation.place(x)
    assert torch.all(placed.source[1:] >= placed.source[:-1])
    back = deformation.bend(placed.points)
    assert not back.empty.any() and torch.allclose(back.points, x[placed.source], atol=1e-12)
    # a rest point shown where it rests exactly when ray bending shows it there
    shown = deformation.bend(x)
    in_place = torch.zeros(len(x), dtype=torch.bool)
    in_place[placed.source[(placed.points == x[placed.source]).all(1)]] = True
    assert torch.equal(in_place, ~shown.empty & (shown.points == x).all(1))
    counts = torch.bincount(placed.source, minlength=len(x))
    in_b = (x[:, 0] > 0.3) & (x[:, 0] < 0.9) & (x[:, 1].abs() < 0.3) & (x[:, 2] > 0) & (x[:, 2] < 0.6)
    in_c = (x[:, 0].abs() < 0.3) & (x[:, 1] > -1) & (x[:, 1] < -0.6) & (x[:, 2] > 0) & (x[:, 2] < 0.5)
    assert torch.all(counts[in_b] == 2) and torch.all(counts[in_c] == 0)  # copied; removed
    assert (counts == 0).sum() > in_c.sum()  # moved content hides background, A's rest place is vacated


def test_splats_follow_the_scene_and_a_chain_places_through_both_edits():
    model = synthetic_model(3000, 3, seed=1, radius=1.0, dtype=np.float64)
    model.means[:, 2] += 0.6
    deformation = scene()
    out, report = deform_model(model, deformation)
    placed = deformation.place(torch.from_numpy(model.means))
    assert len(out) == report.placed == len(placed.source) and report.copied > 0 and report.removed > 0
    assert np.allclose(out.means, placed.points.numpy(), atol=1e-12)
    assert np.array_equal(out.opacities, model.opacities[placed.source.numpy()])
    lift = np.array([0.0, 0.0, 0.2])
    vertices, tets = box([-1.5, -1.5, -0.5], [1.5, 1.5, 2.0])
    chain = SceneDeformation(
        deformation.stages
        + [Stage([SceneObject("all", vertices, tets)], [Instance("all", 0, (vertices + lift)[None])])],
        dtype=torch.float64,
    )
    chained, _ = deform_model(model, chain)
    assert np.allclose(chained.means, out.means + lift, atol=1e-12) and np.allclose(chained.sh, out.sh, atol=1e-12)
    identity = SceneDeformation(
        [Stage([SceneObject("all", vertices, tets)], [Instance("all", 0, vertices[None])])], dtype=torch.float64
    )
    same, report = deform_model(model, identity)
    assert report.moved == 0 and all(np.array_equal(a, b) for a, b in zip(same.arrays(), model.arrays()))
