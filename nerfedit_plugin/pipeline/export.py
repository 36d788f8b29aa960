"""``nerfedit export``: a run's primitives (a splat model), moved by an edit's deformation, as files other tools open.

The export folder, written atomically (staged beside the target, renamed when complete): one model file per frame —
``point_cloud.ply`` (the INRIA layout, float32; ``point_cloud.splat`` for ``format="splat"``) for the unedited model
or a single frame, ``frame_NNNN.ply`` (``NNNN`` the deformation's frame) for several — plus ``export.json`` (the run,
the deformation, and per file its frame, Gaussians and the forward map's report) and ``config.yml`` (the command's
record). The first file is written before the others, and its size times the number of files is stated
(``on_plan``) and checked against the free disk space before the rest is written.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nerfedit_plugin.bending.scene_deformation import load_deformation
from nerfedit_plugin.config import to_plain, write_config
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import atomic_dir
from nerfedit_plugin.pipeline.run import CONFIG, Run
from nerfedit_plugin.render.animation import parse_frames

REPORT = "export.json"


@dataclass(frozen=True)
class ExportPlan:
    """What an export writes: ``files`` model files of about ``bytes_per_file`` each (the first one's size)."""

    files: int
    bytes_per_file: int

    @property
    def total_bytes(self) -> int:
        return self.files * self.bytes_per_file


@dataclass
class ExportResult:
    out: Path
    files: list[Path]
    report: dict


def export_run(
    run: Run,
    out: str | os.PathLike,
    *,
    deformation: str | os.PathLike | None = None,
    frames: str | None = None,
    format: str | None = None,
    overwrite: bool = False,
    record: Any = None,
    on_plan: Callable[[ExportPlan], None] | None = None,
) -> ExportResult:
    """Write ``run``'s model — moved by ``deformation`` (a ``deformation.npz``) at each of ``frames`` (N, A:B,
    A:B:STEP or all, the default) — into the folder ``out`` in ``format`` (one of the field's
    :attr:`~nerfedit_plugin.fields.base.Field.exports`, default its first) → :class:`ExportResult`. A run whose field
    has no primitives to export (``nerf``, ``neus``, ``mesh``), an unknown format, or too little disk space for the
    planned files is a :class:`NerfEditError`."""
    formats = run.field_class.exports
    if not formats:
        raise NerfEditError(
            f"{run.path}: a {run.backend!r} run has no primitives to export (export writes the splat models of "
            "`nerfedit train --field splats` runs; for this run's surface mesh use `nerfedit extract`)"
        )
    format = formats[0] if format is None else format
    if format not in formats:
        raise NerfEditError(f"--format {format}: a {run.backend!r} run exports {' or '.join(formats)}")
    bent = load_deformation(deformation) if deformation is not None else None
    chosen = parse_frames(frames, bent.n_frames) if bent is not None else [0]
    if bent is None and frames is not None:
        raise NerfEditError("--frame: needs --deformation EDIT_DIR/deformation.npz (the unedited model has no frames)")
    field = run.field("cpu")
    names = [f"point_cloud.{format}"] if len(chosen) == 1 else [f"frame_{f:04d}.{format}" for f in chosen]
    entries = []
    with atomic_dir(out, overwrite) as stage:
        for i, (f, name) in enumerate(zip(chosen, names)):
            written = field.export(stage / name, bent, f)
            entries.append({"file": name, "frame": f if bent is not None else None, **written})
            if i == 0:
                plan = ExportPlan(len(names), (stage / name).stat().st_size)
                _check_space(stage, plan)
                if on_plan is not None:
                    on_plan(plan)
        report = {
            "run": str(run.path.resolve()),
            "deformation": None if deformation is None else str(Path(deformation).resolve()),
            "format": format,
            "files": entries,
        }
        (stage / REPORT).write_text(json.dumps(to_plain(report), indent=2))
        if record is not None:
            write_config(stage / CONFIG, record)
    out = Path(out)
    return ExportResult(out, [out / name for name in names], report)


def _check_space(folder: Path, plan: ExportPlan) -> None:
    """Raise :class:`NerfEditError` when the files still to write would not fit on ``folder``'s disk."""
    needed, free = (plan.files - 1) * plan.bytes_per_file, shutil.disk_usage(folder).free
    if needed > free:
        raise NerfEditError(
            f"export: {plan.files} files of {plan.bytes_per_file / 1e6:.1f} MB need {plan.total_bytes / 1e9:.2f} GB, "
            f"{free / 1e9:.2f} GB free on {folder.parent} (export fewer frames with --frame)"
        )
