"""Building blocks of the dense-grid field backends (nerf, neus): their shared config, the coarse-to-fine resolution
check, the colour decoder, the appearance features' total variation and the background model's life cycle
(:mod:`nerfedit_plugin.fields.background`).

Colour: ``rgb = sigmoid(g₁..₃ + MLP([g₁.., SH(d)]))`` — a direct colour from the first three appearance features
``g`` of the grid plus, with ``decoder="mlp"``, a view-dependent residual of a one-hidden-layer MLP on all features
and the spherical-harmonics encoding of the view direction ``d``; its last layer is zero at start, so training
begins as a plain RGB grid.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, Literal

import torch
import torch.nn.functional as F

from nerfedit_plugin.errors import OptionError, check_option
from nerfedit_plugin.fields.background import BackgroundField
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.fields.encoding import spherical_harmonics
from nerfedit_plugin.fields.occupancy import silhouette_depths
from nerfedit_plugin.training.trainer import TrainerConfig

BORDER_COVERAGE = 0.02
"""``background="auto"`` on images with alpha: above this share of covered border pixels
(:attr:`~nerfedit_plugin.data.datasets.Dataset.border_coverage`) the content runs out of the frame and the background
model is on."""


@dataclasses.dataclass
class GridFieldConfig(FieldConfig):
    """Options shared by the dense-grid backends: grid, colour decoder, occupancy grid, learning rates, budget."""

    resolution: int = 128
    """Final grid cells per axis over the scene box (the grid has ``resolution + 1`` vertices per axis)."""
    upsample_steps: tuple[int, ...] = (300,)
    """Coarse to fine: the grid starts at ``resolution / 2^len(upsample_steps)`` cells per axis and doubles (exactly,
    see :meth:`DenseGrid.upsample`) after each of these steps."""
    features: int = 3
    """Appearance feature channels per grid vertex, ≥ 3 (the first three are the direct colour logits; exactly 3
    with ``decoder="rgb"``)."""
    decoder: Literal["mlp", "rgb"] = "rgb"
    """Colour decoder: direct colour plus a tiny MLP residual on features and view direction ("mlp"), or the direct
    colour alone (no view dependence; the built-in scene is unlit, so the MLP only costs time there)."""
    hidden: int = 32
    """Hidden width of the colour MLP (one hidden layer)."""
    sh_degree: int = 1
    """Spherical-harmonics degree of the view-direction encoding fed to the MLP (0: view-independent)."""
    occupancy_resolution: int = 64
    """Occupancy cells per axis; must divide the starting grid resolution. 0 disables the occupancy grid."""
    occupancy_dilation: int = 1
    """Occupied cells are grown by this many cells (neighbours keep learning)."""
    carve: bool = True
    """Before training, carve the occupancy grid to the visual hull of the training images' alpha (when present)."""
    occupancy_warmup: int = 128
    """Steps before the first occupancy update."""
    occupancy_every: int = 32
    """Steps between occupancy updates."""
    lr_grid: float = 0.1
    """Adam learning rate of the grid."""
    lr_mlp: float = 1e-2
    """Adam learning rate of the colour MLP."""
    background: Literal["auto", "color", "field"] = "auto"
    """What lies outside the scene box: ``field`` — a background model in contracted space (floors and surroundings
    that run out of the frame; :mod:`nerfedit_plugin.fields.background`), composited in ray order and never bent;
    ``color`` — the render config's constant colour (objects on a transparent background); ``auto`` — decided by
    ``fit`` from the training images: ``field`` when their content runs out of the frame (opaque images, or
    images with alpha covered on more than :data:`BORDER_COVERAGE` of their border pixels: a floor, a table),
    else ``color`` (the checkpoint stores the decision). With alpha, what the background model leaves transparent
    is composited over the constant colour."""
    background_resolution: int = 128
    """Final cells per axis of the background grid over the contracted cube [-2,2]³ (refined at
    ``upsample_steps`` with the field's grid)."""
    background_samples: tuple[int, int] = (0, 32)
    """Background-grid samples per ray between the camera and the scene box (0: none; what lies there is the ground
    layer's), and beyond the box."""
    ground_layer: int = 128
    """Cells per side of the ground layer's finest texture level (:mod:`nerfedit_plugin.fields.layers`: a plane found
    by a sweep over the training images, for a floor that runs out of the frame); 0: no ground layer."""
    far_layer: int = 64
    """Cells per side of the far sphere layer's finest texture level (surroundings far away); 0: no far layer."""
    lr_background: float = 0.1
    """Adam learning rate of the background grid."""
    appearance_tv: float = 0.05
    """Weight of the appearance features' total variation (:meth:`GridField.appearance_tv`), added to the loss:
    keeps smooth colour smooth where a grid cell is pinned by few pixels, instead of salt-and-pepper noise
    (0: off)."""
    train: TrainerConfig = dataclasses.field(default_factory=TrainerConfig)
    """Optimisation budget and schedule."""

    def __post_init__(self) -> None:
        """Reject values the field cannot be built or trained with (:class:`OptionError` naming the option)."""
        check_grid_config(self)

    @classmethod
    def tiny(cls, seconds: float = 5.0, **overrides: Any) -> GridFieldConfig:
        """A small, fast preset for tests and smoke runs (``seconds`` of training, no progress bar)."""
        preset = dict(
            resolution=32,
            features=4,
            decoder="mlp",
            hidden=16,
            occupancy_resolution=16,
            occupancy_every=16,
            background_resolution=32,
            background_samples=(0, 16),
            ground_layer=64,
            far_layer=32,
            train=TrainerConfig.tiny(seconds),
        )
        return cls(**{**preset, **overrides})


