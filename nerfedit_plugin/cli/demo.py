"""``nerfedit demo``: the whole pipeline on the built-in bunny scene, on the CPU."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, console, print_table, recorded


@dataclasses.dataclass
class DemoArgs:
    """The whole pipeline on the built-in bunny scene, on the CPU: generate, train, extract, ARAP edit, lift,
    render before/after views and a turntable GIF of the edited scene."""

    out: Path = Path("nerfedit-demo")
    """Output folder (dataset, run, edit, renders, summary.json, config.yml)."""
    preset: Literal["fast", "tiny"] = "fast"
    """fast: 100×100 images, 50 views, 150 s of training (minutes end to end on a CPU); tiny: seconds (tests)."""
    field: Literal["nerf", "neus", "splats"] = "neus"
    """Field backend to train (neus: an SDF, whose zero level set gives the cleanest mesh to edit; splats: 3D
    Gaussians, their mesh fused from their rendered depth)."""
    overwrite: bool = False
    """Replace an existing output folder (only after the new one is complete)."""


def demo(args: DemoArgs) -> None:
    from nerfedit_plugin.cli.progress import StageProgress
    from nerfedit_plugin.pipeline.demo import run_demo

    with StageProgress(console) as stages:
        summary = run_demo(
            args.out,
            preset=args.preset,
            field=args.field,
            overwrite=args.overwrite,
            progress=False,
            on_stage=stages.on_stage,
            on_progress=stages.on_progress,
            record=recorded(args),
        )
    print_table(
        "nerfedit demo",
        ("stage", "seconds"),
        [(stage, f"{seconds:.1f}") for stage, seconds in summary["seconds"].items()],
    )
    frame = summary["edit"]["per_frame"][0]
    before, after = summary["before"], summary["after"]
    console.print(
        f"trained {args.field} field on the test views: PSNR {before['psnr']:.2f} dB, "
        f"SSIM {before['ssim']:.3f}; edited renders vs the deformed source mesh: "
        f"PSNR {after['psnr']:.2f} dB, SSIM {after['ssim']:.3f}; "
        f"lift residual {frame['residual_max']:.1e} × bbox, {frame['inverted_tets']} inverted tets"
    )
    console.print(f"outputs in {summary['out']}", soft_wrap=True)
    print_table("files", ("what", "where"), summary["files"].items(), justify="left", overflow="fold")


COMMAND = Command("demo", DemoArgs, demo, records=True)
