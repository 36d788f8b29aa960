"""The editor's interactive loop (docs/benchmarks.md, "The editor").

1. Handle drag on ``sample:bunny`` (28k vertices; bottom fixed, ears moving), per backend: 30 moves of a drag, each
   what the editor does for a mouse drag's move: the handle move + the drag preview
   (:meth:`EditorState.preview_drag`; arap: a warm-started solve of :data:`deformers.arap.PREVIEW_ITERATIONS`;
   cage: the bound coordinates; skeleton: the bound skinning weights) + the shown mesh's positions set in its tensor
   mesh (:class:`~nerfedit_plugin.viewer.editor.ShownMesh`; normals are recomputed on release; the window's
   ``add_geometry`` and frame time are not in it). Target ≤ 100 ms per move. Reports which mesh is shown during the
   drag, the split (solve vs geometry update), the ARAP iterations per move, and the release: the energy gap of the
   last preview to the converged solve, closed, and the time until the settled mesh is shown.
2. ``--run RUN``: the "render" action (lift into the proxy + render at 128 px) from a view of the run's mesh, cold
   (proxy from the cache or built, lift factored, kernels compiled) and warm. Target ≤ 2 s warm.

``--mesh MESH`` drags on another mesh; ``--subdivisions N`` on the bunny Loop-subdivided N times (``bench_scale.py``'s
meshes; 3: 1.8M vertices, which the ARAP backend edits on its coarse level: each move solves the coarse level, which
is what is shown during the drag; the release carries the fine surface and shows it); on another mesh than the bunny
the bunny's drag runs first, as the anchor: each backend's median per move is also printed as its ratio to the
anchor's, measured in the same run (the machine's load moves both alike).
``--deformers`` picks the backends.

Usage: ``python bench/bench_editor.py [--run RUN] [--mesh MESH | --subdivisions N] [--deformers arap cage skeleton]``.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.viewer.backends import editing_backend
from nerfedit_plugin.viewer.editor import ShownMesh, _mesh
from nerfedit_plugin.viewer.editor_state import EditorState
from nerfedit_plugin.viewer.picking import View

MOVES = 30
SKELETON = Path(__file__).resolve().parent.parent / "configs" / "skeleton" / "bunny.json"


def _grab(state: EditorState, name: str) -> None:
    """Bunny handles: bottom fixed and ears moving (arap), the cage's top moving (cage), the head joint (skeleton)."""
    points = state.backend.points
    y = points[:, 1]
    if name == "skeleton":
        state.select([state.backend.skeleton.names.index("neck")])
    else:
        if name == "arap":
            state.select(np.flatnonzero(y <= np.quantile(y, 0.05)))
            state.mark(True)
        state.select(np.flatnonzero(y >= np.quantile(y, 0.97 if name == "arap" else 0.8)))
    state.mark(False)


def drag(name: str, mesh: str = "sample:bunny", anchor: float | None = None) -> float:
    """Drag backend ``name`` on ``mesh`` (printed) → the median ms per move; ``anchor``: the anchor's, for the ratio."""
    rest = SurfaceMesh.load(mesh)
    start = time.perf_counter()
    state = EditorState(editing_backend(name, rest, {"skeleton": SKELETON} if name == "skeleton" else {}))
    _grab(state, name)
    state.preview()  # arap: factorises for these handles (once per handle set)
    print(
        f"{name}: {mesh} {rest.n_vertices} vertices, bind / factorisation + first preview "
        f"{time.perf_counter() - start:.2f} s"
    )
    shown = ShownMesh(rest.faces)
    shown.update(state, normals=True)
    solve, update, iterations = [], [], []
    step = np.array([0.004, 0.002, 0.0]) * rest.bbox_diagonal
    for _ in range(MOVES):
        start = time.perf_counter()
        if name == "skeleton":
            state.rotate([0.0, 0.0, 1.0], 1.0, record=False)
        else:
            state.translate(step, record=False)
        state.preview_drag()
        middle = time.perf_counter()
        mesh = shown.update(state, normals=False)
        update.append(time.perf_counter() - middle)
        solve.append(middle - start)
        iterations.append(state.backend.last_iterations)
    total = 1e3 * (np.array(solve) + np.array(update))
    live = state.live
    what = "the mesh" if live is None else f"the backend's live view ({len(live.vertices)} vertices)"
    print(f"  shown during the drag: {what}")
    vertices = mesh.vertex.positions.numpy()
    start = time.perf_counter()
    mesh.compute_vertex_normals()
    normals = time.perf_counter() - start
    start = time.perf_counter()
    _mesh(vertices, mesh.triangle.indices.numpy(), (0.7, 0.7, 0.7))
    rebuild = time.perf_counter() - start
    counted = f"; {np.mean(iterations):.1f} iterations per move" if name == "arap" else ""
    ratio = "" if anchor is None else f" ({np.median(total) / anchor:.2f}× the anchor's)"
    print(
        f"  drag: {MOVES} moves, per move median {np.median(total):.0f} ms{ratio}, "
        f"p90 {np.percentile(total, 90):.0f} ms, max {total.max():.0f} ms (move + preview median "
        f"{1e3 * np.median(solve):.1f} ms, positions update {1e3 * np.median(update):.2f} ms; "
        f"were it rebuilt with normals {1e3 * rebuild:.1f} ms, normals alone "
        f"{1e3 * normals:.1f} ms){counted}"
    )
    start = time.perf_counter()
    settled = state.converge()
    state.released(settled)
    shown.update(state, normals=True)
    took = time.perf_counter() - start
    if settled is not None:
        _, before, after, count = settled
        print(
            f"  release: energy of the last preview {(before - after) / after:+.1%} above the converged solve, "
            f"closed in {count} iterations; the mesh ({rest.n_vertices} vertices) shown settled after {took:.2f} s"
        )
    else:
        print(f"  release: the mesh ({rest.n_vertices} vertices) shown after {took:.2f} s")
    start = time.perf_counter()
    state.settle()
    print(f"  settle (the exact `nerfedit edit` solve, bind included): {time.perf_counter() - start:.2f} s")
    return float(np.median(total))


def render(run_path: str) -> None:
    from nerfedit_plugin.pipeline.run import open_run
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
    parser.add_argument("--mesh", default="sample:bunny", help="the mesh dragged (a PLY or sample:NAME)")
    parser.add_argument("--subdivisions", type=int, help="drag the bunny Loop-subdivided this many times")
    parser.add_argument("--deformers", nargs="+", default=["arap", "cage", "skeleton"], help="the backends dragged")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    if args.subdivisions is not None:
        from bench_scale import level_mesh

        args.mesh = str(level_mesh(args.subdivisions))
    for name in args.deformers:
        anchor = None
        if args.mesh != "sample:bunny":
            print("anchor:", end=" ")
            anchor = drag(name)
        drag(name, args.mesh, anchor)
    if args.run:
        render(args.run)
