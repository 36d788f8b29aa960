"""numba kernels of the splat forward map (:mod:`nerfedit_plugin.fields.splats.deform`, whose module docstring states
the math): per gradient, its polar rotation and the Wigner matrices of that rotation, packed in one record
(:func:`piece_tables`); per Gaussian, the mean through its rest tet, the covariance in its own axes, its
eigen-decomposition, the new quaternion and log-scales and the SH bands rotated (:func:`map_gaussians` for a tet
proxy, :func:`move_rows` for Gaussians already placed).

Private: ``deform.py`` calls them with contiguous arrays; its torch path is the reference they are tested against.
Every value is computed in float64 from the model's values (float32 or float64, read in place) and written once,
rounded to the model's dtype; scratch lives in registers and per-block buffers.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_PERMUTATIONS = np.array([[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]], dtype=np.int64)
_AXES = np.array([1, 2, 0], dtype=np.int64)  # band 1 of the standard real basis: m = −1, 0, 1 ↔ y, z, x
_TINY = 2.2250738585072014e-308  # the smallest normal float64: squared scales are clamped to it

ROTATION, STRETCH, WIGNER1, WIGNER2, WIGNER3 = 0, 9, 18, 27, 52
"""Offsets in a gradient's record (row-major matrices): ``R``, ``U = Rᵀ F`` (3×3 each), the Wigner matrices of
bands 1, 2, 3 (3×3, 5×5, 7×7)."""

RECORD = 104
"""float64 values per record (101 used; 104 = 13 cache lines)."""

BLOCK = 1024
"""Gaussians per work item of the per-Gaussian kernels (their scratch matrices are allocated once per item)."""

AHEAD = 4
""":func:`map_gaussians` touches the record of the Gaussian this many places ahead, so that its cache misses overlap
the work on the current one."""


@numba.njit(cache=True, inline="always")
def _quaternion(m, out):
    """Unit quaternion w x y z (w ≥ 0) of the rotation ``m`` (Shepperd's method) into ``out``."""
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    big = max(1.0 + trace, 1.0 + 2.0 * m[0, 0] - trace, 1.0 + 2.0 * m[1, 1] - trace, 1.0 + 2.0 * m[2, 2] - trace)
    if big == 1.0 + trace:
        w, x, y, z = 1.0 + trace, m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]
    elif big == 1.0 + 2.0 * m[0, 0] - trace:
        w, x, y, z = m[2, 1] - m[1, 2], big, m[0, 1] + m[1, 0], m[0, 2] + m[2, 0]
    elif big == 1.0 + 2.0 * m[1, 1] - trace:
        w, x, y, z = m[0, 2] - m[2, 0], m[0, 1] + m[1, 0], big, m[1, 2] + m[2, 1]
    else:
        w, x, y, z = m[1, 0] - m[0, 1], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1], big
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0:
        norm = -norm
    out[0], out[1], out[2], out[3] = w / norm, x / norm, y / norm, z / norm


@numba.njit(cache=True, inline="always")
def _multiply(a, b, out, transpose_a=False):
    """``out = a b`` (or ``aᵀ b``) of 3×3 matrices."""
    for i in range(3):
        for j in range(3):
            total = 0.0
            for k in range(3):
                total += (a[k, i] if transpose_a else a[i, k]) * b[k, j]
            out[i, j] = total


# ---- per gradient: polar rotation and Wigner matrices ------------------------------------------------------------


@numba.njit(cache=True, inline="always")
def _p(i, a, b, band, m1, previous):
    """Ivanic–Ruedenberg's ``P`` (:func:`nerfedit_plugin.fields.splats.sh_rotation._p`): row ``i`` of ``M_1``
    against row ``a`` of ``M_{ℓ−1}`` at column ``b`` (centred indices)."""
    lower = band - 1
    if b == band:
        return m1[i + 1, 2] * previous[a + lower, 2 * lower] - m1[i + 1, 0] * previous[a + lower, 0]
    if b == -band:
        return m1[i + 1, 2] * previous[a + lower, 0] + m1[i + 1, 0] * previous[a + lower, 2 * lower]
    return m1[i + 1, 1] * previous[a + lower, b + lower]


