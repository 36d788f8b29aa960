"""Scene edits: several objects selected on one mesh, each deformed, placed, copied or removed (docs/architecture.md,
"Scene edits").

Spec (JSON or YAML)::

    {"objects": [{"name": "bunny", "select": {...},
                  "deformer": "arap", "edit": {<that deformer's spec>},
                  "place": {"translate": [...], "rotate": {...}, "scale": s},
                  "remove": false,
                  "copies": [{"name": "bunny_2", "place": {...}, "deformer": ..., "edit": {...}}]}],
     "frame": "world" | "source"}

Every key but ``select`` is optional. An object's *instances* are its original (unless ``remove``) and its copies;
each is the object's surface, deformed by its own ``edit`` (run by ``deformer``, default the command's
``--deformer``; no ``edit``: unchanged), then placed by ``place`` (a similarity about the object's rest centroid
unless ``rotate.center`` is given). A copy's ``place`` is required. The object's edit spec is read on the object's
own surface (``indices`` index its vertices in mesh order). ``frame`` applies to the objects' selections and
placements, as in a handle spec.

Each object gets its own tet proxy around its selected surface only; unselected geometry never moves. The proxy's
*own* tets — those holding the object's surface, or nearer to it than to the rest of the mesh — are what its
instances carry and what its original leaves empty when it moves (:mod:`~nerfedit_plugin.bending.scene_deformation`):
a floor inside the proxy's margin is neither carried nor carved.
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from nerfedit_plugin.bending.locate import TetLocator
from nerfedit_plugin.bending.scene_deformation import Instance, SceneDeformation, SceneObject, Stage
from nerfedit_plugin.config import to_plain, write_config
from nerfedit_plugin.edit.deformer import DeformerConfig, checked_frames, mesh_digest
from nerfedit_plugin.edit.lift import Lift, LiftConfig, LiftMethod
from nerfedit_plugin.edit.ownership import own_region
from nerfedit_plugin.edit.proxy import ProxyConfig, TetProxy, cached_proxy, proxy_cache_key, stored_proxy
from nerfedit_plugin.edit.selection import Selection, parse_selection
from nerfedit_plugin.edit.spec import (
    FRAMES,
    EditSpec,
    Transform,
    copy_spec_file,
    parse_edit_spec,
    parse_transform,
    read_spec_file,
    source_to_spec,
)
from nerfedit_plugin.edit.spec_values import check_keys, spec_error
from nerfedit_plugin.edit.vacated import fill_patch
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_dir
from nerfedit_plugin.quality import edit_warnings
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.timing import Progress, ProgressListener, Stopwatch, labelled, no_progress, peak_rss_mb

OBJECT_KEYS = ("name", "select", "deformer", "edit", "place", "remove", "copies", "vacated")
VACATED = ("empty", "fill")
COPY_KEYS = ("name", "deformer", "edit", "place")


@dataclass(frozen=True)
class InstanceSpec:
    """One instance of an object: ``deformer`` config and parsed ``edit`` (None: unchanged), ``place`` (None: where
    it is); ``key`` its path in the spec (``objects[0]``, ``objects[0].copies[1]``)."""

    name: str
    key: str
    deformer: DeformerConfig | None
    edit: EditSpec | None
    place: Transform | None


@dataclass(frozen=True)
class ObjectSpec:
    name: str
    key: str
    selection: Selection
    instances: tuple[InstanceSpec, ...]
    """The original first (absent when removed), then the copies."""
    removed: bool
    vacated: str = "empty"
    """What the floor it leaves shows: ``empty`` (what the field holds there) or ``fill``
    (:mod:`~nerfedit_plugin.edit.vacated`)."""

    @property
    def leaves(self) -> bool:
        """Whether its original leaves its place (removed, edited or placed)."""
        return self.removed or self.instances[0].edit is not None or self.instances[0].place is not None


@dataclass(frozen=True)
class ObjectsSpec:
    objects: tuple[ObjectSpec, ...]
    source: str

    def resolve(self, mesh: SurfaceMesh) -> list[np.ndarray]:
        """Each object's selected vertex indices on ``mesh``; a selection of nothing or of every vertex, or two
        objects sharing vertices, is a :class:`NerfEditError` naming the objects and the key."""
        owner = np.full(mesh.n_vertices, -1)
        found = []
        for o, obj in enumerate(self.objects):
            idx = obj.selection.indices(mesh.vertices, self.source, mesh.faces)
            if len(idx) == mesh.n_vertices:
                raise spec_error(self.source, obj.selection.key, f"selects every vertex of the mesh ({len(idx)})")
            shared = owner[idx][owner[idx] >= 0]
            if len(shared):
                other = self.objects[shared[0]]
                raise spec_error(
                    self.source,
                    obj.selection.key,
                    f"shares {len(shared)} vertices with {other.key} ({other.name!r}); objects must not overlap",
                )
            owner[idx] = o
            found.append(idx)
        return found


def is_objects_spec(path: str | os.PathLike) -> bool:
    """Whether the spec file holds a scene edit (a top-level ``objects`` key)."""
    data = read_spec_file(path)
    return isinstance(data, dict) and "objects" in data


def load_objects_spec(
    path: str | os.PathLike, default_deformer: DeformerConfig, source_to_world: np.ndarray | None = None
) -> ObjectsSpec:
    """Read and validate a scene edit spec, every object's edit included (by its deformer's keys), before any
    work. ``source_to_world``: as :meth:`EditSpec.in_world` (``frame: source``, at the top level or in an edit)."""
    path = Path(path)
    source, base_dir = str(path), path.parent
    data = check_keys(read_spec_file(path), ("objects", "frame"), source, "")
    frame = data.get("frame", "world")
    if frame not in FRAMES:
        raise spec_error(source, "frame", f"expected one of {list(FRAMES)}, got {frame!r}")
    world = np.eye(4) if source_to_world is None else np.asarray(source_to_world, dtype=np.float64)
    to_spec = source_to_spec(world, source) if frame == "source" else None
    if not isinstance(data["objects"], list) or not data["objects"]:
        raise spec_error(source, "objects", "expected a non-empty list")
    registry, names, objects = discover(DEFORMERS), set(), []
    for o, item in enumerate(data["objects"]):
        key = f"objects[{o}]"
        check_keys(item, OBJECT_KEYS, source, key, required=("select",))
        name = _name(item, f"object{o}", source, key, names)
        selection = dataclasses.replace(
            parse_selection(item["select"], source, f"{key}.select", base_dir), to_spec=to_spec
        )
        removed = item.get("remove", False)
        if not isinstance(removed, bool):
            raise spec_error(source, f"{key}.remove", f"expected true or false, got {removed!r}")
        if removed and ({"edit", "place", "deformer"} & set(item)):
            raise spec_error(source, key, "a removed object has no edit, place or deformer (give them to a copy)")
        copies = item.get("copies", [])
        if not isinstance(copies, list):
            raise spec_error(source, f"{key}.copies", "expected a list")
        instances = (
            [] if removed else [_instance(item, name, key, registry, default_deformer, world, frame, base_dir, source)]
        )
        for c, copy in enumerate(copies):
            ckey = f"{key}.copies[{c}]"
            check_keys(copy, COPY_KEYS, source, ckey, required=("place",))
            cname = _name(copy, f"{name}#{c + 1}", source, ckey, names)
            instances.append(_instance(copy, cname, ckey, registry, default_deformer, world, frame, base_dir, source))
        vacated = item.get("vacated", "empty")
        if vacated not in VACATED:
            raise spec_error(source, f"{key}.vacated", f"expected one of {list(VACATED)}, got {vacated!r}")
        objects.append(ObjectSpec(name, key, selection, tuple(instances), removed, vacated))
    return ObjectsSpec(tuple(objects), source)


def _name(item: dict, default: str, source: str, key: str, names: set[str]) -> str:
    name = item.get("name", default)
    if not isinstance(name, str) or not name:
        raise spec_error(source, f"{key}.name", f"expected a non-empty string, got {name!r}")
    if name in names:
        raise spec_error(source, f"{key}.name", f"{name!r} is used twice")
    names.add(name)
    return name


def _instance(item, name, key, registry, default_deformer, world, frame, base_dir, source) -> InstanceSpec:
    """Parse an instance's ``deformer``, ``edit`` (by that deformer's keys, mapped into the world) and ``place``."""
    deformer = None
    if "deformer" in item and "edit" not in item:
        raise spec_error(source, f"{key}.deformer", "needs an 'edit' for the deformer to run")
    if "edit" in item:
        deformer = default_deformer
        if "deformer" in item:
            if not isinstance(item["deformer"], str):
                raise spec_error(source, f"{key}.deformer", f"expected a deformer name, got {item['deformer']!r}")
            try:
                deformer = registry.config_class(DEFORMERS, item["deformer"])()
            except NerfEditError as error:
                raise spec_error(source, f"{key}.deformer", str(error)) from None
        edit = parse_edit_spec(item["edit"], deformer._target.spec_keys, f"{source}: {key}.edit", base_dir)
        edit = edit.in_world(world)
    place = None
    if "place" in item:
        place = parse_transform(item["place"], source, f"{key}.place")
        if frame == "source":
            place = place.conjugated(world)
    return InstanceSpec(name, key, deformer, edit if deformer is not None else None, place)


@dataclass
class _Placed:
    """An instance's result: its surface frames ``(F,V,3)``, its proxy frames ``(F,N,3)`` on ``proxy``, reports."""

    spec: InstanceSpec
    surface: np.ndarray
    lifted: np.ndarray
    proxy: TetProxy
    report: dict
    owner: int = -1
    """Its scene object (the own region of its rest proxy, :func:`~nerfedit_plugin.edit.ownership.own_region`)."""
    own: np.ndarray | None = None
    """Its frames ``(F,N',3)`` on that region."""


