"""PSNR-vs-time of the ``nerf`` backend (default settings) on the built-in bunny scene, against the calibration
floor — a plain 96³ density+RGB grid with uniform samples and no occupancy grid — trained in the same run for the
same time.

    /work/venv/bin/python bench/bench_train.py [--quick] [--seconds S]

Generates ``sample:bunny`` at 100×100 (50 train / 10 test views, white background) into a temp folder, trains
each model for S seconds (default 300; ``--quick``: 60) on 2 threads and prints test PSNR every S/10 seconds, then
the final PSNRs and the MSE ratio floor / nerf (> 1: the nerf backend is better).
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import torch

from nerfedit_plugin.datasets import load_dataset
from nerfedit_plugin.fields.nerf import NerfConfig
from nerfedit_plugin.synthetic import GenerateConfig, generate_dataset


def floor_config() -> NerfConfig:
    """The calibration floor: 96³ density + RGB, trilinear, uniform samples, no occupancy, no MLP."""
    return NerfConfig(resolution=96, upsample_steps=(), features=3, decoder="rgb", occupancy_resolution=0,
                      carve=False)


def run(name: str, config: NerfConfig, train, test, seconds: float) -> list[tuple[float, float]]:
    config.train = dataclasses.replace(config.train, max_seconds=seconds, eval_every_seconds=seconds / 10,
                                       progress=False)
    field = config.setup(scene_bbox=train.scene_bbox)
    start = time.perf_counter()
    log = field.fit(train, eval_dataset=test)
    print(f"{name}: {log['steps']} steps, {log['train_seconds']:.1f} s training, "
          f"{time.perf_counter() - start:.1f} s with evaluation")
    return log["eval"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="60 s per model instead of 300 s")
    parser.add_argument("--seconds", type=float, default=None, help="training seconds per model")
    args = parser.parse_args()
    seconds = args.seconds or (60.0 if args.quick else 300.0)
    torch.set_num_threads(2)
    with tempfile.TemporaryDirectory() as tmp:
        data = generate_dataset(GenerateConfig(out=Path(tmp) / "bunny", mesh="sample:bunny", resolution=100,
                                               n_train=50, n_test=10))
        train, test = load_dataset(data, "train"), load_dataset(data, "test")
    ours = run("nerf (defaults)", NerfConfig(), train, test, seconds)
    floor = run("floor (plain 96³ grid)", floor_config(), train, test, seconds)
    print(f"\n{'seconds':>8} {'nerf PSNR':>10} {'floor PSNR':>11}")
    for (t, p), (t2, p2) in zip(ours, floor):
        print(f"{t:8.1f} {p:10.2f} {p2:11.2f}")
    gain = ours[-1][1] - floor[-1][1]
    print(f"\nfinal after {seconds:.0f} s: nerf {ours[-1][1]:.2f} dB, floor {floor[-1][1]:.2f} dB, "
          f"difference {gain:+.2f} dB, MSE ratio floor/nerf {10 ** (gain / 10):.2f}")
    reached = next((t for t, p in ours if p >= 30.0), None)
    print("nerf reached 30 dB at " + (f"{reached:.0f} s" if reached is not None else "— (not within the budget)"))


if __name__ == "__main__":
    main()
