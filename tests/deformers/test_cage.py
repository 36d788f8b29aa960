"""The cage deformer plugin: conformance kit, exact cage maps, handles on cage vertices, artifacts, bad input."""

import re
import warnings

import numpy as np
import pytest
import trimesh

from deformers.cage import CageConfig, CageDeformer, auto_cage, enclosure, validate_cage
from deformers.cage.mean_value import mean_value_coordinates
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.testing import default_edit, default_mesh, parametrize_with_checks

REST = default_mesh()  # ellipsoid, semi-axes 0.4, 0.5, 1.0
_sphere = trimesh.creation.icosphere(subdivisions=1)  # inradius 0.93
# Cage files are PLY (float32 coordinates): dyadic cage vertices and maps keep every deformed cage exact.
CAGE = SurfaceMesh(np.round(np.asarray(_sphere.vertices) * [0.6, 0.7, 1.3] * 256) / 256, np.asarray(_sphere.faces))
AFFINE = np.array([[1.25, 0.25, 0.0], [-0.125, 0.75, 0.25], [0.25, 0.0, 1.125]]), np.array([0.25, -0.125, 0.5])
SIMILARITY = 1.5 * np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]]), np.array([-0.5, 0.125, 0.25])


def bind(config, edit, base_dir=".", rest=REST, source="edit.json"):
    deformer = config.setup()
    deformer.bind(rest, parse_edit_spec(edit, CageDeformer.spec_keys, source, base_dir))
    return deformer


@pytest.fixture
def files(tmp_path):
    """Write cages into tmp_path: ``write(name, mesh)`` returns the file name relative to tmp_path."""

    def write(name, mesh):
        mesh.save(tmp_path / name)
        return name

    return write


# ---- conformance -----------------------------------------------------------------------------------------------
BOTH = [CageConfig(coordinates="mvc"), CageConfig(coordinates="green")]


@parametrize_with_checks(BOTH)
def test_conformance_kit_auto_cage_with_handles(check):
    check()


@parametrize_with_checks(BOTH, rest=REST, edit={"cage": "cage.ply", "deformed_cage": "moved.ply", "frames": 2})
def test_conformance_kit_given_cages(check, files, tmp_path):
    a, b = AFFINE
    files("cage.ply", CAGE)
    files("moved.ply", CAGE.with_vertices(CAGE.vertices @ a.T + b))
    check(base_dir=tmp_path)


def test_registered_as_entry_point():
    assert discover().config_class(DEFORMERS, "cage") is CageConfig


# ---- exact cage maps -------------------------------------------------------------------------------------------
def test_mvc_reproduces_an_affine_cage_map_in_every_frame(files, tmp_path):
    a, b = AFFINE
    edit = {
        "cage": files("cage.ply", CAGE),
        "deformed_cage": files("moved.ply", CAGE.with_vertices(CAGE.vertices @ a.T + b)),
        "frames": 3,
    }
    out = bind(CageConfig(), edit, tmp_path).deform()
    for t, frame in zip([0.0, 0.5, 1.0], out):  # the cage interpolates linearly, so each frame is affine too
        assert np.abs(frame - ((1 - t) * REST.vertices + t * (REST.vertices @ a.T + b))).max() < 1e-12


def test_green_reproduces_a_similarity(files, tmp_path):
    r, b = SIMILARITY
    edit = {
        "cage": files("cage.ply", CAGE),
        "deformed_cage": files("moved.ply", CAGE.with_vertices(CAGE.vertices @ r.T + b)),
    }
    out = bind(CageConfig(coordinates="green"), edit, tmp_path).deform()
    assert np.abs(out[0] - (REST.vertices @ r.T + b)).max() < 1e-10


def test_inward_oriented_cage_is_accepted(files, tmp_path):
    r, b = SIMILARITY
    inward = SurfaceMesh(CAGE.vertices, CAGE.faces[:, ::-1])
    edit = {
        "cage": files("cage.ply", inward),
        "deformed_cage": files("moved.ply", inward.with_vertices(CAGE.vertices @ r.T + b)),
    }
    out = bind(CageConfig(coordinates="green"), edit, tmp_path).deform()
    assert np.abs(out[0] - (REST.vertices @ r.T + b)).max() < 1e-10


