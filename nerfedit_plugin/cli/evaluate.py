"""``nerfedit eval``: PSNR, SSIM and LPIPS of rendered images against ground truth."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from nerfedit_plugin.cli.common import Command, print_table
from nerfedit_plugin.errors import check_option


@dataclasses.dataclass
class EvalArgs:
    """Compare rendered images with ground truth: PSNR, SSIM, LPIPS (when its weights are installed offline) and the
    surface noise (RMS of the error's fine detail over the ground truth's opaque pixels)."""

    pred: Path
    """Folder of predicted PNGs."""
    gt: Path
    """Folder of ground-truth PNGs (RGBA composited over --background); every one needs a same-named prediction."""
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Background the ground truth's alpha is composited over."""
    json_out: Path | None = None
    """Also write the per-image and mean metrics to this JSON file."""

    def __post_init__(self) -> None:
        ok = all(0 <= c <= 1 for c in self.background)
        check_option(self, "background", self.background, ok, "3 numbers in [0, 1]")


def evaluate(args: EvalArgs) -> None:
    from nerfedit_plugin.pipeline.evaluate import evaluate_images

    result = evaluate_images(args.pred, args.gt, args.background, json_out=args.json_out)
    rows = list(result["images"].items()) + [("mean", result["mean"])]
    print_table(
        f"nerfedit eval: {args.pred} vs {args.gt}",
        ("image", "PSNR (dB)", "SSIM", "LPIPS", "noise"),
        [
            (
                name,
                f"{m['psnr']:.2f}",
                f"{m['ssim']:.4f}",
                *("—" if m[k] is None else f"{m[k]:.4f}" for k in ("lpips", "noise")),
            )
            for name, m in rows
        ],
    )


COMMAND = Command("eval", EvalArgs, evaluate)