def _run_instance(
    inst: InstanceSpec,
    surface: SurfaceMesh,
    proxy: TetProxy,
    lift: LiftMethod,
    lift_config: LiftConfig,
    stage: Path,
    progress: Progress = no_progress,
) -> _Placed:
    """Deform (when the instance has an edit), lift, place one instance (each step told to ``progress``)."""
    report = {"name": inst.name, "deformer": None, "lift": None}
    frames, lifted, used = surface.vertices[None], proxy.vertices[None], proxy
    if inst.edit is not None:
        model, digest = inst.deformer.setup(), mesh_digest(surface)
        model.on_progress = labelled(progress, f"{inst.name} bind")
        model.bind(surface, inst.edit)
        model.on_progress = labelled(progress, f"{inst.name} deform")
        frames = checked_frames(model, model.deform(), surface, inst.edit, digest)
        lift_progress = labelled(progress, f"{inst.name} lift")
        lifter = Lift(proxy, surface, lift, lift_config, deformer=model, edit=inst.edit, progress=lift_progress)
        lifted, reports = lifter(frames)
        used = lifter.proxy
        report.update(
            deformer=type(model).__name__,
            lift=lift,
            proxy={"vertices": len(used.vertices), "tets": len(used.tets), "refinements": lifter.refinements},
            per_frame=[dataclasses.asdict(r) for r in reports],
        )
        report["warnings"] = [
            f"{inst.key}: {m}"
            for m in edit_warnings({**report, "surface": {"faces": len(surface.faces)}, "proxy": report["proxy"]})
        ]
        (stage / "objects" / inst.name).mkdir(parents=True, exist_ok=True)
        model.write_artifacts(stage / "objects" / inst.name)
    if inst.place is not None:
        pivot = surface.vertices.mean(0)
        frames = np.stack([inst.place.apply(f, 1.0, pivot) for f in frames])
        lifted = np.stack([inst.place.apply(f, 1.0, pivot) for f in lifted])
    return _Placed(inst, np.asarray(frames, dtype=np.float64), np.asarray(lifted, dtype=np.float64), used, report)


