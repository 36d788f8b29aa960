"""Skeleton deformer speed on the pymeshlab bunny (28k vertices) with the 10-bone example rig.

- Bone-heat weights for 10 bones (target ≤ 2 s); anchor: the bare linear algebra of the same solve with libigl
  operators — ``igl.cotmatrix`` + ``igl.massmatrix`` + one cholespy factorisation + a 10-column solve.
- Each new pose after binding = forward kinematics + skinning (target ≤ 20 ms), DQS and LBS; anchor: libigl's
  LBS, ``M = igl.lbs_matrix(V, W)`` precomputed and one ``M @ T`` per pose.

Usage: ``python bench/bench_skeleton.py [--quick]``. BLAS runs single-threaded (as in a loaded 2-core run).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from timing import best_of  # noqa: E402

from deformers.skeleton import Skeleton  # noqa: E402
from deformers.skeleton.heat_weights import bone_heat_weights  # noqa: E402
from deformers.skeleton.skinning import Binding, normalize_weights, skin  # noqa: E402
from nerfedit_plugin.geometry.mesh import SurfaceMesh  # noqa: E402
from nerfedit_plugin.geometry.samples import sample_mesh_path  # noqa: E402

TARGET_WEIGHTS_S = 2.0
TARGET_POSE_MS = 20.0


def anchor_heat(vertices: np.ndarray, faces: np.ndarray, bones: int) -> None:
    import igl
    from cholespy import CholeskySolverD, MatrixType

    system = (-igl.cotmatrix(vertices, faces) + igl.massmatrix(vertices, faces)).tocoo()
    solver = CholeskySolverD(
        len(vertices), system.row.astype(np.int32), system.col.astype(np.int32), system.data, MatrixType.COO
    )
    rhs = np.ascontiguousarray(np.random.default_rng(0).random((len(vertices), bones)))
    solver.solve(rhs, np.zeros_like(rhs))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = parser.parse_args()
    heat_reps, pose_reps = (1, 20) if args.quick else (3, 200)

    import open3d  # noqa: F401  (import once, outside the timings)

    mesh = SurfaceMesh.load(sample_mesh_path("bunny"))
    skeleton = Skeleton.from_json(ROOT / "configs" / "skeleton" / "bunny.json")
    n_bones = len(skeleton.names)
    v, f = mesh.vertices, mesh.faces
    print(f"bunny: {mesh.n_vertices} vertices, {len(f)} faces; rig: {n_bones} bones")

    weights = bone_heat_weights(v, f, skeleton.heads, skeleton.tails)
    t_heat = best_of(lambda: bone_heat_weights(v, f, skeleton.heads, skeleton.tails), heat_reps)
    t_heat_blind = best_of(lambda: bone_heat_weights(v, f, skeleton.heads, skeleton.tails, visibility=False), heat_reps)
    t_anchor = best_of(lambda: anchor_heat(v, f, n_bones), heat_reps)
    print(
        f"heat weights, visibility on : {t_heat:7.3f} s   = {t_heat / TARGET_WEIGHTS_S:5.2f} x target "
        f"({TARGET_WEIGHTS_S:g} s), {t_heat / t_anchor:5.2f} x anchor"
    )
    print(
        f"heat weights, visibility off: {t_heat_blind:7.3f} s   = {t_heat_blind / TARGET_WEIGHTS_S:5.2f} x target, "
        f"{t_heat_blind / t_anchor:5.2f} x anchor"
    )
    print(f"  anchor (igl cotmatrix + massmatrix + cholespy factor + {n_bones}-column solve): {t_anchor:7.3f} s")

    weights = normalize_weights(weights, 1e-3)
    binding = Binding.create(v, weights)
    rng = np.random.default_rng(0)
    poses = [Rotation.from_rotvec(rng.normal(scale=0.4, size=(n_bones, 3))).as_matrix()[None] for _ in range(pose_reps)]
    zero = np.zeros((1, n_bones, 3))
    state = {"i": 0}

    def new_pose(method: str) -> None:
        rot, trans = skeleton.forward_kinematics(poses[state["i"] % pose_reps], zero)
        state["i"] += 1
        skin(binding, rot[0], trans[0], method)

    import igl

    t_lbs_matrix = best_of(lambda: igl.lbs_matrix(v, weights), 3)
    lbs_m = igl.lbs_matrix(v, weights)
    stacks = [rng.normal(size=(4 * n_bones, 3)) for _ in range(pose_reps)]
    t_anchor_pose = best_of(lambda: lbs_m @ stacks[state["i"] % pose_reps], pose_reps)
    for method in ("dqs", "lbs"):
        t = best_of(lambda method=method: new_pose(method), pose_reps)
        print(
            f"new pose {method.upper()} (FK + skinning): {1e3 * t:7.2f} ms = {1e3 * t / TARGET_POSE_MS:5.2f} x target "
            f"({TARGET_POSE_MS:g} ms), {t / t_anchor_pose:5.2f} x anchor"
        )
    print(
        f"  anchor (one igl.lbs_matrix M @ T per pose): {1e3 * t_anchor_pose:7.2f} ms "
        f"(building M once: {1e3 * t_lbs_matrix:.1f} ms)"
    )


if __name__ == "__main__":
    main()
