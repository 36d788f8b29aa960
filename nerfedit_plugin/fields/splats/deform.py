r"""The forward map of a Gaussian splat model: every Gaussian carried from rest to deformed space.

A Gaussian ``(μ, Σ = R_q S² R_qᵀ, opacity, sh)`` whose mean lies in the rest proxy of a
:class:`~nerfedit_plugin.bending.maps.ForwardMap` (local Jacobian ``F``, constant per tet) becomes the following; a
scene edit (a :class:`~nerfedit_plugin.bending.maps.PlacementMap`) makes one such Gaussian per place of its mean —
copies for copied objects, none for removed or vacated content, by the ownership rule of ray bending:

- ``μ' = φ(μ)``, ``Σ' = F Σ Fᵀ``, opacity unchanged;
- ``Σ'`` re-expressed as a unit quaternion and log-scales: with the polar decomposition ``F = R U`` (``R`` a
  rotation, ``U`` symmetric), ``Σ' = R R_q C R_qᵀ Rᵀ`` with ``C = R_qᵀ U Σ U R_q``, the covariance in the Gaussian's
  own axes; ``C = Q Λ Qᵀ`` (eigen-decomposition, columns of ``Q`` ordered and signed to stay nearest the old axes,
  ``det Q = 1``) gives the rotation ``R R_q Q`` and scales ``√Λ``. A shear turns the axes (``Q ≠ I``); a rigid ``F``
  gives ``R R_q`` and the old scales;
- SH bands 1–3 rotated by the Wigner matrices of ``R`` (:mod:`.sh_rotation`); band 0 unchanged.

Inverted tets (``det F < 0``): ``F``'s polar factor is a reflection, which SH rotation cannot express; ``R`` is then
the nearest rotation, ``W diag(1, 1, −1) Vᵀ`` from the SVD ``F = W Σ_F Vᵀ`` (the reflection across the axis of the
smallest singular value removed), while ``Σ' = F Σ Fᵀ`` is kept exact. They are counted (:attr:`DeformReport.
inverted`). Gaussians outside the proxy, or in tets that do not move, are kept bit for bit.

Needles: a strong stretch grows a Gaussian's anisotropy, ``g = (σ'_max/σ'_min) / (σ_max/σ_min)``. With
``split_growth`` set, a rest Gaussian whose mapped ``g`` (its largest over its places) exceeds ``split_growth`` is
split in rest space into ``k = min(⌈√2 g / split_growth⌉, MAX_CHILDREN)`` children along ``u = F⁻¹ e``, the rest
direction that ``F`` maps onto the deformed longest axis ``e`` (deformed scale ``σ'``): means ``μ + t_j σ' u``,
``t_j = δ (j − (k−1)/2)``, ``δ = √(12 (1 − 2/k²) / (k² − 1))``, covariance ``Σ − (1 − 2/k²) σ'² u uᵀ``, everything
else as the parent's; then the children are mapped, each through its own tet, so a chain of them follows a bend
that one Gaussian could not. The equal mixture of the children has the parent's rest mean and covariance exactly
(so, under one ``F``, its deformed ones too); along ``e`` each child's deformed scale is ``√2 σ' / k`` and neighbours
overlap at 2–2.5 of it, so the chain has no gaps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from nerfedit_plugin.bending.maps import ForwardMap, Placement, PlacementMap
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.splats.model import SplatModel
from nerfedit_plugin.fields.splats.projection import rotation_matrices
from nerfedit_plugin.fields.splats.sh_rotation import rotate_sh, wigner_matrices

MAX_CHILDREN = 8
"""At most this many children replace one stretched Gaussian."""
_PERMUTATIONS = torch.tensor([[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]])


@dataclass
class DeformReport:
    """What :func:`deform_model` did: Gaussians in; placed (Gaussians out); removed (rest Gaussians placed nowhere);
    copied (placements beyond a Gaussian's first); moved (out, in a moving tet); in inverted tets; split (rest
    Gaussians split) into children (added); the anisotropy growth ``g`` of the moved ones before any split (max and
    99th percentile; 1 when none moved)."""

    gaussians: int = 0
    placed: int = 0
    removed: int = 0
    copied: int = 0
    moved: int = 0
    inverted: int = 0
    split: int = 0
    children: int = 0
    growth: dict[str, float] = field(default_factory=lambda: {"max": 1.0, "p99": 1.0})


def polar_rotations(gradients: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``F (P,3,3)`` → ``(R (P,3,3), inverted (P,) bool)``: the rotation of the polar decomposition ``F = R U``,
    ``W Vᵀ`` of the SVD ``F = W Σ Vᵀ``, with ``W``'s last column (the smallest singular value) negated where
    ``det F < 0`` (module docstring)."""
    w, _, vh = torch.linalg.svd(gradients)
    inverted = torch.linalg.det(gradients) < 0
    flip = torch.where(torch.linalg.det(w @ vh) < 0, -1.0, 1.0).to(gradients.dtype)
    w = torch.cat([w[:, :, :2], w[:, :, 2:] * flip[:, None, None]], 2)
    return w @ vh, inverted


