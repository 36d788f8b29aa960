"""Multiresolution ARAP (``arap`` deformer, ``multiresolution``; :mod:`nerfedit_plugin.geometry.multires`) and the
Deformer contract's bind cache.

Oracles: the direct solve (a coarse level equal to the mesh gives it bit for bit; a bent bumpy cylinder stays near
it), exact rigid motions (identity and rigid edits, the bumps of a rigidly moved bumpy sphere), exact handles.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from deformers.arap import ArapConfig
from nerfedit_plugin.edit.deformer import BindCache
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.arap import ArapSolver
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.multires import MultiresArap, coarse_level, rigid_fit


def bumpy_sphere(subdivisions: int = 5) -> SurfaceMesh:
    """An icosphere of radius 1 with radial bumps of amplitude 0.03 (10242 vertices at 5 subdivisions)."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    p = np.asarray(sphere.vertices, dtype=np.float64)
    bumps = 1.0 + 0.03 * np.sin(9 * p[:, 0]) * np.sin(9 * p[:, 1]) * np.sin(9 * p[:, 2])
    return SurfaceMesh(p * bumps[:, None], np.asarray(sphere.faces))


def bumpy_cylinder(rings: int = 121, around: int = 48) -> SurfaceMesh:
    """An open tube of radius 0.2 along z ∈ [0, 2], its radius modulated by bumps of amplitude 0.01."""
    z = np.linspace(0.0, 2.0, rings)
    a = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    zz, aa = np.meshgrid(z, a, indexing="ij")
    radius = 0.2 + 0.01 * np.sin(6 * aa) * np.sin(20 * zz)
    vertices = np.stack([radius * np.cos(aa), radius * np.sin(aa), zz], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(rings - 1), np.arange(around), indexing="ij")
    v00, v01 = i * around + j, i * around + (j + 1) % around
    v10, v11 = v00 + around, v01 + around
    faces = np.concatenate([np.stack([v00, v01, v11], -1).reshape(-1, 3), np.stack([v00, v11, v10], -1).reshape(-1, 3)])
    return SurfaceMesh(vertices, faces)


def spec(handles: list[dict]) -> object:
    return parse_edit_spec({"handles": handles}, ("handles",))


def deform(mesh: SurfaceMesh, edit, cache: BindCache | None = None, **options) -> tuple[np.ndarray, object]:
    model = ArapConfig(**options).setup()
    if cache is not None:
        model.bind_cache = cache
    model.bind(mesh, edit)
    return model.deform(), model


BOX_LOW = {"box": {"min": [-2, -2, -2], "max": [2, 2, -0.5]}}
BOX_HIGH = {"box": {"min": [-2, -2, 0.5], "max": [2, 2, 2]}}


def bend(degrees: float, lift: float):
    """The tube's lower end fixed, its upper end turned by ``degrees`` about x and moved by ``lift`` along y."""
    turn = {"rotate": {"axis": [1, 0, 0], "degrees": degrees, "center": [0, 0, 1.9]}, "translate": [0, lift, 0]}
    return spec(
        [
            {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, 0.2]}}, "fixed": True},
            {"select": {"box": {"min": [-1, -1, 1.8], "max": [1, 1, 3]}}, "transform": turn},
        ]
    )


BEND = bend(40, 0.3)


@pytest.fixture(scope="module")
def cylinder() -> SurfaceMesh:
    return bumpy_cylinder()


def test_coarse_level_equal_to_the_mesh_gives_the_direct_solve(cylinder):
    direct, _ = deform(cylinder, BEND, multiresolution="off")
    multires, model = deform(cylinder, BEND, multiresolution="on", coarse_vertices=cylinder.n_vertices)
    assert model.report()["path"] == "multiresolution" and model.level.is_identity
    assert np.array_equal(multires, direct)


