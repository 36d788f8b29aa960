"""``nerfedit`` command line (tyro). ``nerfedit SUBCOMMAND --help`` lists the options of each subcommand.

Plugins are chosen in a first pass over the arguments (``--deformer NAME``); the chosen plugin's config then
appears as the option group ``--deformer-options.*`` in the second, tyro-parsed pass.
User errors print one line and exit 2; ``--verbose`` shows the traceback.
"""

from __future__ import annotations

import dataclasses
import json
import sys
from pathlib import Path
from typing import Callable, Literal

import tyro
from rich.console import Console
from rich.table import Table

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.edit.lift import LiftConfig, LiftMethod
from nerfedit_plugin.edit.proxy import ProxyConfig
from nerfedit_plugin.registry import DEFORMERS, FIELDS, discover

console = Console(stderr=True)
TYRO_CONFIG = (tyro.conf.SuppressFixed,)


def _option(argv: list[str], name: str, default: str) -> str:
    """Value of ``--name VALUE`` / ``--name=VALUE`` in ``argv`` (first pass of the two-pass parse)."""
    for i, arg in enumerate(argv):
        if arg == f"--{name}" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(f"--{name}="):
            return arg.split("=", 1)[1]
    return default


def _plugin_args(argv: list[str], base: type, option: str, group: str, default: str):
    """The args dataclass ``base`` extended by ``--{option}-options.*``: the config of the plugin named by
    ``--{option}`` (first pass)."""
    config_cls = discover().config_class(group, _option(argv, option, default))
    fields = [(f"{option}_options", config_cls, dataclasses.field(default_factory=config_cls))]
    args = dataclasses.make_dataclass(base.__name__, fields, bases=(base,))
    args.__doc__ = base.__doc__
    return args


@dataclasses.dataclass
class EditArgs:
    """Deform a mesh with a deformer plugin and lift the deformation into a tet proxy (deformation.npz)."""

    edit: Path
    """Edit spec (JSON or YAML), see configs/ for examples."""
    out: Path
    """Output folder (must not exist or be empty unless --overwrite)."""
    mesh: str | None = None
    """Rest surface mesh (PLY/OBJ/OFF/GLB), or sample:bunny / sample:cow / sample:bone / sample:airplane; default:
    the run's extracted mesh (--run)."""
    run: Path | None = None
    """A trained run (`nerfedit train`): its mesh.ply is edited and its cameras set the cage offset."""
    field: str | None = None
    """Field backend of --run (checked against the run); with --render-cameras the edit is rendered through it."""
    render_cameras: Path | None = None
    """With --run: render the edited field from these cameras (transforms JSON) into OUT/renders."""
    deformer: str = "arap"
    """Deformer plugin (entry point group nerfedit.deformers; `nerfedit plugins` lists them)."""
    lift: LiftMethod = "tet-arap"
    """How the surface deformation is carried into the tet proxy."""
    lift_options: LiftConfig = dataclasses.field(default_factory=LiftConfig)
    proxy: ProxyConfig = dataclasses.field(default_factory=ProxyConfig)
    cache_dir: Path | None = None
    """Proxy cache folder (default $NERFEDIT_CACHE or ~/.cache/nerfedit/proxies)."""
    camera_distance: float | None = None
    """Mean camera-to-object distance; sets the cage offset (5% of it). Default: from the run's cameras."""
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""
    verbose: bool = False
    """Show tracebacks for errors."""


def edit(argv: list[str]) -> None:
    from nerfedit_plugin.edit.job import run_edit
    from nerfedit_plugin.io.run import open_run

    Args = _plugin_args(argv, EditArgs, "deformer", DEFORMERS, "arap")
    args = tyro.cli(Args, args=argv, prog="nerfedit edit", config=TYRO_CONFIG)
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
            cache_dir=args.cache_dir,
            overwrite=args.overwrite,
            record=args,
            on_stage=lambda stage: status.update(f"[bold]{stage}[/]"),
        )
    report = result.report
    table = Table(title=f"nerfedit edit → {result.out}")
    for column in ("frame", "residual max (×bbox)", "residual rms", "inverted tets", "folded faces", "iterations", "seconds"):
        table.add_column(column, justify="right")
    for i, frame in enumerate(report["per_frame"]):
        table.add_row(
            str(i), f"{frame['residual_max']:.2e}", f"{frame['residual_rms']:.2e}", str(frame["inverted_tets"]), str(frame["flipped_surface_faces"]),
            str(frame["iterations"]), f"{frame['seconds']:.2f}",
        )
    Console().print(table)
    proxy = report["proxy"]
    timings = ", ".join(f"{k} {v:.2f}s" for k, v in report["timings_s"].items())
    Console().print(f"proxy {proxy['vertices']} vertices / {proxy['tets']} tets{' (cached)' if proxy['cached'] else ''}; {timings}")
    if args.render_cameras is not None:
        out = _render(run, args.render_cameras, result.out / "deformation.npz", None, result.out / "renders", False)
        Console().print(f"renders → {out}")


