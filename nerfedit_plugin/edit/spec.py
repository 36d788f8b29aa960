"""Edit specs (docs/architecture.md, "Edit spec"): handle selections, transforms and frame interpolation, from JSON
or YAML.

A handle selects rest-space points (:mod:`~nerfedit_plugin.edit.selection`: ``box``, ``sphere``, ``indices``, a
selection ``file`` or a mesh ``component``) and either pins them (``"fixed": true``) or moves them by a transform.
At interpolation time t ∈ [0, 1] a transform maps ``x ↦ c + (1 + (s − 1)t) R(t)(x − c) + t·translate`` where
``R(t)`` rotates by ``t·degrees`` about ``axis`` (slerp from the identity) and the pivot ``c`` is ``rotate.center``
or else the selection's rest centroid.
``frames = n`` gives t = 0, 1/(n−1), …, 1 (frame 0 is the rest pose); ``frames = 1`` gives t = 1.
``frame: source`` says the handles' coordinates are those of the mesh the data was generated from (the generator
rotates and normalises it); :meth:`EditSpec.in_world` maps them onto the rest mesh.
Every malformed spec raises :class:`NerfEditError` naming the file and the key before any work is done.
"""

from __future__ import annotations

import dataclasses
import glob
import json
import math
import os
import shutil
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.selection import Selection, parse_selection
from nerfedit_plugin.edit.spec_values import check_keys, number, resolve_path, spec_error, vector
from nerfedit_plugin.errors import NerfEditError

FRAMES = ("world", "source")


@dataclass(frozen=True)
class Transform:
    """Similarity transform with a pivot; :meth:`apply` evaluates it at interpolation time ``t``."""

    translate: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotvec: np.ndarray = field(default_factory=lambda: np.zeros(3))
    center: np.ndarray | None = None
    scale: float = 1.0

    def apply(self, points: np.ndarray, t: float, pivot: np.ndarray) -> np.ndarray:
        c = self.center if self.center is not None else pivot
        rot = Rotation.from_rotvec(t * self.rotvec).as_matrix()
        s = 1.0 + (self.scale - 1.0) * t
        return c + s * (points - c) @ rot.T + t * self.translate

    def conjugated(self, matrix: np.ndarray) -> Transform:
        """This transform given in a frame that the similarity ``matrix`` (4,4) float64, ``x ↦ sRx + b``, maps into
        the rest points' frame → the same motion there, ``M ∘ T ∘ M⁻¹``: pivot ``M c``, rotation vector ``R r``,
        translation ``sR τ``, same scale (a pivot left to the selection's centroid stays so: ``M`` keeps centroids)."""
        linear = matrix[:3, :3]
        rotation = linear / np.cbrt(np.linalg.det(linear))
        center = None if self.center is None else linear @ self.center + matrix[:3, 3]
        return Transform(linear @ self.translate, rotation @ self.rotvec, center, self.scale)


@dataclass(frozen=True)
class Handle:
    selection: Selection
    transform: Transform | None  # None = fixed


