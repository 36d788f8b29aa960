"""The ``nerf`` and ``neus`` defaults (``splats`` on request) on a varied set of generated scenes, each hard in its
own way: test PSNR, SSIM, LPIPS, the surface noise of the renders and the Chamfer distance of the extracted mesh.

    python bench/bench_fields.py [--scenes tube,floor-alpha,...] [--fields nerf,neus,splats] [--seconds S]
                                 [--clock {wall,cpu}] [--resolution PX] [--threads N] [--out DIR]
                                 [--set neus.eikonal_weight=1e-4 ...]

The set (:data:`SCENES`): five objects on a transparent background (a thin tube, a cup's cavity, a tilted slab's flat
faces, the bunny, the bunny with a ~4-px texture), the paper bench's articulated figure (``bench/articulated.py``),
and three scenes (:func:`nerfedit_plugin.data.scene.generate_scene`): the bunny and the cow on the textured floor
inside the far shell (opaque images); a tube and a slab on the floor with nothing around it, so the images are
transparent beyond the floor's edge and the floor runs out of every frame (a film-transparent render of objects on
a floor); and the bunny and the cow in a room, the textured sphere around them brought to 5 units from the centre
(walls about twice the object distance from the cameras). Each is generated at 100×100 (``--resolution``; 50 train
/ 10 test views, 60 train for the floor scene) and each field trained with its default config for S seconds
(default 300, the budget of the targets) on 2 threads (``--threads``; ``splats`` trains on its ``recipe.threads``).

Per row: the PSNR over all test views at the end of the budget (curve: every 60 s) with the steps and training
seconds used; the mean SSIM, LPIPS (None without its offline weights) and surface noise
(:func:`~nerfedit_plugin.training.metrics.surface_noise`: RMS of the high-frequency part of the error over the
ground truth's opaque pixels) of the test renders; the Chamfer distance (``bench_train.chamfer``) of the mesh
extracted at 256³ — on an object, the ``neus`` mesh against the source mesh in % of its bbox diagonal; on a scene,
every field's mesh over the foreground box against the scene's faces inside it, in % of the box diagonal. The
object rows also give the exact ``mesh`` field of the source rendered one ray per pixel (what the images' edge
anti-aliasing costs a field rendered that way). Targets: objects nerf ≥ 32 dB, neus ≥ 31 dB, splats ≥ 33 dB, neus
Chamfer ≤ 0.5 %; scenes ≥ 28 dB.

Every row is written to ``OUT/SCENE/FIELD.json`` as it finishes, with the settings it was measured with; a run with
the same ``--out`` and settings keeps the rows already there, so a full run (~100 min of training) can be split
across sessions: ``--scenes`` picks what to add, and the table covers every row in ``OUT`` measured with the run's
settings. Only a table of every scene × the default fields at the default budget, 100 px and 2 threads without
``--set`` rewrites the one in docs/benchmarks.md between the bench_fields markers; other runs print it.
``--set FIELD.OPTION=VALUE`` overrides a config option (a YAML value; ``neus.train.n_samples=96``) for experiments.
``--out`` also keeps the datasets, the trained fields and the meshes (default: a temporary folder).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import os
import tempfile
import time
from pathlib import Path

import torch
import yaml
from articulated import build_subject
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
from nerfedit_plugin.render.renderer import render_image
from nerfedit_plugin.render.views import default_render_config
from nerfedit_plugin.training.metrics import image_metrics
from nerfedit_plugin.training.trainer import evaluate


@dataclasses.dataclass(frozen=True)
class BenchScene:
    """One scene of the set: an object (``mesh``: the generator's ``--mesh``, or ``articulated`` for the paper
    bench's figure) or a scene (``objects`` on the generator's floor), with further generator ``options``."""

    mesh: str | None = None
    objects: tuple[str, ...] = ()
    options: tuple[tuple[str, object], ...] = ()
    n_train: int = 50

    @property
    def is_scene(self) -> bool:
        return bool(self.objects)


SCENES = {
    "tube": BenchScene("shape:tube"),
    "cup": BenchScene("shape:cup"),
    "slab": BenchScene("shape:slab"),
    "bunny": BenchScene("sample:bunny"),
    "bunny-fine": BenchScene("shape:bunny-fine"),
    "articulated": BenchScene("articulated"),
    "scene": BenchScene(objects=("sample:bunny", "sample:cow")),
    "floor-alpha": BenchScene(objects=("shape:tube", "shape:slab"), options=(("background", False),), n_train=60),
    "room": BenchScene(objects=("sample:bunny", "sample:cow"), options=(("background_radius", 5.0),)),
}
"""Scene name → how it is generated (module docstring)."""
BACKENDS = {"nerf": NerfConfig, "neus": NeusConfig, "splats": SplatsConfig}
DEFAULT_FIELDS = ("nerf", "neus")
"""The fields of a complete run (the docs table)."""
TARGETS = {"nerf": 32.0, "neus": 31.0, "splats": 33.0}
"""Test PSNR targets (dB) on the objects at the full budget (splats: nerf's + 1)."""
SCENE_TARGET = 28.0
"""Test PSNR target (dB) of every field on the scenes at the full budget."""
CHAMFER_TARGET = 0.5
"""Chamfer distance target of the neus mesh of an object, % of the bbox diagonal."""
BUDGET = 300.0
"""Training seconds per field of the targets."""
EVAL_EVERY = 60.0
"""Training seconds between the evaluations of the PSNR curve."""
DOCS = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
MARKERS = ("<!-- bench_fields:begin -->", "<!-- bench_fields:end -->")


def override(config, assignment: str):
    """Apply ``OPTION.PATH=VALUE`` (after the field name) to a config dataclass; returns the new config."""
    path, _, text = assignment.partition("=")
    head, _, rest = path.partition(".")
    value = override(getattr(config, head), f"{rest}={text}") if rest else yaml.safe_load(text)
    if isinstance(getattr(config, head), tuple):
        value = tuple(value)
    return dataclasses.replace(config, **{head: value})


def configured(name: str, args):
    """Field ``name``'s default config with the ``--set`` overrides of that field."""
    config = BACKENDS[name]()
    for assignment in args.set:
        field_name, _, rest = assignment.partition(".")
        if field_name == name:
            config = override(config, rest)
    return config


def settings(args, name: str) -> dict:
    """What a row of field ``name`` is measured with, its config's options included (a kept row is reused only
    under the same settings)."""
    options = json.dumps(dataclasses.asdict(configured(name, args)), sort_keys=True, default=str)
    return {
        "seconds": args.seconds,
        "clock": args.clock,
        "resolution": args.resolution,
        "threads": args.threads,
        "set": sorted(a for a in args.set if a.partition(".")[0] == name),
        "config_sha256": hashlib.sha256(options.encode()).hexdigest(),
    }


def generate(name: str, folder: Path, resolution: int) -> Path:
    """The dataset of scene ``name`` in ``folder`` (kept when it is already there)."""
    if (folder / "transforms_test.json").exists():
        return folder
    spec = SCENES[name]
    config = GenerateConfig(out=folder, resolution=resolution, n_train=spec.n_train, n_test=10, overwrite=True)
    config = dataclasses.replace(config, **dict(spec.options))
    if spec.is_scene:
        return generate_scene(dataclasses.replace(config, objects=list(spec.objects)))
    if spec.mesh == "articulated":
        mesh = folder.parent / "subject.ply"
        build_subject().mesh.save(mesh)
        return generate_dataset(dataclasses.replace(config, mesh=str(mesh), up_axis="z", keep_colors=True))
    return generate_dataset(dataclasses.replace(config, mesh=spec.mesh))


def measure(scene: str, name: str, data: Path, train, test, args) -> dict:
    """Train ``name``'s default config (with ``--set`` overrides) on a scene; its results row (module docstring)."""
    config = configured(name, args)
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
        "background": getattr(field.config, "background", None),
        "psnr": log["eval"][-1][1],
        "curve": [p for _, p in log["eval"][1:]],
        "steps": log["steps"],
        "train_seconds": log["train_seconds"],
        "wall_seconds": time.perf_counter() - start,
        "chamfer_percent": None,
    }
    out = args.out / scene / name
    out.mkdir(parents=True, exist_ok=True)
    field.save(out / "field.pt")
    row.update(image_scores(field, test))
    is_scene = SCENES[scene].is_scene
    if name == "neus" or is_scene:
        source = SurfaceMesh.load(data / "mesh.ply")
        box = train.scene_bbox.double().numpy()
        size = float(((box[1] - box[0]) ** 2).sum() ** 0.5) if is_scene else source.bbox_diagonal
        try:
            mesh = field.extract_mesh(resolution=256)
        except ValueError as exc:  # no surface at the mesh level (an under-trained field): no Chamfer figure
            print(f"{scene} {name}: no mesh ({exc})", flush=True)
        else:
            mesh.save(out / "mesh.ply")
            row["chamfer_percent"] = 100 * chamfer(mesh, inside(source, box) if is_scene else source) / size
    print(
        f"{scene} {name}: {row['psnr']:.2f} dB after {row['steps']} steps, {row['train_seconds']:.1f} s training "
        f"({row['wall_seconds']:.1f} s with evaluation), SSIM {row['ssim']:.4f}"
        + (f", noise {row['noise']:.4f}" if row["noise"] is not None else "")
        + (f", Chamfer {row['chamfer_percent']:.3f} %" if row["chamfer_percent"] is not None else ""),
        flush=True,
    )
    return row


