"""The Deformer contract (entry-point group ``nerfedit.deformers``).

A plugin ships a config dataclass (subclass of :class:`DeformerConfig`, ``_target`` = its :class:`Deformer`
subclass, a docstring per field) and registers the *config class* under the entry point group, e.g.
``[project.entry-points."nerfedit.deformers"] arap = "deformers.arap:ArapConfig"``.

Life cycle: ``deformer = config.setup(); deformer.bind(rest, edit); frames = deformer.deform()``.
Optional hooks (see docs/plugins.md): ``write_artifacts(out_dir) -> list[Path]`` (the CLI calls it to save cages,
weights, …) and the classmethods ``identity_edit(edit, rest)`` / ``rigid_edit(edit, rest)`` used by the
conformance kit ``nerfedit_plugin.testing.deformers.check_deformer``.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import numpy as np

from nerfedit_plugin.config import InstantiateConfig
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.geometry.mesh import SurfaceMesh


@dataclasses.dataclass
class DeformerConfig(InstantiateConfig):
    """Base config of every deformer plugin."""


class Deformer:
    """Deforms a rest surface mesh according to an edit spec; output keeps vertex order and connectivity.

    Subclasses set ``spec_keys`` (the top-level edit-spec keys besides ``frames`` they accept; any other key is
    rejected by :func:`nerfedit_plugin.edit.spec.parse_edit_spec`) and implement :meth:`bind` and :meth:`deform`.
    Deformers defined in space (cage, skeleton) also implement :meth:`deform_points`.
    """

    spec_keys: ClassVar[frozenset[str]] = frozenset({"handles"})

    def __init__(self, config: DeformerConfig) -> None:
        self.config = config

    def bind(self, rest: SurfaceMesh, edit: EditSpec) -> None:
        """All precomputation (factorisations, weights, coordinates). Validates ``edit`` against ``rest``."""
        raise NotImplementedError

    def deform(self) -> np.ndarray:
        """Deformed vertex positions ``(n_frames, V, 3)`` float64, same vertex order as the rest mesh.

        ``n_frames`` is the spec's ``frames`` when it sets one, else the deformer's own count (1 for a single
        pose; the clip length for a BVH, the file count for a mesh sequence).
        """
        raise NotImplementedError

    def deform_points(self, points: np.ndarray, frame: int) -> np.ndarray:
        """Map arbitrary rest-space points ``(M,3)`` to deformed space at ``frame`` (space deformers only)."""
        raise NotImplementedError(f"{type(self).__name__} is defined on the surface only")

    @classmethod
    def supports_points(cls) -> bool:
        """True when the deformer overrides :meth:`deform_points` (so ``--lift direct`` is available)."""
        return cls.deform_points is not Deformer.deform_points
