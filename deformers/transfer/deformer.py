"""Transfer deformer: replay a source mesh's pose sequence on the rest mesh (deformation transfer).

Spec (besides ``frames``)::

    {"source_rest": "rest.obj",                       # the source in its rest pose (OBJ/PLY/…)
     "source_frames": "poses/*.obj",                  # a glob, a list of files, one file, or one .npz (F, V_s, 3)
     "markers": [[12, 803], [[0, 0, 1], [0.1, 0.2, 0.9]]],   # [source vertex, target vertex]; a 3-D point snaps
     "correspondence": "transfer_correspondence.npz"} # optional: a correspondence saved by an earlier edit

Every pose file has the source rest mesh's vertex count and faces. The same faces on both meshes and no markers
give the identity correspondence; otherwise :mod:`deformers.transfer.correspondence` fits the source onto the
target. :class:`deformers.transfer.gradients.TransferSystem` factors the normal equations once in ``bind``; each
pose is one back-substitution. One pose with ``frames = n > 1`` is interpolated linearly from the source rest.
"""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import tyro

from deformers.transfer.correspondence import Correspondence, correspondence, load_correspondence, save_correspondence
from deformers.transfer.gradients import TransferSystem, check_determined
from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig, Overlay
from nerfedit_plugin.edit.spec import EditSpec, spec_error, vector
from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.geometry.mesh import SurfaceMesh

ARTIFACTS = {
    "correspondence": "transfer_correspondence.npz",
    "source": "transfer_source.ply",
    "target": "transfer_target.ply",
}
"""Files :meth:`TransferDeformer.write_artifacts` writes: the correspondence (reusable as the spec's
``correspondence``), the fitted source and the target with faces coloured by corresponding source triangle."""


@dataclasses.dataclass
class TransferConfig(DeformerConfig):
    """Deformation transfer: replay a source mesh's pose sequence on this mesh (Sumner & Popović 2004).

    The source's per-triangle deformation gradients are matched on corresponding target triangles in the least
    squares sense; source and target may have different connectivity (give a few marker pairs)."""

    _target: tyro.conf.Suppress[type] = dataclasses.field(default_factory=lambda: TransferDeformer)
    smoothness_weight: float = 1.0
    """Correspondence fit: weight w_S of the smoothness term (gradients of adjacent source triangles alike)."""
    identity_weight: float = 0.001
    """Correspondence fit: weight w_I of the identity term (gradients close to the identity)."""
    closest_weights: tuple[float, ...] = (0.0, 1.0, 17.0, 290.0, 5000.0)
    """Correspondence fit: the ramp of closest-point weights w_C, one linear solve per value (0: markers only)."""
    match_distance: float = 0.05
    """Correspondence: farthest centroid distance of two matched triangles, in target bounding-box diagonals."""

    def __post_init__(self) -> None:
        check_option(self, "smoothness_weight", self.smoothness_weight, self.smoothness_weight > 0, "> 0")
        check_option(self, "identity_weight", self.identity_weight, self.identity_weight > 0, "> 0")
        weights = tuple(self.closest_weights)
        ramp = len(weights) > 0 and all(w >= 0 and np.isfinite(w) for w in weights)
        check_option(self, "closest_weights", weights, ramp, "a non-empty sequence of finite numbers >= 0")
        check_option(self, "match_distance", self.match_distance, self.match_distance > 0, "> 0")


