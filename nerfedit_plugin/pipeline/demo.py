"""``nerfedit demo``: the whole pipeline on the built-in scene, on the CPU, in minutes.

generate (the pymeshlab bunny, vertex-coloured, rendered by :mod:`nerfedit_plugin.data.synthetic`) → train a field →
extract its mesh (largest connected part) → a built-in ARAP edit (:func:`nod_edit`) → lift into the tet proxy →
render the test views before and after the edit and a turntable GIF of the edited scene. Everything lands in one
folder, written atomically; :func:`run_demo` returns each stage's time and two scores: ``before`` — the trained
field's test views against the dataset's; ``after`` — the edited renders against ground truth made by moving the
*source* mesh through the same tet deformation (forward map: the DeformationField with rest and deformed proxies
swapped) and rendering it, so it measures training, mesh extraction and ray bending together.
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.config import write_config
from nerfedit_plugin.data.datasets import load_dataset
from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset, render_ground_truth
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_dir
from nerfedit_plugin.pipeline.edit import run_edit
from nerfedit_plugin.pipeline.extract import extract_mesh
from nerfedit_plugin.pipeline.train import train_run
from nerfedit_plugin.registry import DEFORMERS, FIELDS, discover
from nerfedit_plugin.render.views import default_render_config, render_views, turntable_cameras, write_gif, write_images
from nerfedit_plugin.timing import ProgressListener, Stopwatch, labelled
from nerfedit_plugin.training.metrics import evaluate_folders


@dataclass(frozen=True)
class Preset:
    """Sizes of one demo preset."""

    resolution: int
    n_train: int
    n_test: int
    train_seconds: float
    train_steps: int
    mesh_resolution: int
    turntable_frames: int


PRESETS = {
    "fast": Preset(
        resolution=100,
        n_train=50,
        n_test=4,
        train_seconds=150.0,
        train_steps=1_000_000,
        mesh_resolution=128,
        turntable_frames=16,
    ),
    "tiny": Preset(
        resolution=32,
        n_train=10,
        n_test=2,
        train_seconds=600.0,
        train_steps=150,
        mesh_resolution=48,
        turntable_frames=4,
    ),
}


def nod_edit(mesh: SurfaceMesh, degrees: float = -25.0) -> dict:
    """An ARAP edit spec that tilts the top of a z-up object: the lowest 40 % of its height is fixed, the top 30 %
    rotates by ``degrees`` about the x axis through the point at 60 % height (the bunny throws its head back; bowing
    it squeezes the tets between chin and paws and inverts more; −25° moves ~7 % of the pixels of a test view and
    keeps the edited renders within 0.3 dB of those at −15°)."""
    low, high = mesh.vertices.min(0), mesh.vertices.max(0)
    pad = 0.01 * float(np.linalg.norm(high - low))
    z = lambda f: float(low[2] + f * (high[2] - low[2]))  # noqa: E731
    lo, hi = (low - pad).tolist(), (high + pad).tolist()
    center = [float((low[0] + high[0]) / 2), float((low[1] + high[1]) / 2), z(0.6)]
    return {
        "handles": [
            {"select": {"box": {"min": lo, "max": hi[:2] + [z(0.4)]}}, "fixed": True},
            {
                "select": {"box": {"min": lo[:2] + [z(0.7)], "max": hi}},
                "transform": {"rotate": {"axis": [1.0, 0.0, 0.0], "degrees": degrees, "center": center}},
            },
        ]
    }


def run_demo(
    out: str | os.PathLike,
    *,
    preset: Literal["fast", "tiny"] = "fast",
    field: str = "neus",
    overwrite: bool = False,
    cache_dir: str | os.PathLike | None = None,
    progress: bool = True,
    on_stage: Callable[[str], None] | None = None,
    on_progress: ProgressListener | None = None,
    record: Any = None,
) -> dict:
    """Run the demo into ``out`` (see the module docstring); returns ``{"out", "seconds" (per stage), "before" and
    "after" (mean PSNR/SSIM/LPIPS, see the module docstring), "edit" (the edit report), "files"}``, also written to
    ``out/summary.json``; ``record`` (the command line's args) goes to ``out/config.yml``. ``on_stage`` and
    ``on_progress``: as :func:`~nerfedit_plugin.pipeline.edit.run_edit`'s, for the demo's stages (the edit's own stages
    and progress are the ``edit`` stage's progress)."""
    sizes = PRESETS[preset]
    registry = discover()
    clock = Stopwatch(on_stage, on_progress=on_progress)
    start = time.perf_counter()
    with atomic_dir(out, overwrite) as stage:
        with clock.stage("generate"):
            data = generate_dataset(
                GenerateConfig(
                    out=stage / "data",
                    mesh="sample:bunny",
                    resolution=sizes.resolution,
                    n_train=sizes.n_train,
                    n_val=1,
                    n_test=sizes.n_test,
                    supersample=2 if preset == "fast" else 1,
                )
            )
        with clock.stage("train"):
            config_class = registry.config_class(FIELDS, field)
            config = config_class.tiny() if preset == "tiny" else config_class()
            if preset == "fast":
                config.train = dataclasses.replace(
                    config.train, max_seconds=sizes.train_seconds, eval_every_seconds=0, progress=progress
                )
            run, _ = train_run(field, config, data, stage / "run", registry=registry)
        with clock.stage("extract"):
            extract_mesh(run, sizes.mesh_resolution)
            mesh = run.mesh()
        with clock.stage("edit"):
            spec = stage / "nod.json"
            spec.write_text(json.dumps(nod_edit(mesh), indent=2))
            arap = registry.config_class(DEFORMERS, "arap")()
            edited = run_edit(
                mesh,
                arap,
                spec,
                stage / "edit",
                camera_distance=run.camera_distance(),
                cache_dir=cache_dir or stage / "cache",
                record={"deformer": "arap", "edit": str(spec)},
                on_stage=lambda name: clock.progress(0, None, name),
                on_progress=lambda name, done, total, detail: labelled(clock.progress, name)(done, total, detail),
            )
        with clock.stage("render"):
            trained = run.field()
            deformation = DeformationField.load(edited.out / "deformation.npz")
            test = load_dataset(data, "test")
            render = default_render_config(trained, test.background)
            names = [p.with_suffix(".png").name for p in test.image_paths]
            before = render_views(trained, test.cameras, render, progress=progress)
            after = render_views(trained, test.cameras, render, deformation=deformation, progress=progress)
            write_images(before, names, stage / "renders" / "before")
            write_images(after, names, stage / "renders" / "after")
            turntable = turntable_cameras(trained.scene_bbox, sizes.turntable_frames, sizes.resolution)
            write_gif(
                stage / "renders" / "turntable.gif",
                render_views(trained, turntable, render, deformation=deformation, progress=progress),
            )
            forward = DeformationField(
                deformation.deformed_vertices[0], deformation.tets, deformation.rest_vertices, dtype=torch.float64
            )  # rest ↔ deformed swapped: maps T to T'
            source = SurfaceMesh.load(data / "mesh.ply")
            moved = forward.to_canonical(torch.from_numpy(source.vertices)).points.numpy()
            render_ground_truth(source, moved, data / "transforms_test.json", stage / "renders" / "after_ground_truth")
        before = evaluate_folders(stage / "renders" / "before", data / "test", test.background)["mean"]
        after = evaluate_folders(
            stage / "renders" / "after", stage / "renders" / "after_ground_truth", test.background
        )["mean"]
        summary = {
            "out": str(Path(out).resolve()),
            "seconds": {**clock.seconds, "total": round(time.perf_counter() - start, 2)},
            "before": before,
            "after": after,
            "edit": {k: edited.report[k] for k in ("proxy", "per_frame")},
            "files": {
                "dataset": "data",
                "run": "run",
                "mesh": "run/mesh.ply",
                "edit": "edit",
                "deformed mesh": "edit/deformed_mesh.ply",
                "deformation": "edit/deformation.npz",
                "before": "renders/before",
                "after": "renders/after",
                "after, ground truth": "renders/after_ground_truth",
                "turntable": "renders/turntable.gif",
            },
        }
        (stage / "summary.json").write_text(json.dumps(summary, indent=2))
        if record is not None:
            write_config(stage / "config.yml", record)
    return summary
