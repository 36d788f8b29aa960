"""TetProxy: orientation, exact embedding, enclosure, watertight cage, offsets, cache, bad input, scale and position
invariance, re-use of an edit's proxy."""

from __future__ import annotations

import dataclasses
import functools
import json
import subprocess
import sys
import textwrap

import igl
import numpy as np
import pytest
import torch
import trimesh

from nerfedit_plugin.bending.locate import locate_brute_force
from nerfedit_plugin.edit import proxy as proxy_module
from nerfedit_plugin.edit.proxy import (
    ProxyConfig,
    TetProxy,
    build_proxy,
    cached_proxy,
    min_distance_to_boundary,
    proxy_cache_key,
    resolve_offset,
    unit_frame,
)
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh, cluster_vertices, grid_cells
from nerfedit_plugin.geometry.tets import (
    DEGENERATE_VOLUME_RATIO,
    boundary_faces,
    clean_tets,
    distance_to_boundary,
    tet_signed_volumes,
)

FAST = ProxyConfig(cage_faces=400, edge_length_fac=0.1)


def sphere() -> SurfaceMesh:
    return SurfaceMesh.from_trimesh(trimesh.creation.icosphere(subdivisions=3))


def torus() -> SurfaceMesh:
    return SurfaceMesh.from_trimesh(trimesh.creation.torus(1.0, 0.3))


def two_spheres() -> SurfaceMesh:
    a = trimesh.creation.icosphere(subdivisions=2)
    b = trimesh.creation.icosphere(subdivisions=2).apply_translation([3.0, 0.0, 0.0])
    return SurfaceMesh.from_trimesh(trimesh.util.concatenate([a, b]))


def open_hemisphere() -> SurfaceMesh:
    """A scanned-like surface with a large hole (upper half of a sphere)."""
    full = trimesh.creation.icosphere(subdivisions=3)
    half = trimesh.Trimesh(full.vertices, full.faces[full.triangles_center[:, 2] > 0], process=False)
    half.remove_unreferenced_vertices()
    return SurfaceMesh.from_trimesh(half)


@functools.cache
def built(make) -> tuple[SurfaceMesh, TetProxy]:
    """One FAST build per test mesh, shared by the tests that only read it."""
    mesh = make()
    return mesh, build_proxy(mesh, FAST)


def assert_valid_proxy(proxy: TetProxy, mesh: SurfaceMesh, config: ProxyConfig = FAST) -> None:
    """Every invariant of the TetProxy contract, checked against independent oracles."""
    vertices, tets = proxy.vertices, proxy.tets
    assert vertices.dtype == np.float64 and tets.dtype == np.int64
    assert proxy.embed_tets.dtype == np.int64 and proxy.embed_bary.dtype == np.float64
    # positively oriented, no zero-volume tets, no unreferenced vertices
    volumes = tet_signed_volumes(vertices, tets)
    assert volumes.min() > DEGENERATE_VOLUME_RATIO * np.median(volumes)
    assert np.array_equal(np.unique(tets), np.arange(len(vertices)))
    # every surface vertex embedded; barycentrics recomputed independently (3x3 solve per vertex)
    assert proxy.embed_tets.shape == (mesh.n_vertices,) and proxy.embed_tets.min() >= 0
    corners = vertices[tets[proxy.embed_tets]]  # (V,4,3)
    edges = (corners[:, 1:] - corners[:, :1]).transpose(0, 2, 1)  # (V,3,3), columns b-a, c-a, d-a
    solved = np.linalg.solve(edges, (mesh.vertices - corners[:, 0])[:, :, None])[:, :, 0]
    oracle = np.concatenate([1.0 - solved.sum(1, keepdims=True), solved], axis=1)
    np.testing.assert_allclose(proxy.embed_bary, oracle, atol=1e-9)
    np.testing.assert_allclose(proxy.embed_bary.sum(1), 1.0, atol=1e-12)
    assert proxy.embed_bary.min() >= -1e-9  # inside its tet (the exact enclosure check)
    # A @ proxy vertices reproduces the surface
    reproduced = proxy.embedding_matrix() @ vertices
    assert proxy.embedding_matrix().shape == (mesh.n_vertices, len(vertices))
    assert np.abs(reproduced - mesh.vertices).max() <= 1e-9 * mesh.bbox_diagonal
    # the boundary surface is libigl's, oriented outward: it encloses exactly the tets' volume
    boundary = boundary_faces(tets)
    assert {tuple(f) for f in np.sort(boundary, 1)} == {tuple(f) for f in np.sort(igl.boundary_facets(tets)[0], 1)}
    tri = vertices[boundary] - vertices.mean(0)  # about the proxy: no cancellation far from the origin
    enclosed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    assert enclosed == pytest.approx(volumes.sum(), rel=1e-9)
    # margin: points min_margin x offset away from each surface vertex (6 axis directions) are inside tets too
    radius = 0.99 * config.min_margin * proxy.info["offset"]
    assert proxy.info["margin"] >= config.min_margin
    directions = np.concatenate([np.eye(3), -np.eye(3)])
    around = (mesh.vertices[:, None] + radius * directions).reshape(-1, 3)
    tet, _ = locate_brute_force(vertices, tets, torch.from_numpy(around), dtype=torch.float64)
    assert (tet >= 0).all()
    # the cage is watertight and encloses every surface vertex (generalised winding number ~ 1)
    assert proxy.cage.to_trimesh().is_watertight
    winding = igl.fast_winding_number(proxy.cage.vertices, proxy.cage.faces, mesh.vertices)
    assert winding.min() > 0.5


