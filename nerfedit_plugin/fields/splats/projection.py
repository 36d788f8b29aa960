r"""Gaussians to the image plane (torch, differentiable): covariances, the EWA projection, view-dependent colour.

Conventions of 3D Gaussian Splatting and gsplat, so that a model trained elsewhere renders the same:

- ``Σ = R S Sᵀ Rᵀ``, ``R`` the rotation of the normalised quaternion ``(w, x, y, z)``, ``S = diag(exp(log_scales))``.
- Camera space is OpenCV's (x right, y down, z forward). nerfedit's :class:`~nerfedit_plugin.data.cameras.Cameras`
  are OpenGL camera-to-world, so the OpenCV camera-to-world is ``c2w · diag(1, −1, −1, 1)`` and the view matrix its
  inverse: ``x_c = Wᵀ(x − c)`` (``W`` the OpenCV camera axes, ``c`` the centre).
- A mean projects to ``u = (f_x x_c / z_c + c_x, f_y y_c / z_c + c_y)`` in pixel units whose pixel ``(i, j)`` has its
  centre at ``(i + ½, j + ½)``.
- EWA: ``Σ₂ = J Wᵀ Σ W Jᵀ + ε I`` with the affine approximation ``J = [[f_x/z, 0, −f_x x/z²], [0, f_y/z, −f_y y/z²]]``
  of the projection at the mean (``x/z``, ``y/z`` clamped to the image border plus 0.3 half fields of view, as 3DGS
  and gsplat do, so a Gaussian far outside the frustum does not smear across it) and the low-pass dilation
  ``ε = 0.3`` pixel². ``conic = Σ₂⁻¹`` as ``(a, b, c)`` for ``[[a, b], [b, c]]``.
- Antialiased mode (Mip-Splatting's 2D filter, gsplat's ``rasterize_mode="antialiased"``): the opacity is scaled by
  ``√(det(Σ₂ − ε I) / det Σ₂)``, so the dilation does not add energy to Gaussians smaller than a pixel.
- Colour: ``max(Σ_k Y_k(d) sh_k + ½, 0)`` with ``d`` the unit direction from the camera centre to the mean.

The renderer's fast path is the same arithmetic compiled (``rasterize.project_gaussians``); this module is the
differentiable reference it is tested against.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from nerfedit_plugin.fields.encoding import spherical_harmonics

EPS2D = 0.3
"""Low-pass dilation added to the 2D covariance (pixel²)."""
NEAR = 0.01
"""Gaussians with a view depth at or below this are not drawn."""
FRUSTUM_SLACK = 0.3
"""The Jacobian is evaluated with ``x/z``, ``y/z`` clamped to the image border plus this fraction of the half field of
view (3DGS's 1.3 half fields of view for a centred principal point)."""
_GL_TO_CV = torch.tensor([1.0, -1.0, -1.0])


def rotation_matrices(quats: torch.Tensor) -> torch.Tensor:
    """``(N,4)`` quaternions w x y z (any non-zero length) → ``(N,3,3)`` rotation matrices."""
    w, x, y, z = torch.nn.functional.normalize(quats, dim=-1).unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z),
        2 * (x * y - w * z),
        2 * (x * z + w * y),
        2 * (x * y + w * z),
        1 - 2 * (x * x + z * z),
        2 * (y * z - w * x),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    ]
    return torch.stack(rows, dim=-1).reshape(quats.shape[:-1] + (3, 3))


def covariances(quats: torch.Tensor, log_scales: torch.Tensor) -> torch.Tensor:
    """``Σ = (R S)(R S)ᵀ`` ``(N,3,3)`` of quaternions ``(N,4)`` and log-scales ``(N,3)``."""
    m = rotation_matrices(quats) * torch.exp(log_scales)[..., None, :]
    return m @ m.transpose(-1, -2)


