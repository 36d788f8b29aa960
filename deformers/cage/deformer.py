"""Cage deformer: a closed triangle cage around the mesh carries it by mean value (default) or Green coordinates.

Spec (besides ``frames``): ``"cage": "cage.ply"`` + ``"deformed_cage": "cage_deformed.ply"`` (both cages given, same
vertex order; frames interpolate linearly), or ``"cage": "auto"`` (default) / a cage file + ``"handles"`` applied to
the *cage* vertices. ``bind`` evaluates the coordinates of the mesh vertices in blocks of ``bind_block`` (memory bounded
by the block, not the mesh) and poses every frame of the spec from each block in float64; it keeps the coordinates
(float64, else float32 when only those fit ``weights_budget_mb``) so that a changed ``deformed_cages`` (the editor's
previews) re-poses with one matrix product per block, and otherwise evaluates them again block by block. Mesh points
outside the cage trigger a warning (mean value coordinates extrapolate; Green coordinates are undefined there and fall
back to mean value coordinates). On meshes bound on a coarse level (``multiresolution``, above
``coarse_above`` vertices, 250k by default) the coordinates are those of the coarse
vertices and their difference stencils; the fine vertices follow the cage map's pose and Jacobian there. Formulas:
docs/method.md, "Built-in deformers".
"""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import Literal

import numpy as np
import tyro

from deformers.cage.editing import CageBackend
from deformers.cage.green import green_coordinates, green_face_terms
from deformers.cage.mean_value import mean_value_coordinates
from nerfedit_plugin.edit.coarse import CoarseOptions, cached_coarse_level
from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig, Overlay
from nerfedit_plugin.edit.proxy import ProxyConfig
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh, cluster_vertices
from nerfedit_plugin.geometry.multires import carry
from nerfedit_plugin.geometry.normals import face_normals
from nerfedit_plugin.geometry.wrap import wrap_and_decimate

NEAR_CAGE = 1e-4  # closer to the cage than this × its size: the exact winding number decides inside / outside
STENCIL_STEP = 1e-4
"""Forward-difference step of the cage map's Jacobian at the coarse vertices (multiresolution), × the mesh's bbox
diagonal: an affine map's differences are exact at any step; rounding costs ~1e-12 relative at this one."""


@dataclasses.dataclass
class CageConfig(DeformerConfig, CoarseOptions):
    """Cage-based deformation (mean value or Green coordinates)."""

    _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: CageDeformer)
    coordinates: Literal["mvc", "green"] = "mvc"
    """Space coordinates: ``mvc`` (mean value: smooth, exact for affine cage maps, extrapolates outside the cage)
    or ``green`` (Green coordinates: shape-preserving, exact for similarities, defined inside the cage only)."""
    auto_alpha: float = 5.0
    """``"cage": "auto"``: alpha-wrap ball size in percent of the mesh's bounding-box diagonal."""
    auto_offset: float = 2.0
    """``"cage": "auto"``: distance of the wrap from the mesh in percent of the bounding-box diagonal (doubled, up to
    twice, when simplification would leave mesh vertices outside)."""
    auto_max_vertices: int = 400
    """``"cage": "auto"``: simplify the wrap (quadric edge collapse) to at most this many vertices."""
    chunk_size: int = 64
    """Points per block when evaluating coordinates (memory ≈ 40 · cage faces · chunk_size floats per thread)."""
    bind_block: int = 16384
    """Mesh vertices whose coordinates are evaluated (and posed) at once by ``bind``: its working memory is about
    ``8 · (C + F) · bind_block`` bytes whatever the mesh size (C cage vertices, F cage faces)."""
    weights_budget_mb: float = 3072.0
    """Keep the coordinates of the mesh vertices after ``bind`` (for re-posing a changed ``deformed_cages``: the
    editor's previews) when they fit in this many MiB: as float64, else as float32 (a re-pose then differs from
    float64 by ~1e-8 of the cage size), else not at all (a re-pose evaluates them again, block by block: as slow as
    the bind). They take ``8 · C · V`` bytes as float64 for ``mvc``, ``8 · (C + F) · V`` for ``green`` (C cage
    vertices, F ≈ 2C faces): with the auto cage's 400 vertices, mvc keeps float64 up to ~1M mesh vertices and float32
    up to 2M; green float64 up to 330k, float32 up to 670k."""

    coarse_above: int = 250_000
    """``multiresolution = "auto"``: meshes of more vertices than this (a vertex count) bind on the coarse level (the
    coordinates of its vertices and their difference stencils, four points each: worth it from a few times the
    coarse level's size)."""

    def __post_init__(self) -> None:
        check_option(self, "auto_alpha", self.auto_alpha, self.auto_alpha > 0, "> 0")
        check_option(self, "auto_offset", self.auto_offset, self.auto_offset > 0, "> 0")
        check_option(self, "auto_max_vertices", self.auto_max_vertices, self.auto_max_vertices >= 4, ">= 4")
        check_option(self, "chunk_size", self.chunk_size, self.chunk_size >= 1, ">= 1")
        check_option(self, "bind_block", self.bind_block, self.bind_block >= 1, ">= 1")
        budget = self.weights_budget_mb
        check_option(self, "weights_budget_mb", budget, bool(np.isfinite(budget) and budget >= 0), "a number >= 0")
        self.check_coarse_options()


