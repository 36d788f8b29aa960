"""SceneDeformation: several objects' deformations resolved together, and edits of edited scenes chained.

A *stage* (one edit) holds objects and instances. An object is a rest proxy ``T_o`` (the tets that hold its own
geometry); an instance is one placed, deformed copy ``T'_i`` of an object's proxy, per frame (an object's original,
moved or not, and its copies; a removed object has no instance of its own). A deformed-space point ``x``:

- inside some instance's ``T'_i``: mapped by the *first* such instance in instance order (objects in spec order, each
  object's original before its copies), ``x_c = Σ b_j r_j`` of that instance's tet (:class:`DeformationField`);
- else inside the rest ``T_o`` of an object that an instance left (``Instance.vacates``: an original, not a copy) or
  that was removed: empty (vacated);
- else: ``x`` itself (identity; Jacobian ``I``).

Primitives (splats) are placed forward by the same rule (:meth:`SceneDeformation.place`): a rest point in an object's
``T_o`` is placed by each of its object's instances at ``Σ b_j d_j`` (its rest barycentrics, the instance's deformed
corners), unless an earlier instance's ``T'`` holds that place; any other rest point stays where it is unless it lies
in a vacated region or in some instance's ``T'``. What lands at a point is then what ray bending shows there.

A chain of stages (the second edit's rest is the first one's deformed mesh) maps ``x`` through the newest stage, then
each older stage at the frame the next edit started from; a point is empty if any stage empties it, and the Jacobian
is the product ``J_0 ⋯ J_newest``; placing runs the stages oldest first, the gradients multiplied. One object with
one instance in one stage is exactly a :class:`DeformationField`.

Saved as ``deformation.npz`` format 2: ``format_version = 2``, ``layout`` (JSON: per stage its ``frame``, objects'
and instances' names, each instance's ``object``) and the arrays ``s{s}_o{o}_rest_vertices``, ``s{s}_o{o}_tets``,
``s{s}_i{i}_deformed_vertices``. :func:`load_deformation` reads format 1 (one :class:`DeformationField`) and 2.
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from nerfedit_plugin.bending.deformation_field import DeformationField, validate_arrays
from nerfedit_plugin.bending.locate import TetLocator
from nerfedit_plugin.bending.maps import BentPoints, CanonicalPoints, Placement
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import atomic_path

FORMAT_VERSION = 2


class SceneObject(NamedTuple):
    name: str
    rest_vertices: np.ndarray  # (N,3) float64
    tets: np.ndarray  # (K,4) int64


class Instance(NamedTuple):
    name: str
    object: int  # index into the stage's objects
    deformed_vertices: np.ndarray  # (F,N,3) float64, N = its object's rest vertex count
    vacates: bool = True
    """Whether the part of its object's rest region it does not cover is emptied (an original moved away); a copy,
    which only reads the region, does not."""


@dataclass
class Stage:
    """One edit of a scene: its objects and their instances (see the module docstring). ``frame``: the frame of this
    stage a newer stage of a chain starts from (ignored for the newest)."""

    objects: list[SceneObject]
    instances: list[Instance]
    frame: int = 0
    _fields: list[DeformationField] = field(default_factory=list, repr=False)
    _vacated: list[TetLocator] = field(default_factory=list, repr=False)
    _grids: dict = field(default_factory=dict, repr=False)  # frame -> _slot_grid

    @property
    def n_frames(self) -> int:
        return max((len(i.deformed_vertices) for i in self.instances), default=1)

    @property
    def n_tets(self) -> int:
        """Tets over all instances: a stage's tet index is its instance's offset plus the tet in that instance."""
        return sum(len(self.objects[i.object].tets) for i in self.instances)


class SceneDeformation:
    """Stages of objects and instances mapping deformed-space points to canonical space (module docstring): a
    :class:`~nerfedit_plugin.bending.maps.BackwardMap`."""

    def __init__(self, stages: list[Stage], *, device="cpu", dtype=torch.float32, kernel: str = "auto"):
        if not stages:
            raise NerfEditError("SceneDeformation: needs at least one stage")
        self.stages = [_checked(stage, f"stage {s}") for s, stage in enumerate(stages)]
        self.device, self.dtype, self.kernel = torch.device(device), dtype, kernel
        codes = 1
        for stage in self.stages:
            codes *= stage.n_tets + 1
        if codes >= 2**62:
            raise NerfEditError("SceneDeformation: too many chained stages to index their tets together")
        for stage in self.stages:
            stage._fields = [
                DeformationField(
                    stage.objects[i.object].rest_vertices,
                    stage.objects[i.object].tets,
                    _frames(i.deformed_vertices, stage.n_frames),
                    device=device,
                    dtype=dtype,
                    kernel=kernel,
                )
                for i in stage.instances
            ]
            shared: dict[int, DeformationField] = {}
            for inst, deformation in zip(stage.instances, stage._fields):  # one rest locator per object
                first = shared.setdefault(inst.object, deformation)
                deformation._rest_locator, deformation._face_pairs = first._rest(), first._face_pairs
            placed = {i.object for i in stage.instances if i.vacates}  # the others are vacated whole
            stage._vacated = [
                TetLocator(o.rest_vertices, o.tets, dtype=dtype, device=device, kernel=kernel)
                for k, o in enumerate(stage.objects)
                if k not in placed
            ]

    @classmethod
    def from_field(cls, deformation: DeformationField, name: str = "object", **kwargs) -> SceneDeformation:
        """One stage with one object and one instance: the same map as ``deformation``."""
        return cls([_single(deformation, name)], **kwargs)

    @property
    def n_frames(self) -> int:
        return self.stages[-1].n_frames

    def _frames(self, frame: int) -> list[tuple[Stage, int]]:
        """The stages newest first, each with the frame it is evaluated at."""
        if not 0 <= frame < self.n_frames:
            raise NerfEditError(f"frame {frame} out of range: the deformation has {self.n_frames} frame(s)")
        return [(self.stages[-1], int(frame))] + [(s, s.frame) for s in reversed(self.stages[:-1])]

    def bend(
        self, x: torch.Tensor, frame: int = 0, *, out: torch.Tensor | None = None, tets: bool = True
    ) -> BentPoints:
        """:meth:`DeformationField.bend` for the scene: ``points (M,3)``, ``tet (M,)`` (a chain index of the tets that
        mapped the point, -1 where no stage did; None with ``tets=False``), ``empty (M,)``."""
        x = torch.as_tensor(x)
        if out is not None and out.shape != (len(x), 3):
            raise ValueError(f"bend: out must have shape ({len(x)}, 3), got {tuple(out.shape)}")
        points = x.to(device=self.device, dtype=self.dtype).reshape(-1, 3)
        code = torch.zeros(len(points), dtype=torch.int64, device=self.device)
        empty = torch.zeros(len(points), dtype=torch.bool, device=self.device)
        radix = 1
        for stage, f in self._frames(frame):
            points, tet, vacated = _bend_stage(stage, points, f)
            code += (tet + 1) * radix
            empty |= vacated
            radix *= stage.n_tets + 1
        if out is not None:
            points = out.copy_(points)
        return BentPoints(points, code - 1 if tets else None, empty)

    def jacobian(self, tet: torch.Tensor, frame: int = 0) -> torch.Tensor:
        """tet (M,) (as :meth:`bend` returns) → ``(M,3,3)`` dx_c/dx: the product of the stages' Jacobians, oldest
        on the left (identity where ``tet`` is -1)."""
        code = torch.as_tensor(tet, device=self.device) + 1
        result = None
        for stage, f in self._frames(frame):
            local = code % (stage.n_tets + 1) - 1
            code = torch.div(code, stage.n_tets + 1, rounding_mode="floor")
            j = _stage_jacobian(stage, local, f, self.dtype)
            result = j if result is None else j @ result
        return result

    def to_canonical(self, x: torch.Tensor, frame: int = 0) -> CanonicalPoints:
        """:meth:`DeformationField.to_canonical` for the scene."""
        bent = self.bend(x, frame)
        return CanonicalPoints(bent.points, bent.tet >= 0, bent.empty, self.jacobian(bent.tet, frame))

    def place(self, x: torch.Tensor, frame: int = 0) -> Placement:
        """Place rest points ``x (M,3)`` in ``frame`` (module docstring), through every stage oldest first →
        :class:`~nerfedit_plugin.bending.maps.Placement`: a :class:`~nerfedit_plugin.bending.maps.PlacementMap`."""
        points = torch.as_tensor(x).to(device=self.device, dtype=self.dtype).reshape(-1, 3)
        source = torch.arange(len(points), device=self.device)
        gradient = torch.eye(3, dtype=self.dtype, device=self.device).expand(len(points), 3, 3)
        for stage, f in reversed(self._frames(frame)):
            rows, points, local = _place_stage(stage, points, f)
            source, gradient = source.index_select(0, rows), local @ gradient.index_select(0, rows)
        return Placement(source, points, gradient)

    def moved_bounds(self, frame: int = 0) -> np.ndarray | None:
        """``(2,3)`` box of every instance's moved tets (:meth:`DeformationField.moved_bounds`) over all stages at
        their frames; None if nothing moves."""
        boxes = [
            b for stage, f in self._frames(frame) for field in stage._fields if (b := field.moved_bounds(f)) is not None
        ]
        return None if not boxes else np.stack([np.min([b[0] for b in boxes], 0), np.max([b[1] for b in boxes], 0)])

    def proxies(self, frame: int = 0) -> list[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
        """The newest stage's instances as ``(name, rest_vertices, tets, deformed_vertices of frame)`` (viewers)."""
        stage, f = self._frames(frame)[0]
        return [
            (i.name, stage.objects[i.object].rest_vertices, stage.objects[i.object].tets, d.deformed_vertices[f])
            for i, d in zip(stage.instances, stage._fields)
        ]

    def chained(self, newer: SceneDeformation, frame: int | None = None) -> SceneDeformation:
        """This deformation followed by ``newer`` (an edit whose rest is this one's deformed mesh of ``frame``,
        default the last): ``x`` maps through ``newer``'s stages, then through this one's at ``frame``."""
        frame = self.n_frames - 1 if frame is None else frame
        if not 0 <= frame < self.n_frames:
            raise NerfEditError(f"frame {frame} out of range: the deformation has {self.n_frames} frame(s)")
        last = self.stages[-1]
        older = [*self.stages[:-1], Stage(last.objects, last.instances, frame)]
        return SceneDeformation(older + newer.stages, device=self.device, dtype=self.dtype, kernel=self.kernel)

    def save(self, path: str | os.PathLike) -> None:
        """Write ``deformation.npz`` (format 2) atomically."""
        layout, arrays = {"stages": []}, {}
        for s, stage in enumerate(self.stages):
            layout["stages"].append(
                {
                    "frame": stage.frame,
                    "objects": [o.name for o in stage.objects],
                    "instances": [{"name": i.name, "object": i.object, "vacates": i.vacates} for i in stage.instances],
                }
            )
            for o, obj in enumerate(stage.objects):
                arrays[f"s{s}_o{o}_rest_vertices"], arrays[f"s{s}_o{o}_tets"] = obj.rest_vertices, obj.tets
            for i, inst in enumerate(stage.instances):
                arrays[f"s{s}_i{i}_deformed_vertices"] = inst.deformed_vertices
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez(handle, format_version=np.int64(FORMAT_VERSION), layout=np.str_(json.dumps(layout)), **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike, **kwargs) -> SceneDeformation:
        """Read a ``deformation.npz`` of either format as a SceneDeformation (format 1: :meth:`from_field`)."""
        loaded = load_deformation(path, **kwargs)
        return loaded if isinstance(loaded, SceneDeformation) else cls.from_field(loaded, **kwargs)