@pytest.mark.parametrize("make", [torus, two_spheres, open_hemisphere], ids=lambda f: f.__name__)
def test_proxy_invariants(make):
    mesh, proxy = built(make)
    assert_valid_proxy(proxy, mesh)
    assert proxy.info["offset"] == pytest.approx(0.02 * mesh.bbox_diagonal * 1.5 ** (proxy.info["attempts"] - 1))


def test_two_components_each_get_tets():
    mesh, proxy = built(two_spheres)
    left = proxy.embed_tets[mesh.vertices[:, 0] < 1.5]
    right = proxy.embed_tets[mesh.vertices[:, 0] > 1.5]
    side = proxy.vertices[proxy.tets][:, :, 0] > 1.5  # (K,4): tet corners right of the gap between the spheres
    assert (side.all(1) | ~side.any(1)).all()  # no tet bridges the gap: two separate blobs
    assert not side[left].any() and side[right].all()


def test_offset_from_camera_distance():
    """Also the invariants test of the sphere."""
    mesh = sphere()
    assert resolve_offset(mesh, FAST, camera_distance=4.0) == pytest.approx(0.05 * 4.0)
    assert resolve_offset(mesh, FAST) == pytest.approx(0.02 * mesh.bbox_diagonal)
    assert resolve_offset(mesh, dataclasses.replace(FAST, offset=0.3), camera_distance=4.0) == 0.3
    proxy = build_proxy(mesh, FAST, camera_distance=4.0)
    assert_valid_proxy(proxy, mesh)
    assert proxy.info["attempts"] == 1 and proxy.info["offset"] == pytest.approx(0.2)
    # the cage lies ~offset outside the unit sphere
    radii = np.linalg.norm(proxy.cage.vertices, axis=1)
    assert np.median(radii) == pytest.approx(1.2, abs=0.04)
    with pytest.raises(NerfEditError, match="camera distance"):
        resolve_offset(mesh, FAST, camera_distance=-1.0)


def test_retry_grows_offset_until_enclosed_with_margin():
    """An 8-face cage is an octahedron-like hull around the unit sphere: at offset 0.64 it cuts into the sphere
    (vertices outside), at 0.8 it holds it with ~0.09 x offset to spare (< min_margin 0.1), at 1 with ~0.17."""
    mesh = sphere()
    coarse = dataclasses.replace(FAST, cage_faces=8, offset=0.64, offset_growth=1.25, max_attempts=3, min_margin=0.1)
    proxy = build_proxy(mesh, coarse)
    assert proxy.info["attempts"] == 3 and proxy.info["offset"] == pytest.approx(1.0)
    assert_valid_proxy(proxy, mesh, coarse)
    with pytest.raises(NerfEditError, match="outside the tets"):
        build_proxy(mesh, dataclasses.replace(coarse, max_attempts=1))
    with pytest.raises(NerfEditError, match="inside the tet boundary"):
        build_proxy(mesh, dataclasses.replace(FAST, min_margin=0.95, max_attempts=1))