def image_scores(field, test) -> dict:
    """Mean SSIM, LPIPS (None without its weights) and surface noise (over the ground truth's opaque pixels) of
    ``field``'s renders of every test view."""
    config = default_render_config(field, test.background)
    scores = []
    for i in range(len(test)):
        image = render_image(field, test.cameras, i, config).cpu().numpy()
        alpha = None if test.alpha is None else test.alpha[i].numpy()
        scores.append(image_metrics(image, test.images[i].numpy(), alpha))
    return {
        key: None if any(s[key] is None for s in scores) else sum(s[key] for s in scores) / len(scores)
        for key in ("ssim", "lpips", "noise")
    }


def inside(mesh: SurfaceMesh, box) -> SurfaceMesh:
    """The faces of ``mesh`` with every vertex in ``box (2,3)``: the scene's geometry in the foreground box."""
    within = ((mesh.vertices >= box[0]) & (mesh.vertices <= box[1])).all(1)
    return SurfaceMesh(mesh.vertices, mesh.faces[within[mesh.faces].all(1)])


def reference_psnr(data: Path, test) -> float:
    """Test PSNR of the exact ``mesh`` field of the source mesh, one ray per pixel."""
    field = MeshField.from_mesh(SurfaceMesh.load(data / "mesh.ply"))
    return evaluate(field, test, default_render_config(field, test.background))