# ---- handles on cage vertices ----------------------------------------------------------------------------------
def test_handles_move_selected_cage_vertices_and_nothing_else():
    edit = default_edit(REST)
    deformer = bind(CageConfig(), edit)
    cage = deformer.rest_cage.vertices
    idx, targets = parse_edit_spec(edit, CageDeformer.spec_keys).handle_targets(cage)
    expected = np.repeat(cage[None], 2, axis=0)
    expected[:, idx] = targets
    assert np.array_equal(deformer.deformed_cages, expected)
    assert 0 < len(idx) < len(cage)  # some cage vertices are free and stay put
    weights = mean_value_coordinates(REST.vertices, cage, deformer.rest_cage.faces)
    assert np.allclose(deformer.deform(), weights @ expected, rtol=0, atol=1e-12)


def test_auto_cage_is_closed_and_encloses_the_mesh():
    cage = validate_cage(auto_cage(REST), "auto")
    _, winding = mean_value_coordinates(REST.vertices, cage.vertices, cage.faces, return_winding=True)
    assert np.all(np.abs(winding) > 0.5)


def test_auto_cage_of_a_dense_mesh_wraps_its_clustering_and_encloses_it(monkeypatch):
    """From AUTO_CLUSTER_FACES triangles on (lowered here to a fine sphere), the wrap gets the vertex clustering."""
    import deformers.cage.deformer as cage_module

    mesh = SurfaceMesh.from_trimesh(trimesh.creation.icosphere(subdivisions=5))
    seen = []
    wrap = cage_module.wrap_and_decimate
    monkeypatch.setattr(
        cage_module, "wrap_and_decimate", lambda v, f, *a, **k: seen.append(len(f)) or wrap(v, f, *a, **k)
    )
    monkeypatch.setattr(cage_module, "AUTO_CLUSTER_FACES", 1)
    monkeypatch.setattr(cage_module, "AUTO_CLUSTER_CELL", 4.0)  # cells of 8 % of the diagonal: few vertices left
    cage = validate_cage(auto_cage(mesh), "auto")
    assert seen[0] < len(mesh.faces) / 4
    _, winding = mean_value_coordinates(mesh.vertices, cage.vertices, cage.faces, return_winding=True)
    assert np.all(np.abs(winding) > 0.5)


def test_coarse_auto_cage_is_rewrapped_until_it_encloses(capsule):
    """Simplifying to very few vertices cuts into the mesh; bind wraps again farther out instead of warning."""
    cage = auto_cage(capsule, max_vertices=40)
    _, winding = mean_value_coordinates(capsule.vertices, cage.vertices, cage.faces, return_winding=True)
    assert np.any(np.abs(winding) < 0.5)  # the plain simplified wrap misses vertices
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        deformer = bind(CageConfig(auto_max_vertices=40), default_edit(capsule), rest=capsule)
    assert deformer.rest_cage.n_vertices <= 40
    _, winding = mean_value_coordinates(
        capsule.vertices, deformer.rest_cage.vertices, deformer.rest_cage.faces, return_winding=True
    )
    assert np.all(np.abs(winding) > 0.5)


def test_deform_points_cache_follows_its_input():
    deformer = bind(CageConfig(), default_edit(REST))
    out = deformer.deform()
    a, b = REST.vertices[:20], REST.vertices[20:50]
    assert np.allclose(deformer.deform_points(a, 1), out[1, :20], rtol=0, atol=1e-12)
    assert np.allclose(deformer.deform_points(b, 1), out[1, 20:50], rtol=0, atol=1e-12)  # new points: recomputed
    assert np.allclose(deformer.deform_points(b, 0), out[0, 20:50], rtol=0, atol=1e-12)  # same points, other frame


# ---- bounded-memory bind: blocks, float32 or dropped coordinates ------------------------------------------------
def _repose(deformer, pose):
    """Re-pose a bound deformer through its public ``deformed_cages`` (as the editor's previews do)."""
    deformer.deformed_cages = pose[None]
    return deformer.deform()[0]


