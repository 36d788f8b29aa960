"""``nerfedit edit``: deform a mesh with a deformer plugin and lift the deformation into a tet proxy."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, console, print_table, recorded
from nerfedit_plugin.cli.progress import StageProgress
from nerfedit_plugin.edit.lift import LiftConfig, LiftMethod
from nerfedit_plugin.edit.proxy import ProxyConfig
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.registry import DEFORMERS


@dataclasses.dataclass
class EditArgs:
    """Deform a mesh with a deformer plugin and lift the deformation into a tet proxy (deformation.npz)."""

    edit: Path
    """Edit spec (JSON or YAML); its format: docs/usage.md, examples: configs/ (both in the nerfedit source tree)."""
    out: Path
    """Output folder (must not exist or be empty unless --overwrite)."""
    mesh: str | None = None
    """Rest surface mesh (PLY/OBJ/OFF/GLB), or sample:bunny / sample:cow / sample:bone / sample:airplane; default:
    the run's mesh (--run)."""
    run: Path | None = None
    """A trained run (`nerfedit train`): its mesh.ply is edited and its cameras set the cage offset."""
    field: str | None = None
    """Field backend of --run (checked against the run); with --render-cameras the edit is rendered through it."""
    render_cameras: Path | None = None
    """With --run: render the edited field from these cameras (transforms JSON) into OUT/renders."""
    deformer: str = "arap"
    """Deformer plugin (entry point group nerfedit.deformers; listed above, and by `nerfedit plugins`)."""
    lift: LiftMethod = "tet-arap"
    """How the surface deformation is carried into the tet proxy."""
    lift_options: LiftConfig = dataclasses.field(default_factory=LiftConfig)
    proxy: ProxyConfig = dataclasses.field(default_factory=ProxyConfig)
    cache_dir: Path | None = None
    """Proxy cache folder (default $NERFEDIT_CACHE or ~/.cache/nerfedit/proxies)."""
    proxy_from: Path | None = None
    """Reuse the tet proxy of an earlier edit (its folder or deformation.npz) instead of meshing again, for the same
    mesh, --proxy options and camera distance. pytetwild is not deterministic: this reproduces an edit bit for bit."""
    camera_distance: float | None = None
    """Mean camera-to-object distance; sets the cage offset (5% of it). Default: from the run's cameras."""
    base: Path | None = None
    """Edit the result of an earlier edit (its folder or deformation.npz): its deformed mesh is the rest, and
    OUT/deformation.npz chains both deformations (render it on the same run)."""
    base_frame: int | None = None
    """With --base: the frame of a sequence whose deformed mesh is the rest (default: its last)."""
    frame: Literal["world", "capture"] = "world"
    """capture (with --run): also write each deformed_mesh*.ply into OUT/capture/, in the capture's own coordinates
    (a COLMAP or nerfstudio capture's frame; see `nerfedit extract --frame capture`)."""
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""