def check_grid_config(config: GridFieldConfig) -> None:
    """The checks of :meth:`GridFieldConfig.__post_init__` (grid, decoder, occupancy, learning rates, budget)."""
    levels = len(config.upsample_steps)
    check_option(config, "resolution", config.resolution, config.resolution >= 1, "a positive integer")
    for step in config.upsample_steps:
        check_option(config, "upsample_steps", config.upsample_steps, step >= 1, "positive step numbers")
    start, occupancy = config.resolution >> levels, config.occupancy_resolution
    check_option(config, "occupancy_resolution", occupancy, 0 <= occupancy <= 256, "in [0, 256] (0: no occupancy grid)")
    if start << levels != config.resolution or (occupancy and start % occupancy):
        multiple = (1 << levels) * max(occupancy, 1)
        raise OptionError(
            config,
            "resolution",
            f"must be a multiple of {multiple} (2^{levels} for the {levels} upsample_steps × occupancy_resolution "
            f"{occupancy}; lower occupancy_resolution or give fewer upsample_steps for a smaller grid), "
            f"got {config.resolution}",
        )
    check_option(config, "features", config.features, config.features >= 3, "at least 3")
    if config.decoder == "rgb":
        check_option(config, "features", config.features, config.features == 3, "exactly 3 with decoder rgb")
    check_option(config, "hidden", config.hidden, config.hidden >= 1, "a positive integer")
    check_option(config, "sh_degree", config.sh_degree, config.sh_degree in (0, 1, 2), "0, 1 or 2")
    choices = ("auto", "color", "field")
    check_option(config, "background", config.background, config.background in choices, "auto, color or field")
    background = config.background_resolution
    ok = background >> levels >= 1 and (background >> levels) << levels == background
    check_option(config, "background_resolution", background, ok, f"a positive multiple of 2^{levels} (upsample_steps)")
    samples = config.background_samples
    ok = len(samples) == 2 and samples[0] >= 0 and samples[1] >= 1
    check_option(config, "background_samples", samples, ok, "two integers: before the box >= 0, beyond it >= 1")
    for name in ("ground_layer", "far_layer"):
        size = getattr(config, name)
        check_option(config, name, size, size == 0 or size >= 32, "0 (off) or at least 32 cells")
    tv = config.appearance_tv
    check_option(config, "appearance_tv", tv, 0 <= tv < math.inf, "a number >= 0 (0: off)")
    check_option(config, "occupancy_dilation", config.occupancy_dilation, config.occupancy_dilation >= 0, ">= 0")
    check_option(config, "occupancy_warmup", config.occupancy_warmup, config.occupancy_warmup >= 0, ">= 0")
    check_option(config, "occupancy_every", config.occupancy_every, config.occupancy_every >= 1, ">= 1")
    for name in ("lr_grid", "lr_mlp", "lr_background"):
        value = getattr(config, name)
        check_option(config, name, value, 0 < value < math.inf, "a positive number")
    check_trainer_config(config, config.train, "train.")