@pytest.mark.parametrize("coordinates", ["mvc", "green"])
def test_bind_in_blocks_and_reposing_without_stored_coordinates_match_the_whole_bind(coordinates, files, tmp_path):
    """bind_block splits the mesh (here into blocks of 7 vertices); weights_budget_mb=0 keeps no coordinates, so a
    new pose evaluates them again block by block: the same frames as one block with float64 coordinates kept."""
    small = CAGE.with_vertices(CAGE.vertices * [0.75, 0.75, 0.625])  # some vertices outside: MVC columns for green
    edit = {"cage": files("cage.ply", small), "handles": default_edit(REST)["handles"], "frames": 2}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = bind(CageConfig(coordinates=coordinates, bind_block=10**6), edit, tmp_path)
        blocks = bind(CageConfig(coordinates=coordinates, bind_block=7, weights_budget_mb=0), edit, tmp_path)
    assert whole._weights[0].dtype == np.float64 and blocks._weights is None
    assert np.allclose(blocks.deform(), whole.deform(), rtol=0, atol=1e-13)
    pose = small.vertices @ AFFINE[0].T + AFFINE[1] + np.random.default_rng(0).normal(0, 0.05, small.vertices.shape)
    assert np.allclose(_repose(blocks, pose), _repose(whole, pose), rtol=0, atol=1e-13)


@pytest.mark.parametrize("coordinates", ["mvc", "green"])
def test_float32_coordinates_repose_within_1e7_of_the_cage_size(coordinates, files, tmp_path):
    """Coordinates that fit weights_budget_mb only as float32 are kept so: the frames of the bind stay float64
    (posed while binding), a new pose from float32 coordinates is within 1e-7 × the cage's bounding-box diagonal of
    the float64 one, also 1e4 cage sizes away from the origin (the pose is taken about the cage's centre)."""
    far = 1e4 * CAGE.bbox_diagonal
    rest = REST.with_vertices(REST.vertices + far)
    cage = CAGE.with_vertices(CAGE.vertices + far)
    edit = {"cage": files("cage.ply", cage), "handles": default_edit(rest)["handles"]}
    rows = len(cage.vertices) + (len(cage.faces) if coordinates == "green" else 0)
    budget = 4.0 * rows * rest.n_vertices / 2**20  # float32 fits, float64 does not
    exact = bind(CageConfig(coordinates=coordinates), edit, tmp_path, rest=rest)
    single = bind(CageConfig(coordinates=coordinates, weights_budget_mb=budget), edit, tmp_path, rest=rest)
    assert exact._weights[0].dtype == np.float64 and single._weights[0].dtype == np.float32
    assert np.array_equal(single.deform(), exact.deform())
    pose = cage.vertices + np.random.default_rng(1).normal(0, 0.05, cage.vertices.shape)
    error = np.abs(_repose(single, pose) - _repose(exact, pose)).max()
    assert error <= 1e-7 * cage.bbox_diagonal


# ---- artifacts -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "frames, names",
    [
        (1, ["cage_rest.ply", "cage_deformed.ply"]),
        (3, ["cage_rest.ply"] + [f"cage_deformed_{i:04d}.ply" for i in range(3)]),
    ],
)
def test_write_artifacts(frames, names, tmp_path):
    deformer = bind(CageConfig(), {**default_edit(REST), "frames": frames})
    written = deformer.write_artifacts(tmp_path / "out")
    assert [p.name for p in written] == names
    loaded = [SurfaceMesh.load(p) for p in written]
    assert np.allclose(loaded[0].vertices, deformer.rest_cage.vertices)
    assert np.array_equal(loaded[0].faces, deformer.rest_cage.faces)
    assert np.allclose(np.stack([m.vertices for m in loaded[1:]]), deformer.deformed_cages)


