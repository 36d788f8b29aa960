"""PSNR-vs-time of a field backend (``nerf`` or ``neus``, default settings) on the built-in bunny scene, against
the calibration floor — a plain 96³ density+RGB grid with uniform samples and no occupancy grid — trained in the
same run for the same time.

    python bench/bench_train.py [--field {nerf,neus}] [--quick] [--seconds S] [--clock {wall,cpu}]

Generates ``sample:bunny`` at 100×100 (50 train / 10 test views, white background) into a temp folder, trains
each model for S seconds (default 300; ``--quick``: 60) on 2 threads and prints test PSNR every S/10 seconds, then
the final PSNRs and the MSE ratio floor / backend (> 1: the backend is better). For ``neus`` it also prints the
Chamfer distance between the extracted zero level set and the source mesh as a fraction of the source mesh's bbox
diagonal: ``½ (mean_p d(p, source) + mean_q d(q, extracted))`` over points sampled uniformly on each surface
(exact point-to-triangle distances from Open3D's ``RaycastingScene``; target ≤ 0.5 %).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import torch

from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset
from nerfedit_plugin.fields.nerf import NerfConfig
from nerfedit_plugin.fields.neus import NeusConfig
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh


def floor_config() -> NerfConfig:
    """The calibration floor: 96³ density + RGB, trilinear, uniform samples, no occupancy, no MLP."""
    return NerfConfig(resolution=96, upsample_steps=(), features=3, decoder="rgb", occupancy_resolution=0, carve=False)


BACKENDS = {"nerf": NerfConfig, "neus": NeusConfig}
SURFACE_SAMPLES = 200_000
"""Points sampled on each surface for the Chamfer distance."""


def run(name: str, config, train, test, seconds: float, clock: str = "wall"):
    """Train ``config``'s field for ``seconds`` of ``clock``; returns the field and its ``(seconds, test PSNR)``
    curve."""
    config.train = dataclasses.replace(
        config.train, max_seconds=seconds, eval_every_seconds=seconds / 10, progress=False, clock=clock
    )
    field = config.setup(scene_bbox=train.scene_bbox)
    start = time.perf_counter()
    log = field.fit(train, eval_dataset=test)
    print(
        f"{name}: {log['steps']} steps, {log['train_seconds']:.1f} s training, "
        f"{time.perf_counter() - start:.1f} s with evaluation"
    )
    return field, log["eval"]


def chamfer(a: SurfaceMesh, b: SurfaceMesh, seed: int = 0) -> float:
    """Symmetric Chamfer distance ``½ (mean_{p∈A} d(p, B) + mean_{q∈B} d(q, A))`` over area-uniform samples."""
    import trimesh

    def one_way(source: SurfaceMesh, target: SurfaceMesh) -> float:
        points, _ = trimesh.sample.sample_surface(source.to_trimesh(), SURFACE_SAMPLES, seed=seed)
        return float(raycast.distance(raycast.raycasting_scene(target.vertices, target.faces), points).mean())

    return 0.5 * (one_way(a, b) + one_way(b, a))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--field", choices=sorted(BACKENDS), default="nerf", help="backend to measure")
    parser.add_argument("--quick", action="store_true", help="60 s per model instead of 300 s")
    parser.add_argument("--seconds", type=float, default=None, help="training seconds per model")
    parser.add_argument(
        "--clock",
        choices=("wall", "cpu"),
        default="wall",
        help="wall-clock seconds, or CPU seconds of the whole process (every thread; use on a busy machine, see "
        "TrainerConfig.clock)",
    )
    args = parser.parse_args()
    seconds = args.seconds or (60.0 if args.quick else 300.0)
    torch.set_num_threads(2)
    with tempfile.TemporaryDirectory() as tmp:
        data = generate_dataset(
            GenerateConfig(out=Path(tmp) / "bunny", mesh="sample:bunny", resolution=100, n_train=50, n_test=10)
        )
        train, test = load_dataset(data, "train"), load_dataset(data, "test")
        source = SurfaceMesh.load(data / "mesh.ply")
    name = args.field
    field, ours = run(f"{name} (defaults)", BACKENDS[name](), train, test, seconds, args.clock)
    _, floor = run("floor (plain 96³ grid)", floor_config(), train, test, seconds, args.clock)
    print(f"\n{'seconds':>8} {name + ' PSNR':>10} {'floor PSNR':>11}")
    for (t, p), (_t2, p2) in zip(ours, floor):
        print(f"{t:8.1f} {p:10.2f} {p2:11.2f}")
    gain = ours[-1][1] - floor[-1][1]
    print(
        f"\nfinal after {seconds:.0f} s: {name} {ours[-1][1]:.2f} dB, floor {floor[-1][1]:.2f} dB, "
        f"difference {gain:+.2f} dB, MSE ratio floor/{name} {10 ** (gain / 10):.2f}"
    )
    reached = next((t for t, p in ours if p >= 30.0), None)
    print(f"{name} reached 30 dB at " + (f"{reached:.0f} s" if reached is not None else "— (not within the budget)"))
    if name == "neus":
        distance = chamfer(field.extract_mesh(resolution=256), source)
        print(
            f"neus mesh Chamfer distance {distance:.5f} = {100 * distance / source.bbox_diagonal:.3f} % of the "
            f"source bbox diagonal (target ≤ 0.5 %)"
        )


if __name__ == "__main__":
    main()
