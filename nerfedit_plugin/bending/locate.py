"""Exact point location in a tetrahedral mesh: :class:`TetLocator` (a uniform grid of per-cell tet lists plus a
walk across faces) and :func:`locate_brute_force` (the oracle), in torch.

Rule, shared bit for bit by both: point ``p`` lies in tet ``t`` iff ``min_i b_i(p) >= -eps`` (barycentrics ``b``
evaluated one element-wise op at a time in the working dtype; ``eps`` = :data:`EPS`); when several tets contain
``p`` the smallest index wins; tets of (near) zero volume never contain a point.
``TetLocator(vertices (N,3), tets (K,4)).locate(points (M,3)) → (tet (M,) int64, -1 outside; bary (M,4))``.
The grid, the walk and why its answer equals brute force: docs/architecture.md, "Point location".
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np
import torch

EPS = {torch.float32: 1e-5, torch.float64: 1e-12}
"""Containment tolerance on barycentrics per working dtype."""

DEEP = 1e-3
"""A point accepted with ``min b >= DEEP`` by a safe tet is resolved without looking further."""

_MAX_BARY_ERROR = 1e-2
"""Tets whose barycentric rounding-error bound ``16 u κ`` exceeds this are degenerate (skipped)."""

_MAX_CELLS = 1 << 22
"""Grid size cap; also keeps padded cell ids exact in float32 arithmetic (< 2**24)."""

_BATCH = 1 << 21
"""Candidate pairs processed at once while building (bounds build memory)."""

_SUB = 4
"""Sub-cells per cell axis in the occupancy masks (4**3 = 64 bits per cell)."""

if TYPE_CHECKING:
    from nerfedit_plugin.bending._locate_kernel import LocatorArrays


def _as_tensor(array, dtype: torch.dtype | None = None, device=None) -> torch.Tensor:
    tensor = array if isinstance(array, torch.Tensor) else torch.as_tensor(np.asarray(array))
    return tensor.to(device=device if device is not None else tensor.device, dtype=dtype or tensor.dtype)


class _TetTable:
    """Per-tet data: rows ``[v0 (3), Minv row-major (9)]`` in the working dtype, float64 geometry, usable mask."""

    def __init__(self, vertices, tets, dtype: torch.dtype, device=None):
        if dtype not in EPS:
            raise ValueError(f"point location supports float32 and float64, not {dtype}")
        vertices = _as_tensor(vertices, device=device)
        self.dtype, self.device, self.eps = dtype, vertices.device, EPS[dtype]
        self.tets = _as_tensor(tets, torch.int64, self.device)
        if vertices.ndim != 2 or vertices.shape[1] != 3:
            raise ValueError(f"vertices: expected shape (N, 3), got {tuple(vertices.shape)}")
        if self.tets.ndim != 2 or self.tets.shape[1] != 4:
            raise ValueError(f"tets: expected shape (K, 4), got {tuple(self.tets.shape)}")
        if len(self.tets) and (self.tets.min() < 0 or self.tets.max() >= len(vertices)):
            raise ValueError(f"tets: vertex index out of range [0, {len(vertices)})")
        # Geometry as the working dtype sees it, then float64 math on it.
        self.corners = vertices.to(dtype).to(torch.float64)[self.tets]  # (K,4,3)
        edges = (self.corners[:, 1:] - self.corners[:, :1]).transpose(1, 2)  # columns v1-v0, v2-v0, v3-v0
        det = torch.linalg.det(edges)
        lo, hi = self.corners.amin(1), self.corners.amax(1)
        extent = (hi - lo).amax(1)
        ok = torch.isfinite(det) & (det != 0) & (extent > 0)
        eye = torch.eye(3, dtype=torch.float64, device=self.device)
        minv = torch.linalg.inv(torch.where(ok[:, None, None], edges, eye))
        self.grads = torch.cat([-minv.sum(1, keepdim=True), minv], 1)  # (K,4,3): gradient of b_i
        kappa = minv.abs().sum(2).amax(1) * extent
        self.error = 16 * (torch.finfo(dtype).eps / 2) * kappa  # bound on |computed b - exact b| near the tet
        self.usable = ok & torch.isfinite(kappa) & (self.error <= _MAX_BARY_ERROR)
        self.tolerance = torch.where(self.usable, self.eps + self.error, 0.0)  # accepted => exact b_i >= -tol
        self.rows = torch.cat([self.corners[:, 0], minv.reshape(-1, 9)], 1).to(dtype)  # (K,12)
        self.columns = self.rows.t().contiguous()  # (12,K): gathers of it give contiguous coefficient rows
        margin = (4 * self.tolerance * extent)[:, None]
        self.box_lo = _round(lo - margin, dtype, -1)
        self.box_hi = _round(hi + margin, dtype, +1)

    def __len__(self) -> int:
        return len(self.rows)

    def exact_bary(self, tet: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        """float64 barycentrics ``(..., 4)`` of ``points (..., P, 3)`` in tets ``tet (...)``."""
        b = torch.einsum("...ij,...pj->...pi", self.grads[tet], points - self.corners[tet, None, 0])
        b[..., 0] += 1
        return b


def _round(x: torch.Tensor, dtype: torch.dtype, direction: int) -> torch.Tensor:
    """Cast float64 ``x`` to ``dtype`` rounding outward (down for ``direction=-1``, up for ``+1``)."""
    y = x.to(dtype)
    step = torch.nextafter(y, torch.full_like(y, direction * float("inf")))
    return torch.where(y.to(torch.float64) * direction < x * direction, step, y)


def barycentric(rows: torch.Tensor, points: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """``(b0, b1, b2, b3)`` of ``points (...,3)`` in tets given by table ``rows (...,12)`` (broadcasting).

    One element-wise op at a time, so the values are bit-identical for any batch shape or layout.
    """
    dx = points[..., 0] - rows[..., 0]
    dy = points[..., 1] - rows[..., 1]
    dz = points[..., 2] - rows[..., 2]
    b1 = rows[..., 3] * dx + rows[..., 4] * dy + rows[..., 5] * dz
    b2 = rows[..., 6] * dx + rows[..., 7] * dy + rows[..., 8] * dz
    b3 = rows[..., 9] * dx + rows[..., 10] * dy + rows[..., 11] * dz
    b0 = 1 - (b1 + b2 + b3)
    return b0, b1, b2, b3


def _min_bary(b: tuple[torch.Tensor, ...]) -> torch.Tensor:
    return torch.minimum(torch.minimum(b[0], b[1]), torch.minimum(b[2], b[3]))


_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
_FACES = ((1, 2, 3), (0, 2, 3), (0, 1, 3), (0, 1, 2))


def _separated(table: _TetTable, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """True where no point that tet ``b`` accepts can be DEEP-accepted by tet ``a`` (rigorous, with tolerances).

    Compares ``{exact b^a >= DEEP - err_a}`` (tet ``a`` shrunk about its centroid) with ``{exact b^b >= -tol_b}``
    (tet ``b`` grown): both are tetrahedra, separated when some axis has their projections disjoint. Face normals
    (8 axes) settle almost every pair; the rest also try the 36 edge-edge cross products.
    """
    deep = (DEEP - table.error[a])[:, None, None]
    tol = table.tolerance[b][:, None, None]
    va, vb = table.corners[a], table.corners[b]
    shrunk = (1 - 4 * deep) * va + deep * va.sum(1, keepdim=True)
    grown = (1 + 4 * tol) * vb - tol * vb.sum(1, keepdim=True)
    scale = (va.amax(1) - va.amin(1)).amax(1) + (vb.amax(1) - vb.amin(1)).amax(1)

    def disjoint(axes, rows=slice(None)):  # axes (P,n,3) -> (P,) some axis separates
        pa, pb = (torch.bmm(axes, v[rows].transpose(1, 2)) for v in (shrunk, grown))
        gap = torch.maximum(pb.amin(2) - pa.amax(2), pa.amin(2) - pb.amax(2))
        return (gap > 1e-9 * axes.norm(dim=2) * scale[rows, None]).any(1)

    normals = [torch.cross(v[:, f[1]] - v[:, f[0]], v[:, f[2]] - v[:, f[0]], dim=-1) for v in (va, vb) for f in _FACES]
    separated = disjoint(torch.stack(normals, 1))
    rest = torch.nonzero(~separated).squeeze(1)
    if len(rest):
        edges_a = torch.stack([va[rest, j] - va[rest, i] for i, j in _EDGES], 1)  # (P,6,3)
        edges_b = torch.stack([vb[rest, j] - vb[rest, i] for i, j in _EDGES], 1)
        crossed = torch.cross(edges_a[:, :, None], edges_b[:, None], dim=-1).flatten(1, 2)  # (P,36,3)
        separated[rest] = disjoint(crossed, rest)
    return separated & (deep[:, 0, 0] >= DEEP / 2)


class TetLocator:
    """Exact point-in-tetrahedron location accelerated by a uniform grid (per-cell tet lists in CSR form).

    ``vertices (N,3)`` float (tensor or array; rounded to the working ``dtype``, float32 or float64), ``tets (K,4)``
    int. ``cells_per_tet`` sets the grid resolution: cubic cells of the mean tet volume divided by it (capped at 4M
    cells). Every point starts at its cell octant's primary tet and walks at most ``rounds`` steps across the face
    its barycentrics point to, stopping as soon as a safe tet accepts it deeply; the others are finished by testing
    their whole cell list. ``kernel``: ``"torch"`` runs the walk vectorised over chunks of ``chunk`` points on any
    device (CPU or CUDA); ``"numba"`` (the default on the CPU, :mod:`nerfedit_plugin.bending._locate_kernel`) walks each
    point in a compiled loop, several times faster; both give the same answer bit for bit. The grid is built by
    numba kernels with ``"numba"`` and vectorised in torch otherwise (the same grid bit for bit). ``face_pairs``:
    :func:`face_pairs` of ``tets``, to share it between locators of the same tets.
    """

    def __init__(
        self,
        vertices,
        tets,
        *,
        dtype: torch.dtype = torch.float32,
        device=None,
        cells_per_tet: float = 4.0,
        chunk: int | None = None,
        rounds: int = 3,
        kernel: str = "auto",
        face_pairs: torch.Tensor | None = None,
    ):
        self._table = table = _TetTable(vertices, tets, dtype, device)
        self.dtype, self.device, self.eps = table.dtype, table.device, table.eps
        if rounds < 1:
            raise ValueError(f"rounds must be >= 1, got {rounds}")
        if kernel not in ("auto", "numba", "torch") or (kernel == "numba" and self.device.type != "cpu"):
            raise ValueError(f"kernel must be 'auto', 'torch' or (on the CPU) 'numba', got {kernel!r}")
        self.kernel = kernel if kernel != "auto" else ("numba" if self.device.type == "cpu" else "torch")
        self.chunk = chunk or (1 << 19 if self.device.type == "cpu" else 1 << 22)
        self.rounds = rounds
        ids = torch.nonzero(table.usable).squeeze(1)
        shape = self._choose_grid(ids, cells_per_tet)
        self.grid_shape = tuple(shape.tolist())
        padded = shape + 2  # a border layer of empty cells takes every point outside the grid
        strides = torch.stack([padded[1] * padded[2], padded[2], torch.ones_like(padded[2])])
        self._strides = strides.tolist()
        self._offset = float(strides.sum())

        n_cells = int(padded.prod())
        self._neighbours = _face_neighbours(table.tets, table.usable, face_pairs)
        self._neighbours_t = self._neighbours.t().contiguous()  # (4,K)
        if self.kernel == "numba":
            safe = self._build_compiled(ids, shape, strides, n_cells)
        else:
            safe = self._build_torch(ids, shape, strides, n_cells)
        # Per tet: the depth that makes an acceptance final (inf for unsafe tets: never) and the walk's neighbours.
        self._deep = torch.where(safe, DEEP, torch.inf).to(dtype)
        self._accept = torch.where(table.usable, -self.eps, torch.inf).to(dtype)  # membership: any acceptance

    def _build_torch(self, ids: torch.Tensor, shape: torch.Tensor, strides: torch.Tensor, n_cells: int) -> torch.Tensor:
        """The grid in torch (any device): cell lists, sub-cell masks, octant primaries; returns the safe tets."""
        table = self._table
        cell, tet, depth, ijk = self._register(ids, shape, strides)
        # Sub-cell masks matter only where the mesh ends: cells holding a tet with a boundary face; every other
        # cell keeps all 64 bits (always conservative).
        touched = torch.zeros(n_cells, dtype=torch.bool, device=self.device)
        touched[cell[(self._neighbours < 0).any(1)[tet]]] = True
        pick = torch.nonzero(touched[cell]).squeeze(1)
        self._cell_mask = torch.where(touched, self._submasks(cell[pick], tet[pick], ijk[pick], n_cells), -1)
        # CSR lists sorted by (cell, tet); per cell octant, the primary tet: deepest at the octant centre.
        order = torch.argsort(tet, stable=True)
        order = order[torch.argsort(cell[order], stable=True)]
        cell, tet, depth = cell[order], tet[order], depth[order]
        first = torch.ones_like(cell, dtype=torch.bool)
        first[1:] = cell[1:] != cell[:-1]
        starts = torch.nonzero(first).squeeze(1)
        lengths = torch.diff(starts, append=torch.tensor([len(cell)], device=self.device))
        self._cell_start = torch.zeros(n_cells, dtype=torch.int64, device=self.device)
        self._cell_start[cell[first]] = starts
        self._cell_count = torch.zeros(n_cells, dtype=torch.int64, device=self.device)
        self._cell_count[cell[first]] = lengths
        self._cell_mask[self._cell_count == 0] = 0
        key = (cell[:, None] * 8 + torch.arange(8, device=self.device)).ravel()
        best = torch.full((8 * n_cells,), -torch.inf, dtype=torch.float64, device=self.device)
        best.scatter_reduce_(0, key, depth.ravel(), "amax")
        winner = torch.nonzero(depth.ravel() == best[key]).squeeze(1)  # ties: the smallest tet index
        primary = torch.full((8 * n_cells,), len(table), dtype=torch.int64, device=self.device)
        primary.scatter_reduce_(0, key[winner], tet.repeat_interleave(8)[winner], "amin")
        self._octant_primary = primary.to(torch.int32)
        self._entry_tet = tet
        return self._safe_tets(starts, lengths, tet)

    def _build_compiled(self, ids: torch.Tensor, shape: torch.Tensor, strides: torch.Tensor, n_cells: int):
        """:meth:`_build_torch` in numba kernels (:mod:`nerfedit_plugin.bending._locate_kernel`, CPU): the same
        tests in the same float64 expressions, so the same grid bit for bit (the tests compare the two builds)."""
        from nerfedit_plugin.bending._locate_kernel import cell_lists, cell_masks, register_cells, unsafe_tets
        from nerfedit_plugin.geometry.launch import launch

        table, k = self._table, len(self._table)
        corners, grads = table.corners.numpy(), table.grads.numpy()
        tolerance = table.tolerance.numpy()
        h = 1 / self._inv.to(torch.float64)
        if len(ids):
            first = self._cell_coords(table.box_lo[ids]).to(torch.int64).clamp_min(0)
            last = torch.minimum(self._cell_coords(table.box_hi[ids]).to(torch.int64), shape - 1)
        else:
            first = last = torch.zeros((0, 3), dtype=torch.int64)
        lo = self._lo.to(torch.float64).numpy()
        ijk, tet, depth = register_cells(
            ids.numpy(), first.numpy(), last.numpy(), corners, grads, tolerance, lo, h.numpy()
        )
        cell = (ijk + 1) @ strides.numpy()
        start, count, order, primary = cell_lists(cell, tet, depth, n_cells, k)
        # sub-cell masks (cells holding a tet with a boundary face; see _build_torch)
        s = _SUB
        box_lo = torch.floor(self._grid_coords(table.box_lo) * s).to(torch.int64).numpy()
        box_hi = torch.floor(self._grid_coords(table.box_hi) * s).to(torch.int64).numpy()
        size = 1 / float(self._inv[0])  # cubic cells; _submasks computes in float32 what involves it and a tensor
        offset = (((torch.arange(s) + 0.5) / s - 0.5) * size).to(torch.float64).numpy()
        boundary = (self._neighbours < 0).any(1).numpy()
        mask = np.empty(n_cells, dtype=np.int64)
        mask_args = (
            start,
            count,
            order,
            ijk,
            tet,
            corners,
            grads,
            tolerance,
            boundary,
            box_lo,
            box_hi,
            lo,
            size,
            offset,
        )
        launch(cell_masks, *mask_args, mask)
        self._cell_start, self._cell_count = torch.from_numpy(start), torch.from_numpy(count)
        self._cell_mask = torch.from_numpy(mask)
        self._octant_primary = torch.from_numpy(primary)
        self._entry_tet = torch.from_numpy(tet[order])
        # safe tets: each tet against every lower-index tet sharing a cell with it
        tet_start = np.zeros(k + 1, dtype=np.int64)
        np.cumsum(np.bincount(tet, minlength=k), out=tet_start[1:])
        unsafe = np.zeros(k, dtype=np.bool_)
        error = table.error.numpy()
        launch(
            unsafe_tets, cell, tet_start, start, count, self._entry_tet.numpy(), corners, error, tolerance, DEEP, unsafe
        )
        return table.usable & ~torch.from_numpy(unsafe)

    @property
    def n_tets(self) -> int:
        return len(self._table)

    def boxes(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(lo, hi)`` ``(S,3)`` float64: the cells whose 64 occupancy bits are all set, and the set sub-cells of
        the others, padded by 1 % of a sub-cell (far beyond the rounding of the cell computation). Outside every box
        no tet accepts a point."""
        padded = torch.tensor(self.grid_shape, device=self.device) + 2

        def coords(cell: torch.Tensor) -> torch.Tensor:
            ijk = torch.stack([cell // (padded[1] * padded[2]), (cell // padded[2]) % padded[1], cell % padded[2]], 1)
            return ijk - 1

        full = torch.nonzero(self._cell_mask == -1).squeeze(1)
        cells = torch.nonzero((self._cell_mask != 0) & (self._cell_mask != -1)).squeeze(1)
        bits = (
            self._cell_mask.index_select(0, cells)[:, None]
            .bitwise_right_shift(torch.arange(_SUB**3, device=self.device))
            .bitwise_and_(1)
        )
        owner, bit = torch.nonzero(bits).unbind(1)
        fine = _SUB * coords(cells.index_select(0, owner)) + torch.stack(
            [bit // (_SUB * _SUB), (bit // _SUB) % _SUB, bit % _SUB], 1
        )
        size = 1 / (_SUB * self._inv.to(torch.float64))
        lo = self._lo.to(torch.float64) + torch.cat([_SUB * coords(full) - 0.01, fine - 0.01]) * size
        span = torch.cat([torch.full((len(full), 1), _SUB + 0.02), torch.full((len(fine), 1), 1.02)]).to(lo)
        return lo, lo + span * size

    def covered_cells(self, scale: torch.Tensor, offset: torch.Tensor, side: int) -> torch.Tensor:
        """``(side³,)`` bool: the cells of the grid ``u = x scale + offset`` (cell ``(i,j,k)`` is ``[i,i+1) ×
        [j,j+1) × [k,k+1)`` in ``u``; float64 ``scale``, ``offset``), grown by 10⁻³ of a cell, every point of which
        some tet accepts. The border layer (``u`` index 0 or ``side - 1``) is never covered.

        Let G be the union of the tets whose barycentric error bound is below ``eps / 2``: a point of G lies exactly
        in such a tet, which therefore accepts it. A cell that no face of G's boundary meets lies wholly inside or
        wholly outside G; it is inside if its centre lies in a tet of G (float64 barycentrics). G's boundary lies in
        the faces of its tets that have no tet of G across them on the other side of the face plane (so overlapping
        or inverted tets only add faces); a face meets a cell only if its bounding box does and its plane does."""
        table, device = self._table, self.device
        covered = torch.zeros(side**3, dtype=torch.bool, device=device)
        if not table.usable.any():
            return covered
        good, (a, b, c, normal), bounds = self._good_boundary
        scale, offset = scale.to(device=device, dtype=torch.float64), offset.to(device=device, dtype=torch.float64)
        box = bounds * scale + offset
        first = [max(1, int(box[0, i])) for i in range(3)]
        last = [min(side - 1, int(box[1, i]) + 1) for i in range(3)]
        strides = torch.tensor([side * side, side, 1], device=device)
        if self.kernel == "numba":
            from nerfedit_plugin.bending._locate_kernel import mark_covered, touch_faces, untouched_centres

            scale64, offset64 = scale.numpy(), offset.numpy()
            touched = np.zeros(side**3, dtype=np.bool_)
            touch_faces(a.numpy(), b.numpy(), c.numpy(), normal.numpy(), scale64, offset64, side, touched)
            bounds = np.asarray([first, last], dtype=np.int64)
            cells, centres = untouched_centres(bounds[0], bounds[1], touched, scale64, offset64, side)
            found = self.member(torch.from_numpy(centres)).numpy()
            mark = covered.numpy()
            mark_covered(cells, centres, found, good.numpy(), table.corners.numpy(), table.grads.numpy(), mark)
            return covered
        # cells meeting the boundary faces (box overlap, then the plane against the cell grown by the padding)
        u = [p * scale + offset for p in (a, b, c)]
        lo = (torch.minimum(torch.minimum(u[0], u[1]), u[2]) - 1e-3).floor().long().clamp(0, side - 1)
        hi = (torch.maximum(torch.maximum(u[0], u[1]), u[2]) + 1e-3).floor().long().clamp(0, side - 1)
        owner, ijk = box_cells(lo, hi)
        normal_u = normal / scale  # n·x = Σ (n_k / scale_k) (u_k - offset_k)
        distance = ((ijk + 0.5 - u[0][owner]) * normal_u[owner]).sum(1).abs()
        reach = 0.5 * (1 + 2e-3) * normal_u[owner].abs().sum(1) * (1 + 1e-9)
        touched = torch.zeros(side**3, dtype=torch.bool, device=device)
        touched[(ijk[distance <= reach] * strides).sum(1)] = True
        # untouched inner cells: inside when the centre lies in a tet of G
        axes = [torch.arange(first[i], last[i], device=device) for i in range(3)]
        inner = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        inner = inner[~touched[(inner * strides).sum(1)]]
        centres = (inner + 0.5 - offset) / scale
        found = self.member(centres)
        hit = torch.nonzero(found >= 0).squeeze(1)
        t = found[hit]
        inside = good[t] & (table.exact_bary(t, centres[hit, None])[:, 0].amin(1) >= 1e-9)
        covered[(inner[hit[inside]] * strides).sum(1)] = True
        return covered

    @functools.cached_property
    def _good_boundary(self) -> tuple[torch.Tensor, tuple[torch.Tensor, ...], torch.Tensor]:
        """``(good (K,) bool, (a, b, c, normal) (F,3) float64, bounds (2,3))``: the tets of G (:meth:`covered_cells`),
        the faces that bound it (corners and ``(b − a) × (c − a)``) and the box of all tets, computed once."""
        table, device = self._table, self.device
        good = table.usable & (table.error <= self.eps / 2)
        k = len(table)
        tet = torch.arange(k, device=device).repeat_interleave(4)
        face = torch.tensor(_FACES, device=device).repeat(k, 1)  # (4K,3) corner indices; face i is opposite corner i
        corner = torch.arange(4, device=device).repeat(k)
        across = self._neighbours.reshape(-1).to(torch.int64)
        a, b, c = (table.corners[tet, face[:, j]] for j in range(3))
        normal = torch.linalg.cross(b - a, c - a)
        own = ((table.corners[tet, corner] - a) * normal).sum(1)
        there = across.clamp_min(0)
        ids = table.tets[tet[:, None], face]  # (4K,3) vertex ids of the face
        off = (
            (table.tets[there][:, :, None] != ids[:, None]).all(2).to(torch.uint8).argmax(1)
        )  # its corner off the face
        other = ((table.corners[there, off] - a) * normal).sum(1)
        closed = (across >= 0) & good[there] & (own * other < 0)
        boundary = torch.nonzero(good[tet] & ~closed).squeeze(1)
        bounds = torch.stack([table.corners.amin((0, 1)), table.corners.amax((0, 1))])
        return good, tuple(x[boundary].contiguous() for x in (a, b, c, normal)), bounds

    def box_bounds(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """``(lo (3,), hi (3,))`` float64: the bounds of :meth:`boxes` (None without boxes)."""
        if self.kernel == "numba":
            from nerfedit_plugin.bending._locate_kernel import box_extent

            lo, hi, n = box_extent(self._cell_mask.numpy(), *self._box_frame())
            return (torch.from_numpy(lo), torch.from_numpy(hi)) if n else None
        lo, hi = self.boxes()
        return (lo.amin(0), hi.amax(0)) if len(lo) else None

    def boxed_cells(self, scale: torch.Tensor, offset: torch.Tensor, side: int) -> torch.Tensor:
        """``(side³,)`` bool: the cells of the grid ``u = x scale + offset`` (``u`` clamped to ``[0, side)``; float64
        ``scale``, ``offset``) that a box of :meth:`boxes`, grown by 10⁻³ of a cell, meets."""
        if self.kernel == "numba":
            from nerfedit_plugin.bending._locate_kernel import mark_boxes

            marked = np.zeros(side**3, dtype=np.bool_)
            scale, offset = (x.to(torch.float64).numpy() for x in (scale, offset))
            mark_boxes(self._cell_mask.numpy(), *self._box_frame(), scale, offset, side, marked)
            return torch.from_numpy(marked)
        box_lo, box_hi = self.boxes()
        first = (box_lo * scale + offset - 1e-3).floor().long().clamp(0, side - 1)
        last = (box_hi * scale + offset + 1e-3).floor().long().clamp(0, side - 1)
        _, ijk = box_cells(first, last)
        marked = torch.zeros(side**3, dtype=torch.bool, device=self.device)
        marked[(ijk * torch.tensor([side * side, side, 1], device=self.device)).sum(1)] = True
        return marked

    def _box_frame(self) -> tuple[np.ndarray, ...]:
        """``(padded shape, lo, sub-cell size, spans)`` as :meth:`boxes` computes them, for the compiled kernels."""
        padded = np.asarray(self.grid_shape, dtype=np.int64) + 2
        size = (1 / (_SUB * self._inv.to(torch.float64))).numpy()
        spans = np.asarray([np.float32(_SUB + 0.02), np.float32(1.02)], dtype=np.float64)  # torch.full's float32
        return padded, self._lo.to(torch.float64).numpy(), size, spans

    def reach_cells(self, scale: torch.Tensor, offset: torch.Tensor, side: int) -> torch.Tensor:
        """``(side³,)`` bool: the cells of the grid ``u = x scale + offset`` (as in :meth:`covered_cells`; ``u``
        clamped to ``[0, side)``) in which some tet may accept a point. Per usable tet, the cells meeting its
        inflated box, grown by 10⁻³ of a cell, in which every ``b_i`` reaches ``−2 tol`` (the cell test of the grid
        build: the max of ``b_i`` over a cell is ``b_i(centre) + Σ_k |∂b_i/∂x_k| half_k``); cells of the border
        layer whenever the box meets them, since they also take the points clamped into them. Compiled
        (:func:`~nerfedit_plugin.bending._locate_kernel.mark_reach`) on the CPU for any device: one pass over the cells
        of the tet boxes."""
        from nerfedit_plugin.bending._locate_kernel import mark_reach
        from nerfedit_plugin.geometry.launch import launch

        table = self._table
        ids = np.flatnonzero(table.usable.cpu().numpy())
        scale, offset = (x.cpu().to(torch.float64).numpy() for x in (scale, offset))
        # numpy: small per-tet arrays, no thread pool to wake (the values are torch's, op for op)
        grads, origin = table.grads.cpu().numpy()[ids], table.corners.cpu().numpy()[ids, 0]
        first = np.floor(table.box_lo.cpu().numpy()[ids] * scale + offset - 1e-3).astype(np.int64).clip(0, side - 1)
        last = np.floor(table.box_hi.cpu().numpy()[ids] * scale + offset + 1e-3).astype(np.int64).clip(0, side - 1)
        # b_i at the centre of cell ijk, (ijk + ½ − offset) / scale, is Σ_k slope_ik ijk_k + value_i
        slope = grads / scale
        centre = ((0.5 - offset) / scale - origin)[:, None]
        value = (grads[..., 0] * centre[..., 0] + grads[..., 1] * centre[..., 1]) + grads[..., 2] * centre[..., 2]
        value[:, 0] += 1
        grow = np.abs(grads) * ((0.5 + 1e-3) / scale)
        value += ((grow[..., 0] + grow[..., 1]) + grow[..., 2]) + 2 * table.tolerance.cpu().numpy()[ids, None]
        reach = np.zeros(side**3, dtype=np.bool_)
        launch(mark_reach, first, last, slope, value, side, reach)
        return torch.from_numpy(reach).to(self.device)

    @property
    def n_entries(self) -> int:
        """Total length of all cell lists."""
        return len(self._entry_tet)

    def _grid_coords(self, points: torch.Tensor) -> torch.Tensor:
        """Grid coordinates ``f = (p - lo) * inv_cell`` per axis in the working dtype (scalar ops on 1-D columns:
        identical values for any batch, monotone in ``p``). Boxes use it; points use :meth:`_cell_ids`, which
        computes ``4 f`` exactly (a power-of-2 scale) and so lands in the same cells and sub-cells."""
        lo, inv = self._lo.tolist(), self._inv.tolist()
        return torch.stack([(points[:, i] - lo[i]) * inv[i] for i in range(3)], 1)

    def _cell_coords(self, points: torch.Tensor) -> torch.Tensor:
        return torch.floor(self._grid_coords(points))

    def _cell_ids(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(padded cell id, sub-cell bit 0..63)`` per point; points outside the grid (or NaN) get an empty
        border cell. Sub-cell coordinate ``floor(4 f)``, cell ``floor(floor(4 f) / 4) = floor(f)``: exact."""
        lo, inv, n, s = self._lo.tolist(), self._inv.tolist(), self.grid_shape, self._strides
        cell = torch.full((len(points),), float(self._offset), dtype=self.dtype, device=self.device)
        sub = torch.zeros(len(points), dtype=self.dtype, device=self.device)
        for i, weight in enumerate((_SUB * _SUB, _SUB, 1)):  # integers < 2**24 throughout: exact in float32
            fine = torch.floor((points[:, i] - lo[i]) * (inv[i] * _SUB))  # scaling by a power of 2 is exact
            coarse = torch.floor(fine * (1 / _SUB))
            sub.add_(fine, alpha=weight).add_(coarse, alpha=-_SUB * weight)
            cell.add_(coarse.clamp_(-1, n[i]), alpha=s[i])
        return torch.nan_to_num_(cell, nan=0.0).to(torch.int64), torch.nan_to_num_(sub, nan=0.0).to(torch.int64)

    def _choose_grid(self, ids: torch.Tensor, cells_per_tet: float) -> torch.Tensor:
        """Set origin and inverse cell size; return the grid shape (cells per axis)."""
        table, dtype = self._table, self.dtype
        if len(ids) == 0:
            self._lo = torch.zeros(3, dtype=dtype, device=self.device)
            self._inv = torch.ones(3, dtype=dtype, device=self.device)
            return torch.ones(3, dtype=torch.int64, device=self.device)
        self._lo = table.box_lo[ids].amin(0)
        hi = table.box_hi[ids].amax(0)
        corners = table.corners[ids]
        volume = torch.linalg.det(corners[:, 1:] - corners[:, :1]).abs().mean() / 6
        cell = float((volume / cells_per_tet) ** (1 / 3))
        while True:
            self._inv = torch.tensor(1 / cell, dtype=torch.float64).to(dtype).expand(3).to(self.device)
            shape = self._cell_coords(hi[None])[0].to(torch.int64) + 1
            if int((shape + 2).prod()) <= _MAX_CELLS:
                return shape
            cell *= 1.25

    def _register(self, ids: torch.Tensor, shape: torch.Tensor, strides: torch.Tensor):
        """``(padded cell id, tet, depth (P,8), ijk)``: cells overlapping the inflated box, minus cells beyond a
        face plane; depth = min_i b_i at the centres of the cell's 8 octants (float64)."""
        table = self._table
        if len(ids) == 0:
            empty = torch.zeros(0, dtype=torch.int64, device=self.device)
            return empty, empty, empty.to(torch.float64).reshape(0, 8), empty.reshape(0, 3)
        first = self._cell_coords(table.box_lo[ids]).to(torch.int64).clamp_min(0)
        last = torch.minimum(self._cell_coords(table.box_hi[ids]).to(torch.int64), shape - 1)
        h = 1 / self._inv.to(torch.float64)
        lo = self._lo.to(torch.float64)
        cells, tets, depths, coords = [], [], [], []
        for a, b in _batches((last - first + 1).prod(1)):
            owner, ijk = box_cells(first[a:b], last[a:b])
            tet = ids[owner + a]
            # max over the cell box (inflated to cover rounding of the cell assignment) of each b_i.
            center = table.exact_bary(tet, (lo + (ijk + 0.5) * h)[:, None])[:, 0]
            reach = (table.grads[tet].abs() * (h * (0.5 + 1e-3))).sum(2)
            keep = torch.nonzero((center + reach).amin(1) >= -2 * table.tolerance[tet]).squeeze(1)
            cells.append(((ijk[keep] + 1) * strides).sum(1))
            tets.append(tet[keep])
            octant = torch.tensor([[(i >> 2) & 1, (i >> 1) & 1, i & 1] for i in range(8)], device=self.device)
            along = table.grads[tet[keep]] @ ((octant - 0.5) * (h / 2)).T  # (P,4,8)
            depths.append((center[keep, :, None] + along).amin(1))
            coords.append(ijk[keep])
        return torch.cat(cells), torch.cat(tets), torch.cat(depths), torch.cat(coords)

    def _submasks(self, cell: torch.Tensor, tet: torch.Tensor, ijk: torch.Tensor, n_cells: int) -> torch.Tensor:
        """Per cell, a 64-bit mask of its 4x4x4 sub-cells that some registered tet may accept a point in (same
        two conservative tests as the cells: inflated box in sub-cell coordinates, face planes in float64)."""
        table, s = self._table, _SUB
        h = 1 / float(self._inv[0])  # cubic cells
        lo = self._lo.to(torch.float64)
        sub = torch.arange(s, device=self.device)
        offset = ((sub + 0.5) / s - 0.5) * h  # sub-cell centre relative to the cell centre, per axis
        box_lo = torch.floor(self._grid_coords(table.box_lo) * s).to(torch.int64)
        box_hi = torch.floor(self._grid_coords(table.box_hi) * s).to(torch.int64)
        bits = torch.zeros((n_cells, s**3), dtype=torch.uint8, device=self.device)
        for a, b in _batches(torch.full_like(tet, 4 * s**3)):
            t, c = tet[a:b], ijk[a:b]
            g = table.grads[t]  # (P,4,3)
            value = table.exact_bary(t, (lo + (c + 0.5) * h)[:, None])[:, 0]  # (P,4) at the cell centre
            value = value + (g.abs() * (h * (0.5 / s + 1e-3))).sum(2) + 2 * table.tolerance[t, None]
            along = g[..., None] * offset  # (P,4,3,s)
            reach = (
                value[:, :, None, None, None]
                + along[:, :, 0, :, None, None]
                + along[:, :, 1, None, :, None]
                + along[:, :, 2, None, None, :]
            )  # (P,4,s,s,s): max over the sub-cell of b_i + 2 tol
            fine = s * c[:, :, None] + sub  # (P,3,s) sub-cell indices
            inbox = (fine >= box_lo[t, :, None]) & (fine <= box_hi[t, :, None])
            inbox = inbox[:, 0, :, None, None] & inbox[:, 1, None, :, None] & inbox[:, 2, None, None, :]
            ok = (reach >= 0).all(1) & inbox
            ok = ok.reshape(-1, s**3).to(torch.uint8)
            bits.scatter_reduce_(0, cell[a:b, None].expand_as(ok), ok, "amax")
        weights = torch.tensor([1 << i for i in range(s**3 - 1)] + [-(1 << 63)], device=self.device)
        return (bits.to(torch.int64) * weights).sum(1)

    def _safe_tets(self, starts: torch.Tensor, lengths: torch.Tensor, tet: torch.Tensor) -> torch.Tensor:
        """Per tet: :func:`_separated` from every lower-index tet it shares a cell with."""
        k = len(self._table)
        owner_of = torch.repeat_interleave(torch.arange(len(starts), device=self.device), lengths)
        per_entry = lengths[owner_of]  # each entry meets every entry of its list
        keys = []
        for a, b in _batches(per_entry):
            entry, local = expand_ranges(per_entry[a:b])
            entry += a
            other = starts[owner_of[entry]] + local
            mine, theirs = tet[entry], tet[other]
            keys.append(torch.unique((mine * k + theirs)[theirs < mine]))
        pairs = torch.unique(torch.cat(keys)) if keys else torch.zeros(0, dtype=torch.int64, device=self.device)
        unsafe = torch.zeros(k, dtype=torch.bool, device=self.device)
        for a, b in _batches(torch.full_like(pairs, 64)):
            bad = pairs[a:b][~_separated(self._table, pairs[a:b] // k, pairs[a:b] % k)]
            unsafe[bad // k] = True
        return self._table.usable & ~unsafe

    def locate(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """points (M,3) (any float; cast to the working dtype) → ``(tet (M,) int64, -1 outside every tet;
        bary (M,4) working dtype, in that tet, 0 where -1)``.

        ``bary`` is a transposed view of a ``(4, M)`` buffer (non-contiguous)."""
        points = _as_tensor(points, self.dtype, self.device).reshape(-1, 3)
        bary = torch.zeros((4, len(points)), dtype=self.dtype, device=self.device)
        return self._run(points, bary), bary.t()

    def member(self, points: torch.Tensor) -> torch.Tensor:
        """points (M,3) → ``(M,)`` int64: *some* tet accepting the point, -1 where none; ``>= 0`` exactly where
        ``locate``'s is. Faster: the walk stops at the first accepting tet, no barycentrics."""
        return self._run(_as_tensor(points, self.dtype, self.device).reshape(-1, 3), None)

    @functools.cached_property
    def arrays(self) -> LocatorArrays:
        """The grid as numpy arrays (views of the CPU tensors) for :mod:`nerfedit_plugin.bending._locate_kernel`."""
        from nerfedit_plugin.bending._locate_kernel import LocatorArrays

        scalar = self._table.rows.numpy().dtype.type
        return LocatorArrays(
            self._lo.numpy(),
            (self._inv * _SUB).numpy(),
            np.asarray(self.grid_shape, dtype=np.int64),
            np.asarray(self._strides, dtype=np.int64),
            self._cell_mask.numpy(),
            self._octant_primary.numpy(),
            self._cell_start.numpy(),
            self._cell_count.numpy(),
            self._entry_tet.numpy(),
            self._table.rows.numpy(),
            self._neighbours.numpy(),
            self._deep.numpy(),
            self._accept.numpy(),
            scalar(1),
            scalar(-self.eps),
        )

    def _run(self, points: torch.Tensor, bary: torch.Tensor | None) -> torch.Tensor:
        """The tet per point of ``points (M,3)`` (any accepting one without ``bary (4,M)``, else filled too)."""
        if self.kernel == "numba":
            from nerfedit_plugin.bending._locate_kernel import locate_points
            from nerfedit_plugin.geometry.launch import launch

            tet = torch.empty(len(points), dtype=torch.int64)
            out = bary.numpy() if bary is not None else np.zeros((0, 0), dtype=self.arrays.rows.dtype)
            launch(locate_points, self.arrays, points.contiguous().numpy(), bary is None, self.rounds, tet.numpy(), out)
            return tet
        tet = torch.full((len(points),), -1, dtype=torch.int64, device=self.device)
        columns = torch.stack(points.unbind(1))  # (3, M): each coordinate contiguous, gathered by index_select(1, ·)
        for start in range(0, len(points), self.chunk):
            stop = min(start + self.chunk, len(points))
            self._locate_chunk(columns[:, start:stop], tet[start:stop], None if bary is None else bary[:, start:stop])
        return tet

    def _bary(self, code: torch.Tensor, columns: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """:func:`barycentric` of points ``columns (3,P)`` in tets ``code (P,)``, on contiguous coefficient rows."""
        return barycentric(self._table.columns.index_select(1, code).t(), columns.t())

    def _locate_chunk(self, columns: torch.Tensor, tet: torch.Tensor, bary: torch.Tensor | None) -> None:
        """Write the answer of points ``columns (3,P)`` into ``tet`` and ``bary (4,P)``; without ``bary``, any
        accepting tet (membership only): every tet's acceptance is final at ``min b >= -eps``."""

        def write(where: torch.Tensor, found: torch.Tensor, b) -> None:
            tet.scatter_(0, where, found.to(torch.int64))
            for i in range(4 if bary is not None else 0):
                bary[i].scatter_(0, where, b[i])

        final_depth = self._deep if bary is not None else self._accept

        cell, sub = self._cell_ids(columns.t())
        # Cell and sub-cell occupancy: points that no tet can accept stop here.
        keep = self._cell_mask.index_select(0, cell).bitwise_right_shift_(sub).bitwise_and_(1)
        pos = torch.nonzero(keep).squeeze(1)
        p, sub = columns.index_select(1, pos), sub.index_select(0, pos)
        octant = (sub >> 3).bitwise_and_(4) | (sub >> 2).bitwise_and_(2) | (sub >> 1).bitwise_and_(1)
        code = self._octant_primary.index_select(0, cell.index_select(0, pos).mul_(8).add_(octant))
        # Walk: a safe tet that accepts the point deeply is the answer (written); a tet that accepts it otherwise,
        # or a walk that leaves the mesh, sends the point to the full scan of its cell list.
        scan = []
        for step in range(self.rounds):
            b = self._bary(code, p)
            low = _min_bary(b)
            done = low >= final_depth.index_select(0, code)
            final = torch.nonzero(done).squeeze(1)
            write(
                pos.index_select(0, final),
                code.index_select(0, final),
                [x.index_select(0, final) for x in b] if bary is not None else None,
            )
            if step + 1 == self.rounds:
                scan.append(pos.index_select(0, torch.nonzero(~done).squeeze(1)))
                break
            rejected = low < -self.eps
            scan.append(pos.index_select(0, torch.nonzero(~(done | rejected)).squeeze(1)))
            out = torch.nonzero(rejected).squeeze(1)  # walk across the face of the most negative b_i
            low, b = low.index_select(0, out), [x.index_select(0, out) for x in b]
            nb = self._neighbours_t.index_select(1, code.index_select(0, out))  # (4,R): across the face opposite i
            code = torch.where(
                b[0] == low, nb[0], torch.where(b[1] == low, nb[1], torch.where(b[2] == low, nb[2], nb[3]))
            )
            inner = code >= 0
            scan.append(pos.index_select(0, out.index_select(0, torch.nonzero(~inner).squeeze(1))))
            go = torch.nonzero(inner).squeeze(1)
            walk = out.index_select(0, go)
            pos, code, p = pos.index_select(0, walk), code.index_select(0, go), p.index_select(1, walk)
            if len(pos) == 0:
                break
        rest = torch.cat(scan)
        if len(rest):
            write(rest, *self._scan(cell.index_select(0, rest), columns.index_select(1, rest), bary is not None))

    def _scan(self, cell: torch.Tensor, columns: torch.Tensor, with_bary: bool = True):
        """Brute force over each point's cell list (points ``columns (3,P)``): the smallest accepting tet index (-1
        if none) and its b (0; None without ``with_bary``)."""
        k = len(self._table)
        owner, local = expand_ranges(self._cell_count.index_select(0, cell))
        entry = self._cell_start.index_select(0, cell).index_select(0, owner) + local
        cand = self._entry_tet.index_select(0, entry)
        b = self._bary(cand, columns.index_select(1, owner))
        key = torch.where(_min_bary(b) >= -self.eps, cand, k)
        found = torch.full((len(cell),), k, dtype=torch.int64, device=self.device)
        found.scatter_reduce_(0, owner, key, "amin")
        inside = found < k
        if not with_bary:
            return torch.where(inside, found, -1), None
        b = self._bary(torch.where(inside, found, 0), columns)
        return torch.where(inside, found, -1), [torch.where(inside, x, 0.0) for x in b]


def box_cells(first: torch.Tensor, last: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(owner, ijk)``: every integer cell ``ijk (P,3)`` of the boxes ``[first_b, last_b]`` (``(B,3)``, inclusive,
    ``last >= first``), with the index ``owner (P,)`` of its box."""
    span = last - first + 1
    owner, local = expand_ranges(span.prod(1))
    sy, sz = span[owner, 1], span[owner, 2]
    return owner, first[owner] + torch.stack([local // (sy * sz), (local // sz) % sy, local % sz], 1)


def expand_ranges(counts: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """counts (B,) int64 → ``(owner (P,), local (P,))`` int64, ``P = Σ counts``: ``range(counts[i])`` for every ``i``,
    concatenated (``local``), with ``i`` repeated alongside (``owner``)."""
    owner = torch.repeat_interleave(torch.arange(len(counts), device=counts.device), counts)
    local = torch.arange(len(owner), device=counts.device) - (torch.cumsum(counts, 0) - counts).index_select(0, owner)
    return owner, local


def face_pairs(tets) -> torch.Tensor:
    """``(2,P)`` int64: the pairs of face slots ``4 t + i`` (the face of tet ``t`` opposite its vertex ``i``) with
    the same three vertices. Depends on the topology only: a :class:`TetLocator` takes it (``face_pairs=``) to share
    it between locators of the same tets (the frames of a :class:`DeformationField`)."""
    tets = _as_tensor(tets, torch.int64)
    k = len(tets)
    faces = torch.stack([tets[:, list(f)] for f in _FACES], 1).sort(2).values.reshape(-1, 3)  # (4K,3)
    n = int(tets.max()) + 1 if k else 1
    key = (faces[:, 0] * n + faces[:, 1]) * n + faces[:, 2]
    order = torch.argsort(key)
    key = key[order]
    same = torch.nonzero(key[1:] == key[:-1]).squeeze(1)
    return torch.stack([order[same], order[same + 1]])


def _face_neighbours(tets: torch.Tensor, usable: torch.Tensor, pairs: torch.Tensor | None = None) -> torch.Tensor:
    """``(K,4)`` int32: the usable tet across the face opposite vertex ``i`` of each tet, -1 if none (``pairs``:
    :func:`face_pairs` of ``tets``, computed if None)."""
    k = len(tets)
    a, b = face_pairs(tets) if pairs is None else pairs.to(tets.device)
    neighbours = torch.full((4 * k,), -1, dtype=torch.int64, device=tets.device)
    neighbours[a], neighbours[b] = b // 4, a // 4
    neighbours = torch.where(usable[neighbours.clamp_min(0)] & (neighbours >= 0), neighbours, -1)
    return neighbours.reshape(k, 4).to(torch.int32)


def _batches(counts: torch.Tensor) -> list[tuple[int, int]]:
    """Split ``range(len(counts))`` into consecutive ranges whose counts sum to about ``_BATCH`` each."""
    if len(counts) == 0:
        return []
    total = torch.cumsum(counts, 0)
    cuts = torch.searchsorted(total, _BATCH * torch.arange(1, int(total[-1]) // _BATCH + 1, device=counts.device))
    edges = sorted({0, len(counts), *(int(c) + 1 for c in cuts if 0 < int(c) + 1 < len(counts))})
    return list(zip(edges[:-1], edges[1:]))


def locate_brute_force(vertices, tets, points, dtype: torch.dtype = torch.float32, chunk: int = 1 << 22):
    """The oracle: test every usable tet for every point (chunked), same rule as :class:`TetLocator`.

    vertices (N,3), tets (K,4) int, points (M,3) → ``(tet (M,) int64, -1 outside; bary (M,4) dtype, 0 where -1)``."""
    table = _TetTable(vertices, tets, dtype, points.device if isinstance(points, torch.Tensor) else None)
    points = _as_tensor(points, dtype, table.device).reshape(-1, 3)
    m, k = len(points), len(table)
    tet = torch.full((m,), -1, dtype=torch.int64, device=table.device)
    bary = torch.zeros((m, 4), dtype=dtype, device=table.device)
    if k == 0:
        return tet, bary
    step = max(1, chunk // k)
    for start in range(0, m, step):
        p = points[start : start + step]
        b = barycentric(table.rows[None], p[:, None])
        hit = (_min_bary(b) >= -table.eps) & table.usable
        first = torch.where(hit.any(1), hit.to(torch.int8).argmax(1), -1)
        rows = torch.nonzero(first >= 0).squeeze(1)
        tet[start + rows] = first[rows]
        bary[start + rows] = torch.stack([x[rows, first[rows]] for x in b], 1)
    return tet, bary
