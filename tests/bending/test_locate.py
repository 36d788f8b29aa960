"""TetLocator: the grid answer equals brute force exactly (tet ids and barycentric bits), no cracks, edge cases; for
both kernels (the compiled CPU walk and the vectorised torch walk)."""

import numpy as np
import pytest
import torch
from locator_checks import assert_primaries_tie

from nerfedit_plugin.bending.locate import EPS, TetLocator, barycentric, box_cells, locate_brute_force
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets


@pytest.fixture(params=["numba", "torch"])
def kernel(request):
    return request.param


@pytest.fixture(scope="session")
def sphere_tets():
    """A real pytetwild tet mesh (~1.6k tets) of an icosphere, positively oriented."""
    import pytetwild
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=2)
    vertices, tets = pytetwild.tetrahedralize(
        mesh.vertices, mesh.faces.astype(np.int32), edge_length_fac=0.07, optimize=True, epsilon=5e-3, quiet=True
    )
    vertices = np.asarray(vertices, dtype=np.float64)
    return vertices, orient_tets(vertices, tets)


def probe_points(vertices: np.ndarray, tets: np.ndarray, n_random: int, seed: int = 0) -> np.ndarray:
    """Random points in the enlarged bbox, every vertex, interior-face centroids, edge midpoints, far points."""
    rng = np.random.default_rng(seed)
    lo, hi = vertices.min(0), vertices.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * 1.15
    faces = np.sort(np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]], tets[:, [0, 1, 2]]]), 1)
    faces = np.unique(faces, axis=0)
    edges = np.unique(np.sort(np.concatenate([tets[:, [i, j]] for i in range(4) for j in range(i + 1, 4)]), 1), axis=0)
    return np.concatenate(
        [
            rng.uniform(centre - half, centre + half, (n_random, 3)),
            vertices,
            vertices[faces].mean(1),
            vertices[edges].mean(1),
            centre + half * 10 * rng.standard_normal((50, 3)),
        ]
    )


def assert_same_as_brute_force(vertices, tets, points, dtype, kernel, **kwargs):
    locator = TetLocator(vertices, tets, dtype=dtype, kernel=kernel, **kwargs)
    tet, bary = locator.locate(torch.as_tensor(points))
    ref_tet, ref_bary = locate_brute_force(vertices, tets, torch.as_tensor(points), dtype=dtype)
    assert torch.equal(tet, ref_tet), f"{int((tet != ref_tet).sum())} of {len(tet)} points differ"
    assert torch.equal(bary.contiguous(), ref_bary)  # bit for bit, and 0 where -1
    # membership: some tet that accepts the point, exactly where the rule finds one
    member = locator.member(torch.as_tensor(points))
    assert torch.equal(member >= 0, ref_tet >= 0)
    table, hit = locator._table, torch.nonzero(member >= 0).squeeze(1)
    b = barycentric(table.rows[member[hit]], torch.as_tensor(points, dtype=dtype)[hit])
    assert (torch.stack(b).amin(0) >= -EPS[dtype]).all() and table.usable[member[hit]].all()
    return tet, bary


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_grid_equals_brute_force_on_pytetwild_mesh(sphere_tets, dtype, kernel):
    vertices, tets = sphere_tets
    points = probe_points(vertices, tets, 3000)
    tet, bary = assert_same_as_brute_force(vertices, tets, points, dtype, kernel, chunk=2500)
    inside = tet >= 0
    assert 0.2 < inside.double().mean() < 0.9
    # barycentrics reproduce the point and satisfy the containment rule
    corners = torch.as_tensor(vertices)[torch.as_tensor(tets)[tet[inside]]]
    rebuilt = (bary[inside].double()[:, :, None] * corners).sum(1)
    tolerance = 1e-5 if dtype == torch.float32 else 1e-12
    assert torch.allclose(rebuilt, torch.as_tensor(points)[inside], atol=tolerance)
    assert bary[inside].min() >= -EPS[dtype]


