"""The Field contract (entry-point group ``nerfedit.fields``): a radiance field in canonical space.

Required: :meth:`Field.query` and :meth:`Field.extract_mesh`. A field declares its kind in two class attributes:

- :attr:`Field.rendering` — ``"rays"``: the shared renderer (:func:`nerfedit_plugin.render.renderer.render_image`)
  marches camera rays, bends their samples through a deformation's backward map and calls ``query``;
  ``"primitives"``: the field draws itself from primitives it holds (:meth:`Field.render`), a deformation moving them.
- :attr:`Field.sources` — what a run of the field is made from: ``"dataset"`` (images with cameras, optimised with
  :meth:`Field.fit`) and/or ``"model"`` (a model file — a mesh, a splat file — read by :meth:`Field.from_file`, nothing
  to fit). A run made from a model file has no cameras.

(``fit``, not ``train``: ``torch.nn.Module.train`` already means "training mode".)
"""

from __future__ import annotations

import abc
import dataclasses
import os
from pathlib import Path
from typing import Any, ClassVar, Literal

import torch

from nerfedit_plugin.config import InstantiateConfig
from nerfedit_plugin.fields.checkpoint import load_field, save_field
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.registry import Registry


@dataclasses.dataclass
class FieldConfig(InstantiateConfig):
    """Base config of every field backend (the first line of a backend's docstring is its description in
    ``nerfedit train --help``)."""


Rendering = Literal["rays", "primitives"]
Source = Literal["dataset", "model"]


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

    rendering: ClassVar[Rendering] = "rays"
    """``"rays"``: rendered by the shared renderer through :meth:`query` (rays bent by a deformation's backward map);
    ``"primitives"``: the field renders itself (:meth:`render`)."""

    sources: ClassVar[frozenset[Source]] = frozenset({"dataset"})
    """What ``nerfedit train --data`` may name: ``"dataset"`` (a dataset folder, transforms file or COLMAP workspace;
    the field is built with ``config.setup(scene_bbox=...)`` and optimised with :meth:`fit`) and/or ``"model"`` (a
    model file; the field is built by the classmethod :meth:`from_file` and has nothing to fit)."""

    exact_mesh: ClassVar[bool] = False
    """:meth:`extract_mesh` returns the mesh the field is made of (the ``mesh`` field), not a level set: a run of it
    holds its ``mesh.ply`` from the start, and extraction has nothing to do."""

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
        """Fields made from a ``"dataset"``: optimise on a :class:`nerfedit_plugin.data.datasets.Dataset` (keyword
        ``eval_dataset`` for a held-out curve); returns a log (loss/PSNR per step)."""
        if "dataset" in self.sources:
            raise NotImplementedError(f"{type(self).__name__} is made from a dataset but does not implement fit()")
        raise NotImplementedError(f"{type(self).__name__} is not trained on a dataset (sources = {set(self.sources)})")

    @classmethod
    def from_file(cls, path: Path, config: FieldConfig | None = None) -> Field:
        """Fields made from a ``"model"``: build the field from the model file ``path`` (a bad file is a
        :class:`~nerfedit_plugin.errors.NerfEditError` naming it); nothing to fit."""
        if "model" in cls.sources:
            raise NotImplementedError(f"{cls.__name__} is made from a model file but does not implement from_file()")
        raise NotImplementedError(f"{cls.__name__} is not made from a model file (sources = {set(cls.sources)})")

    def render(self, cameras: Any, index: int, config: Any, deformation: Any = None, frame: int = 0) -> torch.Tensor:
        """Fields with ``rendering = "primitives"``: the ``(H,W,3)`` image of camera ``index`` of ``cameras``, the
        primitives moved by ``deformation`` (a :class:`~nerfedit_plugin.bending.maps.ForwardMap`) at ``frame``."""
        raise NotImplementedError(f"{type(self).__name__} is rendered by ray marching (rendering = {self.rendering!r})")

    exports: ClassVar[tuple[str, ...]] = ()
    """File formats (suffixes without the dot, the first the default) :meth:`export` writes the field's primitives in,
    e.g. ``("ply", "splat")``; empty (the default): the field has no primitives to export."""

    def export(self, path: str | os.PathLike, deformation: Any = None, frame: int = 0) -> dict:
        """Fields with :attr:`exports`: write the primitives — moved by ``deformation`` (a
        :class:`~nerfedit_plugin.bending.maps.ForwardMap`) at ``frame``, as :meth:`render` draws them — as a model file
        at ``path`` (format by suffix), atomically → a JSON-able record of what was written."""
        raise NotImplementedError(f"{type(self).__name__} has no primitives to export")

    def save(self, path: str | os.PathLike, registry: Registry | None = None) -> None:
        """Checkpoint (``field.pt``): backend name, config, scene box and state dict, written atomically
        (format: :mod:`nerfedit_plugin.fields.checkpoint`)."""
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