@dataclass(frozen=True)
class EditSpec:
    """A parsed edit: handles, frame count and the deformer-specific top-level keys (``extra``)."""

    handles: tuple[Handle, ...] = ()
    frames: int = 1
    extra: dict = field(default_factory=dict)
    frames_given: bool = False
    """Whether the spec set ``frames`` (a deformer with its own timeline, e.g. a BVH clip, uses it when not)."""
    source: str = "<edit spec>"
    base_dir: Path = Path(".")
    frame: str = "world"
    """The frame of the handles' boxes, spheres and transforms: ``world`` (the rest mesh's own coordinates) or
    ``source`` (the mesh the data was generated from: :meth:`in_world` maps them)."""
    file_keys: dict[str, str] = field(default_factory=dict, compare=False, repr=False)
    """The top-level keys files were read from as the deformer bound, each with how: ``"path"`` (one file) or
    ``"paths"`` (a list, or one name globbed): what :func:`copy_spec_file` writes absolute."""

    def in_world(self, source_to_world: np.ndarray) -> EditSpec:
        """This spec with its handles mapped from the ``source`` frame into the world by the similarity
        ``source_to_world`` (4,4) float64 (``x ↦ sRx + b``, s > 0, R a rotation): selections test the rest points
        mapped back into the source frame, transforms are conjugated (:meth:`Transform.conjugated`). A ``world``
        spec is returned as it is. A matrix that is not such a similarity is a :class:`NerfEditError`."""
        if self.frame == "world":
            return self
        matrix = np.asarray(source_to_world, dtype=np.float64)
        inverse = source_to_spec(matrix, self.source)
        handles = tuple(
            Handle(
                dataclasses.replace(handle.selection, to_spec=inverse),
                None if handle.transform is None else handle.transform.conjugated(matrix),
            )
            for handle in self.handles
        )
        return dataclasses.replace(self, handles=handles, frame="world")

    @property
    def times(self) -> np.ndarray:
        """Interpolation time of each frame."""
        return np.ones(1) if self.frames == 1 else np.linspace(0.0, 1.0, self.frames)

    def handle_targets(self, points: np.ndarray, faces: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Resolve handles against rest ``points`` (and the rest mesh's ``faces`` (F,3) over them, which ``component``
        selections need) → ``(indices (H,), targets (frames, H, 3))``.

        A point selected by several handles follows the last one listed.
        """
        if not self.handles:
            raise spec_error(self.source, "handles", "no handles given")
        points = np.asarray(points, dtype=np.float64)
        owner = np.full(len(points), -1)
        for h, handle in enumerate(self.handles):
            owner[handle.selection.indices(points, self.source, faces)] = h
        idx = np.flatnonzero(owner >= 0)
        targets = np.repeat(points[idx][None], self.frames, axis=0)
        for h, handle in enumerate(self.handles):
            if handle.transform is None:
                continue
            sel = handle.selection.indices(points, self.source, faces)
            pivot = points[sel].mean(0)
            cols = np.searchsorted(idx, sel[owner[sel] == h])
            for f, t in enumerate(self.times):
                targets[f, cols] = handle.transform.apply(points[idx[cols]], t, pivot)
        return idx, targets

    def path(self, key: str) -> Path:
        """Resolve the file named by top-level ``key`` relative to the spec's folder; it must exist."""
        if key not in self.extra:
            raise spec_error(self.source, key, "missing")
        self.file_keys.setdefault(key, "path")
        value = self.extra[key]
        if not isinstance(value, (str, os.PathLike)):
            raise spec_error(self.source, key, f"expected a file path, got {value!r}")
        resolved = self._resolve(value, key)
        if not resolved.is_file():
            raise spec_error(self.source, key, f"file not found: {resolved}")
        return resolved

    def _resolve(self, value: Any, key: str) -> Path:
        return resolve_path(self.base_dir, value, self.source, key)

    def paths(self, key: str) -> list[Path]:
        """Resolve a list of files or one glob pattern under ``key`` (sorted); at least one must exist."""
        self.file_keys[key] = "paths"
        value = self.extra.get(key)
        if isinstance(value, str):
            pattern = os.path.join(glob.escape(str(self.base_dir)), value)  # an absolute pattern stays absolute
            found = sorted(Path(p).resolve() for p in glob.glob(pattern)) if any(ch in value for ch in "*?[") else None
            if found is None:
                return [self.path(key)]
            if not found:
                raise spec_error(self.source, key, f"pattern {value!r} matches no file")
            return found
        if isinstance(value, list) and value:
            out = []
            for i, item in enumerate(value):
                resolved = self._resolve(str(item), f"{key}[{i}]")
                if not resolved.is_file():
                    raise spec_error(self.source, f"{key}[{i}]", f"file not found: {resolved}")
                out.append(resolved)
            return out
        raise spec_error(self.source, key, "expected a file, a glob pattern or a non-empty list of files")


def source_to_spec(source_to_world: np.ndarray, source: str) -> np.ndarray:
    """The inverse ``(4,4)`` of the similarity ``source_to_world`` (``x ↦ sRx + b``, s > 0, R a rotation): what takes
    rest points into a ``frame: source`` spec's frame; any other matrix is a :func:`spec_error` of ``source``'s
    ``frame``."""
    matrix = np.asarray(source_to_world, dtype=np.float64)
    linear = matrix[:3, :3] if matrix.shape == (4, 4) else np.zeros((3, 3))
    scale = np.cbrt(np.linalg.det(linear))
    similar = matrix.shape == (4, 4) and np.isfinite(matrix).all() and scale > 0
    if not (similar and np.allclose(linear.T @ linear, scale**2 * np.eye(3), rtol=0, atol=1e-9 * scale**2)):
        raise spec_error(source, "frame", "the source-to-world transform is not a similarity")
    inverse = np.eye(4)
    inverse[:3, :3] = linear.T / scale**2
    inverse[:3, 3] = -inverse[:3, :3] @ matrix[:3, 3]
    return inverse


def parse_transform(obj: Any, source: str, key: str) -> Transform:
    """A ``transform`` mapping (``translate``, ``rotate`` {``axis``, ``degrees``, ``center``}, ``scale``) →
    :class:`Transform`, or :func:`spec_error` naming the key."""
    check_keys(obj, ("translate", "rotate", "scale"), source, key)
    if not obj:
        raise spec_error(source, key, "empty transform")
    translate = vector(obj["translate"], source, f"{key}.translate") if "translate" in obj else np.zeros(3)
    rotvec, center = np.zeros(3), None
    if "rotate" in obj:
        rkey = f"{key}.rotate"
        rot = check_keys(obj["rotate"], ("axis", "degrees", "center"), source, rkey, required=("axis", "degrees"))
        axis = vector(rot["axis"], source, f"{rkey}.axis")
        norm = np.linalg.norm(axis)
        if norm == 0:
            raise spec_error(source, f"{rkey}.axis", "is the zero vector")
        rotvec = axis / norm * math.radians(number(rot["degrees"], source, f"{rkey}.degrees"))
        if "center" in rot:
            center = vector(rot["center"], source, f"{rkey}.center")
    scale = number(obj["scale"], source, f"{key}.scale", positive=True) if "scale" in obj else 1.0
    return Transform(translate, rotvec, center, scale)


def parse_edit_spec(
    data: Any,
    allowed_keys: Iterable[str] = ("handles",),
    source: str = "<edit spec>",
    base_dir: str | os.PathLike = ".",
) -> EditSpec:
    """Validate a spec mapping. ``allowed_keys``: the top-level keys the deformer accepts (``frames`` and ``frame``
    always are)."""
    allowed = set(allowed_keys) | {"frames", "frame"}
    check_keys(data, allowed, source, "")
    frames = data.get("frames", 1)
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise spec_error(source, "frames", f"expected an integer >= 1, got {frames!r}")
    handles = []
    if "handles" in data:
        if not isinstance(data["handles"], list) or not data["handles"]:
            raise spec_error(source, "handles", "expected a non-empty list")
        for i, item in enumerate(data["handles"]):
            key = f"handles[{i}]"
            check_keys(item, ("select", "fixed", "transform"), source, key, required=("select",))
            selection = parse_selection(item["select"], source, f"{key}.select", Path(base_dir))
            fixed = item.get("fixed", False)
            if not isinstance(fixed, bool):
                raise spec_error(source, f"{key}.fixed", f"expected true or false, got {fixed!r}")
            if fixed == ("transform" in item):
                raise spec_error(source, key, "needs exactly one of 'fixed': true or a 'transform'")
            transform = None if fixed else parse_transform(item["transform"], source, f"{key}.transform")
            handles.append(Handle(selection, transform))
    frame = data.get("frame", "world")
    if frame not in FRAMES:
        raise spec_error(source, "frame", f"expected one of {list(FRAMES)}, got {frame!r}")
    extra = {k: v for k, v in data.items() if k not in ("handles", "frames", "frame")}
    return EditSpec(tuple(handles), frames, extra, "frames" in data, source, Path(base_dir), frame)


def read_spec_file(path: str | os.PathLike) -> Any:
    """The parsed content of a JSON or YAML spec file (by suffix; ``.json`` else YAML), not yet validated; a missing,
    unreadable or malformed file is a :class:`NerfEditError` naming it."""
    path = Path(path)
    if not path.is_file():
        raise NerfEditError(f"{path}: edit spec not found")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise NerfEditError(f"{path}: cannot read ({exc})") from exc
    try:
        return json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as exc:  # ValueError: also an integer of more than 4300 digits
        raise NerfEditError(f"{path}: cannot parse ({exc})".replace("\n", " ")) from exc


def _file_selections(document: Any) -> Iterator[dict]:
    """Every ``{"file": name}`` selection in a spec document, at any depth (handles, objects, their edits)."""
    if isinstance(document, dict):
        select = document.get("select")
        if isinstance(select, dict) and isinstance(select.get("file"), str):
            yield select
        for value in document.values():
            yield from _file_selections(value)
    elif isinstance(document, list):
        for value in document:
            yield from _file_selections(value)


def copy_spec_file(path: str | os.PathLike, out_dir: Path, file_keys: dict[str, str] | None = None) -> None:
    """Copy the (validated) spec file ``path`` into ``out_dir`` so that the copy reads as the original does: the
    selection files it names inside its folder are copied to the same relative paths; a selection named with a
    ``..`` (``../x``), and the relative files, lists and globs of ``file_keys`` (the deformer's inputs, at the top
    level and in scene objects' edits: :attr:`EditSpec.file_keys`), are written into the copy as absolute paths
    (then the copy is the spec re-written: comments are lost)."""
    path, file_keys = Path(path), file_keys or {}
    document = read_spec_file(path)
    folder = path.parent if path.parent.is_absolute() else Path.cwd() / path.parent  # names resolve as when read
    outside = False
    for select in _file_selections(document):
        name = select["file"]
        if os.path.isabs(name):
            continue
        if os.pardir in Path(name).parts:  # "../x", also "link/../x" (the OS resolves the link first)
            select["file"], outside = str((path.parent / name).resolve()), True
            continue
        target = out_dir / os.path.normpath(name)
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path.parent / name, target)
    for edit in _edits(document):
        for key in file_keys.keys() & edit.keys():
            value = edit[key]
            if isinstance(value, str) and file_keys[key] == "paths":  # globbed: the folder escaped, the name a pattern
                written = os.path.join(glob.escape(str(folder)), value)
                found = bool(glob.glob(written))
            elif isinstance(value, (str, list)):
                names = value if isinstance(value, list) else [value]
                absolute = [os.path.join(folder, n) if isinstance(n, str) else n for n in names]
                found = all(isinstance(n, str) and os.path.isfile(n) for n in absolute)
                written = absolute if isinstance(value, list) else absolute[0]
            else:
                continue
            if found and written != value:  # another object's "auto" (no file) stays as it is
                edit[key], outside = written, True
    if not outside:
        shutil.copyfile(path, out_dir / path.name)
    elif path.suffix.lower() == ".json":
        (out_dir / path.name).write_text(json.dumps(document, indent=2))
    else:
        (out_dir / path.name).write_text(yaml.safe_dump(document))


def _edits(document: Any) -> Iterator[dict]:
    """The edit specs in a spec document: the document itself, and each scene object's and copy's ``edit``."""
    if not isinstance(document, dict):
        return
    yield document
    for obj in document.get("objects", []) if isinstance(document.get("objects"), list) else []:
        for item in [obj, *(obj.get("copies") or [])] if isinstance(obj, dict) else []:
            if isinstance(item, dict) and isinstance(item.get("edit"), dict):
                yield item["edit"]


def load_edit_spec(path: str | os.PathLike, allowed_keys: Iterable[str] = ("handles",)) -> EditSpec:
    """Read a JSON or YAML edit spec (:func:`read_spec_file`) and validate it."""
    path = Path(path)
    return parse_edit_spec(read_spec_file(path), allowed_keys, str(path), path.parent)
