"""Inversion-free lift vs soft ARAP lift (docs/benchmarks.md), both measured in this run.

For the demo's edit (:func:`nerfedit_plugin.demo.nod_edit` on the pymeshlab bunny, standing in for the trained
field's mesh) and each cheap example config in ``configs/`` (``cage_bunny_files.yaml`` needs hand-made cage files:
skipped): deform the surface with the config's deformer, build the bunny's (or airplane's) tet proxy once (cached in
/tmp), then time ``Lift`` (set-up + every frame) with ``LiftConfig(injective=False)`` (today's soft ARAP lift) and
with the default (soft ARAP, re-lifted inversion-free where it folds). Prints, per case, the worst frame's inverted
tets, max residual (× bbox diagonal) and flipped surface faces of each, and the time ratio new / old (target ≤ 2 on
the demo's edit). The best of ``--repeat`` runs is timed.

Usage: ``python bench/bench_lift.py [--quick] [--repeat N]`` (quick: the demo's edit and the bunny head only).
"""

from __future__ import annotations

import argparse
import functools
import json
import tempfile
from pathlib import Path

from timing import best_of, timed

from nerfedit_plugin.demo import nod_edit
from nerfedit_plugin.edit.lift import Lift, LiftConfig
from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy
from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.samples import sample_mesh_path
from nerfedit_plugin.registry import DEFORMERS, discover

ROOT = Path(__file__).resolve().parents[1]
CACHE = Path("/tmp/nerfedit_bench_lift_proxies")
CASES = {  # name: (sample mesh, deformer, edit spec under configs/ or None for the demo's edit)
    "demo nod (bunny)": ("bunny", "arap", None),
    "arap_bunny_head": ("bunny", "arap", "arap_bunny_head.json"),
    "arap_bunny_ears": ("bunny", "arap", "arap_bunny_ears.json"),
    "arap_airplane_wings": ("airplane", "arap", "arap_airplane_wings.json"),
    "cage_bunny_auto": ("bunny", "cage", "cage_bunny_auto.json"),
    "skeleton_bunny_pose": ("bunny", "skeleton", "skeleton_bunny_pose.json"),
    "skeleton_bunny_bvh": ("bunny", "skeleton", "skeleton_bunny_bvh.json"),
}
QUICK = ("demo nod (bunny)", "arap_bunny_head")


def frames_of(mesh: str, deformer: str, spec: str | None, workdir: Path):
    """(rest SurfaceMesh, tet proxy, surface frames (F,V,3))."""
    rest = SurfaceMesh.load(sample_mesh_path(mesh))
    config = discover().config_class(DEFORMERS, deformer)()
    if spec is None:
        path = workdir / "nod.json"
        path.write_text(json.dumps(nod_edit(rest)))
    else:
        path = ROOT / "configs" / spec
    model = config.setup()
    model.bind(rest, load_edit_spec(path, config._target.spec_keys))
    frames = model.deform()
    proxy, _ = cached_proxy(rest, ProxyConfig(), CACHE)
    return rest, proxy, frames


def lift(proxy, rest, config, frames):
    """Bind and run one lift over all frames (the timed unit: set-up included, as in run_edit)."""
    return Lift(proxy, rest, config=config)(frames)


def worst(reports) -> str:
    inverted = max(r.inverted_tets for r in reports)
    residual = max(r.residual_max for r in reports)
    flipped = max(r.flipped_surface_faces for r in reports)
    return f"inverted {inverted:4d}  residual max {residual:.2e}  flipped faces {flipped:4d}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the demo's edit and the bunny head only")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per lift (best of)")
    args = parser.parse_args()
    ratios = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (mesh, deformer, spec) in CASES.items():
            if args.quick and name not in QUICK:
                continue
            rest, proxy, frames = frames_of(mesh, deformer, spec, Path(tmp))
            print(f"{name}: {len(frames)} frame(s), surface {rest.n_vertices} vertices, proxy {len(proxy.tets)} tets")
            row = {}
            for label, config in (("soft ARAP", LiftConfig(injective=False)), ("inversion-free", LiftConfig())):
                run = functools.partial(lift, proxy, rest, config, frames)
                _, (_, reports) = timed(run)
                row[label] = best_of(run, args.repeat)
                print(f"  {label:15s} {row[label]:7.3f} s  {worst(reports)}")
            ratios[name] = row["inversion-free"] / row["soft ARAP"]
            print(f"  RATIO {name} (inversion-free / soft ARAP lift time) = {ratios[name]:.2f}", flush=True)
    print("RATIOS " + "  ".join(f"{k} {v:.2f}" for k, v in ratios.items()))


if __name__ == "__main__":
    main()
