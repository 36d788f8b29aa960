"""The ``nerf`` field backend: a dense voxel grid of density and appearance features, a colour decoder (optionally a
tiny view-dependent MLP), and an occupancy grid for skipping empty space — built to train in minutes on a CPU.

One channels-last :class:`~nerfedit_plugin.fields.encoding.DenseGrid` with ``1 + features`` channels ``g`` over
``scene_bbox``: ``σ(x) = softplus(g₀(x) + shift) / h`` (0 outside the box; ``h`` the final grid's mean cell size),
``rgb = sigmoid(g₁..₃(x) [+ MLP([g₁..(x), SH(d)])])`` (:class:`~nerfedit_plugin.fields.grid_field.ColorDecoder`;
``decoder="rgb"``, the default, has no MLP). The occupancy grid is updated from exact per-cell maxima of σ, so it
never marks space above the threshold empty. Why these choices: docs/architecture.md, "fields/".
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import torch
import torch.nn.functional as F

from nerfedit_plugin.errors import check_option
from nerfedit_plugin.fields.encoding import DenseGrid
from nerfedit_plugin.fields.grid_field import (
    ColorDecoder,
    GridField,
    GridFieldConfig,
    grid_schedule,
    start_resolution,
)
from nerfedit_plugin.fields.level_set import extract_level_set
from nerfedit_plugin.fields.occupancy import OccupancyGrid, cell_maxima
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.training.trainer import TrainerConfig, train


@dataclasses.dataclass
class NerfConfig(GridFieldConfig):
    """Dense-grid NeRF: a density field and a colour grid (view-dependent decoder optional), trained on posed images.

    The defaults suit an object scene of about 100×100 pixels trained in minutes on a CPU: the grid starts at 64³
    for 300 steps (one cell ≈ one pixel footprint at 100×100, so every vertex gets gradients often), then refines to
    128³."""

    _target: type = dataclasses.field(default_factory=lambda: NerfField)
    density_init: float = 0.1
    """Initial density everywhere, per unit length (sets ``shift = softplus⁻¹(density_init · h)``)."""
    occupancy_threshold: float = 1.0
    """Cells whose maximal density is at most this are skipped by the renderer."""
    occupancy_shell: int = 0
    """Keep only occupied cells within this many cells of free space (0 keeps the whole interior): rays stop in
    the opaque shell, so skipping the interior saves most samples of solid objects."""
    mesh_level: float = 25.0
    """Default density level of :meth:`NerfField.extract_mesh`."""
    tv_points: int = 4096
    """Random points per step at whose cells ``appearance_tv`` is evaluated (half of them in occupied cells)."""
    lr_background: float = 0.3
    """Adam learning rate of the background grid, the model of what lies outside the scene box when the content runs
    out of the frame (scenes, captures, floors); unused on object datasets."""

    def __post_init__(self) -> None:
        super().__post_init__()
        check_option(self, "density_init", self.density_init, 0 < self.density_init < math.inf, "a positive number")
        check_option(self, "tv_points", self.tv_points, self.tv_points >= 1, "a positive integer")
        threshold, shell, level = self.occupancy_threshold, self.occupancy_shell, self.mesh_level
        check_option(self, "occupancy_threshold", threshold, 0 <= threshold < math.inf, "a number >= 0")
        check_option(self, "occupancy_shell", shell, shell >= 0, ">= 0 (0: the whole interior)")
        check_option(self, "mesh_level", level, 0 < level < math.inf, "a positive density")

    @classmethod
    def tiny(cls, seconds: float = 5.0, **overrides: Any) -> NerfConfig:
        """A small, fast preset for tests and smoke runs (``seconds`` of training, no progress bar)."""
        return super().tiny(seconds, **{"occupancy_warmup": 48, **overrides})


class NerfField(GridField):
    """Density and colour features on a dense grid; colour by sigmoid, or with decoder="mlp" a view-dependent MLP."""

    kind = "density"

    def __init__(self, config: NerfConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__(config, scene_bbox)
        start = start_resolution(config)
        self.cell = float(((self.scene_bbox[1] - self.scene_bbox[0]) / config.resolution).mean())
        self.shift = math.log(math.expm1(config.density_init * self.cell))
        init = torch.zeros((start + 1) ** 3, 1 + config.features)
        init[:, 1:].normal_(0.0, 0.1, generator=torch.Generator().manual_seed(0))
        self.grid = DenseGrid(self.scene_bbox, start, 1 + config.features, init)
        self.color = ColorDecoder(config.features, config.decoder, config.hidden, config.sh_degree)
        self.occupancy = (
            OccupancyGrid(self.scene_bbox, config.occupancy_resolution) if config.occupancy_resolution else None
        )

    # ---- the Field contract ------------------------------------------------------------------------------------
    def query(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        values = self.grid(points)
        lo, hi = self.scene_bbox
        inside = ((points >= lo) & (points <= hi)).all(-1)
        density = F.softplus(values[:, 0] + self.shift) * (inside / self.cell)
        return density, self.color(values[:, 1:], directions)

    @torch.no_grad()
    def cell_max_density(self) -> torch.Tensor:
        """Exact maximum of σ over each occupancy cell ``(R,R,R)``: the max over the grid vertices of the cell
        (trilinear interpolation is multilinear, softplus increasing)."""
        raw = self.grid.vertex_values()[0]
        return F.softplus(cell_maxima(raw, self.config.occupancy_resolution) + self.shift) / self.cell

    def update_occupancy(self) -> None:
        """Recompute the occupancy grid from the current densities."""
        if self.occupancy is not None:
            config = self.config
            self.occupancy.update(
                self.cell_max_density(), config.occupancy_threshold, config.occupancy_dilation, config.occupancy_shell
            )

    def fit(self, dataset: Any, *, eval_dataset: Any = None, trainer: TrainerConfig | None = None) -> dict:
        """Train on ``dataset`` with :func:`nerfedit_plugin.training.trainer.train` (``trainer`` overrides
        ``config.train``): the background model settled (:meth:`prepare_background`), the occupancy grid carved to
        the visual hull of transparent images, refreshed every ``occupancy_every`` steps after the warm-up, and the
        grid refined at ``upsample_steps``."""
        trainer = self.prepare_background(dataset, trainer or self.config.train)
        config = self.config

        def groups() -> list[dict]:
            found = [{"params": list(self.grid.parameters()), "lr": config.lr_grid}]
            if self.color.mlp is not None:
                found.append({"params": list(self.color.parameters()), "lr": config.lr_mlp})
            return found + self.background_groups()

        if self.occupancy is not None and config.carve and not dataset.opaque:
            self.occupancy.carve(dataset.cameras, self.free_depths(dataset).to(self.scene_bbox.device))
        generator = torch.Generator().manual_seed(trainer.seed)

        def regularizer(step: int) -> torch.Tensor:
            return config.appearance_tv * self.appearance_tv(self.sample_points(config.tv_points, generator))

        log = train(
            self,
            dataset,
            trainer,
            param_groups=groups,
            regularizer=regularizer if config.appearance_tv > 0 else None,
            callback=grid_schedule(self),
            eval_dataset=eval_dataset,
        )
        self.update_occupancy()
        return log

    @torch.no_grad()
    def extract_mesh(self, resolution: int = 256, level: float | None = None) -> SurfaceMesh:
        """Marching cubes of σ sampled on a ``resolution³`` lattice over ``scene_bbox`` at ``level`` (default
        ``mesh_level``); faces wind counter-clockwise seen from outside (low density); vertex colours are the
        field's RGB at each vertex seen along the inward normal."""
        level = self.config.mesh_level if level is None else float(level)
        return extract_level_set(
            lambda x: self.query(x, torch.zeros_like(x))[0],
            lambda x, d: self.query(x, d)[1],
            self.scene_bbox,
            resolution,
            level,
        )