AUTO_CLUSTER_FACES = ProxyConfig.wrap_cluster_faces
"""Meshes of this many triangles or more are alpha-wrapped through their vertex clustering: the tet proxy's rule
(``ProxyConfig.wrap_cluster_faces``; the wrap's time grows with its input's triangles, 14 s for the 3.6M of a
1.8M-vertex mesh)."""
AUTO_CLUSTER_CELL = ProxyConfig.wrap_cell
"""Cell of that clustering, × the wrap's offset (``ProxyConfig.wrap_cell``)."""


def auto_cage(mesh: SurfaceMesh, alpha: float = 5.0, offset: float = 2.0, max_vertices: int = 400) -> SurfaceMesh:
    """A coarse watertight cage around ``mesh``: pymeshlab alpha wrap (percentages of the bbox diagonal; of the
    :func:`~nerfedit_plugin.geometry.mesh.cluster_vertices` of the mesh on cells of :data:`AUTO_CLUSTER_CELL` ×
    offset from :data:`AUTO_CLUSTER_FACES` triangles on), then quadric edge collapse down to ``max_vertices`` if
    needed."""
    if len(mesh.faces) < AUTO_CLUSTER_FACES:
        return wrap_and_decimate(mesh.vertices, mesh.faces, alpha, offset, percent=True, max_vertices=max_vertices)
    size = mesh.bbox_diagonal / 100.0  # percentages of the mesh's diagonal, not of its clustering's
    wrapped = cluster_vertices(mesh, AUTO_CLUSTER_CELL * offset * size)
    return wrap_and_decimate(wrapped.vertices, wrapped.faces, alpha * size, offset * size, max_vertices=max_vertices)


