"""A run folder: one trained field and what it was trained on (docs/architecture.md, "Run folder").

``RUN_DIR/config.yml``  ``{"field": backend name, "data": the dataset or mesh, relative to RUN_DIR (a run and
                        its data moved together stay valid), "field_config": the backend's full config}``
``RUN_DIR/field.pt``    the checkpoint (:mod:`nerfedit_plugin.io.checkpoint`)
``RUN_DIR/log.json``    training log (loss/PSNR per step, held-out PSNR-vs-time), when the backend trains
``RUN_DIR/mesh.ply``    the surface mesh: written by :func:`extract_mesh` (``nerfedit extract``); a mesh field's
                        run has it at once (the field's own mesh, in its vertex order)
``RUN_DIR/dataparser_transforms.json``  a normalised capture's capture-to-world similarity, nerfstudio's layout:
                        ``{"transform": 3×4 [R | t], "scale": s}``, ``x_world = s (R x + t)``

A run is written atomically (never half a run on disk); an extracted ``mesh.ply`` is added atomically afterwards.
Training checkpoints into the run's staging folder every ``checkpoint_every_seconds``, marked partial; an
interrupted ``train`` keeps the last one as a *partial* run (``.nerfedit-partial`` holds its steps and seconds),
which every reader refuses — unless a previous run is at the path, which stays as it was.
Backends whose ``Field.data == "mesh"`` are built from a mesh file with ``from_mesh`` and their mesh is written in the
same atomic stage; the others ``fit`` an image dataset (the ``test`` split, else ``val``, is used for the held-out
PSNR curve).
"""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nerfedit_plugin.config import read_config, to_plain, write_config
from nerfedit_plugin.data.datasets import Dataset, is_capture, load_dataset, read_transforms, transforms_file
from nerfedit_plugin.data.normalization import apply, box_bounds
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_dir, atomic_path, clear_partial, mark_partial, require_complete
from nerfedit_plugin.io.checkpoint import load_field, save_field
from nerfedit_plugin.io.faults import fault_point
from nerfedit_plugin.quality import training_warnings
from nerfedit_plugin.registry import FIELDS, Registry, discover
from nerfedit_plugin.training.trainer import checkpoints

CONFIG, CHECKPOINT, LOG, MESH = "config.yml", "field.pt", "log.json", "mesh.ply"
DATAPARSER = "dataparser_transforms.json"
CAPTURE_MESH = "mesh_capture.ply"
"""``nerfedit extract --frame capture``: the mesh in the capture's coordinates."""


