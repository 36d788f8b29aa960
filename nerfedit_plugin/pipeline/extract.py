"""``nerfedit extract``: a run's surface mesh into ``RUN_DIR/mesh.ply`` — marching cubes of the field
(``Field.extract_mesh``), the clean-up a scene needs (its floor, floaters: :mod:`nerfedit_plugin.geometry.cleanup`),
and the mesh in a capture's own coordinates (``RUN_DIR/mesh_capture.ply``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from nerfedit_plugin.data.normalization import apply
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.cleanup import drop_floaters as without_floaters
from nerfedit_plugin.geometry.cleanup import drop_plane as without_plane
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_path
from nerfedit_plugin.pipeline.run import CAPTURE_MESH, Run


def extract_mesh(
    run: Run,
    resolution: int = 256,
    level: float | None = None,
    *,
    largest_component: bool = True,
    drop_plane: bool = False,
    drop_floaters: float | None = None,
    overwrite: bool = False,
    device: torch.device | str | None = None,
) -> Path:
    """Extract the run's mesh (marching cubes over ``resolution³`` lattice points at ``level``, default the backend's)
    into ``RUN_DIR/mesh.ply``, atomically; an existing mesh is replaced only with ``overwrite``, except that an
    exact-mesh run (``Field.exact_mesh``: the field is its mesh) is left as it is (nothing to extract).

    Clean-up, on the extracted mesh before the one write, in this order: ``largest_component`` keeps the largest part
    only (drops floaters; not with ``drop_floaters``), ``drop_plane`` removes the vertices on its largest plane (a
    scene's floor, which holds the objects standing on it), ``drop_floaters`` keeps every connected part of at least
    this fraction of the largest part's faces (the objects of a scene). An exact
    mesh is never cleaned (it is the field: clean the mesh before making the run); a clean-up that leaves nothing is
    a :class:`NerfEditError`."""
    clean = drop_plane or drop_floaters is not None
    if clean and run.exact_mesh:
        raise NerfEditError(
            f"{run.path}: the mesh field's mesh is its field and stays whole: clean the mesh before "
            "`nerfedit train --field mesh` (--drop-plane, --drop-floaters)"
        )
    if run.mesh_path.exists() and not overwrite:
        if run.exact_mesh:
            return run.mesh_path
        raise NerfEditError(f"{run.mesh_path}: exists (pass --overwrite to extract again)")
    field = run.field(device)
    try:
        mesh = field.extract_mesh(resolution, level)
    except ValueError as exc:  # e.g. the level lies outside the field's range
        raise NerfEditError(f"{run.path}: {exc}") from exc
    if not run.exact_mesh:
        if largest_component and drop_floaters is None:
            mesh = mesh.largest_component()
        if drop_plane:
            mesh = without_plane(mesh)
        if drop_floaters is not None:
            mesh = without_floaters(mesh, drop_floaters)
    if not len(mesh.faces):
        raise NerfEditError(f"{run.mesh_path}: nothing is left after the clean-up (--drop-plane, --drop-floaters)")
    with atomic_path(run.mesh_path) as tmp:
        mesh.save(tmp)
    return run.mesh_path


def export_capture_mesh(run: Run, overwrite: bool = False) -> Path:
    """The run's mesh mapped back to the capture's coordinates (by the inverse of :meth:`Run.source_transform`) into
    ``RUN_DIR/mesh_capture.ply``, atomically: e.g. to open it next to the COLMAP points."""
    path = run.path / CAPTURE_MESH
    if path.exists() and not overwrite:
        raise NerfEditError(f"{path}: exists (pass --overwrite to export again)")
    return write_in_capture_frame(run, run.mesh(), path)


def write_in_capture_frame(run: Run, mesh: SurfaceMesh, path: Path) -> Path:
    """``mesh`` (in the run's frame) mapped by the inverse of the run's source transform, written to ``path``
    atomically."""
    to_capture = np.linalg.inv(run.source_transform())
    with atomic_path(path) as tmp:
        mesh.with_vertices(apply(to_capture, mesh.vertices)).save(tmp)
    return path