def validate_cage(cage: SurfaceMesh, label: str) -> SurfaceMesh:
    """Check a cage is a closed, consistently oriented triangle mesh without degenerate faces; return it with
    outward-facing triangles. ``label`` (file and key) prefixes every error."""
    faces = cage.faces
    if len(faces) < 4:
        raise NerfEditError(f"{label}: a closed cage needs at least 4 triangles, got {len(faces)}")
    if np.any((faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])):
        raise NerfEditError(f"{label}: has triangles with a repeated vertex")
    v = cage.vertices
    area2 = np.linalg.norm(face_normals(v, faces), axis=1)
    if np.any(area2 <= 1e-12 * cage.bbox_diagonal**2):
        raise NerfEditError(
            f"{label}: {np.count_nonzero(area2 <= 1e-12 * cage.bbox_diagonal**2)} triangles have zero area"
        )
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    keys, counts = np.unique(directed[:, 0] * len(v) + directed[:, 1], return_counts=True)
    if np.any(counts > 1):
        raise NerfEditError(
            f"{label}: not consistently oriented or not manifold ({np.count_nonzero(counts > 1)} edges are "
            "traversed twice in the same direction); recompute normals consistently "
            "(Blender: Recalculate Outside)"
        )
    boundary = ~np.isin(directed[:, 1] * len(v) + directed[:, 0], keys)
    if np.any(boundary):
        raise NerfEditError(
            f"{label}: not closed ({np.count_nonzero(boundary)} boundary edges); a cage must be watertight "
            "(merge duplicate vertices — Blender: Merge by Distance — and fill holes)"
        )
    volume = np.einsum("fi,fi->f", v[faces[:, 0]], np.cross(v[faces[:, 1]], v[faces[:, 2]])).sum() / 6.0
    return cage if volume > 0 else SurfaceMesh(v, faces[:, ::-1].copy())


def enclosure(points: np.ndarray, cage: SurfaceMesh) -> tuple[np.ndarray, np.ndarray]:
    """Masks ``(inside, outside)`` of ``points`` w.r.t. the closed ``cage``; points on the cage are neither.

    Open3D ray parity (float32, majority of 3 rays) decides points farther than ``NEAR_CAGE`` × cage size from
    the cage; the exact winding number of the mean value kernel (±1 inside, 0 outside, ½ on the cage) decides
    the few closer ones."""
    scene = raycast.raycasting_scene(cage.vertices, cage.faces)
    inside = raycast.occupancy(scene, points, nsamples=3)
    outside = ~inside
    near = np.flatnonzero(raycast.distance(scene, points) <= NEAR_CAGE * cage.bbox_diagonal)
    if near.size:
        _, winding = mean_value_coordinates(points[near], cage.vertices, cage.faces, return_winding=True)
        inside[near], outside[near] = np.abs(winding) > 0.5, np.abs(winding) < 0.5
    return inside, outside


def _load_cage(spec: EditSpec, key: str) -> SurfaceMesh:
    """Read the mesh file named by ``key``; errors name the spec, the key and the file."""
    path = spec.path(key)
    try:
        return SurfaceMesh.load(path)
    except NerfEditError as exc:
        message = str(exc) if str(path) in str(exc) else f"{path}: {exc}"
        raise NerfEditError(f"{spec.source}: {key}: {message}") from None