def run_scene(scene: str, fields: list[str], args) -> list[dict]:
    """The rows of ``scene``: those kept in ``OUT/SCENE`` under the same settings, the others measured and kept."""
    rows, folder = [], args.out / scene
    todo = [name for name in fields if kept(folder / f"{name}.json", settings(args, name)) is None]
    if todo:
        data = generate(scene, folder / "data", args.resolution)
        train, test = load_dataset(data, "train"), load_dataset(data, "test")
        reference = None if SCENES[scene].is_scene else reference_psnr(data, test)
    for name in fields:
        path = folder / f"{name}.json"
        row = kept(path, settings(args, name))
        if row is None:
            row = measure(scene, name, data, train, test, args) | {"exact_mesh_psnr": reference}
            row |= {"settings": settings(args, name), "load": os.getloadavg()[0]}
            row["finished"] = f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC"
            write_text(path, json.dumps(row, indent=2))
        rows.append(row)
    return rows


def kept(path: Path, wanted: dict) -> dict | None:
    """The row in ``path`` when it was measured with the ``wanted`` settings, else None."""
    if not path.exists():
        return None
    row = json.loads(path.read_text())
    return row if row.get("settings") == wanted else None


def table(rows: list[dict]) -> str:
    """The results as a Markdown table (a missed target in bold)."""

    def value(x, digits: int, ok: bool = True) -> str:
        if x is None:
            return "—"
        return f"{x:.{digits}f}" if ok else f"**{x:.{digits}f}**"

    lines = [
        "| scene | field | test PSNR dB | target | SSIM | LPIPS | noise | Chamfer % | curve dB (per 60 s; end) | steps "
        "| train s | exact mesh dB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        is_scene = SCENES[row["scene"]].is_scene
        target = SCENE_TARGET if is_scene else TARGETS[row["field"]]
        distance = row["chamfer_percent"]
        chamfer_ok = is_scene or distance is None or distance <= CHAMFER_TARGET
        lines.append(
            f"| {row['scene']} | {row['field']} | {value(row['psnr'], 2, row['psnr'] >= target)} | ≥ {target:.0f} | "
            f"{value(row['ssim'], 4)} | {value(row['lpips'], 4)} | {value(row['noise'], 4)} | "
            f"{value(distance, 3, chamfer_ok)} | "
            + " / ".join(f"{p:.1f}" for p in row["curve"])
            + f" | {row['steps']} | {row['train_seconds']:.0f} | {value(row['exact_mesh_psnr'], 2)} |"
        )
    return "\n".join(lines)


def write_docs(text: str) -> None:
    """Replace the text between the bench_fields markers of docs/benchmarks.md (atomically)."""
    begin_marker, end_marker = MARKERS
    docs = DOCS.read_text()
    head, begin, rest = docs.partition(begin_marker)
    _, end, tail = rest.partition(end_marker)
    if not (begin and end):
        raise SystemExit(f"{DOCS}: the markers {begin_marker} … {end_marker} are missing")
    write_text(DOCS, f"{head}{begin_marker}\n{text}\n{end_marker}{tail}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", default=",".join(SCENES), help=f"comma-separated, of {', '.join(SCENES)}")
    parser.add_argument("--fields", default=",".join(DEFAULT_FIELDS), help="comma-separated, of nerf, neus, splats")
    parser.add_argument("--seconds", type=float, default=BUDGET, help="training budget per field")
    parser.add_argument(
        "--clock", choices=("wall", "cpu"), default="wall", help="training clock (see TrainerConfig.clock)"
    )
    parser.add_argument("--out", type=Path, default=None, help="keep rows, datasets, fields and meshes here")
    parser.add_argument("--set", action="append", default=[], help="FIELD.OPTION=VALUE config override")
    parser.add_argument("--resolution", type=int, default=100, help="image width and height")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (a complete run: 2)")
    args = parser.parse_args()
    scenes, fields = args.scenes.split(","), args.fields.split(",")
    unknown = sorted(set(scenes) - set(SCENES)) + sorted(set(fields) - set(BACKENDS))
    if unknown:
        parser.error(f"unknown scene or field: {', '.join(unknown)}")
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        args.out = args.out or Path(tmp)
        for scene in scenes:
            run_scene(scene, fields, args)
        rows = [
            row
            for scene in SCENES
            for name in fields
            if (row := kept(args.out / scene / f"{name}.json", settings(args, name))) is not None
        ]
    text = table(rows)
    print(f"\n{text}")
    complete = {(r["scene"], r["field"]) for r in rows} == {(s, f) for s in SCENES for f in DEFAULT_FIELDS}
    complete = complete and fields == list(DEFAULT_FIELDS) and args.seconds == BUDGET
    complete = complete and args.resolution == 100 and args.threads == 2 and not args.set
    if complete:
        finished = max(r["finished"] for r in rows)
        loads = [r["load"] for r in rows]
        write_docs(
            f"`python bench/bench_fields.py --clock {args.clock} --out OUT` (rows finished by {finished}, "
            f"{'process CPU' if args.clock == 'cpu' else 'wall'} clock, load average 1-min at the end of each row "
            f"{min(loads):.1f}–{max(loads):.1f}): "
            f"every field with its default config, budget {BUDGET:.0f} s of training per field (evaluation "
            f"excluded), 2 threads. Targets: objects nerf ≥ {TARGETS['nerf']:.0f} dB, neus ≥ "
            f"{TARGETS['neus']:.0f} dB and neus Chamfer ≤ {CHAMFER_TARGET} % of the bbox diagonal; scenes ≥ "
            f"{SCENE_TARGET:.0f} dB; misses in bold. *noise*: the surface noise of the test renders; *Chamfer*: the "
            f"neus mesh of an object (% of its bbox diagonal), every field's mesh of a scene over its foreground "
            f"box (% of the box diagonal); *exact mesh*: the source mesh rendered by the `mesh` field, one ray per "
            f"pixel.\n\n{text}"
        )
        print(f"\nwritten to {DOCS}")


if __name__ == "__main__":
    main()
