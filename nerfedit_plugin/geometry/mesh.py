"""SurfaceMesh: plain triangle-mesh arrays plus I/O (trimesh) and Open3D / trimesh conversions."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.samples import resolve_mesh_path
from nerfedit_plugin.io.atomic import atomic_path


def _read_ply_open3d(path: Path) -> SurfaceMesh | None:
    """PLY through Open3D's reader (0.5 s for 1.8M vertices; trimesh copies and hashes the arrays: 2.2 s), vertex
    order kept; None when Open3D reads no triangles (trimesh then reads the file or says what is wrong)."""
    import open3d as o3d

    with open(path, "rb") as file:
        magic = file.read(4)
        if magic[:3] != b"ply" or not magic[3:].isspace():  # no PLY: Open3D's RPly would print its own error line
            return None
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh = o3d.io.read_triangle_mesh(str(path))
    if not mesh.has_triangles():
        return None
    colors = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else None
    return SurfaceMesh(np.asarray(mesh.vertices).copy(), np.asarray(mesh.triangles).astype(np.int64), colors)


def unit_frame(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """vertices (N,3) → ``(centre (3,) float64, size float)``: the bounding-box centre and diagonal (1 for a single
    point), so ``(x − centre) / size`` is centred with a unit diagonal. Steps whose tolerances are absolute (fTetWild
    segfaults on a cow 1e-6 across; MeshLab's float32 meshes; Open3D's float32 distances far from the origin) run in
    this frame, so their results do not depend on the input's size or position."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    return (low + high) / 2, float(np.linalg.norm(high - low)) or 1.0