@pytest.mark.parametrize(
    "dtype, settings",
    [
        (torch.float32, {}),
        (torch.float64, {}),
        (torch.float32, {"cells_per_tet": 0.3, "rounds": 1}),  # coarse cells, long lists: mostly the full scan
        (torch.float32, {"cells_per_tet": 16.0, "rounds": 6}),
    ],
)
def test_grid_equals_brute_force_on_cube_grid(dtype, settings, kernel):
    vertices, tets = kuhn_grid(5)
    points = probe_points(vertices, tets, 3000, seed=1)
    tet, _ = assert_same_as_brute_force(vertices, tets, points, dtype, kernel, **settings)
    # shared vertices, faces and edges are exactly representable here: they are all found (no cracks) and
    # the smallest index among the tets sharing them wins
    n_random = 3000
    on_mesh = tet[n_random:-50]
    assert (on_mesh >= 0).all()
    assert (tet[-50:] == -1).all()


def test_points_deep_inside_interior_tets_are_never_lost(sphere_tets, kernel):
    vertices, tets = sphere_tets
    rng = np.random.default_rng(2)
    weights = rng.dirichlet(np.ones(4), size=len(tets))
    points = (weights[:, :, None] * vertices[tets]).sum(1)
    tet, _ = TetLocator(vertices, tets, kernel=kernel).locate(torch.as_tensor(points))
    assert (tet >= 0).all()
    # a point strictly inside tet t (valid mesh) is located in t
    strict = weights.min(1) > 1e-3
    assert torch.equal(tet[torch.as_tensor(strict)], torch.arange(len(tets))[torch.as_tensor(strict)])


def test_overlapping_and_degenerate_tets_follow_the_rule(kernel):
    """Two overlapping copies of a grid (so no tet is 'safe') plus zero-volume tets: still brute-force exact."""
    vertices, tets = kuhn_grid(3)
    shifted = vertices + [0.13, 0.05, -0.07]
    flat = np.array([[0, 1, 2, 3]]) + 2 * len(vertices)  # four collinear points: zero volume
    line = np.linspace(0, 1, 4)[:, None] * [1.0, 1.0, 0.0]
    all_vertices = np.concatenate([vertices, shifted, line])
    all_tets = np.concatenate([tets + len(vertices), tets, flat])  # the shifted copy has the lower indices
    points = probe_points(all_vertices, all_tets[:-1], 3000, seed=3)
    tet, _ = assert_same_as_brute_force(all_vertices, all_tets, points, torch.float32, kernel)
    assert (tet != len(all_tets) - 1).all()
    both = torch.as_tensor(((points > [0.13, 0.05, 0.0]) & (points < [1.0, 1.0, 0.93])).all(1))  # the overlap
    assert (tet[both] < len(tets)).all()  # where the copies overlap, the lower-index copy wins


def test_outside_nan_and_empty_inputs(kernel):
    vertices, tets = kuhn_grid(2)
    locator = TetLocator(vertices, tets, kernel=kernel)
    points = torch.tensor(
        [[-5.0, 0.5, 0.5], [0.5, 0.5, 7.0], [float("nan"), 0.5, 0.5], [float("inf"), 0, 0], [0.5, 0.5, 0.5]]
    )
    tet, bary = locator.locate(points)
    assert tet[:4].tolist() == [-1] * 4 and tet[4] >= 0
    assert (bary[:4] == 0).all()
    tet, bary = locator.locate(torch.zeros((0, 3)))
    assert tet.shape == (0,) and bary.shape == (0, 4)
    assert locator.member(torch.zeros((0, 3))).shape == (0,)


def test_all_degenerate_mesh_locates_nothing(kernel):
    vertices = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0.0]])
    tet, _ = TetLocator(vertices, np.array([[0, 1, 2, 3]]), kernel=kernel).locate(torch.rand(10, 3))
    assert (tet == -1).all()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu(sphere_tets):
    vertices, tets = sphere_tets
    points = torch.as_tensor(probe_points(vertices, tets, 5000))
    cpu = TetLocator(vertices, tets, kernel="torch").locate(points)
    gpu = TetLocator(torch.as_tensor(vertices).cuda(), tets).locate(points.cuda())
    assert torch.equal(gpu[0].cpu(), cpu[0])
    assert torch.allclose(gpu[1].cpu(), cpu[1], atol=1e-6)


def test_kernels_agree_on_ray_like_points(sphere_tets):
    """Coherent samples along rays (what rendering sends): both kernels give identical tets and barycentric bits."""
    vertices, tets = sphere_tets
    rng = np.random.default_rng(5)
    origins = rng.normal(size=(200, 3)) * 3
    directions = -origins / np.linalg.norm(origins, axis=1, keepdims=True) + rng.normal(size=(200, 3)) * 0.2
    points = torch.as_tensor(origins[:, None] + np.linspace(0, 6, 300)[:, None] * directions[:, None]).reshape(-1, 3)
    answers = [TetLocator(vertices, tets, kernel=k).locate(points) for k in ("numba", "torch")]
    assert torch.equal(answers[0][0], answers[1][0]) and torch.equal(answers[0][1], answers[1][1])
    assert 0.1 < (answers[0][0] >= 0).double().mean() < 0.9