def _own_regions(
    name: str, runs: list[_Placed], removed: TetProxy | None, surface: SurfaceMesh, others: SurfaceMesh, objects: list
) -> int:
    """Append one scene object ``name`` per distinct rest proxy of ``runs`` (a refined lift makes its own; a ``removed``
    object's built proxy too, when nothing carries it): its own region (:func:`own_region`), and set each run's
    ``owner`` and ``own`` frames. → the index of the region the original leaves (the removed proxy's, else the
    first run's)."""
    groups: dict[int, list[_Placed]] = {}
    for run in runs:
        groups.setdefault(id(run.proxy), []).append(run)
    if removed is not None:
        groups.setdefault(id(removed), [])
    index = {}
    for key, members in groups.items():
        proxy = members[0].proxy if members else removed
        stacked = np.concatenate([m.lifted for m in members]) if members else proxy.vertices[None]
        vertices, tets, frames = own_region(proxy.vertices, proxy.tets, stacked, surface, others)
        index[key] = len(objects)
        objects.append(SceneObject(name, vertices, tets))
        for m, own in zip(members, np.split(frames, np.cumsum([len(m.lifted) for m in members])[:-1])):
            m.owner, m.own = index[key], own
            m.report["own_tets"] = len(tets)
    return index[id(removed)] if removed is not None else runs[0].owner


