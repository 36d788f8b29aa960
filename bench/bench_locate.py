"""Point location in a tet mesh: TetLocator (uniform grid; compiled walk on the CPU) vs VTK's cell locator, exactness
vs brute force.

Anchor (docs/benchmarks.md): ``pyvista.UnstructuredGrid(...).find_containing_cell(points)`` on the same tets and the
same points (uniform in the tets' bounding box enlarged by 10 %, a mix of inside and outside), measured in the
same run. Meshes: real pytetwild tet meshes (``optimize=True, epsilon=5e-3``) of the decimated pymeshlab bunny
(~11k tets) and of an icosphere (~2k tets), cached in ``/tmp``. Exactness: tet ids of the grid answer vs
``locate_brute_force`` (the oracle) on the small mesh. Also timed: ``DeformationField.to_canonical`` on the
same number of points (the bunny proxy twisted about its vertical axis). Times are the best of a few runs (wall
clock); VTK is single-threaded, so TetLocator is reported with torch's default threads and with one thread.

    python bench/bench_locate.py [--quick]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from timing import best_of

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.bending.locate import TetLocator, locate_brute_force
from nerfedit_plugin.geometry.samples import sample_mesh_path
from nerfedit_plugin.geometry.tets import orient_tets

CACHE = Path("/tmp/nerfedit_bench_locate")


def tet_mesh(name: str) -> tuple[np.ndarray, np.ndarray]:
    """pytetwild tet mesh (reoriented to positive volume), cached as ``/tmp/nerfedit_bench_locate/<name>.npz``."""
    path = CACHE / f"{name}.npz"
    if path.is_file():
        data = np.load(path)
        return data["vertices"], data["tets"]
    import pymeshlab
    import pytetwild
    import trimesh

    if name == "bunny":
        meshes = pymeshlab.MeshSet()
        meshes.load_new_mesh(str(sample_mesh_path("bunny")))
        meshes.meshing_decimation_quadric_edge_collapse(targetfacenum=3000)
        vertices, faces, fac = meshes.current_mesh().vertex_matrix(), meshes.current_mesh().face_matrix(), 0.037
    else:
        sphere = trimesh.creation.icosphere(subdivisions=3)
        vertices, faces, fac = sphere.vertices, sphere.faces, 0.085
    vertices, tets = pytetwild.tetrahedralize(
        vertices, faces.astype(np.int32), edge_length_fac=fac, optimize=True, epsilon=5e-3, quiet=True
    )
    vertices = np.asarray(vertices, dtype=np.float64)
    tets = orient_tets(vertices, tets)
    CACHE.mkdir(exist_ok=True)
    np.savez(path, vertices=vertices, tets=tets)
    return vertices, tets


def uniform_points(vertices: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    lo, hi = vertices.min(0), vertices.max(0)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 * 1.1
    return np.random.default_rng(seed).uniform(centre - half, centre + half, (n, 3))


def bench_mesh(name: str, n_points: int, repeats: int, check: int) -> None:
    import pyvista as pv

    vertices, tets = tet_mesh(name)
    points = uniform_points(vertices, n_points)
    torch_points = torch.from_numpy(points).float()
    print(f"\n== {name}: {len(vertices)} vertices, {len(tets)} tets, {n_points / 1e6:g}M points")

    cells = np.hstack([np.full((len(tets), 1), 4), tets]).ravel()
    grid = pv.UnstructuredGrid(cells, np.full(len(tets), pv.CellType.TETRA, dtype=np.uint8), vertices)
    vtk = best_of(lambda: grid.find_containing_cell(points), max(1, repeats // 2), warmup=True)
    vtk_ids = grid.find_containing_cell(points)

    start = time.perf_counter()
    locator = TetLocator(vertices, tets)
    build = time.perf_counter() - start
    ours = best_of(lambda: locator.locate(torch_points), repeats, warmup=True)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    ours_1 = best_of(lambda: locator.locate(torch_points), repeats, warmup=True)
    torch.set_num_threads(threads)
    ids, _ = locator.locate(torch_points)
    vectorised = TetLocator(vertices, tets, kernel="torch")
    ours_torch = best_of(lambda: vectorised.locate(torch_points), repeats, warmup=True)

    print(f"VTK find_containing_cell   {n_points / vtk / 1e6:7.2f} M points/s  ({vtk:.3f} s)")
    print(
        f"TetLocator ({threads} threads)     {n_points / ours / 1e6:7.2f} M points/s  ({ours:.3f} s)  "
        f"build {build:.2f} s, grid {locator.grid_shape}, {locator.n_entries / len(tets):.1f} entries/tet"
    )
    print(f"TetLocator (1 thread)      {n_points / ours_1 / 1e6:7.2f} M points/s  ({ours_1:.3f} s)")
    print(
        f"TetLocator kernel='torch' {n_points / ours_torch / 1e6:7.2f} M points/s  ({ours_torch:.3f} s, "
        f"{threads} threads; the vectorised walk CUDA runs)"
    )
    print(f"ratio vs VTK: {vtk / ours:.1f}x ({threads} threads), {vtk / ours_1:.1f}x (1 thread)")
    inside = ids.numpy() >= 0
    print(f"inside {inside.mean():.1%}; inside/outside agreement with VTK {np.mean(inside == (vtk_ids >= 0)):.4%}")
    if check:
        subset = torch_points[:check]
        reference, _ = locate_brute_force(vertices, tets, subset)
        agree = (locator.locate(subset)[0] == reference).double().mean().item()
        print(f"exactness vs brute force on {check} points: {agree:.4%} identical tet ids")


def bench_to_canonical(name: str, n_points: int, repeats: int) -> None:
    vertices, tets = tet_mesh(name)
    centre = vertices.mean(0)
    angle = 2.0 * (vertices[:, 1] - centre[1])  # a twist about y
    c, s = np.cos(angle), np.sin(angle)
    d = vertices - centre
    twisted = centre + np.stack([c * d[:, 0] + s * d[:, 2], d[:, 1], -s * d[:, 0] + c * d[:, 2]], 1)
    field = DeformationField(vertices, tets, twisted[None])
    points = torch.from_numpy(uniform_points(twisted, n_points, seed=1)).float()
    start = time.perf_counter()
    field.to_canonical(points[:10])  # builds the frame and rest locators
    build = time.perf_counter() - start
    seconds = best_of(lambda: field.to_canonical(points), repeats, warmup=True)
    out = field.to_canonical(points)
    print(f"\n== DeformationField.to_canonical (twisted {name} proxy, {n_points / 1e6:g}M points)")
    print(
        f"{n_points / seconds / 1e6:.2f} M points/s ({seconds:.3f} s); locators built in {build:.2f} s; "
        f"mapped {out.inside.double().mean():.1%}, empty {out.empty.double().mean():.1%}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small mesh only, 200k points")
    args = parser.parse_args()
    import pyvista  # noqa: F401  one-time import stays out of the timings

    n_points, repeats = (200_000, 2) if args.quick else (1_000_000, 3)
    if not args.quick:
        bench_mesh("bunny", n_points, repeats, check=0)
    bench_mesh("sphere", n_points, repeats, check=20_000 if args.quick else 100_000)
    bench_to_canonical("sphere" if args.quick else "bunny", n_points, repeats)


if __name__ == "__main__":
    main()
