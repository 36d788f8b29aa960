"""The skeleton deformer in the editor: a handle is one joint, turned (and moved) about its head; the deformer is
bound once (the skinning weights) and each preview re-poses it through its ``rot`` / ``trans`` (forward kinematics
of the pose). The bones are drawn as the ``skeleton`` layer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.deformer import DeformerConfig
from nerfedit_plugin.edit.editing import EditingBackend, EditorHandle, bind_deformer
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh


class SkeletonBackend(EditingBackend):
    """A handle is one joint of the skeleton (``keys["skeleton"]``, a JSON or BVH file's absolute path), turned and
    moved about its head: the spec's ``pose``."""

    what, scales, own_keys, layer = "joints", False, ("skeleton", "weights"), "skeleton"

    def __init__(self, rest: SurfaceMesh, config: DeformerConfig, keys: dict) -> None:
        if "skeleton" not in keys:
            raise NerfEditError("skeleton: give the skeleton to pose (nerfedit view --skeleton SKELETON.json)")
        self.model = bind_deformer(config, rest, {**keys, "pose": {}})
        self.skeleton = self.model.skeleton
        self.points, self.faces = self.skeleton.heads, None
        super().__init__(rest, config, keys)

    def check_handle(self, indices: np.ndarray, fixed: bool) -> None:
        if fixed or len(indices) != 1:
            raise NerfEditError("mark: a skeleton handle is one moving joint (joints not posed keep their rest pose)")

    def spec_data(self, handles: tuple[EditorHandle, ...], selects: list[dict], folder: Path | None) -> dict:
        out = self.own_spec(folder)
        out["pose"] = {
            self.skeleton.names[h.indices[0]]: {
                "rotate": h.rotate_spec,
                "translate": [float(v) for v in h.translate],
            }
            for h in handles
        }
        return out

    def handles_of(self, spec: EditSpec) -> tuple[EditorHandle, ...]:
        rotvec, trans = self.skeleton.parse_pose(spec.extra.get("pose", {}), spec.source)
        chosen = [self.skeleton.names.index(name) for name in spec.extra.get("pose", {})]
        return tuple(EditorHandle(np.array([j]), False, self.points[j], trans[j], rotvec[j]) for j in chosen)

    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        rotvec, trans = self.skeleton.parse_pose(spec.extra["pose"], spec.source)
        t = spec.times[frame]
        rot = Rotation.from_rotvec(t * rotvec).as_matrix()[None]
        self.model.rot, self.model.trans = self.skeleton.forward_kinematics(rot, t * trans[None])
        self.posed = np.einsum("jik,jk->ji", self.model.rot[0], self.points) + self.model.trans[0]
        return self.model.deform()[0]

    def lines(self) -> tuple[np.ndarray, np.ndarray]:
        tails = np.einsum("jik,jk->ji", self.model.rot[0], self.skeleton.tails) + self.model.trans[0]
        n = len(self.points)
        return np.concatenate([self.posed, tails]), np.column_stack([np.arange(n), n + np.arange(n)])