def _overlaps(placed: list[_Placed], objects: list[SceneObject]) -> list[dict]:
    """Per pair of instances whose deformed own regions overlap: how many of the later one's surface vertices (last
    frame) lie in the earlier one's (resolved in favour of the earlier, as rendered)."""
    found = []
    for i, a in enumerate(placed):
        low, high, locator = a.own[-1].min(0), a.own[-1].max(0), None
        for b in placed[i + 1 :]:
            points = b.surface[-1]
            if not np.any(np.all((points >= low) & (points <= high), 1)):
                continue
            if locator is None:
                locator = TetLocator(a.own[-1], objects[a.owner].tets, dtype=torch.float64)
            count = int((locator.member(torch.as_tensor(points)) >= 0).sum())
            if count:
                found.append({"first": a.spec.name, "second": b.spec.name, "vertices": count})
    return found


def _scene_frames(
    mesh: SurfaceMesh,
    selected: list[np.ndarray],
    surfaces: list[SurfaceMesh],
    spec: ObjectsSpec,
    placed: list[list[_Placed]],
    n: int,
):
    """The edited scene's surface per frame: unselected geometry as it is, each object's original in its place
    (dropped when removed), copies appended (faces and colours of their object's ``surfaces`` entry). Faces joining
    an original to anything else (an object picked from a mesh that runs on into the floor) are dropped, in every
    frame, where a frame stretches one of their edges to more than twice its rest length: they would span the move."""
    keep = np.ones(mesh.n_vertices, dtype=bool)
    for obj, idx in zip(spec.objects, selected):
        keep[idx] = not obj.removed
    base, index = mesh.submesh(keep)
    owner, posed = np.full(base.n_vertices, -1), [base.vertices.copy() for _ in range(n)]
    for o, (obj, idx, instances) in enumerate(zip(spec.objects, selected, placed)):
        if not obj.removed:
            owner[index[idx]] = o
            for f, positions in enumerate(posed):
                positions[index[idx]] = instances[0].surface[min(f, len(instances[0].surface) - 1)]
    corners = owner[base.faces]
    joining = np.flatnonzero((corners != corners[:, :1]).any(1))
    tri, turn = base.faces[joining], base.faces[joining][:, [1, 2, 0]]
    length = np.linalg.norm(base.vertices[tri] - base.vertices[turn], axis=2)
    stretched = np.zeros(len(joining), dtype=bool)
    for positions in posed:
        stretched |= (np.linalg.norm(positions[tri] - positions[turn], axis=2) > 2.0 * length + 1e-12).any(1)
    faces = np.delete(base.faces, joining[stretched], axis=0)
    meshes = []
    for f, positions in enumerate(posed):
        vertices, pieces, colors = [positions], [faces], [base.vertex_colors]
        offset = len(base.vertices)
        for obj, part, instances in zip(spec.objects, surfaces, placed):
            for inst in instances if obj.removed else instances[1:]:  # copies; an original is placed in positions
                frame = inst.surface[min(f, len(inst.surface) - 1)]
                vertices.append(frame)
                pieces.append(part.faces + offset)
                colors.append(part.vertex_colors)
                offset += len(frame)
        colored = all(c is not None for c in colors)
        meshes.append(
            SurfaceMesh(np.concatenate(vertices), np.concatenate(pieces), np.concatenate(colors) if colored else None)
        )
    return meshes


