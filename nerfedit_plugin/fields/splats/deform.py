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
import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.bending.maps import ForwardMap, Placement, PlacementMap
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.splats.model import SplatModel
from nerfedit_plugin.fields.splats.projection import rotation_matrices
from nerfedit_plugin.fields.splats.sh_rotation import rotate_sh

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
    ``"numba"`` (``"auto"``: compiled — through a CPU :class:`DeformationField` one fused pass over the Gaussians,
    their rest tets located once per model and proxy (:func:`_location`), the polar rotations and Wigner matrices
    once per moving tet and frame; through any other map once per distinct ``F``) or ``"torch"`` (the reference,
    per Gaussian, through the map's ``to_deformed`` / ``place``)."""
    if kernel not in ("auto", "numba", "torch"):
        raise ValueError(f"kernel must be 'auto', 'numba' or 'torch', got {kernel!r}")
    out, report, moved = _deform(model, deformation, frame, kernel)
    if split_growth is None or report.moved == 0 or report.growth["max"] <= split_growth:
        return out, report
    source, gradient, growth = moved()
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


Moved = Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray]]
"""``() → (source, F, growth)`` of the moved Gaussians: the rest Gaussian each is of, its gradient ``(P,3,3)``
float64 and its anisotropy growth (made on demand: only a split needs it)."""


def _deform(
    model: SplatModel, deformation: ForwardMap | PlacementMap, frame: int, kernel: str
) -> tuple[SplatModel, DeformReport, Moved]:
    """:func:`deform_model` without splitting → ``(model, report, moved)``."""
    if kernel != "torch" and isinstance(deformation, DeformationField) and deformation.device.type == "cpu":
        return _deform_proxy(model, deformation, frame)
    dtype, count = model.means.dtype, len(model)
    placed = _placement(deformation, torch.from_numpy(np.ascontiguousarray(model.means)), frame)
    source = placed.source.cpu().numpy()
    kept = int(np.count_nonzero(np.bincount(source, minlength=count)))
    out = SplatModel(*(a[source] for a in model.arrays()))  # fresh arrays, updated in place below
    points, gradient = placed.points.cpu(), placed.gradient.cpu()
    means = torch.from_numpy(out.means).to(points.dtype)
    eye = torch.eye(3, dtype=gradient.dtype)
    rows = torch.nonzero((points != means).any(1) | (gradient != eye).flatten(1).any(1)).squeeze(1)
    report = DeformReport(count, len(source), count - kept, len(source) - kept, len(rows))
    index, f = rows.numpy(), gradient.index_select(0, rows)
    if len(rows) == 0:
        return out, report, lambda: (source[index], f.double().numpy(), np.ones(0))
    out.means[index] = points.index_select(0, rows).numpy()
    growth = (_move_torch if kernel == "torch" else _move_compiled)(out, index, f, report).numpy()
    report.growth = _growth(growth)
    return out.astype(dtype), report, lambda: (source[index], f.double().numpy(), growth)


def _growth(growth: np.ndarray) -> dict[str, float]:
    return {"max": float(growth.max()), "p99": float(np.percentile(growth, 99))}


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


class _Tables(NamedTuple):
    """Per gradient: its record (:func:`nerfedit_plugin.fields.splats._deform_kernel.piece_tables`: the polar
    rotation, the stretch ``Rᵀ F`` and the Wigner matrices of bands 1–3, float64) and whether ``det F < 0``."""

    records: np.ndarray
    inverted: np.ndarray


def _tables(gradients: np.ndarray) -> _Tables:
    """:class:`_Tables` of ``gradients (P,3,3)`` float64, compiled, parallel over gradients."""
    from nerfedit_plugin.fields.splats._deform_kernel import RECORD, piece_tables
    from nerfedit_plugin.geometry.launch import launch

    gradients = np.ascontiguousarray(gradients, dtype=np.float64)
    tables = _Tables(np.empty((len(gradients), RECORD)), np.empty(len(gradients), dtype=np.bool_))
    launch(piece_tables, gradients, *tables)
    return tables


