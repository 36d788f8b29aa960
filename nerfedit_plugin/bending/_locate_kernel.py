"""Compiled (numba) CPU kernels of :class:`~nerfedit_plugin.bending.locate.TetLocator`: the same walk, the same rule.

Each point walks on its own in a compiled loop, parallel over points. Every value comes from the same float
expression as the torch path, op by op in the working dtype, so the answers are bit-identical to it and to
:func:`~nerfedit_plugin.bending.locate.locate_brute_force`. Scalars of the working dtype (``one``, ``neg_eps``) are
passed in (a Python literal would promote float32 to float64); a locator's grid arrives as :class:`LocatorArrays`.
:func:`~nerfedit_plugin.geometry.launch.launch` runs them, one at a time, on as many threads as torch uses. Why:
docs/architecture.md, "Point location".
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange


class LocatorArrays(NamedTuple):
    """A :class:`~nerfedit_plugin.bending.locate.TetLocator` as numpy arrays (see its attributes of the same names)."""

    lo: np.ndarray  # (3,) grid origin, working dtype
    inv4: np.ndarray  # (3,) 4 / cell size (exact: a power-of-2 multiple of the inverse cell size)
    shape: np.ndarray  # (3,) int64 cells per axis
    strides: np.ndarray  # (3,) int64 strides of the padded grid
    cell_mask: np.ndarray  # (C,) int64 sub-cell occupancy bits
    octant_primary: np.ndarray  # (8C,) int32
    cell_start: np.ndarray  # (C,) int64
    cell_count: np.ndarray  # (C,) int64
    entry_tet: np.ndarray  # (E,) int64
    rows: np.ndarray  # (K,12) v0, Minv row-major
    neighbours: np.ndarray  # (K,4) int32
    deep: np.ndarray  # (K,) depth that makes an acceptance final (locate)
    accept: np.ndarray  # (K,) the same for membership
    one: np.generic  # 1 in the working dtype
    neg_eps: np.generic  # -eps in the working dtype


@njit(cache=True, inline="always")
def _bary(rows, t, x, y, z, one):
    """:func:`nerfedit_plugin.bending.locate.barycentric`, op for op."""
    dx = x - rows[t, 0]
    dy = y - rows[t, 1]
    dz = z - rows[t, 2]
    b1 = rows[t, 3] * dx + rows[t, 4] * dy + rows[t, 5] * dz
    b2 = rows[t, 6] * dx + rows[t, 7] * dy + rows[t, 8] * dz
    b3 = rows[t, 9] * dx + rows[t, 10] * dy + rows[t, 11] * dz
    b0 = one - (b1 + b2 + b3)
    return b0, b1, b2, b3


@njit(cache=True, inline="always")
def _cell(a, x, y, z):
    """``(padded cell id, sub-cell bit)`` of a point (``TetLocator._cell_ids``); ``(0, 0)`` for NaN (an empty
    border cell)."""
    if x != x or y != y or z != z:
        return 0, 0
    cell = 0
    sub = 0
    for i in range(3):
        value = x if i == 0 else (y if i == 1 else z)
        fine = np.floor((value - a.lo[i]) * a.inv4[i])
        coarse = np.floor(fine * 0.25)
        if coarse < -1.0:
            coarse = -1.0
        elif coarse > a.shape[i]:
            coarse = float(a.shape[i])
        cell += (int(coarse) + 1) * a.strides[i]
        if coarse >= 0.0 and coarse < a.shape[i]:
            sub = sub * 4 + int(fine - 4.0 * coarse)
    return cell, sub


@njit(cache=True, inline="always")
def locate_point(a, x, y, z, final, rounds):
    """``(tet, b0, b1, b2, b3)`` of one point (tet -1 and zeros if none): walk from the primary tet of its cell
    octant; a tet accepting it with ``min b >= final[tet]`` settles it, else the smallest accepting index of its
    cell list (``TetLocator._locate_chunk`` and ``_scan``, point by point)."""
    zero = a.one - a.one
    cell, sub = _cell(a, x, y, z)
    if ((a.cell_mask[cell] >> sub) & 1) == 0:
        return -1, zero, zero, zero, zero
    octant = ((sub >> 3) & 4) | ((sub >> 2) & 2) | ((sub >> 1) & 1)
    t = np.int64(a.octant_primary[cell * 8 + octant])
    for step in range(rounds):
        b0, b1, b2, b3 = _bary(a.rows, t, x, y, z, a.one)
        low = min(min(b0, b1), min(b2, b3))
        if low >= final[t]:
            return t, b0, b1, b2, b3
        if step + 1 == rounds or not low < a.neg_eps:
            break
        face = 0 if b0 == low else (1 if b1 == low else (2 if b2 == low else 3))
        t = np.int64(a.neighbours[t, face])
        if t < 0:
            break
    start = a.cell_start[cell]
    for j in range(start, start + a.cell_count[cell]):  # sorted lists: the first accepting tet is the smallest
        c = a.entry_tet[j]
        b0, b1, b2, b3 = _bary(a.rows, c, x, y, z, a.one)
        if min(min(b0, b1), min(b2, b3)) >= a.neg_eps:
            return c, b0, b1, b2, b3
    return -1, zero, zero, zero, zero


@njit(cache=True, parallel=True)
def locate_points(a, points, membership, rounds, tet, bary):
    """``TetLocator.locate`` of ``points (M,3)`` into ``tet (M,)`` and ``bary (4,M)``, or with ``membership``
    ``.member`` (any accepting tet; ``bary`` untouched)."""
    final = a.accept if membership else a.deep
    for m in prange(points.shape[0]):
        t, b0, b1, b2, b3 = locate_point(a, points[m, 0], points[m, 1], points[m, 2], final, rounds)
        tet[m] = t
        if not membership:
            bary[0, m], bary[1, m], bary[2, m], bary[3, m] = b0, b1, b2, b3


@njit(cache=True, parallel=True)
def mark_reach(first, last, slope, value, side, reach):
    """``reach[cell] = True`` for the cells ``ijk`` of each box ``[first_t, last_t]`` where every
    ``slope_t ijk + value_t`` (4 values) is ``>= 0``, and for its cells in the border layer
    (:meth:`~nerfedit_plugin.bending.locate.TetLocator.reach_cells`). Along a row of the box (``i``, ``j`` fixed) each
    value, evaluated as ``((s0 i + s1 j) + s2 k) + v``, is monotone in ``k`` (every rounding is), so the cells that
    pass form an interval; its ends are found by bisection on the same expression: the same cells as testing each.
    Parallel over the slabs ``i`` of the grid: each slab is written by one thread."""
    for i in prange(side):
        for t in range(first.shape[0]):
            if i < first[t, 0] or i > last[t, 0]:
                continue
            k0, k1 = first[t, 2], last[t, 2]
            for j in range(first[t, 1], last[t, 1] + 1):
                row = (i * side + j) * side
                if i == 0 or j == 0 or i == side - 1 or j == side - 1:
                    for k in range(k0, k1 + 1):
                        reach[row + k] = True
                    continue
                if k0 == 0:
                    reach[row] = True
                if k1 == side - 1:
                    reach[row + side - 1] = True
                a, b = max(k0, 1), min(k1, side - 2)
                for f in range(4):
                    if a > b:
                        break
                    base = slope[t, f, 0] * i + slope[t, f, 1] * j
                    step, v = slope[t, f, 2], value[t, f]
                    if step > 0:  # fails, then passes: the first k that passes
                        if not (base + step * b) + v >= 0.0:
                            a = b + 1
                            continue
                        low, high = a, b
                        while low < high:
                            mid = (low + high) // 2
                            if (base + step * mid) + v >= 0.0:
                                high = mid
                            else:
                                low = mid + 1
                        a = low
                    elif step < 0:  # passes, then fails: the last k that passes
                        if not (base + step * a) + v >= 0.0:
                            b = a - 1
                            continue
                        low, high = a, b
                        while low < high:
                            mid = (low + high + 1) // 2
                            if (base + step * mid) + v >= 0.0:
                                low = mid
                            else:
                                high = mid - 1
                        b = low
                    elif not (base + step * a) + v >= 0.0:  # constant along the row
                        b = a - 1
                for k in range(a, b + 1):
                    reach[row + k] = True


# ---- the build (TetLocator.__init__ with kernel="numba"; the torch build in locate.py is the reference) ----------


@njit(cache=True, inline="always")
def _exact_bary(corners, grads, t, x, y, z, out):
    """``TetLocator._table.exact_bary``: float64 barycentrics of ``(x, y, z)`` in tet ``t`` into ``out (4,)``, the
    same sums in the same order."""
    dx = x - corners[t, 0, 0]
    dy = y - corners[t, 0, 1]
    dz = z - corners[t, 0, 2]
    for f in range(4):
        out[f] = grads[t, f, 0] * dx + grads[t, f, 1] * dy + grads[t, f, 2] * dz
    out[0] += 1.0


@njit(cache=True)
def register_cells(ids, first, last, corners, grads, tolerance, lo, h):
    """``TetLocator._register`` for tets ``ids`` (ascending) with cell boxes ``[first, last]`` ``(U,3)``: the
    ``(ijk (P,3), tet (P,), depth (P,8))`` of every kept (cell, tet) pair, tet-major (exact barycentrics ``b`` at
    the cell centre, kept where ``min_i b_i + Σ_k |∂b_i/∂x_k| h_k (½ + 10⁻³) >= −2 tol``; depth =
    ``min_i b_i`` at the 8 octant centres)."""
    total = 0
    for u in range(len(ids)):
        total += (last[u, 0] - first[u, 0] + 1) * (last[u, 1] - first[u, 1] + 1) * (last[u, 2] - first[u, 2] + 1)
    ijk = np.empty((total, 3), dtype=np.int64)
    tet = np.empty(total, dtype=np.int64)
    depth = np.empty((total, 8), dtype=np.float64)
    grow = np.empty(3, dtype=np.float64)
    octant = np.empty((8, 3), dtype=np.float64)
    for k in range(3):
        grow[k] = h[k] * (0.5 + 1e-3)
        for o in range(8):
            octant[o, k] = (((o >> (2 - k)) & 1) - 0.5) * (h[k] / 2)
    reach = np.empty(4, dtype=np.float64)
    b = np.empty(4, dtype=np.float64)
    n = 0
    for u in range(len(ids)):
        t = ids[u]
        for f in range(4):
            reach[f] = (abs(grads[t, f, 0]) * grow[0] + abs(grads[t, f, 1]) * grow[1]) + abs(grads[t, f, 2]) * grow[2]
        limit = -2 * tolerance[t]
        for i in range(first[u, 0], last[u, 0] + 1):
            x = lo[0] + (i + 0.5) * h[0]
            for j in range(first[u, 1], last[u, 1] + 1):
                y = lo[1] + (j + 0.5) * h[1]
                for k in range(first[u, 2], last[u, 2] + 1):
                    z = lo[2] + (k + 0.5) * h[2]
                    _exact_bary(corners, grads, t, x, y, z, b)
                    low = min(min(b[0] + reach[0], b[1] + reach[1]), min(b[2] + reach[2], b[3] + reach[3]))
                    if not low >= limit:
                        continue
                    ijk[n, 0], ijk[n, 1], ijk[n, 2] = i, j, k
                    tet[n] = t
                    for o in range(8):
                        deepest = np.inf
                        for f in range(4):
                            along = grads[t, f, 0] * octant[o, 0] + grads[t, f, 1] * octant[o, 1]
                            deepest = min(deepest, b[f] + (along + grads[t, f, 2] * octant[o, 2]))
                        depth[n, o] = deepest
                    n += 1
    return ijk[:n], tet[:n], depth[:n]


@njit(cache=True)
def cell_lists(cell, tet, depth, n_cells, n_tets):
    """CSR lists of the entries ``(cell, tet)`` (tet-major, so each list comes out sorted by tet): ``(start, count,
    order (P,) entry of each list slot, octant_primary (8C,) int32)``; start 0 for empty cells; primary = the
    entry of largest depth per cell octant, the smallest tet on ties (``n_tets`` in empty cells)."""
    count = np.zeros(n_cells, dtype=np.int64)
    for e in range(len(cell)):
        count[cell[e]] += 1
    start = np.zeros(n_cells, dtype=np.int64)
    running = 0
    for c in range(n_cells):
        if count[c]:
            start[c] = running
            running += count[c]
    fill = start.copy()
    order = np.empty(len(cell), dtype=np.int64)
    for e in range(len(cell)):
        order[fill[cell[e]]] = e
        fill[cell[e]] += 1
    primary = np.full(8 * n_cells, n_tets, dtype=np.int32)
    best = np.empty(8, dtype=np.float64)
    for c in range(n_cells):
        best[:] = -np.inf
        for s in range(start[c], start[c] + count[c]):
            e = order[s]
            for o in range(8):
                if depth[e, o] > best[o]:
                    best[o] = depth[e, o]
                    primary[8 * c + o] = tet[e]
    return start, count, order, primary


@njit(cache=True, inline="always")
def _passes(value, along, i, j, top):
    """Some sub-cell of slab ``i`` (row ``j``; ``j = -1``: any row) may pass the face test of :func:`cell_masks`:
    every ``((value + along_x) + along_y) + along_z >= 0`` at the largest remaining terms ``top`` (exact: each sum
    is monotone in each of its terms)."""
    for f in range(4):
        y = along[f, 1, top[f, 0]] if j < 0 else along[f, 1, j]
        if not ((value[f] + along[f, 0, i]) + y) + along[f, 2, top[f, 1]] >= 0:
            return False
    return True


@njit(cache=True, parallel=True)
def cell_masks(start, count, order, ijk, tet, corners, grads, tolerance, boundary, box_lo, box_hi, lo, h, offset, mask):
    """``TetLocator._cell_mask`` into ``mask (C,)``: 0 for empty cells, -1 (all 64 bits) for cells holding no tet
    with a boundary face, else the OR over the cell's entries of the 4x4x4 sub-cells that pass both tests of
    ``TetLocator._submasks`` (sub-cell inside the tet's inflated box, ``box_lo``/``box_hi`` (K,3) in sub-cell
    units; every ``b_i`` reaches ``−2 tol`` over the sub-cell; bits already set are not tested again). ``h``: the
    cell size (the torch build computes the cell centre offset ``(ijk + ½) h`` in float32, as here); ``offset
    (4,)``: sub-cell centres relative to the cell centre."""
    n_cells = len(start)
    chunks = min(n_cells, 256)
    grow = h * (0.5 / 4 + 1e-3)
    half, h32 = np.float32(0.5), np.float32(h)
    for chunk in prange(chunks):
        value = np.empty(4, dtype=np.float64)
        along = np.empty((4, 3, 4), dtype=np.float64)
        top = np.zeros((4, 2), dtype=np.int64)
        for c in range(chunk * n_cells // chunks, (chunk + 1) * n_cells // chunks):
            mask[c] = 0
            if count[c] == 0:
                continue
            touched = False
            for s in range(start[c], start[c] + count[c]):
                touched = touched or boundary[tet[order[s]]]
            if not touched:
                mask[c] = -1
                continue
            bits = np.int64(0)
            for s in range(start[c], start[c] + count[c]):
                if bits == -1:
                    break
                e = order[s]
                t = tet[e]
                x = lo[0] + np.float64((np.float32(ijk[e, 0]) + half) * h32)
                y = lo[1] + np.float64((np.float32(ijk[e, 1]) + half) * h32)
                z = lo[2] + np.float64((np.float32(ijk[e, 2]) + half) * h32)
                _exact_bary(corners, grads, t, x, y, z, value)
                for f in range(4):
                    spread = (abs(grads[t, f, 0]) * grow + abs(grads[t, f, 1]) * grow) + abs(grads[t, f, 2]) * grow
                    value[f] = (value[f] + spread) + 2 * tolerance[t]
                    top[f, 0] = top[f, 1] = 0
                    for k in range(3):
                        for q in range(4):
                            along[f, k, q] = grads[t, f, k] * offset[q]
                for f in range(4):  # the largest term along y and z (each sum is monotone in each term)
                    for q in range(4):
                        if along[f, 1, q] > along[f, 1, top[f, 0]]:
                            top[f, 0] = q
                        if along[f, 2, q] > along[f, 2, top[f, 1]]:
                            top[f, 1] = q
                for i in range(4):
                    fi = 4 * ijk[e, 0] + i
                    if fi < box_lo[t, 0] or fi > box_hi[t, 0] or not _passes(value, along, i, -1, top):
                        continue
                    for j in range(4):
                        fj = 4 * ijk[e, 1] + j
                        if fj < box_lo[t, 1] or fj > box_hi[t, 1] or not _passes(value, along, i, j, top):
                            continue
                        for k in range(4):
                            fk = 4 * ijk[e, 2] + k
                            bit = np.int64(1) << np.int64(16 * i + 4 * j + k)
                            if fk < box_lo[t, 2] or fk > box_hi[t, 2] or bits & bit:
                                continue
                            ok = True
                            for f in range(4):
                                ok = ok and ((value[f] + along[f, 0, i]) + along[f, 1, j]) + along[f, 2, k] >= 0
                            if ok:
                                bits |= bit
            mask[c] = bits


@njit(cache=True, inline="always")
def _cross(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@njit(cache=True, inline="always")
def _parts(v, i, j):
    """The difference of corners ``v[j] - v[i]``."""
    return v[j, 0] - v[i, 0], v[j, 1] - v[i, 1], v[j, 2] - v[i, 2]


@njit(cache=True, inline="always")
def _axis_separates(nx, ny, nz, shrunk, grown, scale):
    """The projections of the two tetrahedra on axis ``n`` are disjoint by more than ``1e-9 |n| scale``."""
    a_lo, a_hi, b_lo, b_hi = np.inf, -np.inf, np.inf, -np.inf
    for v in range(4):
        pa = (nx * shrunk[v, 0] + ny * shrunk[v, 1]) + nz * shrunk[v, 2]
        pb = (nx * grown[v, 0] + ny * grown[v, 1]) + nz * grown[v, 2]
        a_lo, a_hi, b_lo, b_hi = min(a_lo, pa), max(a_hi, pa), min(b_lo, pb), max(b_hi, pb)
    gap = max(b_lo - a_hi, a_lo - b_hi)
    return gap > 1e-9 * np.sqrt((nx * nx + ny * ny) + nz * nz) * scale


_FACE_CORNERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], dtype=np.int64)
_EDGE_CORNERS = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


@njit(cache=True)
def separated(corners, error, tolerance, deep_depth, a, b, shrunk, grown):
    """``locate._separated`` of one pair: no point tet ``b`` accepts can be accepted with ``min b >= deep_depth``
    by tet ``a`` (tet ``a`` shrunk by ``deep_depth − error``, ``b`` grown by its tolerance, separating axis among
    the 8 face normals, then the 36 edge-edge cross products). ``shrunk``, ``grown``: (4,3) scratch."""
    deep = deep_depth - error[a]
    if not deep >= deep_depth / 2:
        return False
    tol = tolerance[b]
    extent_a, extent_b = 0.0, 0.0
    for k in range(3):
        sum_a = ((corners[a, 0, k] + corners[a, 1, k]) + corners[a, 2, k]) + corners[a, 3, k]
        sum_b = ((corners[b, 0, k] + corners[b, 1, k]) + corners[b, 2, k]) + corners[b, 3, k]
        lo_a, hi_a, lo_b, hi_b = np.inf, -np.inf, np.inf, -np.inf
        for v in range(4):
            shrunk[v, k] = (1 - 4 * deep) * corners[a, v, k] + deep * sum_a
            grown[v, k] = (1 + 4 * tol) * corners[b, v, k] - tol * sum_b
            lo_a, hi_a = min(lo_a, corners[a, v, k]), max(hi_a, corners[a, v, k])
            lo_b, hi_b = min(lo_b, corners[b, v, k]), max(hi_b, corners[b, v, k])
        extent_a, extent_b = max(extent_a, hi_a - lo_a), max(extent_b, hi_b - lo_b)
    scale = extent_a + extent_b
    va, vb = corners[a], corners[b]
    for side in range(2):
        v = va if side == 0 else vb
        for f in range(4):
            i, j, k = _FACE_CORNERS[f, 0], _FACE_CORNERS[f, 1], _FACE_CORNERS[f, 2]
            ux, uy, uz = _parts(v, i, j)
            wx, wy, wz = _parts(v, i, k)
            nx, ny, nz = _cross(ux, uy, uz, wx, wy, wz)
            if _axis_separates(nx, ny, nz, shrunk, grown, scale):
                return True
    for p in range(6):
        ux, uy, uz = _parts(va, _EDGE_CORNERS[p, 0], _EDGE_CORNERS[p, 1])
        for q in range(6):
            wx, wy, wz = _parts(vb, _EDGE_CORNERS[q, 0], _EDGE_CORNERS[q, 1])
            nx, ny, nz = _cross(ux, uy, uz, wx, wy, wz)
            if _axis_separates(nx, ny, nz, shrunk, grown, scale):
                return True
    return False


@njit(cache=True, parallel=True)
def unsafe_tets(
    entry_cell, tet_start, cell_start, cell_count, entry_tet, corners, error, tolerance, deep_depth, unsafe
):
    """``unsafe[a] = True`` for each tet ``a`` that some lower-index tet sharing a cell with it is not
    :func:`separated` from (``TetLocator._safe_tets``). ``entry_cell``: the cells of each tet, tet-major, tet ``a``'s
    at ``tet_start[a]:tet_start[a+1]``; lists ``cell_start``/``cell_count``/``entry_tet`` sorted by tet. Each pair
    is tested once; a tet stops at its first unseparated pair."""
    k = len(tet_start) - 1
    chunks = min(k, 64)
    for chunk in prange(chunks):
        seen = np.full(k, -1, dtype=np.int64)
        shrunk = np.empty((4, 3), dtype=np.float64)
        grown = np.empty((4, 3), dtype=np.float64)
        for a in range(chunk * k // chunks, (chunk + 1) * k // chunks):
            bad = False
            for e in range(tet_start[a], tet_start[a + 1]):
                c = entry_cell[e]
                for s in range(cell_start[c], cell_start[c] + cell_count[c]):
                    b = entry_tet[s]
                    if b >= a:
                        break
                    if seen[b] == a:
                        continue
                    seen[b] = a
                    if not separated(corners, error, tolerance, deep_depth, a, b, shrunk, grown):
                        bad = True
                        break
                if bad:
                    break
            unsafe[a] = bad


@njit(cache=True, inline="always")
def _box_sides(c, padded, lo, size, spans, low, high):
    """The sides of the boxes of padded cell ``c`` (``TetLocator.boxes``, the same expressions): per axis ``k``,
    ``low[k, q]``/``high[k, q]`` for sub-cell ``q`` (0..3) along it and for the whole cell (``q = 4``)."""
    coords = (c // (padded[1] * padded[2]), (c // padded[2]) % padded[1], c % padded[2])
    for k in range(3):
        base = 4 * (coords[k] - 1)
        for q in range(5):
            fine = base + (q if q < 4 else 0)
            x = lo[k] + np.float64(np.float32(fine) - np.float32(0.01)) * size[k]
            low[k, q] = x
            high[k, q] = x + spans[1 if q < 4 else 0] * size[k]


@njit(cache=True)
def box_extent(cell_mask, padded, lo, size, spans):
    """``(lo (3,), hi (3,), n)``: the bounds of ``TetLocator.boxes()`` and their number ``n`` (inf/-inf if none),
    from the same expressions (``spans`` = the full-cell and sub-cell spans as rounded there)."""
    low = np.full(3, np.inf)
    high = np.full(3, -np.inf)
    side_lo = np.empty((3, 5), dtype=np.float64)
    side_hi = np.empty((3, 5), dtype=np.float64)
    n = 0
    for c in range(len(cell_mask)):
        bits = cell_mask[c]
        if bits == 0:
            continue
        _box_sides(c, padded, lo, size, spans, side_lo, side_hi)
        for q in range(64):
            full = bits == -1
            if full and q > 0:
                break
            if not full and ((bits >> np.int64(q)) & 1) == 0:
                continue
            n += 1
            for k in range(3):
                sub = 4 if full else (q >> (2 * (2 - k))) & 3
                low[k] = min(low[k], side_lo[k, sub])
                high[k] = max(high[k], side_hi[k, sub])
    return low, high, n


@njit(cache=True)
def mark_boxes(cell_mask, padded, lo, size, spans, scale, offset, side, marked):
    """``marked[cell] = True`` for every cell of the grid ``u = x scale + offset`` (``side`` per axis) that a box
    of ``TetLocator.boxes()``, grown by 10⁻³ of a cell, meets (``deformation_field._near_grid``)."""
    side_lo = np.empty((3, 5), dtype=np.float64)
    side_hi = np.empty((3, 5), dtype=np.float64)
    first = np.empty((3, 5), dtype=np.int64)
    last = np.empty((3, 5), dtype=np.int64)
    for c in range(len(cell_mask)):
        bits = cell_mask[c]
        if bits == 0:
            continue
        _box_sides(c, padded, lo, size, spans, side_lo, side_hi)
        for k in range(3):
            for q in range(5):
                first[k, q] = min(max(np.int64(np.floor(side_lo[k, q] * scale[k] + offset[k] - 1e-3)), 0), side - 1)
                last[k, q] = min(max(np.int64(np.floor(side_hi[k, q] * scale[k] + offset[k] + 1e-3)), 0), side - 1)
        for q in range(64):
            full = bits == -1
            if full and q > 0:
                break
            if not full and ((bits >> np.int64(q)) & 1) == 0:
                continue
            a, b, d = (4, 4, 4) if full else (q >> 4, (q >> 2) & 3, q & 3)
            for i in range(first[0, a], last[0, a] + 1):
                for j in range(first[1, b], last[1, b] + 1):
                    for k in range(first[2, d], last[2, d] + 1):
                        marked[(i * side + j) * side + k] = True


@njit(cache=True)
def touch_faces(a, b, c, normal, scale, offset, side, touched):
    """``TetLocator.covered_cells``: ``touched[cell] = True`` for the cells of the grid ``u = x scale + offset``
    that face ``(a, b, c)`` (rows of (F,3)) may meet: its box grown by 10⁻³ cell, then its plane against the cell
    grown by 10⁻³ of a cell."""
    u = np.empty((3, 3), dtype=np.float64)
    nu = np.empty(3, dtype=np.float64)
    first = np.empty(3, dtype=np.int64)
    last = np.empty(3, dtype=np.int64)
    for f in range(len(a)):
        for k in range(3):
            u[0, k] = a[f, k] * scale[k] + offset[k]
            u[1, k] = b[f, k] * scale[k] + offset[k]
            u[2, k] = c[f, k] * scale[k] + offset[k]
            low = min(min(u[0, k], u[1, k]), u[2, k])
            high = max(max(u[0, k], u[1, k]), u[2, k])
            first[k] = min(max(np.int64(np.floor(low - 1e-3)), 0), side - 1)
            last[k] = min(max(np.int64(np.floor(high + 1e-3)), 0), side - 1)
            nu[k] = normal[f, k] / scale[k]
        reach = 0.5 * (1 + 2e-3) * ((abs(nu[0]) + abs(nu[1])) + abs(nu[2])) * (1 + 1e-9)
        for i in range(first[0], last[0] + 1):
            for j in range(first[1], last[1] + 1):
                for k in range(first[2], last[2] + 1):
                    distance = ((i + 0.5 - u[0, 0]) * nu[0] + (j + 0.5 - u[0, 1]) * nu[1]) + (k + 0.5 - u[0, 2]) * nu[2]
                    if abs(distance) <= reach:
                        touched[(i * side + j) * side + k] = True


@njit(cache=True)
def untouched_centres(first, last, touched, scale, offset, side):
    """``(cell (P,), centre (P,3) float64)`` of the cells ``[first, last)`` (per axis) not ``touched``; centre
    ``x = (ijk + ½ − offset) / scale``."""
    n = (last[0] - first[0]) * (last[1] - first[1]) * (last[2] - first[2])
    cell = np.empty(max(n, 0), dtype=np.int64)
    centre = np.empty((max(n, 0), 3), dtype=np.float64)
    m = 0
    for i in range(first[0], last[0]):
        for j in range(first[1], last[1]):
            for k in range(first[2], last[2]):
                index = (i * side + j) * side + k
                if touched[index]:
                    continue
                cell[m] = index
                centre[m, 0] = (i + 0.5 - offset[0]) / scale[0]
                centre[m, 1] = (j + 0.5 - offset[1]) / scale[1]
                centre[m, 2] = (k + 0.5 - offset[2]) / scale[2]
                m += 1
    return cell[:m], centre[:m]


@njit(cache=True)
def mark_covered(cell, centre, found, good, corners, grads, covered):
    """``covered[cell[m]] = True`` where ``found[m]`` is a tet of ``good`` in which the exact barycentrics of
    ``centre[m]`` are all ``>= 1e-9``."""
    b = np.empty(4, dtype=np.float64)
    for m in range(len(cell)):
        t = found[m]
        if t < 0 or not good[t]:
            continue
        _exact_bary(corners, grads, t, centre[m, 0], centre[m, 1], centre[m, 2], b)
        if min(min(b[0], b[1]), min(b[2], b[3])) >= 1e-9:
            covered[cell[m]] = True
