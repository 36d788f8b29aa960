"""Synthetic scenes: render a vertex-coloured mesh on CPU (Open3D ``RaycastingScene``) into a Blender-format dataset,
and render ground-truth images of a deformed version of that mesh from a dataset's cameras.

Rendering is UNLIT: a ray's colour is the barycentric interpolation of the vertex colours of the triangle it hits
first, so a field that stores the surface colour (the ``mesh`` field) reproduces the images exactly. Anti-aliasing
is box-filter supersampling: ``s``×``s`` stratified rays per pixel, averaged (``Cameras.upscale`` then
``block_mean``), which gives soft alpha edges like real photographs; depth is that of the pixel-centre ray.
Scenes of several meshes (:mod:`nerfedit_plugin.data.scene`) are written with the same :func:`write_dataset`.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from nerfedit_plugin.config import write_config
from nerfedit_plugin.data.cameras import Cameras, generate_rays, sphere_poses
from nerfedit_plugin.data.datasets import SPLITS, blender_transforms, block_mean, read_transforms, write_rgba
from nerfedit_plugin.data.shapes import load_scene_mesh
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh, longest_side_frame
from nerfedit_plugin.io.atomic import atomic_dir

RAYS_PER_CHUNK = 1 << 21
"""Rays cast per batch of cameras (bounds memory; few large torch ops run faster than many small ones)."""
FOV_MARGIN = 1.1
"""Automatic field of view: the normalised object's bounding ball, enlarged by this factor, fills the image."""
DEFAULT_RADIUS = 2.5
"""Camera distance from the origin of a one-mesh dataset unless ``radius`` is given."""


def normalize(mesh: SurfaceMesh) -> SurfaceMesh:
    """Centre the bounding box at the origin and scale its longest side to 1 (:func:`longest_side_frame`).
    Coordinates are rounded to float32 (what PLY files store and the ray caster uses), so the mesh written to disk is
    exactly the one rendered."""
    centre, extent = longest_side_frame(mesh.vertices)
    return mesh.with_vertices(((mesh.vertices - centre) / extent).astype(np.float32).astype(np.float64))


