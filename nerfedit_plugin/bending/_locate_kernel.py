"""Compiled (numba) CPU kernels of :class:`~nerfedit_plugin.bending.locate.TetLocator`: the same walk, the same rule.

Each point walks on its own in a compiled loop, parallel over points. Every value comes from the same float
expression as the torch path, op by op in the working dtype, so the answers are bit-identical to it and to
:func:`~nerfedit_plugin.bending.locate.locate_brute_force`. Scalars of the working dtype (``one``, ``neg_eps``) are
passed in (a Python literal would promote float32 to float64); a locator's grid arrives as :class:`LocatorArrays`.
:func:`launch` runs one kernel at a time on numba's ``workqueue`` threading layer (unless ``NUMBA_THREADING_LAYER``
is set), on as many threads as torch uses. Why: docs/architecture.md, "Point location".
"""

from __future__ import annotations

import os
import threading
from typing import NamedTuple

import numba
import numpy as np
import torch
from numba import njit, prange

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"
_LAUNCH = threading.Lock()


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


@njit(cache=True)
def mark_reach(first, last, slope, value, side, reach):
    """``reach[cell] = True`` for the cells ``ijk`` of each box ``[first_t, last_t]`` where every
    ``slope_t ijk + value_t`` (4 values) is ``>= 0``, and for its cells in the border layer
    (:meth:`~nerfedit_plugin.bending.locate.TetLocator.reach_cells`)."""
    for t in range(first.shape[0]):
        for i in range(first[t, 0], last[t, 0] + 1):
            for j in range(first[t, 1], last[t, 1] + 1):
                for k in range(first[t, 2], last[t, 2] + 1):
                    cell = (i * side + j) * side + k
                    if i == 0 or j == 0 or k == 0 or i == side - 1 or j == side - 1 or k == side - 1:
                        reach[cell] = True
                        continue
                    low = np.inf
                    for f in range(4):
                        low = min(low, slope[t, f, 0] * i + slope[t, f, 1] * j + slope[t, f, 2] * k + value[t, f])
                    if low >= 0.0:
                        reach[cell] = True


def launch(kernel, *args) -> None:
    """Run a parallel kernel on as many threads as torch uses (``torch.set_num_threads`` governs both), one launch
    at a time."""
    with _LAUNCH:
        numba.set_num_threads(max(1, min(torch.get_num_threads(), numba.config.NUMBA_NUM_THREADS)))
        kernel(*args)