def load_deformation(path: str | os.PathLike, **kwargs) -> DeformationField | SceneDeformation:
    """Read a ``deformation.npz``: format 1 → :class:`DeformationField`, format 2 → :class:`SceneDeformation`; a
    missing, corrupt or incomplete file raises :class:`NerfEditError` naming it and the key."""
    if not os.path.isfile(path):
        raise NerfEditError(f"{path}: deformation file not found")
    try:
        with np.load(path, allow_pickle=False) as data:
            version = data["format_version"] if "format_version" in data.files else None
            if version is None or version.shape != () or int(version) not in (1, FORMAT_VERSION):
                if version is None:
                    raise NerfEditError(f"{path}: missing key 'format_version'")
                raise NerfEditError(f"{path}: format_version: unsupported {version} (expected 1 or {FORMAT_VERSION})")
            if int(version) == 1:
                return DeformationField.load(path, **kwargs)
            stages = _read_stages(data, str(path))
    except NerfEditError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise NerfEditError(f"{path}: not a readable deformation .npz ({error})") from None
    return SceneDeformation(stages, **kwargs)


def _read_stages(data, where: str) -> list[Stage]:
    if "layout" not in data.files:
        raise NerfEditError(f"{where}: missing key 'layout'")
    try:
        layout = json.loads(str(data["layout"]))
        stages = []
        for s, entry in enumerate(layout["stages"]):
            objects, instances = [], []
            for o, name in enumerate(entry["objects"]):
                keys = (f"s{s}_o{o}_rest_vertices", f"s{s}_o{o}_tets")
                missing = [k for k in keys if k not in data.files]
                if missing:
                    raise NerfEditError(f"{where}: missing key '{missing[0]}'")
                objects.append(SceneObject(str(name), data[keys[0]], data[keys[1]]))
            for i, inst in enumerate(entry["instances"]):
                key = f"s{s}_i{i}_deformed_vertices"
                if key not in data.files:
                    raise NerfEditError(f"{where}: missing key '{key}'")
                instances.append(
                    Instance(str(inst["name"]), int(inst["object"]), data[key], bool(inst.get("vacates", True)))
                )
            stages.append(Stage(objects, instances, int(entry["frame"])))
    except (KeyError, TypeError, ValueError) as error:
        raise NerfEditError(f"{where}: layout: malformed ({error!r})") from None
    return [_checked(stage, where) for stage in stages]


