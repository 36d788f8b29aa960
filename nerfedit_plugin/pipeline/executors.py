"""Executors: where the shots of an animation are rendered — in this process (``local``) or on a Ray cluster.

A shot is ``(deformation frame, one camera)``; :class:`ShotRenderer` turns it into an ``(H,W,3)`` uint8 image and is
what both executors run, so they give the same images bit for bit: the field and the DeformationField are loaded
once per renderer (per Ray actor), and each renderer uses the driver's torch thread count (Ray starts workers with
one thread). ``Executor.map(shots)`` yields ``(index into shots, image)`` as images arrive (any order); the driver
writes them (:mod:`nerfedit_plugin.render.animation`).

Ray (``pip install "nerfedit[ray]"``): ``workers`` actors (default: the cluster's CPUs ÷ the torch threads, at
least 1) on the cluster at ``address`` (default: a local one, started here), every node reading the run and the
deformation from the same paths (a shared file system). An actor that dies is restarted and its unfinished shots
retried (``max_restarts``, ``max_task_retries``). docs/usage.md, "Animations on Ray", has the multi-node set-up and
the cost model.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nerfedit_plugin.data.cameras import Cameras
from nerfedit_plugin.errors import NerfEditError

#: restarts of a dead Ray actor, and retries of each of its unfinished shots
RAY_RETRIES = 3


@dataclass(frozen=True)
class RenderJob:
    """What every shot of an animation shares (plain, picklable): the run folder, the ``deformation.npz``, the
    supersampling, the torch threads and the device of each renderer."""

    run: Path
    deformation: Path | None
    supersample: int = 1
    threads: int = 1
    device: str | None = None


class ShotRenderer:
    """Loads the run's field and the deformation once; ``render(frame, camera)`` → ``(H,W,3)`` uint8."""

    def __init__(self, job: RenderJob) -> None:
        from nerfedit_plugin.bending.scene_deformation import load_deformation
        from nerfedit_plugin.pipeline.run import open_run
        from nerfedit_plugin.render.views import default_render_config

        torch.set_num_threads(job.threads)
        self.job = job
        self.field = open_run(job.run).field(job.device)
        self.deformation = load_deformation(job.deformation) if job.deformation is not None else None
        self.config = default_render_config(self.field)

    def render(self, frame: int, camera: Cameras) -> np.ndarray:
        from nerfedit_plugin.data.datasets import to_uint8
        from nerfedit_plugin.render.renderer import render_image

        image = render_image(
            self.field,
            camera,
            0,
            self.config,
            deformation=self.deformation,
            frame=frame,
            supersample=self.job.supersample,
        )
        return to_uint8(image.cpu().numpy())

    def pid(self) -> int:
        return os.getpid()


class LocalExecutor:
    """Every shot in this process, in order."""

    def __init__(self, job: RenderJob) -> None:
        self.renderer = ShotRenderer(job)

    def map(self, shots: Sequence[tuple[int, Cameras]]) -> Iterator[tuple[int, np.ndarray]]:
        for i, (frame, camera) in enumerate(shots):
            yield i, self.renderer.render(frame, camera)

    def close(self) -> None:
        pass


class RayExecutor:
    """Shots spread round-robin over Ray actors, each a :class:`ShotRenderer` (see the module docstring)."""

    def __init__(self, job: RenderJob, address: str | None = None, workers: int | None = None) -> None:
        try:
            import ray
        except ImportError:
            raise NerfEditError('--executor ray: Ray is not installed (pip install "nerfedit[ray]")') from None
        self.ray, self.started = ray, not ray.is_initialized()
        if self.started:
            _check_reachable(address)
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False)
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise NerfEditError(f"--ray-address: cannot reach a Ray cluster at {address!r} ({exc})") from None
        cpus = int(ray.cluster_resources().get("CPU", 1))
        need = min(job.threads, cpus)
        count = workers or max(1, cpus // need)
        if count * need > cpus:
            self.close()
            raise NerfEditError(
                f"--workers: {count} actors × {need} torch threads need {count * need} CPUs, the cluster has {cpus}"
            )
        actor = ray.remote(num_cpus=need, max_restarts=RAY_RETRIES, max_task_retries=RAY_RETRIES)(ShotRenderer)
        self.actors = [actor.remote(job) for _ in range(count)]

    def map(self, shots: Sequence[tuple[int, Cameras]]) -> Iterator[tuple[int, np.ndarray]]:
        ray = self.ray
        pending = {
            self.actors[i % len(self.actors)].render.remote(frame, camera): i for i, (frame, camera) in enumerate(shots)
        }
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                yield pending.pop(ref), ray.get(ref)

    def close(self) -> None:
        for actor in getattr(self, "actors", []):
            self.ray.kill(actor)
        if self.started:
            self.ray.shutdown()


def _check_reachable(address: str | None, timeout: float = 3.0) -> None:
    """A ``host:port`` or ``ray://host:port`` address must accept a TCP connection within ``timeout`` seconds (Ray
    itself keeps retrying for minutes); ``None`` and ``auto`` are left to Ray."""
    import socket

    if address is None or address == "auto":
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise NerfEditError(f"--ray-address: expected HOST:PORT, ray://HOST:PORT or auto, got {address!r}")
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise NerfEditError(f"--ray-address: cannot reach a Ray cluster at {address!r} ({exc})") from None


def make_executor(kind: str, job: RenderJob, address: str | None = None, workers: int | None = None):
    """The ``local`` or ``ray`` executor of ``job`` (close it when done)."""
    if kind == "ray":
        return RayExecutor(job, address, workers)
    if address is not None or workers is not None:
        raise NerfEditError("--ray-address / --workers: only with --executor ray")
    return LocalExecutor(job)
