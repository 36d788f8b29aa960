"""Compiled (numba) CPU kernel of :meth:`~nerfedit_plugin.bending.deformation_field.DeformationField.bend`: per point,
in one parallel pass, the near-grid test, the location in the deformed proxy T' and the mapping to canonical space, or
the membership test in the rest proxy T (vacated space). The same rules, float expressions and grids as the torch
path (:meth:`DeformationField._bend_torch`), so the answers are identical; this one touches each point once.

Points go in blocks of ``BLOCK``, one thread per block: near-grid bits of the whole block first (vectorised loops
indexed from 0 over block slices), points skipped eight at a time while their bits are zero, and the tet of the
previous point tried first (a point it accepts with ``min b ≥ final`` has exactly the walk's answer). Why:
docs/architecture.md, "Ray bending".
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from nerfedit_plugin.bending._locate_kernel import _bary, locate_point

BLOCK = 4096
"""Points per thread task (a multiple of 8: their bits are scanned as 64-bit words)."""


@njit(cache=True)
def _codes(x, scale, origin, mask, side, codes):
    """``codes[m]`` = the near-grid bits of point ``x[m]`` (``deformation_field._near``; a NaN coordinate counts as
    cell 0 along its axis, and no tet accepts such a point). The cell coordinate ``clamp((x − origin) scale + 1, 0,
    side − 1)`` is the torch path's up to the rounding of the last addition (done in float64 here), far less than
    the grid's 10⁻³-cell padding."""
    flat = x.ravel()
    zero = scale[0] - scale[0]
    top = zero + (side - 1)
    stride = np.int32(side)
    cell = np.empty(len(codes), dtype=np.int32)
    for m in range(len(codes)):
        index = np.int32(0)
        for i in range(3):
            u = (flat[3 * m + i] - origin[i]) * scale[i] + 1.0
            u = u if u > zero else zero
            index = index * stride + np.int32(u if u < top else top)
        cell[m] = index
    for m in range(len(codes)):
        codes[m] = mask[cell[m]]


@njit(cache=True, inline="always")
def _deep_in(a, t, x, y, z, final):
    """``(accepted, b0, b1, b2, b3)``: tet ``t`` (``-1``: none) accepts the point with ``min b >= final[t]``."""
    zero = a.one - a.one
    if t < 0:
        return False, zero, zero, zero, zero
    b0, b1, b2, b3 = _bary(a.rows, t, x, y, z, a.one)
    return min(min(b0, b1), min(b2, b3)) >= final[t], b0, b1, b2, b3


@njit(cache=True, parallel=True)
def bend_points(x, scale, origin, mask, side, deformed, rest, rest_rows, still, rounds, points, tet, empty):
    """Map ``x (M,3)`` into arrays the caller initialised (whole-array fills and copies are cheap in torch; the
    same slice assignments here cost three times the compile time): ``points`` = canonical position, holding ``x``
    on entry (it may be ``x``) and written only for points in T' outside still tets; ``tet`` = deformed tet, -1 on
    entry (-1 outside T'; not written if of length 0); ``empty`` = False on entry, set outside T' but inside T
    (certain in cells with bit 4, tested in the others with bit 2). ``rest_rows (K,12)``: rest corner ``r0`` then
    the rest edge matrix ``R`` row-major; ``x_c = r0 + R (b1, b2, b3)``, or ``x_c = x`` in tets with ``still[t]``
    (``DeformationField.still_tets``: the identity, without rounding)."""
    with_tet = tet.shape[0] > 0
    n = x.shape[0]
    for block in prange((n + BLOCK - 1) // BLOCK):
        first, stop = block * BLOCK, min(n, (block + 1) * BLOCK)
        codes = np.zeros(BLOCK, dtype=np.uint8)
        _codes(x[first:stop], scale, origin, mask, side, codes[: stop - first])
        words = codes.view(np.uint64)
        last, last_rest = -1, -1
        for word in range(BLOCK // 8):
            if words[word] == 0:
                continue
            for q in range(8 * word, 8 * word + 8):
                bits = codes[q]
                if bits == 0:
                    continue
                m = first + q
                px, py, pz = x[m, 0], x[m, 1], x[m, 2]
                t = -1
                if bits & 1:
                    found, b0, b1, b2, b3 = _deep_in(deformed, last, px, py, pz, deformed.deep)
                    if found:
                        t = last
                    else:
                        t, b0, b1, b2, b3 = locate_point(deformed, px, py, pz, deformed.deep, rounds)
                        last = t
                if t >= 0:
                    if with_tet:
                        tet[m] = t
                    if not still[t]:  # a still tet leaves x where it is
                        for i in range(3):
                            points[m, i] = (
                                rest_rows[t, i]
                                + rest_rows[t, 3 + 3 * i] * b1
                                + rest_rows[t, 4 + 3 * i] * b2
                                + rest_rows[t, 5 + 3 * i] * b3
                            )
                elif bits & 4:
                    empty[m] = True
                elif bits & 2:
                    inside = _deep_in(rest, last_rest, px, py, pz, rest.accept)[0]
                    if not inside:
                        last_rest = locate_point(rest, px, py, pz, rest.accept, rounds)[0]
                        inside = last_rest >= 0
                    empty[m] = inside