def _checked(stage: Stage, where: str) -> Stage:
    """The stage with validated arrays (:func:`~nerfedit_plugin.bending.deformation_field.validate_arrays`), or
    :class:`NerfEditError` naming ``where`` and the object or instance."""
    objects = []
    for obj in stage.objects:
        rest, tets, _ = validate_arrays(obj.rest_vertices, obj.tets, obj.rest_vertices, f"{where}: object {obj.name!r}")
        objects.append(SceneObject(obj.name, rest, tets))
    instances, frames = [], set()
    for inst in stage.instances:
        if not 0 <= inst.object < len(objects):
            raise NerfEditError(f"{where}: instance {inst.name!r}: object {inst.object} out of range")
        rest, tets = objects[inst.object][1:]
        _, _, deformed = validate_arrays(rest, tets, inst.deformed_vertices, f"{where}: instance {inst.name!r}")
        instances.append(Instance(inst.name, inst.object, deformed, inst.vacates))
        frames.add(len(deformed))
    if len(frames - {1}) > 1:
        raise NerfEditError(f"{where}: instances have different frame counts {sorted(frames)} (1 or one count)")
    checked = Stage(objects, instances, int(stage.frame))
    if not 0 <= checked.frame < checked.n_frames:
        raise NerfEditError(f"{where}: frame {checked.frame} out of range for {checked.n_frames} frame(s)")
    return checked


