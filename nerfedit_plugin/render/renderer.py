"""The one renderer of every field backend, with optional ray bending through a DeformationField.

Rays ``(R,3)`` are clipped to :func:`sampling_box` (``scene_bbox`` ∪ the box of the tets the frame moves) and sampled
at ``n_samples`` bin centres of width ``δ`` (stratified when training). With a deformation, samples map to
``x_c``, vacated ones are empty, view directions become ``normalize(J d)`` and SDF gradients ``∇ₓf = Jᵀ ∇f(x_c)``.
Opacity ``α = 1 − exp(−σ δ)`` (density) or NeuS's unbiased ``α = clamp((Φ_s(f−) − Φ_s(f+)) / Φ_s(f−), 0, 1)``,
``f∓ = f ∓ c' δ/2`` with ``c'`` the annealed cosine of ``c = d · ∇ₓf`` (sdf); ``w_i = α_i Π_{j<i} (1 − α_j)``,
``rgb = Σ w c + (1 − Σ w)·background``, ``depth = Σ w t / Σ w``. A field's background model
(``Field.background_model()``) adds samples outside ``scene_bbox`` — camera to box, box to infinity — queried unbent
with ``α = 1 − exp(−σ δ)`` over contracted bin lengths, merged with the field's in ray order before compositing.
Opaque fields (``Field.opaque``) are shaded once at each ray's refined first inside point ``t*`` instead. Full
semantics: docs/architecture.md, "Rendering".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import torch
import torch.nn.functional as F

from nerfedit_plugin.bending.maps import BackwardMap
from nerfedit_plugin.data.cameras import Cameras, generate_rays
from nerfedit_plugin.fields.base import Field


@dataclass
class RenderConfig:
    """How rays are sampled and composited."""

    n_samples: int = 128
    """Samples per ray inside the bounds (bin centres; uniform within each bin when stratified, for training)."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Colour composited behind the field where the opacity is below 1."""
    chunk: int = 65536
    """Rays rendered at once by render_image (bounds the memory of one batch of samples)."""
    refine_rounds: int = 3
    """Opaque fields: rounds locating the surface crossing between the last outside and the first inside sample;
    each splits the bracket into ``REFINE_SPLIT`` parts and keeps the first crossing (error δ / 16^rounds)."""
    early_stop: float = 1e-4
    """Without autograd (``render_image``), rays march ``VOLUME_SEGMENT`` samples at a time and stop once their
    transmittance is at most this (what they skip adds at most this much colour); 0 composites every sample."""
    cos_anneal: float = 1.0
    """SDF fields: NeuS cosine annealing ratio in [0, 1]; 1 is the unbiased estimate (trainers ramp it up from 0)."""
    bend_view_directions: bool = True
    """With a deformation, carry each ray's direction ``d`` into canonical space by the bending Jacobian ``J`` of its
    samples (volume-rendered fields): the colour is queried with ``normalize(J d)`` and the NeuS cosine is
    ``c = d · Jᵀ∇f(x_c) = (J d) · ∇f(x_c)``. False keeps ``d`` as it is (the paper's choice; an ablation): colour
    queried with ``d``, cosine ``c = d · ∇f(x_c)``, which is wrong by the rotation of the part the sample lies in."""


VOLUME_SEGMENT = 32
"""Samples per ray per front-to-back step when rays may stop early (density and sdf fields, no autograd)."""
OPAQUE_SEGMENT = 16
"""Opaque fields: samples per ray evaluated per front-to-back step of the first-hit search."""
REFINE_SPLIT = 16
"""Opaque fields: parts each refinement round splits the crossing bracket into."""


class RenderOutput(NamedTuple):
    rgb: torch.Tensor
    """(R,3) composited colour."""
    depth: torch.Tensor
    """(R,) expected distance along the unit ray, Σ w t / Σ w (0 where the opacity is 0)."""
    opacity: torch.Tensor
    """(R,) accumulated opacity Σ w."""


class _Kept(NamedTuple):
    """Samples that survive bending and the occupancy grid: flat sample ``index (K,)``, canonical ``points (K,3)``
    and the bending Jacobian ``(K,3,3)`` (None without a deformation)."""

    index: torch.Tensor
    points: torch.Tensor
    jacobian: torch.Tensor | None


