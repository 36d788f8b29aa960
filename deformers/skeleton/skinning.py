"""Linear blend skinning and dual-quaternion skinning (Kavan et al., ACM TOG 2008), vectorised over points.

Bones are rigid maps ``x ↦ R x + t`` from rest to posed space (``rot (J,3,3)``, ``trans (J,3)`` float); weights
``(N,J)`` are non-negative with rows summing to 1 (:func:`normalize_weights`). LBS: ``x' = Σ_j w_j (R_j x + t_j)``;
DQS blends the bones' unit dual quaternions ``(J,8)`` (rows ``real w,x,y,z, dual w,x,y,z``), each sign-aligned with
the point's dominant bone, and normalises: always rigid per point. Per-point arrays are stored as component rows
(``(3,N)``, ``(J,N)``) for fast BLAS products. Formulas and reasons: docs/method.md, "Skeleton".
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

SkinningMethod = Literal["dqs", "lbs"]


def normalize_weights(weights: np.ndarray, threshold: float = 0.0) -> np.ndarray:
    """weights (N,J) float → (N,J) float64: negatives clipped to 0, weights below ``threshold`` zeroed (never a row's
    largest), each row rescaled to sum 1."""
    weights = np.clip(np.asarray(weights, dtype=np.float64), 0.0, None)
    keep = weights >= threshold
    keep[np.arange(len(weights)), weights.argmax(1)] = True
    weights = np.where(keep, weights, 0.0)
    return weights / weights.sum(1, keepdims=True)


@dataclass(frozen=True)
class Binding:
    """Rest points bound to bones: ``points_t (3,N)``, ``weights_t (J,N)``, and per bone the points it dominates."""

    points_t: np.ndarray
    weights_t: np.ndarray
    dominated: tuple[np.ndarray, ...]

    @classmethod
    def create(cls, points: np.ndarray, weights: np.ndarray) -> Binding:
        """points (N,3) float, weights (N,J) float (rows summing to 1) → the binding (float64 component rows)."""
        weights = np.asarray(weights, dtype=np.float64)
        dominant = weights.argmax(1)
        order = np.argsort(dominant, kind="stable")
        bounds = np.searchsorted(dominant[order], np.arange(weights.shape[1] + 1))
        dominated = tuple(order[bounds[k] : bounds[k + 1]] for k in range(weights.shape[1]))
        points_t = np.ascontiguousarray(np.asarray(points, dtype=np.float64).T)
        return cls(points_t, np.ascontiguousarray(weights.T), dominated)

    @property
    def weights(self) -> np.ndarray:
        return self.weights_t.T


def dual_quaternions(rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """rot (J,3,3), trans (J,3) float → unit dual quaternions ``(J,8)`` float64 (real w,x,y,z, dual w,x,y,z) of the
    rigid maps ``x ↦ R x + t``."""
    xyzw = Rotation.from_matrix(np.asarray(rot, dtype=np.float64).reshape(-1, 3, 3)).as_quat()
    w, v = xyzw[:, 3:], xyzw[:, :3]
    t = np.asarray(trans, dtype=np.float64).reshape(-1, 3)
    # q_ε = ½ (0, t) q = ½ (−t·v, w t + t × v)
    dual_w = -0.5 * np.sum(t * v, axis=1, keepdims=True)
    dual_v = 0.5 * (w * t + np.cross(t, v))
    return np.concatenate([w, v, dual_w, dual_v], axis=1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross products of component-row arrays ``(3,N)``."""
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def lbs(binding: Binding, rot: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """Linear blend skinning: binding of N points, rot (J,3,3), trans (J,3) → posed points ``(N,3)`` float64; blends
    the 3×4 bone matrices per point, then applies the blend."""
    bones = np.concatenate([np.asarray(rot).reshape(-1, 9), np.asarray(trans).reshape(-1, 3)], axis=1)
    blend = bones.T @ binding.weights_t  # (12, N): rows R00 R01 R02 R10 … R22 t0 t1 t2
    x = binding.points_t
    out = blend[9:] + blend[0:9:3] * x[0] + blend[1:9:3] * x[1] + blend[2:9:3] * x[2]
    return np.ascontiguousarray(out.T)


def dqs(binding: Binding, dq: np.ndarray) -> np.ndarray:
    """Dual-quaternion skinning: binding of N points, bone dual quaternions ``dq (J,8)`` float (their signs do not
    matter) → posed points ``(N,3)`` float64."""
    real = dq[:, :4]
    agree = real @ real.T >= 0.0  # agree[k, j]: bone j lies in bone k's hemisphere
    blend = dq.T @ binding.weights_t  # (8, N)
    for k in np.flatnonzero(~agree.all(1)):
        rows = binding.dominated[k]
        if rows.size:
            signed = np.where(agree[k], 1.0, -1.0)[:, None] * dq
            blend[:, rows] = signed.T @ binding.weights_t[:, rows]
    blend /= np.sqrt(np.sum(blend[:4] ** 2, axis=0))
    a0, d0, ae, de = blend[0], blend[1:4], blend[4], blend[5:]
    x = binding.points_t
    out = x + 2.0 * _cross(d0, _cross(d0, x) + a0 * x) + 2.0 * (a0 * de - ae * d0 + _cross(d0, de))
    return np.ascontiguousarray(out.T)


def skin(binding: Binding, rot: np.ndarray, trans: np.ndarray, method: SkinningMethod = "dqs") -> np.ndarray:
    """Posed positions ``(N,3)`` float64 of the bound points under bone transforms ``rot (J,3,3)``, ``trans (J,3)``
    with ``method`` (``"dqs"`` or ``"lbs"``)."""
    if method == "lbs":
        return lbs(binding, rot, trans)
    if method == "dqs":
        return dqs(binding, dual_quaternions(rot, trans))
    raise ValueError(f"unknown skinning method {method!r} (expected 'dqs' or 'lbs')")