def edit(args: EditArgs) -> None:
    from nerfedit_plugin.pipeline.edit import Base, export_to_capture, run_edit
    from nerfedit_plugin.pipeline.render import render_run
    from nerfedit_plugin.pipeline.run import open_run

    run = open_run(args.run) if args.run is not None else None
    if run is not None and args.field is not None and args.field != run.backend:
        raise NerfEditError(f"--field {args.field}: the run {run.path} holds a {run.backend!r} field")
    if run is None and (args.field is not None or args.render_cameras is not None):
        raise NerfEditError("--field and --render-cameras need --run RUN_DIR (the trained field to render)")
    if args.frame == "capture" and run is None:
        raise NerfEditError("--frame capture: needs --run RUN_DIR (the run records the capture's frame)")
    if args.base is None and args.base_frame is not None:
        raise NerfEditError("--base-frame: needs --base EDIT_DIR")
    base = Base.of(args.base, args.base_frame) if args.base is not None else None
    if base is not None and run is not None:
        base.check_run(run.path)
    if base is not None and args.mesh is not None:
        raise NerfEditError("--mesh and --base: the rest of an edit of an edit is the base's deformed mesh")
    if args.mesh is None and run is None and base is None:
        raise NerfEditError("give the mesh to edit: --mesh MESH.ply or --run RUN_DIR (its extracted mesh)")
    mesh = base.mesh() if base is not None else args.mesh if args.mesh is not None else run.mesh()
    distance = args.camera_distance if args.camera_distance is not None or run is None else run.camera_distance()
    record = dataclasses.replace(recorded(args), proxy_from=args.out.absolute())  # a re-run is the same edit
    with StageProgress(console) as progress:
        result = run_edit(
            mesh,
            args.deformer_options,
            args.edit,
            args.out,
            lift=args.lift,
            lift_config=args.lift_options,
            proxy_config=args.proxy,
            camera_distance=distance,
            source_to_world=None if run is None else run.source_transform(),
            cache_dir=args.cache_dir,
            proxy_from=args.proxy_from,
            base=base,
            overwrite=args.overwrite,
            record=record,
            on_stage=progress.on_stage,
            on_progress=progress.on_progress,
        )
    report = result.report
    if report.get("scene"):
        _print_scene(result.out, report)
    else:
        _print_single(result.out, report)
    if args.frame == "capture":
        for path in export_to_capture(run, result.out):
            console.print(f"capture frame → {path}")
    if args.render_cameras is not None:
        out = render_run(run, args.render_cameras, result.out / "deformation.npz", None, result.out / "renders", False)
        console.print(f"renders → {out}")


COLUMNS = ("residual max (×bbox)", "residual rms", "inverted tets", "folded faces", "iterations", "seconds")


def _frame_row(f: dict) -> tuple:
    return (
        f"{f['residual_max']:.2e}",
        f"{f['residual_rms']:.2e}",
        f["inverted_tets"],
        f["flipped_surface_faces"],
        f["iterations"],
        f"{f['seconds']:.2f}",
    )


def _print_single(out: Path, report: dict) -> None:
    print_table(
        f"nerfedit edit → {out}", ("frame", *COLUMNS), [(i, *_frame_row(f)) for i, f in enumerate(report["per_frame"])]
    )
    proxy = report["proxy"]
    timings = ", ".join(f"{k} {v:.2f}s" for k, v in report["timings_s"].items())
    console.print(
        f"proxy {proxy['vertices']} vertices / {proxy['tets']} tets"
        f"{' (refined from ' + str(proxy['built_tets']) + ')' if proxy['refinements'] else ''}"
        f"{' (cached)' if proxy['cached'] and not proxy['reused_from'] else ''}"
        f"{' (from ' + proxy['reused_from'] + ')' if proxy['reused_from'] else ''}; {timings}; "
        f"peak memory {report['peak_rss_mb']:.0f} MB"
    )


def _print_scene(out: Path, report: dict) -> None:
    """One row per instance and frame of a scene edit (instances without an edit: a placement, no lift)."""
    rows = []
    for obj in report["objects"]:
        for inst in obj["instances"]:
            frames = inst.get("per_frame") or [None]
            for i, f in enumerate(frames):
                rows.append((obj["name"], inst["name"], i, *(_frame_row(f) if f else ("placed",) + ("",) * 5)))
        if obj["removed"]:
            rows.append((obj["name"], "(removed)", "", *("",) * 6))
    print_table(f"nerfedit edit (scene) → {out}", ("object", "instance", "frame", *COLUMNS), rows)
    timings = ", ".join(f"{k} {v:.2f}s" for k, v in report["timings_s"].items())
    console.print(
        f"{len(report['objects'])} object(s), {len(report['overlaps'])} overlap(s); {timings}; "
        f"peak memory {report['peak_rss_mb']:.0f} MB"
    )


COMMAND = Command("edit", EditArgs, edit, plugin=("deformer", DEFORMERS, "arap"), records=True)
