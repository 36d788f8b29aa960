"""Deformation transfer: time per further pose after binding, on a ~30k-vertex target (target ≤ 100 ms).

1. Self-transfer of the bending capsule (``nerfedit_plugin.data.sequences.bending_capsule``, 30.7k vertices):
   bind (identity correspondence, elimination of the fourth vertices, one factorisation) and the best time of one
   further pose (sparse product + back-substitution + translation).
2. Transfer from a 7.5k-vertex capsule onto the 30.7k-vertex one (other connectivity, six point markers): bind
   (correspondence fit: 5 phases, each one factorisation of the source system; triangle matching; factorisation)
   and the time per pose.

Anchor, measured in the same run: one ``scipy.sparse.linalg.spsolve`` of ``M − 0.01 L`` (libigl cotangent
Laplacian and Voronoi mass matrix of the target) for 3 right-hand sides — one implicit smoothing step, i.e. what a
solver that does not keep its factorisation pays for each pose. ``RATIO = per-pose time / anchor``.

Usage: ``python bench/bench_transfer.py [--quick]`` (quick: ~7.7k-vertex target).
"""

from __future__ import annotations

import argparse

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve
from timing import best_of, timed

from deformers.transfer import TransferSystem, correspondence
from nerfedit_plugin.data.sequences import bending_capsule

MARKERS = [[0, 0, 0.75], [0, 0, -0.75], [0.25, 0, 0], [-0.25, 0, 0], [0, 0.25, 0], [0, -0.25, 0]]
BUDGET = 0.100  # seconds per pose


def anchor(target) -> float:
    """Best of 3: scipy spsolve of (M − 0.01 L) x = M v, 3 right-hand sides."""
    lap = igl.cotmatrix(target.vertices, target.faces)
    mass = igl.massmatrix(target.vertices, target.faces, igl.MASSMATRIX_TYPE_VORONOI)
    matrix = sp.csc_matrix(mass - 0.01 * lap)
    rhs = mass @ target.vertices
    return best_of(lambda: spsolve(matrix, rhs), 3)


def report(name: str, bind: float, per_pose: float, reference: float, error: float | None = None) -> float:
    ratio = per_pose / reference
    extra = f", max error vs source poses {error:.1e}" if error is not None else ""
    print(f"  {name}: bind {bind:.2f} s, per pose {1e3 * per_pose:.1f} ms (budget {1e3 * BUDGET:.0f} ms){extra}")
    print(f"  RATIO {name} (per pose / anchor) = {ratio:.3f}")
    return ratio


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a ~7.7k-vertex target")
    args = parser.parse_args()
    count = (128, 60) if args.quick else (256, 120)
    source, poses = bending_capsule(n_frames=4, count=count)
    reference = anchor(source)
    print(f"target: bending capsule, {source.n_vertices} vertices / {len(source.faces)} faces")
    print(f"  anchor: scipy spsolve (M - 0.01 L), 3 rhs: {1e3 * reference:.1f} ms")

    faces = np.arange(len(source.faces))
    bind, system = timed(lambda: TransferSystem(source, source, np.column_stack([faces, faces])))
    per_pose = best_of(lambda: system.transfer(poses[-1]), 5, warmup=True)
    error = max(np.abs(system.transfer(p) - p).max() for p in poses)
    self_ratio = report("self-transfer", bind, per_pose, reference, error)

    small, small_poses = bending_capsule(n_frames=4, count=(count[0] // 2, count[1] // 2))
    snap = [[int(np.argmin(np.linalg.norm(m.vertices - p, axis=1))) for m in (small, source)] for p in MARKERS]

    def bind_other():
        return TransferSystem(small, source, correspondence(small, source, np.asarray(snap)).pairs)

    bind, other = timed(bind_other)
    per_pose = best_of(lambda: other.transfer(small_poses[-1]), 5, warmup=True)
    other_ratio = report(f"{small.n_vertices} -> {source.n_vertices} vertices", bind, per_pose, reference)
    print(f"RATIOS self {self_ratio:.3f}  other-mesh {other_ratio:.3f}")


if __name__ == "__main__":
    main()
