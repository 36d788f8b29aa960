"""Cage deformer speed on the pymeshlab bunny (28k vertices) against its automatic ~300-vertex cage.

- Bind (``CageDeformer.bind`` with the cage given as a file: load + checks + mean value coordinates of every mesh
  vertex + the enclosure test for the outside warning (Open3D ray parity) + handle targets), target ≤ 1 s.
  Anchor measured in the same run: one ``np.arctan2`` pass over a (vertices × cage faces) float64 array — the
  cost of touching every (point, face) pair once with one transcendental; MVC needs a few dozen such passes.
- Each new cage pose = one dense product of the precomputed (cage vertices × mesh vertices) weights, target
  ≤ 20 ms. Anchor: one read pass over the same weight matrix (``sum``), the memory-bandwidth floor.
- Also reported: Green coordinates bind (optional mode), and building the automatic cage (alpha wrap).

Usage: ``python bench/bench_cage.py [--quick]`` (quick: the first 4096 bunny vertices, fewer repeats).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_of  # noqa: E402

from deformers.cage import CageConfig, CageDeformer, auto_cage, validate_cage  # noqa: E402
from nerfedit_plugin.edit.spec import parse_edit_spec  # noqa: E402
from nerfedit_plugin.geometry.mesh import SurfaceMesh  # noqa: E402

TARGET_BIND_S = 1.0
TARGET_POSE_MS = 20.0


def arctan2_anchor(f: int, n: int, repeat: int) -> float:
    """Best time of one ``np.arctan2`` pass over a (2, f, n) float64 array; the array is freed on return."""
    grid = np.random.default_rng(0).uniform(0.5, 1.5, size=(2, f, n))
    return best_of(lambda: np.arctan2(grid[0], grid[1]), repeat)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="4096 bunny vertices, fewer repeats")
    args = parser.parse_args()
    repeat = 2 if args.quick else 3

    bunny = SurfaceMesh.load("sample:bunny")
    wrap_s = best_of(lambda: validate_cage(auto_cage(bunny), "auto cage"), 1 if args.quick else 2)
    cage = validate_cage(auto_cage(bunny), "auto cage")
    if args.quick:
        keep = 4096
        bunny = SurfaceMesh(bunny.vertices[:keep], bunny.faces[(bunny.faces < keep).all(1)])
    n, f = bunny.n_vertices, len(cage.faces)
    print(
        f"bunny: {n} vertices; automatic cage: {cage.n_vertices} vertices / {f} faces "
        f"(alpha wrap + checks {wrap_s:.2f} s)"
    )

    anchor_s = arctan2_anchor(f, n, repeat)
    with tempfile.TemporaryDirectory() as tmp:
        cage.save(Path(tmp) / "cage.ply")
        handles = json.loads((ROOT / "configs" / "cage_bunny_auto.json").read_text())["handles"]
        spec = parse_edit_spec({"cage": "cage.ply", "handles": handles}, CageDeformer.spec_keys, "bench", tmp)
        deformer = CageConfig().setup()
        bind_s = best_of(lambda: deformer.bind(bunny, spec), repeat)
        green = CageConfig(coordinates="green").setup()
        green_s = best_of(lambda: green.bind(bunny, spec), 1)
    print(
        f"MVC bind:   {bind_s:.3f} s  = {bind_s / TARGET_BIND_S:.2f} × the {TARGET_BIND_S:.0f} s target"
        f"  = {bind_s / anchor_s:.1f} × one arctan2 pass over {n}×{f} ({anchor_s * 1e3:.1f} ms)"
    )
    print(f"Green bind: {green_s:.3f} s  = {green_s / anchor_s:.1f} × the arctan2 pass")

    weights = np.random.default_rng(1).random((cage.n_vertices, n))  # same shape as the bound (C, V) weights
    pose_s = best_of(deformer.deform, 10 * repeat)
    floor_s = best_of(weights.sum, 10 * repeat)
    print(
        f"pose:       {pose_s * 1e3:.2f} ms = {pose_s * 1e3 / TARGET_POSE_MS:.2f} × the {TARGET_POSE_MS:.0f} ms target"
        f"  = {pose_s / floor_s:.1f} × one read pass over the {weights.nbytes / 1e6:.0f} MB weights "
        f"({floor_s * 1e3:.2f} ms)"
    )


if __name__ == "__main__":
    main()