def run_objects_edit(
    mesh: SurfaceMesh | str | os.PathLike,
    default_deformer: DeformerConfig,
    edit: str | os.PathLike,
    out: str | os.PathLike,
    *,
    lift: LiftMethod = "tet-arap",
    lift_config: LiftConfig | None = None,
    proxy_config: ProxyConfig | None = None,
    camera_distance: float | None = None,
    source_to_world: np.ndarray | None = None,
    cache_dir: Path,
    proxy_from: str | os.PathLike | None = None,
    base=None,
    overwrite: bool = False,
    record: dict | None = None,
    on_stage: Callable[[str], None] | None = None,
    on_progress: ProgressListener | None = None,
) -> tuple[Path, dict]:
    """Run a scene edit (module docstring) end to end → ``(out, report)``. Writes ``deformation.npz`` (format 2),
    ``deformed_mesh.ply`` (the whole edited scene; sequences ``deformed_mesh_0000.ply`` …), the spec, ``config.yml``,
    ``report.json``, each object's proxy as built (``objects/<object>/proxy.npz``) and each deformer's artifacts under
    ``objects/<instance>/``. ``proxy_from`` (an earlier scene edit's folder) reuses its objects' proxies, each
    checked against its recorded key (:func:`~nerfedit_plugin.edit.proxy.stored_proxy`). ``base``: as
    :func:`~nerfedit_plugin.pipeline.edit.run_edit`'s (a :class:`~nerfedit_plugin.pipeline.edit.Base`); so are
    ``on_stage`` and ``on_progress`` (stages ``proxy NAME``, ``edit NAME``, ``own NAME`` per object)."""
    lift_config = LiftConfig() if lift_config is None else lift_config
    proxy_config = ProxyConfig() if proxy_config is None else proxy_config
    clock = Stopwatch(on_stage, on_progress=on_progress)
    with clock.stage("load"):
        rest = mesh if isinstance(mesh, SurfaceMesh) else SurfaceMesh.load(mesh)
        spec = load_objects_spec(edit, default_deformer, source_to_world)
        selected = spec.resolve(rest)
        stored = _stored_keys(Path(proxy_from)) if proxy_from is not None else None
    objects, instances, placed, reports, patches, surfaces = [], [], [], [], [], []
    with atomic_dir(out, overwrite=overwrite) as stage:
        for obj, idx in zip(spec.objects, selected):
            mask = np.zeros(rest.n_vertices, dtype=bool)
            mask[idx] = True
            surface, others = rest.submesh(mask)[0], rest.submesh(~mask)[0]
            surfaces.append(surface)
            with clock.stage(f"proxy {obj.name}"):
                key = proxy_cache_key(surface, proxy_config, camera_distance)
                if stored is not None:
                    where = f"--proxy-from {proxy_from}: object {obj.name!r}"
                    if obj.name not in stored:
                        raise NerfEditError(f"{where}: that scene edit has no such object")
                    file = Path(proxy_from) / "objects" / obj.name / "proxy.npz"
                    proxy = stored_proxy(file, stored[obj.name], surface, proxy_config, camera_distance, where)
                    cached = True
                else:
                    proxy, cached = cached_proxy(surface, proxy_config, cache_dir, camera_distance, clock.progress)
                (stage / "objects" / obj.name).mkdir(parents=True, exist_ok=True)
                proxy.save(stage / "objects" / obj.name / "proxy.npz")
            with clock.stage(f"edit {obj.name}"):
                runs = [
                    _run_instance(inst, surface, proxy, lift, lift_config, stage, clock.progress)
                    for inst in obj.instances
                ]
            with clock.stage(f"own {obj.name}"):
                left = _own_regions(obj.name, runs, proxy if obj.removed else None, surface, others, objects)
            originals = [not obj.removed] + [False] * (len(runs) - 1)  # copies read their region, vacate nothing
            instances += [Instance(r.spec.name, r.owner, r.own, vacates) for r, vacates in zip(runs, originals)]
            fill = None
            if obj.vacated == "fill" and obj.leaves:
                rest_patch, tets, slab = fill_patch(rest, objects[left].rest_vertices, surface.bbox_diagonal)
                patches.append((SceneObject(f"{obj.name}~fill", rest_patch, tets), slab))
                fill = {"instance": f"{obj.name}~fill", "vertices": len(rest_patch), "tets": len(tets)}
            placed.append(runs)
            reports.append(
                {
                    "name": obj.name,
                    "surface": {"vertices": surface.n_vertices, "faces": len(surface.faces)},
                    "proxy": {"vertices": len(proxy.vertices), "tets": len(proxy.tets), "cached": cached, "key": key},
                    "removed": obj.removed,
                    "vacated": obj.vacated,
                    "fill": fill,
                    "instances": [r.report for r in runs],
                }
            )
        counts = {len(p.surface) for runs in placed for p in runs} - {1}
        if len(counts) > 1:
            raise NerfEditError(f"{spec.source}: objects' edits have different frame counts {sorted(counts)}")
        n_frames = max(counts, default=1)
        for patch, slab in patches:  # after every object: moved objects show where they are
            instances.append(Instance(patch.name, len(objects), slab[None], vacates=False))
            objects.append(patch)
        with clock.stage("write"):
            deformation = SceneDeformation([Stage(objects, instances)])
            deformation.save(stage / "deformation.npz")
            if base is not None:
                base.chain(stage / "deformation.npz")
            flat = [p for runs in placed for p in runs]
            overlaps = _overlaps(flat, objects)
            scenes = _scene_frames(rest, selected, surfaces, spec, placed, n_frames)
            names = ["deformed_mesh.ply"] if n_frames == 1 else [f"deformed_mesh_{i:04d}.ply" for i in range(n_frames)]
            for name, scene in zip(names, scenes):
                scene.save(stage / name)
            keys = {k: v for obj in spec.objects for i in obj.instances if i.edit for k, v in i.edit.file_keys.items()}
            copy_spec_file(edit, stage, keys)
            write_config(
                stage / "config.yml", record if record is not None else {"deformer": default_deformer, "lift": lift}
            )
        found = [m for r in reports for i in r["instances"] for m in i.get("warnings", [])]
        found += [
            f"instances {o['first']!r} and {o['second']!r} overlap ({o['vertices']} surface vertices of the second lie "
            f"in the first's proxy): the first is rendered there"
            for o in overlaps
        ]
        report = {
            "scene": True,
            "frames": n_frames,
            "objects": reports,
            "overlaps": overlaps,
            "base": None if base is None else {"folder": str(base.folder.resolve()), "frame": base.frame},
            "timings_s": clock.seconds,
            "peak_rss_mb": peak_rss_mb(),
            "warnings": found,
        }
        (stage / "report.json").write_text(json.dumps(to_plain(report), indent=2))
    for message in found:
        warnings.warn(message, stacklevel=2)
    return Path(out), report


def _stored_keys(folder: Path) -> dict[str, object]:
    """object name → proxy key, as the scene edit at ``folder`` recorded them in its report.json."""
    file = folder / "report.json"
    try:
        report = json.loads(file.read_text())
        return {o["name"]: o["proxy"].get("key") for o in report["objects"]}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        raise NerfEditError(f"--proxy-from {folder}: {file} records no scene edit's objects") from None