# ---- bad input -------------------------------------------------------------------------------------------------
def _bad_cases(files, tmp_path):
    a, _ = AFFINE
    open_cage = SurfaceMesh(CAGE.vertices, CAGE.faces[1:])
    flipped = CAGE.faces.copy()
    flipped[0] = flipped[0, ::-1]
    other = trimesh.creation.icosphere(subdivisions=2)
    retriangulated = CAGE.faces.copy()
    retriangulated[[0, 1]] = retriangulated[[1, 0]][:, [0, 2, 1]]
    handles = default_edit(REST)["handles"]
    lines = (tmp_path / files("nan.obj", CAGE)).read_text().splitlines()
    lines[next(i for i, line in enumerate(lines) if line.startswith("v "))] = "v nan 0 0"
    (tmp_path / "nan.obj").write_text("\n".join(lines) + "\n")
    return [
        (
            {"cage": files("open.ply", open_cage), "deformed_cage": files("d.ply", open_cage)},
            r"cage: .*open\.ply: not closed \(\d+ boundary edges\)",
        ),
        (
            {"cage": files("flip.ply", SurfaceMesh(CAGE.vertices, flipped)), "handles": handles},
            r"cage: .*flip\.ply: not consistently oriented",
        ),
        (
            {"cage": files("c.ply", CAGE), "deformed_cage": files("o.ply", SurfaceMesh(other.vertices, other.faces))},
            r"deformed_cage: .*o\.ply: has 162 vertices, the cage has 42",
        ),
        (
            {
                "cage": files("c.ply", CAGE),
                "deformed_cage": files("t.ply", SurfaceMesh(CAGE.vertices @ a.T, retriangulated)),
            },
            r"deformed_cage: .*t\.ply: its triangles differ",
        ),
        ({"cage": "auto", "deformed_cage": files("c.ply", CAGE)}, r"deformed_cage: needs a cage file"),
        (
            {"cage": files("c.ply", CAGE), "deformed_cage": files("c.ply", CAGE), "handles": handles},
            r"deformed_cage and handles: ",
        ),
        ({"cage": files("c.ply", CAGE)}, r"nothing moves the cage"),
        ({"cage": 3, "handles": handles}, r"cage: expected \"auto\" or a mesh file"),
        ({"cage": "missing.ply", "handles": handles}, r"cage: file not found"),
        ({"cage": "nan.obj", "handles": handles}, r"cage: .*nan\.obj: .*NaN"),
    ]


def test_bad_input_is_rejected_naming_file_and_problem(files, tmp_path):
    for edit, message in _bad_cases(files, tmp_path):
        with pytest.raises(NerfEditError, match=r"^edit\.json: " + message):
            bind(CageConfig(), edit, tmp_path)


@pytest.mark.parametrize(
    "option",
    [{"chunk_size": 0}, {"auto_alpha": 0.0}, {"auto_max_vertices": 3}, {"bind_block": 0}, {"weights_budget_mb": -1.0}],
)
def test_bad_options_are_rejected(option):
    ((name, value),) = option.items()
    with pytest.raises(NerfEditError, match=rf"{name}: must be .*, got {value}"):
        CageConfig(**option)


@pytest.mark.parametrize("coordinates", ["mvc", "green"])
def test_cage_that_misses_points_warns_and_still_maps_affinely(coordinates, files, tmp_path):
    small = CAGE.with_vertices(CAGE.vertices * [0.75, 0.75, 0.625])  # the ellipsoid's tips poke out
    r, b = SIMILARITY
    edit = {
        "cage": files("small.ply", small),
        "deformed_cage": files("moved.ply", small.with_vertices(small.vertices @ r.T + b)),
    }
    with pytest.warns(UserWarning, match=r"small\.ply: (\d+) of 162 mesh vertices lie outside the cage") as record:
        out = bind(CageConfig(coordinates=coordinates), edit, tmp_path).deform()
    outside = int(re.search(r"(\d+) of 162", str(record[0].message)).group(1))
    _, winding = mean_value_coordinates(REST.vertices, small.vertices, small.faces, return_winding=True)
    assert outside == np.count_nonzero(np.abs(winding) < 0.5) > 0
    assert np.abs(out[0] - (REST.vertices @ r.T + b)).max() < 1e-9  # MVC extrapolate affine maps exactly


