r"""Rotation of real spherical-harmonic coefficients (the 3DGS colour basis) by real Wigner matrices.

For a rotation ``R`` the band-``ℓ`` basis functions (``2ℓ + 1`` of them, :func:`~nerfedit_plugin.fields.encoding.
spherical_harmonics`) satisfy ``Y_ℓ(R d) = M_ℓ(R) Y_ℓ(d)`` with an orthogonal ``(2ℓ+1)×(2ℓ+1)`` matrix ``M_ℓ``
(band 0 is invariant, ``M_0 = 1``). A colour ``c(d) = Σ_k Y_k(d) sh_k`` carried by ``R`` becomes ``c(Rᵀ d)``, whose
coefficients are ``sh'_ℓ = M_ℓ(R) sh_ℓ`` per band and channel.

``M_ℓ`` comes from the recurrences of Ivanic & Ruedenberg (J. Phys. Chem. 1996, 100, 6342; erratum 1998, 102, 9099)
in the standard real basis ordered ``m = −ℓ..ℓ`` (band 1 is ``(y, z, x)``: ``M_1`` is ``R`` with its rows and columns
in that order), ``M_ℓ[m, n] = u P_U + v P_V + w P_W`` from ``M_1`` and ``M_{ℓ−1}``. The 3DGS basis is that one with
the Condon–Shortley phase ``(−1)^m``, so its matrices are ``S M_ℓ S``, ``S = diag((−1)^m)``. Exact (no sampling).
"""

from __future__ import annotations

import math

import torch

_AXES = (1, 2, 0)
"""Band 1 of the standard real basis: ``m = −1, 0, 1`` ↔ ``y, z, x``."""


def _centred(matrix: torch.Tensor, band: int, i: int, j: int) -> torch.Tensor:
    return matrix[:, i + band, j + band]


def _p(i: int, a: int, b: int, band: int, m1: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
    """Ivanic–Ruedenberg's ``P``: row ``i`` of ``M_1`` against row ``a`` of ``M_{ℓ−1}`` at column ``b``."""
    lower = band - 1
    if b == band:
        return _centred(m1, 1, i, 1) * _centred(previous, lower, a, lower) - _centred(m1, 1, i, -1) * _centred(
            previous, lower, a, -lower
        )
    if b == -band:
        return _centred(m1, 1, i, 1) * _centred(previous, lower, a, -lower) + _centred(m1, 1, i, -1) * _centred(
            previous, lower, a, lower
        )
    return _centred(m1, 1, i, 0) * _centred(previous, lower, a, b)


def _band(band: int, m1: torch.Tensor, previous: torch.Tensor) -> torch.Tensor:
    """``M_ℓ (N, 2ℓ+1, 2ℓ+1)`` in the standard real basis from ``M_1`` and ``M_{ℓ−1}``."""
    rows = []
    for m in range(-band, band + 1):
        row = []
        for n in range(-band, band + 1):
            centre = m == 0
            denominator = 2 * band * (2 * band - 1) if abs(n) == band else (band + n) * (band - n)
            u = math.sqrt((band + m) * (band - m) / denominator)
            v = 0.5 * math.sqrt((1 + centre) * (band + abs(m) - 1) * (band + abs(m)) / denominator) * (1 - 2 * centre)
            w = -0.5 * math.sqrt((band - abs(m) - 1) * (band - abs(m)) / denominator) * (1 - centre)
            value = torch.zeros_like(m1[:, 0, 0])
            if u:
                value = value + u * _p(0, m, n, band, m1, previous)
            if v:
                if m == 0:
                    term = _p(1, 1, n, band, m1, previous) + _p(-1, -1, n, band, m1, previous)
                elif m > 0:
                    one = m == 1
                    term = _p(1, m - 1, n, band, m1, previous) * math.sqrt(1 + one)
                    if not one:
                        term = term - _p(-1, -m + 1, n, band, m1, previous)
                else:
                    one = m == -1
                    term = _p(-1, -m - 1, n, band, m1, previous) * math.sqrt(1 + one)
                    if not one:
                        term = term + _p(1, m + 1, n, band, m1, previous)
                value = value + v * term
            if w:
                if m > 0:
                    term = _p(1, m + 1, n, band, m1, previous) + _p(-1, -m - 1, n, band, m1, previous)
                else:
                    term = _p(1, m - 1, n, band, m1, previous) - _p(-1, -m + 1, n, band, m1, previous)
                value = value + w * term
            row.append(value)
        rows.append(torch.stack(row, -1))
    return torch.stack(rows, -2)


def wigner_matrices(rotations: torch.Tensor, degree: int) -> list[torch.Tensor]:
    """``rotations (N,3,3)`` (proper rotations) → ``[M_1, …, M_degree]``, ``M_ℓ (N, 2ℓ+1, 2ℓ+1)`` in the 3DGS basis
    (module docstring), in the rotations' dtype."""
    m1 = rotations[:, _AXES][:, :, _AXES]
    standard, matrices = m1, []
    for band in range(1, degree + 1):
        if band > 1:
            standard = _band(band, m1, standard)
        sign = torch.tensor([(-1.0) ** m for m in range(-band, band + 1)], dtype=rotations.dtype)
        matrices.append(standard * sign[:, None] * sign[None, :])
    return matrices


def rotate_sh(sh: torch.Tensor, rotations: torch.Tensor) -> torch.Tensor:
    """Coefficients ``sh (N,K,3)`` (``K = (d+1)²``) of colours carried by ``rotations (N,3,3)`` → ``(N,K,3)``:
    ``sh'_ℓ = M_ℓ(R) sh_ℓ`` per band (band 0 unchanged)."""
    degree = round(sh.shape[1] ** 0.5) - 1
    out = sh.clone()
    for band, matrix in enumerate(wigner_matrices(rotations.to(sh.dtype), degree), start=1):
        rows = slice(band * band, (band + 1) ** 2)
        out[:, rows] = matrix @ sh[:, rows]
    return out
