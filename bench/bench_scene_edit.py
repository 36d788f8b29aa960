"""Scene edits on a trained field, as a user makes them: extract, select one object, move it, render.

The scene and the trained run are :mod:`bench_scene`'s (bunny and cow on the generated floor inside the far shell;
the ``--field`` backend's defaults with their background model, trained ``--seconds`` of CPU time; cached). ``neus``
by default: its surface is what a user extracts and edits (a ``nerf`` field of the scene holds its objects as
semi-transparent volumes, below the default extraction level). The user path:
``extract_mesh`` (the foreground box), an ``objects`` spec that selects the bunny on the *extracted* mesh
(``component`` near its top, ``drop_plane``) and slides it :data:`SLIDE` along the floor, run by ``run_edit`` twice —
``vacated: empty`` and ``vacated: fill``. Ground truth: the generator's scene with the bunny moved the same way
(``scene_mesh``), rendered from the test cameras.

Measured on the test views (PSNR in dB against the ground truth of the edited scene):
- ``all``: every pixel; ``ceiling``: the unedited render against the unedited ground truth (the field's own error);
- ``rest``: pixels where the ground truths of the edited and unedited scenes agree (the other object, the floor, the
  background), and how much the edited render differs there from the unedited render (max |Δ|, mean |Δ|);
- ``arrived``: pixels the bunny covers after the edit only; ``vacated``: pixels it covered before only — what the
  floor shows where it stood, ``empty`` against ``fill``.

Usage: ``python bench/bench_scene_edit.py [--field neus] [--seconds 300] [--views 10] [--level L] [--cache DIR]``
(``--level``: the extraction level, for a field trained too briefly to reach the default one).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH.parent))
sys.path.insert(0, str(BENCH))

from bench_scene import CACHE, dataset, scene_edit, trained_run  # noqa: E402
from timing import timed  # noqa: E402

from nerfedit_plugin.bending.scene_deformation import load_deformation  # noqa: E402
from nerfedit_plugin.data.datasets import load_dataset  # noqa: E402
from nerfedit_plugin.data.scene import read_scene, scene_mesh  # noqa: E402
from nerfedit_plugin.data.synthetic import render_mesh  # noqa: E402
from nerfedit_plugin.geometry.mesh import SurfaceMesh  # noqa: E402
from nerfedit_plugin.pipeline.extract import extract_mesh  # noqa: E402
from nerfedit_plugin.render.views import default_render_config, render_views  # noqa: E402

SLIDE = (1.2, 0.0, 0.0)
"""The bunny's move along the floor (onto the empty stretch between the objects)."""


def psnr(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray) -> float:
    mse = float(((pred - gt) ** 2)[mask].mean()) if mask.any() else float("nan")
    return -10.0 * math.log10(max(mse, 1e-12))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--field", choices=("nerf", "neus"), default="neus", help="field backend to train and edit")
    parser.add_argument("--seconds", type=float, default=300.0, help="training budget of the field (CPU s)")
    parser.add_argument("--views", type=int, default=10, help="test views")
    parser.add_argument("--cache", type=Path, default=CACHE, help="dataset, run, proxies and edits (shared)")
    parser.add_argument("--level", type=float, default=None, help="extraction level (default: the field's)")
    args = parser.parse_args()
    args.cache.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    data = dataset(args.cache)
    seconds, (run, log) = timed(lambda: trained_run(args.cache, data, args.seconds, args.field))
    trained_psnr = log["eval"][-1][1] if log.get("eval") else float("nan")
    steps = log.get("steps")
    print(f"{args.field}: {steps} steps, held-out {trained_psnr:.2f} dB ({seconds:.0f} s incl. cache): {run.path}")
    if not run.mesh_path.is_file():
        seconds, _ = timed(lambda: extract_mesh(run, level=args.level, largest_component=False))  # several parts
        print(f"extracted {run.mesh_path} in {seconds:.1f} s")
    mesh = SurfaceMesh.load(run.mesh_path)
    scene = read_scene(data)
    bunny = scene.part(scene.object("bunny"))
    top = bunny.vertices[np.argmax(bunny.vertices[:, 2])]
    test = load_dataset(data, "test")
    views = list(range(min(args.views, len(test.cameras))))
    cameras = test.cameras[torch.as_tensor(views)]
    field = run.field("cpu")
    config = default_render_config(field, test.background)
    move = np.eye(4)
    move[:3, 3] = SLIDE
    gt_before = render_mesh(scene.mesh, cameras, supersample=2)[0]
    gt_after = render_mesh(scene_mesh(scene, {"bunny": move}), cameras, supersample=2)[0]
    differ = np.abs(gt_after - gt_before).max(-1) > 1e-3
    bunny_before = render_mesh(bunny, cameras)[1] > 0
    bunny_after = render_mesh(bunny.with_vertices(bunny.vertices + SLIDE), cameras)[1] > 0
    regions = {
        "all": np.ones_like(differ),
        "rest": ~differ,
        "arrived": differ & bunny_after & ~bunny_before,
        "vacated": differ & bunny_before & ~bunny_after,
    }
    before = np.stack(render_views(field, cameras, config, progress=False))
    rows = {"ceiling": {"all": psnr(before, gt_before, regions["all"])}}
    for vacated in ("empty", "fill"):
        spec = {
            "objects": [
                {
                    "name": "bunny",
                    "select": {"component": {"near": top.tolist(), "drop_plane": True}},
                    "place": {"translate": list(SLIDE)},
                    "vacated": vacated,
                }
            ]
        }
        path = args.cache / f"edit-quality-{vacated}.json"
        path.write_text(json.dumps(spec, indent=1))
        out = args.cache / f"edit-quality-{vacated}"
        seconds, result = scene_edit(run, mesh, path, out, args.cache)
        selected = result.report["objects"][0]["surface"]["vertices"]
        print(f"edit ({vacated}): {seconds:.1f} s, {selected} of {mesh.n_vertices} extracted vertices selected")
        deformation = load_deformation(out / "deformation.npz")
        after = np.stack(render_views(field, cameras, config, deformation=deformation, progress=False))
        row = {name: psnr(after, gt_after, mask) for name, mask in regions.items()}
        change = np.abs(after - before).max(-1)[regions["rest"]]
        row.update(rest_max_change=float(change.max()), rest_mean_change=float(change.mean()))
        rows[vacated] = row
    print(
        "\n| render | all | rest (others, floor, background) | arrived | vacated | rest: max / mean |Δ| vs unedited |"
    )
    print("|---|---|---|---|---|---|")
    print(f"| unedited vs its ground truth (ceiling) | {rows['ceiling']['all']:.2f} | | | | |")
    for name in ("empty", "fill"):
        r = rows[name]
        print(
            f"| edited, vacated: {name} | {r['all']:.2f} | {r['rest']:.2f} | {r['arrived']:.2f} | {r['vacated']:.2f} | "
            f"{r['rest_max_change']:.3f} / {r['rest_mean_change']:.5f} |"
        )
    print(
        f"pixels per view: rest {regions['rest'].mean():.1%}, arrived {regions['arrived'].mean():.1%}, "
        f"vacated {regions['vacated'].mean():.1%}"
    )
    (args.cache / "edit-quality.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
