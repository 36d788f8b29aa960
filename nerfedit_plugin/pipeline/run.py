"""A run folder: one field and what it was made from (docs/architecture.md, "Run folder").

``RUN_DIR/config.yml``  ``{"field": backend name, "data": the dataset or model file, relative to RUN_DIR (a run and
                        its data moved together stay valid), "source": "dataset" | "model", "field_config": the
                        backend's full config}``
``RUN_DIR/field.pt``    the checkpoint (:mod:`nerfedit_plugin.fields.checkpoint`)
``RUN_DIR/log.json``    training log (loss/PSNR per step, held-out PSNR-vs-time), when the backend trains
``RUN_DIR/mesh.ply``    the surface mesh: written by ``nerfedit extract`` (:func:`~nerfedit_plugin.pipeline.extract.
                        extract_mesh`); a run whose field is a mesh (``Field.exact_mesh``) has it at once
``RUN_DIR/dataparser_transforms.json``  a normalised capture's capture-to-world similarity, nerfstudio's layout:
                        ``{"transform": 3×4 [R | t], "scale": s}``, ``x_world = s (R x + t)``

A run made from a dataset has the dataset's cameras; one made from a model file has none, and whatever needs cameras
(:meth:`Run.cameras`) says so. Runs are written by :func:`~nerfedit_plugin.pipeline.train.train_run`.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nerfedit_plugin.config import read_config
from nerfedit_plugin.data.cameras import Cameras
from nerfedit_plugin.data.datasets import read_transforms, transforms_file, world_up
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.base import Field, Source
from nerfedit_plugin.fields.checkpoint import load_field
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import require_complete
from nerfedit_plugin.registry import FIELDS, Registry, discover

CONFIG, CHECKPOINT, LOG, MESH = "config.yml", "field.pt", "log.json", "mesh.ply"
DATAPARSER = "dataparser_transforms.json"
CAPTURE_MESH = "mesh_capture.ply"
"""``nerfedit extract --frame capture``: the mesh in the capture's coordinates."""
Z_UP = (0.0, 0.0, 1.0)


def default_device() -> torch.device:
    """CUDA when present, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def is_model_file(data: Path) -> bool:
    """A file that is no transforms JSON: a model file (a mesh, a splat file), not a dataset."""
    return data.is_file() and data.suffix != ".json"


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

    @property
    def field_class(self) -> type[Field]:
        return discover(FIELDS).config_class(FIELDS, self.backend)()._target

    def field(self, device: torch.device | str | None = None, registry: Registry | None = None) -> Field:
        """The run's field, on ``device`` (default: CUDA when present)."""
        return load_field(self.path / CHECKPOINT, registry, backend=self.backend, device=device or default_device())

    @property
    def source(self) -> Source:
        """What the run was made from: ``"dataset"`` (images with cameras) or ``"model"`` (a model file, no
        cameras), as config.yml records it (runs that do not record it: the kind of their data path)."""
        recorded = self.config.get("source")
        if recorded in ("dataset", "model"):
            return recorded
        sources = self.field_class.sources
        if len(sources) == 1:
            return next(iter(sources))
        return "model" if is_model_file(self.data) else "dataset"

    @property
    def exact_mesh(self) -> bool:
        """The run's field is a mesh (``Field.exact_mesh``): ``mesh.ply`` is the field's own, nothing to extract."""
        return self.field_class.exact_mesh

    def mesh(self) -> SurfaceMesh:
        """The run's mesh: ``mesh.ply``, or the field's own mesh for an exact-mesh run written before runs held it;
        an error naming the run when ``nerfedit extract`` has not been run."""
        if not self.mesh_path.is_file():
            if self.exact_mesh:
                return self.field("cpu").extract_mesh()
            raise NerfEditError(
                f"{self.path}: no {MESH} in the run (run `nerfedit extract --run {self.path}` first, or give a mesh of "
                "the scene with --mesh MESH.ply)"
            )
        return SurfaceMesh.load(self.mesh_path)

    def cameras(self, split: str = "train") -> Cameras:
        """The cameras of the run's dataset (``split``); a run made from a model file has none, and a dataset that
        is no longer where the run recorded it is gone: both are a :class:`NerfEditError` saying so."""
        if self.source == "model":
            raise NerfEditError(
                f"{self.path}: the run was made from the model file {self.data} and has no cameras "
                "(give the cameras to use, e.g. --cameras transforms.json)"
            )
        return read_transforms(self.data, split).cameras

    def has_cameras(self) -> bool:
        """Whether :meth:`cameras` can answer (a run made from a dataset that is still in place)."""
        try:
            transforms_file(self.data, "train")
        except NerfEditError:
            return False
        return self.source == "dataset"

    def camera_distance(self) -> float | None:
        """Mean distance of the training cameras to the centre of the dataset's scene box, ``None`` for a run made
        from a model file: it sets the proxy's cage offset (5 %, as in the paper; without cameras, the proxy's own
        default). A dataset no longer where the run recorded it is a :class:`NerfEditError` (the offset, and so the
        proxy, would change)."""
        if self.source == "model":
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
        filmed (a capture's field is noise outside its cameras' reach). ``{}`` for a run without cameras (made from
        a model file, or whose dataset is no longer where the run recorded it): the default ring."""
        if not self.has_cameras():
            return {}
        cameras = self.cameras()
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

    def up(self) -> tuple[float, float, float] | None:
        """The up direction of the run's world: :func:`data_up` of its data."""
        return data_up(self.data)

    def source_transform(self) -> np.ndarray:
        """(4,4) float64: the similarity taking the coordinates of the mesh the data was generated from, or of the
        capture, to the run's (a capture's normalisation recorded in ``dataparser_transforms.json``, else the
        dataset's ``source_transform``, written by ``nerfedit generate``); the identity for data that nerfedit did not
        transform (a dataset without the record, a model file other than a generated dataset's ``mesh.ply``). Edit
        specs with ``frame: source`` and ``--frame capture`` use it."""
        if (self.path / DATAPARSER).is_file():
            return read_dataparser_transforms(self.path / DATAPARSER)
        data = self.data
        if is_model_file(data):
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


def data_up(data: Path) -> tuple[float, float, float] | None:
    """The up direction of a dataset's world, ``data`` its folder, a transforms file or a mesh file in it: z for a
    dataset of `nerfedit generate` (its config.yml records the generator's options; its world is z-up by
    construction), else the consensus of the training cameras (:func:`~nerfedit_plugin.data.datasets.world_up`); a
    mesh shares the world of the dataset it sits in (a generated dataset's mesh.ply), else None (unknown)."""
    import yaml

    folder = data.parent if data.is_file() else data
    generated = folder / CONFIG
    if generated.is_file():
        try:
            record = yaml.safe_load(generated.read_text()) or {}
        except (OSError, UnicodeDecodeError, yaml.YAMLError):  # another tool's config.yml: no say on the up
            record = {}
        if isinstance(record, dict) and {"up_axis", "n_train", "resolution"} <= record.keys():
            return Z_UP
    try:
        transforms = read_transforms(transforms_file(folder if data.suffix != ".json" else data, "train"), "train")
    except NerfEditError:
        return None
    return world_up(transforms.cameras)


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
