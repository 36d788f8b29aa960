"""The ``neus`` field backend: a signed distance field and appearance on a dense voxel grid, rendered with NeuS's
unbiased opacity (in the shared renderer), a learned sharpness, an eikonal loss and an occupancy band around the
surface — built to train in minutes on a CPU.

One channels-last :class:`~nerfedit_plugin.fields.encoding.DenseGrid` with ``1 + features`` channels ``g`` over
``scene_bbox``, refined coarse to fine: ``f(x) = h · g₀(x)`` (``h`` the final grid's mean cell size; initialised to a
sphere, or with ``init_hull`` to the signed distance of the images' visual hull — the box itself for opaque
images), colour :class:`~nerfedit_plugin.fields.grid_field.ColorDecoder` of ``g₁..(x)`` and ``d``, sharpness
``s = exp(log_s) / h``.
Eikonal loss ``mean (|∇f| − 1)²`` with the grid's analytic gradient (half the points uniform in the box, half in
occupied cells); only cells holding a point with ``|f| ≤ occupancy_band / s`` are sampled (exact per cell).
Why these choices: docs/architecture.md, "fields/".
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
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
class NeusConfig(GridFieldConfig):
    """Dense-grid NeuS: a signed distance field (its zero level set is the surface), trained on posed images.

    The defaults suit an object scene of about 100×100 pixels trained in minutes on a CPU."""

    _target: type = dataclasses.field(default_factory=lambda: NeusField)
    init_radius: float = 0.5
    """Radius of the initial sphere, as a fraction of the smallest half side of the scene box."""
    init_hull: bool = True
    """When the training images frame objects on a transparent background, :meth:`NeusField.fit` first replaces the
    sphere by the signed distance to the visual hull of the covered pixels (at the starting grid resolution), so
    training starts near the surface. When their content runs out of the frame (the background model on: opaque
    images, a floor) silhouettes are no object's hull: the field starts from the box's own surface (shrunk by two
    cells), carved by the photometric hull when a background layer is found (the pixels that see the floor or the
    far sphere through the box, :meth:`GridField.free_depths`) and by the transparent pixels. Off: the sphere of
    ``init_radius``."""
    init_shell: float = 4.0
    """With ``init_hull`` on images with silhouettes: start from the hull's shell of this thickness in final cells
    (``f = |d + t/2| − t/2``, ``d`` the hull's signed distance), hollow inside; 0: the solid hull. The hull closes a
    cavity no silhouette sees into (a cup, a bowl) with a lid, which a solid start has to carve away cell by cell,
    while the colour loss opens a thin lid onto the hollow. Where the object lies deeper than ``t`` inside its hull
    (the bunny's concavities), training pierces the shell and the void behind it is filled after training
    (``fill_gap``). A scene's photometric hull always starts solid: below its floor it reaches the box's border
    unseen, and a shell there would leave a hollow open to the border, extracted as a second floor."""
    fill_gap: int = 1
    """After training, voids that reach the outside only through gaps of at most ``2·fill_gap`` grid vertices are
    filled (:meth:`NeusField.fill_voids`; 0: only voids closed off entirely). The shell start (``init_shell``)
    leaves such voids where training pierced it."""
    sharpness_init: float = 0.5
    """Initial NeuS sharpness times the final cell size, ``s · h`` (0.5: the logistic density spans ~2 cells)."""
    eikonal_weight: float = 1e-3
    """Weight of the eikonal loss."""
    eikonal_points: int = 4096
    """Random points per step at which the eikonal loss (and ``appearance_tv``) is evaluated."""
    anneal_steps: int = 300
    """The renderer's cosine annealing ratio ramps linearly from 0 to 1 (unbiased) over these first steps."""
    occupancy_band: float = 8.0
    """Cells are sampled when they hold a point with ``|f| ≤ occupancy_band / s`` (opacity changes by at most
    ~``exp(−occupancy_band)`` elsewhere)."""
    occupancy_warmup: int = 64
    """Steps before the first occupancy update."""
    lr_grid: float = 0.2
    """Adam learning rate of the grid (SDF in cells, colour logits)."""
    lr_sharpness: float = 1e-2
    """Adam learning rate of ``log_s``."""
    train: TrainerConfig = dataclasses.field(
        default_factory=lambda: TrainerConfig(batch_rays=2048, n_samples=64, lr_decay_steps=600)
    )
    """Optimisation budget and schedule: 64 samples per ray (the occupancy band keeps them near the surface); the
    learning rates decay to their final value over the first 600 steps whatever the budget, so a longer budget
    trains on at the final rate."""

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("init_radius", "sharpness_init", "occupancy_band", "lr_sharpness"):
            value = getattr(self, name)
            check_option(self, name, value, 0 < value < math.inf, "a positive number")
        check_option(self, "init_radius", self.init_radius, self.init_radius <= 1, "at most 1 (inside the box)")
        weight = self.eikonal_weight
        check_option(self, "eikonal_weight", weight, 0 <= weight < math.inf, "a number >= 0")
        check_option(self, "eikonal_points", self.eikonal_points, self.eikonal_points >= 1, "a positive integer")
        check_option(self, "anneal_steps", self.anneal_steps, self.anneal_steps >= 0, ">= 0")
        check_option(self, "fill_gap", self.fill_gap, self.fill_gap >= 0, ">= 0")

    @classmethod
    def tiny(cls, seconds: float = 5.0, **overrides: Any) -> NeusConfig:
        """A small, fast preset for tests and smoke runs (``seconds`` of training, no progress bar)."""
        return super().tiny(seconds, **{"upsample_steps": (), "occupancy_warmup": 16, "anneal_steps": 20, **overrides})


class NeusField(GridField):
    """Signed distance field on a dense grid with NeuS sharpness (see the module docstring)."""

    kind = "sdf"

    def __init__(self, config: NeusConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__(config, scene_bbox)
        start = start_resolution(config)
        occupancy = config.occupancy_resolution
        lo, hi = self.scene_bbox
        self.cell = float(((hi - lo) / config.resolution).mean())
        init = torch.zeros((start + 1) ** 3, 1 + config.features)
        init[:, 1:].normal_(0.0, 0.1, generator=torch.Generator().manual_seed(0))
        self.grid = DenseGrid(self.scene_bbox, start, 1 + config.features, init)
        with torch.no_grad():
            radius = config.init_radius * float((hi - lo).min()) / 2
            distance = (self.grid.vertex_points().reshape(-1, 3) - (lo + hi) / 2).norm(dim=-1) - radius
            self.grid.table[:, 0] = distance / self.cell
        self.log_sharpness = torch.nn.Parameter(torch.tensor(math.log(config.sharpness_init)))
        self.color = ColorDecoder(config.features, config.decoder, config.hidden, config.sh_degree)
        self.occupancy = OccupancyGrid(self.scene_bbox, occupancy) if occupancy else None

    # ---- the Field contract ------------------------------------------------------------------------------------
    def query(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """SDF and colour; when ``points`` require grad, ``f`` carries the first-order term ``(x − x̄)·∇f(x̄)``
        (``x̄`` = detached ``x``; zero in value) so that autograd's ``∂f/∂x`` is the analytic gradient of the grid,
        differentiable with respect to the grid — the renderer's NeuS cosine then costs no double backward."""
        values, gradient = self.grid.value_and_gradient(points)
        sdf = values[:, 0]
        if points.requires_grad:
            sdf = sdf + ((points - points.detach()) * gradient[:, :, 0]).sum(-1)
        return sdf * self.cell, self.color(values[:, 1:], directions)

    def sharpness(self) -> torch.Tensor:
        return self.log_sharpness.exp() / self.cell

    # ---- training ----------------------------------------------------------------------------------------------
    def eikonal_loss(self, points: torch.Tensor) -> torch.Tensor:
        """``mean (|∇f| − 1)²`` at ``points (M,3)`` (the grid's analytic gradient)."""
        gradient = self.grid.value_and_gradient(points)[1][:, :, 0] * self.cell
        return (gradient.norm(dim=-1) - 1.0).square().mean()

    @torch.no_grad()
    def init_from_hull(
        self, cameras: Any, free: torch.Tensor, margin: int = 0, keep_unseen: bool = False, shell: float | None = None
    ) -> None:
        """Set ``f`` at the grid vertices to the signed distance (Euclidean distance transform, scipy) to the hull that
        the pixels' free depths ``free (C,H,W)`` carve (:meth:`OccupancyGrid.carve` with ``margin`` pixels, of cells
        centred on the vertices): the visual hull of silhouettes (``silhouette_depths``; carved without keeping what
        a camera does not see, as a box corner out of every side view's frame would otherwise stay), or the
        photometric hull of a scene (:meth:`GridField.free_depths`; ``keep_unseen``: the floor runs out of the frames).
        ``shell``: the hollow start's thickness in final cells (default ``init_shell``; 0: the solid hull). Kept as is
        when the hull is empty or fills the box."""
        from scipy.ndimage import distance_transform_edt

        lo, hi = self.scene_bbox
        n = self.grid.resolution
        half = (hi - lo) / (2 * n)
        hull = OccupancyGrid(torch.stack([lo - half, hi + half]), n + 1)
        hull.carve(cameras, free, margin, keep_unseen)
        inside = hull.mask.cpu().numpy()
        if inside.all() or not inside.any():
            return
        width = tuple((2 * half).cpu().tolist())
        distance = distance_transform_edt(~inside, sampling=width) - distance_transform_edt(inside, sampling=width)
        distance -= np.where(inside, -1.0, 1.0) * float(half.mean())  # halfway between the vertices in and out
        shell = self.config.init_shell if shell is None else shell
        if shell > 0:
            thickness = shell * self.cell
            distance = np.abs(distance + thickness / 2) - thickness / 2
        self.grid.table[:, 0] = torch.from_numpy(distance.reshape(-1) / self.cell).to(self.grid.table)

    @torch.no_grad()
    def fill_voids(self) -> None:
        """Make the enclosed voids solid: grid vertices outside the surface (``f > 0``) that no 6-connected path of
        outside vertices links to the grid's border, once the inside is grown by ``fill_gap`` vertices, get
        ``f ← −f`` — with the gaps they were reached through (the growth undone within the outside vertices). No
        camera sees into these voids (a hollow start's shell, unopened or pierced by training through a gap of at
        most ``2·fill_gap`` vertices; a bubble), and their inner walls would otherwise be extracted."""
        from scipy.ndimage import binary_dilation, binary_fill_holes, generate_binary_structure

        inside = (self.grid.vertex_values()[0] <= 0).cpu().numpy()
        gap, faces = self.config.fill_gap, generate_binary_structure(3, 1)
        grown = binary_dilation(inside, faces, iterations=gap) if gap else inside
        void = binary_fill_holes(grown) & ~grown
        if gap and void.any():
            void = binary_dilation(void, faces, iterations=gap + 1, mask=~inside)
        void = torch.from_numpy(void.reshape(-1)).to(self.grid.table.device)
        self.grid.table[void, 0] *= -1

    @torch.no_grad()
    def init_from_box(self) -> None:
        """Set ``f`` at the grid vertices to the signed distance to the scene box shrunk by two final cells: the
        visual hull of opaque images (every pixel covered) is the whole box. NeuS's opacity is flat where
        ``|f| ≫ 1/s``, so surfaces far from a small starting sphere get no gradient; the box's surface lies in front
        of everything inside it."""
        lo, hi = self.scene_bbox
        q = (self.grid.vertex_points().reshape(-1, 3) - (lo + hi) / 2).abs() - ((hi - lo) / 2 - 2 * self.cell)
        distance = q.clamp_min(0.0).norm(dim=-1) + q.amax(-1).clamp_max(0.0)
        self.grid.table[:, 0] = distance / self.cell

    @torch.no_grad()
    def cell_min_distance(self) -> torch.Tensor:
        """Exact ``min |f|`` over each occupancy cell ``(R,R,R)``: the distance from 0 to the range of the vertex
        values of the cell."""
        raw, cells = self.grid.vertex_values()[0], self.config.occupancy_resolution
        high, low = cell_maxima(raw, cells), -cell_maxima(-raw, cells)
        return (F.relu(low) + F.relu(-high)) * self.cell

    def update_occupancy(self) -> None:
        """Occupied ⇔ the cell holds a point with ``|f| ≤ occupancy_band / s`` (within the carved hull)."""
        if self.occupancy is not None:
            band = self.config.occupancy_band / float(self.sharpness().detach())
            self.occupancy.update(-self.cell_min_distance(), -band, self.config.occupancy_dilation)

    def fit(self, dataset: Any, *, eval_dataset: Any = None, trainer: TrainerConfig | None = None) -> dict:
        """Train on ``dataset`` with :func:`nerfedit_plugin.training.trainer.train` (``trainer`` overrides
        ``config.train``): colour loss + ``eikonal_weight`` × eikonal loss, cosine annealing over ``anneal_steps``, the
        occupancy band carved to the visual hull and refreshed every ``occupancy_every`` steps after the warm-up, and
        the grid refined at ``upsample_steps``. With the background model on (:meth:`prepare_background`: content
        runs out of the frame) silhouettes are no object's hull: with ``init_hull`` the field starts from the box
        (:meth:`init_from_box`) carved by the photometric hull and the transparent pixels when there are any;
        opaque images carve nothing from the occupancy grid (measured on the scene: no gain for ``nerf``)."""
        trainer = self.prepare_background(dataset, trainer or self.config.train)
        config = self.config
        generator = torch.Generator().manual_seed(trainer.seed)

        def regularizer(step: int) -> torch.Tensor:
            points = self.sample_points(config.eikonal_points, generator)
            loss = config.eikonal_weight * self.eikonal_loss(points)
            return loss + config.appearance_tv * self.appearance_tv(points) if config.appearance_tv > 0 else loss

        def groups() -> list[dict]:
            return [
                {"params": list(self.grid.parameters()), "lr": config.lr_grid},
                {"params": [self.log_sharpness], "lr": config.lr_sharpness},
                {"params": list(self.color.parameters()), "lr": config.lr_mlp},
            ] + self.background_groups()

        free, scene = self.free_depths(dataset), config.background == "field"
        free = None if free is None else free.to(self.scene_bbox.device)
        if config.init_hull and scene:
            self.init_from_box()
        if config.init_hull and free is not None:
            self.init_from_hull(dataset.cameras, free, keep_unseen=scene, shell=0.0 if scene else None)
        if self.occupancy is not None and config.carve and not dataset.opaque:
            self.occupancy.carve(dataset.cameras, free)
        log = train(
            self,
            dataset,
            trainer,
            param_groups=groups,
            regularizer=regularizer,
            callback=grid_schedule(self),
            cos_anneal=lambda step: min(1.0, step / max(config.anneal_steps, 1)),
            eval_dataset=eval_dataset,
        )
        self.fill_voids()
        self.update_occupancy()
        return log

    def extract_mesh(self, resolution: int = 256, level: float | None = None) -> SurfaceMesh:
        """Marching cubes of the level set ``f = level`` (default 0: the surface) on a ``resolution³`` lattice over
        ``scene_bbox``; faces wind counter-clockwise seen from outside; vertex colours are the field's RGB at each
        vertex seen along the inward normal."""
        level = 0.0 if level is None else float(level)
        return extract_level_set(
            lambda x: -self.query(x, torch.zeros_like(x))[0],
            lambda x, d: self.query(x, d)[1],
            self.scene_bbox,
            resolution,
            -level,
        )
