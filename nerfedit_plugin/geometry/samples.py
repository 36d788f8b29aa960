"""Sample meshes shipped inside the pymeshlab wheel (no download): ``sample:bunny``, ``sample:cow``, …"""

from __future__ import annotations

from pathlib import Path

from nerfedit_plugin.errors import NerfEditError

PREFIX = "sample:"
FILES = {"bunny": "bunny.obj", "cow": "cow.obj", "airplane": "airplane.obj", "bone": "bone.ply"}


def sample_mesh_path(name: str) -> Path:
    """Path of a pymeshlab sample mesh by short name (``bunny``, ``cow``, ``airplane``, ``bone``)."""
    import pymeshlab

    if name not in FILES:
        raise NerfEditError(f"{PREFIX}{name}: unknown sample mesh (available: {', '.join(FILES)})")
    return Path(pymeshlab.__file__).parent / "tests" / "sample_meshes" / FILES[name]


def resolve_mesh_path(path: str | Path) -> Path:
    """``sample:NAME`` → the sample's file; anything else is returned as a Path."""
    text = str(path)
    return sample_mesh_path(text[len(PREFIX) :]) if text.startswith(PREFIX) else Path(path)
