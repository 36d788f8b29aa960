"""Lens models of captures: pinhole intrinsics with Brown–Conrady (OpenCV) distortion, COLMAP's semantics.

A point ``(X, Y, Z)`` in an OpenCV camera frame (+z forward, +y down the image) projects to normalised coordinates
``(u, v) = (X/Z, Y/Z)``, is distorted with ``r² = u² + v²``, ``ρ = k1 r² + k2 r⁴ + k3 r⁶``::

    u_d = u (1 + ρ) + 2 p1 u v + p2 (r² + 2u²)
    v_d = v (1 + ρ) + p1 (r² + 2v²) + 2 p2 u v

and lands on pixel coordinates ``(fx u_d + cx, fy v_d + cy)``, the image's top-left corner at (0, 0) and pixel
``(x, y)``'s centre at ``(x + ½, y + ½)`` (COLMAP's and :mod:`nerfedit_plugin.data.cameras`'s convention). The
COLMAP models SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL and OPENCV are special cases; nerfstudio's OPENCV
``camera_model`` uses ``k1, k2, p1, p2`` (and ``k3`` when given). Fisheye and other models are refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nerfedit_plugin.errors import NerfEditError

COLMAP_MODELS = {
    "SIMPLE_PINHOLE": ("f", "cx", "cy"),
    "PINHOLE": ("fx", "fy", "cx", "cy"),
    "SIMPLE_RADIAL": ("f", "cx", "cy", "k1"),
    "RADIAL": ("f", "cx", "cy", "k1", "k2"),
    "OPENCV": ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"),
}
"""The COLMAP camera models nerfedit reads, with their parameter order (COLMAP's ``params``)."""
DISTORTION = ("k1", "k2", "k3", "p1", "p2")


@dataclass(frozen=True)
class Lens:
    """Intrinsics ``fx, fy, cx, cy`` (pixels) and distortion ``k1, k2, k3`` (radial), ``p1, p2`` (tangential)."""

    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0

    @classmethod
    def from_colmap(cls, model: str, params, where: str) -> Lens:
        """The lens of a COLMAP camera (``model`` name, ``params`` in its order); an unsupported model is a
        :class:`NerfEditError` naming ``where`` (the file and the camera)."""
        names = COLMAP_MODELS.get(model)
        if names is None:
            raise NerfEditError(
                f"{where}: camera model {model} is not supported (supported: {', '.join(COLMAP_MODELS)}); "
                "undistort the images first (COLMAP's image_undistorter) or re-run COLMAP with one of those"
            )
        values = [float(p) for p in params]
        if len(values) != len(names):
            raise NerfEditError(f"{where}: {model} expects {len(names)} parameters, got {len(values)}")
        found = dict(zip(names, values))
        if "f" in found:
            found["fx"] = found["fy"] = found.pop("f")
        return cls(**found)

    @property
    def distorted(self) -> bool:
        return any(getattr(self, k) != 0.0 for k in DISTORTION)

    def scaled(self, factor: int) -> Lens:
        """The lens of the image downscaled by ``factor`` (``f/k, c/k``; distortion acts on normalised coordinates
        and stays)."""
        return Lens(self.fx / factor, self.fy / factor, self.cx / factor, self.cy / factor, *self.coefficients)

    @property
    def coefficients(self) -> tuple[float, ...]:
        return tuple(getattr(self, k) for k in DISTORTION)

    def distort(self, uv: np.ndarray) -> np.ndarray:
        """Normalised coordinates ``(...,2)`` → distorted normalised coordinates (the module docstring's map)."""
        u, v = uv[..., 0], uv[..., 1]
        r2 = u * u + v * v
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        du = 2.0 * self.p1 * u * v + self.p2 * (r2 + 2.0 * u * u)
        dv = self.p1 * (r2 + 2.0 * v * v) + 2.0 * self.p2 * u * v
        return np.stack([u * radial + du, v * radial + dv], axis=-1)

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates ``(...,2)`` of points ``(...,3)`` in the OpenCV camera frame (in front: ``Z > 0``)."""
        points = np.asarray(points, dtype=np.float64)
        uv = self.distort(points[..., :2] / points[..., 2:3])
        return np.stack([self.fx * uv[..., 0] + self.cx, self.fy * uv[..., 1] + self.cy], axis=-1)

    def pixel_to_normalized(self, xy: np.ndarray) -> np.ndarray:
        """Undistorted pixel coordinates ``(...,2)`` → normalised coordinates (the inverse of the pinhole part)."""
        return np.stack([(xy[..., 0] - self.cx) / self.fx, (xy[..., 1] - self.cy) / self.fy], axis=-1)
