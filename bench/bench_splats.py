"""The splat backend at scale: load, validate and render INRIA PLYs of 200k to ~6M Gaussians on the CPU.

    python bench/bench_splats.py [--sizes 200000 1000000 6000000] [--resolution 256]

Per size, a synthetic degree-3 model (:func:`~nerfedit_plugin.fields.splats.model.synthetic_model`: means uniform in
a ball of radius 0.8, each axis's scale log-uniform in [0.003, 0.03] shrunk by the cube root of N / 200k, so the
ball's coverage stays that of the 200k model; opacities uniform in (0.05, 0.95)) is written as an INRIA PLY, then
in a fresh subprocess: ``SplatsField.from_file`` (parse, validate, the scene box) and the first render of one
``--resolution``² view (camera at distance 2.8, 0.8 rad field of view, every Gaussian in view; the compiled kernels
loaded from numba's cache beforehand), then the best of 3 renders with its stages (``SplatsField.last_stats``) and the
process's peak RSS. Anchor, in the same run: the default ``nerf`` field (untrained: every cell of its occupancy grid
occupied, the most expensive render of that field) from the same camera, best of 2; printed as render ÷ anchor.
Target: load + validate + first render of the 1M PLY ≤ 5 s.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch
from timing import best_of

CAMERA_DISTANCE, FOV = 2.8, 0.8


def camera(resolution: int):
    from nerfedit_plugin.data.cameras import Cameras, look_at

    c2w = look_at(torch.tensor([[0.0, -CAMERA_DISTANCE, 0.0]]), torch.zeros(1, 3))
    return Cameras.from_fov(c2w, resolution, resolution, FOV)


def case(path: str, resolution: int) -> None:
    """The subprocess side: time the load and the renders of the PLY ``path``; prints one JSON line."""
    from nerfedit_plugin.fields.splats.field import SplatsField
    from nerfedit_plugin.fields.splats.model import synthetic_model
    from nerfedit_plugin.render.renderer import RenderConfig

    view = camera(resolution)
    SplatsField.from_model(synthetic_model(1000, 3, seed=1)).render(view, 0, RenderConfig())  # load the kernels
    start = time.perf_counter()
    field = SplatsField.from_file(Path(path))
    loaded = time.perf_counter() - start
    field.render(view, 0, RenderConfig())
    first = time.perf_counter() - start
    render = best_of(lambda: field.render(view, 0, RenderConfig()), 3)
    stats = field.last_stats
    row = {
        "gaussians": field.n_gaussians,
        "load_s": loaded,
        "load_and_first_render_s": first,
        "render_s": render,
        "stages_s": dict(stats.seconds),
        "visible": stats.visible,
        "intersections": stats.intersections,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    print(json.dumps(row))


def anchor(resolution: int) -> float:
    """Best of 2 renders of the untrained default ``nerf`` field over the models' box from the same camera."""
    from nerfedit_plugin.fields.nerf import NerfConfig
    from nerfedit_plugin.render.renderer import RenderConfig, render_image

    field = NerfConfig().setup(scene_bbox=torch.tensor([[-0.85] * 3, [0.85] * 3]))
    view = camera(resolution)
    with torch.no_grad():
        return best_of(lambda: render_image(field, view, 0, RenderConfig()), 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[200_000, 1_000_000, 6_000_000])
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--case", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        case(args.case[0], int(args.case[1]))
        return
    from nerfedit_plugin.fields.splats.files import write_ply
    from nerfedit_plugin.fields.splats.model import synthetic_model

    print(
        "| Gaussians | PLY MB | load + validate s | + first render s | render s | project | cull | sort | tiles | "
        "composite | tile entries | peak RSS MB | ÷ nerf render |"
    )
    print("|" + "---|" * 13)
    nerf = anchor(args.resolution)
    with tempfile.TemporaryDirectory() as folder:
        for n in args.sizes:
            shrink = (n / 200_000) ** (1 / 3)
            model = synthetic_model(n, 3, seed=0, radius=0.8, scale=(0.003 / shrink, 0.03 / shrink))
            path = Path(folder) / f"model_{n}.ply"
            write_ply(model, path)
            del model
            command = [sys.executable, __file__, "--case", str(path), str(args.resolution)]
            done = subprocess.run(command, check=True, capture_output=True, text=True)
            r = json.loads(done.stdout.strip().splitlines()[-1])
            stages = " | ".join(f"{r['stages_s'].get(k, 0.0):.3f}" for k in ("project", "cull", "sort", "tiles"))
            print(
                f"| {n} | {path.stat().st_size / 2**20:.0f} | {r['load_s']:.2f} | {r['load_and_first_render_s']:.2f} | "
                f"{r['render_s']:.3f} | {stages} | {r['stages_s'].get('composite', 0.0):.3f} | "
                f"{r['intersections']} | {r['peak_rss_mb']:.0f} | {r['render_s'] / nerf:.2f} |",
                flush=True,
            )
            path.unlink()
    print(f"\nanchor: the untrained nerf field's {args.resolution}² render, best of 2: {nerf:.3f} s")
    print("load average: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))


if __name__ == "__main__":
    main()
