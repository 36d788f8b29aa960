"""Compiled (numba) CPU kernels of :class:`~nerfedit_plugin.geometry.arap.ArapSolver`: the local step, the global
step's right-hand side and the term-by-term energy, straight from the elements (no ``(N, 3G)`` matrix).

Every energy term is an element edge ``e = (i, j)`` (local pair
:data:`~nerfedit_plugin.geometry.cotangent.ELEMENT_EDGES`) with weighted rest edge ``u = w (p_i − p_j)``, held by the
rotation groups of ``mode``: ``ELEMENTS`` (0) its element, ``SPOKES_AND_RIMS`` (1) every corner of its element,
``SPOKES`` (2) its two end points. So ``S_g = Σ u (x_i − x_j)ᵀ`` is a sum of pieces: the element covariances ``S_f``
(``S_v = Σ_{f∋v} S_f`` for spokes-and-rims, ``S_f`` itself for elements) or, for spokes, the covariances of the edges
at each corner; and ``(K R)_v = Σ_{e ∋ v} ±(Σ_{g ∋ e} R_g) u``.
Vertex incidences are corner lists ``f·C + c`` (:func:`~nerfedit_plugin.geometry.cotangent.incidence`).
They run through :func:`~nerfedit_plugin.geometry.launch.launch`.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

ELEMENTS, SPOKES_AND_RIMS, SPOKES = 0, 1, 2
MODES = {"elements": ELEMENTS, "spokes_and_rims": SPOKES_AND_RIMS, "spokes": SPOKES}


@njit(cache=True, parallel=True)
def weighted_edges(rest, elements, pairs, weights, out):
    """``out[f, e] = w_fe (p_i − p_j)`` (F,E,3) for the element edges ``(i, j)``."""
    for f in prange(len(elements)):
        for e in range(len(pairs)):
            i, j = elements[f, pairs[e, 0]], elements[f, pairs[e, 1]]
            for c in range(3):
                out[f, e, c] = weights[f, e] * (rest[i, c] - rest[j, c])


@njit(cache=True, inline="always")
def _minors(m00, m11, m22, m33, n01, n02, n03, n12, n13, n23):
    """``arap._minors_4x4``: the 2×2 minors of rows (0,1) and rows (2,3) of a symmetric 4×4 matrix."""
    return (
        m00 * m11 - n01 * n01,
        m00 * n12 - n01 * n02,
        m00 * n13 - n01 * n03,
        n01 * n12 - m11 * n02,
        n01 * n13 - m11 * n03,
        n02 * n13 - n12 * n03,
        n02 * n13 - n03 * n12,
        n02 * n23 - n03 * m22,
        n02 * m33 - n03 * n23,
        n12 * n23 - n13 * m22,
        n12 * m33 - n13 * n23,
        m22 * m33 - n23 * n23,
    )


@njit(cache=True, inline="always")
def _horn(s, r):
    """The rotation ``r (3,3)`` maximising ``tr(R S)`` for ``s (3,3)`` (Horn's quaternion, Laguerre's method: the
    formulas of :func:`~nerfedit_plugin.geometry.arap.fit_rotations`); returns whether the top eigenvalue is
    nearly double (``r`` then unreliable)."""
    scale = 0.0
    for a in range(3):
        for c in range(3):
            scale += s[a, c] * s[a, c]
    scale = np.sqrt(scale)
    if scale == 0.0:
        for a in range(3):
            for c in range(3):
                r[a, c] = 1.0 if a == c else 0.0
        return False
    xx, xy, xz = s[0, 0] / scale, s[0, 1] / scale, s[0, 2] / scale
    yx, yy, yz = s[1, 0] / scale, s[1, 1] / scale, s[1, 2] / scale
    zx, zy, zz = s[2, 0] / scale, s[2, 1] / scale, s[2, 2] / scale
    d0, d1, d2, d3 = xx + yy + zz, xx - yy - zz, yy - xx - zz, zz - xx - yy
    n01, n02, n03, n12, n13, n23 = yz - zy, zx - xz, xy - yx, xy + yx, zx + xz, yz + zy
    c1 = -8.0 * (xx * (yy * zz - yz * zy) - xy * (yx * zz - yz * zx) + xz * (yx * zy - yy * zx))
    s0, s1, s2, s3, s4, s5, k0, k1, k2, k3, k4, k5 = _minors(d0, d1, d2, d3, n01, n02, n03, n12, n13, n23)
    c0 = s0 * k5 - s1 * k4 + s2 * k3 + s3 * k2 - s4 * k1 + s5 * k0
    lam = np.sqrt(3.0)
    for _ in range(40):
        l2 = lam * lam
        p = (l2 - 2.0) * l2 + c1 * lam + c0
        dp = (4.0 * l2 - 4.0) * lam + c1
        disc = np.sqrt(max(3.0 * (3.0 * dp * dp - 4.0 * p * (12.0 * l2 - 4.0)), 0.0))
        denominator = dp + disc
        step = 4.0 * p / denominator if p > 1e-14 and denominator > 0 else 0.0
        lam -= step
        if step <= 1e-14:
            break
    m00, m11, m22, m33 = d0 - lam, d1 - lam, d2 - lam, d3 - lam
    s0, s1, s2, s3, s4, s5, k0, k1, k2, k3, k4, k5 = _minors(m00, m11, m22, m33, n01, n02, n03, n12, n13, n23)
    a0, a1, a2, a3 = (  # the diagonal of adj(N − λI)
        m11 * k5 - n12 * k4 + n13 * k3,
        m00 * k5 - n02 * k2 + n03 * k1,
        n03 * s4 - n13 * s2 + m33 * s0,
        n02 * s3 - n12 * s1 + m22 * s0,
    )
    size01, size23 = max(abs(a0), abs(a1)), max(abs(a2), abs(a3))
    if size23 > size01:
        if abs(a3) > abs(a2):
            w, x, y, z = (
                -n12 * s5 + m22 * s4 - n23 * s3,
                n02 * s5 - m22 * s2 + n23 * s1,
                -n02 * s4 + n12 * s2 - n23 * s0,
                a3,
            )
        else:
            w, x, y, z = (
                n13 * s5 - n23 * s4 + m33 * s3,
                -n03 * s5 + n23 * s2 - m33 * s1,
                a2,
                -n03 * s3 + n13 * s1 - n23 * s0,
            )
    elif abs(a1) > abs(a0):
        w, x, y, z = (
            -n01 * k5 + n02 * k4 - n03 * k3,
            a1,
            -m00 * k4 + n01 * k2 - n03 * k0,
            m00 * k3 - n01 * k1 + n02 * k0,
        )
    else:
        w, x, y, z = (
            a0,
            -n01 * k5 + n12 * k2 - n13 * k1,
            n01 * k4 - m11 * k2 + n13 * k0,
            -n01 * k3 + m11 * k1 - n12 * k0,
        )
    norm = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / norm, x / norm, y / norm, z / norm
    ww, xx, yy, zz, xy, xz, yz, wx, wy, wz = w * w, x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    r[0, 0], r[0, 1], r[0, 2] = ww + xx - yy - zz, 2 * (xy - wz), 2 * (xz + wy)
    r[1, 0], r[1, 1], r[1, 2] = 2 * (xy + wz), ww - xx + yy - zz, 2 * (yz - wx)
    r[2, 0], r[2, 1], r[2, 2] = 2 * (xz - wy), 2 * (yz + wx), ww - xx - yy + zz
    return max(size01, size23) < 1e-4


@njit(cache=True, parallel=True)
def fit_rotations(covariances, rotations, ill):
    """covariances (G,3,3) → rotations (G,3,3) (maximising ``tr(R_g S_g)``), ill (G,) bool (:func:`_horn`)."""
    for g in prange(len(covariances)):
        ill[g] = _horn(covariances[g], rotations[g])


@njit(cache=True, parallel=True)
def piece_covariances(x, elements, pairs, wedges, per_corner, subset, out):
    """Positions x (N,3) → ``out`` the covariances ``Σ u (x_i − x_j)ᵀ`` (3,3) of the elements ``f`` in ``subset``,
    ``out[f]`` (F,3,3) or, ``per_corner``, of the edges at their corners ``out[f·C + c]`` (F·C,3,3)."""
    n_corners = elements.shape[1]
    for t in prange(len(subset)):
        f = subset[t]
        if per_corner:
            out[f * n_corners : (f + 1) * n_corners] = 0.0
        else:
            out[f] = 0.0
        for e in range(len(pairs)):
            i, j = elements[f, pairs[e, 0]], elements[f, pairs[e, 1]]
            dx, dy, dz = x[i, 0] - x[j, 0], x[i, 1] - x[j, 1], x[i, 2] - x[j, 2]
            u0, u1, u2 = wedges[f, e, 0], wedges[f, e, 1], wedges[f, e, 2]
            for end in range(2 if per_corner else 1):
                s = out[f * n_corners + pairs[e, end]] if per_corner else out[f]
                s[0, 0] += u0 * dx
                s[0, 1] += u0 * dy
                s[0, 2] += u0 * dz
                s[1, 0] += u1 * dx
                s[1, 1] += u1 * dy
                s[1, 2] += u1 * dz
                s[2, 0] += u2 * dx
                s[2, 1] += u2 * dy
                s[2, 2] += u2 * dz


@njit(cache=True, parallel=True)
def local_step(pieces, group_start, group_pieces, groups, covariances, rotations, traces, ill):
    """Per group g in ``groups``: ``covariances[g] = S_g`` (3,3), the sum of its ``pieces``
    (:func:`piece_covariances`), its best rotation ``rotations[g]`` (:func:`_horn`; ``ill[g]``: nearly double top
    eigenvalue), ``traces[g] = tr(R_g S_g)``."""
    for t in prange(len(groups)):
        g = groups[t]
        s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
        for k in range(group_start[g], group_start[g + 1]):
            p = pieces[group_pieces[k]]
            s00 += p[0, 0]
            s01 += p[0, 1]
            s02 += p[0, 2]
            s10 += p[1, 0]
            s11 += p[1, 1]
            s12 += p[1, 2]
            s20 += p[2, 0]
            s21 += p[2, 1]
            s22 += p[2, 2]
        s = covariances[g]
        s[0, 0], s[0, 1], s[0, 2] = s00, s01, s02
        s[1, 0], s[1, 1], s[1, 2] = s10, s11, s12
        s[2, 0], s[2, 1], s[2, 2] = s20, s21, s22
        r = rotations[g]
        ill[g] = _horn(s, r)
        traces[g] = (
            r[0, 0] * s00 + r[0, 1] * s10 + r[0, 2] * s20
            + r[1, 0] * s01 + r[1, 1] * s11 + r[1, 2] * s21
            + r[2, 0] * s02 + r[2, 1] * s12 + r[2, 2] * s22
        )  # fmt: skip


@njit(cache=True, parallel=True)
def rotate_edges(elements, pairs, wedges, rotations, mode, subset, out):
    """``out[f, e] = (Σ_{g ∋ e} R_g) u`` (F,E,3) for the elements f in ``subset``: each of their edges turned by the
    rotations of the groups holding it."""
    n_corners = elements.shape[1]
    for t in prange(len(subset)):
        f = subset[t]
        m00 = m01 = m02 = m10 = m11 = m12 = m20 = m21 = m22 = 0.0
        if mode != SPOKES:
            for corner in range(n_corners if mode == SPOKES_AND_RIMS else 1):
                r = rotations[elements[f, corner]] if mode == SPOKES_AND_RIMS else rotations[f]
                m00 += r[0, 0]
                m01 += r[0, 1]
                m02 += r[0, 2]
                m10 += r[1, 0]
                m11 += r[1, 1]
                m12 += r[1, 2]
                m20 += r[2, 0]
                m21 += r[2, 1]
                m22 += r[2, 2]
        for e in range(len(pairs)):
            if mode == SPOKES:
                a, b = rotations[elements[f, pairs[e, 0]]], rotations[elements[f, pairs[e, 1]]]
                m00, m01, m02 = a[0, 0] + b[0, 0], a[0, 1] + b[0, 1], a[0, 2] + b[0, 2]
                m10, m11, m12 = a[1, 0] + b[1, 0], a[1, 1] + b[1, 1], a[1, 2] + b[1, 2]
                m20, m21, m22 = a[2, 0] + b[2, 0], a[2, 1] + b[2, 1], a[2, 2] + b[2, 2]
            u0, u1, u2 = wedges[f, e, 0], wedges[f, e, 1], wedges[f, e, 2]
            out[f, e, 0] = m00 * u0 + m01 * u1 + m02 * u2
            out[f, e, 1] = m10 * u0 + m11 * u1 + m12 * u2
            out[f, e, 2] = m20 * u0 + m21 * u1 + m22 * u2


@njit(cache=True, parallel=True)
def gather_edges(elements, pairs, turned, vertices, vertex_start, vertex_corners, out):
    """``out[t] = Σ ±turned[f, e]`` (3,) over the element edges at v = vertices[t] (+ where v is the first end):
    with :func:`rotate_edges`, the global step's right-hand side ``(K R)_v``."""
    n_corners = elements.shape[1]
    for t in prange(len(vertices)):
        v = vertices[t]
        b0 = b1 = b2 = 0.0
        for k in range(vertex_start[v], vertex_start[v + 1]):
            f = vertex_corners[k] // n_corners
            c = vertex_corners[k] - f * n_corners
            for e in range(len(pairs)):
                if pairs[e, 0] == c:
                    b0 += turned[f, e, 0]
                    b1 += turned[f, e, 1]
                    b2 += turned[f, e, 2]
                elif pairs[e, 1] == c:
                    b0 -= turned[f, e, 0]
                    b1 -= turned[f, e, 1]
                    b2 -= turned[f, e, 2]
        out[t, 0], out[t, 1], out[t, 2] = b0, b1, b2