@numba.njit(cache=True)
def _band(band, m1, previous, out):
    """``M_ℓ`` in the standard real basis from ``M_1`` and ``M_{ℓ−1}`` into ``out`` (the recurrence of
    :func:`nerfedit_plugin.fields.splats.sh_rotation._band`, term for term)."""
    for m in range(-band, band + 1):
        centre = 1 if m == 0 else 0
        am = abs(m)
        for n in range(-band, band + 1):
            denominator = 2 * band * (2 * band - 1) if abs(n) == band else (band + n) * (band - n)
            u = math.sqrt((band + m) * (band - m) / denominator)
            v = 0.5 * math.sqrt((1 + centre) * (band + am - 1) * (band + am) / denominator) * (1 - 2 * centre)
            w = -0.5 * math.sqrt((band - am - 1) * (band - am) / denominator) * (1 - centre)
            value = 0.0
            if u != 0.0:
                value = value + u * _p(0, m, n, band, m1, previous)
            if v != 0.0:
                if m == 0:
                    term = _p(1, 1, n, band, m1, previous) + _p(-1, -1, n, band, m1, previous)
                elif m > 0:
                    term = _p(1, m - 1, n, band, m1, previous) * math.sqrt(2.0 if m == 1 else 1.0)
                    if m != 1:
                        term = term - _p(-1, -m + 1, n, band, m1, previous)
                else:
                    term = _p(-1, -m - 1, n, band, m1, previous) * math.sqrt(2.0 if m == -1 else 1.0)
                    if m != -1:
                        term = term + _p(1, m + 1, n, band, m1, previous)
                value = value + v * term
            if w != 0.0:
                if m > 0:
                    term = _p(1, m + 1, n, band, m1, previous) + _p(-1, -m - 1, n, band, m1, previous)
                else:
                    term = _p(1, m - 1, n, band, m1, previous) - _p(-1, -m + 1, n, band, m1, previous)
                value = value + w * term
            out[m + band, n + band] = value


@numba.njit(cache=True, inline="always")
def _store_signed(standard, record, offset):
    """``S M S`` with ``S = diag((−1)^m)`` (a standard-basis Wigner matrix in the 3DGS basis) into ``record`` from
    ``offset``, row-major."""
    size = standard.shape[0]
    for a in range(size):
        for b in range(size):
            record[offset + a * size + b] = -standard[a, b] if (a + b) % 2 == 1 else standard[a, b]


@numba.njit(cache=True)
def _record(f, record):
    """The record of the float64 gradient ``f (3,3)`` into ``record`` (``(RECORD,)``, offsets above): the rotation
    ``R`` of its polar decomposition (``W Vᵀ`` of the SVD, ``W``'s last column negated where that determinant is
    negative: the nearest rotation of an inverted ``F``), the stretch ``Rᵀ F`` and the 3DGS-basis Wigner matrices of
    ``R`` (:mod:`nerfedit_plugin.fields.splats.sh_rotation`). Returns whether ``det F < 0``."""
    w, _, vh = np.linalg.svd(f)
    r = w @ vh
    det = (
        r[0, 0] * (r[1, 1] * r[2, 2] - r[1, 2] * r[2, 1])
        - r[0, 1] * (r[1, 0] * r[2, 2] - r[1, 2] * r[2, 0])
        + r[0, 2] * (r[1, 0] * r[2, 1] - r[1, 1] * r[2, 0])
    )
    if det < 0:
        for a in range(3):
            w[a, 2] = -w[a, 2]
        r = w @ vh
    stretch = np.empty((3, 3))
    _multiply(r, f, stretch, True)
    for a in range(3):
        for b in range(3):
            record[ROTATION + 3 * a + b] = r[a, b]
            record[STRETCH + 3 * a + b] = stretch[a, b]
    for k in range(WIGNER3 + 49, RECORD):
        record[k] = 0.0
    m1 = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            m1[a, b] = r[_AXES[a], _AXES[b]]
    m2, m3 = np.empty((5, 5)), np.empty((7, 7))
    _band(2, m1, m1, m2)
    _band(3, m1, m2, m3)
    _store_signed(m1, record, WIGNER1)
    _store_signed(m2, record, WIGNER2)
    _store_signed(m3, record, WIGNER3)
    return (
        f[0, 0] * (f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1])
        - f[0, 1] * (f[1, 0] * f[2, 2] - f[1, 2] * f[2, 0])
        + f[0, 2] * (f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0])
    ) < 0


