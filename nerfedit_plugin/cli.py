"""``nerfedit`` command line (tyro). ``nerfedit SUBCOMMAND --help`` lists the options of each subcommand.

Plugins are chosen in a first pass over the arguments (``--deformer NAME``); the chosen plugin's config then
appears as the option group ``--deformer-options.*`` in the second, tyro-parsed pass.
User errors print one line and exit 2; ``--verbose`` shows the traceback.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Callable

import tyro
from rich.console import Console
from rich.table import Table

from .errors import NerfEditError
from .lift import LiftConfig, LiftMethod
from .proxy import ProxyConfig
from .registry import DEFORMERS, discover

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


@dataclasses.dataclass
class EditArgs:
    """Deform a mesh with a deformer plugin and lift the deformation into a tet proxy (deformation.npz)."""

    mesh: str
    """Rest surface mesh (PLY/OBJ/OFF/GLB), or sample:bunny / sample:cow / sample:bone / sample:airplane."""
    edit: Path
    """Edit spec (JSON or YAML), see configs/ for examples."""
    out: Path
    """Output folder (must not exist or be empty unless --overwrite)."""
    deformer: str = "arap"
    """Deformer plugin (entry point group nerfedit.deformers; `nerfedit plugins` lists them)."""
    lift: LiftMethod = "tet-arap"
    """How the surface deformation is carried into the tet proxy."""
    lift_options: LiftConfig = dataclasses.field(default_factory=LiftConfig)
    proxy: ProxyConfig = dataclasses.field(default_factory=ProxyConfig)
    cache_dir: Path | None = None
    """Proxy cache folder (default $NERFEDIT_CACHE or ~/.cache/nerfedit/proxies)."""
    camera_distance: float | None = None
    """Mean camera-to-object distance; sets the cage offset (5% of it) when given."""
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""
    verbose: bool = False
    """Show tracebacks for errors."""



def edit(argv: list[str]) -> None:
    from .edit import run_edit

    registry = discover()
    name = _option(argv, "deformer", "arap")
    config_cls = registry.config_class(DEFORMERS, name)

    fields = [("deformer_options", config_cls, dataclasses.field(default_factory=config_cls))]
    Args = dataclasses.make_dataclass("EditArgs", fields, bases=(EditArgs,))
    Args.__doc__ = EditArgs.__doc__
    args = tyro.cli(Args, args=argv, prog="nerfedit edit", config=TYRO_CONFIG)
    with console.status("editing") as status:
        result = run_edit(
            args.mesh,
            args.deformer_options,
            args.edit,
            args.out,
            lift=args.lift,
            lift_config=args.lift_options,
            proxy_config=args.proxy,
            camera_distance=args.camera_distance,
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


COMMANDS: dict[str, Callable[[list[str]], None]] = {"edit": edit, "plugins": plugins}


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
