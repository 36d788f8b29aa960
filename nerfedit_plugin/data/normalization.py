"""Normalising a capture like nerfstudio's dataparser: orient, centre, scale — one recorded similarity.

A capture comes in its tool's coordinates (COLMAP's arbitrary frame; the *capture* frame). nerfedit trains in a
frame where

1. *orient*: the mean camera up vector (OpenGL ``c2w[:, :3, 1]``) is +z, by the smallest rotation ``R`` taking one
   to the other (nerfstudio's ``orientation_method="up"``);
2. *centre*: the centre ``c`` of the foreground box (:func:`nerfedit_plugin.data.bounds.foreground_box`, from the
   sparse points or else the frustums, computed in the oriented frame) is the origin;
3. *scale*: the cameras fit the unit box, ``s = 1 / max_i ‖R p_i − c‖_∞`` (nerfstudio's ``auto_scale_poses``).

So ``x_world = s (R x − c)``: the (4,4) ``source_transform`` a run records (``Run.source_transform()``), the same
notion as a generated dataset's; an extracted mesh maps back to the capture by its inverse.
"""

from __future__ import annotations

import numpy as np

from nerfedit_plugin.data.bounds import foreground_box
from nerfedit_plugin.data.cameras import Cameras


def up_rotation(up) -> np.ndarray:
    """(3,3) the smallest rotation taking the direction ``up`` to +z (Rodrigues; a half turn about x when ``up``
    points down)."""
    a = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(a, z), float(a @ z)
    if c < -1.0 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def similarity(scale: float, rotation: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """(4,4) ``x ↦ scale · (rotation x − centre)``."""
    matrix = np.eye(4)
    matrix[:3, :3] = scale * rotation
    matrix[:3, 3] = -scale * np.asarray(centre, dtype=np.float64)
    return matrix


def apply(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Points ``(...,3)`` mapped by the affine ``matrix (4,4)``."""
    return np.asarray(points, dtype=np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def box_bounds(matrix: np.ndarray, box: np.ndarray) -> np.ndarray:
    """(2,3) the axis-aligned bounds of ``box (2,3)``'s 8 corners mapped by ``matrix``."""
    corners = np.stack(np.meshgrid(*np.asarray(box, dtype=np.float64).T, indexing="ij"), axis=-1).reshape(-1, 3)
    moved = apply(matrix, corners)
    return np.stack([moved.min(0), moved.max(0)])


def normalize_capture(cameras: Cameras, points: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``(source_transform (4,4), foreground box (2,3))``: the capture-to-world similarity of the module docstring
    for ``cameras`` (capture frame) and the optional sparse ``points (P,3)``, and the foreground box in the world
    frame."""
    up = cameras.c2w[:, :3, 1].double().cpu().numpy().mean(0)
    rotation = up_rotation(up) if np.linalg.norm(up) > 1e-9 else np.eye(3)
    oriented = cameras.transformed(similarity(1.0, rotation, np.zeros(3)))
    box = foreground_box(oriented, None if points is None else points @ rotation.T)
    centre = box.mean(0)
    reach = np.abs(oriented.centers.double().cpu().numpy() - centre).max()
    scale = 1.0 / reach if reach > 0 else 1.0
    return similarity(scale, rotation, centre), scale * (box - centre)
