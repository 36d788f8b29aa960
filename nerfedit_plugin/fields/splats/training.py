r"""Training Gaussian splats on a dataset: the 3D Gaussian Splatting recipe (Kerbl et al. 2023) sized for a CPU.

- **Start.** The capture's sparse points (COLMAP ``points3D``, a nerfstudio ``ply_file_path``) when the dataset has
  them, else ``init_gaussians`` means uniform in the scene box — and, for opaque images (a scene: floor and
  surroundings run out of the box), ``far_gaussians`` more uniform on the sphere about the cameras' mean centre at
  twice their largest distance from it; scales the mean distance to the 3 nearest other means (isotropic), identity
  rotations, opacity ``init_opacity``, grey colour (SH DC 0, higher bands 0). Means are never confined to the box:
  what lies outside it (floors, far backgrounds) is Gaussians too, over the dataset's constant background colour.
- **Step.** One training view (a shuffled cycle over the views) rendered whole through the differentiable rasteriser
  (:mod:`.backward`: torch projection, numba compositor backward) over the dataset's background colour; loss
  ``(1 − λ) L1 + λ (1 − SSIM)`` (``λ = ssim_weight``; L1 over the dataset's mask when it has one); SH bands used up
  to degree ``min(sh_degree, step // sh_degree_every)``.
- **Adam** per parameter group (the shared loop, :func:`nerfedit_plugin.training.trainer.train`): means at
  ``lr_means × extent`` decaying exponentially to ``lr_means_final`` of it over the budget (``extent`` = 1.1 × the
  largest distance of a camera centre from their mean), the other rates constant.
- **Density control** (:mod:`.densify`) every ``densify_every`` steps in ``[densify_from, densify_until)``: the mean
  over the steps a Gaussian was drawn of the norm of its 2D-mean gradient in NDC units (pixel gradient × (W/2, H/2))
  at or above ``grad_threshold`` marks it; marked Gaussians with largest scale ≤ ``split_scale × extent`` are
  cloned, larger ones split (no growth past ``max_gaussians``: the strongest gradients go first); then Gaussians of
  opacity below ``min_opacity`` or of largest scale above ``prune_scale × extent`` are pruned. Every
  ``reset_every`` steps (until ``densify_until``) opacities are reset to at most 0.01.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from nerfedit_plugin.errors import check_option
from nerfedit_plugin.fields.splats import densify
from nerfedit_plugin.fields.splats.backward import rasterize
from nerfedit_plugin.fields.splats.model import SplatModel
from nerfedit_plugin.fields.splats.projection import colors, covariances, project, view_matrix
from nerfedit_plugin.training.trainer import TrainerConfig, train

RESET_OPACITY = 0.01
"""Opacities are reset to at most this."""
NAMES = tuple(f.name for f in dataclasses.fields(SplatModel))
"""The Gaussians' parameters (the field's attributes), in :class:`SplatModel` order."""


@dataclasses.dataclass
class SplatRecipe:
    """The 3DGS training recipe sized for a CPU: start, learning rates, loss, density control (its schedule in
    steps)."""

    init_gaussians: int = 5000
    """Gaussians uniform in the scene box at the start when the dataset has no sparse points."""
    far_gaussians: int = 2000
    """Opaque images without sparse points: Gaussians that start on a sphere around the cameras (the surroundings)."""
    init_opacity: float = 0.1
    """Opacity of the starting Gaussians."""
    sh_degree: int = 3
    """Highest SH degree of the colours (0–3)."""
    sh_degree_every: int = 250
    """One more SH band is trained every this many steps, up to ``sh_degree``."""
    ssim_weight: float = 0.2
    """λ of the loss (1 − λ) L1 + λ (1 − SSIM)."""
    lr_means: float = 1.6e-4
    """Adam rate of the means, × the camera extent."""
    lr_means_final: float = 0.01
    """The means' rate decays exponentially to this fraction of it over the budget."""
    lr_quats: float = 1e-3
    """Adam rate of the rotations."""
    lr_scales: float = 5e-3
    """Adam rate of the log-scales."""
    lr_opacities: float = 5e-2
    """Adam rate of the opacity logits."""
    lr_sh: float = 2.5e-3
    """Adam rate of the SH coefficients."""
    densify_from: int = 100
    """First step of density control."""
    densify_until: int = 2000
    """No density control nor opacity reset from this step on."""
    densify_every: int = 100
    """Steps between density controls."""
    grad_threshold: float = 2e-4
    """Mean 2D-mean gradient norm (NDC units) at which a Gaussian is cloned or split."""
    split_scale: float = 0.01
    """Marked Gaussians larger than this × the camera extent are split, smaller ones cloned."""
    max_gaussians: int = 50_000
    """Density control never grows the model past this many Gaussians."""
    min_opacity: float = 0.005
    """Gaussians less opaque than this are pruned."""
    prune_scale: float = 0.1
    """Gaussians whose largest scale exceeds this × the camera extent are pruned."""
    reset_every: int = 1000
    """Steps between opacity resets (before ``densify_until``)."""
    threads: int = 1
    """torch (and compiled-kernel) threads while training; 0 keeps torch's setting. A step is hundreds of small tensor
    operations, each a parallel region that waits for every thread: on cores shared with other work one thread was
    several times faster than two."""

    def __post_init__(self) -> None:
        check_option(self, "init_gaussians", self.init_gaussians, self.init_gaussians >= 4, "at least 4")
        check_option(self, "init_opacity", self.init_opacity, 0 < self.init_opacity < 1, "in (0, 1)")
        check_option(self, "sh_degree", self.sh_degree, self.sh_degree in (0, 1, 2, 3), "0, 1, 2 or 3")
        check_option(self, "ssim_weight", self.ssim_weight, 0 <= self.ssim_weight <= 1, "in [0, 1]")
        check_option(self, "min_opacity", self.min_opacity, 0 <= self.min_opacity < RESET_OPACITY, "in [0, 0.01)")
        for name in ("lr_means", "lr_means_final", "lr_quats", "lr_scales", "lr_opacities", "lr_sh", "grad_threshold"):
            value = getattr(self, name)
            check_option(self, name, value, 0 < value < math.inf, "a positive number")
        for name in ("split_scale", "prune_scale"):
            value = getattr(self, name)
            check_option(self, name, value, 0 < value < math.inf, "a positive number")
        for name in ("sh_degree_every", "densify_every", "reset_every", "max_gaussians"):
            check_option(self, name, getattr(self, name), getattr(self, name) >= 1, "a positive integer")
        for name in ("densify_from", "densify_until", "threads", "far_gaussians"):
            check_option(self, name, getattr(self, name), getattr(self, name) >= 0, ">= 0")


