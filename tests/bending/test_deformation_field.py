"""DeformationField: identity, rigid motions, round trip through a non-rigid lift, the three regions, I/O errors."""

import numpy as np
import pytest
import torch
from locator_checks import assert_primaries_tie
from scipy.spatial.transform import Rotation

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.bending.locate import TetLocator
from nerfedit_plugin.bending.maps import BentPoints
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.tets import tet_signed_volumes


@pytest.fixture(scope="module")
def proxy(capsule_proxy):
    """The real tet proxy (pytetwild) of the capsule fixture, with the capsule surface embedded in it."""
    return capsule_proxy


@pytest.fixture(scope="module")
def lifted(proxy) -> tuple[np.ndarray, DeformationField]:
    """``(T', field)``: the proxy translated up along z by 0.35 of its height (T' overlaps T and leaves vacated
    space); shared by the tests of the three regions so its point locators are built once."""
    deformed = proxy.vertices + np.array([0.0, 0.0, 0.35 * np.ptp(proxy.vertices[:, 2])])
    return deformed, DeformationField(proxy.vertices, proxy.tets, deformed[None])


def sample(vertices: np.ndarray, n: int, seed: int = 0, grow: float = 1.2) -> torch.Tensor:
    lo, hi = vertices.min(0), vertices.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * grow
    return torch.as_tensor(np.random.default_rng(seed).uniform(centre - half, centre + half, (n, 3)))


def surface_points(proxy) -> np.ndarray:
    """Surface vertices through their embedding: Σ b_i r_i over their rest tets."""
    return proxy.embedding_matrix() @ proxy.vertices


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_identity_field_is_the_identity(proxy, dtype):
    field = DeformationField.identity(proxy.vertices, proxy.tets, n_frames=2, dtype=dtype)
    x = sample(proxy.vertices, 20000)
    out = field.to_canonical(x, frame=1)
    assert out.points.dtype == dtype and out.jacobian.shape == (len(x), 3, 3)
    assert 0.3 < out.inside.double().mean() < 0.9
    assert not (out.inside & out.empty).any() and not out.empty.any()  # T' = T: nothing is vacated
    assert torch.equal(out.points, x.to(dtype))  # still tets map x to itself, bit for bit
    assert torch.equal(out.jacobian, torch.eye(3, dtype=dtype).expand(len(x), 3, 3))
    assert np.array_equal(field.offsets(1), np.zeros_like(proxy.vertices))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_rigid_motion_maps_back_exactly(proxy, dtype):
    rotation = Rotation.from_rotvec([0.4, -0.3, 0.9]).as_matrix()
    shift = np.array([0.3, -0.2, 0.5])
    field = DeformationField(proxy.vertices, proxy.tets, (proxy.vertices @ rotation.T + shift)[None], dtype=dtype)
    x = sample(proxy.vertices @ rotation.T + shift, 20000, seed=1)
    out = field.to_canonical(x)
    inside = out.inside
    expected = (x.numpy() - shift) @ rotation  # R^T (x - t)
    atol = 1e-5 if dtype == torch.float32 else 1e-12
    assert inside.double().mean() > 0.15
    assert np.allclose(out.points[inside].double().numpy(), expected[inside.numpy()], atol=atol)
    assert np.allclose(out.jacobian[inside].double().numpy(), rotation.T, atol=atol)
    # outside T' the map is the identity
    assert torch.equal(out.points[~inside], x[~inside].to(dtype))
    assert (out.jacobian[~inside] == torch.eye(3, dtype=dtype)).all()


def test_round_trip_of_embedded_surface_under_non_rigid_lift(proxy):
    """Surface points ride their rest tets through a smooth bend + twist; to_canonical brings them back."""
    v = proxy.vertices

    def bend(p):
        angle = 0.6 * p[:, 2]  # twist about z growing with height, plus a bend and a bulge
        c, s = np.cos(angle), np.sin(angle)
        x, y = c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]
        return np.stack([x * (1 + 0.1 * p[:, 2] ** 2) + 0.15 * p[:, 2] ** 2, y, p[:, 2] * 1.1], 1)

    deformed = bend(v)
    assert (tet_signed_volumes(deformed, proxy.tets) > 0).all()  # the map inverts no tet
    field = DeformationField(v, proxy.tets, deformed[None])
    surface = surface_points(proxy)
    moved = proxy.embedding_matrix() @ deformed
    out = field.to_canonical(torch.as_tensor(moved))
    assert out.inside.all()
    scale = np.ptp(v, axis=0).max()
    assert np.abs(out.points.double().numpy() - surface).max() < 1e-5 * scale
    # the Jacobian is dx_c/dx: a small step inside the same tet moves x_c by exactly J step (affine per tet)
    step = torch.full((len(moved), 3), 1e-4 * scale, dtype=torch.float64)
    nudged = field.to_canonical(torch.as_tensor(moved) + step)
    predicted = out.points.double() + (out.jacobian.double() @ step[:, :, None])[:, :, 0]
    error = (nudged.points.double() - predicted).norm(dim=1)
    assert (error < 1e-6 * scale).double().mean() > 0.9  # the rest crossed into a neighbouring tet


