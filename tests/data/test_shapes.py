"""The generated benchmark objects (``shape:NAME``): closed, deterministic, in the generator's frame, each with the
property it exists for, and reachable through the generator and ``nerfedit generate``."""

import numpy as np
import pytest
import yaml

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.data import shapes
from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset, normalize
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.mesh import SurfaceMesh

SMALL = dict(n_train=2, n_val=1, n_test=1, resolution=16, supersample=1)


@pytest.fixture(scope="module")
def built():
    return {name: shape.build() for name, shape in shapes.SHAPES.items()}


@pytest.fixture(scope="module")
def solids(built):
    return {name: mesh.to_trimesh() for name, mesh in built.items()}


def inside(mesh: SurfaceMesh, points) -> np.ndarray:
    return raycast.occupancy(raycast.raycasting_scene(mesh.vertices, mesh.faces), np.asarray(points), nsamples=3)


@pytest.mark.parametrize("name", list(shapes.SHAPES))
def test_each_shape_is_a_closed_consistently_oriented_solid(solids, name):
    mesh = solids[name]
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # faces counter-clockwise seen from outside


@pytest.mark.parametrize("name", list(shapes.SHAPES))
def test_each_shape_is_deterministic_and_in_the_generators_frame(built, name):
    mesh = built[name]
    again = shapes.SHAPES[name].build()
    assert np.array_equal(mesh.vertices, again.vertices) and np.array_equal(mesh.faces, again.faces)
    assert np.abs(mesh.vertices).max() <= 0.5 + 1e-9
    assert np.allclose(normalize(mesh).vertices, mesh.vertices, atol=1e-6)  # the generator rescales nothing


def test_the_tube_is_thin(solids):
    """For a tube of radius r and length L, V = πr²L and A = 2πrL: thickness / length = 2r / L = 16πV² / A³."""
    mesh = solids["tube"]
    assert 16 * np.pi * mesh.volume**2 / mesh.area**3 < 0.05


def test_the_cup_has_a_cavity(built, solids):
    """Points in the cup's opening (on and around its axis, y up) are outside the solid, points in its wall are
    inside, and the solid fills under a third of its bounding cylinder."""
    cup = built["cup"]
    heights = np.linspace(-0.4, 0.45, 18)
    opening = [[r * np.cos(a), y, r * np.sin(a)] for y in heights for r in (0.0, 0.15, 0.25) for a in (0.0, 2.0)]
    assert not inside(cup, opening).any()
    low, high = cup.vertices.min(0), cup.vertices.max(0)
    wall = [[(high[0] - low[0]) / 2 - 0.01, 0.45, 0.0], [0.0, low[1] + 0.02, 0.0]]  # rim, bottom
    assert inside(cup, wall).all()
    cylinder = np.pi * ((high[0] - low[0]) / 2) ** 2 * (high[1] - low[1])
    assert solids["cup"].volume < cylinder / 3


def test_the_slab_has_a_large_tilted_planar_face(solids):
    """The largest set of coplanar faces covers ≥ 30 % of the area, and no axis looks at it edge-on or face-on."""
    mesh = solids["slab"]
    largest = int(np.argmax(mesh.facets_area))
    assert mesh.facets_area[largest] >= 0.3 * mesh.area
    normal = np.abs(mesh.facets_normal[largest])
    assert 0.1 < normal.min() and normal.max() < 0.95


def test_the_fine_bunny_is_the_bunny_refined_with_a_finer_texture(built, solids):
    fine, bunny = built["bunny-fine"], normalize(SurfaceMesh.load("sample:bunny"))
    assert solids["bunny-fine"].edges_unique_length.max() <= shapes.FINE_EDGE * (1 + 1e-9)
    scene = raycast.raycasting_scene(bunny.vertices, bunny.faces)
    assert raycast.distance(scene, fine.vertices).max() < 1e-5  # the same surface
    assert shapes.SHAPES["bunny-fine"].texture_frequency > 2


def test_nerfedit_generate_takes_a_shape_and_records_its_name(tmp_path, monkeypatch):
    """``--mesh shape:slab`` renders the slab as built (the generator rescales nothing; z up: no rotation) and the
    dataset's config.yml keeps the name, not a path."""
    monkeypatch.chdir(tmp_path)
    flags = [f"--{key.replace('_', '-')}={value}" for key, value in SMALL.items()]
    assert main(["generate", "--mesh", "shape:slab", "--up-axis", "z", "--out", "slab"] + flags) == 0
    written, slab = SurfaceMesh.load(tmp_path / "slab" / "mesh.ply"), shapes.slab()
    assert np.array_equal(written.faces, slab.faces) and np.allclose(written.vertices, slab.vertices, atol=1e-6)
    assert yaml.safe_load((tmp_path / "slab" / "config.yml").read_text())["mesh"] == "shape:slab"


def test_an_unknown_shape_is_one_error_naming_it_and_the_known_ones(tmp_path, monkeypatch, capsys):
    with pytest.raises(NerfEditError, match="shape:bottle: unknown shape \\(available: tube, cup, slab, bunny-fine\\)"):
        generate_dataset(GenerateConfig(out=tmp_path / "x", mesh="shape:bottle"))
    monkeypatch.chdir(tmp_path)
    assert main(["generate", "--mesh", "shape:bottle", "--out", "bottle"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: shape:bottle: unknown shape (available: ") and err.count("\n") == 1
    assert not (tmp_path / "x").exists() and not (tmp_path / "bottle").exists()  # rejected before any work