def camera_sphere(cameras: Any) -> tuple[np.ndarray, float]:
    """The cameras' mean centre and the largest distance of a camera centre from it."""
    centres = cameras.c2w[:, :3, 3].double().cpu()
    mean = centres.mean(0)
    return mean.numpy(), float(torch.linalg.norm(centres - mean, dim=1).max().clamp(min=1e-6))


def camera_extent(cameras: Any) -> float:
    """1.1 × the largest distance of a camera centre from the centres' mean (3DGS's scene extent)."""
    return 1.1 * camera_sphere(cameras)[1]


def initial_model(
    box: torch.Tensor, points: np.ndarray | None, config: Any, seed: int, far: tuple[np.ndarray, float] | None = None
) -> SplatModel:
    """The starting Gaussians (module docstring): at ``points (P,3)`` when given, else uniform in ``box (2,3)`` and,
    with ``far = (centre (3,), radius)``, ``config.far_gaussians`` more uniform on that sphere."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    lo, hi = box.double().cpu().numpy()
    if points is None or len(points) < 4:
        means = lo + rng.random((config.init_gaussians, 3)) * (hi - lo)
        if far is not None and config.far_gaussians:
            directions = rng.normal(size=(config.far_gaussians, 3))
            directions /= np.linalg.norm(directions, axis=1, keepdims=True)
            means = np.concatenate([means, far[0] + far[1] * directions])
    else:
        means = np.asarray(points, dtype=np.float64)
    distance, _ = cKDTree(means).query(means, k=4)
    scale = np.sqrt(np.maximum((distance[:, 1:] ** 2).mean(1), 1e-14))
    n = len(means)
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    logit = math.log(config.init_opacity / (1.0 - config.init_opacity))
    sh = np.zeros((n, (config.sh_degree + 1) ** 2, 3))
    return SplatModel(means, quats, np.log(scale)[:, None].repeat(3, 1), np.full(n, logit), sh).astype(np.float32)


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of images ``(H,W,3)`` in [0, 1] with a Gaussian window (Wang et al. 2004; C₁ = 0.01², C₂ = 0.03²,
    zero padding as the 3DGS loss)."""
    x = torch.arange(window, dtype=a.dtype, device=a.device) - (window - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    kernel = (g[:, None] * g[None, :]).expand(3, 1, window, window).contiguous()

    def blur(t: torch.Tensor) -> torch.Tensor:
        return F.conv2d(t, kernel, padding=window // 2, groups=3)

    a, b = a.permute(2, 0, 1)[None], b.permute(2, 0, 1)[None]
    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b, cov = blur(a * a) - mu_a**2, blur(b * b) - mu_b**2, blur(a * b) - mu_a * mu_b
    c1, c2 = 0.01**2, 0.03**2
    value = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a**2 + mu_b**2 + c1) * (var_a + var_b + c2))
    return value.mean()