class TransferDeformer(Deformer):
    """Binds a source sequence to the rest mesh; ``source``, ``correspondence`` and ``poses (F, V_s, 3)`` are set
    by :meth:`bind`."""

    spec_keys = frozenset({"source_rest", "source_frames", "markers", "correspondence"})
    config: TransferConfig

    def __init__(self, config: TransferConfig) -> None:
        super().__init__(config)
        self.source: SurfaceMesh | None = None
        self.target: SurfaceMesh | None = None
        self.correspondence: Correspondence | None = None
        self.poses: np.ndarray | None = None
        self.system: TransferSystem | None = None

    def bind(self, rest: SurfaceMesh, edit: EditSpec) -> None:
        source = _load(edit, "source_rest", edit.path("source_rest"))
        poses = _poses(edit, source)
        markers = _markers(edit, source, rest)
        if len(poses) == 1 and edit.frames > 1:
            t = edit.times[:, None, None]
            poses = (1.0 - t) * source.vertices + t * poses[0]
        elif edit.frames_given and edit.frames != len(poses):
            raise spec_error(edit.source, "frames", f"{edit.frames} frames but source_frames gives {len(poses)} poses")
        if "correspondence" in edit.extra:
            corr = load_correspondence(edit.path("correspondence"), source, rest, f"{edit.source}: correspondence")
        else:
            cfg = self.config
            corr = correspondence(
                source,
                rest,
                markers,
                cfg.smoothness_weight,
                cfg.identity_weight,
                tuple(cfg.closest_weights),
                cfg.match_distance,
                f"{edit.source}: markers",
            )
        key = "correspondence" if "correspondence" in edit.extra else "markers"
        check_determined(source, rest, corr.pairs, f"{edit.source}: {key}")
        self.source, self.target, self.correspondence, self.poses = source, rest, corr, poses
        self.system = TransferSystem(source, rest, corr.pairs)

    def deform(self) -> np.ndarray:
        if self.system is None:
            raise RuntimeError("TransferDeformer.deform() called before bind()")
        return np.stack([self.system.transfer(pose) for pose in self.poses])

    # ---- inspection ------------------------------------------------------------------------------------------------
    def write_artifacts(self, out_dir: Path) -> list[Path]:
        """Write :data:`ARTIFACTS`: the correspondence and two PLYs whose faces are coloured by source triangle
        (the fitted source, and the target coloured by its first corresponding source triangle)."""
        out_dir = Path(out_dir)
        paths = [out_dir / name for name in ARTIFACTS.values()]
        save_correspondence(paths[0], self.correspondence, self.source, self.target)
        colours = _triangle_colours(self.source)
        _face_coloured(self.correspondence.fitted, self.source.faces, colours).save(paths[1])
        pairs = self.correspondence.pairs
        first = np.unique(pairs[:, 1], return_index=True)[1]
        target_colours = np.full((len(self.target.faces), 3), 0.5)
        target_colours[pairs[first, 1]] = colours[pairs[first, 0]]
        _face_coloured(self.target.vertices, self.target.faces, target_colours).save(paths[2])
        return paths

    @classmethod
    def overlays(cls, edit_dir: Path, frame: int) -> list[Overlay]:
        """The source fitted onto the target (wire), as :meth:`write_artifacts` wrote it."""
        path = Path(edit_dir) / ARTIFACTS["source"]
        return [Overlay("correspondence", SurfaceMesh.load(path))] if path.is_file() else []

    # ---- conformance-kit hooks -------------------------------------------------------------------------------------
    @classmethod
    def identity_edit(cls, edit: dict, rest: SurfaceMesh) -> dict:
        """The source rest mesh as the only pose."""
        return {**edit, "source_frames": edit["source_rest"]}

    @classmethod
    def placed_edit(cls, edit: dict, scale: float, offset: np.ndarray, base_dir: Path, folder: Path) -> dict:
        """Conformance-kit hook: the source files (meshes, or a ``.npz`` of poses) placed into ``folder``, marker
        points placed, a saved correspondence copied."""
        from nerfedit_plugin.testing.deformers import placed_mesh_files

        base_dir, folder = Path(base_dir), Path(folder)
        placed_mesh_files(edit["source_rest"], scale, offset, base_dir, folder)
        frames = edit["source_frames"]
        if isinstance(frames, str) and frames.lower().endswith(".npz"):
            with np.load(base_dir / frames) as data:
                placed = {key: scale * data[key] + offset for key in data.files}
            (folder / frames).parent.mkdir(parents=True, exist_ok=True)
            np.savez(folder / frames, **placed)
        elif frames != edit["source_rest"]:
            placed_mesh_files(frames, scale, offset, base_dir, folder)
        if "correspondence" in edit:
            (folder / edit["correspondence"]).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(base_dir / edit["correspondence"], folder / edit["correspondence"])
        edit["markers"] = [
            [
                end if isinstance(end, int) else (scale * np.asarray(end, dtype=np.float64) + offset).tolist()
                for end in pair
            ]
            for pair in edit.get("markers", [])
        ]
        return edit


# ---- reading the spec ----------------------------------------------------------------------------------------------
def _load(edit: EditSpec, key: str, path: Path) -> SurfaceMesh:
    """The mesh file ``path`` named by ``key``; errors name the spec, the key and the file."""
    try:
        return SurfaceMesh.load(path)
    except NerfEditError as exc:
        message = str(exc) if str(path) in str(exc) else f"{path}: {exc}"
        raise NerfEditError(f"{edit.source}: {key}: {message}") from None


