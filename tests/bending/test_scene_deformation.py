"""SceneDeformation: one object is a DeformationField; several objects resolve first-instance-first, vacate their own
rest proxy only, copies read the original's canonical region, chains compose, format 2 round-trips."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.bending.scene_deformation import (
    Instance,
    SceneDeformation,
    SceneObject,
    Stage,
    load_deformation,
)
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.tets import kuhn_grid


def cube(low, high, cells=3):
    vertices, tets = kuhn_grid(cells, 0.0, 1.0)
    return np.asarray(low) + vertices * (np.asarray(high) - np.asarray(low)), tets


def moved(vertices, rotvec=(0.0, 0.0, 0.0), shift=(0.0, 0.0, 0.0), centre=None):
    centre = vertices.mean(0) if centre is None else np.asarray(centre)
    rotation = Rotation.from_rotvec(rotvec).as_matrix()
    return (vertices - centre) @ rotation.T + centre + np.asarray(shift)


def grid_points(low, high, n=24):
    axes = [np.linspace(a, b, n) for a, b in zip(low, high)]
    return torch.as_tensor(np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3))


@pytest.fixture(scope="module")
def two_boxes():
    """Box A at x ∈ [0,1] and box B at x ∈ [2,3] (unit cubes), as scene objects."""
    a, tets = cube([0, 0, 0], [1, 1, 1])
    b, _ = cube([2, 0, 0], [3, 1, 1])
    return SceneObject("a", a, tets), SceneObject("b", b, tets)


def test_one_object_one_instance_is_its_deformation_field(capsule_proxy):
    v, t = capsule_proxy.vertices, capsule_proxy.tets
    deformed = np.stack([v, moved(v, (0.2, -0.4, 0.3), (0.1, 0.2, 0.05))])
    field = DeformationField(v, t, deformed)
    scene = SceneDeformation.from_field(DeformationField(v, t, deformed))
    lo, hi = v.min(0) - 0.3, v.max(0) + 0.3
    x = grid_points(lo, hi, 30)
    for frame in (0, 1):
        a, b = field.bend(x, frame), scene.bend(x, frame)
        assert torch.equal(a.points, b.points) and torch.equal(a.tet, b.tet) and torch.equal(a.empty, b.empty)
        assert torch.equal(field.jacobian(a.tet, frame), scene.jacobian(b.tet, frame))
    assert np.array_equal(field.moved_bounds(1), scene.moved_bounds(1)) and scene.moved_bounds(0) is None


def test_moved_object_vacates_only_its_own_proxy_and_the_other_stays(two_boxes):
    """A moves up by 2; B stays. Points in A's new place map back down; A's old place is empty; B and the space
    around both are the identity."""
    a, b = two_boxes
    up = Instance("a", 0, (a.rest_vertices + [0, 0, 2.0])[None])
    scene = SceneDeformation([Stage([a, b], [up, Instance("b", 1, b.rest_vertices[None])])])
    x = grid_points([-0.5, -0.2, -0.5], [3.5, 1.2, 3.5], 34)  # no sample on a face
    bent = scene.bend(x)
    xs = x.numpy()
    in_new_a = np.all((xs > [0, 0, 2]) & (xs < [1, 1, 3]), 1)
    in_old_a = np.all((xs > [0, 0, 0]) & (xs < [1, 1, 1]), 1)
    assert np.allclose(bent.points[in_new_a].numpy(), xs[in_new_a] - [0, 0, 2], atol=1e-5)
    assert bent.empty.numpy()[in_old_a].all() and not bent.empty.numpy()[in_new_a].any()
    rest = ~(in_new_a | in_old_a)
    assert torch.equal(bent.points[torch.as_tensor(rest)], x[torch.as_tensor(rest)].float())
    strictly_outside_a = ~np.all((xs >= [0, 0, 0]) & (xs <= [1, 1, 1]), 1) & ~np.all(
        (xs >= [0, 0, 2]) & (xs <= [1, 1, 3]), 1
    )
    assert not bent.empty.numpy()[strictly_outside_a].any()
    jac = scene.jacobian(bent.tet).numpy()
    assert np.allclose(jac, np.eye(3), atol=1e-5)  # translations: identity Jacobians everywhere


def test_overlapping_instances_resolve_first_listed_and_removed_objects_vacate(two_boxes):
    """A and B both move onto the same place x ∈ [4,5]: A (listed first) wins there; swapping the order makes B
    win. A removed object (no instance) leaves its rest proxy empty."""
    a, b = two_boxes
    to_a, to_b = (a.rest_vertices + [4.0, 0, 0])[None], (b.rest_vertices + [2.0, 0, 0])[None]
    x = grid_points([4.05, 0.05, 0.05], [4.95, 0.95, 0.95], 9)
    first = SceneDeformation([Stage([a, b], [Instance("a", 0, to_a), Instance("b", 1, to_b)])]).bend(x)
    swapped = SceneDeformation([Stage([a, b], [Instance("b", 1, to_b), Instance("a", 0, to_a)])]).bend(x)
    assert np.allclose(first.points.numpy(), x.numpy() - [4, 0, 0], atol=1e-5)  # into A's rest box
    assert np.allclose(swapped.points.numpy(), x.numpy() - [2, 0, 0], atol=1e-5)  # into B's rest box
    removed = SceneDeformation([Stage([a, b], [Instance("b", 1, b.rest_vertices[None])])])
    inside_a, inside_b = grid_points([0.1] * 3, [0.9] * 3, 5), grid_points([2.1, 0.1, 0.1], [2.9, 0.9, 0.9], 5)
    assert removed.bend(inside_a).empty.all() and not removed.bend(inside_b).empty.any()
    assert torch.equal(removed.bend(inside_b).points, inside_b.float())


def test_copies_read_the_originals_canonical_region(two_boxes):
    """The original stays, a rotated and a scaled copy are placed elsewhere: each copy's points map back to the
    original's rest box by the inverse placement."""
    a, _ = two_boxes
    rotation = Rotation.from_rotvec([0, 0, 0.7]).as_matrix()
    placed = (a.rest_vertices - 0.5) @ rotation.T + [5.0, 5.0, 0.5]
    scaled = (a.rest_vertices - 0.5) * 1.5 + [-5.0, 0.5, 0.75]
    instances = [Instance("a", 0, a.rest_vertices[None]), Instance("a#1", 0, placed[None])]
    scene = SceneDeformation([Stage([a], [*instances, Instance("a#2", 0, scaled[None])])])
    canonical = np.random.default_rng(0).uniform(0.05, 0.95, (500, 3))
    for where, inverse in (
        ((canonical - 0.5) @ rotation.T + [5, 5, 0.5], lambda p: (p - [5, 5, 0.5]) @ rotation + 0.5),
        ((canonical - 0.5) * 1.5 + [-5, 0.5, 0.75], lambda p: (p - [-5, 0.5, 0.75]) / 1.5 + 0.5),
    ):
        out = scene.to_canonical(torch.as_tensor(where))
        assert out.inside.all() and not out.empty.any()
        assert np.allclose(out.points.numpy(), inverse(where), atol=1e-5)
        assert np.allclose(out.points.numpy(), canonical, atol=1e-5)
    original = scene.bend(torch.as_tensor(canonical))
    assert torch.equal(original.points, torch.as_tensor(canonical).float()) and not original.empty.any()


