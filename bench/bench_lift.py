"""Inversion-free lift vs soft ARAP lift (docs/benchmarks.md), both measured in this run.

For the demo's edit (:func:`~nerfedit_plugin.pipeline.demo.nod_edit` on the pymeshlab bunny in the generator's frame —
z up, normalised — standing in for the trained field's mesh), each cheap example config in ``configs/`` (on the sample
meshes as they are; ``cage_bunny_files.yaml`` needs hand-made cage files: skipped) and a tube bent by a cage (fixed
base, tip moved sideways by 17 % of its length): deform the surface with the deformer, build the tet proxy once
(cached in /tmp), then time ``Lift`` (set-up + every frame) three ways: the soft ARAP lift of before
(``injective=False, refine_rounds=0``), the inversion-free lift on the proxy as built (``refine_rounds=0``) and the
default (inversion-free, proxy refined where the fit misses the surface by more than ``residual_target``). Prints,
per case and way, the worst frame's inverted tets, max residual (× bbox diagonal), flipped surface faces, surface faces
pushed through others (counted in frames whose lift misses its residual target) and tets, and the time ratios
against the soft ARAP lift (target for the inversion-free lift: ≤ 2 on the demo's edit). The best of
``--repeat`` runs is timed, by the wall clock and by the process's CPU clock (all threads; steadier on a shared
machine): ``RATIO`` lines give the wall-clock ratio, then the CPU-clock one.

Usage: ``python bench/bench_lift.py [--quick] [--repeat N]`` (quick: the demo's edit, the bunny head and the tube).
"""

from __future__ import annotations

import argparse
import functools
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from timing import timed

from nerfedit_plugin.data.synthetic import normalize
from nerfedit_plugin.edit.lift import Lift, LiftConfig
from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy
from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.samples import sample_mesh_path
from nerfedit_plugin.pipeline.demo import nod_edit
from nerfedit_plugin.registry import DEFORMERS, discover

ROOT = Path(__file__).resolve().parents[1]
CACHE = Path("/tmp/nerfedit_bench_lift_proxies")
CASES = {  # name: (mesh, deformer, edit spec under configs/, the demo's edit, or the tube's cage edit)
    "demo nod (bunny)": ("bunny", "arap", "demo"),
    "arap_bunny_head": ("bunny", "arap", "arap_bunny_head.json"),
    "arap_bunny_ears": ("bunny", "arap", "arap_bunny_ears.json"),
    "arap_airplane_wings": ("airplane", "arap", "arap_airplane_wings.json"),
    "cage_bunny_auto": ("bunny", "cage", "cage_bunny_auto.json"),
    "skeleton_bunny_pose": ("bunny", "skeleton", "skeleton_bunny_pose.json"),
    "skeleton_bunny_bvh": ("bunny", "skeleton", "skeleton_bunny_bvh.json"),
    "tube, cage tip 17 % sideways": ("tube", "cage", "tube"),
}
TUBE_EDIT = {
    "cage": "auto",
    "handles": [
        {"select": {"box": {"min": [-1, -1, -2], "max": [1, 1, -0.7]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.7], "max": [1, 1, 2]}}, "transform": {"translate": [0.35, 0, 0]}},
    ],
}
WAYS = {
    "soft ARAP": LiftConfig(injective=False, refine_rounds=0),
    "inversion-free": LiftConfig(refine_rounds=0),
    "default (refined)": LiftConfig(),
}
QUICK = ("demo nod (bunny)", "arap_bunny_head", "tube, cage tip 17 % sideways")


def rest_mesh(mesh: str, spec: str) -> SurfaceMesh:
    """The case's rest surface: the sample as it is, the bunny in the generator's frame for the demo's edit, or a
    closed tube along z (radius 0.25, z in [-1, 1], edges ≤ 0.05)."""
    if mesh == "tube":
        tube = trimesh.creation.cylinder(radius=0.25, height=2.0, sections=24)
        return SurfaceMesh(*trimesh.remesh.subdivide_to_size(tube.vertices, tube.faces, max_edge=0.05))
    rest = SurfaceMesh.load(sample_mesh_path(mesh))
    if spec == "demo":  # the generator's up_axis="y": (x, y, z) -> (x, -z, y), then normalised
        x, y, z = rest.vertices.T
        rest = normalize(rest.with_vertices(np.stack([x, -z, y], axis=1)))
    return rest


def frames_of(mesh: str, deformer: str, spec: str, workdir: Path):
    """(rest SurfaceMesh, tet proxy, surface frames (F,V,3))."""
    rest = rest_mesh(mesh, spec)
    config = discover().config_class(DEFORMERS, deformer)()
    if spec in ("demo", "tube"):
        path = workdir / f"{spec}.json"
        path.write_text(json.dumps(nod_edit(rest) if spec == "demo" else TUBE_EDIT))
    else:
        path = ROOT / "configs" / spec
    model = config.setup()
    model.bind(rest, load_edit_spec(path, config._target.spec_keys))
    frames = model.deform()
    proxy, _ = cached_proxy(rest, ProxyConfig(), CACHE)
    return rest, proxy, frames


def lift(proxy, rest, config, frames):
    """Bind and run one lift over all frames (the timed unit: set-up and refinement included, as in run_edit) →
    (the Lift, its reports)."""
    bound = Lift(proxy, rest, config=config)
    return bound, bound(frames)[1]


def best_times(fn, repeat: int) -> tuple[float, float]:
    """(smallest wall seconds, smallest CPU seconds of this process) over ``repeat`` calls ``fn()``."""
    wall, cpu = [], []
    for _ in range(repeat):
        start_wall, start_cpu = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - start_wall)
        cpu.append(time.process_time() - start_cpu)
    return min(wall), min(cpu)


def worst(bound: Lift, reports) -> str:
    inverted = max(r.inverted_tets for r in reports)
    residual = max(r.residual_max for r in reports)
    flipped = max(r.flipped_surface_faces for r in reports)
    crossing = max(r.crossing_surface_faces or 0 for r in reports)  # counted only where the lift misses its target
    tets = len(bound.proxy.tets)
    return (
        f"inverted {inverted:4d}  residual max {residual:.2e}  flipped faces {flipped:4d}  crossing faces {crossing:4d}"
        f"  tets {tets}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the demo's edit, the bunny head and the tube")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per lift (best of)")
    args = parser.parse_args()
    ratios = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (mesh, deformer, spec) in CASES.items():
            if args.quick and name not in QUICK:
                continue
            rest, proxy, frames = frames_of(mesh, deformer, spec, Path(tmp))
            print(f"{name}: {len(frames)} frame(s), surface {rest.n_vertices} vertices, proxy {len(proxy.tets)} tets")
            row, cpu = {}, {}
            for label, config in WAYS.items():
                run = functools.partial(lift, proxy, rest, config, frames)
                _, (bound, reports) = timed(run)
                row[label], cpu[label] = best_times(run, args.repeat)
                print(f"  {label:18s} {row[label]:7.3f} s (CPU {cpu[label]:7.3f} s)  {worst(bound, reports)}")
            for label in list(WAYS)[1:]:
                key = f"{name} / {label}"
                ratios[key] = row[label] / row["soft ARAP"], cpu[label] / cpu["soft ARAP"]
                wall, clock = ratios[key]
                print(f"  RATIO {name}: {label} / soft ARAP lift time = {wall:.2f} (CPU {clock:.2f})", flush=True)
    print("RATIOS " + "  ".join(f"{k} {wall:.2f} (CPU {c:.2f})" for k, (wall, c) in ratios.items()), flush=True)


if __name__ == "__main__":
    main()