def test_bent_bumpy_cylinder_stays_as_near_the_direct_solve_as_a_coarser_direct_solve(cylinder):
    """ARAP's minimiser depends on the resolution (its bending stiffness falls like the squared edge length): the
    multiresolution result is compared with the direct solve of the same mesh within the gap between that and the
    direct solve of the same tube at half the resolution (its vertices a subset of the fine ones)."""
    edit = bend(20, 0.05)
    direct, _ = deform(cylinder, edit, multiresolution="off")
    multires, model = deform(cylinder, edit, multiresolution="on", coarse_vertices=1500)
    assert model.report()["coarse"]["vertices"] == pytest.approx(1500, rel=0.15)
    handles, targets = edit.handle_targets(cylinder.vertices, cylinder.faces)
    assert np.array_equal(multires[0, handles], targets[0])  # exactly, not to 1e-9
    half = bumpy_cylinder(61, 24)
    shared = (np.arange(0, 121, 2)[:, None] * 48 + np.arange(0, 48, 2)[None]).ravel()
    assert np.allclose(cylinder.vertices[shared], half.vertices, rtol=0, atol=1e-15)
    coarser, _ = deform(half, edit, multiresolution="off")
    diagonal = cylinder.bbox_diagonal
    resolution_gap = np.linalg.norm(direct[0, shared] - coarser[0], axis=1) / diagonal
    error = np.linalg.norm(multires[0] - direct[0], axis=1) / diagonal
    assert error.mean() <= 1.25 * resolution_gap.mean(), (error.mean(), resolution_gap.mean())
    assert error.max() <= 1.25 * resolution_gap.max(), (error.max(), resolution_gap.max())
    # the bumps ride along: per ring, the sin(6a) Fourier mode of the radius (the bumps; orthogonal to the tube's
    # ovalisation) keeps its rest amplitude 0.01 sin(20 z) to 5 % of the bumps' height (the direct solve: 10 %)
    angles = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)

    def bumps(positions: np.ndarray) -> np.ndarray:
        rings = positions.reshape(121, 48, 3)
        radius = np.linalg.norm(rings - rings.mean(1, keepdims=True), axis=2)
        return 2.0 / 48 * radius @ np.sin(6 * angles)

    rest = bumps(cylinder.vertices)
    assert np.abs(rest - 0.01 * np.sin(20 * np.linspace(0, 2, 121))).max() < 1e-3
    assert np.abs(bumps(multires[0]) - rest).max() < 5e-4


def test_polish_walks_the_carried_surface_to_the_direct_minimiser(cylinder):
    """``polish`` N: N fine L-BFGS iterations from the carried surface: the fine energy falls monotonically in N, the
    result nears the direct solve (the minimiser of the same energy), the handles stay exact; 0 is the carry."""
    edit = bend(20, 0.05)
    direct, direct_model = deform(cylinder, edit, multiresolution="off", tolerance=1e-10, max_iterations=2000)
    handles, targets = edit.handle_targets(cylinder.vertices, cylinder.faces)
    fine = ArapSolver(cylinder.vertices, cylinder.faces, fixed=handles)
    carried, _ = deform(cylinder, edit, multiresolution="on", coarse_vertices=1500)
    energies, errors = [fine.energy(carried[0])], [np.abs(carried[0] - direct[0]).max()]
    for n in (5, 40):
        polished, model = deform(cylinder, edit, multiresolution="on", coarse_vertices=1500, polish=n, tolerance=0)
        assert np.array_equal(polished[0, handles], targets[0])
        report = model.report()["per_frame"][0]["polish"]
        assert report["iterations"] == n and report["energy"] == pytest.approx(fine.energy(polished[0]), rel=1e-9)
        energies.append(fine.energy(polished[0]))
        errors.append(np.abs(polished[0] - direct[0]).max())
    assert energies[0] > energies[1] > energies[2] >= direct_model.results[0].energies[-1] * (1 - 1e-9)
    assert errors[2] < 0.3 * errors[0], errors
    unpolished, _ = deform(cylinder, edit, multiresolution="on", coarse_vertices=1500, polish=0)
    assert np.array_equal(unpolished, carried)


def rigid_motion() -> tuple[np.ndarray, np.ndarray, dict]:
    rotvec = np.array([0.3, -0.5, 0.8])
    rotation = Rotation.from_rotvec(rotvec).as_matrix()
    centre, shift = np.array([0.1, 0.2, -0.3]), np.array([0.5, -0.2, 0.7])
    transform = {
        "rotate": {"axis": list(rotvec / np.linalg.norm(rotvec)), "degrees": float(np.degrees(np.linalg.norm(rotvec)))},
        "translate": list(shift),
    }
    transform["rotate"]["center"] = list(centre)
    return rotation, centre + shift - rotation @ centre, transform


def test_identity_and_rigid_edits_are_exact_and_keep_the_bumps():
    sphere = bumpy_sphere()
    identity = spec([{"select": BOX_LOW, "fixed": True}, {"select": BOX_HIGH, "transform": {"translate": [0, 0, 0]}}])
    out, _ = deform(sphere, identity, multiresolution="on", coarse_vertices=600)
    assert np.abs(out[0] - sphere.vertices).max() <= 1e-12
    rotation, shift, transform = rigid_motion()
    rigid = spec([{"select": BOX_LOW, "transform": transform}, {"select": BOX_HIGH, "transform": transform}])
    out, model = deform(sphere, rigid, multiresolution="on", coarse_vertices=600)
    assert model.level.coarse.n_vertices < sphere.n_vertices / 10  # the bumps live below the coarse level
    expected = sphere.vertices @ rotation.T + shift
    assert np.abs(out[0] - expected).max() <= 1e-12
    centre = shift  # the sphere's centre, moved
    bumps = np.linalg.norm(out[0] - centre, axis=1) - np.linalg.norm(sphere.vertices, axis=1)
    assert np.abs(bumps).max() <= 1e-6


