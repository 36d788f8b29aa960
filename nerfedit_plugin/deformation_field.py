"""DeformationField: a tet proxy in canonical space T and its deformed copies T' (one per frame).

``to_canonical`` maps deformed-space points back to canonical space (ray bending). A point located in deformed
tet ``t`` with barycentrics ``b`` maps to ``x_c = Σ b_i r_i`` (``r_i`` the rest corners), which equals the
per-tet affine map ``A_t x + c_t`` and the paper's ``x + Σ b_i (r_i - d_i)``; its Jacobian is
``A_t = [r1-r0, r2-r0, r3-r0] [d1-d0, d2-d0, d3-d0]^-1``, constant per tet (precomputed in float64, then cast).

Regions: inside T' -> mapped; outside T' but inside the rest proxy T -> ``empty`` (the space the object left;
the renderer treats it as empty); outside both -> identity (``x_c = x``, ``J = I``).

Degenerate and inverted deformed tets never crash: point location skips tets of (near) zero volume (see
:mod:`nerfedit_plugin.locate`), so their points fall to the ``empty``/identity rules; inverted tets are still
located (barycentrics do not depend on orientation) and map through their affine map, whose Jacobian then has
a negative determinant; where inverted tets overlap others, the smallest tet index wins.

Saved as ``deformation.npz`` (``format_version``, ``rest_vertices``, ``tets``, ``deformed_vertices``); it loads
without the deformer that made it. Locators are built lazily (one per frame on T', one on T) and cached.
"""

from __future__ import annotations

import os
import zipfile
from typing import NamedTuple

import numpy as np
import torch

from .atomic import atomic_path
from .errors import NerfEditError
from .locate import TetLocator

FORMAT_VERSION = 1
KEYS = ("rest_vertices", "tets", "deformed_vertices")


class CanonicalPoints(NamedTuple):
    points: torch.Tensor  # (M,3) x_c
    inside: torch.Tensor  # (M,) bool: located in the deformed proxy T' (mapped)
    empty: torch.Tensor  # (M,) bool: outside T' but inside the rest proxy T
    jacobian: torch.Tensor  # (M,3,3) dx_c/dx, constant per tet; identity where not inside


