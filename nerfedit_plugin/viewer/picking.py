"""Screen-space picking for the editor: pixels ↔ world rays, visible vertices under a click, a box or a brush, and
drags in the view plane. Pure numpy on an OpenGL camera (:class:`View`) plus an Open3D ``RaycastingScene`` of the
displayed mesh — no window, so every rule is tested without a display.

Pixels are ``(x, y)`` from the view's top-left corner, ``y`` downwards; a pixel's centre is ``(x + 0.5, y + 0.5)``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from nerfedit_plugin.geometry.raycast import cast_rays, raycasting_scene

CLICK_RADIUS = 12.0
"""A click on points without a surface (a backend's joints or markers) picks the nearest one within this many pixels."""
VISIBLE_SLACK = 1e-3
"""A vertex is visible when the first surface hit on the ray towards it lies at least at its distance × (1 −
this) (float32 ray casting, vertices on the hit triangle)."""


class View(NamedTuple):
    """An OpenGL camera: ``view (4,4)`` world → camera (the camera looks along −z, y up), ``projection (4,4)``,
    and the viewport's ``width``, ``height`` in pixels."""

    view: np.ndarray
    projection: np.ndarray
    width: int
    height: int

    @property
    def camera_to_world(self) -> np.ndarray:
        """(4,4) float64: the camera's pose (OpenGL camera-to-world)."""
        return np.linalg.inv(np.asarray(self.view, dtype=np.float64))

    def ray(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        """pixel ``(x, y)`` → world ray ``(origin (3,), unit direction (3,))`` through its centre."""
        ndc = np.array([2.0 * (x + 0.5) / self.width - 1.0, 1.0 - 2.0 * (y + 0.5) / self.height, 1.0, 1.0])
        eye = np.linalg.solve(np.asarray(self.projection, dtype=np.float64), ndc)
        direction = self.camera_to_world[:3, :3] @ (eye[:3] / eye[3] if abs(eye[3]) > 1e-12 else eye[:3])
        return self.camera_to_world[:3, 3].copy(), direction / np.linalg.norm(direction)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """world points (N,3) → pixels (N,2) float64 and depth in front of the camera (N,) (≤ 0: behind it)."""
        homogeneous = np.column_stack([points, np.ones(len(points))])
        eye = homogeneous @ np.asarray(self.view, dtype=np.float64).T
        clip = eye @ np.asarray(self.projection, dtype=np.float64).T
        w = np.where(np.abs(clip[:, 3]) > 1e-12, clip[:, 3], 1e-12)
        pixels = np.column_stack(
            [(clip[:, 0] / w + 1.0) * 0.5 * self.width - 0.5, (1.0 - clip[:, 1] / w) * 0.5 * self.height - 0.5]
        )
        return pixels, -eye[:, 2]

    def plane_motion(self, anchor: np.ndarray, dx: float, dy: float) -> np.ndarray:
        """A drag of ``(dx, dy)`` pixels → the world translation (3,) in the view plane through ``anchor`` that keeps
        ``anchor`` under the cursor."""
        pixel, depth = self.project(np.asarray(anchor, dtype=np.float64)[None])
        if depth[0] <= 0:
            return np.zeros(3)
        start, towards = self.ray(*(pixel[0]))
        end, towards_end = self.ray(pixel[0, 0] + dx, pixel[0, 1] + dy)
        forward = -self.camera_to_world[:3, 2]
        at_anchor = (np.asarray(anchor) - start) @ forward
        return (
            end
            + towards_end * (at_anchor / (towards_end @ forward))
            - (start + towards * (at_anchor / (towards @ forward)))
        )


class Picker:
    """Picks vertices of a mesh as drawn (``vertices (V,3)``, ``faces (F,3)``) through a :class:`View`; without
    ``faces``, points that nothing hides (a backend's joints or markers)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray | None) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = None if faces is None else np.asarray(faces, dtype=np.int64)
        self.scene = None if faces is None else raycasting_scene(self.vertices, self.faces)

    def click(self, view: View, x: float, y: float) -> int | None:
        """The vertex nearest the surface point under pixel ``(x, y)`` (of the triangle hit), or None on empty
        space; without faces, the point nearest the pixel within :data:`CLICK_RADIUS` pixels."""
        if self.scene is None:
            near = self.brush(view, np.array([[x, y]]), CLICK_RADIUS)
            pixels = view.project(self.vertices[near])[0]
            return int(near[np.argmin(np.sum((pixels - [x, y]) ** 2, axis=1))]) if len(near) else None
        origin, direction = view.ray(x, y)
        hit = cast_rays(self.scene, np.concatenate([origin, direction])[None])
        if not np.isfinite(hit["t_hit"][0]):
            return None
        point = origin + float(hit["t_hit"][0]) * direction
        corners = self.faces[int(hit["primitive_ids"][0])]
        return int(corners[np.argmin(np.linalg.norm(self.vertices[corners] - point, axis=1))])

    def visible(self, view: View, candidates: np.ndarray) -> np.ndarray:
        """Vertex indices (K,) → those not hidden behind the surface from the camera (all, without one)."""
        if not len(candidates) or self.scene is None:
            return candidates
        eye = view.camera_to_world[:3, 3]
        towards = self.vertices[candidates] - eye
        distance = np.linalg.norm(towards, axis=1)
        rays = np.column_stack([np.broadcast_to(eye, towards.shape), towards / distance[:, None]])
        first = cast_rays(self.scene, rays)["t_hit"]
        return candidates[first >= distance * (1.0 - VISIBLE_SLACK)]

    def box(self, view: View, corner: tuple[float, float], opposite: tuple[float, float]) -> np.ndarray:
        """Visible vertex indices whose pixels lie in the rectangle spanned by two corners."""
        pixels, depth = view.project(self.vertices)
        low, high = np.minimum(corner, opposite), np.maximum(corner, opposite)
        inside = (depth > 0) & np.all((pixels >= low) & (pixels <= high), axis=1)
        return self.visible(view, np.flatnonzero(inside))

    def brush(self, view: View, path: np.ndarray, radius: float) -> np.ndarray:
        """Visible vertex indices within ``radius`` pixels of a cursor path ``(K,2)``."""
        pixels, depth = view.project(self.vertices)
        path = np.asarray(path, dtype=np.float64).reshape(-1, 2)
        near = np.zeros(len(pixels), dtype=bool)
        for point in path:
            near |= np.sum((pixels - point) ** 2, axis=1) <= radius * radius
        return self.visible(view, np.flatnonzero(near & (depth > 0)))