@njit(cache=True, inline="always")
def _residual(r, x, rest, i, j, w):
    """``w ‖(x_i − x_j) − r (p_i − p_j)‖²``."""
    total = 0.0
    for c in range(3):
        d = x[i, c] - x[j, c]
        for a in range(3):
            d -= r[c, a] * (rest[i, a] - rest[j, a])
        total += d * d
    return w * total


@njit(cache=True, parallel=True)
def residual_energy(x, rest, elements, pairs, weights, rotations, mode, out):
    """``out[f] = Σ_{e ∈ f} Σ_{g ∋ e} w ‖(x_i − x_j) − R_g (p_i − p_j)‖²`` (F,): the energy term by term."""
    for f in prange(len(elements)):
        total = 0.0
        for e in range(len(pairs)):
            w = weights[f, e]
            if w == 0.0:
                continue
            i, j = elements[f, pairs[e, 0]], elements[f, pairs[e, 1]]
            if mode == ELEMENTS:
                total += _residual(rotations[f], x, rest, i, j, w)
            elif mode == SPOKES_AND_RIMS:
                for corner in range(elements.shape[1]):
                    total += _residual(rotations[elements[f, corner]], x, rest, i, j, w)
            else:
                total += _residual(rotations[i], x, rest, i, j, w) + _residual(rotations[j], x, rest, i, j, w)
        out[f] = total


# ---- L-BFGS vector kernels (flat float64 arrays): the two-loop recursion in one pass per history pair ----------------
@njit(cache=True, parallel=True)
def axpy_dot(q, a, y, s):
    """``q −= a y`` in place, then ``sᵀq``."""
    total = 0.0
    for i in prange(len(q)):
        value = q[i] - a * y[i]
        q[i] = value
        total += s[i] * value
    return total


@njit(cache=True, parallel=True)
def combine(base, scale, weights, rows, slots, out):
    """``out = scale (base − Σ_k weights[k] rows[slots[k]])``."""
    for i in prange(len(base)):
        value = base[i]
        for k in range(len(slots)):
            value -= weights[k] * rows[slots[k], i]
        out[i] = scale * value


@njit(cache=True, parallel=True)
def difference_dots(a, b, c, d):
    """``(sᵀy, sᵀs, yᵀy)`` for ``s = a − b``, ``y = c − d``."""
    sy = ss = yy = 0.0
    for i in prange(len(a)):
        s, y = a[i] - b[i], c[i] - d[i]
        sy += s * y
        ss += s * s
        yy += y * y
    return sy, ss, yy