def _single(deformation: DeformationField, name: str) -> Stage:
    return Stage(
        [SceneObject(name, deformation.rest_vertices, deformation.tets)],
        [Instance(name, 0, deformation.deformed_vertices)],
    )


def _frames(deformed: np.ndarray, n: int) -> np.ndarray:
    """An instance's frames, a single frame held for all ``n``."""
    return np.broadcast_to(deformed, (n, *deformed.shape[1:])) if len(deformed) == 1 else deformed


GRID_CELLS = 32
"""Cells per axis of a stage's slot grid: which instances (and removed objects) a cell of space may concern."""


def _slot_grid(stage: Stage, frame: int) -> tuple[torch.Tensor, ...]:
    """``(low (3,), scale (3,), mask ((C+2)³,) int64)``: cells ``u = floor((x − low) scale) + 1`` in ``[1, C]`` over the
    union, grown by one cell, of the boxes a stage's slots concern — instance ``j``: its deformed frame (and its
    object's rest when it vacates); then each removed object: its rest — and a border layer (cells 0 and C+1) that
    takes every point outside. Bit ``j mod 63`` of a cell is set where slot ``j``'s box, grown by one cell, reaches
    it: a point in a cell without slot ``j``'s bit is outside all that slot maps or empties."""
    if frame not in stage._grids:
        boxes = []
        for inst in stage.instances:
            points = [_frames(inst.deformed_vertices, stage.n_frames)[frame]]
            points += [stage.objects[inst.object].rest_vertices] if inst.vacates else []
            boxes.append(np.concatenate(points))
        placed = {i.object for i in stage.instances if i.vacates}
        boxes += [o.rest_vertices for k, o in enumerate(stage.objects) if k not in placed]
        boxes = np.stack([[b.min(0), b.max(0)] for b in boxes])
        cell = (boxes[:, 1].max(0) - boxes[:, 0].min(0)).clip(1e-12) / (GRID_CELLS - 2)
        low = boxes[:, 0].min(0) - cell
        scale = GRID_CELLS / (boxes[:, 1].max(0) + cell - low)
        mask = np.zeros((GRID_CELLS + 2,) * 3, dtype=np.int64)
        for j, (lo, hi) in enumerate(boxes):
            a = np.clip(np.floor((lo - low) * scale).astype(np.int64), 1, GRID_CELLS)  # one cell grown, +1 border
            b = np.clip(np.floor((hi - low) * scale).astype(np.int64) + 2, 1, GRID_CELLS)
            mask[a[0] : b[0] + 1, a[1] : b[1] + 1, a[2] : b[2] + 1] |= np.int64(1) << (j % 63)
        stage._grids[frame] = (torch.as_tensor(low), torch.as_tensor(scale), torch.as_tensor(mask.reshape(-1)))
    return stage._grids[frame]


