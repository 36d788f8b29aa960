"""Pinhole cameras and camera rays (shared by datasets, training, rendering and the synthetic generator).

Conventions (Blender / nerfstudio): ``c2w`` is OpenGL camera-to-world — the camera looks down its −z axis, +y is
up in the image, +x is right. Pixel ``(x, y)`` (column, row) has its centre at ``(x + 0.5, y + 0.5)``, so the ray
through it has camera-space direction ``((x + 0.5 − cx) / fx, −(y + 0.5 − cy) / fy, −1)``. With this convention
downscaling by an integer factor ``k`` (averaging k×k pixel blocks) maps intrinsics exactly to ``f/k, c/k``.
All functions are device-agnostic torch: outputs live on the cameras' device.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class Cameras:
    """A batch of ``C`` pinhole cameras sharing one image size.

    ``c2w (C,4,4)`` OpenGL camera-to-world; ``fx, fy, cx, cy (C,)`` in pixels (scalars broadcast); ``width,
    height`` in pixels.
    """

    c2w: torch.Tensor
    fx: torch.Tensor
    fy: torch.Tensor
    cx: torch.Tensor
    cy: torch.Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        self.c2w = torch.as_tensor(self.c2w, dtype=torch.float32)
        if self.c2w.ndim != 3 or self.c2w.shape[1:] != (4, 4):
            raise ValueError(f"Cameras.c2w: expected shape (C,4,4), got {tuple(self.c2w.shape)}")
        n, device = self.c2w.shape[0], self.c2w.device
        for name in ("fx", "fy", "cx", "cy"):
            value = torch.as_tensor(getattr(self, name), dtype=torch.float32, device=device)
            value = value.expand(n).clone() if value.ndim == 0 else value
            if value.shape != (n,):
                raise ValueError(f"Cameras.{name}: expected shape ({n},), got {tuple(value.shape)}")
            setattr(self, name, value)
        self.width, self.height = int(self.width), int(self.height)
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Cameras: image size must be positive, got {self.width}x{self.height}")

    @classmethod
    def from_fov(cls, c2w: torch.Tensor, width: int, height: int, camera_angle_x: float) -> Cameras:
        """Square pixels, centred principal point, horizontal field of view ``camera_angle_x`` (radians):
        ``fx = fy = width / (2 tan(camera_angle_x / 2))`` — the Blender / NeRF-synthetic model."""
        focal = 0.5 * width / math.tan(0.5 * camera_angle_x)
        return cls(c2w, focal, focal, width / 2.0, height / 2.0, width, height)

    def __len__(self) -> int:
        return self.c2w.shape[0]

    def __getitem__(self, index) -> Cameras:
        """Subset of cameras (an int keeps the batch dimension)."""
        index = [index] if isinstance(index, int) else index
        return Cameras(
            self.c2w[index], self.fx[index], self.fy[index], self.cx[index], self.cy[index], self.width, self.height
        )

    @property
    def device(self) -> torch.device:
        return self.c2w.device

    @property
    def centers(self) -> torch.Tensor:
        """Camera positions in world space ``(C,3)``."""
        return self.c2w[:, :3, 3]

    @property
    def camera_angle_x(self) -> torch.Tensor:
        """Horizontal field of view per camera (radians), ``2 atan(width / (2 fx))``."""
        return 2.0 * torch.atan(0.5 * self.width / self.fx)

    def to(self, device: torch.device | str) -> Cameras:
        return Cameras(
            self.c2w.to(device),
            self.fx.to(device),
            self.fy.to(device),
            self.cx.to(device),
            self.cy.to(device),
            self.width,
            self.height,
        )

    def transformed(self, similarity) -> Cameras:
        """The cameras moved by a similarity ``x ↦ sRx + b`` ``(4,4)`` (scale ``s = ∛det``): positions mapped, axes
        rotated by ``R``; the images they see are those of the scene moved by it (intrinsics unchanged)."""
        matrix = torch.as_tensor(np.asarray(similarity, dtype=np.float64))
        scale = float(torch.linalg.det(matrix[:3, :3])) ** (1.0 / 3.0)
        c2w = self.c2w.double().cpu()
        moved = c2w.clone()
        moved[:, :3, :3] = matrix[:3, :3] @ c2w[:, :3, :3] / scale
        moved[:, :3, 3] = c2w[:, :3, 3] @ matrix[:3, :3].T + matrix[:3, 3]
        return Cameras(moved.float().to(self.device), self.fx, self.fy, self.cx, self.cy, self.width, self.height)

    def downscale(self, factor: int) -> Cameras:
        """Cameras of images downscaled by averaging ``factor``×``factor`` pixel blocks: intrinsics ÷ factor,
        size ``floor(size / factor)`` (a partial last block row/column is cropped; that does not move ``c``)."""
        factor = _positive_int(factor, "downscale factor")
        if self.width < factor or self.height < factor:
            raise ValueError(f"downscale factor {factor} exceeds the image size {self.width}x{self.height}")
        return Cameras(
            self.c2w,
            self.fx / factor,
            self.fy / factor,
            self.cx / factor,
            self.cy / factor,
            self.width // factor,
            self.height // factor,
        )

    def upscale(self, factor: int) -> Cameras:
        """The exact inverse of :meth:`downscale` (used for supersampling): ``downscale(k)`` of the
        ``upscale(k)`` cameras averages ``k``×``k`` stratified sub-pixel samples per pixel."""
        factor = _positive_int(factor, "upscale factor")
        return Cameras(
            self.c2w,
            self.fx * factor,
            self.fy * factor,
            self.cx * factor,
            self.cy * factor,
            self.width * factor,
            self.height * factor,
        )


def _positive_int(value, what: str) -> int:
    if int(value) != value or value < 1:
        raise ValueError(f"{what} must be a positive integer, got {value}")
    return int(value)


def generate_rays(
    cameras: Cameras, index: int | torch.Tensor | None = None, pixels: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """World-space rays ``(origins, directions)``, directions of unit length.

    - ``pixels=None``: every pixel; ``index=None`` → shape ``(C,H,W,3)``, an int → ``(H,W,3)``, a tensor of ``K``
      camera indices → ``(K,H,W,3)``.
    - ``pixels (...,2)``: pixel indices or continuous coordinates ``(x=column, y=row)``; the ray goes through
      ``(x + 0.5, y + 0.5)``. ``index`` is an int (all rays from one camera) or a tensor broadcastable to
      ``pixels[...,0]`` (per-ray camera, e.g. a random training batch). Output shape ``(...,3)``.
    """
    device = cameras.device
    if pixels is None:
        ys, xs = torch.meshgrid(
            torch.arange(cameras.height, device=device, dtype=torch.float32),
            torch.arange(cameras.width, device=device, dtype=torch.float32),
            indexing="ij",
        )
        if index is None:
            cam = torch.arange(len(cameras), device=device)[:, None, None]
        else:
            cam = torch.as_tensor(index, device=device)
            cam = cam[..., None, None] if cam.ndim else cam
    else:
        if index is None:
            if len(cameras) != 1:
                raise ValueError("generate_rays: pixels given for several cameras; pass index")
            index = 0
        pixels = torch.as_tensor(pixels, device=device).to(torch.float32)
        xs, ys = pixels[..., 0], pixels[..., 1]
        cam = torch.as_tensor(index, device=device)
    fx, fy, cx, cy = cameras.fx[cam], cameras.fy[cam], cameras.cx[cam], cameras.cy[cam]
    u, v = (xs + 0.5 - cx) / fx, -(ys + 0.5 - cy) / fy  # camera-space direction (u, v, -1)
    c2w = cameras.c2w[cam]
    directions = u[..., None] * c2w[..., :3, 0] + v[..., None] * c2w[..., :3, 1] - c2w[..., :3, 2]
    directions = torch.nn.functional.normalize(directions, dim=-1)
    origins = torch.broadcast_to(c2w[..., :3, 3], directions.shape).contiguous()
    return origins, directions


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> torch.Tensor:
    """OpenGL camera-to-world ``(...,4,4)`` of cameras at ``eye (...,3)`` looking at ``target``.

    ``z = normalize(eye − target)`` (the camera looks down −z), ``x = normalize(up × z)``, ``y = z × x``.
    Where ``up`` is (nearly) parallel to the view direction, the world axis least aligned with it is used instead.
    """
    eye = torch.as_tensor(eye, dtype=torch.float64)
    target = torch.as_tensor(target, dtype=torch.float64, device=eye.device)
    z = torch.nn.functional.normalize(eye - target, dim=-1)
    up = torch.broadcast_to(torch.as_tensor(up, dtype=torch.float64, device=eye.device), z.shape)
    parallel = torch.linalg.norm(torch.linalg.cross(up, z), dim=-1, keepdim=True) < 1e-6
    fallback = torch.nn.functional.one_hot(z.abs().argmin(-1), 3).to(z)
    up = torch.where(parallel, fallback, up)
    x = torch.nn.functional.normalize(torch.linalg.cross(up, z), dim=-1)
    y = torch.linalg.cross(z, x)
    c2w = torch.zeros(z.shape[:-1] + (4, 4), dtype=torch.float64, device=eye.device)
    c2w[..., :3, 0], c2w[..., :3, 1], c2w[..., :3, 2], c2w[..., :3, 3] = x, y, z, torch.broadcast_to(eye, z.shape)
    c2w[..., 3, 3] = 1.0
    return c2w.to(torch.float32)


def sphere_poses(
    n: int, radius: float, center=(0.0, 0.0, 0.0), hemisphere: bool = False, seed: int = 0
) -> torch.Tensor:
    """``n`` camera-to-world poses ``(n,4,4)`` evenly spread on a sphere (or the upper, +z hemisphere) of
    ``radius`` around ``center``, all looking at ``center`` with +z as world up.

    Fibonacci spiral: ``z_k = 1 − (k + ½)/n`` (hemisphere) or ``1 − 2(k + ½)/n`` (sphere), i.e. equal-area bands,
    azimuth ``φ_k = k·π(3 − √5) + φ₀`` with ``φ₀`` drawn from ``seed`` (different seeds give different views).
    """
    if n < 1:
        raise ValueError(f"sphere_poses: n must be >= 1, got {n}")
    k = np.arange(n) + 0.5
    z = 1.0 - k / n if hemisphere else 1.0 - 2.0 * k / n
    phi = np.arange(n) * math.pi * (3.0 - math.sqrt(5.0)) + np.random.default_rng(seed).uniform(0, 2 * math.pi)
    ring = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    directions = np.stack([ring * np.cos(phi), ring * np.sin(phi), z], axis=-1)
    center = np.asarray(center, dtype=np.float64)
    return look_at(torch.from_numpy(center + radius * directions), torch.from_numpy(center))


def orbit_poses(
    n: int,
    radius: float,
    center=(0.0, 0.0, 0.0),
    elevation: tuple[float, float] = (15.0, 65.0),
    azimuth: tuple[float, float] = (-180.0, 180.0),
    seed: int = 0,
) -> torch.Tensor:
    """``n`` camera-to-world poses ``(n,4,4)`` spread over the band of a sphere of ``radius`` around ``center``
    between two ``elevation`` angles and two ``azimuth`` angles (degrees; azimuth from +x towards +y, elevation
    above the xy plane), all looking at ``center`` with +z as world up.

    Equal-area strata of elevation, ``sin e_k = sin e₀ + (k + ½)/n (sin e₁ − sin e₀)``, with azimuths along a
    golden-ratio sequence, ``a_k = a₀ + (a₁ − a₀)·frac(u + k(√5 − 1)/2)``, ``u`` drawn from ``seed`` (different
    seeds give different views). The full azimuth range is a band of the Fibonacci spiral of :func:`sphere_poses`.
    """
    if n < 1:
        raise ValueError(f"orbit_poses: n must be >= 1, got {n}")
    low, high = np.sin(np.radians(elevation))
    z = low + (np.arange(n) + 0.5) / n * (high - low)
    fraction = np.mod(np.random.default_rng(seed).uniform() + np.arange(n) * (math.sqrt(5.0) - 1.0) / 2.0, 1.0)
    phi = np.radians(azimuth[0] + (azimuth[1] - azimuth[0]) * fraction)
    ring = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    directions = np.stack([ring * np.cos(phi), ring * np.sin(phi), z], axis=-1)
    center = np.asarray(center, dtype=np.float64)
    return look_at(torch.from_numpy(center + radius * directions), torch.from_numpy(center))


OPENCV_TO_OPENGL = np.diag([1.0, -1.0, -1.0, 1.0])
"""Right-multiplying a camera-to-world matrix by this flips its y and z axes: OpenCV/COLMAP cameras (looking down
+z, +y down the image) ↔ OpenGL cameras (looking down −z, +y up). It is its own inverse."""


def opengl_from_world_to_camera(world_to_camera: np.ndarray) -> np.ndarray:
    """OpenGL camera-to-world ``(...,4,4)`` of OpenCV world-to-camera poses ``[R | t]`` ``(...,3,4)`` or
    ``(...,4,4)`` (COLMAP's ``cam_from_world``): ``c2w = [Rᵀ | −Rᵀt] · diag(1, −1, −1, 1)``, float64."""
    rotation, translation = world_to_camera[..., :3, :3], world_to_camera[..., :3, 3]
    c2w = np.zeros(world_to_camera.shape[:-2] + (4, 4))
    c2w[..., :3, :3] = np.swapaxes(rotation, -1, -2)
    c2w[..., :3, 3] = -np.einsum("...ji,...j->...i", rotation, translation)
    c2w[..., 3, 3] = 1.0
    return c2w @ OPENCV_TO_OPENGL


def world_to_camera_from_opengl(c2w: np.ndarray) -> np.ndarray:
    """The inverse of :func:`opengl_from_world_to_camera`: OpenCV world-to-camera ``(...,4,4)`` of OpenGL
    camera-to-world poses."""
    return np.linalg.inv(np.asarray(c2w, dtype=np.float64) @ OPENCV_TO_OPENGL)
