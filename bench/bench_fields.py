"""Test PSNR of the ``nerf`` and ``neus`` defaults (``splats`` on request), and the Chamfer distance of the ``neus``
mesh, on a set of scenes each hard in its own way (:mod:`nerfedit_plugin.data.shapes`): a thin tube, a cup's cavity,
a tilted slab's flat faces, the bunny, and the bunny with a ~4-px texture.

    python bench/bench_fields.py [--scenes tube,cup] [--fields nerf,neus,splats] [--seconds S] [--clock {wall,cpu}]
                                 [--resolution PX] [--threads N] [--out DIR] [--set neus.eikonal_weight=1e-4 ...]
    python bench/bench_fields.py --scene [--resolution 100] [--fields ...] [--seconds S] [--clock ...] [--set ...]

Each scene is generated at 100×100 (``--resolution``; 50 train / 10 test views, white background, as
``bench/bench_train.py``) and each field trained with its default config for S seconds (default 300, the budget of the
targets) on 2 threads (``--threads``; ``splats`` trains on its ``recipe.threads``, default 1);
the figure is the PSNR over all test views at the end of the budget (curve: every 60 s), with the steps and training
seconds actually used. The in-run reference is the exact ``mesh`` field of the source mesh rendered one ray per
pixel (what the images' edge anti-aliasing costs a field rendered that way). For ``neus`` the Chamfer distance of
the extracted zero level set (256³) to the source mesh is given in % of the source bbox diagonal
(``bench_train.chamfer``). Targets: nerf ≥ 32 dB, neus ≥ 31 dB, splats ≥ 33 dB, Chamfer ≤ 0.5 %.

``--scene``: instead, the generated scene of ``SCENE_OBJECTS`` on its textured floor inside its textured far shell
(:func:`nerfedit_plugin.data.scene.generate_scene`, opaque images, ``--resolution`` px, 50 train / 10 test views),
each field trained twice — its defaults (``background="auto"``: the background model is on for opaque images) and
with ``background="color"`` (the constant-colour model of object datasets) — reporting test PSNR (target ≥ 28 dB)
and the Chamfer distance of each field's mesh (256³ over the foreground box) to the scene's geometry inside the box,
in % of the box diagonal.

Only a complete run (every scene, the default fields and budget at 100 px, no ``--set``) rewrites the table in
docs/benchmarks.md between the bench_fields markers (with ``--scene``: between the bench_fields_scene markers, both
fields at 100 px); other runs print it. ``--set FIELD.OPTION=VALUE`` overrides a
config option (a YAML value; ``neus.train.n_samples=96``) for experiments. ``--out`` keeps the datasets, the
trained fields, the ``neus`` meshes and ``results.json`` (default: a temporary folder).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import torch
import yaml
from bench_train import chamfer

from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.data.scene import generate_scene
from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset
from nerfedit_plugin.fields.mesh_field import MeshField
from nerfedit_plugin.fields.nerf import NerfConfig
from nerfedit_plugin.fields.neus import NeusConfig
from nerfedit_plugin.fields.splats.field import SplatsConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import write_text
from nerfedit_plugin.render.views import default_render_config
from nerfedit_plugin.training.trainer import evaluate

SCENES = {
    "tube": "shape:tube",
    "cup": "shape:cup",
    "slab": "shape:slab",
    "bunny": "sample:bunny",
    "bunny-fine": "shape:bunny-fine",
}
"""Scene name → the generator's ``--mesh``."""
BACKENDS = {"nerf": NerfConfig, "neus": NeusConfig, "splats": SplatsConfig}
DEFAULT_FIELDS = ("nerf", "neus")
"""The fields of a complete run (the docs table)."""
TARGETS = {"nerf": 32.0, "neus": 31.0, "splats": 33.0}
"""Test PSNR targets (dB) at the full budget (splats: nerf's + 1)."""
CHAMFER_TARGET = 0.5
"""Chamfer distance target of the neus mesh, % of the bbox diagonal."""
BUDGET = 300.0
"""Training seconds per field of the targets."""
EVAL_EVERY = 60.0
"""Training seconds between the evaluations of the PSNR curve."""
SCENE_OBJECTS = ("sample:bunny", "sample:cow")
"""The objects of ``--scene``, side by side on the floor."""
SCENE_TARGET = 28.0
"""Test PSNR target (dB) of both fields' defaults on the scene at the full budget."""
BACKGROUNDS = ("auto", "color")
"""``--scene``: each field with its defaults, then with the constant-colour background of object datasets."""
DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
MARKERS = {
    False: ("<!-- bench_fields:begin -->", "<!-- bench_fields:end -->"),
    True: ("<!-- bench_fields_scene:begin -->", "<!-- bench_fields_scene:end -->"),
}
"""The docs markers of the shape set and of ``--scene``."""