def matrix_quaternions(rotations: torch.Tensor) -> torch.Tensor:
    """``(P,3,3)`` rotations → ``(P,4)`` unit quaternions w x y z with ``w ≥ 0`` (Shepperd's method: the largest of
    ``4w², 4x², 4y², 4z²`` picks the stable formula)."""
    m = rotations
    trace = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    candidates = torch.stack(
        [
            torch.stack([1 + trace, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1),
            torch.stack(
                [m[:, 2, 1] - m[:, 1, 2], 1 + 2 * m[:, 0, 0] - trace, m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0]],
                -1,
            ),
            torch.stack(
                [m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1 + 2 * m[:, 1, 1] - trace, m[:, 1, 2] + m[:, 2, 1]],
                -1,
            ),
            torch.stack(
                [m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1], 1 + 2 * m[:, 2, 2] - trace],
                -1,
            ),
        ],
        1,
    )  # row i is 4 q_i q (i = w, x, y, z)
    best = torch.stack([1 + trace, 1 + 2 * m[:, 0, 0] - trace, 1 + 2 * m[:, 1, 1] - trace, 1 + 2 * m[:, 2, 2] - trace])
    q = candidates[torch.arange(len(m)), best.argmax(0)]
    q = torch.nn.functional.normalize(q, dim=-1)
    return torch.where(q[:, :1] < 0, -q, q)


def _nearest_axes(vectors: torch.Tensor) -> torch.Tensor:
    """Eigenvector columns ``(P,3,3)`` permuted and signed to lie nearest the identity (the largest ``Σ |Q_ii|`` over
    the 6 orders, diagonal ≥ 0), with the column of the smallest diagonal negated where that leaves ``det = −1``."""
    picked = vectors[:, :, _PERMUTATIONS]  # (P,3,6,3): column order p
    score = picked.diagonal(dim1=1, dim2=3).abs().sum(-1)  # (P,6)
    order = _PERMUTATIONS[score.argmax(1)]
    q = torch.gather(vectors, 2, order[:, None, :].expand(-1, 3, -1))
    diagonal = q.diagonal(dim1=1, dim2=2)
    q = q * torch.where(diagonal < 0, -1.0, 1.0).to(q.dtype)[:, None, :]
    negative = torch.linalg.det(q) < 0
    weakest = torch.nn.functional.one_hot(q.diagonal(dim1=1, dim2=2).abs().argmin(1), 3).bool() & negative[:, None]
    return q * torch.where(weakest, -1.0, 1.0).to(q.dtype)[:, None, :]


def deform_model(
    model: SplatModel,
    deformation: ForwardMap | PlacementMap,
    frame: int = 0,
    *,
    split_growth: float | None = None,
    kernel: str = "auto",
) -> tuple[SplatModel, DeformReport]:
    """``model`` moved by ``deformation`` at ``frame`` (module docstring) → ``(model in its dtype, report)``; with
    ``split_growth``, stretched Gaussians are split first (their children come after the model's Gaussians, the first
    child in its parent's place; the report's ``growth`` is the one measured before splitting). ``kernel``:
    ``"numba"`` (``"auto"``: compiled, the polar rotation and Wigner matrices once per distinct ``F``) or
    ``"torch"`` (the reference, per Gaussian)."""
    if kernel not in ("auto", "numba", "torch"):
        raise ValueError(f"kernel must be 'auto', 'numba' or 'torch', got {kernel!r}")
    out, report, moved = _deform(model, deformation, frame, kernel)
    if split_growth is None or report.moved == 0 or report.growth["max"] <= split_growth:
        return out, report
    source, gradient, growth = moved
    worst = np.zeros(len(model))  # each rest Gaussian's largest growth over its places, and that place's F
    np.maximum.at(worst, source, growth)
    chosen = np.nonzero(worst > split_growth)[0]
    at = np.full(len(model), -1)
    at[source[growth == worst[source]]] = np.nonzero(growth == worst[source])[0]
    split = _split(model, chosen, gradient[at[chosen]], worst[chosen], split_growth)
    out, after, _ = _deform(split, deformation, frame, kernel)
    after.gaussians, after.split, after.children = len(model), len(chosen), len(split) - len(model)
    after.removed, after.growth = report.removed, report.growth
    return out, after


