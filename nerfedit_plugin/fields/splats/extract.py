r"""A mesh of Gaussian splats: TSDF fusion of their rendered depth (Open3D's ``VoxelBlockGrid``).

Cameras: :data:`VIEWS` on a Fibonacci sphere (:func:`~nerfedit_plugin.data.cameras.sphere_poses`) of radius the box
diagonal ``D`` around the box centre, looking at it, a :data:`FOV_DEGREES` field of view, ``2 × resolution`` pixels
square (at most :data:`MAX_PIXELS`). Per view the rasteriser composites, in one set of tile lists, the colours and
the view depths ``z_i`` of the Gaussians over a black background: ``C = Σ w_i c_i``, ``Z = Σ w_i z_i``,
``A = Σ w_i = 1 − T`` (``w_i`` the compositing weights). Pixels of ``A ≥ level`` (default 0.5) give the depth
``Z / A`` and the colour ``C / A``; the rest give none. The depth maps are fused into a truncated signed distance
volume of voxel ``max(box extent) / resolution`` (truncation :data:`TRUNCATION` voxels) and its zero level set
extracted (marching cubes over the voxels :data:`MIN_WEIGHT` views reached, vertex colours), kept inside the box.
Open3D's ``VoxelBlockGrid`` allocates voxel blocks where depth lands only, so memory follows the surface.

Open3D's pinhole model puts pixel ``(i, j)``'s centre at ``(i, j)``, the rasteriser at ``(i + ½, j + ½)``: the
principal point is passed half a pixel lower.
"""

from __future__ import annotations

import math

import numpy as np

from nerfedit_plugin.data.cameras import sphere_poses, world_to_camera_from_opengl
from nerfedit_plugin.fields.splats.model import SplatModel
from nerfedit_plugin.fields.splats.rasterize import RasterStats, as_float32, composite, project_gaussians, tile_lists
from nerfedit_plugin.geometry.mesh import SurfaceMesh

VIEWS = 48
"""Depth views fused."""
FOV_DEGREES = 60.0
"""Their field of view (the box, seen from a distance of its diagonal, fills about 90 % of it)."""
MAX_PIXELS = 768
"""The largest side of a depth view."""
TRUNCATION = 4.0
"""The TSDF's truncation distance in voxels."""
LEVEL = 0.5
"""Default accumulated opacity a pixel needs to give a depth."""
MIN_WEIGHT = 3.0
"""A voxel enters the surface when at least this many depth views reached it."""
BLOCKS = 40_000
"""Initial capacity of the voxel block hash map (blocks of 8³ voxels; it grows as needed)."""


def depth_view(
    model: SplatModel, c2w: np.ndarray, intrinsics: tuple[float, float, float, float], size: int, antialiased: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One view of the Gaussians (OpenGL ``c2w (4,4)``, ``(f_x, f_y, c_x, c_y)``, ``size²`` pixels) →
    ``(colour C (H,W,3), depth Z (H,W), opacity A (H,W))`` float32 (module docstring), not yet divided by ``A``."""
    means2d, conics, variances, colors, opacities, depths = project_gaussians(
        *model.arrays(), c2w, intrinsics, size, size, antialiased
    )
    mu, conic, opacity = (as_float32(t) for t in (means2d, conics, opacities))
    tiles = tile_lists(mu, variances.numpy(), opacity, depths.numpy(), size, size, RasterStats())
    colour, transmittance, _ = composite(tiles, mu, conic, as_float32(colors), opacity, size, size)
    packed = np.zeros((len(mu), 3), dtype=np.float32)
    packed[:, 0] = as_float32(depths)
    depth = composite(tiles, mu, conic, packed, opacity, size, size)[0][:, :, 0]
    return colour, depth, 1.0 - transmittance


def fuse_mesh(
    model: SplatModel, box: np.ndarray, resolution: int = 256, level: float | None = None, antialiased: bool = False
) -> SurfaceMesh:
    """The TSDF-fused surface of ``model`` inside ``box (2,3)`` (module docstring) → a vertex-coloured
    :class:`SurfaceMesh`; ``ValueError`` when no view has a pixel of opacity ``level`` or the volume no surface."""
    import open3d as o3d
    import open3d.core as o3c

    level = LEVEL if level is None else float(level)
    if not 0.0 < level < 1.0:
        raise ValueError(f"splats mesh: level {level} is no opacity in (0, 1)")
    box = np.asarray(box, dtype=np.float64)
    centre, diagonal = box.mean(0), float(np.linalg.norm(box[1] - box[0]))
    voxel = float((box[1] - box[0]).max()) / resolution
    size = min(2 * resolution, MAX_PIXELS)
    focal = 0.5 * size / math.tan(math.radians(FOV_DEGREES) / 2)
    intrinsics = (focal, focal, 0.5 * size, 0.5 * size)
    matrix = np.array([[focal, 0.0, 0.5 * size - 0.5], [0.0, focal, 0.5 * size - 0.5], [0.0, 0.0, 1.0]])
    camera, far = o3c.Tensor(matrix), 2.0 * diagonal
    grid = o3d.t.geometry.VoxelBlockGrid(
        attr_names=("tsdf", "weight", "color"),
        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
        attr_channels=(1, 1, 3),
        voxel_size=voxel,
        block_resolution=8,
        block_count=BLOCKS,
        device=o3c.Device("CPU:0"),
    )
    seen = 0
    for c2w in sphere_poses(VIEWS, diagonal, centre).double().numpy():
        colour, depth, opacity = depth_view(model, c2w, intrinsics, size, antialiased)
        covered = opacity >= level
        if not covered.any():
            continue
        seen += int(covered.sum())
        safe = np.where(covered, opacity, 1.0)
        depth = np.where(covered, depth / safe, 0.0).astype(np.float32)
        rgb = np.ascontiguousarray(np.clip(colour / safe[:, :, None], 0.0, 1.0), dtype=np.float32)
        depth_image, colour_image = o3d.t.geometry.Image(o3c.Tensor(depth)), o3d.t.geometry.Image(o3c.Tensor(rgb))
        pose = o3c.Tensor(world_to_camera_from_opengl(c2w))
        blocks = grid.compute_unique_block_coordinates(depth_image, camera, pose, 1.0, far, TRUNCATION)
        grid.integrate(blocks, depth_image, colour_image, camera, camera, pose, 1.0, far, TRUNCATION)
    if not seen:
        raise ValueError(f"splats mesh: no pixel of any view reaches opacity {level} (the Gaussians are too faint)")
    mesh = SurfaceMesh.from_open3d(grid.extract_triangle_mesh(weight_threshold=MIN_WEIGHT).to_legacy())
    inside = ((mesh.vertices >= box[0]) & (mesh.vertices <= box[1])).all(1)
    mesh = mesh.submesh(inside)[0]
    mesh = mesh.submesh(mesh.referenced())[0]
    if not len(mesh.faces):
        raise ValueError("splats mesh: the fused depth holds no surface inside the scene box")
    return mesh