def test_unreferenced_vertex_is_embedded():
    base = trimesh.creation.icosphere(subdivisions=2)
    mesh = SurfaceMesh(np.vstack([base.vertices, [[2.5, 0.0, 0.0]]]), base.faces)
    proxy = build_proxy(mesh, FAST)
    assert_valid_proxy(proxy, mesh)


def test_clean_tets_reorients_and_drops_degenerate():
    vertices = np.array(
        [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [9, 9, 9], [0, 0, -1]], dtype=np.float64
    )
    tets = np.array([[0, 2, 1, 3], [0, 1, 2, 3], [0, 1, 2, 4], [0, 1, 2, 6]])  # negative, positive, flat, negative
    cleaned, new_tets, dropped = clean_tets(vertices, tets)
    assert dropped == 1 and len(new_tets) == 3
    np.testing.assert_allclose(tet_signed_volumes(cleaned, new_tets), [1 / 6] * 3)
    # vertex 4 (only in the flat tet) and 5 (unused) are gone; the rest keep their order
    np.testing.assert_array_equal(cleaned, vertices[[0, 1, 2, 3, 6]])
    np.testing.assert_array_equal(np.sort(cleaned[new_tets], axis=1), np.sort(vertices[tets[[0, 1, 3]]], axis=1))


def test_cache_hit_returns_identical_arrays_without_tetwild(tmp_path, monkeypatch):
    import pytetwild

    mesh = sphere()
    proxy, hit = cached_proxy(mesh, FAST, tmp_path)
    assert not hit
    assert (tmp_path / f"{proxy_cache_key(mesh, FAST)}.npz").is_file()

    def no_tetwild(*args, **kwargs):
        raise AssertionError("pytetwild ran on a cache hit")

    monkeypatch.setattr(pytetwild, "tetrahedralize", no_tetwild)
    again, hit = cached_proxy(mesh, FAST, tmp_path)
    assert hit
    for name in ("vertices", "tets", "embed_tets", "embed_bary"):
        assert np.array_equal(getattr(again, name), getattr(proxy, name))
    assert np.array_equal(again.cage.vertices, proxy.cage.vertices)
    assert np.array_equal(again.cage.faces, proxy.cage.faces)
    assert again.info == proxy.info
    # a changed parameter or mesh misses (and would have to run tetwild)
    with pytest.raises(AssertionError, match="cache hit"):
        cached_proxy(mesh, dataclasses.replace(FAST, epsilon=1e-2), tmp_path)
    with pytest.raises(AssertionError, match="cache hit"):
        cached_proxy(mesh.with_vertices(mesh.vertices * 1.01), FAST, tmp_path)
    # a corrupt cache entry is rebuilt (not trusted) and overwritten
    path = tmp_path / f"{proxy_cache_key(mesh, FAST)}.npz"
    path.write_bytes(b"not a zip")
    calls = []
    monkeypatch.setattr(proxy_module, "build_proxy", lambda *args: calls.append(args) or proxy)
    with pytest.warns(UserWarning, match=rf"{path.name}: .*; rebuilding the cache entry"):  # said once, not silent
        rebuilt, hit = cached_proxy(mesh, FAST, tmp_path)
    assert not hit and len(calls) == 1 and rebuilt is proxy
    assert np.array_equal(TetProxy.load(path).tets, proxy.tets)


