"""Generated scenes: several meshes standing on a textured floor inside a textured background, built as ONE
vertex-coloured mesh (``mesh.ply``: the objects in order, then the floor, then the background) and described in
``scene.json`` — each object's source, the similarity from its source mesh to the scene, its vertex and face ranges
in ``mesh.ply`` and its box; the floor and the background with their ranges; the foreground box ``aabb``.

The ground truth of an edit of a scene moves, copies or removes objects of the description (:func:`scene_mesh`) and
renders the resulting mesh with :func:`nerfedit_plugin.data.synthetic.render_mesh_views`. The format and the camera
placements are in docs/usage.md, "Scenes".
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nerfedit_plugin.data.cameras import orbit_poses, sphere_poses
from nerfedit_plugin.data.shapes import load_scene_mesh
from nerfedit_plugin.data.synthetic import (
    GenerateConfig,
    check_config,
    colorize,
    framing,
    smooth_noise,
    to_generator_frame,
    write_dataset,
)
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_dir

FORMAT = "nerfedit-scene"
VERSION = 1
SCENE_FILE = "scene.json"
MESH_FILE = "mesh.ply"
FLOOR_HALF_SIZE = 8.0
"""Half the side of the square floor (it runs out of every frame of the scene's cameras)."""
FLOOR_CELL = 0.25
"""Side of the floor's checker cells."""
FLOOR_STEP = FLOOR_CELL / 4
"""Spacing of the floor's vertex grid (257² = 66049 vertices)."""
FLOOR_NOISE_LENGTH = 3.0
"""Length over which the floor's colour noise makes 1–2.5 cycles."""
BACKGROUND_SUBDIVISIONS = 5
"""Icosphere subdivisions of the background (10242 vertices, edges ~0.6 long)."""
AABB_MARGIN = 0.12
"""The foreground box ``aabb``: the objects' union box grown by this margin (so it holds a slab of floor)."""
SCENE_FOV_DEGREES = 50.0
"""Field of view of a scene's cameras when neither ``fov_degrees`` nor ``radius`` is given."""
CAMERAS = {
    "hemisphere": {"elevation": (15.0, 65.0)},
    "arc": {"elevation": (5.0, 20.0), "azimuth": (-130.0, -50.0)},
}
"""The band of :func:`orbit_poses` of each camera placement (``sphere`` is :func:`sphere_poses`); the arc faces
the scene from −y."""


@dataclass(frozen=True)
class SceneObject:
    """One object of a scene: ``mesh.vertices[vertex_range]`` and ``mesh.faces[face_range]`` (indices into the
    whole mesh) are its own; ``source_transform (4,4)`` takes its source mesh's coordinates to the scene's (up to the
    float32 rounding of the written mesh); ``box (2,3)`` is [min, max] of its vertices."""

    name: str
    source: str
    source_transform: np.ndarray
    vertex_range: range
    face_range: range
    box: np.ndarray


@dataclass(frozen=True)
class Floor:
    """The square floor at z = ``height``, ``2·half_size`` wide, with checker cells of side ``cell``."""

    height: float
    half_size: float
    cell: float
    vertex_range: range
    face_range: range


@dataclass(frozen=True)
class Background:
    """The textured sphere of ``radius`` around the origin, facing inwards."""

    radius: float
    vertex_range: range
    face_range: range


@dataclass(frozen=True)
class Scene:
    """A generated scene: the rendered ``mesh`` and its description (objects, floor, background, each a range of
    the mesh; ``aabb (2,3)``, the foreground box)."""

    mesh: SurfaceMesh
    objects: tuple[SceneObject, ...]
    floor: Floor | None
    background: Background | None
    aabb: np.ndarray

    def object(self, name: str, where: str = "object") -> SceneObject:
        """The object called ``name`` (:class:`NerfEditError` naming ``where`` and the known names otherwise)."""
        for obj in self.objects:
            if obj.name == name:
                return obj
        raise NerfEditError(f"{where}: unknown object {name!r} (objects: {', '.join(o.name for o in self.objects)})")

    def part(self, part: SceneObject | Floor | Background) -> SurfaceMesh:
        """The piece of :attr:`mesh` of one object (or the floor, the background), its faces indexing its vertices."""
        vertices, faces = part.vertex_range, part.face_range
        colors = self.mesh.vertex_colors
        return SurfaceMesh(
            self.mesh.vertices[vertices.start : vertices.stop],
            self.mesh.faces[faces.start : faces.stop] - vertices.start,
            None if colors is None else colors[vertices.start : vertices.stop],
        )

    def to_json(self) -> dict:
        """The ``scene.json`` document (ranges as ``[start, stop)``)."""

        def ranges(part) -> dict:
            return {"vertices": _pair(part.vertex_range), "faces": _pair(part.face_range)}

        return {
            "format": FORMAT,
            "version": VERSION,
            "mesh": MESH_FILE,
            "aabb": self.aabb.tolist(),
            "objects": [
                {
                    "name": o.name,
                    "source": o.source,
                    "source_transform": o.source_transform.tolist(),
                    **ranges(o),
                    "box": o.box.tolist(),
                }
                for o in self.objects
            ],
            "floor": None
            if self.floor is None
            else {"height": self.floor.height, "half_size": self.floor.half_size, "cell": self.floor.cell}
            | ranges(self.floor),
            "background": None
            if self.background is None
            else {"radius": self.background.radius} | ranges(self.background),
        }


def _pair(r: range) -> list[int]:
    return [r.start, r.stop]


# ---- building ---------------------------------------------------------------------------------------------------
def _concatenate(pieces: Sequence[SurfaceMesh]) -> tuple[SurfaceMesh, list[tuple[range, range]]]:
    """One mesh of ``pieces`` in order, and each piece's (vertex range, face range) in it."""
    vertex_ends = np.cumsum([0] + [len(p.vertices) for p in pieces]).tolist()
    face_ends = np.cumsum([0] + [len(p.faces) for p in pieces]).tolist()
    mesh = SurfaceMesh(
        np.concatenate([p.vertices for p in pieces]),
        np.concatenate([p.faces + start for p, start in zip(pieces, vertex_ends)]),
        np.concatenate([p.vertex_colors for p in pieces]),
    )
    ranges = [(range(*vertex_ends[i : i + 2]), range(*face_ends[i : i + 2])) for i in range(len(pieces))]
    return mesh, ranges


def _base_name(source: str) -> str:
    """The base name of an object: ``sample:bunny`` → ``bunny``, ``shape:cup`` → ``cup``, ``dir/chair.ply`` →
    ``chair``."""
    text = str(source)
    return text.split(":", 1)[1] if text.startswith(("sample:", "shape:")) else Path(text).stem


def _unique_names(sources: Sequence[str]) -> list[str]:
    """Base names made unique by ``_2``, ``_3``, … for repeats (``bunny``, ``cow``, ``bunny_2``)."""
    names: list[str] = []
    for source in sources:
        base = name = _base_name(source)
        count = 1
        while name in names:
            count += 1
            name = f"{base}_{count}"
        names.append(name)
    return names


def _turn(scale: float, yaw_degrees: float) -> np.ndarray:
    """(4,4) ``x ↦ scale · R_z(yaw) x``."""
    c, s = math.cos(math.radians(yaw_degrees)), math.sin(math.radians(yaw_degrees))
    matrix = np.eye(4)
    matrix[:3, :3] = scale * np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return matrix


def _apply(matrix: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    return vertices @ matrix[:3, :3].T + matrix[:3, 3]


def _check_scene(config: GenerateConfig) -> None:
    check_config(config)
    n = len(config.objects)
    if not n:
        raise NerfEditError("objects: a scene needs at least one mesh")
    if config.hemisphere:
        raise NerfEditError("hemisphere: a scene's cameras are chosen by --cameras (hemisphere, arc or sphere)")
    if config.mesh != GenerateConfig(out=config.out).mesh:
        raise NerfEditError("mesh: a scene's meshes are given by --objects, not --mesh")
    for name, shape, what in (("positions", (n, 2), "(x, y) pairs"), ("yaws", (n,), "angles")):
        values = np.asarray(getattr(config, name), dtype=np.float64)
        if values.size and values.shape != shape:
            raise NerfEditError(f"{name}: expected none or {n} {what} (one per object), got {getattr(config, name)}")
        if not np.isfinite(values).all():
            raise NerfEditError(f"{name}: contains NaN or Inf")
    if not (math.isfinite(config.object_size) and config.object_size > 0):
        raise NerfEditError(f"object_size: expected a positive length, got {config.object_size}")
    if not (math.isfinite(config.gap) and config.gap >= 0):
        raise NerfEditError(f"gap: expected a length >= 0, got {config.gap}")
    if not (math.isfinite(config.background_radius) and config.background_radius > 0):
        raise NerfEditError(f"background_radius: expected a positive length, got {config.background_radius}")
    if config.cameras is not None and config.cameras not in (*CAMERAS, "sphere"):
        raise NerfEditError(f"cameras: expected hemisphere, arc or sphere, got {config.cameras!r}")


def _objects(config: GenerateConfig) -> list[tuple[SurfaceMesh, np.ndarray]]:
    """Each object placed in the scene, and the similarity from its source mesh: in the generator's frame,
    coloured (seed ``config.seed + i``), scaled to ``object_size``, turned by its yaw, standing on z = 0 at its
    position (default: side by side along x, ``gap`` apart, the row centred at the origin)."""
    framed = []
    for i, source in enumerate(config.objects):
        try:
            mesh, frequency = load_scene_mesh(source)
        except NerfEditError as exc:
            raise NerfEditError(f"objects[{i}]: {exc}") from exc
        mesh, source_to_world = to_generator_frame(mesh, config.up_axis)
        if not (config.keep_colors and mesh.vertex_colors is not None):
            mesh = colorize(mesh, config.seed + i, frequency)
        turn = _turn(config.object_size, config.yaws[i] if config.yaws else 0.0)
        framed.append((mesh.with_vertices(_apply(turn, mesh.vertices)), turn @ source_to_world))
    boxes = [np.stack([m.vertices.min(0), m.vertices.max(0)]) for m, _ in framed]
    if config.positions:
        centres = np.asarray(config.positions, dtype=np.float64)
    else:
        widths = np.array([box[1, 0] - box[0, 0] for box in boxes])
        left = (
            np.concatenate([[0.0], np.cumsum(widths + config.gap)[:-1]])
            - (widths.sum() + config.gap * (len(widths) - 1)) / 2
        )
        centres = np.stack([left + widths / 2, np.zeros(len(widths))], axis=1)
    placed = []
    for (mesh, to_scene), box, centre in zip(framed, boxes, centres):
        shift = np.eye(4)
        shift[:3, 3] = [centre[0] - box[:, 0].mean(), centre[1] - box[:, 1].mean(), -box[0, 2]]
        vertices = _apply(shift, mesh.vertices).astype(np.float32).astype(np.float64)  # exact through PLY
        placed.append((mesh.with_vertices(vertices), shift @ to_scene))
    return placed


def _check_overlaps(names: Sequence[str], meshes: Sequence[SurfaceMesh]) -> None:
    boxes = [np.stack([m.vertices.min(0), m.vertices.max(0)]) for m in meshes]
    for i in range(len(boxes)):
        for j in range(i):
            if (np.minimum(boxes[i][1], boxes[j][1]) - np.maximum(boxes[i][0], boxes[j][0]) > 1e-9).all():
                raise NerfEditError(f"positions: the boxes of objects {names[j]!r} and {names[i]!r} overlap")


TEXTURES = ("checker", "noise")
"""Floor and background textures: ``checker`` (soft cells, smooth tints), or ``noise`` — every vertex an independent
uniform random colour blended with the smooth tint, corners at every pixel scale: what SIFT (structure from motion)
needs everywhere in a frame."""


def _noisy(colors: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The ``noise`` texture: ``colors (V,3)`` blended half and half with uniform random colours in [0.1, 0.9]."""
    return 0.5 * colors + 0.5 * rng.uniform(0.1, 0.9, size=colors.shape)


def floor_mesh(half_size: float = FLOOR_HALF_SIZE, seed: int = 0, texture: str = "checker") -> SurfaceMesh:
    """The floor: a square grid at z = 0 (spacing :data:`FLOOR_STEP`, faces up), coloured with a soft checker of
    cells :data:`FLOOR_CELL` whose light cells get a random brightness each, times smooth, muted colour noise —
    corners everywhere and no period — or with the ``noise`` texture (:data:`TEXTURES`); quantised to 8 bits."""
    rng = np.random.default_rng([seed, 1])
    steps = int(round(2 * half_size / FLOOR_STEP))
    axis = np.linspace(-half_size, half_size, steps + 1)
    x, y = (a.reshape(-1) for a in np.meshgrid(axis, axis, indexing="xy"))
    corner = (np.arange(steps)[None, :] + (steps + 1) * np.arange(steps)[:, None]).reshape(-1)
    quads = np.stack([corner, corner + 1, corner + steps + 2, corner + steps + 1], axis=1)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    points = np.stack([x, y], axis=1)
    noise = smooth_noise(points / FLOOR_NOISE_LENGTH, rng)
    base = np.clip(0.6 + 0.15 * noise[:, :1] + 0.08 * noise, 0.0, 1.0)  # muted: brightness, a slight tint
    checker = 0.5 + 0.5 * np.tanh(3.0 * np.sin(math.pi * x / FLOOR_CELL) * np.sin(math.pi * y / FLOOR_CELL))
    n_cells = int(math.ceil(2 * half_size / FLOOR_CELL)) + 1
    cell = np.clip(np.floor((points + half_size) / FLOOR_CELL).astype(np.int64), 0, n_cells - 1)
    brightness = rng.uniform(0.55, 1.0, size=(n_cells, n_cells))[cell[:, 0], cell[:, 1]]
    colors = base * (0.35 + 0.65 * checker * brightness)[:, None]
    if texture == "noise":
        colors = _noisy(base, rng)
    return SurfaceMesh(np.stack([x, y, np.zeros_like(x)], axis=1), faces, np.round(colors * 255.0) / 255.0)


def background_mesh(radius: float, seed: int = 0, texture: str = "checker") -> SurfaceMesh:
    """The background: an icosphere of ``radius`` around the origin, faces turned inwards, coloured with smooth noise
    of the direction shaded by soft-edged blobs (a thresholded, finer second noise) — no checker, unlike the floor —
    or with the ``noise`` texture (:data:`TEXTURES`); quantised to 8 bits."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=BACKGROUND_SUBDIVISIONS, radius=1.0)
    directions = np.asarray(sphere.vertices)
    rng = np.random.default_rng([seed, 2])
    tint = np.clip(0.55 + 0.3 * smooth_noise(directions, rng, cycles=(1.0, 2.5)), 0.0, 1.0)
    blobs = 0.5 + 0.5 * np.tanh(4.0 * smooth_noise(directions, rng, cycles=(2.0, 5.0))[:, 0])
    colors = _noisy(tint, rng) if texture == "noise" else tint * (0.45 + 0.55 * blobs)[:, None]
    faces = np.asarray(sphere.faces)[:, ::-1]
    return SurfaceMesh(radius * directions, faces, np.round(colors * 255.0) / 255.0)


def build_scene(config: GenerateConfig, texture: str = "checker") -> Scene:
    """The scene of ``config.objects`` (see :class:`GenerateConfig`'s scene options): the placed objects, then the
    floor and the background when enabled (textured by ``texture``, :data:`TEXTURES`), as one mesh with its
    description."""
    _check_scene(config)
    if texture not in TEXTURES:
        raise NerfEditError(f"texture: expected one of {', '.join(TEXTURES)}, got {texture!r}")
    names = _unique_names(config.objects)
    placed = _objects(config)
    _check_overlaps(names, [mesh for mesh, _ in placed])
    pieces = [mesh for mesh, _ in placed]
    pieces += [floor_mesh(seed=config.seed, texture=texture)] if config.floor else []
    pieces += [background_mesh(config.background_radius, config.seed, texture)] if config.background else []
    mesh, ranges = _concatenate(pieces)
    objects = tuple(
        SceneObject(name, str(source), to_scene, vertices, faces, np.stack([m.vertices.min(0), m.vertices.max(0)]))
        for name, source, (m, to_scene), (vertices, faces) in zip(names, config.objects, placed, ranges)
    )
    rest = iter(ranges[len(objects) :])
    floor = Floor(0.0, FLOOR_HALF_SIZE, FLOOR_CELL, *next(rest)) if config.floor else None
    background = Background(config.background_radius, *next(rest)) if config.background else None
    union = np.stack([np.min([o.box[0] for o in objects], 0), np.max([o.box[1] for o in objects], 0)])
    aabb = union + [[-AABB_MARGIN], [AABB_MARGIN]]
    return Scene(mesh, objects, floor, background, aabb)


def scene_poses(kind: str, n: int, radius: float, center, seed: int) -> torch.Tensor:
    """``n`` cameras of the placement ``kind`` (``hemisphere``, ``arc`` — :data:`CAMERAS` — or ``sphere``) at
    ``radius`` from ``center``, looking at it."""
    if kind == "sphere":
        return sphere_poses(n, radius, center, seed=seed)
    return orbit_poses(n, radius, center, seed=seed, **CAMERAS[kind])


def generate_scene(config: GenerateConfig, texture: str = "checker") -> Path:
    """Build the scene of ``config.objects`` (floor and background textured by ``texture``) and write it as a
    Blender dataset, atomically: what :func:`nerfedit_plugin.data.synthetic.generate_dataset` writes (``aabb`` = the
    foreground box; no ``source_transform``, which is per object) plus ``scene.json``. The cameras look at the
    foreground box's centre from ``radius`` (default: the box's bounding ball fills the field of view, 50° unless
    given). Returns the folder."""
    scene = build_scene(config, texture)
    centre = scene.aabb.mean(0)
    ball = float(np.linalg.norm(scene.aabb[1] - scene.aabb[0])) / 2
    both_unset = config.fov_degrees is None and config.radius is None
    radius, fov = framing(ball, config.radius, SCENE_FOV_DEGREES if both_unset else config.fov_degrees)
    kind = config.cameras or "hemisphere"
    reach = float(np.linalg.norm(centre)) + radius
    if config.background and reach >= config.background_radius:
        raise NerfEditError(
            f"background_radius: the cameras stand up to {reach:.3g} from the origin, outside the background sphere "
            f"of radius {config.background_radius:g}; expected a larger radius"
        )

    def poses(n: int, seed: int) -> torch.Tensor:
        return scene_poses(kind, n, radius, centre, seed)

    with atomic_dir(config.out, config.overwrite) as stage:
        write_dataset(stage, config, scene.mesh, poses, fov, scene.aabb, {})
        (stage / SCENE_FILE).write_text(json.dumps(scene.to_json(), indent=2))
    return Path(config.out)


# ---- edits ------------------------------------------------------------------------------------------------------
def _moved(part: SurfaceMesh, motion, where: str) -> SurfaceMesh:
    """``part`` moved by ``motion``: a (4,4) affine transform, or its new vertex positions ``(n, 3)``."""
    try:
        value = np.asarray(motion, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise NerfEditError(
            f"{where}: expected a 4x4 transform or ({len(part.vertices)}, 3) positions ({exc})"
        ) from None
    if value.shape not in ((4, 4), part.vertices.shape):
        raise NerfEditError(
            f"{where}: expected a 4x4 transform or ({len(part.vertices)}, 3) vertex positions, got shape {value.shape}"
        )
    if not np.isfinite(value).all():
        raise NerfEditError(f"{where}: contains NaN or Inf")
    if value.shape == (4, 4):
        if not np.allclose(value[3], [0.0, 0.0, 0.0, 1.0]):
            raise NerfEditError(f"{where}: last row must be [0, 0, 0, 1], got {value[3].tolist()}")
        value = _apply(value, part.vertices)
    return part.with_vertices(value)


def scene_mesh(
    scene: Scene,
    moves: Mapping[str, np.ndarray] | None = None,
    copies: Sequence[tuple[str, np.ndarray]] = (),
    removed: Collection[str] = (),
) -> SurfaceMesh:
    """The mesh of the edited scene — the ground truth of an edit, for
    :func:`nerfedit_plugin.data.synthetic.render_mesh_views`: the objects in order (``removed`` ones dropped; those in
    ``moves`` moved by a (4,4) affine transform or given their new vertex positions ``(n, 3)``, e.g. a deformation),
    the floor, the background, then ``copies``: ``(name, transform or positions)``, each a further copy of that
    object (colours and faces unchanged). Without edits it is ``scene.mesh`` exactly."""
    moves = dict(moves or {})
    for name in moves:
        scene.object(name, f"moves[{name!r}]")
        if name in removed:
            raise NerfEditError(f"moves[{name!r}]: the object is also removed")
    for name in removed:
        scene.object(name, "removed")
    extra = [
        _moved(scene.part(scene.object(name, f"copies[{i}]")), m, f"copies[{i}]") for i, (name, m) in enumerate(copies)
    ]
    pieces = [
        _moved(scene.part(o), moves[o.name], f"moves[{o.name!r}]") if o.name in moves else scene.part(o)
        for o in scene.objects
        if o.name not in removed
    ]
    pieces += [scene.part(p) for p in (scene.floor, scene.background) if p is not None]
    return _concatenate(pieces + extra)[0]


# ---- reading ----------------------------------------------------------------------------------------------------
def read_scene(dataset: str | os.PathLike) -> Scene:
    """The scene of a generated dataset folder (its ``scene.json`` and mesh), validated: a bad file is a
    :class:`NerfEditError` naming the file and the key; the ranges must tile the mesh (objects, floor, background in
    order) with each part's faces indexing only its own vertices."""
    file = Path(dataset) / SCENE_FILE
    if not file.is_file():
        raise NerfEditError(f"{file}: not found (a scene made by `nerfedit generate --objects`)")
    try:
        doc = json.loads(file.read_text())
    except (OSError, ValueError) as exc:
        raise NerfEditError(f"{file}: cannot read JSON ({exc})") from exc
    reader = _Reader(file)
    if not isinstance(doc, dict):
        raise NerfEditError(f"{file}: expected a JSON object at the top level")
    if doc.get("format") != FORMAT:
        raise NerfEditError(f"{file}: format: expected {FORMAT!r}, got {doc.get('format')!r}")
    if doc.get("version") != VERSION:
        raise NerfEditError(f"{file}: version: expected {VERSION}, got {doc.get('version')!r}")
    mesh_name = reader.get(doc, "mesh", str, "mesh")
    mesh = SurfaceMesh.load(file.parent / mesh_name)
    entries = reader.get(doc, "objects", list, "objects")
    if not entries:
        raise NerfEditError(f"{file}: objects: expected a non-empty list")
    objects = []
    for i, entry in enumerate(entries):
        key = f"objects[{i}]"
        entry = reader.get(entries, i, dict, key)
        name = reader.get(entry, "name", str, f"{key}.name")
        if not name or name in [o.name for o in objects]:
            raise NerfEditError(f"{file}: {key}.name: expected a unique non-empty name, got {name!r}")
        objects.append(
            SceneObject(
                name,
                reader.get(entry, "source", str, f"{key}.source"),
                reader.array(entry, "source_transform", (4, 4), f"{key}.source_transform"),
                *reader.ranges(entry, key),
                reader.box(entry, "box", f"{key}.box"),
            )
        )
    floor = background = None
    if doc.get("floor") is not None:
        entry = reader.get(doc, "floor", dict, "floor")
        floor = Floor(
            reader.number(entry, "height", "floor.height"),
            reader.number(entry, "half_size", "floor.half_size", positive=True),
            reader.number(entry, "cell", "floor.cell", positive=True),
            *reader.ranges(entry, "floor"),
        )
    if doc.get("background") is not None:
        entry = reader.get(doc, "background", dict, "background")
        background = Background(
            reader.number(entry, "radius", "background.radius", positive=True), *reader.ranges(entry, "background")
        )
    scene = Scene(mesh, tuple(objects), floor, background, reader.box(doc, "aabb", "aabb"))
    reader.tiling(scene)
    return scene


class _Reader:
    """Typed look-ups in ``scene.json`` whose errors name the file and the key."""

    def __init__(self, file: Path) -> None:
        self.file = file

    def fail(self, key: str, problem: str) -> NerfEditError:
        return NerfEditError(f"{self.file}: {key}: {problem}")

    def get(self, container, item, kind: type, key: str):
        try:
            value = container[item]
        except (KeyError, IndexError):
            raise self.fail(key, "missing") from None
        if not isinstance(value, kind) or isinstance(value, bool):
            raise self.fail(key, f"expected {kind.__name__}, got {value!r}")
        return value

    def number(self, container: dict, item: str, key: str, positive: bool = False) -> float:
        value = container.get(item)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise self.fail(key, f"expected a finite number, got {value!r}")
        if positive and not value > 0:
            raise self.fail(key, f"expected a positive number, got {value!r}")
        return float(value)

    def array(self, container: dict, item: str, shape: tuple[int, ...], key: str) -> np.ndarray:
        if item not in container:
            raise self.fail(key, "missing")
        try:
            value = np.asarray(container[item], dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise self.fail(key, f"expected an array of numbers of shape {shape}") from None
        if value.shape != shape or not np.isfinite(value).all():
            raise self.fail(key, f"expected finite numbers of shape {shape}, got {container[item]!r}"[:300])
        return value

    def box(self, container: dict, item: str, key: str) -> np.ndarray:
        value = self.array(container, item, (2, 3), key)
        if not (value[0] <= value[1]).all():
            raise self.fail(key, "expected [[min x, y, z], [max x, y, z]] with min <= max")
        return value

    def ranges(self, container: dict, key: str) -> tuple[range, range]:
        found = []
        for item in ("vertices", "faces"):
            pair = container.get(item)
            if (
                not isinstance(pair, list)
                or len(pair) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in pair)
                or not 0 <= pair[0] < pair[1]
            ):
                raise self.fail(f"{key}.{item}", f"expected [start, stop] with 0 <= start < stop, got {pair!r}")
            found.append(range(*pair))
        return found[0], found[1]

    def tiling(self, scene: Scene) -> None:
        """The parts' ranges follow each other from 0 to the mesh's sizes, and each part's faces stay inside it."""
        parts = [(f"objects[{i}]", o) for i, o in enumerate(scene.objects)]
        parts += [(k, p) for k, p in (("floor", scene.floor), ("background", scene.background)) if p is not None]
        ends = {"vertices": 0, "faces": 0}
        for key, part in parts:
            for item, r in (("vertices", part.vertex_range), ("faces", part.face_range)):
                if r.start != ends[item]:
                    raise self.fail(
                        f"{key}.{item}", f"starts at {r.start}, not where the previous part ends ({ends[item]})"
                    )
                ends[item] = r.stop
            faces = scene.mesh.faces[part.face_range.start : part.face_range.stop]
            if (
                part.face_range.stop > len(scene.mesh.faces)
                or not ((faces >= part.vertex_range.start) & (faces < part.vertex_range.stop)).all()
            ):
                raise self.fail(f"{key}.faces", "index vertices outside the part's vertex range (or the mesh)")
        for item, total in (("vertices", len(scene.mesh.vertices)), ("faces", len(scene.mesh.faces))):
            if ends[item] != total:
                raise self.fail(parts[-1][0], f"the parts cover {ends[item]} {item}, the mesh has {total}")