def override(config, assignment: str):
    """Apply ``OPTION.PATH=VALUE`` (after the field name) to a config dataclass; returns the new config."""
    path, _, text = assignment.partition("=")
    head, _, rest = path.partition(".")
    value = override(getattr(config, head), f"{rest}={text}") if rest else yaml.safe_load(text)
    if isinstance(getattr(config, head), tuple):
        value = tuple(value)
    return dataclasses.replace(config, **{head: value})


def measure(scene: str, name: str, data: Path, train, test, args, background: str | None = None) -> dict:
    """Train ``name``'s default config (with ``--set`` overrides, and ``background`` when given) on a scene; its
    results row. With ``background`` (``--scene``) every field's mesh is scored against the scene's geometry inside
    the foreground box, else the ``neus`` mesh against the source mesh."""
    config = BACKENDS[name]() if background is None else BACKENDS[name](background=background)
    for assignment in args.set:
        field_name, _, rest = assignment.partition(".")
        if field_name == name:
            config = override(config, rest)
    config.train = dataclasses.replace(
        config.train,
        max_seconds=args.seconds,
        eval_every_seconds=EVAL_EVERY,
        eval_views=len(test),
        progress=False,
        clock=args.clock,
    )
    field = config.setup(scene_bbox=train.scene_bbox)
    start = time.perf_counter()
    log = field.fit(train, eval_dataset=test)
    row = {
        "scene": scene,
        "field": name,
        "background": getattr(field.config, "background", "color"),
        "psnr": log["eval"][-1][1],
        "curve": [p for _, p in log["eval"][1:]],
        "steps": log["steps"],
        "train_seconds": log["train_seconds"],
        "wall_seconds": time.perf_counter() - start,
        "chamfer_percent": None,
    }
    out = args.out / scene / (name if background is None else f"{name}-{background}")
    out.mkdir(parents=True, exist_ok=True)
    field.save(out / "field.pt")
    if name == "neus" or background is not None:
        source = SurfaceMesh.load(data / "mesh.ply")
        box = train.scene_bbox.double().numpy()
        size = source.bbox_diagonal if background is None else float(((box[1] - box[0]) ** 2).sum() ** 0.5)
        try:
            mesh = field.extract_mesh(resolution=256)
        except ValueError as exc:  # no surface at the mesh level (an under-trained field): no Chamfer figure
            print(f"{scene} {name}: no mesh ({exc})", flush=True)
        else:
            mesh.save(out / "mesh.ply")
            truth = source if background is None else inside(source, box)
            row["chamfer_percent"] = 100 * chamfer(mesh, truth) / size
    print(
        f"{scene} {name}: {row['psnr']:.2f} dB after {row['steps']} steps, {row['train_seconds']:.1f} s training "
        f"({row['wall_seconds']:.1f} s with evaluation)"
        + (f", Chamfer {row['chamfer_percent']:.3f} %" if row["chamfer_percent"] is not None else ""),
        flush=True,
    )
    return row


def inside(mesh: SurfaceMesh, box) -> SurfaceMesh:
    """The faces of ``mesh`` with every vertex in ``box (2,3)``: the scene's geometry in the foreground box."""
    within = ((mesh.vertices >= box[0]) & (mesh.vertices <= box[1])).all(1)
    return SurfaceMesh(mesh.vertices, mesh.faces[within[mesh.faces].all(1)])