def test_cache_key_tracks_mesh_and_parameters():
    mesh = sphere()
    key = proxy_cache_key(mesh, FAST)
    assert key == proxy_cache_key(sphere(), ProxyConfig(cage_faces=400, edge_length_fac=0.1))
    moved = mesh.vertices.copy()
    moved[0, 0] += 1e-12
    faces = mesh.faces.copy()
    faces[0] = faces[0, [1, 2, 0]]
    changed = [
        proxy_cache_key(SurfaceMesh(moved, mesh.faces), FAST),
        proxy_cache_key(SurfaceMesh(mesh.vertices, faces), FAST),
        proxy_cache_key(mesh, dataclasses.replace(FAST, epsilon=1e-2)),
        proxy_cache_key(mesh, dataclasses.replace(FAST, cage_faces=401)),
        proxy_cache_key(mesh, dataclasses.replace(FAST, edge_length_fac=0.09)),
        proxy_cache_key(mesh, dataclasses.replace(FAST, wrap_alpha_factor=2.0)),
        proxy_cache_key(mesh, dataclasses.replace(FAST, offset_bbox_fraction=0.03)),
        proxy_cache_key(mesh, FAST, camera_distance=4.0),
    ]
    assert len(set(changed + [key])) == len(changed) + 1
    # only the resolved offset matters: an explicit offset equal to the derived one is the same build
    same = dataclasses.replace(FAST, offset=resolve_offset(mesh, FAST))
    assert proxy_cache_key(mesh, same) == key
    assert proxy_cache_key(mesh, same, camera_distance=4.0) == key


def test_cache_key_names_the_wrap_clustering_only_where_it_applies():
    """Meshes below wrap_cluster_faces are wrapped as they are: their key ignores both clustering options (the keys
    of caches and edit folders from before the options stay valid); above it, wrap_cell is part of the key."""
    mesh = sphere()  # 1280 faces
    key = proxy_cache_key(mesh, FAST)
    assert proxy_cache_key(mesh, dataclasses.replace(FAST, wrap_cell=0.5, wrap_cluster_faces=1281)) == key
    assert proxy_cache_key(mesh, dataclasses.replace(FAST, wrap_cell=0.0, wrap_cluster_faces=10)) == key
    dense = [
        proxy_cache_key(mesh, dataclasses.replace(FAST, wrap_cell=c, wrap_cluster_faces=1280)) for c in (0.25, 0.5)
    ]
    assert len({key, *dense}) == 3


def test_clustered_wrap_gives_a_valid_proxy(monkeypatch):
    """A surface wrapped through its vertex clustering (wrap_cluster_faces lowered to the test mesh) still meets
    every invariant: the clustering moves the wrap input by a fraction of the cell, the margin is checked on the
    surface itself."""
    mesh = SurfaceMesh.from_trimesh(trimesh.creation.icosphere(subdivisions=5))  # edges ~1/100 of the diagonal
    config = dataclasses.replace(FAST, wrap_cluster_faces=1, wrap_cell=1.0)  # cells of 1/50 of it
    seen = []
    wrap = proxy_module.wrap_and_decimate
    monkeypatch.setattr(
        proxy_module, "wrap_and_decimate", lambda v, f, *a, **k: seen.append(len(f)) or wrap(v, f, *a, **k)
    )
    proxy = build_proxy(mesh, config)
    assert seen and seen[0] < len(mesh.faces) / 2  # the wrap got the clustering
    assert "cluster" in proxy.info["times"]
    assert_valid_proxy(proxy, mesh, config)


def test_cluster_vertices_merges_cells_and_keeps_lone_vertices_exact():
    rng = np.random.default_rng(0)
    mesh = torus()
    clustered = cluster_vertices(mesh, 0.1)
    cells, owner, low = grid_cells(mesh.vertices, 0.1)
    assert clustered.n_vertices == len(cells) < mesh.n_vertices
    for row in rng.choice(len(cells), 20, replace=False):  # each cluster is the mean of its cell's vertices
        members = mesh.vertices[owner == row]
        assert np.allclose(clustered.vertices[row], members.mean(0), rtol=0, atol=1e-15)
        assert (np.floor((members - low) / 0.1) == cells[row]).all()
    corners = owner[mesh.faces]
    kept = (corners[:, 0] != corners[:, 1]) & (corners[:, 1] != corners[:, 2]) & (corners[:, 2] != corners[:, 0])
    assert np.array_equal(clustered.faces, corners[kept])
    fine = cluster_vertices(mesh, 1e-6)  # every vertex alone in its cell: the mesh itself, bit for bit
    lone = grid_cells(mesh.vertices, 1e-6)[1]
    assert np.array_equal(fine.vertices[lone], mesh.vertices) and np.array_equal(fine.faces, lone[mesh.faces])


