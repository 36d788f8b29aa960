"""SurfaceDeformation: ray bending by the displacement of the nearest point of the deformed surface, per sample.

The baselines of NeRF-Editing's comparisons (Table 1), which build no tet proxy. A surface ``S`` (rest vertices
``v``, faces) and its deformed copies ``S'`` (vertices ``v'``, one set per frame) give each deformed-space point ``x``
the offsets ``o = v − v'`` of the nearest part of ``S'``:

- ``closest-point``: ``x_c = x + Σ_k b_k o_{t_k}``, ``t`` the triangle of ``S'`` holding the closest point to ``x``
  and ``b`` that point's barycentrics (Open3D, float32: :func:`~nerfedit_plugin.geometry.raycast.closest_points`);
- ``knn3``: ``x_c = x + Σ_j w_j o_j`` over the 3 vertices of ``S'`` nearest to ``x``, ``w_j ∝ 1 / |x − v'_j|``.

So a vertex of ``S'`` maps to its rest vertex and a translation of the whole surface maps every point back by it.
Every point is mapped (none is empty) and the Jacobian is the identity: the baselines carry no view directions. The
map jumps where the nearest triangle (the three nearest vertices) changes, the medial axis of ``S'`` included, and
space a part moved away from maps to itself where the nearest part of ``S'`` did not move (the part shows there
too): the artefacts the paper's proxy removes. It is a :class:`~nerfedit_plugin.bending.maps.BackwardMap`, the
interface the renderer uses. For the paper's comparisons (``bench/bench_paper.py``), not an edit's lift:
docs/architecture.md, "Ray bending".
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import torch
from scipy.spatial import cKDTree

from nerfedit_plugin.bending.deformation_field import MOVED_TOLERANCE
from nerfedit_plugin.bending.maps import BentPoints, CanonicalPoints
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import raycast

SurfaceMethod = Literal["closest-point", "knn3"]


class SurfaceDeformation:
    """A rest surface and its deformed frames bending each point by the offset of its nearest surface point
    (module docstring). ``rest_vertices (V,3)``, ``faces (F,3)`` int, ``deformed_vertices (n_frames,V,3)`` (or
    ``(V,3)`` for one frame), arrays or tensors, stored as float64 / int64 numpy arrays; offsets are computed in
    float64 and points returned in ``dtype`` on ``device``."""

    def __init__(
        self,
        rest_vertices,
        faces,
        deformed_vertices,
        method: SurfaceMethod = "closest-point",
        *,
        device="cpu",
        dtype=torch.float32,
    ):
        if method not in ("closest-point", "knn3"):
            raise ValueError(f"method must be 'closest-point' or 'knn3', got {method!r}")
        rest, faces, deformed = (
            x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)
            for x in (rest_vertices, faces, deformed_vertices)
        )
        if deformed.ndim == 2:
            deformed = deformed[None]
        if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 3:
            raise NerfEditError(f"SurfaceDeformation: rest_vertices: expected shape (V>=3, 3), got {rest.shape}")
        if deformed.ndim != 3 or deformed.shape[1:] != rest.shape or len(deformed) == 0:
            raise NerfEditError(
                f"SurfaceDeformation: deformed_vertices: expected shape (F>=1, {len(rest)}, 3), got {deformed.shape}"
            )
        if not (np.isfinite(rest).all() and np.isfinite(deformed).all()):
            raise NerfEditError("SurfaceDeformation: vertices must be finite")
        if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or not np.issubdtype(faces.dtype, np.integer):
            raise NerfEditError(f"SurfaceDeformation: faces: expected (F>=1, 3) integers, got {faces.shape}")
        if faces.min() < 0 or faces.max() >= len(rest):
            raise NerfEditError(f"SurfaceDeformation: faces: vertex index out of range [0, {len(rest)})")
        self.rest_vertices, self.faces = rest.astype(np.float64), faces.astype(np.int64)
        self.deformed_vertices = deformed.astype(np.float64)
        self.method = method
        self.device, self.dtype = torch.device(device), dtype
        self._queries: dict[int, object] = {}  # frame -> Open3D RaycastingScene or cKDTree of S'
        self._moved: dict[int, np.ndarray | None] = {}  # frame -> moved_bounds (the renderer asks once per ray batch)

    @property
    def n_frames(self) -> int:
        return len(self.deformed_vertices)

    def _check_frame(self, frame: int) -> int:
        if not 0 <= frame < self.n_frames:
            raise NerfEditError(f"frame {frame} out of range: the surface deformation has {self.n_frames} frame(s)")
        return int(frame)

    def displacements(self, points: np.ndarray, frame: int = 0) -> np.ndarray:
        """points (M,3) float64 in deformed space → ``(M,3)`` float64 ``x_c − x``: the blended offsets ``v − v'`` of
        the closest point (the three nearest vertices) of ``frame``'s deformed surface."""
        frame = self._check_frame(frame)
        offsets = self.rest_vertices - self.deformed_vertices[frame]
        if frame not in self._queries:
            deformed = self.deformed_vertices[frame]
            self._queries[frame] = (
                cKDTree(deformed) if self.method == "knn3" else raycast.raycasting_scene(deformed, self.faces)
            )
        query = self._queries[frame]
        if self.method == "knn3":
            distances, nearest = query.query(points, k=3)
            weights = 1.0 / np.maximum(distances, 1e-12)
            weights /= weights.sum(1, keepdims=True)
            return np.einsum("mk,mkd->md", weights, offsets[nearest])
        triangle, bary = raycast.closest_points(query, points)
        return np.einsum("mk,mkd->md", bary, offsets[self.faces[triangle]])

    def moved_bounds(self, frame: int = 0) -> np.ndarray | None:
        """``(2,3)`` float64 (lo, hi) bounding box of the deformed corners of the faces of ``frame`` with a corner
        displaced by more than ``MOVED_TOLERANCE`` × the rest surface's extent; None if there is none (an identity
        edit: the renderer samples as without it). The moved content lies in this box, the still surface where it
        was (the renderer's sampling box adds this box to the scene box)."""
        frame = self._check_frame(frame)
        if frame not in self._moved:
            rest, deformed = self.rest_vertices, self.deformed_vertices[frame]
            moved = np.linalg.norm(deformed - rest, axis=1) > MOVED_TOLERANCE * float(np.ptp(rest, axis=0).max())
            corners = deformed[self.faces[moved[self.faces].any(1)]].reshape(-1, 3)
            self._moved[frame] = np.stack([corners.min(0), corners.max(0)]) if len(corners) else None
        return self._moved[frame]

    def bend(
        self, x: torch.Tensor, frame: int = 0, *, out: torch.Tensor | None = None, tets: bool = True
    ) -> BentPoints:
        """Map deformed-space points ``x (M,3)`` of ``frame`` to canonical space, ``x_c = x +`` :meth:`displacements`
        → :class:`BentPoints`: ``points (M,3)`` (``dtype``), ``tet (M,)`` int64 all -1 (no tet: the identity
        Jacobian; None with ``tets=False``), ``empty (M,)`` all False. ``out``: an ``(M,3)`` tensor that receives
        ``x_c`` (and is returned as ``points``); it may be ``x`` itself. Otherwise ``x`` is not modified."""
        x = torch.as_tensor(x)
        if out is not None and out.shape != (len(x), 3):
            raise ValueError(f"bend: out must have shape ({len(x)}, 3), got {tuple(out.shape)}")
        points = x.detach().reshape(-1, 3).cpu().numpy().astype(np.float64)
        mapped = torch.from_numpy(points + self.displacements(points, frame)).to(device=self.device, dtype=self.dtype)
        if out is not None:
            mapped = out.copy_(mapped)
        tet = torch.full((len(points),), -1, dtype=torch.int64, device=self.device) if tets else None
        return BentPoints(mapped, tet, torch.zeros(len(points), dtype=torch.bool, device=self.device))

    def jacobian(self, tet: torch.Tensor, frame: int = 0) -> torch.Tensor:
        """tet (M,) as :meth:`bend` returns → ``(M,3,3)`` identities (``dtype``, on ``device``): the baselines do not
        bend view directions."""
        self._check_frame(frame)
        return torch.eye(3, dtype=self.dtype, device=self.device).expand(len(tet), 3, 3)

    def to_canonical(self, x: torch.Tensor, frame: int = 0) -> CanonicalPoints:
        """:meth:`bend` as :class:`CanonicalPoints`: ``inside`` is all True (every point is mapped), ``empty`` all
        False, ``jacobian`` the identities."""
        bent = self.bend(x, frame)
        inside = torch.ones(len(bent.points), dtype=torch.bool, device=self.device)
        return CanonicalPoints(bent.points, inside, bent.empty, self.jacobian(bent.tet, frame))