def default_device() -> torch.device:
    """CUDA when present, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


@dataclass
class Run:
    """An opened run folder (see the module docstring)."""

    path: Path
    backend: str
    data: Path
    config: dict

    @property
    def mesh_path(self) -> Path:
        return self.path / MESH

    def field(self, device: torch.device | str | None = None, registry: Registry | None = None) -> Field:
        """The trained field, on ``device`` (default: CUDA when present)."""
        return load_field(self.path / CHECKPOINT, registry, backend=self.backend, device=device or default_device())

    @property
    def from_mesh(self) -> bool:
        """The run's field is built from a mesh (``Field.data == "mesh"``): the field is the mesh."""
        return _builds_from_mesh(self.backend)

    def mesh(self) -> SurfaceMesh:
        """The run's mesh: ``mesh.ply``, or the field's own mesh for a mesh field's run written before runs held it;
        an error naming the run when ``nerfedit extract`` has not been run."""
        if not self.mesh_path.is_file():
            if self.from_mesh:
                return self.field("cpu").extract_mesh()
            raise NerfEditError(f"{self.path}: no {MESH} in the run (run `nerfedit extract --run {self.path}` first)")
        return SurfaceMesh.load(self.mesh_path)

    def camera_distance(self) -> float | None:
        """Mean distance of the training cameras to the centre of the dataset's scene box (``None`` for runs built
        from a mesh): it sets the proxy's cage offset (5 %, as in the paper)."""
        if _is_mesh_file(self.data):
            return None
        transforms = read_transforms(self.data, "train")
        centers = transforms.cameras.c2w[:, :3, 3].double()
        box = transforms.meta.get("aabb")
        center = torch.tensor(box, dtype=torch.float64).mean(0) if box is not None else centers.mean(0)
        return float(torch.linalg.norm(centers - center, dim=1).mean())

    def filming(self, scene_bbox: torch.Tensor, up: tuple[float, float, float]) -> dict:
        """Where the training cameras stood, as keywords of :func:`~nerfedit_plugin.render.views.turntable_cameras`:
        their median distance to the centre of ``scene_bbox`` (in half-diagonals of it), elevation above its
        equator about ``up`` (degrees) and vertical field of view (degrees), so an orbit sees the scene as it was
        filmed (a capture's field is noise outside its cameras' reach). ``{}`` for runs built from a mesh or whose
        dataset is no longer where the run recorded it."""
        if self.from_mesh or _is_mesh_file(self.data):
            return {}
        try:
            cameras = read_transforms(self.data, "train").cameras
        except NerfEditError:  # the dataset moved or is gone: the default ring
            return {}
        box = torch.as_tensor(scene_bbox, dtype=torch.float64).cpu()
        offsets = cameras.c2w[:, :3, 3].double() - box.mean(0)
        distance = torch.linalg.norm(offsets, dim=1)
        axis = torch.as_tensor(up, dtype=torch.float64)
        sine = (offsets @ (axis / torch.linalg.norm(axis))) / distance
        fov = 2.0 * torch.atan(cameras.height / (2.0 * cameras.fy.double().expand(len(distance))))
        return {
            "distance": float(distance.median() / (torch.linalg.norm(box[1] - box[0]) / 2)),
            "elevation_degrees": float(torch.rad2deg(torch.asin(sine.clamp(-1, 1))).median()),
            "fov_degrees": float(torch.rad2deg(fov).median()),
        }

    def source_transform(self) -> np.ndarray:
        """(4,4) float64: the similarity taking the coordinates of the mesh the data was generated from, or of the
        capture, to the run's (a capture's normalisation recorded in ``dataparser_transforms.json``, else the
        dataset's ``source_transform``, written by ``nerfedit generate``); the identity for data that nerfedit did not
        transform (a dataset without the record, a mesh file other than a generated dataset's ``mesh.ply``). Edit
        specs with ``frame: source`` and ``--frame capture`` use it."""
        if (self.path / DATAPARSER).is_file():
            return read_dataparser_transforms(self.path / DATAPARSER)
        data = self.data
        if _is_mesh_file(data):
            if data.name != MESH or not (data.parent / "transforms_train.json").is_file():
                return np.eye(4)
            data = data.parent  # the mesh of a generated dataset: the dataset's record
        recorded = read_transforms(data, "train").meta.get("source_transform")
        if recorded is None:
            return np.eye(4)
        matrix = np.asarray(recorded, dtype=np.float64)
        if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
            raise NerfEditError(f"{self.data}: source_transform: expected a 4×4 matrix of numbers")
        return matrix


def dataparser_transforms(source_transform: np.ndarray) -> dict:
    """nerfstudio's ``dataparser_transforms.json`` of a similarity ``x ↦ sRx + b``: ``{"transform": [R | b/s],
    "scale": s}``."""
    scale = float(np.cbrt(np.linalg.det(source_transform[:3, :3])))
    return {"transform": (source_transform[:3] / scale).tolist(), "scale": scale}


def read_dataparser_transforms(file: Path) -> np.ndarray:
    """(4,4) the similarity of a ``dataparser_transforms.json`` (the inverse of :func:`dataparser_transforms`)."""
    try:
        record = json.loads(file.read_text())
        matrix = np.vstack([float(record["scale"]) * np.asarray(record["transform"], dtype=np.float64), [0, 0, 0, 1]])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise NerfEditError(f"{file}: expected {{'transform': 3x4, 'scale': s}} ({exc})") from exc
    if matrix.shape != (4, 4) or not np.isfinite(matrix).all():
        raise NerfEditError(f"{file}: expected {{'transform': 3x4, 'scale': s}}")
    return matrix


def open_run(path: str | os.PathLike) -> Run:
    """Read ``RUN_DIR/config.yml``; a folder that is not a run is an error naming it."""
    path = Path(path)
    require_complete(path, "run folder")
    file = path / CONFIG
    if not file.is_file():
        raise NerfEditError(f"{path}: not a run folder (no {CONFIG}; make one with `nerfedit train`)")
    config = read_config(file, "a run's config")
    if not isinstance(config.get("field"), str) or "data" not in config:
        raise NerfEditError(f"{file}: expected the keys 'field' and 'data' of a run written by `nerfedit train`")
    return Run(path, config["field"], (path / config["data"]).resolve(), config)


def _builds_from_mesh(backend: str) -> bool:
    """Whether the backend's field is built from a mesh (``Field.data == "mesh"``)."""
    return discover(FIELDS).config_class(FIELDS, backend)()._target.data == "mesh"


