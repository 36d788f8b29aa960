"""``nerfedit edit``: rest mesh + deformer + edit spec → deformed meshes, lifted proxy, ``deformation.npz``, report.

The edit folder (:class:`EditFolder`; written atomically: staged beside the target, renamed on success):
``config.yml``, a copy of the spec, ``deformed_mesh.ply`` (or ``deformed_mesh_0000.ply`` … for sequences),
``deformation.npz`` (the lifted proxy: refined where the lift needed it), ``proxy.npz`` (the proxy as built, for
``--proxy-from``, when the lift refined it), ``report.json`` and whatever the deformer's optional
``write_artifacts(out_dir)`` writes. A spec with ``objects`` is a scene edit (:mod:`~nerfedit_plugin.edit.objects`).
An edit of an earlier edit's result (``base``) saves the two deformations chained (format 2).
"""

from __future__ import annotations

import dataclasses
import json
import os
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.bending.scene_deformation import SceneDeformation
from nerfedit_plugin.config import to_plain, write_config
from nerfedit_plugin.edit.deformer import BindCache, DeformerConfig, checked_frames, mesh_digest
from nerfedit_plugin.edit.lift import Lift, LiftConfig, LiftMethod
from nerfedit_plugin.edit.objects import is_objects_spec, run_objects_edit
from nerfedit_plugin.edit.proxy import ProxyConfig, TetProxy, cached_proxy, proxy_cache_key, stored_proxy
from nerfedit_plugin.edit.spec import copy_spec_file, load_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_dir
from nerfedit_plugin.pipeline.extract import write_in_capture_frame
from nerfedit_plugin.pipeline.run import Run
from nerfedit_plugin.quality import edit_warnings
from nerfedit_plugin.timing import ProgressListener, Stopwatch, peak_rss_mb


