"""``nerfedit train``: make a run folder (:mod:`nerfedit_plugin.pipeline.run`) — train a field on a dataset, or build
it from a model file.

A run is written atomically (never half a run on disk). Training checkpoints into the run's staging folder every
``checkpoint_every_seconds``, marked partial; an interrupted ``train`` keeps the last one as a *partial* run
(``.nerfedit-partial`` holds its steps and seconds), which every reader refuses — unless a previous run is at the path,
which stays as it was. A dataset's ``test`` split, else ``val``, gives the held-out PSNR curve.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nerfedit_plugin.config import to_plain, write_config
from nerfedit_plugin.data.datasets import Dataset, is_capture, load_dataset, read_transforms, transforms_file
from nerfedit_plugin.data.normalization import box_bounds
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.base import Field, FieldConfig, Source
from nerfedit_plugin.fields.checkpoint import save_field
from nerfedit_plugin.io.atomic import atomic_dir, clear_partial, mark_partial
from nerfedit_plugin.io.faults import fault_point
from nerfedit_plugin.pipeline.run import (
    CHECKPOINT,
    CONFIG,
    DATAPARSER,
    LOG,
    MESH,
    Run,
    dataparser_transforms,
    default_device,
    is_model_file,
    open_run,
    read_dataparser_transforms,
)
from nerfedit_plugin.quality import training_warnings
from nerfedit_plugin.registry import FIELDS, Registry, discover
from nerfedit_plugin.training.trainer import checkpoints


def run_source(backend: str, target: type[Field], data: Path) -> Source:
    """What ``data`` is for the field class ``target``: ``"model"`` (a model file) or ``"dataset"``; data of a kind
    the backend does not take is a :class:`NerfEditError` saying what it takes."""
    source = "model" if is_model_file(data) else "dataset"
    if source in target.sources:
        return source
    if "model" in target.sources:
        raise NerfEditError(f"{data}: the {backend!r} field is made from a model file (e.g. PLY/OBJ/OFF/GLB)")
    raise NerfEditError(f"{data}: the {backend!r} field trains on a dataset folder, transforms file or COLMAP capture")


def _eval_split(data: Path, downscale: int) -> Dataset | None:
    for split in ("test", "val"):
        try:
            transforms_file(data, split)
        except NerfEditError:
            continue
        return load_dataset(data, split, downscale=downscale)
    return None


def _scene_box(train: Dataset, scene_box, frame: str, source_transform: np.ndarray) -> torch.Tensor:
    """The field's box: ``scene_box`` ([min, max], in the run's ``world`` frame or the ``capture``'s: then the bounds
    of its corners mapped to the world) when given, else the dataset's (a capture's foreground box)."""
    if scene_box is None:
        return train.scene_bbox
    box = np.asarray(scene_box, dtype=np.float64).reshape(2, 3)
    if not (np.isfinite(box).all() and (box[0] < box[1]).all()):
        raise NerfEditError(f"scene_box: expected [min x, y, z, max x, y, z] with min < max, got {box.tolist()}")
    if frame == "capture":
        box = box_bounds(source_transform, box)
    return torch.tensor(box, dtype=torch.float32, device=train.scene_bbox.device)


def train_run(
    backend: str,
    config: FieldConfig,
    data: str | os.PathLike,
    out: str | os.PathLike,
    *,
    overwrite: bool = False,
    device: torch.device | str | None = None,
    registry: Registry | None = None,
    record: Any = None,
    downscale: int = 1,
    scene_box=None,
    box_frame: str = "world",
    dataparser: str | os.PathLike | None = None,
) -> tuple[Run, dict]:
    """Build (``data`` = a model file: :meth:`Field.from_file`) or train (``data`` = dataset folder, transforms file or
    COLMAP workspace: :meth:`Field.fit`) the field ``backend`` with ``config`` and write the run folder ``out``
    atomically, with ``mesh.ply`` for exact-mesh fields and ``dataparser_transforms.json`` for normalised captures.
    Images are downscaled by ``downscale``; ``scene_box`` (6 numbers, in ``box_frame``: ``world`` or ``capture``)
    overrides the dataset's box. ``dataparser`` (a model file only): nerfstudio's ``dataparser_transforms.json`` of
    the run the model was exported from, recorded as the run's capture frame. ``record`` (the command line's args)
    goes to config.yml under ``command``. Returns the run and the training log."""
    registry = discover() if registry is None else registry
    if registry.config_class(FIELDS, backend) is not type(config):
        raise NerfEditError(f"field: the config {type(config).__name__} is not the {backend!r} backend's")
    data = Path(data).resolve()
    target = config._target
    device = torch.device(device) if device is not None else default_device()
    source = run_source(backend, target, data)
    if dataparser is not None:
        if source != "model":
            raise NerfEditError(
                f"--dataparser-transforms: {data} is a dataset; it applies to a model file (a dataset's own "
                "normalisation is recorded from it)"
            )
        capture = read_dataparser_transforms(Path(dataparser))
    plain = {
        "field": backend,
        "data": os.path.relpath(data, Path(out).resolve()),
        "source": source,
        "field_config": config,
    }
    if record is not None:
        plain["command"] = record
    with atomic_dir(out, overwrite, keep_partial=True) as stage:
        if source == "model":
            field, log = target.from_file(data, config).to(device), {}
            if dataparser is not None:
                (stage / DATAPARSER).write_text(json.dumps(dataparser_transforms(capture), indent=2))
            if target.exact_mesh:
                field.extract_mesh().save(stage / MESH)
        else:
            train = load_dataset(data, "train", downscale=downscale).to(device)
            evaluation = _eval_split(data, downscale)
            transforms = read_transforms(data, "train")
            similarity = np.asarray(transforms.meta.get("source_transform", np.eye(4)), dtype=np.float64)
            field = config.setup(scene_bbox=_scene_box(train, scene_box, box_frame, similarity)).to(device)
            if is_capture(transforms):
                (stage / DATAPARSER).write_text(json.dumps(dataparser_transforms(similarity), indent=2))

            def checkpoint(field: Field, progress: dict) -> None:  # kept as a partial run if interrupted
                mark_partial(stage, progress)
                save_field(field, stage / CHECKPOINT, registry)
                write_config(stage / CONFIG, plain)
                fault_point("train.checkpoint")

            with checkpoints(checkpoint):
                log = field.fit(train, eval_dataset=None if evaluation is None else evaluation.to(device))
            (stage / LOG).write_text(json.dumps(to_plain(log)))
        save_field(field, stage / CHECKPOINT, registry)
        write_config(stage / CONFIG, plain)
        clear_partial(stage)
    for message in training_warnings(log):
        warnings.warn(f"{out}: {message}", stacklevel=2)
    return open_run(out), log
