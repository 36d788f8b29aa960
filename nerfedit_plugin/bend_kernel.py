"""Compiled (numba) CPU kernel of :meth:`~nerfedit_plugin.deformation_field.DeformationField.bend`: per point, in
one parallel pass, the near-grid test, the location in the deformed proxy T' and the mapping to canonical space, or
the membership test in the rest proxy T (vacated space). The same rules, float expressions and grids as the torch
path (:meth:`DeformationField._bend_torch`), so the answers are identical; the vectorised torch path pays a pass
over memory per step and per subset, this one touches each point once.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from .locate_kernel import locate_point


@njit(cache=True, inline="always")
def _near_code(scale, offset, mask, marked, side, x, y, z):
    """Bits of the point's cell in the near grid (``deformation_field._near``; NaN points: 0), read only where the
    packed ``marked`` bit of the cell is set (that bitset stays in cache; most samples stop there). The cell
    coordinate may round differently from torch's fused multiply-add, by far less than the grid's 10⁻³-cell
    padding."""
    cell = 0
    for i in range(3):
        value = x if i == 0 else (y if i == 1 else z)
        u = value * scale[i] + offset[i]
        if u != u:
            return np.uint8(0)
        u = min(max(u, 0.0), side - 1.0)
        cell = cell * side + int(np.floor(u))
    if (marked[cell >> 3] >> (cell & 7)) & 1 == 0:
        return np.uint8(0)
    return mask[cell]


@njit(cache=True, parallel=True)
def bend_points(x, scale, offset, mask, marked, side, deformed, rest, rest_rows, rounds, copy, points, tet, empty):
    """Map ``x (M,3)``: ``points`` = canonical position (``x`` outside T'; written there only with ``copy``, so
    ``points`` may be ``x``), ``tet`` = deformed tet (-1 outside T'; not written if of length 0), ``empty`` =
    outside T' but inside T (certain in cells with bit 4, tested in the others with bit 2). ``rest_rows (K,12)``:
    rest corner ``r0`` then the rest edge matrix ``R`` row-major; ``x_c = r0 + R (b1, b2, b3)``. Skipping the
    writes a caller does not need keeps the pass over memory small."""
    with_tet = tet.shape[0] > 0
    for m in prange(x.shape[0]):
        px, py, pz = x[m, 0], x[m, 1], x[m, 2]
        code = _near_code(scale, offset, mask, marked, side, px, py, pz)
        if copy:
            points[m, 0], points[m, 1], points[m, 2] = px, py, pz
        if with_tet:
            tet[m] = -1
        empty[m] = False
        if code & 1:
            t, b0, b1, b2, b3 = locate_point(deformed, px, py, pz, deformed.deep, rounds)
            if with_tet:
                tet[m] = t
            if t >= 0:
                for i in range(3):
                    points[m, i] = (rest_rows[t, i] + rest_rows[t, 3 + 3 * i] * b1 + rest_rows[t, 4 + 3 * i] * b2
                                    + rest_rows[t, 5 + 3 * i] * b3)
                continue
        if code & 4:
            empty[m] = True
        elif code & 2:
            empty[m] = locate_point(rest, px, py, pz, rest.accept, rounds)[0] >= 0