def test_grid_cells_sparse_and_dense_agree_with_unique():
    points = np.random.default_rng(1).normal(size=(5000, 3))
    for cell in (0.05, 1e-4):  # a grid small enough for flags, and one that needs the sort
        cells, owner, low = grid_cells(points, cell)
        ijk = np.floor((points - low) / cell).astype(np.int64)
        expected, inverse = np.unique(ijk, axis=0, return_inverse=True)
        assert np.array_equal(cells, expected) and np.array_equal(owner, inverse.ravel())


@pytest.mark.parametrize("make", [torus, open_hemisphere], ids=lambda f: f.__name__)
def test_pruned_margin_is_the_full_minimum_bit_for_bit(make, monkeypatch):
    mesh, proxy = built(make)
    monkeypatch.setattr(proxy_module, "PRUNED_MARGIN_POINTS", 0)
    full = float(distance_to_boundary(proxy.vertices, proxy.tets, mesh.vertices).min())
    for cell in (0.01, 0.05, 0.3):
        assert min_distance_to_boundary(proxy.vertices, proxy.tets, mesh.vertices, cell * mesh.bbox_diagonal) == full


def test_save_load_roundtrip_and_bad_files(tmp_path):
    mesh, proxy = built(two_spheres)
    path = tmp_path / "proxy.npz"
    proxy.save(path)
    loaded = TetProxy.load(path)
    assert_valid_proxy(loaded, mesh)
    assert (loaded.embedding_matrix() != proxy.embedding_matrix()).nnz == 0
    with pytest.raises(NerfEditError, match="not found"):
        TetProxy.load(tmp_path / "missing.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(NerfEditError, match="junk.npz"):
        TetProxy.load(tmp_path / "junk.npz")
    np.savez(tmp_path / "other.npz", vertices=np.zeros((3, 3)))
    with pytest.raises(NerfEditError, match="other.npz"):
        TetProxy.load(tmp_path / "other.npz")


def test_bad_input_raises(tmp_path):
    empty = SurfaceMesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    with pytest.raises(NerfEditError, match="empty"):
        build_proxy(empty, FAST)
    with pytest.raises(NerfEditError, match="empty"):
        cached_proxy(empty, FAST, tmp_path)
    points_only = SurfaceMesh(np.random.default_rng(0).normal(size=(5, 3)), np.zeros((0, 3), dtype=np.int64))
    with pytest.raises(NerfEditError, match="no triangles"):
        build_proxy(points_only, FAST)
    collapsed = SurfaceMesh(np.ones((3, 3)), np.array([[0, 1, 2]]))
    with pytest.raises(NerfEditError, match="coincide"):
        build_proxy(collapsed, FAST)
    for field, value in [("offset", -1.0), ("cage_faces", 2), ("epsilon", 0.0), ("offset_growth", 1.0)]:
        with pytest.raises(NerfEditError, match=f"ProxyConfig.{field}: must be"):
            build_proxy(sphere(), dataclasses.replace(FAST, **{field: value}))


# ---- scale and position -----------------------------------------------------------------------------------------

COARSE = ProxyConfig(cage_faces=200, edge_length_fac=0.2)
SIMILARITIES = [(1e-6, 0.0), (1.0, 0.0), (1e6, 0.0), (1.0, 1e5)]  # (scale, offset of every coordinate)


def test_mesher_input_is_the_same_at_any_scale_and_position(monkeypatch):
    """What the scale-sensitive steps (wrap, decimation, pytetwild, margin) get is the mesh in its unit frame and the
    offset in unit-frame units: the same, to rounding, whatever the mesh's size and position. (The cage itself is not
    compared: the alpha wrap amplifies a 1e-16 change of its input into ~offset/2, and pytetwild is random.)"""
    base = SurfaceMesh.load("sample:cow")
    seen = []

    class Stop(Exception):
        pass

    def spy(mesh, offset, config, times=None):
        seen.append((mesh.vertices.copy(), mesh.faces.copy(), offset))
        raise Stop

    monkeypatch.setattr(proxy_module, "build_cage", spy)
    for scale, shift in SIMILARITIES:
        with pytest.raises(Stop):
            build_proxy(base.with_vertices(base.vertices * scale + shift), COARSE)
    reference = seen[SIMILARITIES.index((1.0, 0.0))]
    assert np.abs(reference[0]).max() <= 0.5 + 1e-12 and np.linalg.norm(np.ptp(reference[0], 0)) == pytest.approx(1)
    for vertices, faces, offset in seen:
        np.testing.assert_array_equal(faces, base.faces)
        # 1e5 + a mesh 2 across: the input itself is only known to 1e5 x 2^-52 ~ 1e-11 (5e-12 of the diagonal)
        assert np.abs(vertices - reference[0]).max() < 2e-11
        assert offset == pytest.approx(COARSE.offset_bbox_fraction, rel=1e-12)


def test_tiny_mesh_builds_in_a_subprocess():
    """The bone scaled by 1e-6 segfaulted inside pytetwild (exit 139) before the unit frame; a subprocess, so that a
    crash fails this test instead of killing pytest."""
    script = textwrap.dedent(
        """
        import json
        import numpy as np
        from nerfedit_plugin.edit.proxy import ProxyConfig, build_proxy
        from nerfedit_plugin.geometry.mesh import SurfaceMesh
        base = SurfaceMesh.load("sample:bone")
        mesh = base.with_vertices(base.vertices * 1e-6)
        proxy = build_proxy(mesh, ProxyConfig(cage_faces=200, edge_length_fac=0.2))
        error = np.abs(proxy.embedding_matrix() @ proxy.vertices - mesh.vertices).max() / mesh.bbox_diagonal
        print(json.dumps({"info": proxy.info, "inside": bool((proxy.embed_tets >= 0).all()), "error": error,
                          "diagonal": mesh.bbox_diagonal}))
        """
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, f"exit {result.returncode}: {result.stderr[-2000:]}"
    out = json.loads(result.stdout.strip().splitlines()[-1])
    assert out["inside"] and out["error"] < 1e-9
    assert out["info"]["margin"] >= COARSE.min_margin
    assert out["info"]["offset"] == pytest.approx(0.02 * out["diagonal"] * 1.5 ** (out["info"]["attempts"] - 1))


@pytest.mark.parametrize("scale, shift", [(1e6, 0.0), (1.0, 1e5)], ids=["1e6", "far"])
def test_proxy_valid_when_large_or_far_from_origin(capsule, scale, shift):
    """Every invariant of the contract holds with tolerances relative to the mesh's size (Open3D's float32 margin
    at 1e5 alone would be off by ~1e-2, half the offset), and the proxy in its unit frame is where the unit-size one
    is: its bounding box within the offset plus tetwild's envelope of the cage's."""
    mesh = capsule.with_vertices(capsule.vertices * scale + shift)
    proxy = build_proxy(mesh, COARSE)
    assert_valid_proxy(proxy, mesh, COARSE)
    centre, size = unit_frame(mesh.vertices)
    assert proxy.info["unit_frame"] == {"centre": centre.tolist(), "scale": size}
    unit = (proxy.vertices - centre) / size
    reference = (capsule.vertices - unit_frame(capsule.vertices)[0]) / capsule.bbox_diagonal
    offset = proxy.info["offset"] / size
    assert np.all(unit.min(0) <= reference.min(0) - COARSE.min_margin * offset)
    assert np.all(unit.max(0) >= reference.max(0) + COARSE.min_margin * offset)
    assert np.all(unit.min(0) >= reference.min(0) - 2 * offset - COARSE.epsilon)
    assert np.all(unit.max(0) <= reference.max(0) + 2 * offset + COARSE.epsilon)


# ---- re-use of an edit's proxy ----------------------------------------------------------------------------------


def test_rerun_with_proxy_from_is_bit_identical(tmp_path, capsule):
    """pytetwild is random (two cold builds differ), so a re-run reuses the proxy of the edit: in a fresh process,
    cold cache, the same deformation.npz byte for byte. Another mesh or other proxy settings are refused."""
    from nerfedit_plugin.cli.app import main
    from nerfedit_plugin.pipeline.edit import reuse_proxy

    capsule.save(tmp_path / "capsule.ply")
    edit = {
        "handles": [
            {"select": {"box": {"min": [-1, -1, -1.1], "max": [1, 1, -0.6]}}, "fixed": True},
            {"select": {"box": {"min": [-1, -1, 0.6], "max": [1, 1, 1.1]}}, "transform": {"translate": [0, 0.3, 0]}},
        ],
        "frames": 1,
    }
    (tmp_path / "edit.json").write_text(json.dumps(edit))
    first = tmp_path / "first"
    options = ["--proxy.cage-faces", "200", "--proxy.edge-length-fac", "0.2", "--cache-dir", str(tmp_path / "c1")]
    argv = ["edit", "--mesh", str(tmp_path / "capsule.ply"), "--edit", str(tmp_path / "edit.json"), *options]
    assert main([*argv, "--out", str(first)]) == 0
    again = tmp_path / "again"
    rerun = [*argv, "--cache-dir", str(tmp_path / "c2"), "--proxy-from", str(first), "--out", str(again)]
    script = f"import sys; from nerfedit_plugin.cli.app import main; sys.exit(main({rerun!r}))"
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert (again / "deformation.npz").read_bytes() == (first / "deformation.npz").read_bytes()
    assert not (tmp_path / "c2").exists()  # nothing meshed
    report = json.loads((again / "report.json").read_text())["proxy"]
    assert (
        report["reused_from"] == str(first)
        and report["key"] == json.loads((first / "report.json").read_text())["proxy"]["key"]
    )
    assert "proxy_from" in (again / "config.yml").read_text()  # --load-config of the re-run re-uses it too
    # the proxy is the build's: same tets, same embedding (recomputed from the same arrays)
    built = TetProxy.load(next((tmp_path / "c1").glob("*.npz")))
    rest = SurfaceMesh.load(tmp_path / "capsule.ply")  # as the command read it
    reused = reuse_proxy(first, rest, COARSE)
    for name in ("vertices", "tets", "embed_tets", "embed_bary"):
        assert np.array_equal(getattr(reused, name), getattr(built, name))
    with pytest.raises(NerfEditError, match="another mesh or other proxy settings"):
        reuse_proxy(first, rest, FAST)
    with pytest.raises(NerfEditError, match="another mesh or other proxy settings"):
        reuse_proxy(first, rest.with_vertices(rest.vertices * 1.01), COARSE)
    with pytest.raises(NerfEditError, match="records no proxy key"):
        reuse_proxy(tmp_path, rest, COARSE)
    with pytest.raises(NerfEditError, match="no such edit folder or deformation.npz"):
        reuse_proxy(tmp_path / "nowhere", rest, COARSE)


def test_ctrl_c_after_pytetwild_still_reaches_python():
    """pytetwild resets the process's SIGINT handler to the default (Ctrl-C would kill the edit with its staging
    folder left behind); tetrahedralize installs Python's again."""
    code = (
        "import os, signal, sys, trimesh\n"
        "from nerfedit_plugin.edit.proxy import ProxyConfig, tetrahedralize\n"
        "from nerfedit_plugin.geometry.mesh import SurfaceMesh\n"
        "seen = []\n"
        "signal.signal(signal.SIGINT, lambda *a: seen.append(1))\n"
        "ball = trimesh.creation.icosphere(2)\n"
        "tetrahedralize(SurfaceMesh(ball.vertices, ball.faces), ProxyConfig())\n"
        "os.kill(os.getpid(), signal.SIGINT)\n"
        "print('handled' if seen else 'missed')\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout.strip() == "handled", (done.returncode, done.stderr)
