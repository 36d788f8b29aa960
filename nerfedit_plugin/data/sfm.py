"""Structure from motion with pycolmap: images alone → a COLMAP workspace that :mod:`nerfedit_plugin.data.colmap`
reads (``nerfedit train --data WORKSPACE``).

The standard COLMAP pipeline on the CPU: SIFT features (one shared camera, ``camera_model``, the focal length
guessed from the image size and refined by bundle adjustment), exhaustive matching, incremental mapping. The
largest model becomes ``WORKSPACE/sparse/0``, written atomically; the feature database stays in the workspace.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from nerfedit_plugin.data.colmap import require_pycolmap
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.io.atomic import atomic_dir


def reconstruct(
    workspace: str | os.PathLike, camera_model: str = "SIMPLE_RADIAL", overwrite: bool = False
) -> tuple[Path, int]:
    """Run SIFT extraction, exhaustive matching and incremental mapping on ``workspace/images``; write the largest
    model to ``workspace/sparse/0``. Returns that folder and its number of registered images; no model at all is a
    :class:`NerfEditError`."""
    pycolmap = require_pycolmap()
    workspace = Path(workspace)
    images = workspace / "images"
    if not images.is_dir():
        raise NerfEditError(f"{workspace}: no images/ folder to reconstruct")
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = max(level, 1)  # warnings up: INFO is ~300 lines a run
    try:
        with atomic_dir(workspace / "sparse", overwrite) as stage, tempfile.TemporaryDirectory() as scratch:
            database = Path(scratch) / "database.db"
            reader = pycolmap.ImageReaderOptions()
            reader.camera_model = camera_model
            pycolmap.extract_features(database, images, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader)
            pycolmap.match_exhaustive(database)
            models = pycolmap.incremental_mapping(database, images, Path(scratch) / "models")
            if not models:
                raise NerfEditError(
                    f"{images}: structure from motion registered no images (too little texture or overlap)"
                )
            best = max(models.values(), key=lambda model: model.num_reg_images())
            (stage / "0").mkdir()
            best.write(str(stage / "0"))
            shutil.copy(database, workspace / "database.db")
    finally:
        pycolmap.logging.minloglevel = level
    return workspace / "sparse" / "0", best.num_reg_images()
