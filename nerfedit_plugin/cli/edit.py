"""``nerfedit edit``: deform a mesh with a deformer plugin and lift the deformation into a tet proxy."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nerfedit_plugin.cli.common import Command, console, print_table, recorded
from nerfedit_plugin.edit.lift import LiftConfig, LiftMethod
from nerfedit_plugin.edit.proxy import ProxyConfig
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.registry import DEFORMERS


@dataclasses.dataclass
class EditArgs:
    """Deform a mesh with a deformer plugin and lift the deformation into a tet proxy (deformation.npz)."""

    edit: Path
    """Edit spec (JSON or YAML), see configs/ for examples."""
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
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""


def edit(args: EditArgs) -> None:
    from nerfedit_plugin.cli.render import render_run
    from nerfedit_plugin.edit.job import run_edit
    from nerfedit_plugin.io.run import open_run

    run = open_run(args.run) if args.run is not None else None
    if run is not None and args.field is not None and args.field != run.backend:
        raise NerfEditError(f"--field {args.field}: the run {run.path} holds a {run.backend!r} field")
    if run is None and (args.field is not None or args.render_cameras is not None):
        raise NerfEditError("--field and --render-cameras need --run RUN_DIR (the trained field to render)")
    if args.mesh is None and run is None:
        raise NerfEditError("give the mesh to edit: --mesh MESH.ply or --run RUN_DIR (its extracted mesh)")
    mesh = args.mesh if args.mesh is not None else run.mesh()
    distance = args.camera_distance if args.camera_distance is not None or run is None else run.camera_distance()
    with console.status("editing") as status:
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
            overwrite=args.overwrite,
            record=recorded(args),
            on_stage=lambda stage: status.update(f"[bold]{stage}[/]"),
        )
    report = result.report
    print_table(
        f"nerfedit edit → {result.out}",
        ("frame", "residual max (×bbox)", "residual rms", "inverted tets", "folded faces", "iterations", "seconds"),
        [
            (
                i,
                f"{f['residual_max']:.2e}",
                f"{f['residual_rms']:.2e}",
                f["inverted_tets"],
                f["flipped_surface_faces"],
                f["iterations"],
                f"{f['seconds']:.2f}",
            )
            for i, f in enumerate(report["per_frame"])
        ],
    )
    proxy = report["proxy"]
    timings = ", ".join(f"{k} {v:.2f}s" for k, v in report["timings_s"].items())
    console.print(
        f"proxy {proxy['vertices']} vertices / {proxy['tets']} tets"
        f"{' (refined from ' + str(proxy['built_tets']) + ')' if proxy['refinements'] else ''}"
        f"{' (cached)' if proxy['cached'] and not proxy['reused_from'] else ''}"
        f"{' (from ' + proxy['reused_from'] + ')' if proxy['reused_from'] else ''}; {timings}"
    )
    if args.render_cameras is not None:
        out = render_run(run, args.render_cameras, result.out / "deformation.npz", None, result.out / "renders", False)
        console.print(f"renders → {out}")


COMMAND = Command("edit", EditArgs, edit, plugin=("deformer", DEFORMERS, "arap"), records=True)
