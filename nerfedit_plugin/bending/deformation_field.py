"""DeformationField: a tet proxy in canonical space T and its deformed copies T' (one per frame); ray bending.

``to_canonical(x (M,3), frame)`` maps deformed-space points to canonical space: a point in deformed tet ``t`` with
barycentrics ``b`` maps to ``x_c = Σ b_i r_i`` (``r_i`` the rest corners), the affine map ``A_t x + c_t`` with
Jacobian ``A_t = [r1-r0, r2-r0, r3-r0] [d1-d0, d2-d0, d3-d0]^-1``. Inside T' → mapped; outside T' but inside the
rest proxy T → ``empty`` (vacated); outside both → identity (``x_c = x``, ``J = I``). *Still* tets (no corner moved
by more than ``MOVED_TOLERANCE`` × the rest proxy's extent) map by the exact identity. Saved as ``deformation.npz``:
``rest_vertices (N,3)``, ``tets (K,4)``, ``deformed_vertices (F,N,3)``. Semantics, degenerate and inverted tets,
and the near-grid fast path: docs/architecture.md, "Ray bending".
"""

from __future__ import annotations

import os
import zipfile
from typing import NamedTuple

import numpy as np
import torch

from nerfedit_plugin.bending.locate import TetLocator, face_pairs
from nerfedit_plugin.bending.maps import BentPoints, CanonicalPoints, DeformedPoints
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import atomic_path

FORMAT_VERSION = 1
KEYS = ("rest_vertices", "tets", "deformed_vertices")


NEAR_CELLS = 96
"""Cells per axis of the per-frame grid that tells which points need point location."""

MOVED_TOLERANCE = 1e-6
"""Displacements up to this fraction of the rest proxy's extent count as none (still tets)."""