def _move_compiled(model: SplatModel, index: np.ndarray, f: torch.Tensor, report: DeformReport) -> torch.Tensor:
    """:func:`_move_torch` with the polar rotations and Wigner matrices computed once per distinct gradient (``F`` is
    constant per tet) and the per-Gaussian work in one compiled pass on the model's arrays
    (:mod:`._deform_kernel`)."""
    from nerfedit_plugin.fields.splats._deform_kernel import move_rows
    from nerfedit_plugin.geometry.launch import launch

    table, piece = _pieces(f.numpy())
    tables = _tables(table)
    report.inverted = int(tables.inverted[piece].sum())
    growth = np.empty(len(index))
    arrays = [np.ascontiguousarray(a) for a in (model.quats, model.log_scales, model.sh)]
    launch(move_rows, np.ascontiguousarray(index), piece, tables.records, *arrays, growth)
    model.quats, model.log_scales, model.sh = arrays
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


# ---- through a tet proxy: located once, one fused pass per frame -------------------------------------------------

LOCATIONS_KEPT = 2
"""Located models kept per proxy (the model and, say, its split children)."""

FRAMES_KEPT = 4
"""Frames of per-tet tables kept per located model."""

_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # DeformationField → [_Location], newest last
_CACHE_LOCK = threading.Lock()


@dataclass(eq=False)
class _Location:
    """Where the rest means ``means`` (a copy: the key) lie in a proxy's rest tets: ``tet (N,)`` int64 (-1 outside),
    ``bary (4,N)`` (computed in the proxy's dtype, stored as float64), ``used`` the tets that hold some, their rest edge
    inverses ``D⁻¹`` (float64) and whether ``D`` is regular; per frame, :class:`_Frame`."""

    means: np.ndarray
    tet: np.ndarray
    bary: np.ndarray
    used: np.ndarray
    inverse: np.ndarray
    regular: np.ndarray
    frames: OrderedDict = field(default_factory=OrderedDict)


class _Frame(NamedTuple):
    """A frame's moving tets among the used ones: ``slot (K,)`` their row in the tables (-1: still or empty), gradients
    ``(T,3,3)`` (float64 holding values of the proxy's dtype), whether each is exactly ``I``, and their
    :class:`_Tables`."""

    slot: np.ndarray
    gradient: np.ndarray
    identity: np.ndarray
    tables: _Tables


def _location(deformation: DeformationField, means: np.ndarray) -> _Location:
    """The rest tets of ``means`` in ``deformation``'s proxy, located by its rest locator (the one ``to_deformed``
    uses: exact, the tet brute force picks) on the first call, then from the cache while the proxy lives and the
    means are the same."""
    with _CACHE_LOCK:
        entries = _CACHE.setdefault(deformation, [])
        for entry in entries:
            if entry.means.shape == means.shape and entry.means.dtype == means.dtype:
                if np.array_equal(entry.means, means):
                    entries.remove(entry)
                    entries.append(entry)
                    return entry
    tet, bary = deformation.locate_rest(torch.from_numpy(np.ascontiguousarray(means)))
    tet = tet.numpy()
    used = np.unique(tet)
    used = used[used >= 0]
    rest = torch.as_tensor(deformation.rest_vertices)[torch.as_tensor(deformation.tets[used])]
    edges = (rest[:, 1:] - rest[:, :1]).transpose(1, 2)  # D: the rest edges as columns
    regular = torch.linalg.det(edges) != 0
    eye = torch.eye(3, dtype=torch.float64)
    inverse = torch.linalg.inv(torch.where(regular[:, None, None], edges, eye)).numpy()
    bary = bary.t().numpy().astype(np.float64)  # exact: one kernel for either dtype
    entry = _Location(means.copy(), tet, bary, used, inverse, regular.numpy())
    with _CACHE_LOCK:
        entries = _CACHE.setdefault(deformation, [])
        entries.append(entry)
        del entries[:-LOCATIONS_KEPT]
    return entry


