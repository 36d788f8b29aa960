"""Fast pure-torch encodings: a dense trilinear voxel grid and the real spherical-harmonics basis of directions.

The grid table is channels-last, so a lookup of ``M`` points is one gather of ``(M, 8, C)`` contiguous corner rows.
Why dense rather than hashed or ``grid_sample``: docs/architecture.md, "fields/".
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

#: Corner order of :meth:`DenseGrid.corners`: (a, b, c) ∈ {0,1}³ with x slowest, z fastest.
_CORNERS = torch.tensor([(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)])


class DenseGrid(torch.nn.Module):
    """``channels`` values on the ``(N+1)³`` vertices of ``N³`` equal cells spanning the box ``bbox (2,3)``;
    a point's value is the trilinear blend of its cell's 8 corner values.

    Vertex ``(i, j, k)`` sits at ``lo + (i, j, k) · (hi − lo) / N``. Points outside the box are clamped to it
    (callers mask them). ``table`` is the parameter, shape ``((N+1)³, channels)``, row ``(i·(N+1) + j)·(N+1) + k``.
    """

    def __init__(self, bbox: torch.Tensor, resolution: int, channels: int, init: torch.Tensor | None = None) -> None:
        super().__init__()
        if resolution < 1 or channels < 1:
            raise ValueError(f"DenseGrid: resolution and channels must be positive, got {resolution}, {channels}")
        self.resolution, self.channels = int(resolution), int(channels)
        self.register_buffer("bbox", torch.as_tensor(bbox, dtype=torch.float32).reshape(2, 3).clone())
        n = self.resolution + 1
        table = torch.zeros(n**3, channels) if init is None else torch.as_tensor(init, dtype=torch.float32)
        if table.shape != (n**3, channels):
            raise ValueError(f"DenseGrid: init must have shape {(n**3, channels)}, got {tuple(table.shape)}")
        self.table = torch.nn.Parameter(table.clone())

    def _cell(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Table rows ``(M,8)`` of each point's cell corners and the point's fractional position ``(M,3)`` in it."""
        lo, hi = self.bbox
        n = self.resolution
        u = ((points - lo) / (hi - lo) * n).clamp(0.0, float(n))
        cell = u.detach().floor().clamp_max(n - 1)
        frac = u - cell
        cell = cell.long()
        stride = torch.tensor([(n + 1) ** 2, n + 1, 1], device=points.device)
        rows = (cell * stride).sum(-1, keepdim=True) + (_CORNERS.to(points.device) * stride).sum(-1)
        return rows, frac

    def corners(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Table rows ``(M,8)`` of each point's cell corners and their trilinear weights ``(M,8)`` (sum 1)."""
        rows, frac = self._cell(points)
        return rows, _blend(torch.stack([1.0 - frac, frac], dim=1))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        """Trilinear values ``(M, channels)`` at ``points (M,3)``."""
        rows, weights = self.corners(points)
        return torch.bmm(weights[:, None, :], F.embedding(rows, self.table))[:, 0]

    def value_and_gradient(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Trilinear values ``(M, channels)`` at ``points (M,3)`` and their exact spatial gradients
        ``(M, 3, channels)`` (of the interpolant of each point's cell; points outside the box are clamped onto it),
        from one gather. Differentiable with respect to the table, not the points: ``∂w_c/∂x_a`` replaces the
        factor of axis ``a`` in each corner weight by ``±N_a / (hi_a − lo_a)``."""
        lo, hi = self.bbox
        rows, frac = self._cell(points.detach())
        pair = torch.stack([1.0 - frac, frac], dim=1)  # (M, 2, 3)
        slope = torch.tensor([-1.0, 1.0], device=points.device)[:, None] * (self.resolution / (hi - lo))  # (2, 3)
        weights = [_blend(pair)] + [
            _blend(torch.cat([pair[..., :a], slope[:, a].expand(len(pair), 2)[..., None], pair[..., a + 1 :]], -1))
            for a in range(3)
        ]
        out = torch.bmm(torch.stack(weights, dim=1), F.embedding(rows, self.table))  # (M, 4, channels)
        return out[:, 0], out[:, 1:]

    @torch.no_grad()
    def upsample(self) -> None:
        """Double the resolution (``table`` becomes a new Parameter). Exact: the fine grid's trilinear
        interpolant equals the coarse one, since every fine cell lies inside one coarse cell."""
        n = 2 * self.resolution + 1
        fine = F.interpolate(self.vertex_values()[None], size=(n, n, n), mode="trilinear", align_corners=True)
        self.table = torch.nn.Parameter(fine[0].reshape(self.channels, -1).T.contiguous())
        self.resolution *= 2

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        """Adopt the resolution of a stored table (a checkpoint saved after coarse-to-fine refinement)."""
        stored = state_dict.get(prefix + "table")
        if stored is not None and stored.shape != self.table.shape and stored.ndim == 2:
            n = round(stored.shape[0] ** (1.0 / 3.0))
            if n**3 == stored.shape[0] and n >= 2 and stored.shape[1] == self.channels:
                self.resolution = n - 1
                self.table = torch.nn.Parameter(torch.empty_like(stored, device=self.table.device))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def vertex_values(self) -> torch.Tensor:
        """The table as a volume ``(channels, N+1, N+1, N+1)`` indexed ``[c, i, j, k]``."""
        n = self.resolution + 1
        return self.table.T.reshape(self.channels, n, n, n)

    def vertex_points(self) -> torch.Tensor:
        """World positions ``(N+1, N+1, N+1, 3)`` of the vertices."""
        lo, hi = self.bbox
        steps = torch.linspace(0.0, 1.0, self.resolution + 1, device=lo.device)
        axes = [steps * (hi[d] - lo[d]) + lo[d] for d in range(3)]
        return torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)


def _blend(pair: torch.Tensor) -> torch.Tensor:
    """Corner weights ``(M,8)`` (order of ``_CORNERS``) as products of per-axis factors ``pair (M,2,3)``:
    ``pair[:, b, a]`` is the factor of the corners on side ``b`` of axis ``a``."""
    return (pair[:, :, None, None, 0] * pair[:, None, :, None, 1] * pair[:, None, None, :, 2]).reshape(-1, 8)


def spherical_harmonics(directions: torch.Tensor, degree: int) -> torch.Tensor:
    """Real SH basis of unit ``directions (M,3)`` up to ``degree`` ∈ {0, 1, 2, 3}: ``(M, (degree+1)²)`` columns
    (the constants of Sloan's "Stupid SH tricks"; orthonormal on the sphere; the basis and order of 3D Gaussian
    Splatting's colours)."""
    if degree not in (0, 1, 2, 3):
        raise ValueError(f"spherical_harmonics: degree must be 0, 1, 2 or 3, got {degree}")
    x, y, z = directions.unbind(-1)
    bands = [torch.full_like(x, 0.28209479177387814)]
    if degree >= 1:
        bands += [-0.4886025119029199 * y, 0.4886025119029199 * z, -0.4886025119029199 * x]
    if degree >= 2:
        bands += [
            1.0925484305920792 * x * y,
            -1.0925484305920792 * y * z,
            0.31539156525252005 * (3.0 * z * z - 1.0),
            -1.0925484305920792 * x * z,
            0.5462742152960396 * (x * x - y * y),
        ]
    if degree >= 3:
        xx, yy, zz = x * x, y * y, z * z
        bands += [
            -math.sqrt(35 / (32 * math.pi)) * y * (3.0 * xx - yy),
            math.sqrt(105 / math.pi) / 2 * x * y * z,
            -math.sqrt(21 / (32 * math.pi)) * y * (4.0 * zz - xx - yy),
            math.sqrt(7 / math.pi) / 4 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            -math.sqrt(21 / (32 * math.pi)) * x * (4.0 * zz - xx - yy),
            math.sqrt(105 / math.pi) / 4 * z * (xx - yy),
            -math.sqrt(35 / (32 * math.pi)) * x * (xx - 3.0 * yy),
        ]
    return torch.stack(bands, dim=-1)