def _validate(rest, tets, deformed, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arrays as (N,3) f64, (K,4) i64, (F,N,3) f64, or :class:`NerfEditError` naming ``where`` and the key."""
    rest, tets, deformed = (x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)
                            for x in (rest, tets, deformed))
    if rest.ndim != 2 or rest.shape[1] != 3 or len(rest) < 4:
        raise NerfEditError(f"{where}: rest_vertices: expected shape (N>=4, 3), got {rest.shape}")
    if tets.ndim != 2 or tets.shape[1] != 4 or len(tets) == 0:
        raise NerfEditError(f"{where}: tets: expected shape (K>=1, 4), got {tets.shape}")
    if deformed.ndim == 2:
        deformed = deformed[None]
    if deformed.ndim != 3 or deformed.shape[1:] != rest.shape or len(deformed) == 0:
        raise NerfEditError(
            f"{where}: deformed_vertices: expected shape (F>=1, {len(rest)}, 3), got {deformed.shape}")
    for key, array in (("rest_vertices", rest), ("deformed_vertices", deformed)):
        if not np.issubdtype(array.dtype, np.number) or not np.isfinite(array).all():
            raise NerfEditError(f"{where}: {key}: values must be finite numbers")
    if not np.issubdtype(tets.dtype, np.integer):
        if not np.issubdtype(tets.dtype, np.floating) or not np.array_equal(tets, np.round(tets)):
            raise NerfEditError(f"{where}: tets: expected integer vertex indices, got {tets.dtype}")
    if tets.min() < 0 or tets.max() >= len(rest):
        raise NerfEditError(f"{where}: tets: vertex index out of range [0, {len(rest)})")
    return rest.astype(np.float64), tets.astype(np.int64), deformed.astype(np.float64)


class _Frame(NamedTuple):
    locator: TetLocator
    rest_rows: torch.Tensor  # (K,12): r0, then rest edges r1-r0, r2-r0, r3-r0 (columns of R, row-major)
    jacobian: torch.Tensor  # (K,3,3): A_t


class DeformationField:
    """Tet proxy in canonical space T plus its deformed copies T' per frame; maps deformed-space points to canonical."""

    def __init__(self, rest_vertices, tets, deformed_vertices, *, device="cpu", dtype=torch.float32):
        self.rest_vertices, self.tets, self.deformed_vertices = _validate(
            rest_vertices, tets, deformed_vertices, "DeformationField")
        self.device, self.dtype = torch.device(device), dtype
        self._frames: dict[int, _Frame] = {}
        self._rest_locator: TetLocator | None = None

    @property
    def n_frames(self) -> int:
        return len(self.deformed_vertices)

    def offsets(self, frame: int) -> np.ndarray:
        """``rest - deformed[frame]`` (N,3): the paper's barycentric offsets."""
        return self.rest_vertices - self.deformed_vertices[self._check_frame(frame)]

    def _check_frame(self, frame: int) -> int:
        if not 0 <= frame < self.n_frames:
            raise NerfEditError(f"frame {frame} out of range: the deformation field has {self.n_frames} frame(s)")
        return int(frame)

    def _frame(self, frame: int) -> _Frame:
        frame = self._check_frame(frame)
        if frame not in self._frames:
            tets = torch.as_tensor(self.tets, device=self.device)
            rest = torch.as_tensor(self.rest_vertices, device=self.device)[tets]
            deformed = torch.as_tensor(self.deformed_vertices[frame], device=self.device)
            corners = deformed[tets]
            edges_rest = (rest[:, 1:] - rest[:, :1]).transpose(1, 2)  # (K,3,3) columns
            edges = (corners[:, 1:] - corners[:, :1]).transpose(1, 2)
            ok = torch.linalg.det(edges) != 0
            eye = torch.eye(3, dtype=torch.float64, device=self.device)
            jacobian = edges_rest @ torch.linalg.inv(torch.where(ok[:, None, None], edges, eye))
            self._frames[frame] = _Frame(
                TetLocator(deformed, self.tets, dtype=self.dtype, device=self.device),
                torch.cat([rest[:, 0], edges_rest.reshape(-1, 9)], 1).to(self.dtype),
                torch.where(ok[:, None, None], jacobian, eye).to(self.dtype),
            )
        return self._frames[frame]

    def _rest(self) -> TetLocator:
        if self._rest_locator is None:
            self._rest_locator = TetLocator(self.rest_vertices, self.tets, dtype=self.dtype, device=self.device)
        return self._rest_locator

    def to_canonical(self, x: torch.Tensor, frame: int = 0) -> CanonicalPoints:
        """Map deformed-space points ``x (M,3)`` of ``frame`` to canonical space (see the module docstring)."""
        mapping = self._frame(frame)
        x = torch.as_tensor(x).to(device=self.device, dtype=self.dtype).reshape(-1, 3)
        tet, bary = mapping.locator.locate(x)
        inside = tet >= 0
        idx = torch.nonzero(inside).squeeze(1)
        t, b = tet.index_select(0, idx), bary.index_select(0, idx)
        r = mapping.rest_rows.index_select(0, t)
        points = x.clone()
        mapped = [r[:, i] + r[:, 3 + 3 * i] * b[:, 1] + r[:, 4 + 3 * i] * b[:, 2] + r[:, 5 + 3 * i] * b[:, 3]
                  for i in range(3)]  # r0 + R (b1, b2, b3) = Σ b_i r_i
        points.index_copy_(0, idx, torch.stack(mapped, 1))
        jacobian = torch.eye(3, dtype=self.dtype, device=self.device).repeat(len(x), 1, 1)
        jacobian.index_copy_(0, idx, mapping.jacobian.index_select(0, t))
        outside = torch.nonzero(~inside).squeeze(1)
        in_rest = self._rest().locate(x.index_select(0, outside))[0] >= 0
        empty = torch.zeros_like(inside).index_copy_(0, outside, in_rest)
        return CanonicalPoints(points, inside, empty, jacobian)

    def save(self, path: str | os.PathLike) -> None:
        """Write ``deformation.npz`` atomically."""
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez(handle, format_version=np.int64(FORMAT_VERSION), rest_vertices=self.rest_vertices,
                     tets=self.tets, deformed_vertices=self.deformed_vertices)

    @classmethod
    def load(cls, path: str | os.PathLike, *, device="cpu", dtype=torch.float32) -> "DeformationField":
        """Read a ``deformation.npz``; a missing, corrupt or incomplete file raises :class:`NerfEditError`."""
        if not os.path.isfile(path):
            raise NerfEditError(f"{path}: deformation file not found")
        try:
            with np.load(path, allow_pickle=False) as data:
                names = set(data.files)
                missing = [key for key in ("format_version", *KEYS) if key not in names]
                if missing:
                    raise NerfEditError(f"{path}: missing key '{missing[0]}' (expected {', '.join(KEYS)})")
                version = data["format_version"]
                if version.shape != () or int(version) != FORMAT_VERSION:
                    raise NerfEditError(f"{path}: format_version: unsupported {version} (expected {FORMAT_VERSION})")
                arrays = [data[key] for key in KEYS]
        except NerfEditError:
            raise
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
            raise NerfEditError(f"{path}: not a readable deformation .npz ({error})") from None
        return cls(*_validate(*arrays, str(path)), device=device, dtype=dtype)

    @classmethod
    def identity(cls, vertices, tets, n_frames: int = 1, **kwargs) -> "DeformationField":
        """Every frame equal to the rest proxy."""
        vertices = np.asarray(vertices, dtype=np.float64)
        return cls(vertices, tets, np.repeat(vertices[None], n_frames, axis=0), **kwargs)