def check_trainer_config(config: Any, train: TrainerConfig, prefix: str) -> None:
    """Check a backend's :class:`TrainerConfig` (option names ``prefix + field``; errors name ``config``)."""
    positive = {"max_seconds": train.max_seconds, "lr_final_factor": train.lr_final_factor}
    for name, value in positive.items():
        check_option(config, prefix + name, value, 0 < value < math.inf, "a positive number")
    for name in ("max_steps", "batch_rays", "n_samples", "eval_views", "log_every"):
        value = getattr(train, name)
        check_option(config, prefix + name, value, value >= 1, "a positive integer")
    every = train.eval_every_seconds
    check_option(config, prefix + "eval_every_seconds", every, 0 <= every < math.inf, ">= 0 (0: no evaluation)")
    decay = train.lr_decay_steps
    check_option(config, prefix + "lr_decay_steps", decay, decay >= 0, ">= 0 (0: decay over the budget)")
    margin = train.foreground_margin
    check_option(config, prefix + "foreground_margin", margin, margin >= -1, ">= -1 (-1: every pixel)")
    check_option(config, prefix + "clock", train.clock, train.clock in ("wall", "cpu"), "wall or cpu")


def start_resolution(config: Any) -> int:
    """The starting grid resolution ``resolution / 2^len(upsample_steps)`` of a grid config (``resolution``,
    ``upsample_steps``, ``features``, ``decoder``, ``occupancy_resolution``), checking that it is exact, that the
    occupancy resolution divides it and that the features suit the decoder (ValueError naming the config)."""
    name = type(config).__name__
    if config.features < 3 or (config.decoder == "rgb" and config.features != 3):
        raise ValueError(f"{name}: features must be >= 3 (exactly 3 with decoder='rgb'), got {config.features}")
    start, levels = config.resolution >> len(config.upsample_steps), len(config.upsample_steps)
    occupancy = config.occupancy_resolution
    if start << levels != config.resolution or (occupancy and start % occupancy):
        raise ValueError(
            f"{name}: resolution {config.resolution} must be a multiple of 2^{levels} "
            f"(len(upsample_steps)) times occupancy_resolution {occupancy}"
        )
    return start


def grid_schedule(field: Any) -> Callable[[int], bool]:
    """The trainer callback of a grid field (``field.grid``, ``field.background``, ``field.update_occupancy()``,
    ``field.config`` a :class:`GridFieldConfig`): refine the grid and the background grid after each of
    ``upsample_steps`` (returns True: the optimiser is rebuilt) and refresh the occupancy grid every
    ``occupancy_every`` steps after ``occupancy_warmup``."""
    config = field.config

    def callback(step: int) -> bool:
        refine = step + 1 in config.upsample_steps
        if refine:
            field.grid.upsample()
            if field.background is not None:
                field.background.grid.upsample()
        since = step + 1 - config.occupancy_warmup
        if since >= 0 and since % config.occupancy_every == 0:
            field.update_occupancy()
        return refine

    return callback


