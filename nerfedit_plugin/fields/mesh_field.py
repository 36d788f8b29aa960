"""The ``mesh`` field backend: a vertex-coloured triangle mesh used as an exact opaque field.

Inside the (watertight) mesh the density is a large constant, outside it is 0; the colour at any point is the
barycentric vertex colour of the closest surface point. The shared renderer treats it as a solid (``opaque``): it
finds each ray's surface crossing by bisection on :meth:`MeshField.occupied` and queries the colour there once,
so an unedited render reproduces the synthetic generator's unlit render of the mesh, and an edited render measures
ray bending with no training error. ``fit`` has nothing to learn; ``extract_mesh`` returns the mesh unchanged (same
vertex order). Point queries run on the CPU (Open3D ``RaycastingScene``); results come back on the points' device.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch

from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh


@dataclasses.dataclass
class MeshFieldConfig(FieldConfig):
    """A vertex-coloured mesh as an exact opaque field (instant previews; the oracle of ray bending)."""

    _target: type = dataclasses.field(default_factory=lambda: MeshField)
    density: float = 1e4
    """Density returned inside the mesh (volume rendering of it is opaque within a few samples)."""
    padding: float = 0.05
    """Scene box of a mesh = its bounding box grown by this fraction of its diagonal on every side."""
    color: tuple[float, float, float] | None = None
    """RGB in [0, 1] given to every vertex of a mesh without vertex colours (a mesh with colours keeps its own);
    default: such a mesh is refused."""

    def __post_init__(self) -> None:
        check_option(self, "density", self.density, 0 < self.density < math.inf, "a positive number")
        check_option(self, "padding", self.padding, 0 <= self.padding < math.inf, "a number >= 0")
        if self.color is not None:
            ok = len(self.color) == 3 and all(0 <= c <= 1 for c in self.color)
            check_option(self, "color", self.color, ok, "three numbers in [0, 1]")


class MeshField(Field):
    """Holds a SurfaceMesh as buffers ``vertices (V,3)`` float64, ``faces (F,3)`` int64, ``vertex_colors (V,3)``
    float32 (part of the checkpoint). Build one with :meth:`from_mesh`; ``MeshFieldConfig().setup(scene_bbox=...)``
    gives an empty field that :meth:`load_state_dict` fills."""

    kind: ClassVar[str] = "density"
    opaque: ClassVar[bool] = True
    view_dependent: ClassVar[bool] = False  # the colour of the closest surface point
    sources: ClassVar[frozenset[str]] = frozenset({"model"})
    exact_mesh: ClassVar[bool] = True

    def __init__(self, config: MeshFieldConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__(config, scene_bbox)
        self.register_buffer("vertices", torch.zeros(0, 3, dtype=torch.float64))
        self.register_buffer("faces", torch.zeros(0, 3, dtype=torch.int64))
        self.register_buffer("vertex_colors", torch.zeros(0, 3, dtype=torch.float32))
        self._scene = None

    @classmethod
    def from_file(cls, path: Path, config: MeshFieldConfig | None = None) -> MeshField:
        """The field of the mesh file ``path`` (PLY/OBJ/OFF/GLB): :meth:`from_mesh` of it."""
        mesh = SurfaceMesh.load(path)
        try:
            return cls.from_mesh(mesh, config)
        except NerfEditError as exc:
            raise NerfEditError(f"{path}: {exc}") from None

    @classmethod
    def from_mesh(cls, mesh: SurfaceMesh, config: MeshFieldConfig | None = None) -> MeshField:
        """The field of ``mesh`` (its vertex colours, else ``config.color``), scene box = bbox ± ``config.padding`` ×
        diagonal."""
        config = MeshFieldConfig() if config is None else config
        if mesh.vertex_colors is None and config.color is not None:
            colors = np.tile(np.asarray(config.color, dtype=np.float64), (mesh.n_vertices, 1))
            mesh = SurfaceMesh(mesh.vertices, mesh.faces, colors)
        if mesh.vertex_colors is None:
            raise NerfEditError(
                "mesh field: the mesh has no vertex colours (give every vertex one with --field-options.color R G B)"
            )
        if len(mesh.faces) == 0:
            raise NerfEditError("mesh field: the mesh has no triangles")
        pad = config.padding * mesh.bbox_diagonal
        bbox = np.stack([mesh.vertices.min(0) - pad, mesh.vertices.max(0) + pad])
        field = cls(config, torch.from_numpy(bbox))
        field.vertices = torch.from_numpy(mesh.vertices.copy())
        field.faces = torch.from_numpy(mesh.faces.copy())
        field.vertex_colors = torch.from_numpy(mesh.vertex_colors.astype(np.float32))
        return field

    @property
    def mesh(self) -> SurfaceMesh:
        return SurfaceMesh(
            self.vertices.cpu().numpy(), self.faces.cpu().numpy(), self.vertex_colors.cpu().numpy().astype(np.float64)
        )

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        """Adopt the checkpoint's mesh array shapes (an empty field loads any mesh), then load as usual."""
        for name in ("vertices", "faces", "vertex_colors"):
            value = state_dict.get(prefix + name)
            if isinstance(value, torch.Tensor):
                setattr(self, name, torch.empty_like(value, device=getattr(self, name).device))
        self._scene = None
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _raycasting_scene(self):
        if self._scene is None:
            if len(self.faces) == 0:
                raise NerfEditError("mesh field: no mesh loaded (use MeshField.from_mesh or load a checkpoint)")
            self._scene = raycast.raycasting_scene(self.vertices.cpu().numpy(), self.faces.cpu().numpy())
        return self._scene

    @staticmethod
    def _numpy_points(points: torch.Tensor) -> np.ndarray:
        return points.detach().reshape(-1, 3).cpu().numpy()

    def occupied(self, points: torch.Tensor) -> torch.Tensor:
        """Exact inside test ``(M,)`` (Open3D ray-parity occupancy; the mesh must be watertight)."""
        if len(points) == 0:
            return torch.zeros(0, dtype=torch.bool, device=points.device)
        occupancy = raycast.occupancy(self._raycasting_scene(), self._numpy_points(points))
        return torch.from_numpy(occupancy).to(points.device)

    def surface_colors(self, points: torch.Tensor) -> torch.Tensor:
        """``(M,3)``: barycentric vertex colour of the closest surface point of each point."""
        if len(points) == 0:
            return torch.zeros(0, 3, dtype=torch.float32, device=points.device)
        triangle, bary = raycast.closest_points(self._raycasting_scene(), self._numpy_points(points), np.float32)
        tri = self.faces.cpu().numpy()[triangle]
        colors = self.vertex_colors.cpu().numpy()
        rgb = np.einsum("mk,mkc->mc", bary, colors[tri])
        return torch.from_numpy(rgb.astype(np.float32)).to(points.device)

    def query(self, points: torch.Tensor, directions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Density ``config.density`` inside / 0 outside, colour of the closest surface point (view-independent)."""
        density = self.occupied(points).to(torch.float32) * self.config.density
        return density, self.surface_colors(points)

    def fit(self, dataset: Any, **kwargs: Any) -> dict:
        """Nothing to optimise: the mesh is the field. Returns an empty log."""
        return {}

    def extract_mesh(self, resolution: int = 256, level: float | None = None) -> SurfaceMesh:
        """The mesh itself, unchanged (same vertices, order, faces and colours); the arguments are ignored."""
        return self.mesh
