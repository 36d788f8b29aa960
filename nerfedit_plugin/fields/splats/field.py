"""The ``splats`` field backend: anisotropic 3D Gaussians in the INRIA conventions, drawn by the CPU rasteriser.

A run is made from a splat file (``nerfedit train --field splats --data point_cloud.ply``, or a ``.splat`` file) or
trained on a dataset (:meth:`SplatsField.fit`, the 3DGS recipe of :mod:`.training`). The Gaussians live in the
checkpoint's state dict (``means``, ``quats``, ``log_scales``, ``opacities``, ``sh``): the run's one store of the
model. A run made from a file has its scene box span the ``[p, 100 − p]`` percentiles of the means on each axis
(``box_percentile``), grown by ``padding`` × its diagonal: imported captures carry far background Gaussians, which a
min/max box would let decide the box (a trained run has the dataset's box).

Rendering (:meth:`SplatsField.render`): projection and colours in torch (:mod:`.projection`), compositing by the
numba rasteriser (:mod:`.rasterize`). A deformation (a :class:`~nerfedit_plugin.bending.maps.ForwardMap`) moves the
Gaussians (:func:`.deform.deform_model`: ``μ ↦ φ(μ)``, ``Σ ↦ F Σ Fᵀ``, SH rotated by ``F``'s polar rotation); the
moved model is drawn as any other, and :meth:`SplatsField.export` writes that same model.
"""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np
import torch
import tyro

from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.fields.grid_field import check_trainer_config
from nerfedit_plugin.fields.splats.deform import DeformReport, deform_model
from nerfedit_plugin.fields.splats.extract import fuse_mesh
from nerfedit_plugin.fields.splats.files import read_splats, write_splats
from nerfedit_plugin.fields.splats.model import SplatModel
from nerfedit_plugin.fields.splats.rasterize import RasterStats, project_gaussians, rasterize
from nerfedit_plugin.fields.splats.training import SplatRecipe
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.training.trainer import TrainerConfig

PARAMETERS = ("means", "quats", "log_scales", "opacities", "sh")
"""The Gaussians' parameters, in :class:`SplatModel` order."""


@dataclasses.dataclass
class SplatsConfig(FieldConfig):
    """3D Gaussian splats (INRIA layout), trained on posed images or read from a PLY or .splat file."""

    _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: SplatsField)
    box_percentile: float = 1.0
    """The scene box spans the [p, 100 − p] percentiles of the Gaussians' means on each axis (far background
    Gaussians of a capture stay outside it)."""
    padding: float = 0.05
    """The percentile box is grown by this fraction of its diagonal on every side."""
    rasterize_mode: Literal["classic", "antialiased"] = "classic"
    """``classic``: 3DGS's rasterisation; ``antialiased``: opacities scaled by √(det(Σ₂ − 0.3 I) / det Σ₂)
    (Mip-Splatting's 2D filter) — the mode the model was trained with (a PLY does not record it)."""
    split_growth: float | None = None
    """Under a deformation, split each Gaussian whose anisotropy (longest / shortest axis) grows by more than this
    factor into up to 8 along its stretched axis (the needle remedy); default: never split."""
    recipe: SplatRecipe = dataclasses.field(default_factory=SplatRecipe)
    """Training on a dataset: start, learning rates, loss, density control."""
    train: TrainerConfig = dataclasses.field(default_factory=TrainerConfig)
    """Optimisation budget (``batch_rays`` and ``n_samples`` are unused: a step renders one whole training view)."""

    def __post_init__(self) -> None:
        check_option(self, "box_percentile", self.box_percentile, 0 <= self.box_percentile < 50, "in [0, 50)")
        check_option(self, "padding", self.padding, 0 <= self.padding < math.inf, "a number >= 0")
        check_option(
            self, "rasterize_mode", self.rasterize_mode, self.rasterize_mode in ("classic", "antialiased"),
            "'classic' or 'antialiased'",
        )  # fmt: skip
        if self.split_growth is not None:
            check_option(self, "split_growth", self.split_growth, 1 <= self.split_growth < math.inf, "a number >= 1")
        check_trainer_config(self, self.train, "train.")

    @classmethod
    def tiny(cls, seconds: float = 5.0, **overrides: Any) -> SplatsConfig:
        """A small, fast preset for tests and smoke runs: ``seconds`` of training from 2000 Gaussians (500 far),
        density control every 50 steps up to 10k Gaussians, no progress bar."""
        recipe = SplatRecipe(
            init_gaussians=2000, far_gaussians=500, densify_from=50, densify_every=50, max_gaussians=10_000
        )
        return cls(**{"recipe": recipe, "train": TrainerConfig.tiny(seconds), **overrides})