@numba.njit(cache=True, parallel=True)
def piece_tables(gradients, records, inverted):
    """For each gradient ``gradients[p]`` (``(P,3,3)``, any float dtype, taken as float64): its record
    ``records[p]`` (:func:`_record`) and ``inverted[p] = det F < 0``."""
    for p in numba.prange(len(gradients)):
        f = np.empty((3, 3))
        for a in range(3):
            for b in range(3):
                f[a, b] = gradients[p, a, b]
        inverted[p] = _record(f, records[p])


@numba.njit(cache=True, parallel=True)
def tet_tables(chosen, used, tets, rest_inverse, regular, deformed, single, gradient, identity, records, inverted):
    """For each ``j``, the tet ``t = used[chosen[j]]`` with rest edge inverse ``rest_inverse[chosen[j]]`` (``D⁻¹``,
    float64; ``regular[chosen[j]]`` false for a degenerate rest tet, whose gradient is ``I``) and deformed corners
    ``deformed[tets[t]]``: ``gradient[j] = D' D⁻¹`` (float64 sums of products; rounded to float32 where ``single``),
    ``identity[j]`` whether it is exactly ``I``, and from it ``records[j]``, ``inverted[j]`` (:func:`_record`)."""
    for j in numba.prange(len(chosen)):
        u = chosen[j]
        t = used[u]
        edges = np.empty((3, 3))
        for a in range(3):
            for b in range(3):
                edges[a, b] = deformed[tets[t, b + 1], a] - deformed[tets[t, 0], a]  # columns d_b − d_0
        f = np.empty((3, 3))
        same = True
        for a in range(3):
            for b in range(3):
                if regular[u]:
                    total = 0.0
                    for k in range(3):
                        total += edges[a, k] * rest_inverse[u, k, b]
                    if single:
                        total = np.float64(np.float32(total))
                else:
                    total = 1.0 if a == b else 0.0
                f[a, b] = total
                gradient[j, a, b] = total
                if total != (1.0 if a == b else 0.0):
                    same = False
        identity[j] = same
        inverted[j] = _record(f, records[j])


# ---- per Gaussian ------------------------------------------------------------------------------------------------


@numba.njit(cache=True)
def _scratch():
    """float64 scratch of :func:`_move_one`: six 3×3 matrices, a quaternion and one SH band's coefficients."""
    return (
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty((3, 3)),
        np.empty(4),
        np.empty((7, 3)),
    )


@numba.njit(cache=True, inline="always")
def _rotation(app, aqq, apq):
    """The Jacobi rotation that zeroes ``a_pq`` of a symmetric matrix: ``(t, c, s)``, ``t = tan`` of its angle (the
    smaller root of ``t² + 2θt − 1 = 0``, ``θ = (a_qq − a_pp) / 2a_pq``), ``c = cos``, ``s = sin``. With ``g = a_qq −
    a_pp`` and ``r = √(g² + 4a_pq²)``: ``t = 2a_pq sgn(g) / (|g| + r)``, ``c = √((r + |g|) / 2r)`` (the half-angle
    cosine, no cancellation); a small angle (``x = a_pq / g``, ``|x| < 3·10⁻⁵``, as in the last sweeps) takes the
    series ``t = x (1 − x²)``, ``c = 1 − t²/2 + 3t⁴/8``, exact to below 2·10⁻¹⁸ relative."""
    gap = aqq - app
    size = abs(gap)
    if abs(apq) < 3e-5 * size:
        x = apq / gap
        t = x * (1.0 - x * x)
        t2 = t * t
        c = 1.0 - 0.5 * t2 + 0.375 * t2 * t2
        return t, c, t * c
    r = math.sqrt(gap * gap + 4.0 * apq * apq)
    t = 2.0 * apq / (size + r)
    if gap < 0:
        t = -t
    c = math.sqrt((r + size) / (2.0 * r))
    return t, c, t * c