def test_chain_composes_the_stages_and_their_jacobians(two_boxes):
    """Edit 1 rotates A; edit 2 (rest = edit 1's result) shears it: the chain equals bending through edit 2, then
    edit 1, and its Jacobian is the product (finite differences)."""
    a, _ = two_boxes
    first = moved(a.rest_vertices, (0.0, 0.3, 0.0))
    shear = first.copy()
    shear[:, 0] += 0.3 * (first[:, 2] - first[:, 2].min())
    one = SceneDeformation([Stage([a], [Instance("a", 0, first[None])])])
    two = SceneDeformation([Stage([SceneObject("a", first, a.tets)], [Instance("a", 0, shear[None])])])
    chain = one.chained(two)
    x = torch.as_tensor(np.random.default_rng(1).uniform(shear.min(0), shear.max(0), (3000, 3)))
    step = two.bend(x, 0)
    expected = one.bend(step.points.double(), 0)
    got = chain.to_canonical(x, 0)
    assert torch.allclose(got.points, expected.points, atol=1e-5)
    assert torch.equal(got.empty, step.empty | expected.empty)
    inside = got.inside & (step.tet >= 0) & (expected.tet >= 0)
    assert inside.double().mean() > 0.3
    product = one.jacobian(expected.tet) @ two.jacobian(step.tet)
    assert torch.allclose(got.jacobian[inside], product[inside], atol=1e-5)
    # both maps are affine per tet: J applied to a small step inside one tet is the displacement of x_c
    assert not torch.allclose(got.jacobian[inside], torch.eye(3).expand(int(inside.sum()), 3, 3), atol=1e-3)


