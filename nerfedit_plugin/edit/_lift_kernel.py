"""Compiled (numba) kernels of :mod:`nerfedit_plugin.edit.lift`: per surface vertex passes at millions of vertices
without sorts or temporaries. They run through :func:`~nerfedit_plugin.geometry.launch.launch`."""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def sample_mask(tets, step, cap, keep):
    """tets (S,) int64 the tet of each surface vertex (in index order), step (K,) int64 per tet, cap → keep (S,)
    bool: vertex ``s`` of rank ``r`` among its tet's vertices (in index order) is kept when ``r % step[t] == 0`` and
    ``r // step[t] < cap``. One pass in index order, counting each tet's vertices seen so far."""
    seen = np.zeros(len(step), dtype=np.int64)
    for s in range(len(tets)):
        t = tets[s]
        rank = seen[t]
        seen[t] = rank + 1
        keep[s] = rank % step[t] == 0 and rank // step[t] < cap


@njit(cache=True, parallel=True)
def embedded_distances(rows, embed_tets, embed_bary, tets, vertices, surface, out):
    """rows (R,) int64 surface vertices, embed_tets (V,) int64, embed_bary (V,4), tets (K,4) int64, vertices (N,3)
    the proxy's (deformed) vertices, surface (V,3) → out (R,): ``|Σ_j b_ij x_{tets[t_i, j]} − v_i|`` for ``i =
    rows[r]``."""
    for r in prange(len(rows)):
        i = rows[r]
        t = embed_tets[i]
        a0 = a1 = a2 = 0.0
        for j in range(4):
            b, k = embed_bary[i, j], tets[t, j]
            a0 += b * vertices[k, 0]
            a1 += b * vertices[k, 1]
            a2 += b * vertices[k, 2]
        d0, d1, d2 = a0 - surface[i, 0], a1 - surface[i, 1], a2 - surface[i, 2]
        out[r] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
