"""The Field contract (entry-point group ``nerfedit.fields``): a radiance field in canonical space.

Required: :meth:`Field.query` and :meth:`Field.extract_mesh`; image-trained fields (``data = "images"``) also
:meth:`Field.fit`, mesh-built ones (``data = "mesh"``) :meth:`Field.from_mesh`. All rendering goes through the one
shared renderer (:func:`nerfedit_plugin.render.renderer.render_image`), which bends rays before calling ``query``.
(``fit``, not ``train``: ``torch.nn.Module.train`` already means "training mode".)
"""

from __future__ import annotations

import abc
import dataclasses
import os
from typing import Any, ClassVar

import torch

from nerfedit_plugin.config import InstantiateConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.checkpoint import load_field, save_field
from nerfedit_plugin.registry import Registry


@dataclasses.dataclass
class FieldConfig(InstantiateConfig):
    """Base config of every field backend (the first line of a backend's docstring is its description in
    ``nerfedit train --help``)."""


class Field(torch.nn.Module, metaclass=abc.ABCMeta):
    """Density or SDF plus colour, queried at canonical points.

    ``kind`` tells the renderer how to turn the first output of :meth:`query` into opacity:
    ``"density"`` (σ ≥ 0, classic volume rendering) or ``"sdf"`` (signed distance, negative inside; NeuS
    unbiased rendering with :meth:`sharpness`).
    """

    kind: ClassVar[str] = "density"
    opaque: ClassVar[bool] = False
    """A solid (density 0 outside, effectively infinite inside, e.g. the ``mesh`` field): :meth:`occupied` is then
    the exact inside test, and the renderer moves each ray's first inside sample onto the surface crossing by
    bisection and queries the colour there once, instead of compositing every sample."""

    data: ClassVar[str] = "images"
    """What ``nerfedit train --data`` names: ``"images"`` (a dataset folder; the field is built with
    ``config.setup(scene_bbox=...)`` and optimised with :meth:`fit`) or ``"mesh"`` (a mesh file; the field is built
    with the classmethod ``from_mesh(mesh: SurfaceMesh, config)`` and has nothing to fit)."""

    def __init__(self, config: FieldConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("scene_bbox", torch.as_tensor(scene_bbox, dtype=torch.float32).reshape(2, 3))

    @property
    def view_dependent(self) -> bool:
        """Whether the colour :meth:`query` returns depends on ``directions`` (default True). Only then does the
        renderer rotate view directions into canonical space along bent rays."""
        return True

    @abc.abstractmethod
    def query(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``points (M,3)``, unit ``directions (M,3)`` in canonical space → ``(density_or_sdf (M,), rgb (M,3))``."""

    @abc.abstractmethod
    def extract_mesh(self, resolution: int = 256, level: float | None = None) -> SurfaceMesh:
        """Marching cubes (scikit-image) of the density/SDF over ``scene_bbox`` at ``level`` → a vertex-coloured
        :class:`SurfaceMesh` (the mesh itself for mesh-built fields)."""

    # ---- optional hooks --------------------------------------------------------------------------------------------
    @property
    def render_samples(self) -> int | None:
        """Samples per ray to render with (e.g. those the field was trained and evaluated with); ``None`` (default):
        the renderer's default."""
        return None

    def occupied(self, points: torch.Tensor) -> torch.Tensor | None:
        """Optional occupancy grid: ``(M,)`` bool, False where canonical ``points (M,3)`` are certainly empty (the
        renderer then skips them); ``None`` (the default) = no grid, every sample is queried."""
        return None

    def background_model(self) -> torch.nn.Module | None:
        """Optional model of what lies outside ``scene_bbox`` (a :class:`~nerfedit_plugin.fields.background.
        BackgroundField`: ``samples(origins, directions, near, far, stratified)`` and ``query(points)``), composited
        by the renderer in ray order with the field's own samples and never bent; ``None`` (the default): the
        render config's constant background colour."""
        return None

    def sharpness(self) -> torch.Tensor:
        """NeuS inverse standard deviation ``s`` of the logistic density (``sdf`` fields only)."""
        raise NotImplementedError(f"{type(self).__name__} is not an SDF field")

    def fit(self, dataset: Any, **kwargs: Any) -> dict:
        """``data = "images"`` fields: optimise on a :class:`nerfedit_plugin.data.datasets.Dataset` (keyword
        ``eval_dataset`` for a held-out curve); returns a log (loss/PSNR per step)."""
        if self.data == "images":
            raise NotImplementedError(f"{type(self).__name__} has data = 'images' but does not implement fit()")
        raise NotImplementedError(f"{type(self).__name__} is not trained on images (data = {self.data!r})")

    @classmethod
    def from_mesh(cls, mesh: SurfaceMesh, config: FieldConfig | None = None) -> Field:
        """``data = "mesh"`` fields: build the field from a (vertex-coloured) mesh; nothing to fit."""
        if cls.data == "mesh":
            raise NotImplementedError(f"{cls.__name__} has data = 'mesh' but does not implement from_mesh()")
        raise NotImplementedError(f"{cls.__name__} is not built from a mesh (data = {cls.data!r})")

    def save(self, path: str | os.PathLike, registry: Registry | None = None) -> None:
        """Checkpoint (``field.pt``): backend name, config, scene box and state dict, written atomically
        (format: :mod:`nerfedit_plugin.io.checkpoint`)."""
        save_field(self, path, registry)

    @classmethod
    def load(
        cls,
        path: str | os.PathLike,
        registry: Registry | None = None,
        *,
        backend: str | None = None,
        device: torch.device | str = "cpu",
    ) -> Field:
        """Read a checkpoint written by :meth:`save`; ``Field.load`` takes any backend, ``Backend.load`` only its
        own. A checkpoint of another backend, a missing or a corrupt file raises NerfEditError naming the file."""
        return load_field(path, registry, backend=backend, expected=None if cls is Field else cls, device=device)