def test_frames_and_held_single_frame_instances(two_boxes):
    a, b = two_boxes
    frames = np.stack([a.rest_vertices + [0, 0, z] for z in (0.0, 1.0, 2.0)])
    scene = SceneDeformation([Stage([a, b], [Instance("a", 0, frames), Instance("b", 1, (b.rest_vertices + 1)[None])])])
    assert scene.n_frames == 3
    x = torch.tensor([[0.5, 0.5, 2.5], [3.5, 1.5, 1.5]], dtype=torch.float64)
    assert np.allclose(scene.bend(x, 2).points.numpy(), [[0.5, 0.5, 0.5], [2.5, 0.5, 0.5]], atol=1e-5)
    with pytest.raises(NerfEditError, match="frame 3 out of range"):
        scene.bend(x, 3)
    with pytest.raises(NerfEditError, match="different frame counts"):
        SceneDeformation([Stage([a, b], [Instance("a", 0, frames), Instance("b", 1, frames[:2] + 2)])])


def test_save_load_round_trip_and_format_1(tmp_path, two_boxes):
    a, b = two_boxes
    one = SceneDeformation([Stage([a], [Instance("a", 0, moved(a.rest_vertices, (0, 0.3, 0))[None])])])
    two = SceneDeformation([Stage([a, b], [Instance("b", 1, (b.rest_vertices + [0, 2, 0])[None])])])
    chain = one.chained(two)
    chain.save(tmp_path / "deformation.npz")
    loaded = load_deformation(tmp_path / "deformation.npz")
    assert isinstance(loaded, SceneDeformation) and len(loaded.stages) == 2
    x = grid_points([-0.5] * 3, [3.5, 3.5, 1.5], 20)
    want, got = chain.bend(x), loaded.bend(x)
    assert all(torch.equal(getattr(want, k), getattr(got, k)) for k in ("points", "tet", "empty"))
    assert [i.name for i in loaded.stages[1].instances] == ["b"]
    field = DeformationField(a.rest_vertices, a.tets, (a.rest_vertices + 1)[None])
    field.save(tmp_path / "v1.npz")
    assert isinstance(load_deformation(tmp_path / "v1.npz"), DeformationField)
    assert torch.equal(SceneDeformation.load(tmp_path / "v1.npz").bend(x).points, field.bend(x).points)