@dataclasses.dataclass
class TrainArgs:
    """Train a field backend on a dataset (or, for the mesh field, load a vertex-coloured mesh) into a run folder."""

    data: Path
    """Dataset folder or transforms JSON (Blender or nerfstudio); a mesh file for --field mesh."""
    out: Path
    """Run folder to write (field.pt, config.yml, log.json)."""
    field: str = "nerf"
    """Field backend (entry point group nerfedit.fields; `nerfedit plugins` lists them)."""
    device: str | None = None
    """torch device (default: cuda when present, else cpu)."""
    overwrite: bool = False
    """Replace an existing run folder (only after the new one is complete)."""
    verbose: bool = False
    """Show tracebacks for errors."""


def train(argv: list[str]) -> None:
    from nerfedit_plugin.io.run import train_run

    Args = _plugin_args(argv, TrainArgs, "field", FIELDS, "nerf")
    args = tyro.cli(Args, args=argv, prog="nerfedit train", config=TYRO_CONFIG)
    run, log = train_run(args.field, args.field_options, args.data, args.out, overwrite=args.overwrite,
                         device=args.device, record=args)
    table = Table(title=f"nerfedit train → {run.path}")
    for column in ("field", "steps", "seconds", "held-out PSNR"):
        table.add_column(column, justify="right")
    evals = log.get("eval") or []
    table.add_row(run.backend, str(log.get("steps", 0)), f"{log.get('train_seconds', 0.0):.1f}",
                  f"{evals[-1][1]:.2f} dB" if evals else "—")
    Console().print(table)


@dataclasses.dataclass
class ExtractArgs:
    """Extract the run's surface mesh (marching cubes; the mesh itself for mesh fields) into RUN_DIR/mesh.ply."""

    run: Path
    """Run folder (`nerfedit train --out`)."""
    resolution: int = 256
    """Marching-cubes lattice points per axis over the scene box."""
    level: float | None = None
    """Density (nerf) or SDF (neus) level of the surface; default: the backend's."""
    largest_component: bool = True
    """Keep only the largest connected part (drops floaters, which no deformer handle would reach)."""
    overwrite: bool = False
    """Replace an existing mesh.ply."""
    verbose: bool = False
    """Show tracebacks for errors."""


def extract(argv: list[str]) -> None:
    from nerfedit_plugin.io.run import extract_mesh, open_run

    args = tyro.cli(ExtractArgs, args=argv, prog="nerfedit extract", config=TYRO_CONFIG)
    run = open_run(args.run)
    path = extract_mesh(run, args.resolution, args.level, overwrite=args.overwrite,
                        largest_component=args.largest_component)
    mesh = run.mesh()
    Console().print(f"{path}: {mesh.n_vertices} vertices, {len(mesh.faces)} faces")


@dataclasses.dataclass
class RenderArgs:
    """Render a run's field — edited when --deformation is given — from the cameras of a transforms file."""

    run: Path
    """Run folder (`nerfedit train --out`)."""
    cameras: Path
    """Transforms JSON (Blender or nerfstudio) or dataset folder (its test split) with the cameras to render."""
    out: Path
    """Image folder to write (one PNG per camera, named like the transforms file's frames)."""
    deformation: Path | None = None
    """deformation.npz of an edit (`nerfedit edit --out EDIT_DIR`); default: render the unedited field."""
    frame: int | None = None
    """Frame of an animated deformation (default: every frame, into OUT/frame_0000, ...)."""
    supersample: int = 1
    """Anti-aliasing: supersample × supersample rays per pixel, averaged."""
    overwrite: bool = False
    """Replace an existing image folder."""
    verbose: bool = False
    """Show tracebacks for errors."""


