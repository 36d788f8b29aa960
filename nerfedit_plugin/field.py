"""The Field contract (entry-point group ``nerfedit.fields``): a radiance field in canonical space.

A backend ships a config dataclass (subclass of :class:`FieldConfig`, ``_target`` = its :class:`Field` subclass) and
registers the config class, e.g. ``nerf = "nerfedit_plugin.fields.nerf:NerfConfig"``. All rendering goes through
the one shared renderer, which bends rays with an optional DeformationField before calling :meth:`Field.query`.
(``fit`` rather than ``train``: ``torch.nn.Module.train`` already means "training mode".)
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any, ClassVar

import torch

from .config import InstantiateConfig
from .mesh import SurfaceMesh


@dataclasses.dataclass
class FieldConfig(InstantiateConfig):
    """Base config of every field backend."""


class Field(torch.nn.Module):
    """Density or SDF plus colour, queried at canonical points.

    ``kind`` tells the renderer how to turn the first output of :meth:`query` into opacity:
    ``"density"`` (σ ≥ 0, classic volume rendering) or ``"sdf"`` (signed distance, negative inside; NeuS
    unbiased rendering with :meth:`sharpness`).
    """

    kind: ClassVar[str] = "density"

    def __init__(self, config: FieldConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("scene_bbox", torch.as_tensor(scene_bbox, dtype=torch.float32).reshape(2, 3))

    def query(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``points (M,3)``, unit ``directions (M,3)`` in canonical space → ``(density_or_sdf (M,), rgb (M,3))``."""
        raise NotImplementedError

    def sharpness(self) -> torch.Tensor:
        """NeuS inverse standard deviation ``s`` of the logistic density (``sdf`` fields only)."""
        raise NotImplementedError(f"{type(self).__name__} is not an SDF field")

    def fit(self, dataset: Any, **kwargs: Any) -> dict:
        """Optimise the field on a :class:`nerfedit_plugin.datasets.Dataset`; returns a log (loss/PSNR per step)."""
        raise NotImplementedError

    def extract_mesh(self, resolution: int = 256, level: float | None = None) -> SurfaceMesh:
        """Marching cubes (scikit-image) of the density/SDF over ``scene_bbox`` at ``level``."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike) -> None:
        """Checkpoint (``field.pt``): backend name, config and state dict, written atomically."""
        raise NotImplementedError
