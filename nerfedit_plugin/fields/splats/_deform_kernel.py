"""numba kernel of the splat forward map: per moved Gaussian, the covariance in its own axes, its eigen-decomposition,
the new quaternion and log-scales, and the SH bands rotated by its piece's Wigner matrices.

Private: :func:`nerfedit_plugin.fields.splats.deform.deform_model` calls it with contiguous arrays; the torch path
there is the reference it is tested against.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_PERMUTATIONS = np.array([[0, 1, 2], [0, 2, 1], [1, 0, 2], [1, 2, 0], [2, 0, 1], [2, 1, 0]], dtype=np.int64)


@numba.njit(cache=True, inline="always")
def _jacobi(c, v):
    """Eigen-decomposition of the symmetric 3×3 ``c`` (overwritten: eigenvalues on its diagonal) by cyclic Jacobi
    rotations; ``v`` receives the eigenvectors as columns."""
    for i in range(3):
        for j in range(3):
            v[i, j] = 1.0 if i == j else 0.0
    for _ in range(32):
        off = c[0, 1] * c[0, 1] + c[0, 2] * c[0, 2] + c[1, 2] * c[1, 2]
        scale = c[0, 0] * c[0, 0] + c[1, 1] * c[1, 1] + c[2, 2] * c[2, 2]
        if off <= 1e-32 * scale or off == 0.0:
            return
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if c[p, q] == 0.0:
                continue
            theta = (c[q, q] - c[p, p]) / (2.0 * c[p, q])
            t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            cs = 1.0 / math.sqrt(t * t + 1.0)
            sn = t * cs
            for k in range(3):  # c ← Jᵀ c J
                a, b = c[k, p], c[k, q]
                c[k, p], c[k, q] = cs * a - sn * b, sn * a + cs * b
            for k in range(3):
                a, b = c[p, k], c[q, k]
                c[p, k], c[q, k] = cs * a - sn * b, sn * a + cs * b
            for k in range(3):
                a, b = v[k, p], v[k, q]
                v[k, p], v[k, q] = cs * a - sn * b, sn * a + cs * b


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


BLOCK = 1024
"""Gaussians per work item of :func:`move_gaussians` (its scratch matrices are allocated once per item)."""


@numba.njit(cache=True, parallel=True)
def move_gaussians(piece, rotation, stretch, wigner1, wigner2, wigner3, quats, log_scales, sh, growth):
    """For each moved Gaussian ``i`` (float64 arrays ``quats (P,4)``, ``log_scales (P,3)``, ``sh (P,K,3)``, updated in
    place as deform.py's module docstring says) with gradient piece ``p = piece[i]``: ``rotation[p]``, ``stretch[p]``
    the polar factors ``R``, ``U`` of ``F``, ``wigner{1,2,3}[p]`` the 3DGS-basis Wigner matrices of ``R`` (bands
    beyond the model's degree unused); ``growth[i]`` receives the anisotropy growth."""
    bands = int(round(math.sqrt(sh.shape[1]))) - 1
    for block in numba.prange((len(quats) + BLOCK - 1) // BLOCK):
        axes, local, work = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
        covariance, c, vectors, nearest = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
        scales, new, out, coefficients = np.empty(3), np.empty(3), np.empty(4), np.empty((sh.shape[1], 3))
        for i in range(block * BLOCK, min(len(quats), (block + 1) * BLOCK)):
            p = piece[i]
            q = quats[i]
            norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            w, x, y, z = q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm
            axes[0, 0], axes[0, 1], axes[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
            axes[1, 0], axes[1, 1], axes[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
            axes[2, 0], axes[2, 1], axes[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
            for a in range(3):
                scales[a] = math.exp(log_scales[i, a])
            _multiply(axes, stretch[p], work, True)
            _multiply(work, axes, local)  # R_qᵀ U R_q, then · S
            for a in range(3):
                for b in range(3):
                    local[a, b] *= scales[b]
            for a in range(3):
                for b in range(3):
                    covariance[a, b] = local[a, 0] * local[b, 0] + local[a, 1] * local[b, 1] + local[a, 2] * local[b, 2]
                    c[a, b] = covariance[a, b]
            _jacobi(c, vectors)
            best, order = -1.0, 0
            for k in range(6):
                score = 0.0
                for a in range(3):
                    score += abs(vectors[a, _PERMUTATIONS[k, a]])
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
            _multiply(covariance, nearest, work)
            for a in range(3):
                value = nearest[0, a] * work[0, a] + nearest[1, a] * work[1, a] + nearest[2, a] * work[2, a]
                new[a] = math.sqrt(max(value, 2.2250738585072014e-308))
                log_scales[i, a] = math.log(new[a])
            growth[i] = (max(new[0], new[1], new[2]) / min(new[0], new[1], new[2])) / (
                max(scales[0], scales[1], scales[2]) / min(scales[0], scales[1], scales[2])
            )
            _multiply(rotation[p], axes, work)
            _multiply(work, nearest, local)
            _quaternion(local, out)
            for k in range(4):
                quats[i, k] = out[k]
            for k in range(sh.shape[1]):
                for channel in range(3):
                    coefficients[k, channel] = sh[i, k, channel]
            for band in range(1, bands + 1):
                matrix = wigner1[p] if band == 1 else wigner2[p] if band == 2 else wigner3[p]
                first = band * band
                for a in range(2 * band + 1):
                    for channel in range(3):
                        total = 0.0
                        for b in range(2 * band + 1):
                            total += matrix[a, b] * coefficients[first + b, channel]
                        sh[i, first + a, channel] = total