def reference_psnr(data: Path, test) -> float:
    """Test PSNR of the exact ``mesh`` field of the source mesh, one ray per pixel."""
    field = MeshField.from_mesh(SurfaceMesh.load(data / "mesh.ply"))
    return evaluate(field, test, default_render_config(field, test.background))


def table(rows: list[dict], references: dict[str, float]) -> str:
    """The results as a Markdown table (a missed target in bold)."""

    def mark(value: float, ok: bool, digits: int) -> str:
        return f"{value:.{digits}f}" if ok else f"**{value:.{digits}f}**"

    lines = [
        "| scene | field | test PSNR dB | target | curve dB (per 60 s; end) | Chamfer % bbox | steps | train s | "
        "exact mesh dB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        target = TARGETS[row["field"]]
        distance = row["chamfer_percent"]
        lines.append(
            f"| {row['scene']} | {row['field']} | {mark(row['psnr'], row['psnr'] >= target, 2)} | ≥ {target:.0f} | "
            + " / ".join(f"{p:.1f}" for p in row["curve"])
            + f" | {'—' if distance is None else mark(distance, distance <= CHAMFER_TARGET, 3)} | {row['steps']} | "
            f"{row['train_seconds']:.0f} | {references[row['scene']]:.2f} |"
        )
    return "\n".join(lines)


def scene_table(rows: list[dict]) -> str:
    """The ``--scene`` results as a Markdown table (a missed target in bold)."""
    lines = [
        "| field | background | test PSNR dB | target | curve dB (per 60 s; end) | Chamfer % box | steps | train s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        psnr = f"{row['psnr']:.2f}" if row["psnr"] >= SCENE_TARGET else f"**{row['psnr']:.2f}**"
        lines.append(
            f"| {row['field']} | {row['background']} | {psnr} | ≥ {SCENE_TARGET:.0f} | "
            + " / ".join(f"{p:.1f}" for p in row["curve"])
            + f" | {'—' if row['chamfer_percent'] is None else format(row['chamfer_percent'], '.3f')} | "
            f"{row['steps']} | {row['train_seconds']:.0f} |"
        )
    return "\n".join(lines)


def write_docs(text: str, scene: bool = False) -> None:
    """Replace the text between the bench_fields (``scene``: bench_fields_scene) markers of docs/benchmarks.md
    (atomically)."""
    begin_marker, end_marker = MARKERS[scene]
    docs = DOCS.read_text()
    head, begin, rest = docs.partition(begin_marker)
    _, end, tail = rest.partition(end_marker)
    if not (begin and end):
        raise SystemExit(f"{DOCS}: the markers {begin_marker} … {end_marker} are missing")
    write_text(DOCS, f"{head}{begin_marker}\n{text}\n{end_marker}{tail}")


def backgrounds(name: str) -> tuple[str | None, ...]:
    """The background variants of ``--scene`` for field ``name``: :data:`BACKGROUNDS`, or only its defaults (None)
    for a field without a ``background`` option (``splats``: the Gaussians are the background)."""
    options = {f.name for f in dataclasses.fields(BACKENDS[name])}
    return BACKGROUNDS if "background" in options else (None,)


def run_scene(args, fields: list[str]) -> None:
    """``--scene``: generate the scene, train every field with each of :data:`BACKGROUNDS`, print (and for a
    complete run write) the table."""
    started = datetime.datetime.now(datetime.timezone.utc)
    with tempfile.TemporaryDirectory() as tmp:
        args.out = args.out or Path(tmp)
        generated = GenerateConfig(
            out=args.out / "scene" / "data",
            objects=list(SCENE_OBJECTS),
            resolution=args.resolution,
            n_train=50,
            n_test=10,
            overwrite=True,
        )
        data = generate_scene(generated)
        train, test = load_dataset(data, "train"), load_dataset(data, "test")
        rows = [measure("scene", name, data, train, test, args, bg) for name in fields for bg in backgrounds(name)]
        (args.out / "results.json").write_text(json.dumps({"rows": rows}, indent=2))
    text = scene_table(rows)
    print(f"\n{text}")
    if (
        fields == list(DEFAULT_FIELDS)
        and args.seconds == BUDGET
        and args.resolution == 100
        and args.threads == 2
        and not args.set
    ):
        load = os.getloadavg()
        write_docs(
            f"`python {' '.join(sys.argv)}` ({started:%Y-%m-%d %H:%M} UTC, {args.clock} clock, load average at the "
            f"end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}): {' and '.join(SCENE_OBJECTS)} on the generated "
            f"floor inside the far shell, {args.resolution}×{args.resolution}, 50 train / 10 test views; each field "
            f"with its defaults (`auto`: the background model on) and with `background=color`, budget "
            f"{BUDGET:.0f} s of training per run (evaluation excluded), 2 threads. Target: ≥ {SCENE_TARGET:.0f} dB "
            f"(misses in bold). Chamfer: the field's mesh (256³ over the foreground box) against the scene's "
            f"faces inside the box, % of the box diagonal.\n\n{text}",
            scene=True,
        )
        print(f"\nwritten to {DOCS}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default=",".join(SCENES), help=f"comma-separated, of {', '.join(SCENES)}")
    parser.add_argument("--fields", default=",".join(DEFAULT_FIELDS), help="comma-separated, of nerf, neus, splats")
    parser.add_argument("--seconds", type=float, default=BUDGET, help="training budget per field")
    parser.add_argument(
        "--clock", choices=("wall", "cpu"), default="wall", help="training clock (see TrainerConfig.clock)"
    )
    parser.add_argument("--out", type=Path, default=None, help="keep datasets, fields and results here")
    parser.add_argument("--set", action="append", default=[], help="FIELD.OPTION=VALUE config override")
    parser.add_argument("--scene", action="store_true", help="the generated scene with floor and far shell instead")
    parser.add_argument("--resolution", type=int, default=100, help="image width and height")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (a complete run: 2)")
    args = parser.parse_args()
    scenes, fields = args.scenes.split(","), args.fields.split(",")
    unknown = sorted(set(scenes) - set(SCENES)) + sorted(set(fields) - set(BACKENDS))
    if unknown:
        parser.error(f"unknown scene or field: {', '.join(unknown)}")
    torch.set_num_threads(args.threads)
    if args.scene:
        run_scene(args, fields)
        return
    started = datetime.datetime.now(datetime.timezone.utc)
    with tempfile.TemporaryDirectory() as tmp:
        args.out = args.out or Path(tmp)
        rows, references = [], {}
        for scene in scenes:
            data = generate_dataset(
                GenerateConfig(
                    out=args.out / scene / "data",
                    mesh=SCENES[scene],
                    n_train=50,
                    n_test=10,
                    resolution=args.resolution,
                    overwrite=True,
                )
            )
            train, test = load_dataset(data, "train"), load_dataset(data, "test")
            references[scene] = reference_psnr(data, test)
            rows.extend(measure(scene, name, data, train, test, args) for name in fields)
        (args.out / "results.json").write_text(json.dumps({"rows": rows, "references": references}, indent=2))
    text = table(rows, references)
    print(f"\n{text}")
    complete = scenes == list(SCENES) and fields == list(DEFAULT_FIELDS) and args.seconds == BUDGET
    complete = complete and args.resolution == 100 and args.threads == 2 and not args.set
    if complete:
        load = os.getloadavg()
        write_docs(
            f"`python {' '.join(sys.argv)}` ({started:%Y-%m-%d %H:%M} UTC, {args.clock} clock, load average at the "
            f"end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}): every field with its default config, budget "
            f"{BUDGET:.0f} s of training per field (evaluation excluded), 2 threads. Targets: nerf ≥ "
            f"{TARGETS['nerf']:.0f} dB and neus ≥ {TARGETS['neus']:.0f} dB on every scene, neus mesh Chamfer ≤ "
            f"{CHAMFER_TARGET} % of the bbox diagonal; misses in bold. *exact mesh*: the source mesh rendered by the "
            f"`mesh` field, one ray per pixel.\n\n{text}"
        )
        print(f"\nwritten to {DOCS}")


if __name__ == "__main__":
    main()