def _slots(stage: Stage, x: torch.Tensor, frame: int) -> torch.Tensor:
    """``(M,)`` int64: the slot bits of the points' cells (:func:`_slot_grid`; NaN points: none), one coordinate
    column at a time as :func:`~nerfedit_plugin.bending.deformation_field._near` does."""
    low, scale, mask = (t.to(device=x.device) for t in _slot_grid(stage, frame))
    side, cell = GRID_CELLS + 2, None
    for i, stride in enumerate((side * side, side, 1)):
        u = (x[:, i] - float(low[i])).mul_(float(scale[i])).add_(1.0).clamp_(0.0, side - 1.0).floor_()
        cell = u.mul_(stride) if cell is None else cell.add_(u, alpha=stride)
    return mask.index_select(0, torch.nan_to_num_(cell, nan=0.0).to(torch.int64))


def _bend_stage(stage: Stage, x: torch.Tensor, frame: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Points ``x (M,3)`` through one stage → ``(points, tet (M,) stage index or -1, empty (M,))``. Each slot sees only
    the points of cells it may concern (:func:`_slots`) that no earlier instance mapped."""
    if len(stage._fields) == 1 and not stage._vacated:  # one slot: nothing to sort out
        bent = stage._fields[0].bend(x, frame)
        return bent.points, bent.tet, bent.empty & stage.instances[0].vacates
    out = x.clone()
    tet = torch.full((len(x),), -1, dtype=torch.int64, device=x.device)
    empty = torch.zeros(len(x), dtype=torch.bool, device=x.device)
    code, offset = _slots(stage, x, frame), 0
    for j, (instance, deformation) in enumerate(zip(stage.instances, stage._fields)):
        rows = torch.nonzero(code & (1 << (j % 63))).squeeze(1)
        if len(rows):
            bent = deformation.bend(x.index_select(0, rows), frame)
            mapped = torch.nonzero(bent.tet >= 0).squeeze(1)
            where = rows.index_select(0, mapped)
            out.index_copy_(0, where, bent.points.index_select(0, mapped))
            tet.index_copy_(0, where, bent.tet.index_select(0, mapped) + offset)
            code.index_fill_(0, where, 0)  # mapped: later slots never see it
            if instance.vacates:
                empty.index_fill_(0, rows[bent.empty], True)
        offset += len(deformation.tets)
    for j, locator in enumerate(stage._vacated, start=len(stage.instances)):
        rows = torch.nonzero(code & (1 << (j % 63))).squeeze(1)
        if len(rows):
            empty.index_fill_(0, rows[locator.member(x.index_select(0, rows)) >= 0], True)
    return out, tet, empty & (tet < 0)


def _place_stage(stage: Stage, x: torch.Tensor, frame: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rest points ``x (M,3)`` through one stage → ``(rows (P,) non-decreasing, points (P,3), gradient (P,3,3))``:
    each instance places the points of its object's ``T_o`` unless an earlier instance's ``T'`` holds the place; the
    other points stay unless vacated or inside some instance's ``T'`` (module docstring)."""
    rows, points, gradients = [], [], []
    vacated = torch.zeros(len(x), dtype=torch.bool, device=x.device)
    covered = torch.zeros_like(vacated)
    for j, (instance, deformation) in enumerate(zip(stage.instances, stage._fields)):
        moved = deformation.to_deformed(x, frame)
        inside = torch.nonzero(moved.inside).squeeze(1)
        placed = moved.points.index_select(0, inside)
        free = torch.ones(len(inside), dtype=torch.bool, device=x.device)
        for earlier in stage._fields[:j]:
            free &= earlier.bend(placed, frame).tet < 0
        rows.append(inside[free])
        points.append(placed[free])
        gradients.append(moved.gradient.index_select(0, inside)[free])
        if instance.vacates:
            vacated |= moved.inside
        covered |= deformation.bend(x, frame).tet >= 0
    for locator in stage._vacated:
        vacated |= locator.member(x) >= 0
    stay = torch.nonzero(~vacated & ~covered).squeeze(1)
    rows.append(stay)
    points.append(x.index_select(0, stay))
    gradients.append(torch.eye(3, dtype=x.dtype, device=x.device).expand(len(stay), 3, 3))
    order = torch.argsort(torch.cat(rows), stable=True)
    return torch.cat(rows)[order], torch.cat(points)[order], torch.cat(gradients)[order]


def _stage_jacobian(stage: Stage, tet: torch.Tensor, frame: int, dtype: torch.dtype) -> torch.Tensor:
    """``(M,3,3)`` Jacobians of stage tets ``tet`` (-1: identity)."""
    result = torch.eye(3, dtype=dtype, device=tet.device).repeat(len(tet), 1, 1)
    offset = 0
    for deformation in stage._fields:
        rows = torch.nonzero((tet >= offset) & (tet < offset + len(deformation.tets))).squeeze(1)
        if len(rows):
            result.index_copy_(0, rows, deformation.jacobian(tet.index_select(0, rows) - offset, frame))
        offset += len(deformation.tets)
    return result
