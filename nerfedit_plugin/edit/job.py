"""The edit job: rest mesh + deformer + edit spec → deformed meshes, lifted proxy, ``deformation.npz``, report.

Output folder (written atomically: staged beside the target, renamed on success):
``config.yml``, a copy of the spec, ``deformed_mesh.ply`` (or ``deformed_mesh_0000.ply`` … for sequences),
``deformation.npz``, ``report.json`` and whatever the deformer's optional ``write_artifacts(out_dir)`` writes.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.config import to_plain, write_config
from nerfedit_plugin.edit.deformer import DeformerConfig
from nerfedit_plugin.edit.lift import Lift, LiftConfig, LiftMethod
from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy
from nerfedit_plugin.edit.spec import load_edit_spec
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_dir
from nerfedit_plugin.timing import Stopwatch


def default_cache_dir() -> Path:
    """``$NERFEDIT_CACHE`` or ``$XDG_CACHE_HOME/nerfedit/proxies`` (``~/.cache/nerfedit/proxies``)."""
    if "NERFEDIT_CACHE" in os.environ:
        return Path(os.environ["NERFEDIT_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "nerfedit" / "proxies"


@dataclasses.dataclass
class EditResult:
    out: Path
    report: dict


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
    cache_dir: str | os.PathLike | None = None,
    overwrite: bool = False,
    record: dict | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> EditResult:
    """Run one edit end to end; ``record`` is the full config written to ``config.yml``. ``lift_config`` and
    ``proxy_config`` default to ``LiftConfig()`` and ``ProxyConfig()``."""
    lift_config = LiftConfig() if lift_config is None else lift_config
    proxy_config = ProxyConfig() if proxy_config is None else proxy_config
    clock = Stopwatch(on_stage)
    with clock.stage("load"):
        rest = mesh if isinstance(mesh, SurfaceMesh) else SurfaceMesh.load(mesh)
        target_cls = deformer._target
        spec = load_edit_spec(edit, target_cls.spec_keys)
    with atomic_dir(out, overwrite=overwrite) as stage:
        with clock.stage("bind"):
            model = deformer.setup()
            model.bind(rest, spec)
        with clock.stage("deform"):
            frames = model.deform()
        with clock.stage("proxy"):
            proxy, cached = cached_proxy(rest, proxy_config, cache_dir or default_cache_dir(), camera_distance)
        with clock.stage("lift"):
            lifted, reports = Lift(proxy, rest, lift, lift_config, deformer=model, edit=spec)(frames)
        with clock.stage("write"):
            names = (
                ["deformed_mesh.ply"]
                if len(frames) == 1
                else [f"deformed_mesh_{i:04d}.ply" for i in range(len(frames))]
            )
            for name, positions in zip(names, frames):
                rest.with_vertices(positions).save(stage / name)
            DeformationField(proxy.vertices, proxy.tets, lifted).save(stage / "deformation.npz")
            shutil.copyfile(edit, stage / Path(edit).name)
            model.write_artifacts(stage)
            write_config(stage / "config.yml", record if record is not None else {"deformer": deformer, "lift": lift})
        report = {
            "deformer": type(model).__name__,
            "lift": lift,
            "frames": len(frames),
            "surface": {"vertices": rest.n_vertices, "faces": len(rest.faces)},
            "proxy": {"vertices": len(proxy.vertices), "tets": len(proxy.tets), "cached": cached},
            "timings_s": clock.seconds,
            "per_frame": [dataclasses.asdict(r) for r in reports],
        }
        (stage / "report.json").write_text(json.dumps(to_plain(report), indent=2))
    return EditResult(Path(out), report)