def test_kernel_choice_is_checked():
    vertices, tets = kuhn_grid(1)
    assert TetLocator(vertices, tets).kernel == "numba"  # the CPU default
    with pytest.raises(ValueError, match="kernel"):
        TetLocator(vertices, tets, kernel="cython")


def anisotropic_grid(vertices: np.ndarray, side: int = 42) -> tuple[torch.Tensor, torch.Tensor, int]:
    """``(scale, offset, side)`` of a cell grid ``u = x scale + offset`` over the mesh, finer than the tets near
    the boundary, with other cell sizes per axis."""
    lo, hi = vertices.min(0), vertices.max(0)
    scale = torch.as_tensor((side - 2) / (hi - lo) * [1.0, 0.8, 0.9])
    return scale, torch.as_tensor(1.0 - lo * scale.numpy()), side


def points_in_cells(cells: torch.Tensor, scale: torch.Tensor, offset: torch.Tensor, side: int) -> torch.Tensor:
    """Up to 1000 of the cells (float32 points): 24 random points of each, grown by 1e-3 cell, and its 8 corners."""
    cells = cells[torch.randperm(len(cells), generator=torch.Generator().manual_seed(0))[:1000]]
    ijk = torch.stack([cells // (side * side), (cells // side) % side, cells % side], 1).double()
    rng = np.random.default_rng(7)
    u = ijk[:, None] + torch.as_tensor(rng.uniform(-1e-3, 1 + 1e-3, (len(cells), 24, 3)))
    corners = torch.as_tensor([[(c >> 2) & 1, (c >> 1) & 1, c & 1] for c in range(8)], dtype=torch.float64)
    u = torch.cat([u, ijk[:, None] + corners * (1 + 2e-3) - 1e-3], 1).reshape(-1, 3)
    return ((u - offset) / scale).float()


@pytest.mark.parametrize("hole", [False, True])
def test_covered_cells_are_wholly_accepted(sphere_tets, hole):
    """Every point of a covered cell (grown by 1e-3 cell) is accepted by the rule; a removed tet leaves a hole
    whose cells are not covered."""
    vertices, tets = sphere_tets
    if hole:
        centre = vertices[tets].mean(1)
        tets = tets[np.linalg.norm(centre, axis=1) > 0.25]  # carve out the middle
    locator = TetLocator(vertices, tets)
    scale, offset, side = anisotropic_grid(vertices)
    covered = locator.covered_cells(scale, offset, side)
    cells = torch.nonzero(covered).squeeze(1)
    assert len(cells) > 1000
    assert (locate_brute_force(vertices, tets, points_in_cells(cells, scale, offset, side))[0] >= 0).all()
    if hole:
        middle = offset.floor().long()  # the cell of the origin, in the hole
        assert locate_brute_force(vertices, tets, torch.zeros(1, 3))[0].item() == -1
        assert not covered[(middle * torch.tensor([side * side, side, 1])).sum()]
        assert (
            covered.double().mean()
            < TetLocator(vertices, sphere_tets[1]).covered_cells(scale, offset, side).double().mean()
        )


def test_reach_cells_hold_every_accepted_point(sphere_tets):
    """No point of a cell left out of ``reach_cells`` (grown by 1e-3 cell) is accepted, and every accepted point
    near the surface lies in a reached cell; the face-plane test leaves out cells that the tet boxes meet."""
    vertices, tets = sphere_tets
    locator = TetLocator(vertices, tets)
    scale, offset, side = anisotropic_grid(vertices)
    reach = locator.reach_cells(scale, offset, side)
    boxes = locator.boxes()
    first = (boxes[0] * scale + offset).floor().long().clamp(0, side - 1)
    last = (boxes[1] * scale + offset).floor().long().clamp(0, side - 1)
    met = torch.zeros(side**3, dtype=torch.bool)
    met[(box_cells(first, last)[1] * torch.tensor([side * side, side, 1])).sum(1)] = True
    left_out = torch.nonzero(met & ~reach).squeeze(1)
    assert len(left_out) > 100
    assert (locate_brute_force(vertices, tets, points_in_cells(left_out, scale, offset, side))[0] == -1).all()
    rng = np.random.default_rng(3)
    direction = rng.normal(size=(100000, 3))
    radius = np.linalg.norm(vertices, axis=1).max() * rng.uniform(0.9, 1.1, (100000, 1))
    points = torch.as_tensor(direction / np.linalg.norm(direction, axis=1, keepdims=True) * radius).float()
    accepted = points[locate_brute_force(vertices, tets, points)[0] >= 0]
    assert len(accepted) > 1000
    ijk = (accepted.double() * scale + offset).floor().long().clamp(0, side - 1)
    assert reach[(ijk * torch.tensor([side * side, side, 1])).sum(1)].all()


GRID_ARRAYS = ("_cell_mask", "_octant_primary", "_cell_start", "_cell_count", "_entry_tet", "_deep", "_neighbours")


def assert_same_grid(compiled: TetLocator, reference: TetLocator) -> None:
    """Two locators of the same tets hold the same grid bit for bit: cell lists, sub-cell masks, safe tets, walk
    neighbours, and the cells their grid queries report; octant primaries too, except where two tets tie for the
    deepest at the octant centre (within 1e-12: the two builds round differently on some CPUs, and either tet is a
    valid start of the walk)."""
    assert compiled.grid_shape == reference.grid_shape
    for name in GRID_ARRAYS:
        if name == "_octant_primary":
            assert_primaries_tie(compiled, reference)
            continue
        assert torch.equal(getattr(compiled, name), getattr(reference, name)), name
    for a, b in zip(compiled.boxes(), reference.boxes()):
        assert torch.equal(a, b)
    bounds = [locator.box_bounds() for locator in (compiled, reference)]
    assert all(torch.equal(a, b) for a, b in zip(*bounds)) if bounds[0] else bounds[1] is None
    scale, offset, side = anisotropic_grid(compiled._table.corners.reshape(-1, 3).numpy())
    for query in ("boxed_cells", "reach_cells", "covered_cells"):
        assert torch.equal(
            getattr(compiled, query)(scale, offset, side), getattr(reference, query)(scale, offset, side)
        )


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("case", ["sphere", "shaken", "overlapping", "coarse", "fine"])
def test_compiled_build_equals_torch_build(sphere_tets, case, dtype):
    """The oracle of the compiled build (numba kernels, the CPU default) is the vectorised torch build: the same
    grid bit for bit on a real mesh, on one with inverted and overlapping tets (unsafe tets), on two overlapping
    copies plus a zero-volume tet, and at other cell sizes."""
    vertices, tets = sphere_tets
    settings = {}
    if case == "shaken":
        vertices = vertices + np.random.default_rng(4).normal(0, 0.04, vertices.shape)
    elif case == "overlapping":
        grid, cube = kuhn_grid(3)
        line = np.linspace(0, 1, 4)[:, None] * [1.0, 1.0, 0.0]
        vertices = np.concatenate([grid, grid + [0.13, 0.05, -0.07], line])
        tets = np.concatenate([cube + len(grid), cube, np.array([[0, 1, 2, 3]]) + 2 * len(grid)])
    elif case in ("coarse", "fine"):
        settings = {"cells_per_tet": 0.3 if case == "coarse" else 16.0}
    compiled = TetLocator(vertices, tets, dtype=dtype, kernel="numba", **settings)
    reference = TetLocator(vertices, tets, dtype=dtype, kernel="torch", **settings)
    assert_same_grid(compiled, reference)
    usable = compiled._table.usable
    if case in ("shaken", "overlapping"):  # the separating-axis test found unsafe tets
        assert torch.isinf(compiled._deep[usable]).any()
    else:
        assert torch.isfinite(compiled._deep[usable]).all()


def test_compiled_build_of_degenerate_and_empty_meshes():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0.0]])
    for kernel in ("numba", "torch"):
        locator = TetLocator(vertices, np.array([[0, 1, 2, 3]]), kernel=kernel)
        assert locator.n_entries == 0 and locator.box_bounds() is None
        assert not locator.boxed_cells(torch.ones(3, dtype=torch.float64), torch.ones(3, dtype=torch.float64), 4).any()
    assert_same_grid(
        TetLocator(vertices, np.array([[0, 1, 2, 3]]), kernel="numba"),
        TetLocator(vertices, np.array([[0, 1, 2, 3]]), kernel="torch"),
    )
