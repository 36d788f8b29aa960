"""Synthetic mesh sequences (same connectivity in every frame) for tests, docs and deformation transfer examples.

No redistributable mesh-sequence dataset is available offline, so sequences are generated: each function returns
``(rest SurfaceMesh, frames (F, V, 3) float64)`` with frame ``i`` at time ``t = i / (F − 1)`` (frame 0 is the rest
pose); :func:`write_sequence` writes one as a folder (``rest.ply`` + ``frames.npz`` or ``frame_0000.ply`` …).
Everything is deterministic and made from trimesh primitives, so the files are freely redistributable.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_dir


def _times(n_frames: int) -> np.ndarray:
    if n_frames < 1:
        raise NerfEditError(f"n_frames: expected an integer >= 1, got {n_frames}")
    return np.linspace(0.0, 1.0, n_frames) if n_frames > 1 else np.ones(1)


def capsule(height: float = 1.0, radius: float = 0.25, count: tuple[int, int] = (24, 12)) -> SurfaceMesh:
    """A closed capsule along z centred at the origin: cylinder ``height`` plus two caps of ``radius``; ``count``
    = (segments around, rings) as in ``trimesh.creation.capsule``."""
    import trimesh

    mesh = trimesh.creation.capsule(height=height, radius=radius, count=list(count))
    return SurfaceMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))


def bending_capsule(
    n_frames: int = 8, degrees: float = 90.0, count: tuple[int, int] = (24, 12)
) -> tuple[SurfaceMesh, np.ndarray]:
    """A capsule (height 1, radius 0.25, along z) bending at its middle: linear blend skinning of two bones, the
    lower one fixed, the upper one turning about the x axis through the origin by ``t · degrees``; the upper bone's
    weight is a smoothstep of z over [−0.2, 0.2]."""
    rest = capsule(count=count)
    z = np.clip((rest.vertices[:, 2] + 0.2) / 0.4, 0.0, 1.0)
    weight = (z * z * (3.0 - 2.0 * z))[:, None]
    frames = []
    for t in _times(n_frames):
        turned = rest.vertices @ Rotation.from_euler("x", t * degrees, degrees=True).as_matrix().T
        frames.append(rest.vertices + weight * (turned - rest.vertices))
    return rest, np.stack(frames)


def twisting_bar(n_frames: int = 8, degrees: float = 180.0, subdivisions: int = 3) -> tuple[SurfaceMesh, np.ndarray]:
    """A bar 0.3 × 0.3 × 1.2 along z (a box split ``subdivisions`` times, each splitting every triangle in four)
    twisting about z: a point at height z turns by ``t · degrees · (z − z_min) / length``."""
    import trimesh

    box = trimesh.creation.box(extents=[0.3, 0.3, 1.2])
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces)
    for _ in range(subdivisions):
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
    rest = SurfaceMesh(vertices, faces)
    fraction = (rest.vertices[:, 2] + 0.6) / 1.2
    frames = []
    for t in _times(n_frames):
        angle = np.radians(t * degrees) * fraction
        cos, sin = np.cos(angle), np.sin(angle)
        x, y = rest.vertices[:, 0], rest.vertices[:, 1]
        frames.append(np.column_stack([cos * x - sin * y, sin * x + cos * y, rest.vertices[:, 2]]))
    return rest, np.stack(frames)


def write_sequence(
    folder: str | os.PathLike,
    rest: SurfaceMesh,
    frames: np.ndarray,
    format: Literal["npz", "ply"] = "npz",
    overwrite: bool = False,
) -> list[Path]:
    """Write ``folder`` atomically: ``rest.ply`` and either ``frames.npz`` (array ``frames (F, V, 3)`` float64) or
    ``frame_0000.ply`` … (the rest faces, float64 vertices). Returns the written files, rest first. A transfer spec
    then names ``"source_rest": "<folder>/rest.ply"`` and ``"source_frames": "<folder>/frames.npz"`` (or
    ``"<folder>/frame_*.ply"``)."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim != 3 or frames.shape[1:] != (rest.n_vertices, 3):
        raise NerfEditError(f"frames: expected shape (F, {rest.n_vertices}, 3), got {frames.shape}")
    if format not in ("npz", "ply"):
        raise NerfEditError(f"format: expected 'npz' or 'ply', got {format!r}")
    folder = Path(folder)
    names = ["rest.ply"] + (["frames.npz"] if format == "npz" else [f"frame_{i:04d}.ply" for i in range(len(frames))])
    with atomic_dir(folder, overwrite=overwrite) as stage:
        rest.save(stage / "rest.ply")
        if format == "npz":
            np.savez(stage / "frames.npz", frames=frames)
        else:
            for name, frame in zip(names[1:], frames):
                rest.with_vertices(frame).save(stage / name)
    return [folder / name for name in names]
