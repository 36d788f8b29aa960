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

from nerfedit_plugin.config import InstantiateConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh


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

    def query(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``points (M,3)``, unit ``directions (M,3)`` in canonical space → ``(density_or_sdf (M,), rgb (M,3))``."""
        raise NotImplementedError

    def occupied(self, points: torch.Tensor) -> torch.Tensor | None:
        """Optional occupancy grid: ``(M,)`` bool, False where canonical ``points (M,3)`` are certainly empty (the
        renderer then skips them); ``None`` (the default) = no grid, every sample is queried."""
        return None

    def sharpness(self) -> torch.Tensor:
        """NeuS inverse standard deviation ``s`` of the logistic density (``sdf`` fields only)."""
        raise NotImplementedError(f"{type(self).__name__} is not an SDF field")

    def fit(self, dataset: Any, **kwargs: Any) -> dict:
        """Optimise the field on a :class:`nerfedit_plugin.data.datasets.Dataset`; returns a log (loss/PSNR per step)."""
        raise NotImplementedError

    def extract_mesh(self, resolution: int = 256, level: float | None = None) -> SurfaceMesh:
        """Marching cubes (scikit-image) of the density/SDF over ``scene_bbox`` at ``level``."""
        raise NotImplementedError

    def save(self, path: str | os.PathLike) -> None:
        """Checkpoint (``field.pt``): backend name, config and state dict, written atomically
        (:func:`nerfedit_plugin.io.checkpoint.save_field`)."""
        from nerfedit_plugin.io.checkpoint import save_field

        save_field(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Field":
        """Read a checkpoint written by :meth:`save`; a checkpoint of another backend, a missing or a corrupt file
        raises :class:`nerfedit_plugin.errors.NerfEditError` naming the file."""
        from nerfedit_plugin.io.checkpoint import load_field

        return load_field(path, expected=None if cls is Field else cls)