class GridField(Field):
    """What the dense-grid fields share beyond their config: view dependence from the colour decoder, the training
    samples per ray as the render default, the occupancy-grid mask, the background model (``self.background``, a
    :class:`BackgroundField` or None). Subclasses set ``self.color`` (a :class:`ColorDecoder`) and
    ``self.occupancy`` (an ``OccupancyGrid`` or None)."""

    def __init__(self, config: GridFieldConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__(config, scene_bbox)
        self.background = None
        if config.background == "field":
            self._add_background()

    def _add_background(self) -> None:
        config = self.config
        final = config.background_resolution
        start = final >> len(config.upsample_steps)
        self.background = BackgroundField(
            self.scene_bbox,
            start,
            final,
            *config.background_samples,
            ground=config.ground_layer,
            far=config.far_layer,
        )

    def background_model(self) -> BackgroundField | None:
        return self.background

    def prepare_background(self, dataset: Any, trainer: TrainerConfig) -> TrainerConfig:
        """Before ``fit``: settle ``background="auto"`` on ``dataset`` (:class:`GridFieldConfig`'s ``background``;
        ``self.config`` becomes a copy saying which) and build the background model when it is on. Returns the
        trainer config to use: with a background model rays are drawn from every pixel."""
        if self.config.background == "auto":
            leaves_frame = dataset.border_coverage > BORDER_COVERAGE
            self.config = dataclasses.replace(self.config, background="field" if leaves_frame else "color")
        if self.config.background != "field":
            return trainer
        if self.background is None:
            self._add_background()
        self.background.fit_layers(dataset)
        return dataclasses.replace(trainer, foreground_margin=-1)

    def free_depths(self, dataset: Any) -> torch.Tensor | None:
        """How far each training pixel's ray is known to be empty, ``(C,H,W)`` camera-space depths for
        :meth:`OccupancyGrid.carve`: off the silhouettes of images with alpha the whole ray (``inf``, else 0), and
        up to the background layer a pixel sees (:meth:`BackgroundField.free_depths`, after
        :meth:`prepare_background`), whichever reaches farther; None when nothing is known."""
        layers = None if self.background is None else self.background.free_depths(dataset)
        if dataset.opaque:
            return layers
        silhouettes = silhouette_depths(dataset.alpha > 0)
        return silhouettes if layers is None else torch.maximum(silhouettes, layers.to(silhouettes))

    def background_groups(self) -> list[dict]:
        """The optimiser group of the background grid (none without a background model)."""
        if self.background is None:
            return []
        return [{"params": list(self.background.parameters()), "lr": self.config.lr_background}]

    def sample_points(self, count: int, generator: torch.Generator) -> torch.Tensor:
        """``count`` points ``(count,3)``: half uniform in the box, half uniform in occupied occupancy cells."""
        lo, hi = self.scene_bbox
        uniform = torch.rand(count - count // 2, 3, generator=generator).to(lo)
        points = [lo + uniform * (hi - lo)]
        if self.occupancy is not None:
            cells = self.occupancy.mask.nonzero()
            if len(cells):
                pick = torch.randint(0, len(cells), (count // 2,), generator=generator).to(cells.device)
                offset = torch.rand(count // 2, 3, generator=generator).to(lo)
                points.append(lo + (cells[pick] + offset) * (hi - lo) / self.occupancy.resolution)
        return torch.cat(points)

    def appearance_tv(self, points: torch.Tensor) -> torch.Tensor:
        """Total variation of the appearance features over the cells of ``points (M,3)``: the mean over the cells'
        12 edges and the feature channels of ``(g(a) − g(b))²``, ``a, b`` an edge's two grid vertices (Plenoxels'
        TV, on sampled cells)."""
        rows = self.grid.corners(points.detach())[0]
        features = F.embedding(rows, self.grid.table)[..., 1:]  # (M, 8, C)
        a, b = _EDGES.to(rows.device).unbind(0)
        return (features[:, a] - features[:, b]).square().mean()

    @property
    def view_dependent(self) -> bool:
        return self.color.view_dependent

    @property
    def render_samples(self) -> int:
        """The samples per ray of training (those the held-out PSNR was measured with)."""
        return self.config.train.n_samples

    def occupied(self, points: torch.Tensor) -> torch.Tensor:
        """Occupancy-grid mask of canonical ``points`` (the box itself without an occupancy grid)."""
        if self.occupancy is None:
            lo, hi = self.scene_bbox
            return ((points >= lo) & (points <= hi)).all(-1)
        return self.occupancy.occupied(points)


_EDGES = torch.tensor(
    [[0, 1, 2, 3, 0, 1, 4, 5, 0, 2, 4, 6], [4, 5, 6, 7, 2, 3, 6, 7, 1, 3, 5, 7]]
)  # the 12 edges of a cell as pairs of corners (DenseGrid.corners order: x slowest, z fastest)


class ColorDecoder(torch.nn.Module):
    """Appearance features ``(M, features)`` and unit directions ``(M,3)`` → ``rgb (M,3)`` (module docstring)."""

    def __init__(self, features: int, decoder: str, hidden: int, sh_degree: int) -> None:
        super().__init__()
        self.sh_degree = sh_degree
        self.mlp = None
        if decoder == "mlp":
            width = features + (sh_degree + 1) ** 2
            self.mlp = torch.nn.Sequential(torch.nn.Linear(width, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, 3))
            torch.nn.init.zeros_(self.mlp[2].weight)
            torch.nn.init.zeros_(self.mlp[2].bias)

    @property
    def view_dependent(self) -> bool:
        """The MLP sees the view direction (degree ≥ 1 spherical harmonics)."""
        return self.mlp is not None and self.sh_degree > 0

    def forward(self, features: torch.Tensor, directions: torch.Tensor) -> torch.Tensor:
        logits = features[:, :3]
        if self.mlp is not None:
            logits = logits + self.mlp(torch.cat([features, spherical_harmonics(directions, self.sh_degree)], -1))
        return torch.sigmoid(logits)
