"""The shared training loop: PSNR, budgets, the foreground ray pool, optimiser rebuilds after parameter swaps."""

import math

import pytest
import torch

from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.data.datasets import Dataset
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.training.metrics import psnr_from_mse as psnr
from nerfedit_plugin.training.trainer import TrainerConfig, _clock, _ray_pool, train


def test_psnr_of_known_errors():
    assert psnr(0.01) == pytest.approx(20.0)
    assert psnr(torch.tensor(1e-3)) == pytest.approx(30.0)


class ConstantField(Field):
    """A box of constant density and one learnable colour: training must drive the colour to the target."""

    def __init__(self, config, scene_bbox):
        super().__init__(config, scene_bbox)
        self.logit = torch.nn.Parameter(torch.zeros(3))
        self.swaps = 0

    def query(self, points, directions):
        return torch.full((len(points),), 50.0), torch.sigmoid(self.logit).expand(len(points), 3)

    def swap(self):  # replace the parameter, as a coarse-to-fine grid does
        self.logit = torch.nn.Parameter(self.logit.detach().clone())
        self.swaps += 1

    def extract_mesh(self, resolution=256, level=None):
        raise NotImplementedError


def flat_dataset(color=(0.2, 0.6, 0.9), size=8, alpha=None):
    eye = torch.tensor([[0.0, -3.0, 0.0], [3.0, 0.0, 0.0]])
    cameras = Cameras.from_fov(look_at(eye, torch.zeros(2, 3)), size, size, 0.3)
    images = torch.tensor(color).expand(2, size, size, 3).clone()
    return Dataset(images, cameras, "train", [], (1.0, 1.0, 1.0), torch.tensor([[-0.5] * 3, [0.5] * 3]), alpha)


def test_training_fits_the_colour_and_honours_the_step_budget():
    data = flat_dataset()
    field = ConstantField(FieldConfig(), data.scene_bbox)

    def callback(step):
        if step == 3:
            field.swap()
            return True
        return False

    config = TrainerConfig(
        max_steps=150, max_seconds=60, batch_rays=64, n_samples=8, eval_every_seconds=0, log_every=10, progress=False
    )
    log = train(
        field,
        data,
        config,
        param_groups=lambda: [{"params": [field.logit], "lr": 0.1}],
        callback=callback,
        eval_dataset=data,
    )
    assert log["steps"] == 150 and field.swaps == 1
    assert [t for t, _ in log["eval"]][0] == 0.0 and len(log["eval"]) == 2
    assert log["eval"][-1][1] > 35.0 > log["eval"][0][1]  # the constant colour is learnt (sigmoid(0) = 0.5 at start)
    assert log["step"] == sorted(log["step"]) and all(math.isfinite(p) for p in log["psnr"])
    torch.testing.assert_close(torch.sigmoid(field.logit), torch.tensor([0.2, 0.6, 0.9]), atol=0.01, rtol=0)


@pytest.mark.parametrize("decay_steps", [0, 10])
def test_learning_rate_decays_over_the_budget_or_the_decay_steps(monkeypatch, decay_steps):
    """``lr = lr₀ · lr_final_factor^p`` with ``p`` the budget's progress, or with ``lr_decay_steps`` ``min(1,
    max(p, step / lr_decay_steps))``: the final rate is reached at that step and held."""
    import nerfedit_plugin.training.trainer as trainer

    data = flat_dataset()
    field = ConstantField(FieldConfig(), data.scene_bbox)
    optimizers, rates = [], []
    adam = trainer._adam
    monkeypatch.setattr(trainer, "_adam", lambda *a: optimizers.append(adam(*a)) or optimizers[-1])
    config = TrainerConfig(
        max_steps=40, max_seconds=1e6, batch_rays=16, n_samples=4, eval_every_seconds=0, progress=False,
        lr_final_factor=0.1, lr_decay_steps=decay_steps,
    )  # fmt: skip
    group = lambda: [{"params": [field.logit], "lr": 0.5}]  # noqa: E731
    train(
        field,
        data,
        config,
        param_groups=group,
        callback=lambda step: rates.append(optimizers[-1].param_groups[0]["lr"]),
    )
    progress = [s / 40 if not decay_steps else min(1.0, s / decay_steps) for s in range(40)]
    assert rates == pytest.approx([0.5 * 0.1**p for p in progress], rel=1e-12)
    assert (rates[-1] == pytest.approx(0.05)) == bool(decay_steps)


def test_ray_pool_keeps_covered_pixels_and_drops_far_background():
    alpha = torch.zeros(2, 8, 8)
    alpha[0, 3, 3] = 0.5
    pool = _ray_pool(flat_dataset(alpha=alpha), margin=1)
    expected = {0 * 64 + r * 8 + c for r in (2, 3, 4) for c in (2, 3, 4)}
    assert set(pool.tolist()) == expected
    assert len(_ray_pool(flat_dataset(alpha=alpha), margin=-1)) == 128
    assert len(_ray_pool(flat_dataset(), margin=3)) == 128  # no alpha: every pixel
    assert len(_ray_pool(flat_dataset(alpha=torch.ones(2, 8, 8)), margin=3)) == 128  # opaque images: every pixel


def test_cpu_clock_counts_every_thread_and_bad_clocks_are_rejected():
    """The ``cpu`` clock is the process's CPU time: work on another thread (numpy, the GIL released) counts while the
    calling thread sleeps; a training run on it reports that time."""
    import threading
    import time

    import numpy as np

    clock = _clock("cpu")

    def work() -> None:
        matrix = np.random.default_rng(0).random((300, 300))
        deadline = time.perf_counter() + 0.4
        while time.perf_counter() < deadline:
            matrix = np.tanh(matrix @ matrix.T / 300.0)

    worker = threading.Thread(target=work)
    start, start_thread = clock(), time.thread_time()
    worker.start()
    worker.join()
    assert time.thread_time() - start_thread < 0.1  # this thread only waited
    assert clock() - start > 0.2  # the worker's work counts

    data = flat_dataset()
    field = ConstantField(FieldConfig(), data.scene_bbox)
    config = TrainerConfig(max_steps=20, batch_rays=64, n_samples=8, eval_every_seconds=0, progress=False, clock="cpu")
    log = train(field, data, config)
    assert log["steps"] == 20 and log["train_seconds"] > 0.0
    with pytest.raises(ValueError, match="clock"):
        train(field, data, TrainerConfig(max_steps=1, progress=False, clock="sundial"))