def test_load_errors_name_the_file_and_key(tmp_path, two_boxes):
    a, _ = two_boxes
    scene = SceneDeformation([Stage([a], [Instance("a", 0, a.rest_vertices[None])])])
    scene.save(tmp_path / "good.npz")
    with np.load(tmp_path / "good.npz") as data:
        arrays = dict(data)
    np.savez(tmp_path / "missing.npz", **{k: v for k, v in arrays.items() if k != "s0_i0_deformed_vertices"})
    with pytest.raises(NerfEditError, match="missing.npz: missing key 's0_i0_deformed_vertices'"):
        load_deformation(tmp_path / "missing.npz")
    np.savez(tmp_path / "layout.npz", **{**arrays, "layout": np.str_("{not json")})
    with pytest.raises(NerfEditError, match="layout.npz: layout: malformed"):
        load_deformation(tmp_path / "layout.npz")
    bad = arrays["s0_i0_deformed_vertices"].copy()
    bad[0, 0, 0] = np.nan
    np.savez(tmp_path / "nan.npz", **{**arrays, "s0_i0_deformed_vertices": bad})
    with pytest.raises(NerfEditError, match="nan.npz: instance 'a': deformed_vertices: values must be finite"):
        load_deformation(tmp_path / "nan.npz")
    with pytest.raises(NerfEditError, match="deformation file not found"):
        load_deformation(tmp_path / "absent.npz")


def test_copies_do_not_vacate_and_a_removed_object_with_copies_is_vacated(two_boxes):
    """A moved original empties the part of its rest box it left; a copy never does (it only reads the region); an
    object whose original is removed is empty at rest even when copies of it are placed elsewhere."""
    a, _ = two_boxes
    inside = grid_points([0.1] * 3, [0.9] * 3, 5)
    copy = Instance("a#1", 0, (a.rest_vertices + [0, 3.0, 0])[None], vacates=False)
    stays = SceneDeformation([Stage([a], [Instance("a", 0, a.rest_vertices[None]), copy])])
    assert not stays.bend(inside).empty.any() and torch.equal(stays.bend(inside).points, inside.float())
    removed = SceneDeformation([Stage([a], [copy])])
    assert removed.bend(inside).empty.all()
    moved_copy = removed.bend(inside + torch.tensor([0, 3.0, 0], dtype=torch.float64))
    assert not moved_copy.empty.any() and torch.allclose(moved_copy.points, inside.float(), atol=1e-6)


def test_bend_through_the_slot_grid_equals_every_instance_on_every_point(capsule_proxy, two_boxes):
    """The oracle of the cell prefilter: each instance's own DeformationField run on every point, first mapped wins,
    empties of vacating instances and of removed objects, gives the same points, tets and empties bit for bit."""
    v, t = capsule_proxy.vertices, capsule_proxy.tets
    a, b = two_boxes
    capsule = SceneObject("capsule", v, t)
    instances = [
        Instance("capsule", 0, moved(v, (0.3, 0.2, 0.1), (0.2, 0.0, 0.1))[None]),
        Instance("capsule#1", 0, moved(v, (0.0, 0.0, 1.2), (1.5, 0.5, 0.0))[None], vacates=False),
        Instance("capsule#2", 0, (v * 0.5 + [0.0, -1.0, 0.0])[None], vacates=False),
        Instance("a", 1, (a.rest_vertices + [-2.0, 0.0, 0.0])[None]),
    ]
    scene = SceneDeformation([Stage([capsule, a, b], instances)])
    x = grid_points([-3.0, -2.0, -1.5], [4.0, 2.0, 1.5], 41)
    got = scene.bend(x)
    points, tet, empty = x.float().clone(), torch.full((len(x),), -1), torch.zeros(len(x), dtype=torch.bool)
    offset = 0
    for inst in instances:
        obj = scene.stages[0].objects[inst.object]
        bent = DeformationField(obj.rest_vertices, obj.tets, inst.deformed_vertices).bend(x)
        take = (bent.tet >= 0) & (tet < 0)
        points[take], tet[take] = bent.points[take], bent.tet[take] + offset
        empty |= bent.empty & inst.vacates
        offset += len(obj.tets)
    from nerfedit_plugin.bending.locate import TetLocator

    empty |= TetLocator(b.rest_vertices, b.tets).member(x) >= 0  # b: removed (no instance)
    empty &= tet < 0
    assert (tet >= 0).any() and empty.any()
    assert torch.equal(got.points, points) and torch.equal(got.tet, tet) and torch.equal(got.empty, empty)