def sampling_box(field: Field, deformation: BackwardMap | None = None, frame: int = 0) -> torch.Tensor:
    """field, deformation (or None), frame → ``(2,3)`` box (``scene_bbox``'s dtype and device) rays are clipped to:
    ``scene_bbox`` ∪ the box of the tets that ``frame`` moves (:meth:`DeformationField.moved_bounds`; elsewhere the
    scene is where it was, so an identity edit samples every ray exactly as the unedited render does)."""
    box = field.scene_bbox
    bounds = None if deformation is None else deformation.moved_bounds(frame)
    if bounds is None:
        return box
    moved = torch.as_tensor(bounds, dtype=box.dtype, device=box.device)
    return torch.stack([torch.minimum(box[0], moved[0]), torch.maximum(box[1], moved[1])])


def ray_box(origins: torch.Tensor, directions: torch.Tensor, box: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Slab test. origins (R,3), unit directions (R,3), box (2,3) (lo, hi) → ``(near (R,), far (R,))`` in the
    origins' dtype, the part of each ray inside ``box``; ``near ≥ 0``; ``far = near`` for rays that miss."""
    safe = torch.where(directions.abs() < 1e-12, torch.full_like(directions, 1e-12), directions)
    t0, t1 = (box[0] - origins) / safe, (box[1] - origins) / safe
    near = torch.minimum(t0, t1).amax(-1).clamp_min(0.0)
    far = torch.maximum(torch.maximum(t0, t1).amin(-1), near)
    return near, far


def _keep(
    field: Field, points: torch.Tensor, deformation: BackwardMap | None, frame: int, jacobian: bool = True
) -> _Kept:
    """Bend flat samples to canonical space and keep those neither empty (vacated) nor rejected by
    ``field.occupied`` (one mask, one ``nonzero``); the Jacobians are gathered for the kept samples only (not at
    all without ``jacobian``). An opaque field's ``occupied`` is its exact inside test, dear per sample: it skips
    the empty samples (one more ``nonzero``), where a grid lookup is cheaper than that."""
    tet, empty, live = None, None, None
    if deformation is not None:
        bent = deformation.bend(points, frame, out=points, tets=jacobian)  # the samples are ours: bend in place
        tet = None if bent.tet is None else bent.tet.to(points.device)
        empty = bent.empty.to(points.device)
        if field.opaque:
            live = torch.nonzero(~empty).squeeze(1)
            points, empty = points.index_select(0, live), None
            tet = None if tet is None else tet.index_select(0, live)
    keep = field.occupied(points)
    if empty is not None:
        keep = ~empty if keep is None else keep & ~empty
    if keep is None:
        index = torch.arange(len(points), device=points.device)
    else:
        index = torch.nonzero(keep).squeeze(1)
        points = points.index_select(0, index)
        tet = None if tet is None else tet.index_select(0, index)
    if live is not None:
        index = live.index_select(0, index)
    if deformation is None or not jacobian:
        return _Kept(index, points, None)
    return _Kept(index, points, deformation.jacobian(tet, frame).to(points))


def _canonical_directions(directions: torch.Tensor, jacobian: torch.Tensor | None) -> torch.Tensor:
    """``normalize(J d)``: the direction of the bent ray in canonical space."""
    if jacobian is None:
        return directions
    return F.normalize(torch.einsum("kij,kj->ki", jacobian, directions), dim=-1)


def render_rays(
    field: Field,
    origins: torch.Tensor,
    directions: torch.Tensor,
    config: RenderConfig,
    *,
    deformation: BackwardMap | None = None,
    frame: int = 0,
    stratified: bool = False,
    bounds: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> RenderOutput:
    """Render rays: origins (R,3), unit directions (R,3) float (deformed/world space) → :class:`RenderOutput`
    (``rgb (R,3)``, ``depth (R,)``, ``opacity (R,)``, on the field's device) — see the module docstring.
    Differentiable with respect to the field's parameters (training calls it under autograd). ``bounds`` = per-ray
    ``(near (R,), far (R,))`` overrides the ray/box intersection."""
    device = field.scene_bbox.device
    origins, directions = origins.to(device), directions.to(device)
    if bounds is None:
        near, far = ray_box(origins, directions, sampling_box(field, deformation, frame))
    else:
        near, far = (b.to(device=device, dtype=origins.dtype) for b in bounds)
    n_rays, n = len(origins), config.n_samples
    offsets = torch.rand(n_rays, n, device=device) if stratified else torch.full((n_rays, n), 0.5, device=device)
    delta = ((far - near) / n)[:, None]
    t = near[:, None] + (torch.arange(n, device=device) + offsets) * delta
    background = torch.tensor(config.background, dtype=origins.dtype, device=device)
    if field.opaque:
        return _render_opaque(field, origins, directions, near, t, background, config, deformation, frame)
    delta, outside = delta.expand(n_rays, n), None
    model = field.background_model()
    if model is not None:
        t, delta, outside = _with_background(model, field.scene_bbox, origins, directions, t, delta, stratified)
        n = t.shape[1]
    stop = config.early_stop if not torch.is_grad_enabled() else 0.0
    segment = VOLUME_SEGMENT if stop > 0 else n
    color_sum, depth_sum = origins.new_zeros(n_rays, 3), origins.new_zeros(n_rays)
    opacity, transmittance = origins.new_zeros(n_rays), origins.new_ones(n_rays)
    active = torch.arange(n_rays, device=device)
    for start in range(0, n, segment):
        if len(active) == 0:
            break
        ts = t.index_select(0, active)[:, start : start + segment]
        alpha, colors = _samples(
            field,
            origins.index_select(0, active),
            directions.index_select(0, active),
            ts,
            delta.index_select(0, active)[:, start : start + segment],
            config,
            deformation,
            frame,
            None if outside is None else (model, outside.index_select(0, active)[:, start : start + segment]),
        )
        inner = torch.cumprod(torch.cat([alpha.new_ones(len(active), 1), 1.0 - alpha], dim=1), dim=1)
        weights = alpha * inner[:, :-1] * transmittance.index_select(0, active)[:, None]
        color_sum = color_sum.index_add(0, active, (weights[..., None] * colors).sum(1))
        depth_sum = depth_sum.index_add(0, active, (weights * ts).sum(1))
        opacity = opacity.index_add(0, active, weights.sum(1))
        transmittance = transmittance.index_copy(0, active, transmittance.index_select(0, active) * inner[:, -1])
        active = active[transmittance.index_select(0, active) > stop]
    rgb = color_sum + (1.0 - opacity)[:, None] * background
    return RenderOutput(rgb, depth_sum / opacity.clamp_min(1e-10), opacity)


def _with_background(model, box, origins, directions, t, delta, stratified: bool):
    """The field's samples ``t, δ (R,S)`` merged in ray order with the background model's (outside ``box``: from the
    camera to the box and beyond it; ``δ`` in contracted units) → ``t, δ`` and whose each sample is, ``(R, S + S_b)``:
    −1 for the field's, else the model's ``kind``. The order also holds when an edit grows the sampling box beyond
    ``box``."""
    near, far = ray_box(origins, directions, box)
    t_outside, delta_outside, kind = model.samples(origins, directions, near, far, stratified)
    order = torch.argsort(torch.cat([t, t_outside], 1), dim=1, stable=True)
    whose = torch.cat([torch.full_like(t, -1, dtype=torch.int64), kind], 1)
    return (
        torch.cat([t, t_outside], 1).gather(1, order),
        torch.cat([delta, delta_outside], 1).gather(1, order),
        whose.gather(1, order),
    )


def _samples(
    field: Field,
    origins,
    directions,
    t,
    delta,
    config: RenderConfig,
    deformation: BackwardMap | None,
    frame,
    outside=None,
):
    """Opacity ``(A,S)`` and colour ``(A,S,3)`` of the samples at distances ``t (A,S)`` of rays ``(A,3)`` with bin
    widths ``delta (A,S)`` (bent, packed, queried; dropped samples get α = 0). ``outside`` = (background model, whose
    ``(A,S)``: −1 for the field's samples, else the model's kind): the model's are queried from it at their unbent
    position, ``α = 1 − exp(−σ δ)``."""
    n_rays, n = t.shape
    points = (origins[:, None] + t[..., None] * directions[:, None]).reshape(-1, 3)
    delta = delta.reshape(-1)
    if outside is not None:
        model, whose = outside
        whose = whose.reshape(-1)
        far, near = torch.nonzero(whose >= 0).squeeze(1), torch.nonzero(whose < 0).squeeze(1)
        sigma, far_rgb = model.query(points.index_select(0, far), whose.index_select(0, far))
        far_alpha = 1.0 - torch.exp(-sigma * delta.index_select(0, far))
        points = points.index_select(0, near)
    bent = config.bend_view_directions and (field.kind == "sdf" or field.view_dependent)
    kept = _keep(field, points, deformation, frame, jacobian=bent)
    index = kept.index if outside is None else near.index_select(0, kept.index)
    ray = torch.div(index, n, rounding_mode="floor")
    ray_dirs = directions.index_select(0, ray)
    query_dirs = _canonical_directions(ray_dirs, kept.jacobian) if field.view_dependent else ray_dirs
    if field.kind == "sdf":
        alpha, rgb = _sdf_alpha(field, kept, query_dirs, ray_dirs, delta.index_select(0, index), config.cos_anneal)
    elif field.kind == "density":
        sigma, rgb = field.query(kept.points, query_dirs)
        alpha = 1.0 - torch.exp(-sigma * delta.index_select(0, index))
    else:
        raise ValueError(f"{type(field).__name__}.kind = {field.kind!r}; expected 'density' or 'sdf'")
    alpha = alpha.new_zeros(n_rays * n).index_copy(0, index, alpha)
    colors = rgb.new_zeros(n_rays * n, 3).index_copy(0, index, rgb)
    if outside is not None:
        alpha, colors = alpha.index_copy(0, far, far_alpha.to(alpha)), colors.index_copy(0, far, far_rgb.to(colors))
    return alpha.view(n_rays, n), colors.view(n_rays, n, 3)


def _sdf_alpha(
    field: Field, kept: _Kept, query_dirs: torch.Tensor, ray_dirs: torch.Tensor, delta: torch.Tensor, anneal: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """NeuS unbiased opacity ``(K,)`` and colour ``(K,3)`` of the kept samples (see the module docstring)."""
    outer = torch.is_grad_enabled()
    with torch.enable_grad():
        points = kept.points if kept.points.requires_grad else kept.points.detach().requires_grad_(True)
        sdf, rgb = field.query(points, query_dirs)
        (grad,) = torch.autograd.grad(sdf, points, torch.ones_like(sdf), create_graph=outer)
    if not outer:
        sdf, rgb = sdf.detach(), rgb.detach()
    if kept.jacobian is not None:
        grad = torch.einsum("kji,kj->ki", kept.jacobian, grad)  # Jᵀ ∇f(x_c): the gradient in deformed space
    cos = (ray_dirs * grad).sum(-1)
    cos = -(F.relu(-cos * 0.5 + 0.5) * (1.0 - anneal) + F.relu(-cos) * anneal)
    s = field.sharpness()
    prev = torch.sigmoid((sdf - cos * delta * 0.5) * s)
    after = torch.sigmoid((sdf + cos * delta * 0.5) * s)
    return ((prev - after + 1e-5) / (prev + 1e-5)).clamp(0.0, 1.0), rgb


def _inside(field: Field, points: torch.Tensor, deformation: BackwardMap | None, frame: int) -> torch.Tensor:
    """Bent exact inside test of an opaque field at points ``(M,3)`` in deformed space."""
    inside = torch.zeros(len(points), dtype=torch.bool, device=points.device)
    return inside.index_fill_(0, _keep(field, points, deformation, frame, jacobian=False).index, True)


def _first_inside(field: Field, origins, directions, t, deformation: BackwardMap | None, frame) -> torch.Tensor:
    """Index ``(R,)`` of each ray's first inside sample (−1 if none), marching front to back ``OPAQUE_SEGMENT``
    samples at a time: rays stop being evaluated once they have hit (nothing behind the surface is bent)."""
    n_rays, n = t.shape
    first = torch.full((n_rays,), -1, dtype=torch.int64, device=t.device)
    active = torch.arange(n_rays, device=t.device)
    for start in range(0, n, OPAQUE_SEGMENT):
        if len(active) == 0:
            break
        segment = t.index_select(0, active)[:, start : start + OPAQUE_SEGMENT]
        o, d = origins.index_select(0, active), directions.index_select(0, active)
        points = (o[:, None] + segment[..., None] * d[:, None]).reshape(-1, 3)
        inside = _inside(field, points, deformation, frame).view(segment.shape)
        found = inside.any(1)
        first.index_copy_(0, active[found], start + inside[found].to(torch.uint8).argmax(1))  # first maximum
        active = active[~found]
    return first


def _render_opaque(
    field: Field, origins, directions, near, t, background, config: RenderConfig, deformation: BackwardMap | None, frame
) -> RenderOutput:
    """First surface crossing of each ray, refined; one colour query there (see the module docstring)."""
    n_rays = len(t)
    first = _first_inside(field, origins, directions, t, deformation, frame)
    rays = torch.nonzero(first >= 0).squeeze(1)
    first = first.index_select(0, rays)
    t_hit = t.index_select(0, rays)
    hi = t_hit.gather(1, first[:, None])[:, 0]
    lo = torch.where(first > 0, t_hit.gather(1, (first - 1).clamp_min(0)[:, None])[:, 0], near.index_select(0, rays))
    o, d = origins.index_select(0, rays), directions.index_select(0, rays)
    fractions = torch.arange(1, REFINE_SPLIT, device=t.device, dtype=t.dtype) / REFINE_SPLIT
    for _ in range(config.refine_rounds):
        probes = lo[:, None] + (hi - lo)[:, None] * fractions  # (H, REFINE_SPLIT − 1)
        hit = _inside(field, (o[:, None] + probes[..., None] * d[:, None]).reshape(-1, 3), deformation, frame)
        hit = torch.cat([hit.view(len(rays), REFINE_SPLIT - 1), hit.new_ones(len(rays), 1)], 1)  # hi is inside
        edges = torch.cat([lo[:, None], probes, hi[:, None]], 1)
        j = hit.to(torch.uint8).argmax(1)  # edges[j + 1] is the first inside edge, edges[j] is outside
        lo, hi = edges.gather(1, j[:, None])[:, 0], edges.gather(1, j[:, None] + 1)[:, 0]
    points = o + hi[:, None] * d
    if deformation is not None:
        bent = deformation.to_canonical(points, frame)
        points, d = bent.points.to(points), _canonical_directions(d, bent.jacobian.to(points))
    _, color = field.query(points, d)
    rgb = background.expand(n_rays, 3).index_copy(0, rays, color.to(background.dtype))
    depth = torch.zeros_like(near).index_copy(0, rays, hi)
    opacity = torch.zeros_like(near).index_fill_(0, rays, 1.0)
    return RenderOutput(rgb, depth, opacity)


@torch.no_grad()
def render_image(
    field: Field,
    cameras: Cameras,
    index: int,
    config: RenderConfig,
    *,
    deformation: BackwardMap | None = None,
    frame: int = 0,
    supersample: int = 1,
) -> torch.Tensor:
    """Render camera ``index`` of ``cameras`` → ``(H,W,3)`` rgb in [0,1] (the rays' dtype, float32 for the built-in
    cameras) on the field's device, in chunks of ``config.chunk`` rays, without autograd. ``supersample`` s: s×s
    stratified sub-pixel rays per pixel, averaged (``Cameras.upscale``). A field that renders itself
    (``rendering == "primitives"``) draws the image with :meth:`~nerfedit_plugin.fields.base.Field.render`."""
    fine = cameras.upscale(supersample) if supersample > 1 else cameras
    s, h, w = supersample, cameras.height, cameras.width
    if field.rendering == "primitives":
        image = field.render(fine, index, config, deformation=deformation, frame=frame)
        return image.reshape(h, s, w, s, 3).mean((1, 3))
    origins, directions = generate_rays(fine, index)
    origins, directions = origins.reshape(-1, 3), directions.reshape(-1, 3)
    device = field.scene_bbox.device
    rgb = torch.cat(
        [
            render_rays(
                field,
                origins[start : start + config.chunk].to(device),
                directions[start : start + config.chunk].to(device),
                config,
                deformation=deformation,
                frame=frame,
            ).rgb
            for start in range(0, len(origins), config.chunk)
        ]
    )
    return rgb.view(h, s, w, s, 3).mean((1, 3))