class CageDeformer(Deformer):
    """Binds mesh vertices to a cage; ``rest_cage`` and ``deformed_cages (frames, C, 3)`` are set by :meth:`bind`."""

    spec_keys = frozenset({"cage", "deformed_cage", "handles"})
    editor = CageBackend

    def __init__(self, config: CageConfig) -> None:
        super().__init__(config)
        self.rest_cage: SurfaceMesh | None = None
        self.deformed_cages: np.ndarray | None = None
        self._points: np.ndarray | None = None  # the bound mesh vertices (V,3) and which lie inside the cage (V,) bool
        self._inside: np.ndarray | None = None
        self._weights: tuple[np.ndarray, np.ndarray | None] | None = None  # (phiᵀ (C,V), psiᵀ (F,V) or None) or None
        self._posed: tuple[np.ndarray, np.ndarray] | None = None  # (deformed_cages, frames (frames,V,3)) of the bind
        self._last: tuple[np.ndarray, tuple[np.ndarray, np.ndarray | None]] | None = None

    # ---- binding -----------------------------------------------------------------------------------------------
    def bind(self, rest: SurfaceMesh, edit: EditSpec) -> None:
        cage_value = edit.extra.get("cage", "auto")
        if not isinstance(cage_value, str):
            raise NerfEditError(f'{edit.source}: cage: expected "auto" or a mesh file, got {cage_value!r}')
        has_target, has_handles = "deformed_cage" in edit.extra, bool(edit.handles)
        if has_target and has_handles:
            raise NerfEditError(f"{edit.source}: deformed_cage and handles: give one of them, not both")
        if not (has_target or has_handles):
            raise NerfEditError(f"{edit.source}: nothing moves the cage: give 'deformed_cage' or 'handles'")
        if cage_value == "auto" and has_target:
            raise NerfEditError(
                f'{edit.source}: deformed_cage: needs a cage file with the same vertex order, but cage is "auto"'
            )
        self.rest, self.level, self.level_cached, points = rest, None, False, rest.vertices
        if self.config.binds_coarse(rest):  # bind the coarse vertices' stencils instead of the mesh vertices
            level, self.level_cached = cached_coarse_level(self.bind_cache, rest, self.config.coarse_vertices)
            if not level.is_identity:
                self.level = level
                points = stencil(level.coarse.vertices, STENCIL_STEP * rest.bbox_diagonal)
        if cage_value == "auto":
            label = f"{edit.source}: cage: auto"
            cage, (inside, outside) = self._auto_cage(rest, points, label)
        else:
            label = f"{edit.source}: cage: {edit.path('cage')}"
            loaded = _load_cage(edit, "cage")
            cage = validate_cage(loaded, label)
            self.on_progress(0, None, "inside/outside the cage")
            inside, outside = enclosure(points, cage)

        if has_target:
            target = _load_cage(edit, "deformed_cage")
            where = f"{edit.source}: deformed_cage: {edit.path('deformed_cage')}"
            if target.n_vertices != cage.n_vertices:
                raise NerfEditError(
                    f"{where}: has {target.n_vertices} vertices, the cage has {cage.n_vertices} "
                    "(same vertex order required)"
                )
            if not np.array_equal(np.sort(target.faces, axis=1), np.sort(loaded.faces, axis=1)):
                raise NerfEditError(f"{where}: its triangles differ from the cage's (edit vertex positions only)")
            t = edit.times[:, None, None]
            poses = (1.0 - t) * cage.vertices + t * target.vertices
        else:
            idx, targets = edit.handle_targets(cage.vertices, cage.faces)
            poses = np.repeat(cage.vertices[None], edit.frames, axis=0)
            poses[:, idx] = targets

        self.rest_cage, self.deformed_cages, self._last = cage, poses, None
        self._points, self._inside = points, inside
        self._weights, frames = self._evaluate(poses, keep=True)
        self._posed = (poses.copy(), self._carried(frames))
        outside = int(np.count_nonzero(outside))
        if outside:
            fallback = (
                "mean value coordinates extrapolate them"
                if self.config.coordinates == "mvc"
                else "Green coordinates are undefined there; they use mean value coordinates"
            )
            what = "mesh vertices" if self.level is None else "points bound (the coarse level's vertices and stencils)"
            warnings.warn(f"{label}: {outside} of {len(points)} {what} lie outside the cage ({fallback})", stacklevel=2)

    def _mean_value(self, points: np.ndarray, cage: SurfaceMesh) -> np.ndarray:
        """Mean value coordinates ``(P, C)`` of ``points`` in ``cage``."""
        return mean_value_coordinates(points, cage.vertices, cage.faces, chunk_size=self.config.chunk_size)

    def _auto_cage(
        self, rest: SurfaceMesh, points: np.ndarray, label: str
    ) -> tuple[SurfaceMesh, tuple[np.ndarray, np.ndarray]]:
        """The automatic cage around ``rest`` and the :func:`enclosure` of the bound ``points`` (the mesh vertices or
        the coarse level's stencils) in it. Simplification can cut into the mesh: then wrap again farther out (offset
        ×2, ×4) until every point is inside."""
        cfg = self.config
        for attempt in range(3):
            self.on_progress(0, None, "automatic cage" + (f" (offset ×{2**attempt})" if attempt else ""))
            wrap = auto_cage(rest, cfg.auto_alpha, cfg.auto_offset * 2**attempt, cfg.auto_max_vertices)
            cage = validate_cage(wrap, label)
            masks = enclosure(points, cage)
            if not np.any(masks[1]):
                break
        return cage, masks

    def _coordinates(self, points: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """``(phiᵀ (C, P), psiᵀ (F, P) or None)`` float64 of ``points (P,3)`` in the rest cage, ``inside (P,)`` bool
        their :func:`enclosure`: mean value coordinates, or Green coordinates (mean value ones outside the cage);
        transposed so a pose is one C-contiguous product."""
        cage, chunk = self.rest_cage, self.config.chunk_size
        if self.config.coordinates == "mvc":
            return self._mean_value(points, cage).T, None
        phi_t, psi_t = np.empty((len(cage.vertices), len(points))), np.zeros((len(cage.faces), len(points)))
        if not inside.all():  # mean value coordinates where Green coordinates are undefined
            phi_t[:, ~inside] = self._mean_value(points[~inside], cage).T
        if inside.any():
            green_phi, green_psi = green_coordinates(points[inside], cage.vertices, cage.faces, chunk_size=chunk)
            phi_t[:, inside], psi_t[:, inside] = green_phi.T, green_psi.T
        return phi_t, psi_t

    def _stored_dtype(self) -> type | None:
        """float64, float32 or None: how the coordinates of the bound points fit ``weights_budget_mb``."""
        cage, n = self.rest_cage, len(self._points)
        rows = len(cage.vertices) + (len(cage.faces) if self.config.coordinates == "green" else 0)
        budget = self.config.weights_budget_mb * 2**20
        return next(
            (dtype for dtype in (np.float64, np.float32) if rows * n * np.dtype(dtype).itemsize <= budget), None
        )

    def _evaluate(
        self, poses: np.ndarray, keep: bool
    ) -> tuple[tuple[np.ndarray, np.ndarray | None] | None, np.ndarray]:
        """Coordinates of the bound points evaluated block by block (``bind_block`` points) and applied to
        ``poses (frames, C, 3)`` → ``(the coordinates as :meth:`_stored_dtype` keeps them, or None; frames
        (frames, V, 3) float64)``. Only ``keep`` stores coordinates. Progress: one unit per block."""
        cage, points, inside = self.rest_cage, self._points, self._inside
        n, block = len(points), self.config.bind_block
        dtype = self._stored_dtype() if keep else None
        green = self.config.coordinates == "green"
        stored = None
        if dtype is not None:
            stored = (
                np.empty((len(cage.vertices), n), dtype=dtype),
                np.empty((len(cage.faces), n), dtype=dtype) if green else None,
            )
        terms = [green_face_terms(cage.vertices, pose, cage.faces) for pose in poses] if green else None
        frames = np.empty((len(poses), n, 3))
        blocks, what = -(-n // block), "Green" if green else "mean value"
        for b, start in enumerate(range(0, n, block)):
            self.on_progress(b, blocks, f"{what} coordinates of {n} vertices")
            part = slice(start, min(start + block, n))
            phi_t, psi_t = self._coordinates(points[part], inside[part])
            for f, pose in enumerate(poses):
                frames[f, part] = _posed(phi_t, psi_t, pose, None if terms is None else terms[f])
            if stored is not None:
                stored[0][:, part] = phi_t
                if green:
                    stored[1][:, part] = psi_t
        self.on_progress(blocks, blocks, f"{what} coordinates of {n} vertices")
        return stored, frames

    # ---- evaluation --------------------------------------------------------------------------------------------
    def _apply(self, weights: tuple[np.ndarray, np.ndarray | None], frame: int) -> np.ndarray:
        """The ``frame`` pose of points with coordinates ``weights`` (float64 or float32, ``(C, P)`` / ``(F, P)``)
        → (P,3) float64, block by block (``bind_block`` points: float32 coordinates are widened one block at a
        time)."""
        phi_t, psi_t = weights
        pose = self.deformed_cages[frame]
        terms = None if psi_t is None else green_face_terms(self.rest_cage.vertices, pose, self.rest_cage.faces)
        n, block = phi_t.shape[1], self.config.bind_block
        if phi_t.dtype == np.float64 and n <= block:
            return _posed(phi_t, psi_t, pose, terms)
        out = np.empty((n, 3))
        for start in range(0, n, block):
            part = slice(start, min(start + block, n))
            out[part] = _posed(phi_t[:, part], None if psi_t is None else psi_t[:, part], pose, terms)
        return out

    def deform(self) -> np.ndarray:
        if self._posed is None:
            raise RuntimeError("CageDeformer.deform() called before bind()")
        if np.array_equal(self._posed[0], self.deformed_cages):  # the poses of the bind: posed then, in float64
            return self._posed[1].copy()
        if self._weights is None:  # the coordinates did not fit weights_budget_mb: evaluate them again
            return self._carried(self._evaluate(np.asarray(self.deformed_cages, dtype=np.float64), keep=False)[1])
        return self._carried(np.stack([self._apply(self._weights, f) for f in range(len(self.deformed_cages))]))

    def _carried(self, frames: np.ndarray) -> np.ndarray:
        """The bound points' poses (frames, P, 3) → the mesh's (frames, V, 3): the same on the mesh itself; on a coarse
        level, each coarse vertex's pose and the Jacobian of the cage map there (forward differences over its
        :func:`stencil`) carry the fine vertices (:func:`~nerfedit_plugin.geometry.multires.carry`: exact for an
        affine cage map, as the coordinates are)."""
        if self.level is None:
            return frames
        n, step = self.level.coarse.n_vertices, STENCIL_STEP * self.rest.bbox_diagonal
        out = np.empty((len(frames), self.rest.n_vertices, 3))
        for f, posed in enumerate(frames):
            centre = posed[:n]
            jacobian = np.stack([posed[(a + 1) * n : (a + 2) * n] - centre for a in range(3)], axis=2) / step
            out[f] = carry(self.level, self.rest.vertices, centre, jacobian)
        return out

    def report(self) -> dict:
        """``path``: ``direct`` (coordinates of every mesh vertex) or ``multiresolution`` (of the coarse level's
        vertices and their stencils; ``coarse``: ``vertices``, ``faces``, ``cached``: read from the bind cache)."""
        if self.level is None:
            return {"path": "direct"}
        coarse = self.level.coarse
        cached = {"vertices": coarse.n_vertices, "faces": len(coarse.faces), "cached": self.level_cached}
        return {"path": "multiresolution", "coarse": cached}

    def deform_points(self, points: np.ndarray, frame: int) -> np.ndarray:
        """Cage coordinates of ``points`` (cached for repeated calls with the same points) applied to ``frame``."""
        if self._weights is None:
            raise RuntimeError("CageDeformer.deform_points() called before bind()")
        points = np.asarray(points, dtype=np.float64)
        if self._last is None or not np.array_equal(self._last[0], points):
            self._last = (points.copy(), self._coordinates(points, enclosure(points, self.rest_cage)[0]))
        return self._apply(self._last[1], frame)

    def write_artifacts(self, out_dir: Path) -> list[Path]:
        """Write the cages used: ``cage_rest.ply`` and ``cage_deformed.ply`` (``cage_deformed_0000.ply``… for
        sequences)."""
        out_dir = Path(out_dir)
        n = len(self.deformed_cages)
        names = ["cage_deformed.ply"] if n == 1 else [f"cage_deformed_{i:04d}.ply" for i in range(n)]
        written = [out_dir / "cage_rest.ply"]
        self.rest_cage.save(written[0])
        for name, pose in zip(names, self.deformed_cages):
            self.rest_cage.with_vertices(pose).save(out_dir / name)
            written.append(out_dir / name)
        return written

    @classmethod
    def overlays(cls, edit_dir: Path, frame: int) -> list[Overlay]:
        """The rest cage and the cage of ``frame``, as :meth:`write_artifacts` wrote them."""
        rest = Path(edit_dir) / "cage_rest.ply"
        if not rest.is_file():
            return []
        posed = sorted(Path(edit_dir).glob("cage_deformed*.ply"))
        cage = SurfaceMesh.load(rest)
        return [Overlay("cage", cage, SurfaceMesh.load(posed[min(frame, len(posed) - 1)]) if posed else None)]

    @classmethod
    def handle_points(cls, edit_dir: Path, rest: SurfaceMesh) -> np.ndarray:
        """Handles grab the rest cage's vertices."""
        cage = Path(edit_dir) / "cage_rest.ply"
        return SurfaceMesh.load(cage).vertices if cage.is_file() else rest.vertices

    # ---- conformance-kit hooks ---------------------------------------------------------------------------------
    @classmethod
    def identity_edit(cls, edit: dict, rest: SurfaceMesh) -> dict | None:
        """The deformed cage is the rest cage; for handle edits the kit's default (zero transforms) applies."""
        return {**edit, "deformed_cage": edit["cage"]} if "deformed_cage" in edit else None

    @classmethod
    def placed_edit(cls, edit: dict, scale: float, offset: np.ndarray, base_dir: Path, folder: Path) -> dict:
        """Conformance-kit hook: the cage files, placed into ``folder``."""
        from nerfedit_plugin.testing.deformers import placed_mesh_files

        for key in ("cage", "deformed_cage"):
            if key in edit and edit[key] != "auto":
                placed_mesh_files(edit[key], scale, offset, base_dir, folder)
        return edit

    @classmethod
    def rigid_edit(cls, edit: dict, rest: SurfaceMesh) -> dict:
        """Move every cage vertex by one rigid motion (a handle selecting the whole cage)."""
        out = {k: v for k, v in edit.items() if k not in ("deformed_cage", "handles")}
        everything = {"box": {"min": [-1e12] * 3, "max": [1e12] * 3}}
        motion = {
            "rotate": {"axis": [1.0, -1.0, 2.0], "degrees": 30.0},
            "translate": [0.1 * rest.bbox_diagonal, 0.0, 0.0],
        }
        return {**out, "handles": [{"select": everything, "transform": motion}]}


def stencil(points: np.ndarray, step: float) -> np.ndarray:
    """points (C,3) → (4C,3): the points, then each moved by ``step`` along x, along y, along z (forward differences
    of a space map at the points)."""
    return np.concatenate([points] + [points + step * np.eye(3)[a] for a in range(3)])


def _posed(phi_t: np.ndarray, psi_t: np.ndarray | None, pose: np.ndarray, terms: np.ndarray | None) -> np.ndarray:
    """Points with coordinates ``phi_t (C,P)``, ``psi_t (F,P)`` or None (float64 or float32) under the cage pose
    ``pose (C,3)`` (``terms (F,3)``: its :func:`green_face_terms`) → (P,3) float64. float32 coordinates are widened
    (their sum is 1 to ~1e-7 only: the pose is taken about its bounding-box centre, so the error scales with the
    cage's size, not with its distance from the origin)."""
    if phi_t.dtype != np.float64:
        centre = (pose.min(0) + pose.max(0)) / 2
        out = (pose - centre).T @ phi_t.astype(np.float64)
        out += centre[:, None]
    else:
        out = pose.T @ phi_t
    if psi_t is not None:
        out += terms.T @ psi_t.astype(np.float64, copy=False)
    return np.ascontiguousarray(out.T)
