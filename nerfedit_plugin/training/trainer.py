"""The training loop shared by every field backend: random ray batches, Adam, a time/step budget, rich progress.

Each step draws ``batch_rays`` pixels uniformly from all training images, renders them with the shared renderer
(:func:`nerfedit_plugin.render.renderer.render_rays`, stratified samples) and minimises the mean squared colour error
plus an optional backend regulariser. Every learning rate decays exponentially with training progress
``p = max(step / max_steps, seconds / max_seconds)`` (or ``min(1, max(p, step / lr_decay_steps))``):
``lr(p) = lr₀ · lr_final_factor^p``. Evaluation (PSNR over
whole held-out images) runs every ``eval_every_seconds`` of training time and is excluded from the clock, so the
log's ``(seconds, psnr)`` pairs are a PSNR-vs-training-time curve. The clock is wall time, or the CPU time of the
whole process (``TrainerConfig.clock``: every thread, torch's and numba's workers included), which does not grow
with other processes' load and counts the same work the same for every backend.
Inside :func:`checkpoints` the loop hands the field to a callback every ``checkpoint_every_seconds`` (``nerfedit
train`` keeps the last one as a partial run when it is interrupted).
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Literal

import torch

from nerfedit_plugin.data.cameras import generate_rays
from nerfedit_plugin.training.metrics import psnr_from_mse


@dataclass
class TrainerConfig:
    """Optimisation budget and schedule (shared by all field backends)."""

    max_seconds: float = 270.0
    """Training budget in seconds of ``clock`` (evaluation time excluded)."""
    clock: Literal["wall", "cpu"] = "wall"
    """How training time is measured: ``wall`` — wall-clock seconds; ``cpu`` — CPU seconds of the whole process, every
    thread's (torch's intra-op and numba's workers included): the compute a run used, the same for every backend and
    whatever the machine's other load, for budgets and PSNR-vs-time curves on a busy machine. A run on ``n`` busy
    threads spends it ``n`` times as fast as wall time; workers that spin while they wait count too."""
    max_steps: int = 1_000_000
    """Step budget; training stops at whichever budget runs out first."""
    batch_rays: int = 4096
    """Rays (pixels) per optimisation step, drawn uniformly from all training images."""
    lr_final_factor: float = 0.1
    """Learning rates decay exponentially to this fraction of their initial values at the end of the budget (or of
    ``lr_decay_steps``)."""
    lr_decay_steps: int = 0
    """When > 0, the learning rates reach ``lr_final_factor`` after this many steps, or at the end of the budget if
    that comes first, and stay there: a longer budget adds steps at the final rate instead of slowing the decay."""
    n_samples: int = 96
    """Samples per ray while training (the renderer's ``n_samples``)."""
    eval_every_seconds: float = 30.0
    """Evaluate on the held-out images every this many seconds of training (0 disables intermediate evaluation)."""
    eval_views: int = 10
    """Held-out images used per evaluation (the first ones of the split)."""
    foreground_margin: int = 3
    """With alpha in the dataset, draw rays only from pixels within this many pixels of covered ones (alpha > 0):
    farther pixels are known background whose rays cross carved, empty space. −1 draws from all pixels."""
    checkpoint_every_seconds: float = 60.0
    """Inside :func:`checkpoints`: hand the field to the checkpoint callback every this many seconds of training
    (excluded from the clock; 0 disables)."""
    log_every: int = 25
    """Record the batch loss and PSNR every this many steps."""
    seed: int = 0
    """Seed of the ray batches and stratified samples."""
    progress: bool = True
    """Show a rich progress bar with the loss and PSNR."""

    @classmethod
    def tiny(cls, seconds: float = 5.0) -> TrainerConfig:
        """The budget of the backends' ``tiny`` presets (tests, smoke runs): ``seconds`` of small batches, no
        intermediate evaluation, no progress bar."""
        return cls(max_seconds=seconds, batch_rays=1024, n_samples=48, eval_every_seconds=0, progress=False)


_checkpoint: contextvars.ContextVar[Callable[[Any, dict], None] | None] = contextvars.ContextVar(
    "checkpoint", default=None
)


@contextlib.contextmanager
def checkpoints(callback: Callable[[Any, dict], None]) -> Iterator[None]:
    """Within the block, :func:`train` calls ``callback(field, {"steps": …, "train_seconds": …})`` every
    ``checkpoint_every_seconds`` of training, whichever backend's ``fit`` runs it."""
    token = _checkpoint.set(callback)
    try:
        yield
    finally:
        _checkpoint.reset(token)


@torch.no_grad()
def evaluate(field: Any, dataset: Any, render_config: Any, views: int | None = None) -> float:
    """PSNR over the pixels (those of the dataset's ``mask`` when it has one) of the first ``views`` images of
    ``dataset`` rendered by ``field``."""
    from nerfedit_plugin.render.renderer import render_image

    count = len(dataset) if views is None else min(views, len(dataset))
    mask = getattr(dataset, "mask", None)
    squared = 0.0
    for i in range(count):
        image = render_image(field, dataset.cameras, i, render_config)
        error = (image - dataset.images[i].to(image.device)) ** 2
        squared += float(error.mean() if mask is None else error[mask[i].to(image.device)].mean())
    return psnr_from_mse(squared / count)


def train(
    field: torch.nn.Module,
    dataset: Any,
    config: TrainerConfig,
    *,
    param_groups: Callable[[], Iterable[dict]] | None = None,
    regularizer: Callable[[int], torch.Tensor | None] | None = None,
    callback: Callable[[int], bool] | None = None,
    cos_anneal: Callable[[int], float] | None = None,
    eval_dataset: Any = None,
    loss: Callable[[int], tuple[torch.Tensor, torch.Tensor]] | None = None,
    after_step: Callable[[int, torch.optim.Optimizer], None] | None = None,
) -> dict:
    """Optimise ``field`` on ``dataset`` (a :class:`nerfedit_plugin.data.datasets.Dataset`) and return the log.

    ``param_groups()``: torch optimiser groups with their initial ``lr`` (default: all parameters at 1e-2) and
    optionally their own ``lr_final_factor`` (else the config's; 1 keeps a rate constant);
    ``regularizer(step)``: extra loss added to the colour MSE; ``callback(step)``: called after every step (e.g.
    occupancy-grid updates); it returns True when it replaced parameters (e.g. a grid refined coarse to fine),
    and the optimiser is then rebuilt from ``param_groups()`` keeping the moments of unchanged parameters.
    ``loss(step)``: the step's ``(loss, colour MSE)`` computed by the field itself (e.g. whole images drawn by a
    rasterising field), instead of a batch of rays through the shared renderer; ``after_step(step, optimizer)``:
    called after every optimiser step, before ``callback``; it may replace parameters together with their state in
    ``optimizer`` (e.g. densification and pruning of primitives).
    ``cos_anneal(step)``: the renderer's NeuS cosine-annealing ratio for the training batch of ``step`` (sdf fields;
    default 1, the unbiased estimate — evaluation always uses 1).
    The log holds ``step``, ``seconds``, ``loss``, ``psnr`` (batch values every ``log_every`` steps), ``eval``
    (list of ``(seconds, psnr)`` on ``eval_dataset`` — at 0 s, every ``eval_every_seconds`` and at the end),
    ``steps`` and ``train_seconds`` (totals).
    """
    from nerfedit_plugin.render.renderer import RenderConfig

    generator = torch.Generator(device="cpu").manual_seed(config.seed)
    torch.manual_seed(config.seed)
    render_config = RenderConfig(n_samples=config.n_samples, background=tuple(dataset.background))
    if loss is None:
        loss = _ray_loss(field, dataset, config, render_config, generator, cos_anneal)
    if param_groups is None:
        param_groups = lambda: [{"params": list(field.parameters()), "lr": 1e-2}]  # noqa: E731
    optimizer = _adam(param_groups())
    log: dict = {"step": [], "seconds": [], "loss": [], "psnr": [], "eval": []}

    def run_eval(seconds: float) -> None:
        if eval_dataset is not None:
            field.eval()
            log["eval"].append((seconds, evaluate(field, eval_dataset, render_config, config.eval_views)))
            field.train()

    run_eval(0.0)
    field.train()
    clock = _clock(config.clock)
    seconds, step, next_eval = 0.0, 0, config.eval_every_seconds
    checkpoint, next_checkpoint = _checkpoint.get(), config.checkpoint_every_seconds
    with _Progress(config) as bar:
        while step < config.max_steps and seconds < config.max_seconds:
            start = clock()
            progress = max(step / config.max_steps, seconds / config.max_seconds)
            if config.lr_decay_steps:
                progress = min(1.0, max(progress, step / config.lr_decay_steps))
            for group in optimizer.param_groups:
                group["lr"] = group["initial_lr"] * group.get("lr_final_factor", config.lr_final_factor) ** progress
            total, mse = loss(step)
            extra = regularizer(step) if regularizer is not None else None
            if extra is not None:
                total = total + extra
            optimizer.zero_grad(set_to_none=True)
            total.backward()
            optimizer.step()
            if after_step is not None:
                after_step(step, optimizer)
            if callback is not None and callback(step):
                optimizer = _adam(param_groups(), optimizer)
            step += 1
            seconds += clock() - start
            if step % config.log_every == 0 or step == 1:
                log["step"].append(step)
                log["seconds"].append(seconds)
                log["loss"].append(float(total.detach()))
                log["psnr"].append(psnr_from_mse(mse.detach()))
                done = max(step / config.max_steps, seconds / config.max_seconds)
                bar.update(done, log["loss"][-1], log["psnr"][-1], log["eval"][-1][1] if log["eval"] else None)
            if config.eval_every_seconds > 0 and seconds >= next_eval and seconds < config.max_seconds:
                run_eval(seconds)
                next_eval += config.eval_every_seconds
            if checkpoint is not None and 0 < next_checkpoint <= seconds < config.max_seconds:
                checkpoint(field, {"steps": step, "train_seconds": seconds})
                next_checkpoint = seconds + config.checkpoint_every_seconds
        if step:
            bar.update(1.0, float(total.detach()), psnr_from_mse(mse.detach()), None)
    run_eval(seconds)
    field.eval()
    log["steps"], log["train_seconds"] = step, seconds
    return log


def _ray_loss(field, dataset, config: TrainerConfig, render_config, generator, cos_anneal) -> Callable[[int], tuple]:
    """The default step loss: ``batch_rays`` pixels drawn from the ray pool, rendered by the shared renderer
    (stratified), their colour MSE (as both the loss and the MSE)."""
    from nerfedit_plugin.render.renderer import render_rays

    device = field.scene_bbox.device
    origins, directions = generate_rays(dataset.cameras.to(device))
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    colors = dataset.images.to(device).reshape(-1, 3)
    pool = _ray_pool(dataset, config.foreground_margin).to(device)

    def loss(step: int) -> tuple[torch.Tensor, torch.Tensor]:
        batch = pool[torch.randint(0, len(pool), (config.batch_rays,), generator=generator).to(device)]
        step_config = (
            render_config if cos_anneal is None else dataclasses.replace(render_config, cos_anneal=cos_anneal(step))
        )
        out = render_rays(field, origins[batch], directions[batch], step_config, stratified=True)
        mse = torch.mean((out.rgb - colors[batch]) ** 2)
        return mse, mse

    return loss


def _clock(kind: str) -> Callable[[], float]:
    """The training clock of ``TrainerConfig.clock`` (seconds)."""
    if kind == "wall":
        return time.perf_counter
    if kind == "cpu":
        return time.process_time
    raise ValueError(f"TrainerConfig.clock: expected 'wall' or 'cpu', got {kind!r}")


def _ray_pool(dataset: Any, margin: int) -> torch.Tensor:
    """Flat indices of the pixels rays are drawn from (see ``TrainerConfig.foreground_margin``), never outside the
    dataset's ``mask`` (when it has one: masked-out pixels are not trained on)."""
    keep = torch.ones_like(dataset.images[..., 0], dtype=torch.bool)
    if margin >= 0 and dataset.alpha is not None:
        covered = (dataset.alpha > 0).float()[:, None]
        keep = torch.nn.functional.max_pool2d(covered, 2 * margin + 1, stride=1, padding=margin)[:, 0] > 0
    if getattr(dataset, "mask", None) is not None:
        keep &= dataset.mask.to(keep.device)
    return keep.reshape(-1).nonzero()[:, 0]


def _adam(groups: Iterable[dict], previous: torch.optim.Optimizer | None = None) -> torch.optim.Optimizer:
    """Adam (fused kernel) over ``groups`` (each remembers its ``lr`` as ``initial_lr``, the start of its decay);
    moments of parameters already in ``previous`` carry over."""
    optimizer = torch.optim.Adam(list(groups), betas=(0.9, 0.99), eps=1e-15, fused=True)
    for group in optimizer.param_groups:
        group.setdefault("initial_lr", group["lr"])
    if previous is not None:
        for p, state in previous.state.items():
            if any(p is q for group in optimizer.param_groups for q in group["params"]):
                optimizer.state[p] = state
    return optimizer


class _Progress:
    """A rich progress bar over the training budget showing the loss, batch PSNR and the last eval PSNR."""

    def __init__(self, config: TrainerConfig) -> None:
        self.config, self.progress, self.task = config, None, None

    def __enter__(self) -> _Progress:
        if self.config.progress:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

            self.progress = Progress(
                TextColumn("training"),
                BarColumn(),
                TimeElapsedColumn(),
                TextColumn("{task.fields[status]}"),
                transient=False,
            )
            self.progress.start()
            self.task = self.progress.add_task("train", total=1.0, status="")
        return self

    def update(self, done: float, loss: float, batch_psnr: float, eval_psnr: float | None) -> None:
        """``done``: fraction of the budget used (steps or seconds, whichever is further along)."""
        if self.progress is not None:
            status = f"loss {loss:.5f}  psnr {batch_psnr:5.2f} dB"
            if eval_psnr is not None:
                status += f"  eval {eval_psnr:5.2f} dB"
            self.progress.update(self.task, completed=min(done, 1.0), status=status)

    def __exit__(self, *exc: object) -> None:
        if self.progress is not None:
            self.progress.stop()