def default_cache_dir() -> Path:
    """``$NERFEDIT_CACHE`` or ``$XDG_CACHE_HOME/nerfedit/proxies`` (``~/.cache/nerfedit/proxies``): the proxy cache,
    and the deformers' bind cache (:class:`~nerfedit_plugin.edit.deformer.BindCache`, ``bind-*.npz``)."""
    if "NERFEDIT_CACHE" in os.environ:
        return Path(os.environ["NERFEDIT_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "nerfedit" / "proxies"


def reuse_proxy(
    source: str | os.PathLike, mesh: SurfaceMesh, config: ProxyConfig, camera_distance: float | None = None
) -> TetProxy:
    """The tet proxy of an earlier edit (its folder or its ``deformation.npz``), for the same rest mesh and proxy
    settings (:func:`~nerfedit_plugin.edit.proxy.stored_proxy`): the proxy as built (the folder's ``proxy.npz``: the
    lift may have refined it since; folders without one, the rest tets of ``deformation.npz``). The folder's
    ``report.json`` records its proxy key; a folder without one is a :class:`NerfEditError`."""
    source = Path(source)
    path = source / "deformation.npz" if source.is_dir() else source
    if not source.exists():
        raise NerfEditError(f"--proxy-from {source}: no such edit folder or deformation.npz")
    report_path = path.parent / "report.json"
    try:
        recorded = json.loads(report_path.read_text())["proxy"]["key"]
    except (OSError, ValueError, KeyError, TypeError):
        raise NerfEditError(
            f"--proxy-from {source}: {report_path} records no proxy key (not an edit folder of this nerfedit)"
        ) from None
    file = path.parent / "proxy.npz" if (path.parent / "proxy.npz").is_file() else path
    return stored_proxy(file, recorded, mesh, config, camera_distance, f"--proxy-from {source}")


DEFORMATION, REPORT, CONFIG = "deformation.npz", "report.json", "config.yml"


@dataclasses.dataclass(frozen=True)
class EditFolder:
    """An edit folder (see the module docstring) and what its ``config.yml`` records of the command that made it."""

    path: Path
    record: dict

    @classmethod
    def open(cls, path: str | os.PathLike) -> EditFolder:
        """The edit folder at ``path``; a folder that is no edit folder (no ``config.yml`` or no
        ``deformation.npz``; a run folder) is a :class:`NerfEditError` naming it."""
        from nerfedit_plugin.config import read_config

        path = Path(path)
        if not (path / CONFIG).is_file():
            raise NerfEditError(f"{path}: not an edit folder (no {CONFIG}; make one with `nerfedit edit`)")
        if not (path / DEFORMATION).is_file():
            run_folder = (path / "field.pt").is_file()
            what = "a run folder: edit its field with --run" if run_folder else "make one with `nerfedit edit`"
            raise NerfEditError(f"{path}: not an edit folder (no {DEFORMATION}; {what})")
        return cls(path, read_config(path / CONFIG, "the config.yml of `nerfedit edit`"))

    @property
    def deformation(self) -> Path:
        return self.path / DEFORMATION

    @property
    def mesh(self) -> str | None:
        """The ``--mesh`` the edit was made from (None: made from a run, or not recorded)."""
        mesh = self.record.get("mesh")
        return mesh if isinstance(mesh, str) else None

    @property
    def run(self) -> Path | None:
        """The ``--run`` folder the edit was made on (None: made from a mesh, or not recorded)."""
        run = self.record.get("run")
        return Path(run) if isinstance(run, str) else None

    def deformed_meshes(self) -> list[Path]:
        """``deformed_mesh.ply``, or ``deformed_mesh_0000.ply`` … of a sequence, in frame order."""
        return sorted(self.path.glob("deformed_mesh*.ply"))


@dataclasses.dataclass
class EditResult:
    out: Path
    report: dict


@dataclasses.dataclass(frozen=True)
class Base:
    """An earlier edit whose result is edited again: its folder and the frame whose deformed mesh is the new rest."""

    folder: Path
    frame: int

    @classmethod
    def of(cls, folder: str | os.PathLike, frame: int | None = None) -> Base:
        """``folder`` (an edit folder, or its ``deformation.npz``) at ``frame`` (default its last); a missing path,
        a folder without ``deformation.npz`` or a frame out of range is a :class:`NerfEditError`."""
        folder = Path(folder)
        if folder.is_file() and folder.name == DEFORMATION:
            folder = folder.parent
        if not folder.exists():
            raise NerfEditError(f"--base {folder}: no such edit folder")
        if not (folder / DEFORMATION).is_file():
            raise NerfEditError(f"--base {folder}: not an edit folder (no {DEFORMATION})")
        n = len(sorted(folder.glob("deformed_mesh*.ply")))
        frame = n - 1 if frame is None else frame
        if not 0 <= frame < n:
            raise NerfEditError(f"--base-frame {frame}: out of range for the {n} frame(s) of {folder}")
        return cls(folder, frame)

    def check_run(self, run: str | os.PathLike) -> None:
        """Raise :class:`NerfEditError` when the base edit was made on something other than the run folder ``run``:
        a chained deformation bends only the field of the run it was made on. What the base's ``config.yml`` records
        decides, following its own ``--base`` back: another run that still exists, or a mesh, is an error; a run no
        longer there (the folders moved) or no record (the demo's, the Python API's) is taken on trust."""
        folder, seen = self.folder, set()
        while folder is not None and folder.resolve() not in seen:
            seen.add(folder.resolve())
            edit = EditFolder.open(folder)
            if edit.run is not None:
                if edit.run.is_dir() and edit.run.resolve() != Path(run).resolve():
                    raise NerfEditError(f"--base {self.folder}: an edit of the run {edit.run}, not of --run {run}")
                return
            if edit.mesh is not None:
                raise NerfEditError(f"--base {self.folder}: an edit of the mesh {edit.mesh}, not of --run {run}")
            base = edit.record.get("base")
            folder = Path(base) if isinstance(base, str) else None

    def mesh(self) -> SurfaceMesh:
        """The base edit's deformed mesh of :attr:`frame`: the rest of the new edit."""
        return SurfaceMesh.load(sorted(self.folder.glob("deformed_mesh*.ply"))[self.frame])

    def chain(self, path: Path) -> None:
        """Rewrite the new edit's ``deformation.npz`` at ``path`` as the base's deformation followed by it."""
        base = SceneDeformation.load(self.folder / "deformation.npz")
        base.chained(SceneDeformation.load(path), self.frame).save(path)


def run_edit(
    mesh: SurfaceMesh | str | os.PathLike,
    deformer: DeformerConfig,
    edit: str | os.PathLike,
    out: str | os.PathLike,
    *,
    lift: LiftMethod = "tet-arap",
    lift_config: LiftConfig | None = None,
    proxy_config: ProxyConfig | None = None,
    camera_distance: float | None = None,
    source_to_world: np.ndarray | None = None,
    cache_dir: str | os.PathLike | None = None,
    proxy_from: str | os.PathLike | None = None,
    base: Base | None = None,
    overwrite: bool = False,
    record: dict | None = None,
    on_stage: Callable[[str], None] | None = None,
    on_progress: ProgressListener | None = None,
) -> EditResult:
    """Run one edit end to end; ``record`` is the full config written to ``config.yml``. ``lift_config`` and
    ``proxy_config`` default to ``LiftConfig()`` and ``ProxyConfig()``. ``proxy_from`` (an earlier edit's folder or
    ``deformation.npz``) reuses its proxy instead of building one (:func:`reuse_proxy`). ``source_to_world`` (4,4):
    where a spec with ``frame: source`` is mapped from (a run's
    :meth:`~nerfedit_plugin.pipeline.run.Run.source_transform`; None: the identity, the mesh is its own source).
    ``base``: the edit whose deformed mesh ``mesh`` is; the saved deformation chains onto it. A spec with ``objects``
    runs :func:`~nerfedit_plugin.edit.objects.run_objects_edit`.

    ``on_stage(name)`` is called as each stage starts (load, bind, deform, proxy, lift, write) and
    ``on_progress(stage, done, total, detail)`` with the stage's :class:`~nerfedit_plugin.timing.Progress` reports
    (the deformer's :attr:`~nerfedit_plugin.edit.deformer.Deformer.on_progress`, the proxy build's steps, the
    lift's frames and iterations)."""
    if is_objects_spec(edit):
        return EditResult(
            *run_objects_edit(
                mesh,
                deformer,
                edit,
                out,
                lift=lift,
                lift_config=lift_config,
                proxy_config=proxy_config,
                camera_distance=camera_distance,
                source_to_world=source_to_world,
                cache_dir=Path(cache_dir or default_cache_dir()),
                proxy_from=proxy_from,
                base=base,
                overwrite=overwrite,
                record=record,
                on_stage=on_stage,
                on_progress=on_progress,
            )
        )
    lift_config = LiftConfig() if lift_config is None else lift_config
    proxy_config = ProxyConfig() if proxy_config is None else proxy_config
    clock = Stopwatch(on_stage, on_progress=on_progress)
    with clock.stage("load"):
        rest = mesh if isinstance(mesh, SurfaceMesh) else SurfaceMesh.load(mesh)
        target_cls = deformer._target
        spec = load_edit_spec(edit, target_cls.spec_keys)
        spec = spec.in_world(np.eye(4) if source_to_world is None else source_to_world)
    with atomic_dir(out, overwrite=overwrite) as stage:
        with clock.stage("bind"):
            model, digest = deformer.setup(), mesh_digest(rest)
            model.on_progress = clock.progress
            model.bind_cache = BindCache(cache_dir or default_cache_dir(), digest)
            model.bind(rest, spec)
        with clock.stage("deform"):
            frames = checked_frames(model, model.deform(), rest, spec, digest)
        with clock.stage("proxy"):
            key = proxy_cache_key(rest, proxy_config, camera_distance)
            if proxy_from is not None:
                proxy, cached = reuse_proxy(proxy_from, rest, proxy_config, camera_distance), True
            else:
                proxy, cached = cached_proxy(
                    rest, proxy_config, cache_dir or default_cache_dir(), camera_distance, progress=clock.progress
                )
        with clock.stage("lift"):
            lifter = Lift(proxy, rest, lift, lift_config, deformer=model, edit=spec, progress=clock.progress)
            lifted, reports = lifter(frames)
        with clock.stage("write"):
            names = (
                ["deformed_mesh.ply"]
                if len(frames) == 1
                else [f"deformed_mesh_{i:04d}.ply" for i in range(len(frames))]
            )
            for name, positions in zip(names, frames):
                rest.with_vertices(positions).save(stage / name)
            DeformationField(lifter.proxy.vertices, lifter.proxy.tets, lifted).save(stage / "deformation.npz")
            if base is not None:
                base.chain(stage / "deformation.npz")
            if lifter.refinements:  # else deformation.npz holds the proxy as built
                proxy.save(stage / "proxy.npz")
            copy_spec_file(edit, stage, spec.file_keys)
            model.write_artifacts(stage)
            write_config(stage / "config.yml", record if record is not None else {"deformer": deformer, "lift": lift})
        report = {
            "deformer": type(model).__name__,
            "lift": lift,
            "frames": len(frames),
            "surface": {"vertices": rest.n_vertices, "faces": len(rest.faces)},
            "proxy": {
                "vertices": len(lifter.proxy.vertices),
                "tets": len(lifter.proxy.tets),
                "built_tets": len(proxy.tets),
                "refinements": lifter.refinements,
                "cached": cached,
                "key": key,
                "reused_from": None if proxy_from is None else str(Path(proxy_from).resolve()),
            },
            "timings_s": clock.seconds,
            "peak_rss_mb": peak_rss_mb(),
            "per_frame": [dataclasses.asdict(r) for r in reports],
            "deformer_report": model.report(),
            "base": None if base is None else {"folder": str(base.folder.resolve()), "frame": base.frame},
        }
        report["warnings"] = edit_warnings(report)
        (stage / "report.json").write_text(json.dumps(to_plain(report), indent=2))
    for message in report["warnings"]:
        warnings.warn(message, stacklevel=2)
    return EditResult(Path(out), report)


def export_to_capture(run: Run, folder: Path) -> list[Path]:
    """Each ``deformed_mesh*.ply`` of an edit ``folder`` mapped by the inverse of the run's source transform (the
    capture's frame) into ``folder/capture/`` under the same name, each written atomically."""
    (folder / "capture").mkdir(exist_ok=True)
    return [
        write_in_capture_frame(run, SurfaceMesh.load(path), folder / "capture" / path.name)
        for path in sorted(folder.glob("deformed_mesh*.ply"))
    ]
