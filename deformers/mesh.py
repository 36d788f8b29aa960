"""The ``mesh`` deformer: the deformed mesh is given (edited in Blender or any tool keeping vertex order).

Spec: ``{"deformed": "edited.ply" | "poses/*.obj" | ["a.ply", "b.ply"], "frames": n}``. A list or glob gives one
frame per file (sorted); a single file with ``frames = n > 1`` is interpolated linearly from the rest pose.
Every file must have the rest mesh's vertex count and faces, else a NerfEditError names the file.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh


@dataclasses.dataclass
class MeshConfig(DeformerConfig):
    """Use deformed meshes made elsewhere (same vertex count and order as the rest mesh)."""

    _target: type = dataclasses.field(default_factory=lambda: MeshDeformer)
    check_faces: bool = True
    """Require identical faces (connectivity), not only the same vertex count."""


class MeshDeformer(Deformer):
    """Reads the deformed vertex positions from mesh files."""

    spec_keys = frozenset({"deformed"})
    config: MeshConfig

    def bind(self, rest: SurfaceMesh, edit: EditSpec) -> None:
        files = edit.paths("deformed")
        if len(files) > 1 and edit.frames_given and edit.frames != len(files):
            raise NerfEditError(
                f"{edit.source}: frames: {edit.frames} frame(s) but {len(files)} deformed meshes (leave frames out: "
                "one frame per mesh)"
            )
        poses = []
        for path in files:
            mesh = SurfaceMesh.load(path)
            if mesh.n_vertices != rest.n_vertices:
                raise NerfEditError(f"{path}: {mesh.n_vertices} vertices, the rest mesh has {rest.n_vertices}")
            if self.config.check_faces and not np.array_equal(mesh.faces, rest.faces):
                raise NerfEditError(f"{path}: connectivity differs from the rest mesh (faces are not identical)")
            poses.append(mesh.vertices)
        if len(poses) == 1:
            t = edit.times[:, None, None]
            self._frames = (1 - t) * rest.vertices + t * poses[0]
        else:
            self._frames = np.stack(poses)

    def deform(self) -> np.ndarray:
        return self._frames.copy()

    @classmethod
    def placed_edit(cls, edit: dict, scale: float, offset: np.ndarray, base_dir: Path, folder: Path) -> dict:
        """Conformance-kit hook: the deformed meshes, placed into ``folder``."""
        from nerfedit_plugin.testing.deformers import placed_mesh_files

        placed_mesh_files(edit["deformed"], scale, offset, base_dir, folder)
        return edit
