"""The cage deformer in the editor: handles on the cage's vertices (``"cage": "auto"`` or a cage file); the deformer
is bound once (the cage and the coordinates of every mesh vertex) and each preview re-poses it through its
``deformed_cages``. The cage is drawn as the ``cage`` layer."""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.edit.deformer import DeformerConfig
from nerfedit_plugin.edit.editing import EditingBackend, bind_deformer
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.geometry.mesh import SurfaceMesh


class CageBackend(EditingBackend):
    """Handles on the cage's vertices (``keys["cage"]``: ``"auto"`` or a cage file's absolute path)."""

    what, own_keys, layer = "cage vertices", ("cage",), "cage"

    def __init__(self, rest: SurfaceMesh, config: DeformerConfig, keys: dict) -> None:
        keys = {"cage": "auto", **keys}
        self.model = bind_deformer(config, rest, {**keys, "handles": [{"select": {"indices": [0]}, "fixed": True}]})
        self.points, self.faces = self.model.rest_cage.vertices, self.model.rest_cage.faces
        super().__init__(rest, config, keys)

    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        indices, targets = spec.handle_targets(self.points, self.faces)
        pose = self.points.copy()
        pose[indices] = targets[frame]
        self.model.deformed_cages, self.posed = pose[None], pose
        return self.model.deform()[0]

    def lines(self) -> tuple[np.ndarray, np.ndarray]:
        f = self.faces
        edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
        return self.posed, edges
