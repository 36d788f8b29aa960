"""ARAP solver vs libigl (docs/benchmarks.md), both ratios measured in this run.

1. Surface ARAP (SPOKES_AND_RIMS) on the pymeshlab bunny with ``configs/arap_bunny_head.json`` (bottom fixed,
   head and ears rotated), and its Loop subdivisions (``--levels 0 1``: 28k and 112k vertices): wall time
   (precompute + iterations) until our solver stops (relative energy decrease < 1e-6; ``--method``, default the
   ``arap`` deformer's L-BFGS) vs libigl's ``arap_precomputation`` + ``arap_solve`` iterated until its energy
   reaches ours (or stops decreasing, or hits the iteration cap). Target ratio ≤ 0.5.
2. Tet ARAP (ELEMENTS) on a pytetwild sphere (27k vertices, 155k tets; cached in /tmp): precompute + 10 iterations,
   both. Target ratio ≤ 0.5.

Usage: ``python bench/bench_arap.py [--quick] [--levels 0 1] [--method lbfgs|anderson]`` (quick: bunny decimated to
~5k vertices, ~4k-vertex tets).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import igl
import numpy as np
import pymeshlab
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.geometry.arap import ArapSolver
from nerfedit_plugin.geometry.tets import orient_tets

ROOT = Path(__file__).resolve().parents[1]
TOLERANCE = 1e-6


def bunny(quick: bool, level: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The pymeshlab bunny, decimated (``quick``) or after ``level`` Loop subdivisions."""
    ms = pymeshlab.MeshSet()
    ms.load_new_mesh(os.path.join(os.path.dirname(pymeshlab.__file__), "tests", "sample_meshes", "bunny.obj"))
    if quick:
        ms.meshing_decimation_quadric_edge_collapse(targetfacenum=10000, preservenormal=True)
    elif level:
        ms.meshing_surface_subdivision_loop(iterations=level, threshold=pymeshlab.PercentageValue(0))
    mesh = ms.current_mesh()
    return mesh.vertex_matrix().astype(np.float64), mesh.face_matrix().astype(np.int64)


def sphere_tets(quick: bool) -> tuple[np.ndarray, np.ndarray]:
    """pytetwild tetrahedralisation of an icosphere (cached), positively oriented."""
    import pytetwild
    import trimesh

    factor = 0.035 if quick else 0.021
    cache = Path(f"/tmp/nerfedit_bench_sphere_tets_{factor}.npz")
    if not cache.exists():
        sphere = trimesh.creation.icosphere(3)
        faces = np.asarray(sphere.faces, dtype=np.int32)
        vertices, tets = pytetwild.tetrahedralize(
            np.asarray(sphere.vertices), faces, edge_length_fac=factor, optimize=True, epsilon=5e-3
        )
        np.savez(cache, vertices=vertices, tets=tets)
    data = np.load(cache)
    vertices = data["vertices"].astype(np.float64)
    return vertices, orient_tets(vertices, data["tets"])


def run_ours(vertices, elements, handles, targets, energy: str | None = None, **solve):
    """Our solver, built (the precompute) and run: ``(solver, result, precompute seconds, total seconds)``."""
    start = time.perf_counter()
    solver = ArapSolver(vertices, elements, energy=energy, fixed=handles)
    precompute = time.perf_counter() - start
    ours = solver.solve(targets, **solve)
    return solver, ours, precompute, time.perf_counter() - start


def igl_precompute(vertices, elements, handles, energy, max_iter: int) -> tuple[igl.ARAPData, float]:
    """libigl's ``arap_precomputation``: ``(data, seconds)``."""
    start = time.perf_counter()
    data = igl.ARAPData()
    data.energy = energy
    data.max_iter = max_iter
    igl.arap_precomputation(vertices, elements, 3, handles.astype(np.int32), data)
    return data, time.perf_counter() - start


