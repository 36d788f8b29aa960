r"""The contracts between a deformation and what it moves: the backward and the forward map.

A ray-marched field (``Field.rendering == "rays"``) is rendered by bending each sample of a camera ray from deformed
space back into canonical (rest) space, where the unchanged field is queried: :class:`BackwardMap` is what the
renderer (:mod:`nerfedit_plugin.render.renderer`) needs of any deformation for that. ``DeformationField`` (one tet
proxy and its frames) and ``SceneDeformation`` (several objects, copies and chained edits) declare it.

A field drawn from primitives (``Field.rendering == "primitives"``) moves the primitives instead:
:class:`ForwardMap` carries rest points into deformed space with the local Jacobian ``F = ∂x'/∂x`` (a tet's
deformation gradient ``D' D⁻¹``, ``D`` the matrix of its edge vectors), which a primitive's shape is transformed by.
``DeformationField`` declares it. A scene edit may send a rest point to several places (copies) or none (removed and
vacated content): :class:`PlacementMap` (``SceneDeformation``). All three are structural :class:`typing.Protocol`\ s:
a third party's deformation passes if it has the members.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

import numpy as np
import torch


class BentPoints(NamedTuple):
    points: torch.Tensor  # (M,3) x_c (x itself where not inside T')
    tet: torch.Tensor | None  # (M,) int64: the deformed tet containing x, -1 outside T' (None if not asked for)
    empty: torch.Tensor  # (M,) bool: outside T' but inside the rest proxy T


class CanonicalPoints(NamedTuple):
    points: torch.Tensor  # (M,3) x_c
    inside: torch.Tensor  # (M,) bool: located in the deformed proxy T' (mapped)
    empty: torch.Tensor  # (M,) bool: outside T' but inside the rest proxy T
    jacobian: torch.Tensor  # (M,3,3) dx_c/dx, constant per tet; identity where not inside


class DeformedPoints(NamedTuple):
    points: torch.Tensor  # (M,3) x' (x itself where not inside the rest proxy T)
    inside: torch.Tensor  # (M,) bool: located in the rest proxy T (mapped)
    gradient: torch.Tensor  # (M,3,3) dx'/dx, constant per tet; identity where not inside


class Placement(NamedTuple):
    source: torch.Tensor  # (P,) int64: the rest point each placement is of, non-decreasing
    points: torch.Tensor  # (P,3) where it is placed
    gradient: torch.Tensor  # (P,3,3) dx'/dx there


@runtime_checkable
class BackwardMap(Protocol):
    """Deformed space → canonical space, per frame ``0 ≤ frame < n_frames``.

    A point ``x`` is *mapped* (it lies in a moved part: ``x_c`` is where its content rests), *empty* (the space a part
    left: nothing renders there) or the identity (``x_c = x``: background and untouched content). The renderer clips
    rays to the field's box grown by :meth:`moved_bounds` and rotates view directions by the Jacobian ``J = ∂x_c/∂x``
    (``d_c = normalize(J d)``)."""

    @property
    def n_frames(self) -> int:
        """Frames of the deformation (an animation's; 1 for a still edit)."""

    def bend(
        self, x: torch.Tensor, frame: int = 0, *, out: torch.Tensor | None = None, tets: bool = True
    ) -> BentPoints:
        """Map ``x (M,3)`` of ``frame`` to canonical space → :class:`BentPoints`; ``tet`` indexes the pieces
        :meth:`jacobian` takes (None with ``tets=False``); ``out`` (may be ``x``) receives the points."""

    def jacobian(self, tet: torch.Tensor, frame: int = 0) -> torch.Tensor:
        """``tet (M,)`` of :meth:`bend` → ``(M,3,3)`` ∂x_c/∂x (the identity where ``tet`` is -1)."""

    def moved_bounds(self, frame: int = 0) -> np.ndarray | None:
        """``(2,3)`` bounding box of where content moved to in ``frame``; None when nothing moved."""

    def to_canonical(self, x: torch.Tensor, frame: int = 0) -> CanonicalPoints:
        """:meth:`bend` and :meth:`jacobian` at once → :class:`CanonicalPoints`."""


@runtime_checkable
class ForwardMap(Protocol):
    """Canonical (rest) space → deformed space, per frame ``0 ≤ frame < n_frames``: a rest point in the proxy moves
    with it; every other point stays (``x' = x``, ``F = I``)."""

    @property
    def n_frames(self) -> int:
        """Frames of the deformation."""

    def to_deformed(self, x: torch.Tensor, frame: int = 0) -> DeformedPoints:
        """Map rest points ``x (M,3)`` to ``frame`` → :class:`DeformedPoints`."""


@runtime_checkable
class PlacementMap(Protocol):
    """Canonical (rest) space → deformed space where a rest point may appear any number of times, per frame: once
    per instance that carries it (moved, or copied), not at all where the content was removed or its rest place is
    vacated, and — for what no instance owns — in place unless moved content covers it there."""

    @property
    def n_frames(self) -> int:
        """Frames of the deformation."""

    def place(self, x: torch.Tensor, frame: int = 0) -> Placement:
        """Place rest points ``x (M,3)`` in ``frame`` → :class:`Placement` (in rest-point order)."""
