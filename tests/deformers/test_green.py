"""Green coordinates: Green's identity, exact similarities, and agreement with Lipman et al.'s pseudo-code."""

import igl
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_mean_value import star_cage

from deformers.cage.green import green_coordinates, green_deform, green_face_terms

V, F = star_cage()
RNG = np.random.default_rng(1)
_candidates = RNG.uniform(V.min(0), V.max(0), size=(2000, 3))
INSIDE = _candidates[igl.winding_number(V, F, _candidates) > 0.5][:400]
SCALE = float(np.linalg.norm(V.max(0) - V.min(0)))
NORMALS = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
NORMALS /= np.linalg.norm(NORMALS, axis=1, keepdims=True)


def gc_tri_int(p, v1, v2, eta):
    """GCTriInt of Lipman, Levin & Cohen-Or (2008), literally."""

    def angle(a, b):
        return np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1, 1))

    alpha, beta = angle(v2 - v1, p - v1), angle(v1 - p, v2 - p)
    lam = np.sum((p - v1) ** 2) * np.sin(alpha) ** 2
    c = np.sum((p - eta) ** 2)
    values = []
    for theta in (np.pi - alpha, np.pi - alpha - beta):
        s, co = np.sin(theta), np.cos(theta)
        first = 2 * np.sqrt(c) * np.arctan(np.sqrt(c) * co / np.sqrt(lam + s * s * c))
        inner = 1 - 2 * c * co / (c * (1 + co) + lam + np.sqrt(lam * lam + lam * c * s * s))
        second = np.sqrt(lam) * np.log(2 * np.sqrt(lam) * s * s / (1 - co) ** 2 * inner) if lam > 0 else 0.0
        values.append(-np.sign(s) / 2 * (first + second))
    return -abs(values[0] - values[1] - np.sqrt(c) * beta) / (4 * np.pi)


def lipman_reference(x, vertices, faces):
    """The paper's per-point pseudo-code (Algorithm 1, interior points)."""
    phi, psi = np.zeros(len(vertices)), np.zeros(len(faces))
    for j, tri in enumerate(faces):
        v = vertices[tri] - x
        n = np.cross(v[1] - v[0], v[2] - v[0])
        n /= np.linalg.norm(n)
        p = (v[0] @ n) * n
        s, big_i, big_ii, big_n = [], [], [], []
        for l in range(3):
            a, b = v[l], v[(l + 1) % 3]
            s.append(np.sign(np.cross(a - p, b - p) @ n))
            big_i.append(gc_tri_int(p, a, b, np.zeros(3)))
            big_ii.append(gc_tri_int(np.zeros(3), b, a, np.zeros(3)))
            q = np.cross(b, a)
            big_n.append(q / np.linalg.norm(q))
        total = -abs(sum(sk * ik for sk, ik in zip(s, big_i)))
        psi[j] = -total
        w = n * total + sum(nk * iik for nk, iik in zip(big_n, big_ii))
        for l in range(3):
            phi[tri[l]] += big_n[(l + 1) % 3] @ w / (big_n[(l + 1) % 3] @ v[l])
    return phi, psi


def test_agrees_with_lipman_pseudocode():
    phi, psi = green_coordinates(INSIDE[:4], V, F)
    for x, ours_phi, ours_psi in zip(INSIDE[:4], phi, psi):
        ref_phi, ref_psi = lipman_reference(x, V, F)
        assert np.abs(ours_phi - ref_phi).max() < 1e-9 and np.abs(ours_psi - ref_psi).max() < 1e-9


def test_greens_identity_reproduces_interior_points():
    phi, psi = green_coordinates(INSIDE, V, F)
    assert phi.shape == (len(INSIDE), len(V)) and psi.shape == (len(INSIDE), len(F))
    assert np.abs(phi @ V + psi @ NORMALS - INSIDE).max() < 1e-10 * SCALE
    assert np.abs(phi.sum(1) - 1).max() < 1e-10  # translations
    assert np.allclose(green_deform(phi, psi, V, V, F), INSIDE, rtol=0, atol=1e-10 * SCALE)


@pytest.mark.parametrize("scale", [0.5, 1.0, 2.5])
def test_similarity_maps_are_exact(scale):
    rotation = Rotation.from_rotvec([0.4, -0.9, 0.3]).as_matrix()
    shift = np.array([1.0, -2.0, 0.5])
    phi, psi = green_coordinates(INSIDE, V, F)
    out = green_deform(phi, psi, V, scale * V @ rotation.T + shift, F)
    assert np.abs(out - (scale * INSIDE @ rotation.T + shift)).max() < 1e-10 * scale * SCALE


def test_not_exact_for_a_non_uniform_stretch():
    """Green coordinates preserve shape (conformal-like), so a general affine cage map is not reproduced."""
    phi, psi = green_coordinates(INSIDE, V, F)
    stretch = np.diag([2.0, 1.0, 1.0])
    assert np.abs(green_deform(phi, psi, V, V @ stretch, F) - INSIDE @ stretch).max() > 1e-3 * SCALE


def test_face_terms_of_similar_cages():
    assert np.allclose(green_face_terms(V, V, F), NORMALS)
    rotation = Rotation.from_rotvec([0.0, 0.7, 0.2]).as_matrix()
    assert np.allclose(green_face_terms(V, 3.0 * V @ rotation.T, F), 3.0 * NORMALS @ rotation.T)
