"""The editor's interactive loop (docs/benchmarks.md, "The editor").

1. Handle drag on ``sample:bunny`` (28k vertices; bottom fixed, ears moving): 30 moves of a drag, each the handle
   move + a warm-started preview solve (:data:`~nerfedit_plugin.viewer.editor_state.PREVIEW_ITERATIONS`) + the
   deformed mesh rebuilt as the scene's geometry (the window's ``add_geometry`` and frame time are not in it). Target
   ≤ 100 ms per move. Reports the iterations per move and the energy gap of the last preview to the converged solve.
2. ``--run RUN``: the "render" action (lift into the proxy + render at 128 px) from a view of the run's mesh, cold
   (proxy from the cache or built, lift factored, kernels compiled) and warm. Target ≤ 2 s warm.

Usage: ``python bench/bench_editor.py [--run RUN]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nerfedit_plugin.geometry.arap import ArapSolver
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.viewer.editor import _mesh
from nerfedit_plugin.viewer.editor_state import EditorState
from nerfedit_plugin.viewer.picking import View

MOVES = 30


def drag() -> None:
    rest = SurfaceMesh.load("sample:bunny")
    state = EditorState(rest, discover(DEFORMERS).config_class(DEFORMERS, "arap")())
    y = rest.vertices[:, 1]
    state.select(np.flatnonzero(y <= np.quantile(y, 0.05)))
    state.mark(True)
    state.select(np.flatnonzero(y >= np.quantile(y, 0.97)))
    state.mark(False)
    start = time.perf_counter()
    state.preview()  # factorises for these handles (once per handle set)
    print(f"bunny {rest.n_vertices} vertices: factorisation + first preview {time.perf_counter() - start:.2f} s")
    times, iterations = [], []
    step = np.array([0.004, 0.002, 0.0]) * rest.bbox_diagonal
    for _ in range(MOVES):
        start = time.perf_counter()
        state.translate(step, record=False)
        vertices = state.preview()
        _mesh(vertices, rest.faces, (0.7, 0.7, 0.7))
        times.append(time.perf_counter() - start)
        iterations.append(state.last_result.iterations)
    indices, targets = state.targets()
    solver = ArapSolver(rest.vertices, rest.faces, fixed=indices)
    converged = solver.solve(targets[0], initial=state.deformed)
    preview_energy = solver.energy(state.deformed)
    gap = (preview_energy - converged.energies[-1]) / converged.energies[-1]
    times_ms = 1e3 * np.array(times)
    print(
        f"drag: {MOVES} moves, per move median {np.median(times_ms):.0f} ms, p90 {np.percentile(times_ms, 90):.0f} ms, "
        f"max {times_ms.max():.0f} ms; {np.mean(iterations):.1f} iterations per move; energy of the last preview "
        f"{gap:+.1%} above the converged solve ({converged.iterations} more iterations)"
    )
    start = time.perf_counter()
    state.settle()
    print(f"settle (the exact `nerfedit edit` solve, bind included): {time.perf_counter() - start:.2f} s")


def render(run_path: str) -> None:
    from nerfedit_plugin.io.run import open_run
    from nerfedit_plugin.viewer.field_preview import FieldPreview

    run = open_run(run_path)
    rest = run.mesh()
    centre = rest.vertices.mean(0)
    eye = centre + np.array([0.0, -2.5, 1.2]) * rest.bbox_diagonal
    forward = (centre - eye) / np.linalg.norm(centre - eye)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, :3] = np.column_stack([right, up, -forward])
    c2w[:3, 3] = eye
    f = 1.0 / np.tan(np.radians(20))
    view = View(
        np.linalg.inv(c2w),
        np.diag([f, f, -1.0, 0.0]) + np.array([[0, 0, 0, 0]] * 2 + [[0, 0, 0, -0.2], [0, 0, -1, 0]]),
        128,
        128,
    )
    preview = FieldPreview(run, rest, width=128)
    deformed = rest.vertices.copy()
    top = rest.vertices[:, 2] >= np.quantile(rest.vertices[:, 2], 0.8)
    deformed[top] += [0.05 * rest.bbox_diagonal, 0.0, 0.0]
    start = time.perf_counter()
    preview.unedited(view)
    print(f"unedited render 128 px: {time.perf_counter() - start:.2f} s")
    for label in ("cold", "warm", "warm"):
        start = time.perf_counter()
        preview.edited(view, deformed)
        print(f"render action ({label}, lift + render 128 px): {time.perf_counter() - start:.2f} s")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", help="a trained run with mesh.ply (render action)")
    args = parser.parse_args()
    drag()
    if args.run:
        render(args.run)