def view_matrix(c2w_gl: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """OpenGL camera-to-world ``(4,4)`` → the OpenCV world-to-camera rotation ``(3,3)`` and translation ``(3,)``."""
    axes = c2w_gl[:3, :3] * _GL_TO_CV.to(c2w_gl)
    rotation = axes.T
    return rotation, -rotation @ c2w_gl[:3, 3]


def frustum_limits(intrinsics: tuple[float, float, float, float], width: int, height: int) -> tuple[float, ...]:
    """The clamps of ``x/z`` (towards +x, −x) and ``y/z`` (+y, −y) in the Jacobian: the image border plus
    ``FRUSTUM_SLACK`` half fields of view."""
    fx, fy, cx, cy = intrinsics
    slack_x, slack_y = FRUSTUM_SLACK * 0.5 * width / fx, FRUSTUM_SLACK * 0.5 * height / fy
    return (width - cx) / fx + slack_x, cx / fx + slack_x, (height - cy) / fy + slack_y, cy / fy + slack_y


class Projected(NamedTuple):
    means2d: torch.Tensor  # (N,2) pixel coordinates (pixel centres at +0.5)
    conics: torch.Tensor  # (N,3) a, b, c of Σ₂⁻¹
    covars2d: torch.Tensor  # (N,2,2) Σ₂ (dilated)
    depths: torch.Tensor  # (N,) z_c
    compensation: torch.Tensor  # (N,) √(det(Σ₂ − εI) / det Σ₂)


def project(
    means: torch.Tensor,
    covars: torch.Tensor,
    rotation: torch.Tensor,
    translation: torch.Tensor,
    intrinsics: tuple[float, float, float, float],
    width: int,
    height: int,
    eps2d: float = EPS2D,
) -> Projected:
    """The EWA projection (module docstring) of Gaussians ``means (N,3)``, ``covars (N,3,3)`` by the view
    ``x_c = rotation x + translation`` and pinhole ``intrinsics = (fx, fy, cx, cy)``."""
    fx, fy, cx, cy = intrinsics
    pc = means @ rotation.T + translation
    x, y, z = pc.unbind(-1)
    right, left, down, up = frustum_limits(intrinsics, width, height)
    tx = z * torch.clamp(x / z, min=-left, max=right)
    ty = z * torch.clamp(y / z, min=-up, max=down)
    zero = torch.zeros_like(z)
    jac = torch.stack([fx / z, zero, -fx * tx / (z * z), zero, fy / z, -fy * ty / (z * z)], dim=-1).reshape(-1, 2, 3)
    t = jac @ rotation
    cov2d = t @ covars @ t.transpose(-1, -2)
    det_raw = cov2d[:, 0, 0] * cov2d[:, 1, 1] - cov2d[:, 0, 1] * cov2d[:, 1, 0]
    cov2d = cov2d + eps2d * torch.eye(2, dtype=cov2d.dtype, device=cov2d.device)
    det = (cov2d[:, 0, 0] * cov2d[:, 1, 1] - cov2d[:, 0, 1] * cov2d[:, 1, 0]).clamp(min=1e-10)
    conics = torch.stack(
        [cov2d[:, 1, 1] / det, -0.5 * (cov2d[:, 0, 1] + cov2d[:, 1, 0]) / det, cov2d[:, 0, 0] / det], -1
    )
    means2d = torch.stack([fx * x / z + cx, fy * y / z + cy], dim=-1)
    compensation = torch.sqrt(torch.clamp(det_raw / det, min=0.0))
    return Projected(means2d, conics, cov2d, z, compensation)


def colors(sh: torch.Tensor, means: torch.Tensor, center: torch.Tensor, degree: int | None = None) -> torch.Tensor:
    """``(N,3)`` colours ``max(SH(d) + ½, 0)`` of coefficients ``sh (N,K,3)`` seen from ``center (3,)`` (bands up to
    ``degree``, default all of them)."""
    k = sh.shape[1]
    degree = round(k**0.5) - 1 if degree is None else degree
    directions = torch.nn.functional.normalize(means - center, dim=-1)
    basis = spherical_harmonics(directions, degree)
    return torch.clamp((basis[:, :, None] * sh[:, : (degree + 1) ** 2]).sum(1) + 0.5, min=0.0)