def longest_side_frame(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """vertices (N,3) → ``(centre (3,) float64, extent float)``: the bounding-box centre and longest side, so
    ``(x − centre) / extent`` fits the centred unit cube (the data generator's frame). Coinciding vertices are a
    :class:`NerfEditError`."""
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    extent = float((high - low).max())
    if not extent > 0:
        raise NerfEditError("mesh: all vertices coincide (nothing to render)")
    return (low + high) / 2, extent


def grid_cells(points: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """points (M,3) float64, cell size → ``(cells (C,3) int64 grid coordinates of the occupied cells (in increasing
    linear order), owner (M,) int64 each point's row in ``cells``, low (3,) float64 the grid's origin)``: cell
    ``(i,j,k)`` is ``low + cell · [i, i+1) × [j, j+1) × [k, k+1)``."""
    low = points.min(axis=0)
    ijk = np.floor((points - low) / cell).astype(np.int64)
    dims = ijk.max(axis=0) + 1
    key = np.ravel_multi_index(ijk.T, dims)
    if int(np.prod(dims)) <= max(4 * len(points), 1 << 22):  # np.unique without its sort: flags on the whole grid
        occupied = np.zeros(int(np.prod(dims)), dtype=bool)
        occupied[key] = True
        linear = np.flatnonzero(occupied)
        row = np.cumsum(occupied) - 1
        owner = row[key]
    else:
        linear, owner = np.unique(key, return_inverse=True)
    return np.stack(np.unravel_index(linear, dims), axis=1), owner.ravel(), low


def cluster_vertices(mesh: SurfaceMesh, cell: float) -> SurfaceMesh:
    """Vertex clustering: the vertices of each occupied grid cell (size ``cell``) merged into their mean, the faces
    whose three corners fall into three different cells kept (a vertex alone in its cell keeps its position bit for
    bit). Deterministic; linear in the mesh but for one sort of the cell keys."""
    return vertex_clusters(mesh, cell)[0]


def vertex_clusters(mesh: SurfaceMesh, cell: float) -> tuple[SurfaceMesh, np.ndarray]:
    """:func:`cluster_vertices` of ``mesh`` (V vertices) and ``owner (V,) int64``, the clustered vertex each vertex
    of ``mesh`` merged into."""
    cells, owner, _ = grid_cells(mesh.vertices, cell)
    counts = np.bincount(owner, minlength=len(cells))
    centres = np.stack([np.bincount(owner, mesh.vertices[:, k], len(cells)) for k in range(3)], axis=1)
    faces = owner[mesh.faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    return SurfaceMesh(centres / counts[:, None], faces), owner


@dataclass
class SurfaceMesh:
    """A triangle mesh: ``vertices (V,3) float64``, ``faces (F,3) int64``, optional ``vertex_colors (V,3)`` float64
    in [0,1] (inputs are cast; colours above 1 are read as 0–255; a 4th colour channel is dropped)."""

    vertices: np.ndarray
    faces: np.ndarray
    vertex_colors: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.int64)
        if self.vertices.ndim != 2 or self.vertices.shape[1] != 3:
            raise NerfEditError(f"mesh vertices: expected shape (V,3), got {self.vertices.shape}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3:
            raise NerfEditError(f"mesh faces: expected triangles (F,3), got {self.faces.shape}")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            face = int(np.flatnonzero(((self.faces < 0) | (self.faces >= len(self.vertices))).any(1))[0])
            raise NerfEditError(
                f"mesh faces: face {face} {self.faces[face].tolist()} has a vertex index out of range "
                f"(the mesh has {len(self.vertices)} vertices)"
            )
        finite = np.isfinite(self.vertices).all(1)
        if not finite.all():
            first = int(np.flatnonzero(~finite)[0])
            raise NerfEditError(
                f"mesh vertices: vertex {first} is {self.vertices[first].tolist()} "
                f"({np.count_nonzero(~finite)} vertices contain NaN or Inf)"
            )
        if self.vertex_colors is not None:
            colors = np.asarray(self.vertex_colors, dtype=np.float64)
            if colors.max(initial=0.0) > 1.0:
                colors = colors / 255.0
            self.vertex_colors = np.ascontiguousarray(colors[:, :3])

    @property
    def n_vertices(self) -> int:
        """V, the number of vertices."""
        return len(self.vertices)

    @property
    def bbox_diagonal(self) -> float:
        """Length of the diagonal of the vertices' axis-aligned bounding box (float)."""
        v = self.vertices  # per coordinate column: numpy reduces a (V,3) array over axis 0 ten times slower
        return float(np.linalg.norm([v[:, d].max() - v[:, d].min() for d in range(v.shape[1])]))

    def referenced(self) -> np.ndarray:
        """(V,) bool: the vertices some face uses (linear in the faces; ``np.unique`` would sort the 3F corners)."""
        used = np.zeros(len(self.vertices), dtype=bool)
        used[self.faces.ravel()] = True
        return used

    def with_vertices(self, vertices: np.ndarray) -> SurfaceMesh:
        """vertices (V,3) float → a SurfaceMesh with the same connectivity and colours, new positions."""
        return SurfaceMesh(vertices, self.faces, self.vertex_colors)

    def component_labels(self) -> np.ndarray:
        """→ (V,) int64 connected-part label of each vertex, 0 … C−1 (parts connect through faces; an unreferenced
        vertex is a part of its own), numbered in the order of their lowest vertex."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        n = self.n_vertices
        edges = coo_matrix(
            (np.ones(self.faces.size), (self.faces.reshape(-1), self.faces[:, [1, 2, 0]].reshape(-1))), (n, n)
        )
        return connected_components(edges, directed=False)[1].astype(np.int64)

    def self_intersecting_faces(self) -> np.ndarray:
        """→ (F,) bool: the faces that cross another face of the mesh (pymeshlab's per-face self-intersection test:
        faces sharing an edge never count, faces sharing only a vertex count when they pass through each other)."""
        import pymeshlab

        if len(self.faces) == 0:
            return np.zeros(0, dtype=bool)
        meshes = pymeshlab.MeshSet()
        meshes.add_mesh(pymeshlab.Mesh(self.vertices, self.faces))
        meshes.compute_selection_by_self_intersections_per_face()
        return meshes.current_mesh().face_selection_array().astype(bool)

    def submesh(self, keep: np.ndarray) -> tuple[SurfaceMesh, np.ndarray]:
        """keep (V,) bool → ``(mesh, index)``: the kept vertices (order and colours unchanged) with the faces whose
        three vertices are all kept, and ``index (V,) int64``, each vertex's index in that mesh or −1."""
        keep = np.asarray(keep, dtype=bool)
        index = np.full(self.n_vertices, -1, dtype=np.int64)
        index[keep] = np.arange(np.count_nonzero(keep))
        faces = index[self.faces[keep[self.faces].all(axis=1)]]
        colors = None if self.vertex_colors is None else self.vertex_colors[keep]
        return SurfaceMesh(self.vertices[keep], faces, colors), index

    def largest_component(self) -> SurfaceMesh:
        """→ the connected part (through shared vertices) with the most faces (of equal ones, the one of the lowest
        face), as a SurfaceMesh of ``V' ≤ V`` vertices; unused vertices dropped, the order of the kept ones
        unchanged."""
        labels = self.component_labels()
        face_labels = labels[self.faces[:, 0]]
        counts = np.bincount(face_labels)
        biggest = face_labels[np.flatnonzero(counts[face_labels] == counts.max())[0]]
        return self.submesh(labels == biggest)[0]

    # ---- conversions -------------------------------------------------------------------------
    def to_trimesh(self):
        """→ ``trimesh.Trimesh`` (``process=False``: vertex order and duplicates kept; colours as vertex colours)."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, vertex_colors=self.vertex_colors, process=False)

    @classmethod
    def from_trimesh(cls, mesh) -> SurfaceMesh:
        colors = None
        visual = getattr(mesh, "visual", None)
        if visual is not None and getattr(visual, "kind", None) == "vertex":
            colors = np.asarray(visual.vertex_colors)[:, :3] / 255.0
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.faces), colors)

    def to_open3d(self):
        """→ ``open3d.geometry.TriangleMesh`` (float64 vertices, int32 triangles, vertex colours when present)."""
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices), o3d.utility.Vector3iVector(self.faces.astype(np.int32))
        )
        if self.vertex_colors is not None:
            mesh.vertex_colors = o3d.utility.Vector3dVector(self.vertex_colors)
        return mesh

    @classmethod
    def from_open3d(cls, mesh) -> SurfaceMesh:
        colors = np.asarray(mesh.vertex_colors) if mesh.has_vertex_colors() else None
        return cls(np.asarray(mesh.vertices), np.asarray(mesh.triangles), colors)

    # ---- files -------------------------------------------------------------------------------
    @classmethod
    def load(cls, path: str | os.PathLike) -> SurfaceMesh:
        """Read PLY/OBJ/OFF/GLB/STL keeping the file's vertex order; ``sample:bunny`` names a shipped sample."""
        import trimesh

        path = resolve_mesh_path(path)
        if not path.is_file():
            raise NerfEditError(f"{path}: mesh file not found")
        if path.suffix.lower() == ".ply":
            try:
                fast = _read_ply_open3d(path)
            except NerfEditError as exc:  # bad values in the file: name it
                raise NerfEditError(f"{path}: {exc}") from exc
            if fast is not None:
                return fast
        try:
            try:  # keep the file's vertex order (OBJ otherwise splits/reorders vertices by texture coordinate)
                loaded = trimesh.load(path, process=False, force="mesh", maintain_order=True)
            except IndexError:  # trimesh cannot keep order for some textured OBJ files
                loaded = trimesh.load(path, process=False, force="mesh")
        except Exception as exc:  # trimesh raises many types for corrupt files
            raise NerfEditError(f"{path}: cannot read mesh ({exc})") from exc
        if not hasattr(loaded, "faces") or len(loaded.faces) == 0:
            raise NerfEditError(f"{path}: no triangles in file")
        try:
            return cls.from_trimesh(loaded)
        except NerfEditError as exc:  # bad values in the file: name it
            raise NerfEditError(f"{path}: {exc}") from exc

    def save(self, path: str | os.PathLike) -> None:
        """Write atomically; format from the suffix. PLY files hold the vertices in float64 (Open3D's writer:
        trimesh's is float32, which moves a vertex 1e5 from the origin by up to 4e-3)."""
        path = Path(path)
        kind = path.suffix.lstrip(".").lower()
        with atomic_path(path) as tmp:
            if kind != "ply":
                self.to_trimesh().export(tmp, file_type=kind)
            else:
                import open3d as o3d

                if not o3d.io.write_triangle_mesh(tmp, self.to_open3d(), write_ascii=False, write_vertex_normals=False):
                    raise NerfEditError(f"{path}: Open3D could not write the mesh")
