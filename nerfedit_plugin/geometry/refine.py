"""Conforming local refinement of a tet mesh by edge bisection.

:func:`bisect` splits every edge of the marked tets at its midpoint and cuts each tet that has a split edge into
children by successive bisection: a tet is halved through its split edge of highest priority (the longest; ties by
vertex ids), the child ``(…, m, …)`` that replaces one end of the edge by its midpoint ``m``, and each child again
through its own remaining split edges. A face is cut only by bisections of its own edges, and every tet cuts its
faces' edges in the one global order, so the two tets on a face cut it alike: the refined mesh is conforming (no
hanging vertices) whatever the marking, neighbours of the marked tets being cut only where they touch a split edge.
Children keep their parent's orientation (a corner moved along one of the tet's own edges), and a piecewise-linear
map on the coarse mesh is the same map on the refined one, its value at a midpoint the mean of its edge's ends
(:meth:`Refinement.prolong`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit, prange

from nerfedit_plugin.geometry.launch import launch

#: the six edges of a tet as pairs of its corner slots
TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


class Refinement:
    """A refined tet mesh: ``vertices (N+E,3)`` float64 (the coarse ones first, then one midpoint per split edge),
    ``tets (K',4)`` int64, ``edges (E,2)`` int64 (the coarse edge whose midpoint is vertex ``N + e``) and ``parent
    (K',)`` int64 (the coarse tet each refined tet lies in)."""

    def __init__(self, vertices: np.ndarray, tets: np.ndarray, edges: np.ndarray, parent: np.ndarray) -> None:
        self.vertices, self.tets, self.edges, self.parent = vertices, tets, edges, parent

    def prolong(self, positions: np.ndarray) -> np.ndarray:
        """positions (N,3) float64 of the coarse vertices (a deformed frame) → (N+E,3) float64: the same
        piecewise-linear map on the refined mesh (each midpoint at the mean of its edge's ends)."""
        positions = np.asarray(positions, dtype=np.float64)
        return np.concatenate([positions, positions[self.edges].mean(axis=1)])

    def locate(self, points: np.ndarray, coarse: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """points (M,3) float64 in the coarse tets ``coarse (M,)`` int64 with barycentrics ``bary (M,4)`` float64 there
        → ``(tet (M,) int64, bary (M,4) float64)`` in the refined mesh: a point of an uncut tet keeps its barycentrics
        (the tet is its own child, corners in the same order); a point of a cut tet goes to the child whose smallest
        barycentric is largest (the one holding it, up to rounding, also on faces shared by children; compiled: no
        per-point temporaries at millions of points)."""
        points, coarse = np.asarray(points, dtype=np.float64), np.asarray(coarse, dtype=np.int64)
        order = np.argsort(self.parent, kind="stable")
        starts = np.searchsorted(self.parent[order], np.arange(int(self.parent.max(initial=-1)) + 2))
        tet, out = np.empty(len(coarse), dtype=np.int64), np.empty((len(coarse), 4))
        bary = np.asarray(bary, dtype=np.float64)
        launch(_locate_in_children, points, coarse, bary, starts, order, self.vertices, self.tets, tet, out)
        return tet, out


@njit(cache=True, parallel=True)
def _locate_in_children(points, coarse, bary, starts, order, vertices, tets, tet, out):
    """For each point ``m`` in coarse tet ``c = coarse[m]``, whose children are ``order[starts[c] : starts[c + 1]]``:
    an only child (the tet uncut) takes the point with its barycentrics ``bary[m]``; else the child whose smallest
    barycentric (Cramer's rule) is largest, with those barycentrics → ``tet``, ``out``."""
    for m in prange(len(coarse)):
        c = coarse[m]
        first, count = starts[c], starts[c + 1] - starts[c]
        if count == 1:
            tet[m] = order[first]
            out[m, 0], out[m, 1], out[m, 2], out[m, 3] = bary[m, 0], bary[m, 1], bary[m, 2], bary[m, 3]
            continue
        best = -np.inf
        for k in range(count):
            child = order[first + k]
            l0, l1, l2, l3 = _barycentrics(vertices, tets[child], points[m])
            smallest = min(min(l0, l1), min(l2, l3))
            if smallest > best:
                best = smallest
                tet[m] = child
                out[m, 0], out[m, 1], out[m, 2], out[m, 3] = l0, l1, l2, l3


@njit(cache=True, inline="always")
def _barycentrics(vertices, corners, point):
    """The barycentrics of ``point`` in the tet ``corners (4,)`` by Cramer's rule, without temporaries."""
    a = corners[0]
    ux, uy, uz = (
        vertices[corners[1], 0] - vertices[a, 0],
        vertices[corners[1], 1] - vertices[a, 1],
        vertices[corners[1], 2] - vertices[a, 2],
    )
    vx, vy, vz = (
        vertices[corners[2], 0] - vertices[a, 0],
        vertices[corners[2], 1] - vertices[a, 1],
        vertices[corners[2], 2] - vertices[a, 2],
    )
    wx, wy, wz = (
        vertices[corners[3], 0] - vertices[a, 0],
        vertices[corners[3], 1] - vertices[a, 1],
        vertices[corners[3], 2] - vertices[a, 2],
    )
    px, py, pz = point[0] - vertices[a, 0], point[1] - vertices[a, 1], point[2] - vertices[a, 2]
    det = _triple(ux, uy, uz, vx, vy, vz, wx, wy, wz)
    l1 = _triple(px, py, pz, vx, vy, vz, wx, wy, wz) / det
    l2 = _triple(ux, uy, uz, px, py, pz, wx, wy, wz) / det
    l3 = _triple(ux, uy, uz, vx, vy, vz, px, py, pz) / det
    return 1.0 - (l1 + l2 + l3), l1, l2, l3


@njit(cache=True, inline="always")
def _triple(ux, uy, uz, vx, vy, vz, wx, wy, wz):
    """``u · (v × w)``."""
    return ux * (vy * wz - vz * wy) + uy * (vz * wx - vx * wz) + uz * (vx * wy - vy * wx)


class _Split(NamedTuple):
    keys: np.ndarray  # sorted keys ``i · n + j`` (i < j) of the split edges
    edge: np.ndarray  # edge index of each sorted key
    rank: np.ndarray  # priority rank of each edge (0 = first)


def _split_edges(vertices: np.ndarray, tets: np.ndarray, marked: np.ndarray, n_ids: int) -> tuple[np.ndarray, _Split]:
    edges = np.unique(np.sort(tets[marked][:, TET_EDGES].reshape(-1, 2), axis=1), axis=0)
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    rank = np.empty(len(edges), dtype=np.int64)
    rank[np.lexsort((edges[:, 1], edges[:, 0], -lengths))] = np.arange(len(edges))
    keys = edges[:, 0] * n_ids + edges[:, 1]
    order = np.argsort(keys)
    return edges, _Split(keys[order], order, rank)


def bisect(vertices: np.ndarray, tets: np.ndarray, marked: np.ndarray) -> Refinement:
    """vertices (N,3) float64, tets (K,4) int (positively oriented), marked (K,) bool → the conforming
    :class:`Refinement` in which every edge of a marked tet is halved (see the module docstring)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    marked = np.asarray(marked, dtype=bool)
    if not marked.any():
        return Refinement(vertices, tets, np.zeros((0, 2), dtype=np.int64), np.arange(len(tets)))
    n_ids = len(vertices) + 6 * int(marked.sum())  # above every vertex id, midpoints included
    edges, split = _split_edges(vertices, tets, marked, n_ids)
    done, parents = [], []
    work, parent = tets, np.arange(len(tets))
    while len(work):
        pairs = np.sort(work[:, TET_EDGES], axis=2)
        keys = pairs[..., 0] * n_ids + pairs[..., 1]
        slot = np.minimum(np.searchsorted(split.keys, keys), len(split.keys) - 1)
        hit = split.keys[slot] == keys
        edge = split.edge[slot]
        priority = np.where(hit, split.rank[edge], np.iinfo(np.int64).max)
        cut = hit.any(axis=1)
        done.append(work[~cut])
        parents.append(parent[~cut])
        work, parent, edge, priority = work[cut], parent[cut], edge[cut], priority[cut]
        best = priority.argmin(axis=1)
        rows = np.arange(len(work))
        midpoint = len(vertices) + edge[rows, best]
        corners = TET_EDGES[best]
        first, second = work.copy(), work.copy()
        first[rows, corners[:, 1]] = midpoint  # (…, a, …, m, …): keeps the edge's first end
        second[rows, corners[:, 0]] = midpoint  # (…, m, …, b, …): keeps its second end
        work, parent = np.concatenate([first, second]), np.concatenate([parent, parent])
    midpoints = vertices[edges].mean(axis=1)
    return Refinement(
        np.concatenate([vertices, midpoints]), np.concatenate(done), edges.astype(np.int64), np.concatenate(parents)
    )