def _frame(deformation: DeformationField, location: _Location, frame: int) -> _Frame:
    """:class:`_Frame` of ``frame`` (cached per location): the gradients ``D' D⁻¹`` of the used tets that are not
    still (float64, then the proxy's dtype, as ``to_deformed``'s; the identity for degenerate rest tets), their polar
    rotations and Wigner matrices, in one compiled pass over those tets."""
    from nerfedit_plugin.fields.splats._deform_kernel import RECORD, tet_tables
    from nerfedit_plugin.geometry.launch import launch

    with _CACHE_LOCK:
        if frame in location.frames:
            location.frames.move_to_end(frame)
            return location.frames[frame]
    chosen = np.flatnonzero(~deformation.still_tets(frame)[location.used])
    n = len(chosen)
    gradient, identity = np.empty((n, 3, 3)), np.empty(n, dtype=np.bool_)
    tables = _Tables(np.empty((n, RECORD)), np.empty(n, dtype=np.bool_))
    launch(
        tet_tables,
        chosen,
        location.used,
        deformation.tets,
        location.inverse,
        location.regular,
        deformation.deformed_vertices[frame],
        _single(deformation),
        gradient,
        identity,
        *tables,
    )
    slot = np.full(len(deformation.tets), -1, dtype=np.int64)
    slot[location.used[chosen]] = np.arange(n)
    result = _Frame(slot, gradient, identity, tables)
    with _CACHE_LOCK:
        location.frames[frame] = result
        while len(location.frames) > FRAMES_KEPT:
            location.frames.popitem(last=False)
    return result


def _deform_proxy(
    model: SplatModel, deformation: DeformationField, frame: int
) -> tuple[SplatModel, DeformReport, Moved]:
    """:func:`_deform` through a tet proxy on the CPU: the cached location, the frame's per-tet tables, then one
    compiled pass over the Gaussians (:func:`nerfedit_plugin.fields.splats._deform_kernel.map_gaussians`), which
    writes the output model in the model's dtype. Equal to the reference through ``to_deformed``."""
    from nerfedit_plugin.fields.splats._deform_kernel import map_gaussians
    from nerfedit_plugin.geometry.launch import launch

    frame = deformation._check_frame(frame)
    arrays = [np.ascontiguousarray(a) for a in model.arrays()]
    location = _location(deformation, arrays[0])
    tables = _frame(deformation, location, frame)
    out = SplatModel(*(np.empty_like(a) for a in arrays))
    count = len(model)
    moved, growth = np.empty(count, dtype=np.uint8), np.empty(count)
    launch(
        map_gaussians,
        location.tet,
        location.bary,
        tables.slot,
        deformation.tets,
        deformation.deformed_vertices[frame],
        _single(deformation),
        tables.identity,
        tables.tables.records,
        *arrays,
        *out.arrays(),
        moved,
        growth,
    )
    index = np.flatnonzero(moved)
    report = DeformReport(count, count, 0, 0, len(index))
    if len(index) == 0:
        return out, report, lambda: (index, np.zeros((0, 3, 3)), np.ones(0))
    piece = tables.slot[location.tet[index]]
    if tables.tables.inverted.any():
        report.inverted = int(tables.tables.inverted[piece].sum())
    growth = growth[index]
    report.growth = _growth(growth)
    return out, report, lambda: (index, tables.gradient[piece], growth)


def _single(deformation: DeformationField) -> bool:
    """Whether the proxy maps in float32 (else float64)."""
    if deformation.dtype not in (torch.float32, torch.float64):
        raise NerfEditError(f"the forward map supports float32 and float64 proxies, not {deformation.dtype}")
    return deformation.dtype == torch.float32


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
