"""Per-frame setup of ray bending: ``DeformationField._frame`` = the deformed proxy's ``TetLocator`` + the near grid.

Anchor (docs/benchmarks.md): ``scipy.spatial.Delaunay`` of the same deformed vertices (Qhull: a tet mesh and its
point-location structure from scratch), measured in the same run. Also timed in the same run: the torch build
(``kernel="torch"``: the vectorised build that was the CPU path before the compiled one, and that CUDA runs),
whose grids must equal the compiled build's bit for bit (checked here on every frame). Meshes: the tet proxies
(``build_proxy``, default ``ProxyConfig``) of ``sample:bunny`` and of the capsule of the tests, cached in ``/tmp``,
bent smoothly about their long axis over ``--frames`` frames. Times are per frame (median over frames 1.., frame 0
also builds the rest locator), wall clock, torch's default threads; numba kernels are compiled before timing.

    python bench/bench_frames.py [--quick] [--frames N]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from timing import best_of

from nerfedit_plugin.bending.deformation_field import DeformationField, _near_grid

CACHE = Path("/tmp/nerfedit_bench_frames")
GRID = ("_cell_mask", "_octant_primary", "_cell_start", "_cell_count", "_entry_tet", "_deep", "_neighbours")


def proxy(name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices, tets)`` of the tet proxy of ``sample:bunny`` or of the tests' capsule (cached)."""
    import trimesh

    from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    if name == "bunny":
        mesh = SurfaceMesh.load("sample:bunny")
    else:
        capsule = trimesh.creation.capsule(height=1.3, radius=0.35, count=[24, 12])
        mesh = SurfaceMesh(np.asarray(capsule.vertices), np.asarray(capsule.faces))
    CACHE.mkdir(exist_ok=True)
    built, _ = cached_proxy(mesh, ProxyConfig(), CACHE)
    return built.vertices, built.tets


def bent(vertices: np.ndarray, angle: float) -> np.ndarray:
    """A smooth bend: rotation about a transverse axis by ``angle`` × (normalised position along the long axis)²."""
    centre, extent = vertices.mean(0), np.ptp(vertices, 0)
    axis = int(np.argmax(extent))
    other = (axis + 1) % 3
    s = (vertices[:, axis] - centre[axis]) / extent.max()
    turn = angle * s * s
    d = vertices - centre
    out = vertices.copy()
    out[:, axis] = centre[axis] + np.cos(turn) * d[:, axis] - np.sin(turn) * d[:, other]
    out[:, other] = centre[other] + np.sin(turn) * d[:, axis] + np.cos(turn) * d[:, other]
    return out


def time_frames(field: DeformationField) -> tuple[list[float], list[float]]:
    """Per frame 1..F-1: (TetLocator build, near grid) seconds, the way ``_frame`` builds them."""
    rest = field._rest()
    locator_times, grid_times = [], []
    for frame in range(1, field.n_frames):
        start = time.perf_counter()
        locator = field._locator(field.deformed_vertices[frame])
        middle = time.perf_counter()
        _near_grid(locator, rest)
        locator_times.append(middle - start)
        grid_times.append(time.perf_counter() - middle)
    return locator_times, grid_times


def bench(name: str, n_frames: int) -> None:
    from scipy.spatial import Delaunay

    vertices, tets = proxy(name)
    frames = np.stack([bent(vertices, 0.9 * f / max(1, n_frames - 1)) for f in range(n_frames)])
    print(f"\n== {name} proxy: {len(vertices)} vertices, {len(tets)} tets, {n_frames} frames")
    anchor = best_of(lambda: Delaunay(frames[-1]), 5, warmup=True)
    fields = {kernel: DeformationField(vertices, tets, frames, kernel=kernel) for kernel in ("numba", "torch")}
    for field in fields.values():
        field._frame(0)  # rest locator, numba compilation / cache loading
    median = {}
    for kernel, field in fields.items():
        locator_times, grid_times = time_frames(field)
        total = [a + b for a, b in zip(locator_times, grid_times)]
        median[kernel] = statistics.median(total)
        print(
            f"{kernel:5s} build: {median[kernel] * 1e3:7.1f} ms per frame (TetLocator "
            f"{statistics.median(locator_times) * 1e3:.1f} ms + near grid {statistics.median(grid_times) * 1e3:.1f} "
            f"ms; best {min(total) * 1e3:.1f} ms)"
        )
    print(f"scipy Delaunay of the deformed vertices: {anchor * 1e3:.1f} ms")
    print(
        f"ratio: compiled build {median['numba'] / anchor:.2f}x Delaunay, torch build {median['torch'] / anchor:.2f}x;"
        f" compiled {median['torch'] / median['numba']:.1f}x faster than torch"
    )
    same = True
    for frame in range(n_frames):
        a, b = (field._frame(frame) for field in fields.values())
        same &= all(torch.equal(x, y) for x, y in zip(a.near, b.near))
        same &= all(torch.equal(getattr(a.locator, g), getattr(b.locator, g)) for g in GRID)
    print(f"compiled and torch grids (locator + near grid) identical on all {n_frames} frames: {same}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="capsule only")
    parser.add_argument("--frames", type=int, default=6, help="frames per edit (the first is not timed)")
    args = parser.parse_args()
    for name in ["capsule"] if args.quick else ["bunny", "capsule"]:
        bench(name, max(2, args.frames))


if __name__ == "__main__":
    main()