def validate_arrays(rest, tets, deformed, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arrays as (N,3) f64, (K,4) i64, (F,N,3) f64, or :class:`NerfEditError` naming ``where`` and the key."""
    rest, tets, deformed = (
        x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x) for x in (rest, tets, deformed)
    )
    if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 4:
        raise NerfEditError(f"{where}: rest_vertices: expected shape (N>=4, 3), got {rest.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4 or len(tets) == 0:
        raise NerfEditError(f"{where}: tets: expected shape (K>=1, 4), got {tets.shape}")
    if deformed.ndim == 2:
        deformed = deformed[None]
    if deformed.ndim != 3 or deformed.shape[1:] != rest.shape or len(deformed) == 0:
        raise NerfEditError(f"{where}: deformed_vertices: expected shape (F>=1, {len(rest)}, 3), got {deformed.shape}")
    for key, array in (("rest_vertices", rest), ("deformed_vertices", deformed)):
        if not np.issubdtype(array.dtype, np.number) or not np.isfinite(array).all():
            raise NerfEditError(f"{where}: {key}: values must be finite numbers")
    if not np.issubdtype(tets.dtype, np.integer):
        if not np.issubdtype(tets.dtype, np.floating) or not np.array_equal(tets, np.round(tets)):
            raise NerfEditError(f"{where}: tets: expected integer vertex indices, got {tets.dtype}")
    if tets.min() < 0 or tets.max() >= len(rest):
        raise NerfEditError(f"{where}: tets: vertex index out of range [0, {len(rest)})")
    return rest.astype(np.float64), tets.astype(np.int64), deformed.astype(np.float64)


class _Frame(NamedTuple):
    locator: TetLocator
    rest_rows: torch.Tensor  # (K,12): r0, then R = [r1-r0, r2-r0, r3-r0] (rest edges as columns) row-major
    still: torch.Tensor  # (K,) bool: DeformationField.still_tets (the map is the identity there)
    jacobian: torch.Tensor  # (K+1,3,3): A_t, then the identity (row K, for points outside T')
    near: tuple[torch.Tensor, torch.Tensor, torch.Tensor]  # see _near_grid


def _near_grid(deformed: TetLocator, rest: TetLocator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(scale (3,), origin (3,), mask ((C+2)³,) uint8)``, ``C = NEAR_CELLS``: cell coordinates ``u = (x − origin)
    scale + 1`` lie in ``[1, C+1)`` over the union of the locators' boxes (:meth:`TetLocator.boxes`: set sub-cells
    of their occupancy masks); the border layer (cells 0 and C+1) takes every point outside it. Subtracting the
    origin first keeps the rounding error of ``u`` below ``|u| 2⁻²³`` cells (~10⁻⁵, far inside the 10⁻³-cell
    padding) wherever the grid lies; ``x scale + offset`` cancels, with an error of ``|x| scale 2⁻²⁴`` cells. Bit 1 of
    a cell: a box of T' (``deformed``), padded by 10⁻³ cell, touches it and a tet of T' may reach it
    (:meth:`TetLocator.reach_cells`); bit 2: the same for T; bit 4: every point of the cell is inside T
    (:meth:`TetLocator.covered_cells`). Points in a cell without bit 1 (2) are outside every tet of T' (T)."""
    bounds = [box for box in (deformed.box_bounds(), rest.box_bounds()) if box is not None]
    dtype, device, side = deformed.dtype, deformed.device, NEAR_CELLS + 2
    mask = torch.zeros(side**3, dtype=torch.uint8, device=device)
    if not bounds:
        return torch.ones(3, dtype=dtype, device=device), torch.zeros(3, dtype=dtype, device=device), mask
    lo = torch.stack([box[0] for box in bounds]).amin(0).to(device)
    hi = torch.stack([box[1] for box in bounds]).amax(0).to(device)
    origin, extent = lo.to(dtype), (hi - lo).clamp_min(1e-12)
    scale = (NEAR_CELLS * (1 - 1e-6) / extent).to(dtype)
    # u = x scale64 + offset64 in float64: the map the points take, up to their rounding error
    scale64, offset64 = scale.to(torch.float64), 1.0 - origin.to(torch.float64) * scale.to(torch.float64)
    for bit, locator in zip((1, 2), (deformed, rest)):
        marked = locator.boxed_cells(scale64, offset64, side) & locator.reach_cells(scale64, offset64, side)
        mask |= marked.to(torch.uint8) * bit
    mask |= rest.covered_cells(scale64, offset64, side).to(torch.uint8) * 4
    return scale, origin, mask


def _near(grid: tuple[torch.Tensor, torch.Tensor, torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """``(M,)`` uint8: the bits of the points' cells in :func:`_near_grid` (NaN points: 0). One coordinate column
    at a time: ``floor(clamp((x − origin) scale + 1, 0, C+1))`` times the cell stride, summed (ids < 2²⁴:
    exact)."""
    scale, origin, mask = grid
    side = NEAR_CELLS + 2
    cell = None
    for i, stride in enumerate((side * side, side, 1)):
        u = (x[:, i] - origin[i]).mul_(scale[i]).add_(1.0).clamp_(0.0, side - 1.0).floor_()
        cell = u.mul_(stride) if cell is None else cell.add_(u, alpha=stride)
    return mask.index_select(0, torch.nan_to_num_(cell, nan=0.0).to(torch.int64))


class DeformationField:
    """Tet proxy in canonical space T plus its deformed copies T' per frame; maps deformed-space points to canonical
    (a :class:`~nerfedit_plugin.bending.maps.BackwardMap`) and rest points to deformed space (a
    :class:`~nerfedit_plugin.bending.maps.ForwardMap`).

    ``rest_vertices (N,3)``, ``tets (K,4)`` int, ``deformed_vertices (F,N,3)`` (or ``(N,3)`` for one frame), arrays
    or tensors, stored as float64 / int64 numpy arrays; points are mapped in ``dtype`` on ``device``.
    """

    def __init__(
        self, rest_vertices, tets, deformed_vertices, *, device="cpu", dtype=torch.float32, kernel: str = "auto"
    ):
        self.rest_vertices, self.tets, self.deformed_vertices = validate_arrays(
            rest_vertices, tets, deformed_vertices, "DeformationField"
        )
        self.device, self.dtype = torch.device(device), dtype
        if kernel not in ("auto", "numba", "torch") or (kernel == "numba" and self.device.type != "cpu"):
            raise ValueError(f"kernel must be 'auto', 'torch' or (on the CPU) 'numba', got {kernel!r}")
        self.kernel = kernel  # TetLocator's: "auto" (compiled on the CPU), "numba" or "torch"
        self._frames: dict[int, _Frame] = {}
        self._still: dict[int, np.ndarray] = {}
        self._moved: dict[int, np.ndarray | None] = {}
        self._rest_locator: TetLocator | None = None
        self._face_pairs: torch.Tensor | None = None  # the tets' shared faces (topology only), for every locator

    @property
    def n_frames(self) -> int:
        return len(self.deformed_vertices)

    def offsets(self, frame: int) -> np.ndarray:
        """``rest - deformed[frame]`` (N,3) float64: the paper's barycentric offsets."""
        return self.rest_vertices - self.deformed_vertices[self._check_frame(frame)]

    def still_tets(self, frame: int = 0) -> np.ndarray:
        """``(K,)`` bool: no corner of the tet is displaced in ``frame`` by more than ``MOVED_TOLERANCE`` × the rest
        proxy's extent (the map is the identity there)."""
        frame = self._check_frame(frame)
        if frame not in self._still:
            rest = self.rest_vertices
            extent = float(np.ptp(rest, axis=0).max()) if len(rest) else 0.0
            displaced = np.linalg.norm(self.deformed_vertices[frame] - rest, axis=1) > MOVED_TOLERANCE * extent
            self._still[frame] = ~displaced[self.tets].any(1)
        return self._still[frame]

    def moved_bounds(self, frame: int = 0) -> np.ndarray | None:
        """``(2,3)`` float64 (lo, hi) bounding box of the deformed corners of the tets of ``frame`` that are not still;
        None if all are. Every other point of space maps to itself or is vacated, so content appears elsewhere than
        at its rest place only inside this box (the renderer's sampling box adds it to the scene box; an identity
        edit adds nothing)."""
        frame = self._check_frame(frame)
        if frame not in self._moved:
            corners = self.deformed_vertices[frame][self.tets[~self.still_tets(frame)]].reshape(-1, 3)
            self._moved[frame] = np.stack([corners.min(0), corners.max(0)]) if len(corners) else None
        return self._moved[frame]

    def _check_frame(self, frame: int) -> int:
        if not 0 <= frame < self.n_frames:
            raise NerfEditError(f"frame {frame} out of range: the deformation field has {self.n_frames} frame(s)")
        return int(frame)

    def _frame(self, frame: int) -> _Frame:
        frame = self._check_frame(frame)
        if frame not in self._frames:
            tets = torch.as_tensor(self.tets, device=self.device)
            rest = torch.as_tensor(self.rest_vertices, device=self.device)[tets]
            deformed = torch.as_tensor(self.deformed_vertices[frame], device=self.device)
            corners = deformed[tets]
            still = torch.as_tensor(self.still_tets(frame), device=self.device)
            edges_rest = (rest[:, 1:] - rest[:, :1]).transpose(1, 2)  # (K,3,3) columns
            edges = (corners[:, 1:] - corners[:, :1]).transpose(1, 2)
            ok = (torch.linalg.det(edges) != 0) & ~still  # the others get A_t = I
            eye = torch.eye(3, dtype=torch.float64, device=self.device)
            jacobian = edges_rest @ torch.linalg.inv(torch.where(ok[:, None, None], edges, eye))
            unmoved = np.array_equal(self.deformed_vertices[frame], self.rest_vertices)
            locator = self._rest() if unmoved else self._locator(deformed)  # a frame at rest shares its locator
            near = _near_grid(locator, self._rest())
            self._frames[frame] = _Frame(
                locator,
                torch.cat([rest[:, 0], edges_rest.reshape(-1, 9)], 1).to(self.dtype),
                still,
                torch.cat([torch.where(ok[:, None, None], jacobian, eye), eye[None]]).to(self.dtype),
                near,
            )
        return self._frames[frame]

    def locate_rest(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Rest tet ``(M,)`` (-1 outside the proxy) and barycentrics ``(M,4)`` of points ``x (M,3)`` in the field's
        dtype, by the rest locator :meth:`bend` and :meth:`to_deformed` use (exact: the tet brute force picks)."""
        return self._rest().locate(torch.as_tensor(x).to(device=self.device, dtype=self.dtype).reshape(-1, 3))

    def _rest(self) -> TetLocator:
        if self._rest_locator is None:
            self._rest_locator = self._locator(self.rest_vertices)
        return self._rest_locator

    def _locator(self, vertices) -> TetLocator:
        """A point locator of the tets on ``vertices`` (the rest or a deformed proxy), sharing the face pairs."""
        if self._face_pairs is None:
            self._face_pairs = face_pairs(torch.as_tensor(self.tets, device=self.device))
        return TetLocator(
            vertices, self.tets, dtype=self.dtype, device=self.device, kernel=self.kernel, face_pairs=self._face_pairs
        )

    def bend(
        self, x: torch.Tensor, frame: int = 0, *, out: torch.Tensor | None = None, tets: bool = True
    ) -> BentPoints:
        """Map deformed-space points ``x (M,3)`` of ``frame`` to canonical space; report each point's deformed tet
        (see the module docstring; ``tet`` is None with ``tets=False``, for callers that need no Jacobian). ``out``:
        an ``(M,3)`` tensor that receives ``x_c`` (and is returned as ``points``); it may be ``x`` itself, to bend
        in place. Otherwise ``x`` is not modified. → :class:`BentPoints`: ``points (M,3)`` (the field's dtype),
        ``tet (M,)`` int64 or None, ``empty (M,)`` bool."""
        mapping = self._frame(frame)
        x = torch.as_tensor(x)
        if out is not None and out.shape != (len(x), 3):
            raise ValueError(f"bend: out must have shape ({len(x)}, 3), got {tuple(out.shape)}")
        source = x.to(device=self.device, dtype=self.dtype).reshape(-1, 3)
        direct = out is not None and out.dtype == self.dtype and out.device == self.device and out.is_contiguous()
        target = out if direct else torch.empty_like(source)
        if mapping.locator.kernel == "numba":
            tet, empty = self._bend_compiled(mapping, source, target, tets)
        else:
            tet, empty = self._bend_torch(mapping, source, target)
        if out is not None and not direct:
            target = out.copy_(target)
        return BentPoints(target, tet if tets else None, empty)

    def _bend_compiled(
        self, mapping: _Frame, x: torch.Tensor, out: torch.Tensor, tets: bool
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`bend` in one compiled pass (:mod:`nerfedit_plugin.bending._bend_kernel`): writes ``out``, returns
        ``(tet, empty)`` (``tet`` empty without ``tets``)."""
        from nerfedit_plugin.bending._bend_kernel import bend_points
        from nerfedit_plugin.geometry.launch import launch

        x = x.contiguous()
        tet = torch.full((len(x) if tets else 0,), -1, dtype=torch.int64)
        empty = torch.zeros(len(x), dtype=torch.bool)
        if out.data_ptr() != x.data_ptr():
            out.copy_(x)
        scale, origin, mask = (t.numpy() for t in mapping.near)
        rest = self._rest()
        launch(
            bend_points,
            x.numpy(),
            scale,
            origin,
            mask,
            NEAR_CELLS + 2,
            mapping.locator.arrays,
            rest.arrays,
            mapping.rest_rows.numpy(),
            mapping.still.numpy(),
            rest.rounds,
            out.numpy(),
            tet.numpy(),
            empty.numpy(),
        )
        return tet, empty

    def _bend_torch(self, mapping: _Frame, x: torch.Tensor, out: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`bend` vectorised over points in torch (any device): writes ``out``, returns ``(tet, empty)``."""
        code = _near(mapping.near, x)
        near = torch.nonzero(code.bitwise_and(1)).squeeze(1)
        found, bary = mapping.locator.locate(x.index_select(0, near))
        inside = torch.nonzero(found >= 0).squeeze(1)
        code.index_fill_(0, near.index_select(0, inside), 0)  # points in T' are not empty
        idx = inside[~mapping.still.index_select(0, found.index_select(0, inside))]  # still tets: x_c = x
        r = mapping.rest_rows.index_select(0, found.index_select(0, idx)).t()  # (12,P)
        b = bary.t().index_select(1, idx)  # (4,P)
        mapped = [
            r[i] + r[3 + 3 * i] * b[1] + r[4 + 3 * i] * b[2] + r[5 + 3 * i] * b[3] for i in range(3)
        ]  # r0 + R (b1, b2, b3) = Σ b_i r_i
        rows = near.index_select(0, idx)
        empty = code.bitwise_and(4).to(torch.bool)
        unsure = torch.nonzero(code.bitwise_and_(6).eq_(2)).squeeze(1)
        empty.index_fill_(0, unsure[self._rest().member(x.index_select(0, unsure)) >= 0], True)
        if out.data_ptr() != x.data_ptr():
            out.copy_(x)
        out.index_copy_(0, rows, torch.stack(mapped, 1))
        tet = torch.full((len(x),), -1, dtype=torch.int64, device=self.device).index_copy_(0, near, found)
        return tet, empty

    def jacobian(self, tet: torch.Tensor, frame: int = 0) -> torch.Tensor:
        """tet (M,) int64 → ``(M,3,3)`` dx_c/dx (the field's dtype and device) of points in deformed tets ``tet`` of
        ``frame`` (identity where ``tet`` is -1)."""
        table = self._frame(frame).jacobian
        tet = torch.as_tensor(tet, device=self.device)
        return table.index_select(0, torch.where(tet >= 0, tet, len(table) - 1))

    def to_canonical(self, x: torch.Tensor, frame: int = 0) -> CanonicalPoints:
        """Map deformed-space points ``x (M,3)`` of ``frame`` to canonical space (see the module docstring) →
        :class:`CanonicalPoints`: ``points (M,3)``, ``inside (M,)`` bool, ``empty (M,)`` bool, ``jacobian (M,3,3)``,
        in the field's dtype (float32 by default) on its device."""
        bent = self.bend(x, frame)
        return CanonicalPoints(bent.points, bent.tet >= 0, bent.empty, self.jacobian(bent.tet, frame))

    def to_deformed(self, x: torch.Tensor, frame: int = 0) -> DeformedPoints:
        """Map rest points ``x (M,3)`` to deformed space in ``frame``: a point in rest tet ``t`` with barycentrics
        ``b`` goes to ``Σ b_i d_i`` (``d_i`` the tet's corners in the frame), with gradient ``F_t = D'_t D_t⁻¹``
        (``D`` the tet's edge vectors ``[r1-r0, r2-r0, r3-r0]``, ``D'`` the deformed ones); points outside the rest
        proxy, and points in still tets, map by the exact identity. → :class:`DeformedPoints` in the field's dtype on
        its device (points located as by :meth:`bend`'s rest locator: exact, the same tet as brute force)."""
        frame = self._check_frame(frame)
        x = torch.as_tensor(x).to(device=self.device, dtype=self.dtype).reshape(-1, 3)
        tet, bary = self._rest().locate(x)
        still = torch.as_tensor(self.still_tets(frame), device=self.device)
        moving = torch.nonzero(tet >= 0).squeeze(1)
        moving = moving[~still.index_select(0, tet.index_select(0, moving))]
        found = tet.index_select(0, moving)
        tets = torch.as_tensor(self.tets, device=self.device).index_select(0, found)
        deformed = torch.as_tensor(self.deformed_vertices[frame], device=self.device)[tets]  # (P,4,3) float64
        points = x.clone()
        points.index_copy_(0, moving, (bary.index_select(0, moving).double()[:, :, None] * deformed).sum(1).to(x))
        gradient = torch.eye(3, dtype=self.dtype, device=self.device).repeat(len(x), 1, 1)
        gradient.index_copy_(0, moving, self._gradients(frame).index_select(0, found))
        return DeformedPoints(points, tet >= 0, gradient)

    def _gradients(self, frame: int) -> torch.Tensor:
        """``(K,3,3)`` the deformation gradients ``D' D⁻¹`` of ``frame``'s tets (identity for degenerate ones)."""
        tets = torch.as_tensor(self.tets, device=self.device)
        rest = torch.as_tensor(self.rest_vertices, device=self.device)[tets]
        deformed = torch.as_tensor(self.deformed_vertices[frame], device=self.device)[tets]
        edges_rest = (rest[:, 1:] - rest[:, :1]).transpose(1, 2)
        edges = (deformed[:, 1:] - deformed[:, :1]).transpose(1, 2)
        ok = torch.linalg.det(edges_rest) != 0
        eye = torch.eye(3, dtype=torch.float64, device=self.device)
        inverse = torch.linalg.inv(torch.where(ok[:, None, None], edges_rest, eye))
        return torch.where(ok[:, None, None], edges @ inverse, eye).to(self.dtype)

    def save(self, path: str | os.PathLike) -> None:
        """Write ``deformation.npz`` atomically."""
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez(
                handle,
                format_version=np.int64(FORMAT_VERSION),
                rest_vertices=self.rest_vertices,
                tets=self.tets,
                deformed_vertices=self.deformed_vertices,
            )

    @classmethod
    def load(cls, path: str | os.PathLike, *, device="cpu", dtype=torch.float32) -> DeformationField:
        """Read a ``deformation.npz``; a missing, corrupt or incomplete file raises :class:`NerfEditError`."""
        if not os.path.isfile(path):
            raise NerfEditError(f"{path}: deformation file not found")
        try:
            with np.load(path, allow_pickle=False) as data:
                names = set(data.files)
                missing = [key for key in ("format_version", *KEYS) if key not in names]
                if missing:
                    raise NerfEditError(f"{path}: missing key '{missing[0]}' (expected {', '.join(KEYS)})")
                version = data["format_version"]
                if version.shape != () or int(version) != FORMAT_VERSION:
                    raise NerfEditError(f"{path}: format_version: unsupported {version} (expected {FORMAT_VERSION})")
                arrays = [data[key] for key in KEYS]
        except NerfEditError:
            raise
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
            raise NerfEditError(f"{path}: not a readable deformation .npz ({error})") from None
        return cls(*validate_arrays(*arrays, str(path)), device=device, dtype=dtype)

    @classmethod
    def identity(cls, vertices, tets, n_frames: int = 1, **kwargs) -> DeformationField:
        """vertices (N,3), tets (K,4) → a field whose ``n_frames`` frames all equal the rest proxy."""
        vertices = np.asarray(vertices, dtype=np.float64)
        return cls(vertices, tets, np.repeat(vertices[None], n_frames, axis=0), **kwargs)
