"""The ``skeleton`` deformer: skin the rest mesh to a skeleton and pose it (dual-quaternion or linear blend skinning).

Spec: ``{"skeleton": "skeleton.json" | "walk.bvh", "pose": {"<joint>": {"rotate": {"axis": [x,y,z], "degrees": d},
"translate": [x,y,z]}}, "weights": "weights.npy", "frames": n}`` (``pose`` and ``weights`` optional). Each joint is
one bone (segment head → tail); a pose rotates joints about their heads and composes down the hierarchy; a BVH
without a pose plays its clip. Weights: ``weights.npy (V, joints)`` float, else bone heat
(:mod:`deformers.skeleton.heat_weights`). :meth:`SkeletonDeformer.deform_points` skins a point off the surface with the
weights of its closest surface point. Skeleton JSON, BVH and pose rules: docs/architecture.md, "Edit spec".
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from deformers.skeleton.bvh import BvhClip, parse_bvh, placed_bvh
from deformers.skeleton.editing import SkeletonBackend
from deformers.skeleton.heat_weights import bone_heat_weights
from deformers.skeleton.skinning import Binding, normalize_weights, skin
from nerfedit_plugin.edit.coarse import CoarseOptions, cached_coarse_level
from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.edit.spec import EditSpec, check_keys, vector
from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_path


def closest_point_barycentrics(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates ``(M,3)`` of the closest point to ``p`` on triangle ``abc``, in float64.

    Ericson, *Real-Time Collision Detection* §5.1.5 (vertex, edge and face Voronoi regions), so a point on a vertex
    gets exactly that vertex's coordinates. Zero-area triangles give their nearest corner.
    """
    ab, ac = b - a, c - a
    d1, d2 = np.sum(ab * (p - a), 1), np.sum(ac * (p - a), 1)
    d3, d4 = np.sum(ab * (p - b), 1), np.sum(ac * (p - b), 1)
    d5, d6 = np.sum(ab * (p - c), 1), np.sum(ac * (p - c), 1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    zero, one = np.zeros(len(p)), np.ones(len(p))
    with np.errstate(divide="ignore", invalid="ignore"):
        v, w = vb / (va + vb + vc), vc / (va + vb + vc)
        s_ab, s_ac = d1 / (d1 - d3), d2 / (d2 - d6)
        s_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out = np.stack([1.0 - v - w, v, w], axis=1)  # face region; later regions take priority
        regions = [
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), (zero, 1 - s_bc, s_bc)),  # edge BC
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), (1 - s_ac, zero, s_ac)),  # edge AC
            ((d6 >= 0) & (d5 <= d6), (zero, zero, one)),  # vertex C
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), (1 - s_ab, s_ab, zero)),  # edge AB
            ((d3 >= 0) & (d4 <= d3), (zero, one, zero)),  # vertex B
            ((d1 <= 0) & (d2 <= 0), (one, zero, zero)),  # vertex A
        ]
        for mask, value in regions:
            out[mask] = np.stack(value, axis=1)[mask]
    bad = ~np.isfinite(out).all(1)
    if bad.any():
        corner = np.argmin(np.stack([np.sum((p - q) ** 2, 1) for q in (a, b, c)], 1)[bad], 1)
        out[bad] = np.eye(3)[corner]
    return np.clip(out, 0.0, 1.0)