class SplatsField(Field):
    """``N`` Gaussians as parameters ``means (N,3)``, ``quats (N,4)`` (w x y z), ``log_scales (N,3)``, ``opacities
    (N,)`` (logits), ``sh (N,K,3)``. Build one with :meth:`from_file` or :meth:`from_model`;
    ``SplatsConfig().setup(scene_bbox=...)`` gives an empty field that :meth:`load_state_dict` fills or :meth:`fit`
    trains."""

    kind: ClassVar[str] = "density"
    rendering: ClassVar[str] = "primitives"
    sources: ClassVar[frozenset[str]] = frozenset({"model", "dataset"})
    exports: ClassVar[tuple[str, ...]] = ("ply", "splat")

    def __init__(self, config: SplatsConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__(config, scene_bbox)
        self.means = torch.nn.Parameter(torch.zeros(0, 3))
        self.quats = torch.nn.Parameter(torch.zeros(0, 4))
        self.log_scales = torch.nn.Parameter(torch.zeros(0, 3))
        self.opacities = torch.nn.Parameter(torch.zeros(0))
        self.sh = torch.nn.Parameter(torch.zeros(0, 1, 3))
        self.last_stats = RasterStats()
        """Counts and stage times of the last :meth:`render`."""
        self._deformed: tuple | None = None  # (key, (model, report)) of :meth:`deformed`

    # ---- building --------------------------------------------------------------------------------------------------
    @classmethod
    def from_file(cls, path: Path, config: SplatsConfig | None = None) -> SplatsField:
        """The field of the splat file ``path`` (INRIA/nerfstudio PLY or ``.splat``; bad files are a
        NerfEditError naming the file)."""
        return cls.from_model(read_splats(path), config)

    @classmethod
    def from_model(cls, model: SplatModel, config: SplatsConfig | None = None) -> SplatsField:
        """The field of ``model`` (float32), its scene box from the percentiles of the means (module docstring)."""
        config = SplatsConfig() if config is None else config
        model = model.validate("splats").astype(np.float32)
        field = cls(config, torch.from_numpy(scene_box(model.means, config.box_percentile, config.padding)))
        for name, values in zip(PARAMETERS, model.arrays()):
            setattr(field, name, torch.nn.Parameter(torch.from_numpy(values.copy())))
        return field

    def set_model(self, model: SplatModel) -> None:
        """Replace the Gaussians by ``model``'s (float32, on the field's device)."""
        device = self.scene_bbox.device
        for name, values in zip(PARAMETERS, model.astype(np.float32).arrays()):
            setattr(self, name, torch.nn.Parameter(torch.from_numpy(values.copy()).to(device)))

    def fit(self, dataset: Any, *, eval_dataset: Any = None, trainer: TrainerConfig | None = None) -> dict:
        """Train on ``dataset`` from its sparse points (a capture's) or from Gaussians uniform in the scene box, with
        the 3DGS recipe (:mod:`.training`; ``trainer`` overrides ``config.train``)."""
        from nerfedit_plugin.fields.splats import training

        points = None if dataset.points is None else dataset.points.double().cpu().numpy()
        return training.fit(self, dataset, eval_dataset, trainer or self.config.train, points)

    def to_model(self) -> SplatModel:
        """The Gaussians as a :class:`SplatModel` (float32 numpy)."""
        return SplatModel(*(getattr(self, name).detach().cpu().numpy().copy() for name in PARAMETERS))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        """Adopt the checkpoint's parameter shapes (an empty field loads any model), then load as usual."""
        for name in PARAMETERS:
            value = state_dict.get(prefix + name)
            if isinstance(value, torch.Tensor):
                current = getattr(self, name)
                setattr(self, name, torch.nn.Parameter(torch.empty_like(value, device=current.device)))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @property
    def n_gaussians(self) -> int:
        return len(self.means)

    @property
    def degree(self) -> int:
        return round(self.sh.shape[1] ** 0.5) - 1

    # ---- the Field contract ----------------------------------------------------------------------------------------
    def query(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Not available: splats are drawn by rasterisation (``rendering = "primitives"``, :meth:`render`)."""
        raise NotImplementedError("the splats field renders by rasterisation (render()), not by point queries")

    def extract_mesh(self, resolution: int = 256, level: float | None = None) -> SurfaceMesh:
        """TSDF fusion of the Gaussians' depth seen from around the scene box (:func:`.extract.fuse_mesh`; voxel
        ``max(box extent) / resolution``; ``level``: the accumulated opacity a pixel needs to give a depth, default
        0.5)."""
        box = self.scene_bbox.detach().double().cpu().numpy()
        return fuse_mesh(self.to_model(), box, resolution, level, self.config.rasterize_mode == "antialiased")

    @torch.no_grad()
    def render(self, cameras: Any, index: int, config: Any, deformation: Any = None, frame: int = 0) -> torch.Tensor:
        """The ``(H,W,3)`` image in [0, 1] of camera ``index`` (module docstring), composited over
        ``config.background``; with ``deformation`` (a ForwardMap) the Gaussians moved into ``frame``."""
        if self.n_gaussians == 0:
            raise NerfEditError("splats field: no Gaussians loaded (use SplatsField.from_file or load a checkpoint)")
        stats, start = RasterStats(), time.perf_counter()
        c2w = cameras.c2w[index].detach().double().cpu()
        intrinsics = tuple(float(getattr(cameras, k)[index]) for k in ("fx", "fy", "cx", "cy"))
        size = (cameras.width, cameras.height)
        antialiased = self.config.rasterize_mode == "antialiased"
        model = self.to_model() if deformation is None else self.deformed(deformation, frame)[0]
        projected = project_gaussians(*model.arrays(), c2w.numpy(), intrinsics, *size, antialiased)
        stats.seconds["project"] = time.perf_counter() - start
        background = tuple(getattr(config, "background", (1.0, 1.0, 1.0)))
        image, _ = rasterize(*projected, *size, background, stats)
        self.last_stats = stats
        return image.clamp(0.0, 1.0).to(self.scene_bbox.device)

    def deformed(self, deformation: Any, frame: int = 0) -> tuple[SplatModel, DeformReport]:
        """The model moved by the forward map ``deformation`` at ``frame`` (:func:`.deform.deform_model`, splitting
        by the config's ``split_growth``) and its report; the last result is kept for the next camera of the frame."""
        key = (deformation, frame, self.config.split_growth, id(self.means), self.means._version)
        if self._deformed is None or self._deformed[0] != key:
            self._deformed = None  # the old model is freed before the new one is made
            moved = deform_model(self.to_model(), deformation, frame, split_growth=self.config.split_growth)
            self._deformed = (key, moved)
        return self._deformed[1]

    def export(self, path: str | Path, deformation: Any = None, frame: int = 0) -> dict:
        """Write the Gaussians — moved by ``deformation`` at ``frame`` when given, exactly as :meth:`render` draws
        them — as a splat file (``.splat`` by suffix, else the INRIA PLY, float32), atomically → what was written
        (``gaussians``, and the forward map's report under ``deformation``)."""
        if deformation is None:
            write_splats(self.to_model(), path)
            return {"gaussians": self.n_gaussians}
        model, report = self.deformed(deformation, frame)
        write_splats(model, path)
        return {"gaussians": len(model), "deformation": dataclasses.asdict(report)}


def scene_box(means: np.ndarray, percentile: float, padding: float) -> np.ndarray:
    """``(2,3)``: the ``[percentile, 100 − percentile]`` per-axis percentiles of ``means (N,3)``, grown by ``padding`` ×
    the diagonal on every side (a box of a single point gets a unit diagonal's padding)."""
    box = np.percentile(means.astype(np.float64), [percentile, 100.0 - percentile], axis=0)
    diagonal = float(np.linalg.norm(box[1] - box[0])) or 1.0
    return np.stack([box[0] - padding * diagonal, box[1] + padding * diagonal])
