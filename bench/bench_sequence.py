"""Sequences: lifting 60 frames through one proxy, and rendering 60 frames locally and on Ray.

1. Lift. The bending capsule (``nerfedit_plugin.data.sequences.bending_capsule``, 60 frames, 90°) through its tet
   proxy with the default ``tet-arap`` lift: one :class:`Lift` (one factorisation), frames warm-started from the
   previous one. Anchor, measured in the same run: one frame (the last) lifted from scratch (a new ``Lift``:
   factorisation, knn3 start). ``RATIO = 60-frame time / anchor`` (target ≤ 10).
2. Render. The exact mesh field of the capsule (vertex-coloured), the 60-frame deformation, ``--trajectory fixed``
   at 100×100: the local executor (this process, torch's threads) against the Ray executor (a local cluster,
   ``--workers`` actors of one thread each, the same two cores), not counting ``ray.init`` (reported apart).
   ``RATIO = Ray wall time / local wall time`` (target ≤ 1.2: this measures overhead, not speed-up). Also the
   per-task overhead: the mean round trip of 200 calls of an empty actor method, in ms.

Usage: ``python bench/bench_sequence.py [--frames 60] [--size 100] [--skip-render]``.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import torch
from timing import timed

from nerfedit_plugin.data.sequences import bending_capsule
from nerfedit_plugin.edit.lift import Lift
from nerfedit_plugin.edit.proxy import ProxyConfig, build_proxy


def bench_lift(frames: int) -> None:
    rest, poses = bending_capsule(n_frames=frames, degrees=90.0)
    proxy = build_proxy(rest, ProxyConfig())
    sequence, (_, reports) = timed(lambda: Lift(proxy, rest)(poses))
    single, _ = timed(lambda: Lift(proxy, rest)(poses[-1:]))
    worst, residual = max(r.inverted_tets for r in reports), max(r.residual_max for r in reports)
    print(f"lift: {frames} frames {sequence:.2f} s, one frame from scratch {single:.3f} s "
          f"({len(proxy.tets)} tets, worst inverted tets {worst}, max residual {residual:.2e})")  # fmt: skip
    print(f"RATIO lift {frames} frames / one frame from scratch = {sequence / single:.2f} (target <= 10)")


def bench_render(frames: int, size: int, workers: int) -> None:
    import ray

    from nerfedit_plugin.cli.app import main
    from nerfedit_plugin.data.synthetic import colorize
    from nerfedit_plugin.pipeline.executors import LocalExecutor, RayExecutor, RenderJob
    from nerfedit_plugin.pipeline.run import open_run
    from nerfedit_plugin.render.animation import render_animation, trajectory

    root = Path(tempfile.mkdtemp(prefix="bench-sequence-"))
    rest, _ = bending_capsule(n_frames=2)
    colorize(rest).save(root / "capsule.ply")
    edit = {
        "handles": [
            {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, -0.3]}}, "fixed": True},
            {"select": {"box": {"min": [-1, -1, 0.3], "max": [1, 1, 1]}}, "transform": {"translate": [0.2, 0, 0]}},
        ],
        "frames": frames,
    }
    (root / "edit.json").write_text(json.dumps(edit))
    for argv in (
        ["generate", "--mesh", root / "capsule.ply", "--resolution", size, "--n-train", 2, "--n-val", 1,
         "--n-test", 1, "--supersample", 1, "--up-axis", "z", "--out", root / "data"],
        ["train", "--field", "mesh", "--data", root / "data" / "mesh.ply", "--out", root / "run"],
        ["edit", "--run", root / "run", "--edit", root / "edit.json", "--out", root / "edit"],
    ):  # fmt: skip
        assert main([str(a) for a in argv]) == 0, argv
    run = open_run(root / "run")
    order = list(range(frames))
    cameras, _ = trajectory("fixed", order, cameras=root / "data", view=0)
    deformation = root / "edit" / "deformation.npz"

    def render(executor, out):
        return render_animation(executor, order, cameras, root / out, key={}, progress=False)

    local_job = RenderJob(run.path, deformation, 1, torch.get_num_threads())
    local, _ = timed(lambda: render(LocalExecutor(local_job), "local"))
    start, _ = timed(lambda: ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False))
    try:
        executor = RayExecutor(RenderJob(run.path, deformation, 1, 1), workers=workers)
        ray.get([actor.pid.remote() for actor in executor.actors])  # actors started (field loaded)
        calls = 200
        began = time.perf_counter()
        ray.get([executor.actors[i % workers].pid.remote() for i in range(calls)])
        per_task = (time.perf_counter() - began) / calls
        remote, _ = timed(lambda: render(executor, "ray"))
        executor.close()
    finally:
        ray.shutdown()
    print(f"render: {frames} frames {size}x{size}: local ({torch.get_num_threads()} threads) {local:.1f} s, "
          f"Ray ({workers} actors x 1 thread) {remote:.1f} s; ray.init {start:.1f} s; per-task overhead "
          f"{1e3 * per_task:.2f} ms")  # fmt: skip
    print(f"RATIO render Ray / local = {remote / local:.2f} (target <= 1.2)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--size", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--skip-render", action="store_true")
    args = parser.parse_args()
    bench_lift(args.frames)
    if not args.skip_render:
        bench_render(args.frames, args.size, args.workers)


if __name__ == "__main__":
    main()