@numba.njit(cache=True, inline="always")
def _eigen(a00, a11, a22, a01, a02, a12, vectors):
    """Eigenvectors of the symmetric 3×3 ``[[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]]`` as the columns of
    ``vectors``, by cyclic Jacobi rotations on scalars, until the off-diagonal part is below 10⁻¹⁶ of the
    diagonal (relative, in the Frobenius norm)."""
    v00, v01, v02, v10, v11, v12, v20, v21, v22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    for _ in range(32):
        off = a01 * a01 + a02 * a02 + a12 * a12
        if off == 0.0 or off <= 1e-32 * (a00 * a00 + a11 * a11 + a22 * a22):
            break
        if a01 != 0.0:  # p, q = 0, 1
            t, c, s = _rotation(a00, a11, a01)
            a00, a11, a01 = a00 - t * a01, a11 + t * a01, 0.0
            a02, a12 = c * a02 - s * a12, s * a02 + c * a12
            v00, v01 = c * v00 - s * v01, s * v00 + c * v01
            v10, v11 = c * v10 - s * v11, s * v10 + c * v11
            v20, v21 = c * v20 - s * v21, s * v20 + c * v21
        if a02 != 0.0:  # p, q = 0, 2
            t, c, s = _rotation(a00, a22, a02)
            a00, a22, a02 = a00 - t * a02, a22 + t * a02, 0.0
            a01, a12 = c * a01 - s * a12, s * a01 + c * a12
            v00, v02 = c * v00 - s * v02, s * v00 + c * v02
            v10, v12 = c * v10 - s * v12, s * v10 + c * v12
            v20, v22 = c * v20 - s * v22, s * v20 + c * v22
        if a12 != 0.0:  # p, q = 1, 2
            t, c, s = _rotation(a11, a22, a12)
            a11, a22, a12 = a11 - t * a12, a22 + t * a12, 0.0
            a01, a02 = c * a01 - s * a02, s * a01 + c * a02
            v01, v02 = c * v01 - s * v02, s * v01 + c * v02
            v11, v12 = c * v11 - s * v12, s * v11 + c * v12
            v21, v22 = c * v21 - s * v22, s * v21 + c * v22
    vectors[0, 0], vectors[0, 1], vectors[0, 2] = v00, v01, v02
    vectors[1, 0], vectors[1, 1], vectors[1, 2] = v10, v11, v12
    vectors[2, 0], vectors[2, 1], vectors[2, 2] = v20, v21, v22


@numba.njit(cache=True, inline="always")
def _rotate_band(record, offset, size, first, sh, sh_out, coefficients):
    """``sh_out[first:first+size] = M sh[first:first+size]`` per channel (float64 sums), ``M`` the ``size × size``
    matrix at ``record[offset:]``; ``coefficients`` (≥ size × 3 float64) holds the band's input, read once."""
    for b in range(size):
        coefficients[b, 0] = sh[first + b, 0]
        coefficients[b, 1] = sh[first + b, 1]
        coefficients[b, 2] = sh[first + b, 2]
    for a in range(size):
        t0, t1, t2 = 0.0, 0.0, 0.0
        row = offset + a * size
        for b in range(size):
            m = record[row + b]
            t0 += m * coefficients[b, 0]
            t1 += m * coefficients[b, 1]
            t2 += m * coefficients[b, 2]
        sh_out[first + a, 0], sh_out[first + a, 1], sh_out[first + a, 2] = t0, t1, t2