def _is_mesh_file(data: Path) -> bool:
    """A file that is not a transforms JSON: the mesh a ``data == "mesh"`` field is built from."""
    return data.is_file() and data.suffix != ".json"


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
) -> tuple[Run, dict]:
    """Build (``data`` = mesh file, mesh backends) or train (``data`` = dataset folder, transforms file or COLMAP
    workspace) the field ``backend`` with ``config`` and write the run folder ``out`` atomically, with ``mesh.ply``
    for mesh backends and ``dataparser_transforms.json`` for normalised captures. Images are downscaled by
    ``downscale``; ``scene_box`` (6 numbers, in ``box_frame``: ``world`` or ``capture``) overrides the dataset's box.
    ``record`` (the command line's args) goes to config.yml under ``command``. Returns the run and the training
    log."""
    registry = discover() if registry is None else registry
    if registry.config_class(FIELDS, backend) is not type(config):
        raise NerfEditError(f"field: the config {type(config).__name__} is not the {backend!r} backend's")
    data = Path(data).resolve()
    target = config._target
    device = torch.device(device) if device is not None else default_device()
    if target.data == "mesh":
        if not data.is_file():
            raise NerfEditError(f"{data}: the {backend!r} field is built from a mesh file (PLY/OBJ/OFF/GLB)")
    elif _is_mesh_file(data):
        raise NerfEditError(f"{data}: the {backend!r} field trains on a dataset folder or transforms file")
    plain = {"field": backend, "data": os.path.relpath(data, Path(out).resolve()), "field_config": config}
    if record is not None:
        plain["command"] = record
    with atomic_dir(out, overwrite, keep_partial=True) as stage:
        if target.data == "mesh":
            field, log = target.from_mesh(SurfaceMesh.load(data), config).to(device), {}
            field.extract_mesh().save(stage / MESH)
        else:
            train = load_dataset(data, "train", downscale=downscale).to(device)
            evaluation = _eval_split(data, downscale)
            transforms = read_transforms(data, "train")
            source = np.asarray(transforms.meta.get("source_transform", np.eye(4)), dtype=np.float64)
            field = config.setup(scene_bbox=_scene_box(train, scene_box, box_frame, source)).to(device)
            if is_capture(transforms):
                (stage / DATAPARSER).write_text(json.dumps(dataparser_transforms(source), indent=2))

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


def extract_mesh(
    run: Run,
    resolution: int = 256,
    level: float | None = None,
    *,
    largest_component: bool = True,
    overwrite: bool = False,
    device: torch.device | str | None = None,
    clean: Callable[[SurfaceMesh], SurfaceMesh] | None = None,
) -> Path:
    """Extract the run's mesh (marching cubes for trained fields; the mesh itself for mesh fields) into
    ``RUN_DIR/mesh.ply``, atomically; an existing mesh is replaced only with ``overwrite``, except that a mesh
    field's run, which has its mesh from :func:`train_run`, is left as it is (nothing to extract). ``largest_component``
    drops floaters of trained fields (a mesh field's mesh is always kept whole, in its vertex order); ``clean`` (e.g.
    dropping the ground plane) runs on the extracted mesh before it is written, so the file is only ever its result."""
    if run.mesh_path.exists() and not overwrite:
        if run.from_mesh:
            return run.mesh_path
        raise NerfEditError(f"{run.mesh_path}: exists (pass --overwrite to extract again)")
    field = run.field(device)
    try:
        mesh = field.extract_mesh(resolution, level)
    except ValueError as exc:  # e.g. the level lies outside the field's range
        raise NerfEditError(f"{run.path}: {exc}") from exc
    if largest_component and field.data != "mesh":
        mesh = mesh.largest_component()
    if clean is not None:
        mesh = clean(mesh)
    with atomic_path(run.mesh_path) as tmp:
        mesh.save(tmp)
    return run.mesh_path


def export_capture_mesh(run: Run, overwrite: bool = False) -> Path:
    """The run's mesh mapped back to the capture's coordinates (by the inverse of :meth:`Run.source_transform`) into
    ``RUN_DIR/mesh_capture.ply``, atomically: e.g. to open it next to the COLMAP points."""
    path = run.path / CAPTURE_MESH
    if path.exists() and not overwrite:
        raise NerfEditError(f"{path}: exists (pass --overwrite to export again)")
    mesh = run.mesh()
    mesh = mesh.with_vertices(apply(np.linalg.inv(run.source_transform()), mesh.vertices))
    with atomic_path(path) as tmp:
        mesh.save(tmp)
    return path
