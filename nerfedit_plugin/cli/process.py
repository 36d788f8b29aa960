"""``nerfedit process``: a video or a folder of photos into a COLMAP workspace (frames + structure from motion)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from nerfedit_plugin.cli.common import Command, console
from nerfedit_plugin.errors import check_option


@dataclasses.dataclass
class ProcessArgs:
    """Turn a video or photos into a capture that `nerfedit train --data` reads: frames, then COLMAP (pycolmap).

    Like nerfstudio's `ns-process-data video`: evenly spaced frames written as OUT/images/*.png, then SIFT features,
    exhaustive matching and incremental mapping into OUT/sparse/0. The folder is written atomically."""

    out: Path
    """Capture folder to write (a COLMAP workspace)."""
    video: Path | None = None
    """Video file (MP4, MOV, …, anything ffmpeg reads)."""
    images: Path | None = None
    """Folder of photos instead of a video (PNG, JPEG, TIFF, BMP; sorted by name)."""
    frames: int = 60
    """Frames taken from the video, evenly spaced (all of them when it has fewer)."""
    max_size: int | None = 512
    """Downsize every image so that its longest side is at most this many pixels (None: keep the size)."""
    camera_model: Literal["SIMPLE_RADIAL", "OPENCV", "SIMPLE_PINHOLE", "PINHOLE", "RADIAL"] = "SIMPLE_RADIAL"
    """COLMAP camera model of the one camera shared by all images (its distortion is undone when training)."""
    overwrite: bool = False
    """Replace an existing capture folder."""

    def __post_init__(self) -> None:
        check_option(self, "frames", self.frames, self.frames >= 3, "an integer >= 3")
        if self.max_size is not None:
            check_option(self, "max_size", self.max_size, self.max_size >= 16, "an integer >= 16")


def process(args: ProcessArgs) -> None:
    from nerfedit_plugin.data.video import process_capture

    out, count, registered = process_capture(
        args.out,
        video=args.video,
        images=args.images,
        frames=args.frames,
        max_size=args.max_size,
        camera_model=args.camera_model,
        overwrite=args.overwrite,
    )
    console.print(f"capture → {out}: {registered} of {count} images registered (`nerfedit train --data {out}`)")


COMMAND = Command("process", ProcessArgs, process)