def to_generator_frame(mesh: SurfaceMesh, up_axis: str) -> tuple[SurfaceMesh, np.ndarray]:
    """The mesh in the generator's frame — its ``up_axis`` (``y`` or ``z``) rotated to +z, then :func:`normalize`
    — and the (4,4) similarity taking the given mesh's coordinates to it (up to the float32 rounding)."""
    source_to_world = np.eye(4)
    if up_axis == "y":  # (x, y, z) -> (x, -z, y): a rotation taking +y to +z
        source_to_world[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
        mesh = mesh.with_vertices(mesh.vertices @ source_to_world[:3, :3].T)
    centre, extent = longest_side_frame(mesh.vertices)
    source_to_world[:3] = np.concatenate([source_to_world[:3, :3], -centre[:, None]], axis=1) / extent
    return normalize(mesh), source_to_world


def smooth_noise(points: np.ndarray, rng: np.random.Generator, cycles: tuple[float, float] = (1.0, 2.5)) -> np.ndarray:
    """Smooth, non-periodic noise ``(n, 3)`` (one channel per colour) at ``points (n, d)``: per channel the sum of 6
    plane waves of random directions, ``cycles`` (low, high) cycles per unit length and phases drawn from ``rng``,
    divided by √6 (unit variance)."""
    waves = rng.normal(size=(3, 6, points.shape[1]))
    waves *= (2 * math.pi * rng.uniform(*cycles, size=(3, 6, 1))) / np.linalg.norm(waves, axis=-1, keepdims=True)
    phases = rng.uniform(0.0, 2 * math.pi, size=(3, 6))
    return np.sin(np.einsum("vd,ckd->vck", points, waves) + phases).sum(-1) / math.sqrt(6.0)


def colorize(mesh: SurfaceMesh, seed: int = 0, frequency: float = 1.0) -> SurfaceMesh:
    """A deterministic, smooth, textured-looking vertex colouring, quantised to 8 bits (exact through PLY).

    With ``p`` the position in the unit bounding box: per channel, a sum of 6 random plane waves of 1–2.5 cycles
    across the object (smooth 3-D noise), times a soft 3-D checker ``½ + ½ tanh(4 sin 6πp_x sin 6πp_y sin 6πp_z)``
    that darkens alternate cells to 65 % — a pattern of ~10-pixel features at 100×100 that a field can learn;
    ``frequency`` multiplies the checker's (``sin 6π·frequency·p``: 2.5 gives ~3.5-pixel cells).
    """
    low, high = mesh.vertices.min(0), mesh.vertices.max(0)
    p = (mesh.vertices - low) / max(float((high - low).max()), 1e-12)
    base = np.clip(0.55 + 0.3 * smooth_noise(p, np.random.default_rng(seed)), 0.0, 1.0)
    checker = 0.5 + 0.5 * np.tanh(4.0 * np.prod(np.sin(6 * math.pi * frequency * p), axis=-1))
    colors = base * (0.65 + 0.35 * checker)[:, None]
    return SurfaceMesh(mesh.vertices, mesh.faces, np.round(colors * 255.0) / 255.0)


def bend(vertices: np.ndarray, radius: float) -> np.ndarray:
    """A smooth, isometric reference edit (tests and benchmarks of ray bending): bend the z axis, from z = −1 up,
    into a circular arc of ``radius`` in the xz plane, ``(x, y, z) ↦ (ρ − (ρ − x) cos θ, y, −1 + (ρ − x) sin θ)``
    with ``θ = (z + 1)/ρ``."""
    x, y, z = np.asarray(vertices, dtype=np.float64).T
    angle = (z + 1.0) / radius
    return np.stack([radius - (radius - x) * np.cos(angle), y, -1.0 + (radius - x) * np.sin(angle)], axis=1)


def render_mesh(
    mesh: SurfaceMesh, cameras: Cameras, background=(1.0, 1.0, 1.0), supersample: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render a vertex-coloured mesh, unlit: ``(rgb (C,H,W,3), alpha (C,H,W), depth (C,H,W))``, float32.

    ``rgb`` = premultiplied colour + ``background``·(1 − α) (``background=(0,0,0)`` gives the premultiplied
    colour); ``alpha`` = fraction of the ``supersample``² sub-pixel rays that hit; ``depth`` = distance along the
    unit pixel-centre ray of :func:`generate_rays` to the first hit, ``inf`` where it misses.
    """
    if mesh.vertex_colors is None:
        raise NerfEditError("mesh: has no vertex colours to render (see synthetic.colorize)")
    scene = raycast.raycasting_scene(mesh.vertices, mesh.faces)
    colors, faces = mesh.vertex_colors.astype(np.float32), mesh.faces
    fine = cameras.upscale(supersample)
    background = np.asarray(background, dtype=np.float32)

    def cast(cams: Cameras, index: torch.Tensor) -> dict[str, np.ndarray]:
        rays = torch.cat(generate_rays(cams, index), dim=-1).cpu().numpy()  # Open3D layout: origin, direction
        return raycast.cast_rays(scene, rays)

    rgb, alpha, depth = [], [], []
    chunk = max(1, RAYS_PER_CHUNK // (fine.width * fine.height))
    for index in torch.arange(len(cameras), device=cameras.device).split(chunk):
        hits = cast(fine, index)
        hit = hits["primitive_ids"] != scene.INVALID_ID
        tri = faces[np.where(hit, hits["primitive_ids"], 0)]
        u, v = hits["primitive_uvs"][..., 0:1], hits["primitive_uvs"][..., 1:2]
        color = (1 - u - v) * colors[tri[..., 0]] + u * colors[tri[..., 1]] + v * colors[tri[..., 2]]
        for premultiplied, covered in zip(np.where(hit[..., None], color, 0.0).astype(np.float32), hit):
            coverage = block_mean(covered.astype(np.float32), supersample)
            rgb.append(block_mean(premultiplied, supersample) + background * (1.0 - coverage[..., None]))
            alpha.append(coverage)
        depth.extend((hits if supersample == 1 else cast(cameras, index))["t_hit"])  # pixel-centre rays
    return np.stack(rgb), np.stack(alpha), np.stack(depth).astype(np.float32)


def _write_views(mesh: SurfaceMesh, cameras: Cameras, paths: list[Path], supersample: int) -> None:
    """Render every camera and write straight-alpha RGBA PNGs (one code path for datasets and ground truth)."""
    rgb, alpha, _ = render_mesh(mesh, cameras, background=(0.0, 0.0, 0.0), supersample=supersample)
    straight = np.divide(rgb, alpha[..., None], out=np.zeros_like(rgb), where=alpha[..., None] > 0)
    for path, image, a in zip(paths, straight, alpha):
        path.parent.mkdir(parents=True, exist_ok=True)
        write_rgba(path, image, a)


@dataclass
class GenerateConfig:
    """Render a mesh, or a scene of several (--objects), into a Blender-format dataset.

    A mesh: transforms_{train,val,test}.json + RGBA PNGs + mesh.ply. A scene: its meshes stand on a textured floor
    inside a textured background (opaque images, + scene.json)."""

    out: Path
    """Output dataset folder (must not exist or be empty unless --overwrite)."""
    mesh: str = "sample:bunny"
    """Mesh to render: a file (PLY/OBJ/OFF/GLB), sample:NAME (bunny, cow, airplane, bone) or shape:NAME (tube, cup,
    slab, bunny-fine: the generated benchmark objects, each with its texture frequency)."""
    n_train: int = 50
    """Training views."""
    n_val: int = 5
    """Validation views."""
    n_test: int = 10
    """Test views (also the cameras of ground-truth renders of edits)."""
    resolution: int = 100
    """Image width and height in pixels."""
    hemisphere: bool = False
    """Place cameras on the upper (+z) hemisphere only, as in NeRF-synthetic, instead of the whole sphere (one mesh;
    a scene's cameras are chosen by --cameras)."""
    radius: float | None = None
    """Camera distance from the origin (one mesh, default 2.5; the object is normalised to a longest side of 1
    centred at the origin) or from the centre of a scene's foreground box (default: set by the field of view)."""
    fov_degrees: float | None = None
    """Horizontal = vertical field of view; default: the object's (the scene's foreground box's) bounding ball
    (+10 %) fills the image at the camera distance; a scene without --radius defaults to 50°."""
    seed: int = 0
    """Seed of the colouring and of the camera placement (splits use seed, seed+1, seed+2; a scene's objects are
    coloured with seed, seed+1, …)."""
    supersample: int = 2
    """Anti-aliasing: supersample × supersample rays per pixel (soft alpha edges); 1 disables it."""
    up_axis: Literal["y", "z"] = "y"
    """The mesh's up axis: ``y`` (OBJ/glTF convention, e.g. the samples) is rotated to the z-up world of the cameras."""
    keep_colors: bool = False
    """Use the mesh's own vertex colours when it has them instead of the generated texture."""
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""
    objects: list[str] = field(default_factory=list)
    """A scene instead of --mesh: its meshes (files, sample:NAME, shape:NAME; repeats allowed), each standing on the
    floor, side by side along x unless --positions are given (nerfedit_plugin.data.scene)."""
    positions: list[tuple[float, float]] = field(default_factory=list)
    """Scene: the (x, y) centre of each object's box on the floor (default: side by side along x, centred)."""
    yaws: list[float] = field(default_factory=list)
    """Scene: each object's rotation about the vertical axis in degrees (default 0)."""
    object_size: float = 1.0
    """Scene: the longest side of every object."""
    gap: float = 0.3
    """Scene: the space between neighbouring objects placed automatically."""
    floor: bool = True
    """Scene: a large textured floor at z = 0 (--no-floor leaves the objects floating over the background)."""
    background: bool = True
    """Scene: a far textured sphere around everything, so every pixel is opaque."""
    background_radius: float = 18.0
    """Scene: the radius of that sphere around the origin (a few times the camera distance: walls close behind the
    objects, as in a room)."""
    cameras: Literal["hemisphere", "arc", "sphere"] | None = None
    """Scene: camera placement around the foreground box centre — hemisphere (the default: elevations 15°–65°),
    arc (forward-facing: ±40° of azimuth in front of the scene, elevations 5°–20°) or sphere."""


SCENE_OPTIONS = ("positions", "yaws", "object_size", "gap", "floor", "background", "background_radius", "cameras")
"""The :class:`GenerateConfig` fields that only a scene (``objects``) uses."""


def check_config(config: GenerateConfig) -> None:
    """The checks of the options every generated dataset uses (one mesh or a scene)."""
    for name in ("n_train", "n_val", "n_test", "resolution", "supersample"):
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise NerfEditError(f"{name}: expected a positive integer, got {value!r}")
    if config.radius is not None and not config.radius > 0:
        raise NerfEditError(f"radius: expected a positive distance, got {config.radius}")
    if config.up_axis not in ("y", "z"):
        raise NerfEditError(f"up_axis: expected 'y' or 'z', got {config.up_axis!r}")
    if config.fov_degrees is not None and not 0 < config.fov_degrees < 180:
        raise NerfEditError(f"fov_degrees: expected degrees in (0, 180), got {config.fov_degrees}")


def framing(ball: float, radius: float | None, fov_degrees: float | None) -> tuple[float, float]:
    """``(camera distance, field of view in radians)`` of cameras looking at the centre of a ball of radius
    ``ball``: the one not given is chosen so that the ball enlarged by :data:`FOV_MARGIN` fills the image."""
    if fov_degrees is None:
        if radius is None or radius <= FOV_MARGIN * ball:
            raise NerfEditError(f"radius: {radius} puts the cameras inside the object's bounding ball")
        return radius, 2.0 * math.asin(FOV_MARGIN * ball / radius)
    fov = math.radians(fov_degrees)
    return (FOV_MARGIN * ball / math.sin(fov / 2) if radius is None else radius), fov


def write_dataset(
    stage: Path,
    config: GenerateConfig,
    mesh: SurfaceMesh,
    poses: Callable[[int, int], torch.Tensor],
    fov: float,
    aabb: np.ndarray,
    extra: dict,
) -> None:
    """Write a generated dataset into the (staging) folder ``stage``: per split, ``poses(n, seed)`` cameras (seeds
    ``config.seed``, +1, +2 for train, val, test) rendered into ``{split}/r_{i}.png`` and
    ``transforms_{split}.json`` (Blender keys, ``aabb``, ``supersample``, then ``extra``); ``mesh.ply``;
    ``config.yml``."""
    counts = {"train": config.n_train, "val": config.n_val, "test": config.n_test}
    for offset, split in enumerate(SPLITS):
        size = config.resolution
        cameras = Cameras.from_fov(poses(counts[split], config.seed + offset), size, size, fov)
        names = [f"./{split}/r_{i}" for i in range(counts[split])]
        _write_views(mesh, cameras, [stage / f"{name}.png" for name in names], config.supersample)
        transforms = {
            **blender_transforms(cameras, names),
            "aabb": np.asarray(aabb).tolist(),
            "supersample": config.supersample,
            **extra,
        }
        (stage / f"transforms_{split}.json").write_text(json.dumps(transforms, indent=2))
    mesh.save(stage / "mesh.ply")
    write_config(stage / "config.yml", config)


def generate_dataset(config: GenerateConfig) -> Path:
    """Normalise (and colour) the mesh, render train/val/test views on a sphere or hemisphere, and write the
    Blender dataset atomically: ``transforms_{split}.json`` (+ ``w``, ``h``, ``aabb`` = object box ± 0.1,
    ``supersample`` and ``source_transform``: the (4,4) similarity taking the given mesh's coordinates to the
    dataset's, up-axis rotation then normalisation, up to the float32 rounding of the written mesh),
    ``{split}/r_{i}.png`` (RGBA), ``mesh.ply`` (the exact geometry and colours rendered) and ``config.yml``. Returns
    the dataset folder. A scene (``config.objects``) is :func:`nerfedit_plugin.data.scene.generate_scene`'s."""
    check_config(config)
    if config.objects:
        raise NerfEditError("objects: a scene; generate it with nerfedit_plugin.data.scene.generate_scene")
    defaults = GenerateConfig(out=config.out)
    for name in SCENE_OPTIONS:
        if getattr(config, name) != getattr(defaults, name):
            raise NerfEditError(f"{name}: an option of scenes; give the scene's meshes with --objects")
    mesh, frequency = load_scene_mesh(config.mesh)
    mesh, source_to_world = to_generator_frame(mesh, config.up_axis)
    if not (config.keep_colors and mesh.vertex_colors is not None):
        mesh = colorize(mesh, config.seed, frequency)
    ball = float(np.linalg.norm(mesh.vertices, axis=1).max())
    radius, fov = framing(ball, DEFAULT_RADIUS if config.radius is None else config.radius, config.fov_degrees)
    aabb = np.stack([mesh.vertices.min(0) - 0.1, mesh.vertices.max(0) + 0.1])

    def poses(n: int, seed: int) -> torch.Tensor:
        return sphere_poses(n, radius, hemisphere=config.hemisphere, seed=seed)

    with atomic_dir(config.out, config.overwrite) as stage:
        write_dataset(stage, config, mesh, poses, fov, aabb, {"source_transform": source_to_world.tolist()})
    return Path(config.out)


def render_mesh_views(
    mesh: SurfaceMesh,
    transforms: str | os.PathLike,
    out_dir: str | os.PathLike,
    supersample: int | None = None,
    overwrite: bool = False,
) -> list[Path]:
    """Render a vertex-coloured mesh from every camera of a transforms file into ``out_dir/<frame image name>.png``
    (RGBA), written atomically — the ground truth of an edit, given the edited mesh.

    ``supersample`` defaults to the file's ``supersample`` key (written by :func:`generate_dataset`), else 2, so
    the dataset's own mesh reproduces its images exactly. Returns the written paths in frame order.
    """
    parsed = read_transforms(transforms)
    supersample = int(parsed.meta.get("supersample", 2)) if supersample is None else supersample
    names = [path.with_suffix(".png").name for path in parsed.image_paths]
    if len(set(names)) != len(names):
        raise NerfEditError(f"{parsed.file}: frames share image names; cannot name the ground-truth images")
    with atomic_dir(out_dir, overwrite) as stage:
        _write_views(mesh, parsed.cameras, [stage / name for name in names], supersample)
    return [Path(out_dir) / name for name in names]


def render_ground_truth(
    mesh: SurfaceMesh | str | os.PathLike,
    deformed_vertices: np.ndarray,
    transforms: str | os.PathLike,
    out_dir: str | os.PathLike,
    supersample: int | None = None,
    overwrite: bool = False,
) -> list[Path]:
    """:func:`render_mesh_views` of the mesh with its vertices moved to ``deformed_vertices (V,3)`` (same faces and
    colours): the identity deformation reproduces the dataset's images exactly."""
    mesh = mesh if isinstance(mesh, SurfaceMesh) else SurfaceMesh.load(mesh)
    deformed = np.asarray(deformed_vertices, dtype=np.float64)
    if deformed.shape != mesh.vertices.shape:
        raise NerfEditError(
            f"deformed vertices: expected shape {mesh.vertices.shape} (the mesh's vertices), got {deformed.shape}"
        )
    return render_mesh_views(mesh.with_vertices(deformed), transforms, out_dir, supersample, overwrite)