class SplatTrainer:
    """One training run of a :class:`~nerfedit_plugin.fields.splats.field.SplatsField` (module docstring): the step
    loss, the parameter groups and the density control handed to the shared loop."""

    def __init__(self, field: Any, dataset: Any, trainer: TrainerConfig) -> None:
        self.field, self.dataset, self.trainer, self.config = field, dataset, trainer, field.config.recipe
        self.extent = camera_extent(dataset.cameras)
        self.generator = torch.Generator().manual_seed(trainer.seed)
        self.order: list[int] = []
        self.means2d: torch.Tensor | None = None
        self.size = (dataset.cameras.width, dataset.cameras.height)
        self._clear_statistics()

    # ---- the shared loop's hooks -----------------------------------------------------------------------------------
    def param_groups(self) -> list[dict]:
        f, c = self.field, self.config
        return [
            {"params": [f.means], "lr": c.lr_means * self.extent, "lr_final_factor": c.lr_means_final},
            {"params": [f.quats], "lr": c.lr_quats, "lr_final_factor": 1.0},
            {"params": [f.log_scales], "lr": c.lr_scales, "lr_final_factor": 1.0},
            {"params": [f.opacities], "lr": c.lr_opacities, "lr_final_factor": 1.0},
            {"params": [f.sh], "lr": c.lr_sh, "lr_final_factor": 1.0},
        ]

    def loss(self, step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``((1 − λ) L1 + λ (1 − SSIM), MSE)`` of one training view."""
        if not self.order:
            self.order = torch.randperm(len(self.dataset), generator=self.generator).tolist()
        index = self.order.pop()
        degree = min(self.field.degree, step // self.config.sh_degree_every)
        image = self.render(index, degree)
        target = self.dataset.images[index].to(image.device)
        mask = self.dataset.mask[index].to(image.device) if self.dataset.mask is not None else None
        error = (image - target).abs()
        l1 = error.mean() if mask is None else error[mask].mean()
        mse = ((image - target) ** 2).mean() if mask is None else ((image - target) ** 2)[mask].mean()
        weight = self.config.ssim_weight
        loss = (1.0 - weight) * l1 + (weight * (1.0 - ssim(image, target)) if weight > 0 else 0.0)
        return loss, mse.detach()

    def render(self, index: int, degree: int) -> torch.Tensor:
        """The ``(H,W,3)`` image of training camera ``index`` with gradients (2D means kept in ``self.means2d``)."""
        f, cameras = self.field, self.dataset.cameras
        c2w = cameras.c2w[index].detach().cpu()
        intrinsics = tuple(float(getattr(cameras, k)[index]) for k in ("fx", "fy", "cx", "cy"))
        p = project(f.means, covariances(f.quats, f.log_scales), *view_matrix(c2w), intrinsics, *self.size)
        opacity = torch.sigmoid(f.opacities)
        if f.config.rasterize_mode == "antialiased":
            opacity = opacity * p.compensation
        rgb = colors(f.sh, f.means, c2w[:3, 3], degree)
        p.means2d.retain_grad()
        self.means2d = p.means2d
        image, _ = rasterize(
            p.means2d, p.conics, p.covars2d.diagonal(0, 1, 2), rgb, opacity, p.depths, *self.size,
            tuple(self.dataset.background),
        )  # fmt: skip
        return image

    def after_step(self, step: int, optimizer: torch.optim.Optimizer) -> None:
        """Gradient statistics, then density control and opacity resets on their schedule (module docstring)."""
        c = self.config
        if step >= c.densify_until:
            return
        grad = self.means2d.grad
        if grad is not None:
            ndc = grad.detach() * torch.tensor([self.size[0] / 2.0, self.size[1] / 2.0])
            seen = (grad != 0).any(-1)
            self.grad_sum += torch.where(seen, ndc.norm(dim=-1), torch.zeros(()))
            self.seen += seen
        done = step + 1
        if done >= c.densify_from and done % c.densify_every == 0:
            self.densify(optimizer)
        if done % c.reset_every == 0:
            densify.reset_opacity(self.field, optimizer, RESET_OPACITY)

    # ---- density control -------------------------------------------------------------------------------------------
    def densify(self, optimizer: torch.optim.Optimizer) -> None:
        f, c, names = self.field, self.config, NAMES
        average = self.grad_sum / self.seen.clamp(min=1)
        marked = average >= c.grad_threshold
        room = max(c.max_gaussians - f.n_gaussians, 0)
        if int(marked.sum()) > room:  # the strongest gradients first; a split adds one Gaussian, a clone one
            strongest = torch.topk(torch.where(marked, average, torch.zeros(())), room).indices
            marked = torch.zeros_like(marked)
            marked[strongest] = True
        large = torch.exp(f.log_scales.detach()).amax(-1) > c.split_scale * self.extent
        densify.clone(f, optimizer, names, marked & ~large)
        n = len(marked)
        split = torch.zeros(f.n_gaussians, dtype=torch.bool)
        split[:n] = marked & large
        densify.split(f, optimizer, names, split, self.generator)
        scales = torch.exp(f.log_scales.detach()).amax(-1)
        remove = (torch.sigmoid(f.opacities.detach()) < c.min_opacity) | (scales > c.prune_scale * self.extent)
        if remove.all():  # never prune the model away
            remove[:] = False
        densify.prune(f, optimizer, names, remove)
        self._clear_statistics()

    def _clear_statistics(self) -> None:
        n = self.field.n_gaussians
        self.grad_sum, self.seen = torch.zeros(n), torch.zeros(n, dtype=torch.int64)


def fit(field: Any, dataset: Any, eval_dataset: Any, trainer: TrainerConfig, points: np.ndarray | None) -> dict:
    """Initialise ``field`` on ``dataset`` (from the sparse ``points`` when given) and train it with the shared loop
    (module docstring); returns the loop's log with the final ``gaussians`` count."""
    recipe = field.config.recipe
    centre, radius = camera_sphere(dataset.cameras)
    far = (centre, 2.0 * radius) if dataset.opaque else None
    field.set_model(initial_model(field.scene_bbox, points, recipe, trainer.seed, far))
    run = SplatTrainer(field, dataset, trainer)
    threads = torch.get_num_threads()
    torch.set_num_threads(recipe.threads or threads)
    try:
        log = train(
            field,
            dataset,
            trainer,
            param_groups=run.param_groups,
            loss=run.loss,
            after_step=run.after_step,
            eval_dataset=eval_dataset,
        )
    finally:
        torch.set_num_threads(threads)
    log["gaussians"] = field.n_gaussians
    return log
