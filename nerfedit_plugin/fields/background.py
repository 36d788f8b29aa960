"""The background model of the grid fields: what lies outside the foreground box (``scene_bbox``), in contracted
space, and where its samples go along a ray.

Contraction (mip-NeRF 360; nerfstudio's ``SceneContraction`` with the L∞ norm): with ``y = (x − c) / r`` the point
in the box normalised to ``[-1,1]³`` (``c`` its centre, ``r`` its half sides) and ``n = ‖y‖∞``,
``contract(x) = y`` for ``n ≤ 1`` and ``(2 − 1/n) · y/n`` outside, so all of space fits in ``[-2,2]³``, the box
stays as it is, and the shell ``‖y‖∞ = n`` maps to the cube of half side ``ρ = 2 − 1/n``.

Samples: ``n_before`` between the camera and the box entry ``near`` and ``n_after`` from the box exit ``far`` to
infinity (a ray that misses the box is split at its point closest to the box centre), spaced uniformly in
``u = |t − t_b| / (|t − t_b| + L)`` (``t_b`` = ``near`` or ``far``, ``L`` the box's mean half side): uniform in the
disparity seen from the box, ``L / n`` apart next to it, as the contraction is, and sparse far away, to ``u → 1``.
A sample's opacity is ``α = 1 − exp(−σ δ)`` with ``δ`` the contracted
length of its bin (the chord between the contracted bin edges) and ``σ`` a density per contracted unit:
``σ = softplus(g₀(contract(x)) + shift) / h`` with ``h`` the grid's final cell size, so ``g₀`` is an optical
thickness per cell as in the ``nerf`` field; colour ``sigmoid(g₁..₃)``, view independent. The background is never
bent by a deformation: edits live inside the foreground box.

Layers (:mod:`nerfedit_plugin.fields.layers`): a ground plane and a far sphere, each adding one sample per ray at
its crossing (``δ = 1``, so ``α = 1 − exp(−τ)`` with the layer's optical thickness ``τ``), for the floor and the
surroundings the grid's cells are too coarse for. :meth:`BackgroundField.samples` says which samples are whose.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from nerfedit_plugin.data.datasets import world_up
from nerfedit_plugin.fields.encoding import DenseGrid
from nerfedit_plugin.fields.layers import FarSphereLayer, GroundLayer, fit_far_sphere, fit_ground, free_depths

DENSITY_INIT = 0.1
"""Initial density of the background model per contracted unit (a faint haze: the nerf field's ``density_init``)."""
FAR_U = 1.0 - 1e-4
"""``u`` of the last sample edge beyond the box (``t = far + 10⁴ L``): stands for infinity."""
GRID, GROUND, FAR = 0, 1, 2
"""Whose a background sample is (:meth:`BackgroundField.samples`): the grid's, the ground layer's, the far sphere's."""


def contract(points: torch.Tensor, box: torch.Tensor) -> torch.Tensor:
    """``points (M,3)`` → contracted points ``(M,3)`` in ``[-2,2]³`` (module docstring; ``box (2,3)``)."""
    y = (points - (box[0] + box[1]) / 2) / ((box[1] - box[0]) / 2)
    n = y.abs().amax(-1, keepdim=True).clamp_min(1.0)  # inside: (2 − 1/1) · y/1 = y exactly
    return (2.0 - 1.0 / n) * y / n


class BackgroundField(torch.nn.Module):
    """Density and colour of what lies outside ``box (2,3)``: a :class:`DenseGrid` of 4 channels over the contracted
    cube ``[-2,2]³`` (``resolution`` cells per axis now; ``final_resolution`` after coarse-to-fine refinement sets the
    density scale ``h``), ``n_before`` samples between the camera and the box and ``n_after`` beyond it (module
    docstring); with ``ground`` / ``far`` > 0, a ground plane / far sphere layer with a texture of that many cells
    per side (off until :meth:`fit_layers` finds them). ``seed`` seeds the initial colour noise."""

    def __init__(
        self,
        box: torch.Tensor,
        resolution: int,
        final_resolution: int,
        n_before: int,
        n_after: int,
        seed: int = 0,
        *,
        ground: int = 0,
        far: int = 0,
    ) -> None:
        super().__init__()
        self.register_buffer("box", torch.as_tensor(box, dtype=torch.float32).reshape(2, 3).clone())
        self.n_before, self.n_after = int(n_before), int(n_after)
        self.cell = 4.0 / final_resolution
        self.scale = float((self.box[1] - self.box[0]).mean()) / 2
        self.shift = math.log(math.expm1(DENSITY_INIT * self.cell))
        init = torch.zeros((resolution + 1) ** 3, 4)
        init[:, 1:].normal_(0.0, 0.1, generator=torch.Generator().manual_seed(seed))
        cube = torch.tensor([[-2.0] * 3, [2.0] * 3], device=self.box.device)
        self.grid = DenseGrid(cube, resolution, 4, init.to(self.box.device))
        self.ground = GroundLayer(self.box, ground) if ground > 0 else None
        self.far = FarSphereLayer(self.box, far) if far > 0 else None

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        """A checkpoint written before the layers existed (no ``ground.`` / ``far.`` keys) loads without them."""
        for name in ("ground", "far"):
            if getattr(self, name) is not None and not any(k.startswith(f"{prefix}{name}.") for k in state_dict):
                setattr(self, name, None)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def fit_layers(self, dataset) -> dict:
        """Place the layers from the training images (:func:`~nerfedit_plugin.fields.layers.fit_ground` with the
        cameras' up direction, :func:`~nerfedit_plugin.data.datasets.world_up`, then
        :func:`~nerfedit_plugin.fields.layers.fit_far_sphere` on opaque images: with alpha, what lies beyond the
        covered content is transparent, no far surface); returns what each sweep found."""
        found = {}
        if self.ground is not None:
            found["ground"] = fit_ground(self.ground, dataset, world_up(dataset.cameras))
        if self.far is not None and dataset.opaque:
            found["far"] = fit_far_sphere(self.far, dataset, self.ground)
        elif self.far is not None:
            self.far.active.fill_(False)
            found["far"] = {"active": False, "reason": "images with alpha: transparent beyond their content"}
        return found

    def free_depths(self, dataset) -> torch.Tensor | None:
        """How far each training pixel's ray is empty, up to the layer it sees (:func:`~nerfedit_plugin.fields.layers.
        free_depths`; None with no layer active)."""
        return free_depths(self.ground, self.far, dataset)

    def query(self, points: torch.Tensor, kind: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """World ``points (M,3)`` and whose samples they are (``kind (M,)``, :data:`GRID` where None) →
        ``(σ (M,) per contracted unit, rgb (M,3))``; a layer's ``σ`` is its optical thickness (its ``δ`` is 1)."""
        values = self.grid(contract(points, self.box))
        sigma, rgb = F.softplus(values[:, 0] + self.shift) / self.cell, torch.sigmoid(values[:, 1:])
        for code, layer in ((GROUND, self.ground), (FAR, self.far)) if kind is not None else ():
            if layer is not None:
                rows = torch.nonzero(kind == code).squeeze(1)
                if len(rows):
                    thickness, color = layer.query(points.index_select(0, rows))
                    sigma, rgb = sigma.index_copy(0, rows, thickness), rgb.index_copy(0, rows, color)
        return sigma, rgb

    def samples(
        self, origins: torch.Tensor, directions: torch.Tensor, near: torch.Tensor, far: torch.Tensor, stratified: bool
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Rays ``(R,3)`` (unit directions) and their segment ``[near, far] (R,)`` in the box (``far ≤ near``: a
        miss, split at the point closest to the box centre instead) → sample distances ``t (R, S)``, the
        contracted length ``δ`` of each sample's bin (module docstring) and whose sample it is (``kind (R,S)`` int64,
        :data:`GRID`, :data:`GROUND` or :data:`FAR`): ``n_before + n_after`` grid samples in ray order, then one per
        layer (``δ = 1`` where the ray crosses it, else ``δ = 0`` at the last grid sample), unsorted: the renderer
        sorts them with the field's."""
        lo, hi = self.box
        closest = ((lo + hi) / 2 - origins).mul(directions).sum(-1).clamp_min(0.0)
        hit = far > near
        near, far = torch.where(hit, near, closest), torch.where(hit, far, closest)
        before = self._segment(origins, directions, near, near / (near + self.scale), self.n_before, -1.0, stratified)
        after = self._segment(origins, directions, far, torch.full_like(far, FAR_U), self.n_after, 1.0, stratified)
        t, delta = torch.cat([before[0].flip(1), after[0]], 1), torch.cat([before[1].flip(1), after[1]], 1)
        kind = torch.full_like(t, GRID, dtype=torch.int64)
        for code, layer in ((GROUND, self.ground), (FAR, self.far)):
            if layer is not None:
                at, crosses = layer.crossing(origins, directions)
                t = torch.cat([t, torch.where(crosses, at, t[:, -1])[:, None]], 1)
                delta = torch.cat([delta, crosses.to(delta.dtype)[:, None]], 1)
                kind = torch.cat([kind, torch.full_like(kind[:, :1], code)], 1)
        return t, delta, kind

    def _segment(self, origins, directions, bound, reach, count: int, sign: float, stratified: bool):
        """``count`` samples on ``t = bound + sign · L u/(1 − u)``, ``u`` from 0 to ``reach (R,)`` in equal bins:
        their distances and contracted bin lengths ``(R, count)``, ordered away from the box."""
        steps = torch.arange(count + 1, device=bound.device, dtype=bound.dtype) / max(count, 1)
        edges = reach[:, None] * steps
        offsets = torch.rand(len(bound), count, device=bound.device) if stratified else 0.5
        centres = edges[:, :-1] + (edges[:, 1:] - edges[:, :-1]) * offsets

        def distance(u: torch.Tensor) -> torch.Tensor:
            return bound[:, None] + sign * self.scale * u / (1.0 - u)

        ends = contract(origins[:, None] + distance(edges)[..., None] * directions[:, None], self.box)
        return distance(centres), (ends[:, 1:] - ends[:, :-1]).norm(dim=-1)