def test_enclosure_agrees_with_winding_numbers_on_and_next_to_the_cage():
    """Ray parity decides far points, the exact winding number the ones within NEAR_CAGE: points 1e-9 inside or
    outside a face are classified like their winding number, points on a face are neither inside nor outside."""
    cage = validate_cage(CAGE, "cage")
    rng = np.random.default_rng(3)
    faces = rng.integers(0, len(cage.faces), 200)
    on_face = np.einsum("pk,pki->pi", rng.dirichlet([1, 1, 1], 200), cage.vertices[cage.faces[faces]])
    normal = np.cross(*(cage.vertices[cage.faces[faces, k]] - cage.vertices[cage.faces[faces, 0]] for k in (1, 2)))
    step = 1e-9 * cage.bbox_diagonal * normal / np.linalg.norm(normal, axis=1, keepdims=True)
    far = rng.uniform(cage.vertices.min(0) * 1.2, cage.vertices.max(0) * 1.2, size=(400, 3))
    points = np.concatenate([on_face - step, on_face + step, on_face, far])
    inside, outside = enclosure(points, cage)
    _, winding = mean_value_coordinates(points, cage.vertices, cage.faces, return_winding=True)
    assert np.array_equal(inside, np.abs(winding) > 0.5) and np.array_equal(outside, np.abs(winding) < 0.5)
    assert inside[:200].all() and outside[200:400].all() and not (inside | outside)[400:600].any()
    assert inside[600:].any() and outside[600:].any()


@pytest.mark.parametrize("coordinates", ["mvc", "green"])
def test_enclosing_cage_does_not_warn(coordinates, files, tmp_path):
    """Every mesh vertex inside the cage (winding number 1): no warning, and the map is right — the identity for an
    unmoved cage, the similarity for a cage moved by one (both coordinates reproduce it exactly)."""
    _, winding = mean_value_coordinates(REST.vertices, CAGE.vertices, CAGE.faces, return_winding=True)
    assert np.abs(winding - 1).max() < 1e-9
    r, b = SIMILARITY
    edit = {
        "cage": files("cage.ply", CAGE),
        "deformed_cage": files("moved.ply", CAGE.with_vertices(CAGE.vertices @ r.T + b)),
        "frames": 2,  # frame 0: the unmoved cage
    }
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = bind(CageConfig(coordinates=coordinates), edit, tmp_path).deform()
    assert out.shape == (2, REST.n_vertices, 3)
    assert np.abs(out[0] - REST.vertices).max() < 1e-10
    assert np.abs(out[1] - (REST.vertices @ r.T + b)).max() < 1e-10


# ---- multiresolution ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("coordinates", ["mvc", "green"])
def test_coarse_level_keeps_the_exact_maps_and_follows_the_direct_bind(coordinates, files, tmp_path):
    """Bound on a clustering of the ellipsoid to a quarter of its vertices: the maps the coordinates reproduce exactly
    (affine for mvc, a similarity for green) stay exact on every fine vertex, a non-rigid handle edit lands near the
    direct bind's (within a tenth of the motion on this coarse a level: the detail carried is large), and a re-pose
    (the editor's previews) equals a fresh bind of that pose."""
    matrix, shift = AFFINE if coordinates == "mvc" else SIMILARITY
    coarse = {"multiresolution": "on", "coarse_vertices": REST.n_vertices // 4, "coordinates": coordinates}
    exact = {
        "cage": files("cage.ply", CAGE),
        "deformed_cage": files("moved.ply", CAGE.with_vertices(CAGE.vertices @ matrix.T + shift)),
    }
    deformer = bind(CageConfig(**coarse), exact, tmp_path)
    report = deformer.report()
    assert report["path"] == "multiresolution" and report["coarse"]["vertices"] < REST.n_vertices // 3
    np.testing.assert_allclose(deformer.deform()[0], REST.vertices @ matrix.T + shift, rtol=0, atol=1e-9)
    handles = {"cage": files("cage.ply", CAGE), "handles": default_edit(REST)["handles"]}
    direct, fine = (
        bind(CageConfig(coordinates=coordinates), handles, tmp_path),
        bind(CageConfig(**coarse), handles, tmp_path),
    )
    assert direct.report() == {"path": "direct"}
    moved = np.linalg.norm(direct.deform()[-1] - REST.vertices, axis=1).max()
    error = np.linalg.norm(fine.deform()[-1] - direct.deform()[-1], axis=1)
    assert moved > 0.05 * REST.bbox_diagonal and error.max() < 0.1 * moved and error.mean() < 0.02 * moved
    pose = CAGE.vertices + np.random.default_rng(1).normal(0, 0.03, CAGE.vertices.shape)
    again = {"cage": files("cage.ply", CAGE), "deformed_cage": files("pose.ply", CAGE.with_vertices(pose))}
    np.testing.assert_allclose(
        _repose(fine, pose), bind(CageConfig(**coarse), again, tmp_path).deform()[-1], atol=1e-12
    )