def bench_surface(quick: bool, level: int, method: str) -> float:
    vertices, faces = bunny(quick, level)
    scale = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    handles, targets = load_edit_spec(ROOT / "configs" / "arap_bunny_head.json").handle_targets(vertices)
    targets = targets[-1]

    solver, ours, precompute, ours_time = run_ours(
        vertices, faces, handles, targets, max_iterations=1000, tolerance=TOLERANCE, method=method
    )
    print(
        f"surface ARAP ({method}), bunny {len(vertices)} vertices / {len(faces)} faces, {len(handles)} handle vertices"
    )
    print(
        f"  ours:   precompute {precompute:.2f} s, {ours.iterations} iterations {ours_time - precompute:.2f} s, "
        f"total {ours_time:.2f} s, energy {ours.energies[-1]:.9g} (converged={ours.converged})"
    )

    data, igl_setup = igl_precompute(vertices, faces, handles, igl.ARAP_ENERGY_TYPE_SPOKES_AND_RIMS, 10)
    current = vertices.copy()
    current[handles] = targets
    energy, iterations, igl_time, cap = solver.energy(current), 0, igl_setup, 6000 if not quick else 1500
    reason = "iteration cap"
    while iterations < cap:
        start = time.perf_counter()
        current = igl.arap_solve(targets, data, current)
        igl_time += time.perf_counter() - start
        iterations += data.max_iter
        previous, energy = energy, solver.energy(current)  # not timed
        if energy <= ours.energies[-1]:
            reason = "reached our energy"
            break
        if previous - energy <= data.max_iter * TOLERANCE * abs(previous):
            reason = "stopped decreasing"
            break
    difference = np.abs(current - ours.vertices).max() / scale
    print(
        f"  libigl: precompute {igl_setup:.2f} s, {iterations} iterations {igl_time - igl_setup:.2f} s, "
        f"total {igl_time:.2f} s, energy {energy:.9g} ({reason})"
    )
    ratio = ours_time / igl_time
    print(f"  max vertex difference ours vs libigl: {difference:.2e} x bbox diagonal")
    print(f"  RATIO surface (ours / libigl, time to converged energy) = {ratio:.3f}  (target <= 0.5)")
    return ratio


def bench_tets(quick: bool) -> float:
    vertices, tets = sphere_tets(quick)
    fixed = np.flatnonzero(vertices[:, 1] < -0.8)
    moved = np.flatnonzero(vertices[:, 1] > 0.8)
    handles = np.concatenate([fixed, moved])
    rot = Rotation.from_rotvec([np.radians(30.0), 0, 0]).as_matrix()
    centre = vertices[moved].mean(0)
    targets = np.concatenate([vertices[fixed], (vertices[moved] - centre) @ rot.T + centre + [0, 0.2, 0]])
    iterations = 10

    solver, ours, precompute, ours_time = run_ours(
        vertices, tets, handles, targets, "elements", max_iterations=iterations, tolerance=0.0
    )
    print(f"tet ARAP (ELEMENTS), pytetwild sphere {len(vertices)} vertices / {len(tets)} tets, {len(handles)} handles")
    print(
        f"  ours:   precompute {precompute:.2f} s, {ours.iterations} iterations {ours_time - precompute:.2f} s, "
        f"total {ours_time:.2f} s, energy {ours.energies[-1]:.9g}"
    )

    data, igl_setup = igl_precompute(vertices, tets, handles, igl.ARAP_ENERGY_TYPE_ELEMENTS, iterations)
    initial = vertices.copy()
    initial[handles] = targets
    start = time.perf_counter()
    result = igl.arap_solve(targets, data, initial)
    igl_time = igl_setup + time.perf_counter() - start
    print(
        f"  libigl: precompute {igl_setup:.2f} s, {iterations} iterations {igl_time - igl_setup:.2f} s, "
        f"total {igl_time:.2f} s, energy {solver.energy(result):.9g}"
    )
    ratio = ours_time / igl_time
    print(f"  RATIO tets (ours / libigl, precompute + {iterations} iterations) = {ratio:.3f}  (target <= 0.5)")
    return ratio


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smaller meshes")
    parser.add_argument("--levels", type=int, nargs="+", default=[0], help="Loop subdivisions of the surface case")
    parser.add_argument("--method", choices=("lbfgs", "anderson"), default="lbfgs", help="our solver's method")
    parser.add_argument("--no-tets", action="store_true", help="skip the tet case")
    args = parser.parse_args()
    surface = [bench_surface(args.quick, level, args.method) for level in args.levels]
    tets = None if args.no_tets else bench_tets(args.quick)
    print("RATIOS surface " + " ".join(f"{r:.3f}" for r in surface) + ("" if tets is None else f"  tets {tets:.3f}"))


if __name__ == "__main__":
    main()