def test_regions_mapped_vacated_and_far(proxy, lifted):
    v = proxy.vertices
    size = np.ptp(v, axis=0)
    deformed, field = lifted
    shift = deformed[0] - v[0]
    centre = (v.min(0) + v.max(0)) / 2
    points = torch.as_tensor(
        np.array(
            [
                centre + [0, 0, 0.5 * size[2]],  # inside T' (and T): mapped back by -shift
                centre - [0, 0, 0.4 * size[2]],  # inside T only: the space the object left
                centre + [10 * size[0], 0, 0],  # far away: identity
            ]
        )
    )
    out = field.to_canonical(points)
    assert out.inside.tolist() == [True, False, False]
    assert out.empty.tolist() == [False, True, False]
    assert torch.allclose(out.points[0].double(), points[0] - torch.as_tensor(shift), atol=1e-5)
    assert torch.equal(out.points[1:], points[1:].float())
    assert torch.allclose(out.jacobian, torch.eye(3).expand(3, 3, 3), atol=1e-6)  # a translation: J = I


def test_degenerate_and_inverted_deformed_tets_do_not_crash(proxy):
    v, tets = proxy.vertices, proxy.tets
    deformed = v * [-1.0, 1.0, 1.0]  # a mirror: every tet inverted
    deformed[tets[0, 1]] = deformed[tets[0, 0]]  # and tet 0 (and its neighbours around that edge) degenerate
    field = DeformationField(v, tets, deformed[None])
    x = sample(deformed, 5000, seed=4)
    out = field.to_canonical(x)
    assert out.inside.double().mean() > 0.3
    assert torch.isfinite(out.points).all() and torch.isfinite(out.jacobian).all()
    mapped = out.inside.numpy()
    mirrored = x.numpy() * [-1.0, 1.0, 1.0]
    good = mapped & (np.abs(out.points.double().numpy() - mirrored).max(1) < 1e-5)
    assert good.sum() > 0.95 * mapped.sum()  # only points in tets touching the collapsed edge differ
    assert (torch.linalg.det(out.jacobian[out.inside].double()) < 0).double().mean() > 0.95


def folded(vertices: np.ndarray) -> np.ndarray:
    """The top tenth mirrored down through a plane: inverted tets overlapping upright ones."""
    mid = vertices[:, 2].max() - 0.1 * np.ptp(vertices[:, 2])
    return vertices * [1.0, 1.0, 0.0] + np.c_[0 * vertices[:, :2], mid - np.abs(vertices[:, 2] - mid)]


def assert_bend_is_point_location(field: DeformationField, rest, deformed, tets, seed: int):
    """``bend`` locates only points in cells its grid marks for T' (then T): its regions and tets must equal plain
    point location in T' and T for points on vertices, face centres and just around both, sampled around, along
    rays (ray after ray, as renders send them: the compiled kernel tries the previous point's tet first) and NaN."""
    rng = np.random.default_rng(seed)
    faces = np.concatenate([vertices[tets[:, [1, 2, 3]]].mean(1) for vertices in (rest, deformed)])
    boundary = np.concatenate([rest, deformed, faces])
    both = np.concatenate([rest, deformed])
    ends = [sample(both, 300, seed=seed + i, grow=2.0).numpy() for i in (1, 2)]
    rays = (ends[0][:, None] + np.linspace(0, 1, 64)[:, None] * (ends[1] - ends[0])[:, None]).reshape(-1, 3)
    points = np.concatenate(
        [boundary]
        + [boundary + rng.normal(0, s, boundary.shape) for s in (1e-6, 1e-4, 1e-2)]
        + [sample(both, 20000, seed=seed, grow=1.5).numpy(), rays, np.full((3, 3), np.nan)]
    )
    x = torch.as_tensor(points, dtype=torch.float32)
    bent = field.bend(x)
    tet_deformed, bary = TetLocator(deformed, tets).locate(x)
    in_rest = TetLocator(rest, tets).locate(x)[0] >= 0
    assert torch.equal(bent.tet, tet_deformed)
    assert torch.equal(bent.empty, (tet_deformed < 0) & in_rest)
    return x, bent, tet_deformed, bary