def test_auto_threshold_and_override(cylinder):
    _, model = deform(cylinder, BEND)
    assert model.report()["path"] == "direct"  # 5808 vertices: below the threshold
    _, model = deform(cylinder, BEND, coarse_vertices=1500, coarse_above=1000)
    assert model.report()["path"] == "multiresolution"
    _, model = deform(cylinder, BEND, multiresolution="off")
    assert model.report()["path"] == "direct"
    with pytest.raises(NerfEditError, match="multiresolution"):
        ArapConfig(multiresolution="maybe")


def test_a_part_without_handle_is_an_error(cylinder):
    shifted = cylinder.with_vertices(cylinder.vertices + [5.0, 0, 0])
    two = SurfaceMesh(
        np.concatenate([cylinder.vertices, shifted.vertices]),
        np.concatenate([cylinder.faces, cylinder.faces + cylinder.n_vertices]),
    )
    with pytest.raises(NerfEditError, match="no fixed vertex"):
        deform(two, BEND, multiresolution="on", coarse_vertices=3000)


def test_bind_cache_keeps_the_coarse_level(cylinder, tmp_path):
    from nerfedit_plugin.edit.deformer import mesh_digest

    cache = BindCache(tmp_path, mesh_digest(cylinder))
    first, model = deform(cylinder, BEND, cache, multiresolution="on", coarse_vertices=1500)
    assert model.report()["coarse"]["cached"] is False
    again, model = deform(cylinder, BEND, cache, multiresolution="on", coarse_vertices=1500)
    assert model.report()["coarse"]["cached"] is True
    assert np.array_equal(first, again)
    _, model = deform(cylinder, BEND, cache, multiresolution="on", coarse_vertices=1200)
    assert model.report()["coarse"]["cached"] is False  # other parameters, other entry
    assert len(list(tmp_path.glob("bind-coarse-level-*.npz"))) == 2


def test_bind_cache_contract(tmp_path):
    calls = []

    def build():
        calls.append(1)
        return {"a": np.arange(3.0)}

    assert BindCache().fetch("k", {}, build)[1] is False and BindCache().fetch("k", {}, build)[1] is False
    assert len(calls) == 2  # no folder: nothing stored
    cache = BindCache(tmp_path, "digest")
    arrays, hit = cache.fetch("k", {"n": 1}, build)
    assert not hit and np.array_equal(cache.fetch("k", {"n": 1}, build)[0]["a"], arrays["a"])
    assert len(calls) == 3
    assert not BindCache(tmp_path, "other").fetch("k", {"n": 1}, build)[1]  # another mesh
    (entry,) = tmp_path.glob(f"bind-k-{cache.key('k', {'n': 1})}.npz")
    entry.write_bytes(b"not a zip")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert not cache.fetch("k", {"n": 1}, build)[1]
    assert "unreadable" in str(caught[0].message)
    assert cache.fetch("k", {"n": 1}, build)[1]


def test_vertex_rotations_follow_a_rigid_motion(cylinder):
    rotation, shift, _ = rigid_motion()
    solver = ArapSolver(cylinder.vertices, cylinder.faces, fixed=[0])
    rotations = solver.vertex_rotations(cylinder.vertices @ rotation.T + shift)
    assert np.abs(rotations - rotation).max() < 1e-12
    fit = rigid_fit(cylinder.vertices, cylinder.vertices @ rotation.T + shift)
    assert np.abs(fit[0] - rotation).max() < 1e-12 and fit[2] < 1e-12


def test_partial_clusters_take_the_handles_similarity(cylinder):
    level = coarse_level(cylinder, 1500)
    rotation, shift, transform = rigid_motion()
    edit = spec([{"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, 1.03]}}, "transform": transform}])
    handles, targets = edit.handle_targets(cylinder.vertices, cylinder.faces)
    solver = MultiresArap(level, cylinder, handles)
    coarse = solver.coarse_targets(targets)[0]
    expected = level.coarse.vertices[solver.fixed] @ rotation.T + shift
    assert np.abs(coarse - expected).max() < 1e-9


def test_report_json_records_the_path(cylinder, tmp_path):
    from nerfedit_plugin.pipeline.edit import run_edit

    path = tmp_path / "edit.json"
    path.write_text(
        json.dumps(
            {
                "handles": [
                    {"select": BOX_LOW, "fixed": True},
                    {"select": BOX_HIGH, "transform": {"translate": [0.05, 0, 0]}},
                ]
            }
        )
    )
    mesh = bumpy_sphere(3)
    config = ArapConfig(multiresolution="on", coarse_vertices=300)
    for cached in (False, True):
        report = run_edit(mesh, config, path, tmp_path / f"out{cached}", cache_dir=tmp_path / "cache").report
        recorded = json.loads((tmp_path / f"out{cached}" / "report.json").read_text())["deformer_report"]
        assert recorded["path"] == "multiresolution" and recorded["coarse"]["cached"] is cached
        assert recorded["per_frame"][0]["handle_gap"] >= 0 and recorded["detail_max"] > 0
        assert report["proxy"]["cached"] is cached
