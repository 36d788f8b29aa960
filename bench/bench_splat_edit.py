"""The splat edit against an exact ground truth: Gaussians on a capsule's surface, bent by a known smooth map.

    python bench/bench_splat_edit.py [--gaussians N] [--resolution PX] [--bend RAD] [--proxy OPTION=VALUE ...]
                                     [--out DIR]

The model: ``N`` flat Gaussians (disks of radius 0.02, a tenth as thick) on the surface of a capsule (height 1.2,
radius 0.3, edges subdivided to at most 0.04), each with a random DC colour and degree-3 view-dependent terms. The
edit: the capsule's mesh bent by ``φ`` (a bend about y of ``RAD`` radians per unit of height, and a twist about z of
half that) is given to ``nerfedit edit --deformer mesh`` on the splat run, which lifts it into the tet proxy
(``deformation.npz``; ``--proxy edge-length-fac=0.025`` becomes ``--proxy.edge-length-fac 0.025``). The ground
truth: the same Gaussians moved by ``φ`` itself and its exact Jacobian at each mean (an analytic
:class:`~nerfedit_plugin.bending.maps.ForwardMap` through the same ``deform_model``). Both are rendered from 8
cameras around the bent capsule; the figure is the PSNR of the edit's renders against the ground truth's, and the
seconds of the forward map.

    python bench/bench_splat_edit.py --map [--sizes N ...] [--frames F] [--resolution PX]

``--map`` times the forward map alone, per frame of an animation: a 12³ Kuhn grid proxy of the cube [-1, 1]³
(10,368 tets) bent and stretched over ``F`` frames (frame ``k`` is ``(k+1)/F`` of the way to the bar of
:func:`proxy_frames`), carrying synthetic degree-3 models of ``N`` Gaussians (means uniform in the ball of radius
0.8, every Gaussian moving; scales log-uniform in [0.003, 0.03]). The first frame also locates the rest means (once
per model and proxy); frames 1.. are the per-frame cost (their median, best and worst, wall and process CPU seconds).
Anchor, measured in the same run: one copy of the model's arrays (the memory traffic every map pays, best of 3);
and for the smallest size, one 256² render of the unedited model (distance 2.8, 0.8 rad field of view; best of 3).
The numba kernels are compiled (or loaded from numba's cache) before timing; the load average is printed with each
size.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import trimesh
from timing import best_of

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.bending.maps import DeformedPoints
from nerfedit_plugin.cli import main
from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.fields.splats.deform import deform_model
from nerfedit_plugin.fields.splats.field import SplatsField
from nerfedit_plugin.fields.splats.files import write_ply
from nerfedit_plugin.fields.splats.model import surface_model, synthetic_model
from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets
from nerfedit_plugin.render.renderer import RenderConfig
from nerfedit_plugin.render.views import turntable_cameras


def bend(x: torch.Tensor, rate: float) -> torch.Tensor:
    """``φ``: a twist about z of ``rate / 2`` rad per unit height, then a bend about y of ``rate``."""
    z = x[:, 2] + 0.9
    twist, angle = 0.5 * rate * z, rate * z
    u = x[:, 0] * torch.cos(twist) - x[:, 1] * torch.sin(twist)
    v = x[:, 0] * torch.sin(twist) + x[:, 1] * torch.cos(twist)
    radius = 1.0 / rate
    return torch.stack([(u - radius) * torch.cos(angle) + radius, v, (radius - u) * torch.sin(angle) - 0.9], 1)


class AnalyticMap:
    """``φ`` and its Jacobian (autograd) everywhere: a ForwardMap of one frame."""

    n_frames = 1

    def __init__(self, rate: float) -> None:
        self.rate = rate

    def to_deformed(self, x: torch.Tensor, frame: int = 0) -> DeformedPoints:
        x = x.double()
        jacobian = torch.func.vmap(torch.func.jacrev(lambda p: bend(p[None], self.rate)[0]))(x)
        return DeformedPoints(bend(x, self.rate), torch.ones(len(x), dtype=torch.bool), jacobian)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10.0 * math.log10(max(float(np.mean((a - b) ** 2)), 1e-12)))


def run(out: Path, gaussians: int, resolution: int, rate: float, proxy: list[str]) -> dict:
    capsule = trimesh.creation.capsule(height=1.2, radius=0.3, count=[48, 24])
    vertices, faces = trimesh.remesh.subdivide_to_size(capsule.vertices, capsule.faces, max_edge=0.04)
    capsule = trimesh.Trimesh(vertices, faces)  # its cylinder is one band of faces: subdivided, the mesh can bend
    capsule.export(out / "capsule.ply")
    model = surface_model(capsule, gaussians)
    write_ply(model, out / "model.ply")
    bent = bend(torch.from_numpy(np.asarray(capsule.vertices)), rate).numpy()
    trimesh.Trimesh(bent, capsule.faces, process=False).export(out / "bent.ply")
    (out / "edit.json").write_text(json.dumps({"deformed": "bent.ply"}))
    assert main(["train", "--field", "splats", "--data", str(out / "model.ply"), "--out", str(out / "run")]) == 0
    args = ["edit", "--run", str(out / "run"), "--mesh", str(out / "capsule.ply"), "--deformer", "mesh"]
    args += [part for option in proxy for part in ("--proxy." + option.split("=")[0], option.split("=", 1)[1])]
    assert main([*args, "--edit", str(out / "edit.json"), "--out", str(out / "edit"), "--overwrite"]) == 0
    deformation = DeformationField.load(out / "edit" / "deformation.npz")
    start = time.perf_counter()
    edited, report = deform_model(model, deformation)
    seconds = time.perf_counter() - start
    truth, _ = deform_model(model, AnalyticMap(rate))
    box = torch.tensor(np.stack([bent.min(0), bent.max(0)]), dtype=torch.float32)
    cameras = turntable_cameras(box, 8, resolution, elevation_degrees=25.0, distance=2.2)
    config = RenderConfig(background=(1.0, 1.0, 1.0))
    scores = []
    for i in range(len(cameras)):
        a = SplatsField.from_model(edited).render(cameras, i, config).numpy()
        b = SplatsField.from_model(truth).render(cameras, i, config).numpy()
        scores.append(psnr(a, b))
    return {
        "gaussians": gaussians,
        "proxy": {"options": proxy, "tets": len(deformation.tets)},
        "resolution": resolution,
        "bend_rad_per_unit": rate,
        "psnr_db": {"mean": float(np.mean(scores)), "min": float(np.min(scores))},
        "moved": report.moved,
        "outside_proxy": gaussians - report.moved,
        "inverted": report.inverted,
        "anisotropy_growth": report.growth,
        "forward_map_s": seconds,
    }


def proxy_frames(frames: int) -> DeformationField:
    """The 12³ Kuhn grid of [-1, 1]³ bent about y (0.4 rad per unit of height), sheared and stretched (y by up to
    1.4, z by 1.3), reached in ``frames`` equal steps (frame ``k``: ``(k+1)/frames`` of the displacement)."""
    vertices, tets = kuhn_grid(12, np.full(3, -1.0), np.full(3, 1.0))
    x, y, z = vertices.T
    h = z + 1.0
    bent = np.stack([x * np.cos(0.4 * h) + 0.3 * h * np.sin(0.4 * h) - 0.2 * y, y * (1 + 0.2 * h), 1.3 * z], 1)
    steps = [vertices + (bent - vertices) * (k + 1) / frames for k in range(frames)]
    return DeformationField(vertices, orient_tets(vertices, tets), np.stack(steps))


def _load() -> str:
    return "load " + " ".join(f"{x:.2f}" for x in os.getloadavg())


def time_map(sizes: list[int], frames: int, resolution: int) -> dict:
    """The ``--map`` measurements (module docstring) → per size, the seconds and ratios (also printed)."""
    field = proxy_frames(frames)
    deform_model(synthetic_model(2000, 3, seed=1), field, 0)  # compile or load the kernels
    results = {}
    for n in sizes:
        model = synthetic_model(n, 3, seed=0, radius=0.8, scale=(0.003, 0.03))
        print(f"\n== {n} Gaussians, {len(field.tets)} tets, {frames} frames ({_load()})")
        start, cpu = time.perf_counter(), time.process_time()
        _, report = deform_model(model, field, 0)
        first = (time.perf_counter() - start, time.process_time() - cpu)
        wall, process = [], []
        for frame in range(1, frames):
            start, cpu = time.perf_counter(), time.process_time()
            deform_model(model, field, frame)
            wall.append(time.perf_counter() - start)
            process.append(time.process_time() - cpu)
        anchor = best_of(lambda model=model: [a.copy() for a in model.arrays()], 3)
        median = statistics.median(wall)
        row = {
            "gaussians": n,
            "moved": report.moved,
            "first_frame_s": first[0],
            "per_frame_s": {"median": median, "best": min(wall), "worst": max(wall)},
            "per_frame_cpu_s": statistics.median(process),
            "anchor_copy_s": anchor,
            "ratio_to_copy": median / anchor,
        }
        print(f"first frame (locates the means): {first[0]:.3f} s wall, {first[1]:.3f} s CPU; moved {report.moved}")
        print(
            f"per frame: {median:.3f} s median (best {min(wall):.3f}, worst {max(wall):.3f}), "
            f"{row['per_frame_cpu_s']:.3f} s CPU ({_load()})"
        )
        print(f"anchor, one copy of the model's arrays: {anchor * 1e3:.1f} ms; ratio {median / anchor:.1f}x")
        if n == min(sizes):
            splats = SplatsField.from_model(model)
            c2w = look_at(torch.tensor([[0.0, -2.8, 0.0]]), torch.zeros(1, 3))
            camera = Cameras.from_fov(c2w, resolution, resolution, 0.8)
            render = best_of(lambda s=splats, c=camera: s.render(c, 0, RenderConfig()), 3, warmup=True)
            row.update({"render_s": render, "ratio_to_render": median / render})
            print(f"one {resolution}² render of the model: {render:.3f} s; map / render = {median / render:.2f}")
        results[n] = row
    return results


def main_bench() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussians", type=int, default=50000)
    parser.add_argument("--resolution", type=int, default=None, help="render size (128; 256 with --map)")
    parser.add_argument("--bend", type=float, default=0.8)
    parser.add_argument("--proxy", nargs="*", default=[], help="proxy options OPTION=VALUE (nerfedit edit --proxy.*)")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--map", action="store_true", help="time the forward map per frame instead (docstring)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[200_000, 1_000_000])
    parser.add_argument("--frames", type=int, default=6)
    options = parser.parse_args()
    if options.map:
        print(json.dumps(time_map(options.sizes, max(2, options.frames), options.resolution or 256), indent=2))
        return
    options.resolution = options.resolution or 128
    with tempfile.TemporaryDirectory() as scratch:
        out = options.out or Path(scratch)
        out.mkdir(parents=True, exist_ok=True)
        print(json.dumps(run(out, options.gaussians, options.resolution, options.bend, options.proxy), indent=2))


if __name__ == "__main__":
    main_bench()