def _render(run, cameras: Path, deformation: Path | None, frame: int | None, out: Path, overwrite: bool,
            supersample: int = 1) -> Path:
    """Render ``run``'s field from a transforms file (bent by ``deformation``: one frame, or every frame into
    ``out/frame_NNNN``) into PNGs named like the file's frames."""
    from nerfedit_plugin.data.datasets import read_transforms
    from nerfedit_plugin.bending.deformation_field import DeformationField
    from nerfedit_plugin.render.views import default_render_config, render_views, write_images

    field = run.field()
    transforms = read_transforms(cameras, "test" if Path(cameras).is_dir() else None)
    names = [p.with_suffix(".png").name for p in transforms.image_paths]
    bent = DeformationField.load(deformation) if deformation is not None else None
    config = default_render_config(field)
    if bent is None or frame is not None or bent.n_frames == 1:
        images = render_views(field, transforms.cameras, config, deformation=bent, frame=frame or 0,
                              supersample=supersample)
        write_images(images, names, out, overwrite)
        return out
    from nerfedit_plugin.io.atomic import atomic_dir

    with atomic_dir(out, overwrite) as stage:
        for f in range(bent.n_frames):
            images = render_views(field, transforms.cameras, config, deformation=bent, frame=f,
                                  supersample=supersample)
            write_images(images, names, stage / f"frame_{f:04d}")
    return out


def render(argv: list[str]) -> None:
    from nerfedit_plugin.io.run import open_run

    args = tyro.cli(RenderArgs, args=argv, prog="nerfedit render", config=TYRO_CONFIG)
    out = _render(open_run(args.run), args.cameras, args.deformation, args.frame, args.out, args.overwrite,
                  args.supersample)
    Console().print(f"renders → {out}")


@dataclasses.dataclass
class EvalArgs:
    """Compare rendered images with ground truth: PSNR, SSIM and LPIPS (when its weights are installed offline)."""

    pred: Path
    """Folder of predicted PNGs."""
    gt: Path
    """Folder of ground-truth PNGs (RGBA composited over --background); every one needs a same-named prediction."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Background the ground truth's alpha is composited over."""
    json_out: Path | None = None
    """Also write the per-image and mean metrics to this JSON file."""
    verbose: bool = False
    """Show tracebacks for errors."""


def evaluate(argv: list[str]) -> None:
    from nerfedit_plugin.io.atomic import write_text
    from nerfedit_plugin.training.metrics import evaluate_folders

    args = tyro.cli(EvalArgs, args=argv, prog="nerfedit eval", config=TYRO_CONFIG)
    result = evaluate_folders(args.pred, args.gt, args.background)
    table = Table(title=f"nerfedit eval: {args.pred} vs {args.gt}")
    for column in ("image", "PSNR (dB)", "SSIM", "LPIPS"):
        table.add_column(column, justify="right")
    rows = list(result["images"].items()) + [("mean", result["mean"])]
    for name, m in rows:
        table.add_row(name, f"{m['psnr']:.2f}", f"{m['ssim']:.4f}", "—" if m["lpips"] is None else f"{m['lpips']:.4f}")
    Console().print(table)
    if args.json_out is not None:
        write_text(args.json_out, json.dumps(result, indent=2))


def generate(argv: list[str]) -> None:
    """Render a mesh into a Blender-format dataset (the synthetic scene generator)."""
    from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset

    config = tyro.cli(GenerateConfig, args=argv, prog="nerfedit generate", config=TYRO_CONFIG)
    Console().print(f"dataset → {generate_dataset(config)}")


@dataclasses.dataclass
class ViewArgs:
    """Show a mesh and an edit (deformed mesh, tet proxies, cages, handles) with Open3D; headless: --screenshot."""

    mesh: str | None = None
    """Rest mesh, or sample:NAME; default: the mesh the edit folder's config names."""
    edit: Path | None = None
    """Edit folder (`nerfedit edit --out`)."""
    frame: int = 0
    """Frame of an animated edit."""
    show: tuple[str, ...] | None = None
    """Layers: mesh, deformed, proxy, deformed-proxy, handles, and what the edit's deformer adds (cage); default:
    all but proxy."""
    screenshot: Path | None = None
    """Render offscreen into this PNG instead of opening a window (works without a display)."""
    width: int = 960
    """Screenshot width in pixels."""
    height: int = 540
    """Screenshot height in pixels."""
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    """World up direction of the view (samples: y; datasets of `nerfedit generate`: z)."""
    verbose: bool = False
    """Show tracebacks for errors."""


