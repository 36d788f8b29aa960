"""A Gaussian splat model as arrays, in the INRIA (3D Gaussian Splatting) parametrisation.

Gaussian ``i`` has mean ``μ_i``, rotation ``q_i = (w, x, y, z)`` (any non-zero quaternion: it is normalised where it is
used), log-scales ``s_i`` (``Σ_i = R(q_i) diag(exp 2 s_i) R(q_i)ᵀ``), opacity logit ``o_i`` (opacity
``sigmoid(o_i)``) and spherical-harmonics coefficients ``sh_i (K,3)``, ``K = (degree + 1)²`` per colour channel,
``sh_i[0]`` the DC term (``f_dc``). Its colour seen along the unit direction ``d`` from the camera centre to ``μ_i`` is
``max(Σ_k Y_k(d) sh_ik + ½, 0)`` with the real SH basis ``Y_k`` of :func:`nerfedit_plugin.fields.encoding.
spherical_harmonics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nerfedit_plugin.errors import NerfEditError

SH_C0 = 0.28209479177387814
"""``Y_0 = 1 / (2 √π)``: a DC coefficient ``c`` is the colour ``SH_C0 · c + ½``."""

MAX_DEGREE = 3


def degree_of(coefficients: int) -> int | None:
    """The SH degree ``d`` with ``(d + 1)² == coefficients`` (0..3), else None."""
    for degree in range(MAX_DEGREE + 1):
        if (degree + 1) ** 2 == coefficients:
            return degree
    return None


@dataclass
class SplatModel:
    """``N`` Gaussians: ``means (N,3)``, ``quats (N,4)`` w x y z, ``log_scales (N,3)``, ``opacities (N,)`` logits,
    ``sh (N,K,3)``; float32 or float64 arrays (as read)."""

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacities: np.ndarray
    sh: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.means)
        shapes = {
            "means": (n, 3),
            "quats": (n, 4),
            "log_scales": (n, 3),
            "opacities": (n,),
        }
        for name, shape in shapes.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"SplatModel.{name}: expected shape {shape}, got {getattr(self, name).shape}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3 or degree_of(self.sh.shape[1]) is None:
            raise ValueError(f"SplatModel.sh: expected shape ({n}, (d+1)², 3) with d in 0..3, got {self.sh.shape}")

    def __len__(self) -> int:
        return len(self.means)

    @property
    def degree(self) -> int:
        """SH degree 0..3."""
        return degree_of(self.sh.shape[1])

    def astype(self, dtype) -> SplatModel:
        return SplatModel(*(np.ascontiguousarray(a, dtype=dtype) for a in self.arrays()))

    def arrays(self) -> tuple[np.ndarray, ...]:
        return self.means, self.quats, self.log_scales, self.opacities, self.sh

    def validate(self, source: str) -> SplatModel:
        """``self`` if every Gaussian is usable, else one :class:`NerfEditError` ``"{source}: ..."`` naming the
        problem: no Gaussians, non-finite values (which attribute, how many, the first index), zero quaternions."""
        if len(self) == 0:
            raise NerfEditError(f"{source}: empty splat model (0 Gaussians)")
        for name, values in zip(("means", "quats", "log_scales", "opacities", "sh"), self.arrays()):
            bad = ~np.isfinite(values.reshape(len(self), -1)).all(1)
            if bad.any():
                raise NerfEditError(
                    f"{source}: {int(bad.sum())} Gaussian(s) with NaN/Inf {name} (first: Gaussian {int(bad.argmax())})"
                )
        zero = (self.quats.astype(np.float64) ** 2).sum(1) == 0
        if zero.any():
            raise NerfEditError(
                f"{source}: {int(zero.sum())} Gaussian(s) with a zero rotation quaternion (first: Gaussian "
                f"{int(zero.argmax())})"
            )
        return self


def synthetic_model(
    n: int,
    degree: int = 3,
    *,
    seed: int = 0,
    radius: float = 0.8,
    scale: tuple[float, float] = (0.01, 0.08),
    dtype=np.float32,
) -> SplatModel:
    """``n`` random Gaussians: means uniform in the ball of ``radius`` about the origin, random rotations (unnormalised
    quaternions), each axis's scale log-uniform in ``scale``, opacities uniform in (0.05, 0.95), DC colours uniform in
    [0, 1] and higher SH coefficients normal with standard deviation 0.1 (degrees 1..``degree``)."""
    rng = np.random.default_rng(seed)
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    means = direction * radius * rng.random((n, 1)) ** (1 / 3)
    quats = rng.normal(size=(n, 4)) * rng.uniform(0.5, 2.0, size=(n, 1))
    log_scales = rng.uniform(np.log(scale[0]), np.log(scale[1]), size=(n, 3))
    opacity = rng.uniform(0.05, 0.95, size=n)
    sh = rng.normal(scale=0.1, size=(n, (degree + 1) ** 2, 3))
    sh[:, 0] = (rng.random((n, 3)) - 0.5) / SH_C0
    model = SplatModel(means, quats, log_scales, np.log(opacity / (1 - opacity)), sh)
    return model.astype(dtype)


def surface_model(
    mesh, n: int, *, seed: int = 0, radius: float = 0.02, thickness: float = 0.1, opacity: float = 2.5
) -> SplatModel:
    """``n`` flat Gaussians on the surface of ``mesh`` (a ``trimesh.Trimesh``), area-uniform: tangent scales
    ``radius``, the normal one ``thickness × radius`` along the face normal, opacity logit ``opacity``, the vertex
    colours of the mesh (barycentric) as DC colour when it has them, else uniform random, and degree-3 SH of standard
    deviation 0.08 (float32)."""
    import trimesh
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    points, face = trimesh.sample.sample_surface(mesh, n, seed=seed)
    normal = mesh.face_normals[face]
    helper = np.where(np.abs(normal[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    first = np.cross(normal, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    axes = np.stack([first, np.cross(normal, first), normal], 2)  # columns: two tangents, the normal
    quats = Rotation.from_matrix(axes).as_quat()[:, [3, 0, 1, 2]]
    sh = rng.normal(scale=0.08, size=(n, 16, 3))
    if getattr(mesh.visual, "kind", None) == "vertex":
        corners = mesh.faces[face]
        weights = trimesh.triangles.points_to_barycentric(mesh.triangles[face], points)
        colors = np.einsum("nc,ncd->nd", weights, mesh.visual.vertex_colors[corners][..., :3] / 255.0)
    else:
        colors = rng.random((n, 3))
    sh[:, 0] = (colors - 0.5) / SH_C0
    log_scales = np.log(np.tile([radius, radius, thickness * radius], (n, 1)))
    return SplatModel(points, quats, log_scales, np.full(n, float(opacity)), sh).astype(np.float32)