def assert_same_bend(bent: BentPoints, expected: BentPoints, fields=("points", "tet", "empty"), pick=None) -> None:
    """The named fields of ``bent`` equal those of ``expected`` (rows ``pick`` of it) bit for bit: two bends of the
    same points, e.g. by the two kernels."""
    for name in fields:
        want = getattr(expected, name)
        assert torch.equal(getattr(bent, name), want if pick is None else want[pick]), name


@pytest.mark.parametrize("kernel", ["numba", "torch"])
def test_bend_of_inverted_overlapping_tets_is_point_location(proxy, kernel):
    v, tets = proxy.vertices, proxy.tets
    field = DeformationField(v, tets, folded(v)[None], kernel=kernel)
    assert_bend_is_point_location(field, v, folded(v), tets, seed=8)


@pytest.mark.parametrize("kernel", ["numba", "torch"])
def test_bend_of_a_small_proxy_far_from_the_origin_is_point_location(proxy, kernel):
    """The near grid's cell coordinates are taken relative to its origin: for the proxy shrunk to 1 % and moved
    to 1000, ``x scale + offset`` would cancel and lose ``|x| scale 2⁻²⁴`` cells (~0.2), far beyond the grid's
    10⁻³-cell padding; points near faces would then be declared outside T'."""
    v = (proxy.vertices - proxy.vertices.mean(0)) * 0.01 + 1000.0
    deformed = v + np.array([0.0, 0.0, 0.35 * np.ptp(v[:, 2])])
    field = DeformationField(v, proxy.tets, deformed[None], kernel=kernel)
    assert_bend_is_point_location(field, v, deformed, proxy.tets, seed=9)


@pytest.fixture(scope="module", params=["numba", "torch"])
def lifted_field(request, proxy, lifted) -> tuple[np.ndarray, DeformationField]:
    """``lifted`` with each bending kernel (the compiled CPU pass and the vectorised torch path)."""
    deformed, field = lifted
    if request.param != "numba":  # the shared field uses the CPU default, the compiled kernel
        field = DeformationField(proxy.vertices, proxy.tets, deformed[None], kernel=request.param)
    return deformed, field


def test_bend_agrees_with_point_location_in_both_proxies(proxy, lifted_field):
    v, tets = proxy.vertices, proxy.tets
    deformed, field = lifted_field  # T' overlaps T and leaves vacated space
    x, bent, tet_deformed, bary = assert_bend_is_point_location(field, v, deformed, tets, seed=6)
    inside = tet_deformed >= 0
    assert 0.2 < inside.double().mean() < 0.8 and 0.05 < bent.empty.double().mean()
    assert torch.allclose(bent.points[~inside], x[~inside], rtol=0, atol=0, equal_nan=True)  # NaN stays NaN
    expected = (
        bary[inside, :, None] * torch.as_tensor(v, dtype=torch.float32)[torch.as_tensor(tets)[tet_deformed[inside]]]
    ).sum(1)
    assert torch.allclose(bent.points[inside], expected, atol=1e-5)
    out = field.to_canonical(x)
    assert torch.allclose(out.points, bent.points, rtol=0, atol=0, equal_nan=True) and torch.equal(out.inside, inside)
    assert torch.equal(out.jacobian, field.jacobian(bent.tet))