@numba.njit(cache=True, inline="always")
def _move_one(q, log_scale, sh, record, quat_out, log_scale_out, sh_out, work):
    """One Gaussian (its rows ``q (4,)``, ``log_scale (3,)``, ``sh (K,3)``, any float dtype) carried by its
    gradient's ``record`` (:func:`piece_tables`): the new quaternion, log-scales and SH bands written to the
    ``*_out`` rows (distinct from the input rows); returns its anisotropy growth. ``work``: :func:`_scratch`."""
    axes, local, tmp, covariance, vectors, nearest, out, coefficients = work
    q0, q1, q2, q3 = np.float64(q[0]), np.float64(q[1]), np.float64(q[2]), np.float64(q[3])
    norm = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    w, x, y, z = q0 / norm, q1 / norm, q2 / norm, q3 / norm
    axes[0, 0], axes[0, 1], axes[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    axes[1, 0], axes[1, 1], axes[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    axes[2, 0], axes[2, 1], axes[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    s0 = math.exp(np.float64(log_scale[0]))
    s1 = math.exp(np.float64(log_scale[1]))
    s2 = math.exp(np.float64(log_scale[2]))
    for i in range(3):  # R_qᵀ U
        for j in range(3):
            total = 0.0
            for k in range(3):
                total += axes[k, i] * record[STRETCH + 3 * k + j]
            tmp[i, j] = total
    _multiply(tmp, axes, local)  # R_qᵀ U R_q, then · S
    for a in range(3):
        local[a, 0] *= s0
        local[a, 1] *= s1
        local[a, 2] *= s2
    for a in range(3):
        for b in range(a, 3):
            value = local[a, 0] * local[b, 0] + local[a, 1] * local[b, 1] + local[a, 2] * local[b, 2]
            covariance[a, b] = value
            covariance[b, a] = value
    _eigen(
        covariance[0, 0],
        covariance[1, 1],
        covariance[2, 2],
        covariance[0, 1],
        covariance[0, 2],
        covariance[1, 2],
        vectors,
    )
    best, order = -1.0, 0
    for k in range(6):
        score = abs(vectors[0, _PERMUTATIONS[k, 0]]) + abs(vectors[1, _PERMUTATIONS[k, 1]])
        score += abs(vectors[2, _PERMUTATIONS[k, 2]])
        if score > best:
            best, order = score, k
    for b in range(3):
        column = _PERMUTATIONS[order, b]
        sign = -1.0 if vectors[b, column] < 0 else 1.0
        for a in range(3):
            nearest[a, b] = sign * vectors[a, column]
    det = (
        nearest[0, 0] * (nearest[1, 1] * nearest[2, 2] - nearest[1, 2] * nearest[2, 1])
        - nearest[0, 1] * (nearest[1, 0] * nearest[2, 2] - nearest[1, 2] * nearest[2, 0])
        + nearest[0, 2] * (nearest[1, 0] * nearest[2, 1] - nearest[1, 1] * nearest[2, 0])
    )
    if det < 0:
        weakest = 0
        for b in range(1, 3):
            if abs(nearest[b, b]) < abs(nearest[weakest, weakest]):
                weakest = b
        for a in range(3):
            nearest[a, weakest] = -nearest[a, weakest]
    _multiply(covariance, nearest, tmp)
    n0 = math.sqrt(max(nearest[0, 0] * tmp[0, 0] + nearest[1, 0] * tmp[1, 0] + nearest[2, 0] * tmp[2, 0], _TINY))
    n1 = math.sqrt(max(nearest[0, 1] * tmp[0, 1] + nearest[1, 1] * tmp[1, 1] + nearest[2, 1] * tmp[2, 1], _TINY))
    n2 = math.sqrt(max(nearest[0, 2] * tmp[0, 2] + nearest[1, 2] * tmp[1, 2] + nearest[2, 2] * tmp[2, 2], _TINY))
    log_scale_out[0], log_scale_out[1], log_scale_out[2] = math.log(n0), math.log(n1), math.log(n2)
    growth = (max(n0, n1, n2) / min(n0, n1, n2)) / (max(s0, s1, s2) / min(s0, s1, s2))
    for i in range(3):  # R R_q Q
        for j in range(3):
            total = 0.0
            for k in range(3):
                total += record[ROTATION + 3 * i + k] * axes[k, j]
            tmp[i, j] = total
    _multiply(tmp, nearest, local)
    _quaternion(local, out)
    quat_out[0], quat_out[1], quat_out[2], quat_out[3] = out[0], out[1], out[2], out[3]
    count = sh.shape[0]
    sh_out[0, 0], sh_out[0, 1], sh_out[0, 2] = sh[0, 0], sh[0, 1], sh[0, 2]
    if count >= 4:
        _rotate_band(record, WIGNER1, 3, 1, sh, sh_out, coefficients)
    if count >= 9:
        _rotate_band(record, WIGNER2, 5, 4, sh, sh_out, coefficients)
    if count >= 16:
        _rotate_band(record, WIGNER3, 7, 9, sh, sh_out, coefficients)
    return growth


@numba.njit(cache=True, parallel=True)
def map_gaussians(
    tet,
    bary,
    slot,
    tets,
    deformed,
    single,
    identity,
    records,
    means,
    quats,
    log_scales,
    opacities,
    sh,
    out_means,
    out_quats,
    out_log_scales,
    out_opacities,
    out_sh,
    moved,
    growth,
):
    """The forward map of a model through a tet proxy: each Gaussian ``i`` with rest tet ``t = tet[i]`` (-1 outside) and
    barycentrics ``bary[:, i]`` (``(4,N)`` float64, as the locator computed them). A tet with ``slot[t] = s ≥ 0`` moves:
    its corners ``deformed[tets[t]]`` (float64), its gradient's record ``records[s]`` (:func:`piece_tables`),
    ``identity[s]`` true where the gradient is exactly ``I``. The mean ``μ' = Σ b_k d_k`` (float64) is rounded to the
    locator's dtype (float32 where ``single``), as the forward map returns it; the Gaussian moves where ``μ'`` differs
    from its mean (in that dtype) or the gradient is not ``I``: then ``out_means[i] = μ'`` and :func:`_move_one` writes
    the rest, ``moved[i] = 1``, ``growth[i]`` its anisotropy growth. Every other Gaussian is copied unchanged
    (``moved[i] = 0``). Returns a sum of values read ahead (:data:`AHEAD`), to be ignored."""
    count, n = sh.shape[1], len(tet)
    ahead = np.zeros((n + BLOCK - 1) // BLOCK)
    for block in numba.prange(len(ahead)):
        work = _scratch()
        point = np.empty(3)
        touched = 0.0
        for i in range(block * BLOCK, min(n, (block + 1) * BLOCK)):
            if i + AHEAD < n and tet[i + AHEAD] >= 0:
                later = slot[tet[i + AHEAD]]
                if later >= 0:
                    for k in range(0, RECORD, 8):
                        touched += records[later, k]
            t = tet[i]
            s = slot[t] if t >= 0 else -1
            go = False
            if s >= 0:
                go = not identity[s]
                for a in range(3):
                    value = 0.0
                    for k in range(4):
                        value += bary[k, i] * deformed[tets[t, k], a]
                    rest = np.float64(means[i, a])
                    if single:
                        value, rest = np.float64(np.float32(value)), np.float64(np.float32(rest))
                    point[a] = value
                    if value != rest:
                        go = True
            out_opacities[i] = opacities[i]
            if not go:
                for a in range(3):
                    out_means[i, a] = means[i, a]
                for a in range(4):
                    out_quats[i, a] = quats[i, a]
                for a in range(3):
                    out_log_scales[i, a] = log_scales[i, a]
                for k in range(count):
                    for a in range(3):
                        out_sh[i, k, a] = sh[i, k, a]
                moved[i] = 0
                continue
            for a in range(3):
                out_means[i, a] = point[a]
            moved[i] = 1
            growth[i] = _move_one(
                quats[i], log_scales[i], sh[i], records[s], out_quats[i], out_log_scales[i], out_sh[i], work
            )
        ahead[block] = touched
    return ahead.sum()


_move_called = numba.njit(cache=True)(_move_one.py_func)  # compiled once, called: move_rows is no hot path


@numba.njit(cache=True, parallel=True)
def move_rows(index, piece, records, quats, log_scales, sh, growth):
    """Gaussians ``index[j]`` of the model arrays ``quats``, ``log_scales``, ``sh`` (updated in place) carried by
    gradient record ``records[piece[j]]`` (:func:`piece_tables`); ``growth[j]`` receives the anisotropy growth."""
    count = sh.shape[1]
    for block in numba.prange((len(index) + BLOCK - 1) // BLOCK):
        work = _scratch()
        coefficients = np.empty((count, 3))
        for j in range(block * BLOCK, min(len(index), (block + 1) * BLOCK)):
            i = index[j]
            for k in range(count):
                for channel in range(3):
                    coefficients[k, channel] = sh[i, k, channel]
            growth[j] = _move_called(
                quats[i], log_scales[i], coefficients, records[piece[j]], quats[i], log_scales[i], sh[i], work
            )