def view(argv: list[str]) -> None:
    import yaml

    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.viewer.layers import edit_geometries, screenshot, show

    args = tyro.cli(ViewArgs, args=argv, prog="nerfedit view", config=TYRO_CONFIG)
    mesh = args.mesh
    if mesh is None and args.edit is not None and (args.edit / "config.yml").is_file():
        mesh = (yaml.safe_load((args.edit / "config.yml").read_text()) or {}).get("mesh")
    if mesh is None:
        raise NerfEditError("view: give --mesh MESH (the edit folder's config names no mesh)")
    geometries = edit_geometries(SurfaceMesh.load(mesh), args.edit, args.frame, args.show)
    if args.screenshot is not None:
        Console().print(f"screenshot → {screenshot(geometries, args.screenshot, args.width, args.height, args.up)}")
    else:
        show(geometries)


@dataclasses.dataclass
class DemoArgs:
    """The whole pipeline on the built-in bunny scene, on the CPU: generate, train, extract, ARAP edit, lift,
    render before/after views and a turntable GIF of the edited scene."""

    out: Path = Path("nerfedit-demo")
    """Output folder (dataset, run, edit, renders, summary.json)."""
    preset: Literal["fast", "tiny"] = "fast"
    """fast: 100×100 images, 50 views, 150 s of training (≤ 5 min end to end on 2 cores); tiny: seconds (tests)."""
    field: Literal["nerf", "neus"] = "neus"
    """Field backend to train (neus: an SDF, whose zero level set gives the cleanest mesh to edit)."""
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""
    verbose: bool = False
    """Show tracebacks for errors."""


def demo(argv: list[str]) -> None:
    from nerfedit_plugin.demo import run_demo

    args = tyro.cli(DemoArgs, args=argv, prog="nerfedit demo", config=TYRO_CONFIG)
    with console.status("demo") as status:
        summary = run_demo(args.out, preset=args.preset, field=args.field, overwrite=args.overwrite,
                           progress=False, on_stage=lambda stage: status.update(f"[bold]demo: {stage}[/]"))
    table = Table(title="nerfedit demo")
    table.add_column("stage")
    table.add_column("seconds", justify="right")
    for stage, seconds in summary["seconds"].items():
        table.add_row(stage, f"{seconds:.1f}")
    Console().print(table)
    frame = summary["edit"]["per_frame"][0]
    before, after = summary["before"], summary["after"]
    Console().print(f"trained {args.field} field on the test views: PSNR {before['psnr']:.2f} dB, SSIM {before['ssim']:.3f}; "
                    f"edited renders vs the deformed source mesh: PSNR {after['psnr']:.2f} dB, SSIM {after['ssim']:.3f}; "
                    f"lift residual {frame['residual_max']:.1e} × bbox, {frame['inverted_tets']} inverted tets")
    Console().print(f"outputs in {summary['out']}", soft_wrap=True)
    files = Table(title="files")
    files.add_column("what")
    files.add_column("where", overflow="fold")
    for what, where in summary["files"].items():
        files.add_row(what, str(where))
    Console().print(files)


def plugins(argv: list[str]) -> None:
    """List the plugins found through entry points, and those skipped with the reason."""
    tyro.cli(lambda: None, args=argv, prog="nerfedit plugins", description=plugins.__doc__)
    registry = discover()
    table = Table(title="nerfedit plugins")
    for column in ("group", "name", "entry point", "distribution"):
        table.add_column(column)
    for group, found in registry.plugins.items():
        for plugin in found.values():
            table.add_row(group, plugin.name, plugin.target, plugin.distribution)
    Console().print(table)
    if registry.skipped:
        skipped = Table(title="skipped", style="yellow")
        for column in ("group", "name", "entry point", "reason"):
            skipped.add_column(column)
        for s in registry.skipped:
            skipped.add_row(s.group, s.name, s.target, s.reason)
        Console().print(skipped)


COMMANDS: dict[str, Callable[[list[str]], None]] = {
    "train": train, "extract": extract, "edit": edit, "render": render, "eval": evaluate, "view": view,
    "generate": generate, "demo": demo, "plugins": plugins,
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in COMMANDS:
        console.print("usage: nerfedit {" + ",".join(COMMANDS) + "} [--help]")
        return 0 if not argv or argv[0] in ("-h", "--help") else 2
    command, rest = argv[0], argv[1:]
    try:
        COMMANDS[command](rest)
    except NerfEditError as exc:
        if "--verbose" in rest:
            raise
        console.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