def test_bend_kernels_agree_and_bend_in_place(proxy, lifted):
    deformed, compiled = lifted
    vectorised = DeformationField(proxy.vertices, proxy.tets, deformed[None], kernel="torch")
    x = sample(np.concatenate([proxy.vertices, deformed]), 50000, seed=11).float()
    a, b = compiled.bend(x), vectorised.bend(x)
    assert_same_bend(a, b)
    assert (a.tet >= 0).any() and a.empty.any() and not torch.equal(a.points, x)
    for field in (compiled, vectorised):
        y = x.clone()
        bent = field.bend(y, out=y, tets=False)  # in place, without the tets
        assert bent.points is y and torch.equal(y, a.points) and bent.tet is None and torch.equal(bent.empty, a.empty)
        wide = torch.zeros(len(x), 3, dtype=torch.float64)  # another dtype: cast into out
        assert field.bend(x, out=wide).points is wide and torch.equal(wide, a.points.double())
    with pytest.raises(ValueError, match="out must have shape"):
        compiled.bend(x, out=torch.zeros(3, 3))
    inside = torch.nonzero(a.tet >= 0).squeeze(1)
    for n in (1, 7, 9, 4097):  # partial 8-point words and blocks, ending with a point inside T'
        pick = torch.cat([torch.arange(n - 1), inside[-1:]])
        part = compiled.bend(x[pick])
        assert_same_bend(part, a, pick=pick)


@pytest.mark.parametrize("kernel", ["numba", "torch"])
def test_points_in_still_tets_keep_their_place_and_the_others_follow_their_tet(proxy, kernel):
    """A local edit (top 10 % of the vertices moved, the rest jittered by 10⁻¹² like a solver's noise): points
    located in tets with no moved corner come back bit for bit with J = I; in the other tets of T' they map to
    Σ b_i r_i as before; both kernels agree exactly."""
    rest, tets = proxy.vertices, proxy.tets
    top = rest[:, 2] > np.quantile(rest[:, 2], 0.9)
    local = rest + np.random.default_rng(1).uniform(-1e-12, 1e-12, rest.shape)
    local[top] += [0.3, 0.0, 0.2]
    field = DeformationField(rest, tets, local[None], kernel=kernel)
    x = sample(np.concatenate([rest, local]), 30000, seed=3).float()
    out = field.to_canonical(x)
    still = ~top[tets].any(1)
    assert np.array_equal(field.still_tets(0), still)
    bent = field.bend(x)
    located = bent.tet >= 0
    in_still = located & torch.from_numpy(still)[bent.tet.clamp_min(0)]
    assert in_still.sum() > 1000 and (located & ~in_still).sum() > 1000
    assert torch.equal(bent.points[in_still], x[in_still])
    assert torch.equal(out.jacobian[in_still], torch.eye(3).expand(int(in_still.sum()), 3, 3))
    moving = located & ~in_still
    tet_ids, bary = TetLocator(local, tets).locate(x[moving])
    expected = (bary.double()[:, :, None] * torch.from_numpy(rest[tets[tet_ids.numpy()]])).sum(1)
    torch.testing.assert_close(bent.points[moving].double(), expected, atol=1e-6, rtol=0)
    other = DeformationField(rest, tets, local[None], kernel="torch" if kernel == "numba" else "numba").bend(x)
    assert_same_bend(other, bent, ("points", "tet"))


def test_moved_bounds_box_the_tets_a_frame_moves(proxy):
    """None for the identity (and for jitter below the tolerance), the whole deformed proxy for a rigid motion, and
    for a local edit the box of the deformed corners of exactly the tets with a displaced corner (brute force)."""
    rest, tets = proxy.vertices, proxy.tets
    extent = np.ptp(rest, axis=0).max()
    jitter = rest + np.random.default_rng(0).uniform(-1e-7, 1e-7, rest.shape) * extent
    rigid = rest @ Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_matrix().T + 0.5
    local = rest.copy()
    top = rest[:, 2] > np.quantile(rest[:, 2], 0.9)
    local[top] += [0.3, 0.0, 0.2]
    field = DeformationField(rest, tets, np.stack([rest, jitter, rigid, local]))
    assert field.moved_bounds(0) is None and field.moved_bounds(1) is None
    np.testing.assert_array_equal(field.moved_bounds(2), [rigid.min(0), rigid.max(0)])
    corners = np.concatenate([local[tet] for tet in tets if top[tet].any()])
    np.testing.assert_array_equal(field.moved_bounds(3), [corners.min(0), corners.max(0)])
    assert (field.moved_bounds(3)[0] > local.min(0)).any()  # a local edit does not take the whole proxy