def _poses(edit: EditSpec, source: SurfaceMesh) -> np.ndarray:
    """``source_frames`` → ``(F, V_s, 3)`` float64: mesh files with the source rest's vertex count and faces, or one
    ``.npz`` holding ``frames`` (or a single array) of that shape."""
    files = edit.paths("source_frames")
    where = f"{edit.source}: source_frames"
    if len(files) == 1 and files[0].suffix.lower() == ".npz":
        return _npz_poses(files[0], source, where)
    poses = []
    for path in files:
        mesh = _load(edit, "source_frames", path)
        if mesh.n_vertices != source.n_vertices:
            raise NerfEditError(f"{where}: {path}: {mesh.n_vertices} vertices, source_rest has {source.n_vertices}")
        if len(mesh.faces) != len(source.faces):
            raise NerfEditError(f"{where}: {path}: {len(mesh.faces)} faces, source_rest has {len(source.faces)}")
        differ = np.flatnonzero(np.any(mesh.faces != source.faces, axis=1))
        if differ.size:
            f = int(differ[0])
            raise NerfEditError(
                f"{where}: {path}: connectivity differs from source_rest: face {f} is {mesh.faces[f].tolist()}, "
                f"source_rest has {source.faces[f].tolist()} ({differ.size} faces differ)"
            )
        poses.append(mesh.vertices)
    return np.stack(poses)


def _npz_poses(path: Path, source: SurfaceMesh, where: str) -> np.ndarray:
    try:
        with np.load(path, allow_pickle=False) as data:
            if "frames" not in data.files and len(data.files) != 1:
                raise NerfEditError(
                    f"{where}: {path}: expected an array 'frames' (or a single array), got {data.files}"
                )
            poses = np.asarray(data["frames" if "frames" in data.files else data.files[0]], dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise NerfEditError(f"{where}: {path}: cannot read ({exc})") from None
    if poses.ndim != 3 or poses.shape[1:] != (source.n_vertices, 3) or not len(poses):
        raise NerfEditError(
            f"{where}: {path}: poses of shape {poses.shape}, expected (frames, {source.n_vertices}, 3) for source_rest"
        )
    bad = np.flatnonzero(~np.isfinite(poses).all(axis=(1, 2)))
    if bad.size:
        raise NerfEditError(f"{where}: {path}: frame {int(bad[0])} contains NaN or Inf")
    return poses


def _markers(edit: EditSpec, source: SurfaceMesh, target: SurfaceMesh) -> np.ndarray:
    """``markers`` → ``(M, 2)`` int64 (source vertex, target vertex); a 3-D point snaps to the nearest vertex."""
    value = edit.extra.get("markers", [])
    if not isinstance(value, list):
        raise spec_error(edit.source, "markers", f"expected a list of [source, target] pairs, got {value!r:.100}")
    out, seen = [], {}
    for i, pair in enumerate(value):
        key = f"markers[{i}]"
        if not isinstance(pair, list) or len(pair) != 2:
            raise spec_error(
                edit.source, key, f"expected [source, target] (vertex indices or points), got {pair!r:.100}"
            )
        ends = [
            _marker_vertex(end, mesh, edit.source, f"{key}[{side}]", name)
            for side, (end, mesh, name) in enumerate(zip(pair, (source, target), ("source_rest", "the rest mesh")))
        ]
        if ends[0] in seen:
            raise spec_error(edit.source, f"{key}[0]", f"source vertex {ends[0]} is already marker {seen[ends[0]]}")
        seen[ends[0]] = i
        out.append(ends)
    return np.asarray(out, dtype=np.int64).reshape(-1, 2)


def _marker_vertex(value, mesh: SurfaceMesh, source: str, key: str, name: str) -> int:
    if isinstance(value, int) and not isinstance(value, bool):
        if not 0 <= value < mesh.n_vertices:
            raise spec_error(source, key, f"vertex {value} out of range ({name} has {mesh.n_vertices} vertices)")
        return value
    point = vector(value, source, key)
    return int(np.argmin(np.linalg.norm(mesh.vertices - point, axis=1)))


# ---- artifacts -----------------------------------------------------------------------------------------------------
def _triangle_colours(mesh: SurfaceMesh) -> np.ndarray:
    """(F,3) colours in [0,1]: each triangle's centroid in the mesh's bounding box, as RGB."""
    centres = mesh.vertices[mesh.faces].mean(1)
    lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
    return (centres - lo) / np.where(hi > lo, hi - lo, 1.0)


def _face_coloured(vertices: np.ndarray, faces: np.ndarray, colours: np.ndarray) -> SurfaceMesh:
    """A mesh with one colour per face: each face gets its own three vertices."""
    corners = np.arange(3 * len(faces)).reshape(-1, 3)
    return SurfaceMesh(vertices[faces].reshape(-1, 3), corners, np.repeat(colours, 3, axis=0))
