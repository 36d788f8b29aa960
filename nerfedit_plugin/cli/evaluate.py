"""``nerfedit eval``: PSNR, SSIM and LPIPS of rendered images against ground truth."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from nerfedit_plugin.cli.common import Command, print_table
from nerfedit_plugin.errors import NerfEditError, check_option


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

    def __post_init__(self) -> None:
        ok = all(0 <= c <= 1 for c in self.background)
        check_option(self, "background", self.background, ok, "3 numbers in [0, 1]")


def image_folder(path: Path, option: str) -> Path:
    """The folder of PNGs ``path`` stands for: itself when it holds PNGs (e.g. a `nerfedit render` folder, whose
    config.yml is ignored), else a dataset's test images (`nerfedit generate --out`: the cameras `nerfedit render
    --cameras DATASET` renders). An animated render (frame_NNNN folders) is an error naming a frame folder."""
    from nerfedit_plugin.data.datasets import read_transforms

    if not path.is_dir() or any(path.glob("*.png")):
        return path
    frames = sorted(p for p in path.glob("frame_[0-9]*") if p.is_dir())
    if frames:
        raise NerfEditError(f"{option} {path}: an animated render; compare one frame, e.g. {option} {frames[0]}")
    try:
        folders = {p.parent for p in read_transforms(path, "test").image_paths}
    except NerfEditError:
        return path
    return folders.pop() if len(folders) == 1 else path


def evaluate(args: EvalArgs) -> None:
    from nerfedit_plugin.io.atomic import write_text
    from nerfedit_plugin.training.metrics import evaluate_folders

    result = evaluate_folders(image_folder(args.pred, "--pred"), image_folder(args.gt, "--gt"), args.background)
    rows = list(result["images"].items()) + [("mean", result["mean"])]
    print_table(
        f"nerfedit eval: {args.pred} vs {args.gt}",
        ("image", "PSNR (dB)", "SSIM", "LPIPS"),
        [
            (name, f"{m['psnr']:.2f}", f"{m['ssim']:.4f}", "—" if m["lpips"] is None else f"{m['lpips']:.4f}")
            for name, m in rows
        ],
    )
    if args.json_out is not None:
        write_text(args.json_out, json.dumps(_json_numbers(result), indent=2, allow_nan=False))


def _json_numbers(value):
    """``value`` with non-finite floats as None: JSON has no inf (the PSNR of identical images) or NaN."""
    if isinstance(value, dict):
        return {k: _json_numbers(v) for k, v in value.items()}
    return None if isinstance(value, float) and not math.isfinite(value) else value


COMMAND = Command("eval", EvalArgs, evaluate)