@dataclass(frozen=True)
class Skeleton:
    """Joints (one bone each, ``heads[j] → tails[j]``) in rest space; ``parents[j] = -1`` for roots."""

    names: tuple[str, ...]
    parents: np.ndarray
    heads: np.ndarray
    tails: np.ndarray
    order: tuple[int, ...]
    """Joint indices with every parent before its children."""
    source: str

    @classmethod
    def build(cls, names: list[str], parents: list[int], heads: np.ndarray, tails: np.ndarray, source: str) -> Skeleton:
        """Validate names and hierarchy; NaN rows of ``tails`` get the default (children's mean head, else head)."""
        seen: dict[str, int] = {}
        for j, name in enumerate(names):
            if name in seen:
                raise NerfEditError(f"{source}: joints[{j}]: duplicate joint name {name!r} (also joints[{seen[name]}])")
            seen[name] = j
        parents_arr = np.asarray(parents, dtype=np.int64)
        children: list[list[int]] = [[] for _ in names]
        for j, parent in enumerate(parents_arr):
            if parent >= 0:
                children[parent].append(j)
        order, stack = [], [j for j, parent in enumerate(parents_arr) if parent < 0][::-1]
        while stack:
            j = stack.pop()
            order.append(j)
            stack.extend(children[j][::-1])
        if len(order) < len(names):
            placed = set(order)
            loop = [next(k for k in range(len(names)) if k not in placed)]
            while parents_arr[loop[-1]] not in loop:
                loop.append(int(parents_arr[loop[-1]]))
            cycle = loop[loop.index(int(parents_arr[loop[-1]])) :]
            path = " → ".join(names[k] for k in cycle + [cycle[0]])
            raise NerfEditError(f"{source}: joints: parent cycle {path} (the hierarchy must be a tree)")
        tails = np.array(tails, dtype=np.float64)
        for j in range(len(names)):
            if np.isnan(tails[j]).any():
                tails[j] = heads[children[j]].mean(0) if children[j] else heads[j]
        return cls(tuple(names), parents_arr, np.asarray(heads, dtype=np.float64), tails, tuple(order), source)

    @classmethod
    def from_json(cls, path: Path) -> Skeleton:
        source = str(path)
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:  # ValueError: bad UTF-8, bad JSON, an integer of > 4300 digits
            raise NerfEditError(f"{source}: cannot parse skeleton JSON ({exc})".replace("\n", " ")) from exc
        check_keys(data, {"joints"}, source, "skeleton")
        joints = data.get("joints")
        if not isinstance(joints, list) or not joints:
            raise NerfEditError(f"{source}: joints: expected a non-empty list of joints")
        names, parent_names, heads, tails = [], [], [], []
        for j, joint in enumerate(joints):
            key = f"joints[{j}]"
            check_keys(joint, {"name", "parent", "head", "tail"}, source, key, required=("name", "head"))
            if not isinstance(joint["name"], str) or not joint["name"]:
                raise NerfEditError(f"{source}: {key}.name: expected a non-empty string, got {joint['name']!r}")
            parent = joint.get("parent")
            if parent is not None and not isinstance(parent, str):
                raise NerfEditError(f"{source}: {key}.parent: expected a joint name or null, got {parent!r}")
            names.append(joint["name"])
            parent_names.append(parent)
            heads.append(vector(joint["head"], source, f"{key}.head"))
            tails.append(vector(joint["tail"], source, f"{key}.tail") if "tail" in joint else np.full(3, np.nan))
        index = {name: j for j, name in enumerate(names)}
        parents = []
        for j, parent in enumerate(parent_names):
            if parent is not None and parent not in index:
                raise NerfEditError(f"{source}: joints[{j}].parent: unknown joint {parent!r}")
            parents.append(-1 if parent is None else index[parent])
        return cls.build(names, parents, np.asarray(heads), np.asarray(tails), source)

    @classmethod
    def from_bvh(cls, clip: BvhClip) -> Skeleton:
        heads = clip.heads
        return cls.build(list(clip.names), list(clip.parents), heads, heads + clip.end_sites, clip.source)

    def forward_kinematics(self, rot: np.ndarray, trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bone maps ``x ↦ R x + t`` (``(F,J,3,3)``, ``(F,J,3)``) from local rotations about the heads + translations.

        Local map of joint j: ``L_j(x) = h_j + R_j (x − h_j) + t_j``; global ``G_j = G_parent ∘ L_j``.
        """
        glob_rot, glob_trans = np.empty_like(rot), np.empty_like(trans)
        for j in self.order:
            head = self.heads[j]
            local_trans = head - rot[:, j] @ head + trans[:, j]
            parent = self.parents[j]
            if parent < 0:
                glob_rot[:, j], glob_trans[:, j] = rot[:, j], local_trans
            else:
                glob_rot[:, j] = glob_rot[:, parent] @ rot[:, j]
                glob_trans[:, j] = np.einsum("fik,fk->fi", glob_rot[:, parent], local_trans) + glob_trans[:, parent]
        return glob_rot, glob_trans

    def parse_pose(self, pose: Any, source: str) -> tuple[np.ndarray, np.ndarray]:
        """Per-joint rotation vectors and translations ``(J,3)`` from a spec's ``pose`` mapping."""
        if not isinstance(pose, dict):
            raise NerfEditError(f"{source}: pose: expected a mapping of joint names, got {type(pose).__name__}")
        rotvec, trans = np.zeros((len(self.names), 3)), np.zeros((len(self.names), 3))
        for name, item in pose.items():
            key = f"pose.{name}"
            if name not in self.names:
                raise NerfEditError(
                    f"{source}: {key}: unknown joint (the skeleton {self.source} has {list(self.names)})"
                )
            j = self.names.index(name)
            check_keys(item, {"rotate", "translate"}, source, key)
            if not item:
                raise NerfEditError(f"{source}: {key}: empty transform (give rotate and/or translate)")
            if "translate" in item:
                trans[j] = vector(item["translate"], source, f"{key}.translate")
            if "rotate" in item:
                required = ("axis", "degrees")
                rot = check_keys(item["rotate"], required, source, f"{key}.rotate", required=required)
                axis = vector(rot["axis"], source, f"{key}.rotate.axis")
                degrees = rot["degrees"]
                try:
                    ok = not isinstance(degrees, bool) and isinstance(degrees, (int, float)) and math.isfinite(degrees)
                except OverflowError:  # an integer beyond float range
                    ok = False
                if not ok:
                    raise NerfEditError(f"{source}: {key}.rotate.degrees: expected a finite number, got {degrees!r}")
                if not np.linalg.norm(axis) > 0:
                    raise NerfEditError(f"{source}: {key}.rotate.axis: is the zero vector")
                rotvec[j] = axis / np.linalg.norm(axis) * math.radians(degrees)
        return rotvec, trans


def load_skeleton(path: Path) -> tuple[Skeleton, BvhClip | None]:
    """A skeleton from ``.json`` or ``.bvh`` (then also its clip)."""
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        clip = parse_bvh(path)
        return Skeleton.from_bvh(clip), clip
    if suffix == ".json":
        return Skeleton.from_json(path), None
    raise NerfEditError(f"{path}: unknown skeleton format {suffix!r} (expected .json or .bvh)")


@dataclasses.dataclass
class SkeletonConfig(DeformerConfig, CoarseOptions):
    """Pose a skeleton (JSON joints or BVH) and skin the mesh to it, with automatic bone-heat weights."""

    _target: type = dataclasses.field(default_factory=lambda: SkeletonDeformer)
    method: Literal["dqs", "lbs"] = "dqs"
    """Skinning: dual quaternions (rigid blends, twists keep volume) or linear blend (collapses on twists)."""
    heat_bones: int = 1
    """Bones heating each vertex in the bone-heat solve: its k nearest (visible) ones, ties included (paper: 1)."""
    visibility: bool = True
    """Only bones visible from a vertex (the segment to the bone stays inside the mesh) heat it (Open3D rays)."""
    heat_strength: float = 1.0
    """c in H_ii = k c / d_i²: larger keeps weights closer to the nearest-bone assignment (paper: 1)."""
    weight_threshold: float = 1e-3
    """Weights below this are dropped (never a vertex's largest) and rows renormalised to sum 1."""

    def __post_init__(self) -> None:
        check_option(self, "heat_bones", self.heat_bones, self.heat_bones >= 1, ">= 1")
        check_option(self, "heat_strength", self.heat_strength, 0 < self.heat_strength < math.inf, "a number > 0")
        check_option(self, "weight_threshold", self.weight_threshold, 0 <= self.weight_threshold < 1, "in [0, 1)")
        self.check_coarse_options()


class SkeletonDeformer(Deformer):
    """Skeleton skinning; defined in space, so it also maps arbitrary points (``deform_points``)."""

    spec_keys = frozenset({"skeleton", "pose", "weights"})
    editor = SkeletonBackend
    config: SkeletonConfig

    def bind(self, rest: SurfaceMesh, edit: EditSpec) -> None:
        cfg = self.config
        skeleton, clip = load_skeleton(edit.path("skeleton"))
        local_rot, local_trans = self._local_transforms(skeleton, clip, edit)
        self.level, self.level_cached = None, False
        if "weights" in edit.extra:
            weights = self._read_weights(edit.path("weights"), rest, skeleton)
        else:
            weights = self._heat_weights(rest, skeleton)
        self.skeleton, self.rest = skeleton, rest
        self.weights_source = "file" if "weights" in edit.extra else "bone heat"
        self.binding = Binding.create(rest.vertices, normalize_weights(weights, cfg.weight_threshold))
        self.rot, self.trans = skeleton.forward_kinematics(local_rot, local_trans)
        self._scene = None
        self._cached: tuple[np.ndarray, Binding] | None = None

    def _heat_weights(self, rest: SurfaceMesh, skeleton: Skeleton) -> np.ndarray:
        """Bone heat on ``rest``, or (:meth:`CoarseOptions.binds_coarse`) on its coarse level, blended to each fine
        vertex by the barycentrics of its closest coarse point (rows still sum to 1; a rigid pose stays rigid)."""
        cfg = self.config
        surface = rest
        if cfg.binds_coarse(rest):
            self.on_progress(0, None, "coarse level")
            self.level, self.level_cached = cached_coarse_level(self.bind_cache, rest, cfg.coarse_vertices)
            surface = self.level.coarse
        weights = bone_heat_weights(
            surface.vertices,
            surface.faces,
            skeleton.heads,
            skeleton.tails,
            nearest=cfg.heat_bones,
            visibility=cfg.visibility,
            strength=cfg.heat_strength,
            progress=self.on_progress,
        )
        if self.level is None or self.level.is_identity:
            return weights
        corners, blend = self.level.corners, self.level.weights
        fine = blend[:, :1] * weights[corners[:, 0]]
        for c in (1, 2):
            fine += blend[:, c : c + 1] * weights[corners[:, c]]
        return fine

    def report(self) -> dict:
        """``weights`` (``file`` or ``bone heat``) and ``path`` (``direct``, or ``multiresolution``: the heat solved on
        a coarse level, whose ``coarse`` gives ``vertices``, ``faces`` and ``cached``: read from the bind cache)."""
        report = {
            "weights": self.weights_source,
            "path": "direct" if self.level is None else "multiresolution",
        }
        if self.level is not None:
            coarse = self.level.coarse
            report["coarse"] = {"vertices": coarse.n_vertices, "faces": len(coarse.faces), "cached": self.level_cached}
        return report

    @classmethod
    def identity_edit(cls, edit: dict, rest: SurfaceMesh) -> dict | None:
        """Conformance-kit hook: ``edit`` with every posed joint given a zero translation (None without a pose)."""
        if not isinstance(edit.get("pose"), dict):
            return None
        return {**edit, "pose": {name: {"translate": [0.0, 0.0, 0.0]} for name in edit["pose"]}}

    @classmethod
    def placed_edit(cls, edit: dict, scale: float, offset: np.ndarray, base_dir: Path, folder: Path) -> dict:
        """Conformance-kit hook: the skeleton file (JSON joint heads and tails; BVH offsets and position channels)
        placed into ``folder``, the weights file copied, pose translations scaled."""
        source, target = Path(base_dir) / edit["skeleton"], Path(folder) / edit["skeleton"]
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.suffix.lower() == ".bvh":
            target.write_text(placed_bvh(source.read_text(), scale, offset))
        else:
            data = json.loads(source.read_text())
            for joint in data["joints"]:
                for end in ("head", "tail"):
                    if end in joint:
                        joint[end] = (scale * np.asarray(joint[end], dtype=np.float64) + offset).tolist()
            target.write_text(json.dumps(data))
        if "weights" in edit:
            (Path(folder) / edit["weights"]).write_bytes((Path(base_dir) / edit["weights"]).read_bytes())
        pose = {
            name: {**item, "translate": (scale * np.asarray(item["translate"], dtype=np.float64)).tolist()}
            if "translate" in item
            else item
            for name, item in edit.get("pose", {}).items()
        }
        return {**edit, "pose": pose} if "pose" in edit else edit

    @staticmethod
    def _local_transforms(skeleton: Skeleton, clip: BvhClip | None, edit: EditSpec) -> tuple[np.ndarray, np.ndarray]:
        if "pose" in edit.extra:
            rotvec, trans = skeleton.parse_pose(edit.extra["pose"], edit.source)
            t = edit.times[:, None, None]
            rot = Rotation.from_rotvec((t * rotvec).reshape(-1, 3)).as_matrix().reshape(len(t), -1, 3, 3)
            return rot, t * trans
        if clip is None:
            raise NerfEditError(f"{edit.source}: pose: missing (a JSON skeleton needs a pose)")
        if clip.n_frames == 0:
            raise NerfEditError(f"{edit.source}: pose: missing, and {clip.source} has no motion frames")
        return clip.local_transforms(edit.frames if edit.frames_given else None)

    @staticmethod
    def _read_weights(path: Path, rest: SurfaceMesh, skeleton: Skeleton) -> np.ndarray:
        try:
            weights = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise NerfEditError(f"{path}: cannot read weights ({exc})") from exc
        expected = (rest.n_vertices, len(skeleton.names))
        if weights.shape != expected:
            raise NerfEditError(
                f"{path}: weights shape {weights.shape}, expected {expected} "
                f"(mesh vertices × joints of {skeleton.source})"
            )
        if not np.issubdtype(weights.dtype, np.number) or not np.isfinite(weights).all():
            raise NerfEditError(f"{path}: weights must be finite numbers")
        if (weights < 0).any():
            raise NerfEditError(f"{path}: negative weight at vertex {int(np.argwhere(weights < 0)[0, 0])}")
        empty = np.flatnonzero(weights.sum(1) <= 0)
        if empty.size:
            raise NerfEditError(f"{path}: vertex {int(empty[0])} has all-zero weights")
        return weights.astype(np.float64)

    @property
    def n_frames(self) -> int:
        return len(self.rot)

    @property
    def weights(self) -> np.ndarray:
        """Skinning weights of the rest vertices ``(V, joints)``, rows summing to 1."""
        return self.binding.weights

    def deform(self) -> np.ndarray:
        frames, what = [], f"skinning ({self.config.method})"
        for f in range(self.n_frames):
            self.on_progress(f, self.n_frames, what)
            frames.append(self._skin(self.binding, f))
        self.on_progress(self.n_frames, self.n_frames, what)
        return np.stack(frames)

    def deform_points(self, points: np.ndarray, frame: int) -> np.ndarray:
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"points: expected shape (M, 3), got {points.shape}")
        if not 0 <= frame < self.n_frames:
            raise IndexError(f"frame {frame} out of range for {self.n_frames} frames")
        if self._cached is None or not np.array_equal(self._cached[0], points):
            self._cached = (points.copy(), Binding.create(points, self.point_weights(points)))
        return self._skin(self._cached[1], frame)

    def point_weights(self, points: np.ndarray) -> np.ndarray:
        """Weights of arbitrary points: the vertex weights interpolated at the nearest surface point ``(M,J)``."""
        if self._scene is None:
            self._scene = raycast.raycasting_scene(self.rest.vertices, self.rest.faces)
        triangle, _ = raycast.closest_points(self._scene, points)  # Open3D's float32 barycentrics: recomputed exactly
        tri = self.rest.faces[triangle]
        corners = self.rest.vertices[tri]
        bary = closest_point_barycentrics(points, corners[:, 0], corners[:, 1], corners[:, 2])
        return np.einsum("mk,mkj->mj", bary, self.weights[tri])

    def _skin(self, binding: Binding, frame: int) -> np.ndarray:
        return skin(binding, self.rot[frame], self.trans[frame], self.config.method)

    def write_artifacts(self, out_dir: Path) -> list[Path]:
        """Save the skinning weights used (``skin_weights.npy``, V × joints) so they can be edited and reused."""
        path = Path(out_dir) / "skin_weights.npy"
        with atomic_path(path) as tmp:
            np.save(tmp, self.weights)
        return [path]
