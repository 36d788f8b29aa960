"""Checkpoints: save/load round trips (mesh field through the installed entry point, a parametric field through an
explicit registry), and every failure — missing, corrupt, foreign, mismatched — is a NerfEditError naming the file."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from nerfedit_plugin.data.synthetic import colorize
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.fields.checkpoint import load_field, save_field
from nerfedit_plugin.fields.mesh_field import MeshField, MeshFieldConfig
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.registry import FIELDS, Plugin, Registry


@dataclasses.dataclass
class GridConfig(FieldConfig):
    """A dense density grid (test backend)."""

    _target: type = dataclasses.field(default_factory=lambda: GridField)
    resolution: int = 4
    """Cells per axis."""
    scale: tuple[float, float] = (1.0, 2.0)
    """Nested non-scalar option (exercises the config round trip)."""


class GridField(Field):
    def __init__(self, config: GridConfig, scene_bbox: torch.Tensor) -> None:
        super().__init__(config, scene_bbox)
        self.grid = torch.nn.Parameter(torch.zeros(4, *(config.resolution,) * 3))

    def query(self, points, directions):
        grid = self.grid[None]
        lo, hi = self.scene_bbox
        coords = (2 * (points - lo) / (hi - lo) - 1).flip(-1)[None, :, None, None]
        values = torch.nn.functional.grid_sample(grid, coords, align_corners=True)[0, :, :, 0, 0].T
        return torch.nn.functional.softplus(values[:, 0]), torch.sigmoid(values[:, 1:])

    def extract_mesh(self, resolution=256, level=None):
        raise NotImplementedError("not needed by the checkpoint tests")


REGISTRY = Registry(
    plugins={FIELDS: {"grid": Plugin(FIELDS, "grid", "test_checkpoint:GridConfig", "tests", GridConfig)}}
)


@pytest.fixture(scope="module")
def mesh_field() -> MeshField:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
    mesh = colorize(SurfaceMesh(sphere.vertices, sphere.faces), seed=3)
    return MeshField.from_mesh(mesh, MeshFieldConfig(density=77.0))


def test_mesh_field_round_trip_keeps_the_mesh_and_config(mesh_field, tmp_path):
    path = tmp_path / "run" / "field.pt"
    mesh_field.save(path)  # the generic Field.save, backend found through the installed entry point
    loaded = MeshField.load(path)
    assert type(loaded) is MeshField and loaded.config == mesh_field.config
    for name in ("vertices", "faces", "vertex_colors", "scene_bbox"):
        assert torch.equal(getattr(loaded, name), getattr(mesh_field, name)), name
    points = torch.rand(200, 3) - 0.5
    for a, b in zip(loaded.query(points, points), mesh_field.query(points, points)):
        assert torch.equal(a, b)
    assert [p.name for p in tmp_path.joinpath("run").iterdir()] == ["field.pt"]  # atomic: no temporary left


def test_parametric_field_round_trip_through_an_explicit_registry(tmp_path):
    field = GridField(GridConfig(resolution=5, scale=(0.5, 3.0)), torch.tensor([[-1.0, -2, -3], [1, 2, 3]]))
    torch.nn.init.normal_(field.grid)
    save_field(field, tmp_path / "field.pt", registry=REGISTRY)
    loaded = load_field(tmp_path / "field.pt", registry=REGISTRY, backend="grid")
    assert isinstance(loaded, GridField) and loaded.config == field.config
    assert torch.equal(loaded.grid, field.grid) and torch.equal(loaded.scene_bbox, field.scene_bbox)


def test_unregistered_config_cannot_be_saved(tmp_path):
    field = GridField(GridConfig(), torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    with pytest.raises(NerfEditError, match="not registered"):
        save_field(field, tmp_path / "field.pt", registry=Registry())
    assert not (tmp_path / "field.pt").exists()


def test_missing_and_corrupt_files_are_clear_errors(mesh_field, tmp_path):
    missing = tmp_path / "nothing.pt"
    with pytest.raises(NerfEditError, match=f"{missing}: field checkpoint not found"):
        load_field(missing)
    good = tmp_path / "good.pt"
    mesh_field.save(good)
    data = good.read_bytes()
    variants = {
        "garbage.pt": np.random.default_rng(0).bytes(4096),
        "truncated.pt": data[: len(data) // 2],
        "empty.pt": b"",
    }
    for name, content in variants.items():
        (tmp_path / name).write_bytes(content)
        with pytest.raises(NerfEditError, match=f"{tmp_path / name}: not a readable field checkpoint"):
            load_field(tmp_path / name)
    torch.save({"weights": torch.zeros(3)}, tmp_path / "other.pt")  # a valid torch file, not a checkpoint
    with pytest.raises(NerfEditError, match="other.pt: not a field checkpoint"):
        load_field(tmp_path / "other.pt")


def test_checkpoint_of_another_backend_is_refused(mesh_field, tmp_path):
    path = tmp_path / "field.pt"
    mesh_field.save(path)
    with pytest.raises(NerfEditError, match=f"{path}: checkpoint of the 'mesh' field backend, not 'grid'"):
        load_field(path, backend="grid")
    with pytest.raises(NerfEditError, match=f"{path}: checkpoint of the 'mesh' field backend .*not GridField"):
        GridField.load(path)
    with pytest.raises(NerfEditError, match=f"{path}: unknown field 'mesh'"):
        load_field(path, registry=REGISTRY)  # a registry without the backend


def test_state_that_does_not_fit_the_config_is_an_error(tmp_path):
    field = GridField(GridConfig(resolution=3), torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    path = tmp_path / "field.pt"
    save_field(field, path, registry=REGISTRY)
    payload = torch.load(path, weights_only=True)
    payload["config"]["resolution"] = 6  # edited by hand: the grid no longer has the configured shape
    torch.save(payload, path)
    with pytest.raises(NerfEditError, match=f"{path}: checkpoint does not match the 'grid' backend"):
        load_field(path, registry=REGISTRY)