def _deform(
    model: SplatModel, deformation: ForwardMap | PlacementMap, frame: int, kernel: str
) -> tuple[SplatModel, DeformReport, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`deform_model` without splitting → ``(model, report, (source, F, growth))`` of the moved Gaussians:
    the rest Gaussian each is of, its gradient ``(P,3,3)`` float64 and its anisotropy growth."""
    dtype, count = model.means.dtype, len(model)
    placed = _placement(deformation, torch.from_numpy(np.ascontiguousarray(model.means)), frame)
    source = placed.source.cpu().numpy()
    kept = int(np.count_nonzero(np.bincount(source, minlength=count)))
    out = SplatModel(*(a[source] for a in model.arrays()))  # fresh arrays, updated in place below
    means = torch.from_numpy(out.means)
    points, gradient = placed.points.cpu(), placed.gradient.cpu()
    eye = torch.eye(3, dtype=gradient.dtype)
    rows = torch.nonzero((points.to(means) != means).any(1) | (gradient != eye).flatten(1).any(1)).squeeze(1)
    report = DeformReport(count, len(source), count - kept, len(source) - kept, len(rows))
    index, f = rows.numpy(), gradient.index_select(0, rows)
    if len(rows) == 0:
        return out, report, (source[index], f.double().numpy(), np.ones(0))
    out.means[index] = points.index_select(0, rows).numpy()
    growth = (_move_torch if kernel == "torch" else _move_compiled)(out, index, f, report).numpy()
    report.growth = {"max": float(growth.max()), "p99": float(np.percentile(growth, 99))}
    return out.astype(dtype), report, (source[index], f.double().numpy(), growth)


def _move_torch(model: SplatModel, index: np.ndarray, f: torch.Tensor, report: DeformReport) -> torch.Tensor:
    """Gaussians ``index`` of ``model`` given gradients ``f (P,3,3)``: quaternions, log-scales and SH updated in place
    (module docstring), per Gaussian in torch → their anisotropy growth ``(P,)``."""
    f = f.double()
    rotation, inverted = polar_rotations(f)
    report.inverted = int(inverted.sum())
    stretch = rotation.transpose(1, 2) @ f  # U = Rᵀ F
    quats = torch.from_numpy(model.quats[index]).double()
    scales = torch.exp(torch.from_numpy(model.log_scales[index]).double())
    axes = rotation_matrices(quats)
    local = axes.transpose(1, 2) @ stretch @ axes * scales[:, None, :]  # B = R_qᵀ U R_q S: C = B Bᵀ
    covariance = local @ local.transpose(1, 2)
    q = _nearest_axes(torch.linalg.eigh(covariance).eigenvectors)
    values = (q.transpose(1, 2) @ covariance @ q).diagonal(dim1=1, dim2=2)
    new_scales = values.clamp_min(torch.finfo(torch.float64).tiny).sqrt()
    model.quats[index] = matrix_quaternions(rotation @ axes @ q).numpy()
    model.log_scales[index] = torch.log(new_scales).numpy()
    model.sh[index] = rotate_sh(torch.from_numpy(model.sh[index]).double(), rotation).numpy()
    return (new_scales.amax(1) / new_scales.amin(1)) / (scales.amax(1) / scales.amin(1))


def _move_compiled(model: SplatModel, index: np.ndarray, f: torch.Tensor, report: DeformReport) -> torch.Tensor:
    """:func:`_move_torch` with the polar rotations and Wigner matrices computed once per distinct gradient (``F`` is
    constant per tet) and the per-Gaussian work in one compiled pass (:mod:`._deform_kernel`)."""
    from nerfedit_plugin.fields.splats._deform_kernel import move_gaussians
    from nerfedit_plugin.geometry.launch import launch

    table, piece = _pieces(f.numpy())
    rotation, inverted = polar_rotations(torch.from_numpy(table))
    report.inverted = int(inverted.numpy()[piece].sum())
    stretch = rotation.transpose(1, 2) @ torch.from_numpy(table)
    wigner = wigner_matrices(rotation, 3)
    moved = [np.ascontiguousarray(a[index], dtype=np.float64) for a in (model.quats, model.log_scales, model.sh)]
    growth = np.empty(len(index))
    tables = (np.ascontiguousarray(a) for a in (rotation, stretch, *wigner))
    launch(move_gaussians, piece, *tables, *moved, growth)
    model.quats[index], model.log_scales[index], model.sh[index] = moved
    return torch.from_numpy(growth)


def _pieces(gradients: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``gradients (P,3,3)`` float → ``(distinct (D,3,3) float64, piece (P,))`` with ``gradients == distinct[piece]``:
    rows grouped by a 64-bit hash of their bits (splitmix64 of each entry, folded), checked, and grouped exactly
    where a hash collided."""
    flat = np.ascontiguousarray(gradients.reshape(len(gradients), 9))
    bits = flat.view(np.uint32 if flat.dtype == np.float32 else np.uint64).astype(np.uint64)
    hashed = np.zeros(len(flat), dtype=np.uint64)
    with np.errstate(over="ignore"):
        for k in range(9):
            x = bits[:, k] + np.uint64(0x9E3779B97F4A7C15 * (k + 1) % 2**64)
            x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
            x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
            hashed = (hashed ^ x ^ (x >> np.uint64(31))) * np.uint64(0x100000001B3)
    _, first, piece = np.unique(hashed, return_index=True, return_inverse=True)
    distinct = flat[first]
    if not np.array_equal(distinct[piece], flat):
        distinct, piece = np.unique(flat, axis=0, return_inverse=True)
    return distinct.reshape(-1, 3, 3).astype(np.float64), piece.reshape(-1)


def _placement(deformation: ForwardMap | PlacementMap, means: torch.Tensor, frame: int) -> Placement:
    """Where ``deformation`` puts each of ``means (N,3)`` (a forward map: each once)."""
    if isinstance(deformation, PlacementMap):
        return deformation.place(means, frame)
    if isinstance(deformation, ForwardMap):
        moved = deformation.to_deformed(means, frame)
        return Placement(torch.arange(len(means)), moved.points, moved.gradient)
    raise NerfEditError(f"a {type(deformation).__name__} moves no primitives (no forward map: to_deformed or place)")


def _split(model: SplatModel, chosen: np.ndarray, f: np.ndarray, growth: np.ndarray, limit: float) -> SplatModel:
    """``model`` with the rest Gaussians ``chosen``, mapped by gradients ``f (C,3,3)`` with anisotropy ``growth``,
    split in rest space (module docstring): the first child in its parent's place, the others appended."""
    k = np.clip(np.ceil(math.sqrt(2.0) * growth / limit), 2, MAX_CHILDREN).astype(np.int64)
    quats = torch.from_numpy(model.quats[chosen]).double()
    scales = torch.exp(torch.from_numpy(model.log_scales[chosen]).double())
    axes = rotation_matrices(quats) * scales[:, None, :]
    covariance = axes @ axes.transpose(1, 2)
    gradient = torch.from_numpy(f)
    values, vectors = torch.linalg.eigh(gradient @ covariance @ gradient.transpose(1, 2))
    sigma, longest = values[:, -1].clamp_min(0).sqrt(), vectors[:, :, -1]
    u = torch.linalg.solve(gradient, longest)  # F⁻¹ e
    kf = torch.from_numpy(k).double()
    child = covariance - ((1.0 - 2.0 / kf**2) * sigma**2)[:, None, None] * u[:, :, None] * u[:, None, :]
    values, vectors = torch.linalg.eigh(child)
    vectors = vectors * torch.where(torch.linalg.det(vectors) < 0, -1.0, 1.0).to(vectors.dtype)[:, None, None]
    delta = torch.sqrt(12.0 * (1.0 - 2.0 / kf**2) / (kf**2 - 1.0))
    parent = np.repeat(np.arange(len(chosen)), k)
    j = torch.from_numpy(np.arange(len(parent)) - np.repeat(np.cumsum(k) - k, k)).double()
    t = delta[parent] * (j - (kf[parent] - 1.0) / 2.0)
    offsets = (t * sigma[parent])[:, None] * u[parent]
    source = chosen[parent]
    children = SplatModel(
        (torch.from_numpy(model.means[source]).double() + offsets).numpy(),
        matrix_quaternions(vectors).numpy()[parent],
        (0.5 * torch.log(values.clamp_min(torch.finfo(torch.float64).tiny))).numpy()[parent],
        model.opacities[source],
        model.sh[source],
    ).astype(model.means.dtype)
    head = j.numpy() == 0
    whole = SplatModel(*(a.copy() for a in model.arrays()))
    for mine, theirs in zip(whole.arrays(), children.arrays()):
        mine[chosen] = theirs[head]
    return SplatModel(*(np.concatenate([a, b[~head]]) for a, b in zip(whole.arrays(), children.arrays())))