def test_save_load_round_trip(tmp_path, proxy):
    frames = np.stack([proxy.vertices, proxy.vertices * 1.1])
    field = DeformationField(proxy.vertices, proxy.tets, frames)
    path = tmp_path / "edit" / "deformation.npz"
    field.save(path)
    loaded = DeformationField.load(path, dtype=torch.float64)
    assert loaded.n_frames == 2 and loaded.dtype == torch.float64
    for key in ("rest_vertices", "tets", "deformed_vertices"):
        assert np.array_equal(getattr(loaded, key), getattr(field, key))
    assert np.array_equal(loaded.offsets(1), proxy.vertices - proxy.vertices * 1.1)
    assert [p.name for p in path.parent.iterdir()] == ["deformation.npz"]  # no temporary left behind


def test_load_errors_name_file_and_key(tmp_path, proxy):
    path = tmp_path / "deformation.npz"
    with pytest.raises(NerfEditError, match="deformation.npz: deformation file not found"):
        DeformationField.load(path)
    path.write_bytes(b"not a zip file")
    with pytest.raises(NerfEditError, match="deformation.npz: not a readable"):
        DeformationField.load(path)
    np.savez(path, format_version=1, rest_vertices=proxy.vertices, deformed_vertices=proxy.vertices[None])
    with pytest.raises(NerfEditError, match="deformation.npz: missing key 'tets'"):
        DeformationField.load(path)
    np.savez(
        path,
        format_version=1,
        rest_vertices=proxy.vertices,
        tets=proxy.tets + 10**6,
        deformed_vertices=proxy.vertices[None],
    )
    with pytest.raises(NerfEditError, match="deformation.npz: tets: vertex index out of range"):
        DeformationField.load(path)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda r, t, d: (r[:, :2], t, d), "rest_vertices: expected shape"),
        (lambda r, t, d: (r, t[:, :3], d), "tets: expected shape"),
        (lambda r, t, d: (r, t, d[:, :-1]), "deformed_vertices: expected shape"),
        (lambda r, t, d: (r, t, np.where(np.arange(d.size).reshape(d.shape) == 7, np.nan, d)), "finite"),
        (lambda r, t, d: (r, t - 1, d), "out of range"),
        (lambda r, t, d: (r, t + 0.5, d), "integer"),
    ],
)
def test_constructor_validates(proxy, change, message):
    args = change(proxy.vertices, proxy.tets, proxy.vertices[None].copy())
    with pytest.raises(NerfEditError, match=message):
        DeformationField(*args)
    with pytest.raises(NerfEditError, match="frame 3 out of range"):
        DeformationField.identity(proxy.vertices, proxy.tets).to_canonical(torch.zeros(1, 3), frame=3)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_to_canonical_matches_cpu(proxy):
    deformed = proxy.vertices * [1.0, 1.2, 0.9] + 0.1
    x = sample(deformed, 5000, seed=5)
    cpu = DeformationField(proxy.vertices, proxy.tets, deformed[None]).to_canonical(x)
    gpu = DeformationField(proxy.vertices, proxy.tets, deformed[None], device="cuda").to_canonical(x.cuda())
    assert torch.equal(gpu.inside.cpu(), cpu.inside) and torch.equal(gpu.empty.cpu(), cpu.empty)
    assert torch.allclose(gpu.points.cpu(), cpu.points, atol=1e-5)


def test_unknown_kernel_is_refused_at_construction(proxy):
    with pytest.raises(ValueError, match="kernel"):
        DeformationField(proxy.vertices, proxy.tets, proxy.vertices[None], kernel="cython")


@pytest.mark.parametrize("edit", ["lifted", "folded"])
def test_compiled_frame_build_equals_torch_build(proxy, lifted, edit):
    """The near grid of a frame built by the compiled kernels (the CPU default) equals the torch build bit for bit
    (scale, origin, every bit of every cell), as does the frame's locator grid."""
    deformed = lifted[0] if edit == "lifted" else folded(proxy.vertices)
    frames = [
        DeformationField(proxy.vertices, proxy.tets, deformed[None], kernel=kernel)._frame(0)
        for kernel in ("numba", "torch")
    ]
    for a, b in zip(frames[0].near, frames[1].near):
        assert torch.equal(a, b)
    assert {1, 2, 4} <= {bit for bit in (1, 2, 4) if (frames[0].near[2] & bit).any()}
    for name in ("_cell_mask", "_cell_start", "_cell_count", "_entry_tet", "_deep"):
        assert torch.equal(getattr(frames[0].locator, name), getattr(frames[1].locator, name)), name
    assert_primaries_tie(frames[0].locator, frames[1].locator)  # ties for the deepest may differ (test_locate.py)
