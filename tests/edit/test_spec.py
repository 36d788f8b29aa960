"""Edit specs: selections, transforms, frame interpolation, and one clear error per malformed-spec class."""

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nerfedit_plugin.edit.spec import check_keys, load_edit_spec, number, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError

GRID = np.stack(np.meshgrid(*[np.linspace(-1, 1, 5)] * 3, indexing="ij"), -1).reshape(-1, 3)


def spec(handles, **extra):
    return parse_edit_spec({"handles": handles, **extra}, source="e.json")


def test_box_sphere_indices_select_expected_points():
    box = spec([{"select": {"box": {"min": [0, -1, -1], "max": [1, 1, 1]}}, "fixed": True}])
    idx, _ = box.handle_targets(GRID)
    assert np.array_equal(idx, np.flatnonzero(GRID[:, 0] >= 0))
    sphere = spec([{"select": {"sphere": {"center": [0, 0, 0], "radius": 0.6}}, "fixed": True}])
    idx, _ = sphere.handle_targets(GRID)
    assert np.array_equal(idx, np.flatnonzero(np.linalg.norm(GRID, axis=1) <= 0.6))
    ind = spec([{"select": {"indices": [7, 3, 3]}, "fixed": True}])
    assert np.array_equal(ind.handle_targets(GRID)[0], [3, 7])


def test_fixed_handles_stay_and_transform_is_similarity_about_pivot():
    s = spec(
        [
            {"select": {"box": {"min": [-1, -1, -1], "max": [-0.9, 1, 1]}}, "fixed": True},
            {
                "select": {"box": {"min": [0.9, -1, -1], "max": [1, 1, 1]}},
                "transform": {
                    "translate": [0, 0, 1],
                    "rotate": {"axis": [0, 0, 2], "degrees": 90, "center": [1, 0, 0]},
                    "scale": 2.0,
                },
            },
        ]
    )
    idx, targets = s.handle_targets(GRID)
    assert targets.shape == (1, len(idx), 3)
    left = GRID[idx, 0] < 0
    assert np.array_equal(targets[0, left], GRID[idx[left]])
    rot = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    expected = np.array([1, 0, 0]) + 2 * (GRID[idx[~left]] - [1, 0, 0]) @ rot.T + [0, 0, 1]
    assert np.allclose(targets[0, ~left], expected)


def test_frames_interpolate_from_rest_with_slerp():
    s = spec(
        [
            {
                "select": {"indices": [0]},
                "transform": {"rotate": {"axis": [0, 0, 1], "degrees": 120, "center": [0, 0, 0]}},
            }
        ],
        frames=3,
    )
    point = np.array([[1.0, 0.0, 0.0]])
    _, targets = s.handle_targets(point)
    assert np.allclose(targets[0, 0], point[0])  # frame 0 is the rest pose
    angles = [math.degrees(math.atan2(t[0, 1], t[0, 0])) for t in targets]
    assert np.allclose(angles, [0, 60, 120])
    assert np.allclose(np.linalg.norm(targets[:, 0], axis=1), 1.0)  # slerp keeps the radius


def test_pivot_defaults_to_selection_centroid():
    s = spec([{"select": {"indices": [0, 1]}, "transform": {"scale": 3}}])
    pts = np.array([[0.0, 0, 0], [2.0, 0, 0]])
    _, targets = s.handle_targets(pts)
    assert np.allclose(targets[0], [[-2, 0, 0], [4, 0, 0]])


def test_later_handle_wins_on_overlap():
    s = spec(
        [
            {"select": {"indices": [0, 1]}, "fixed": True},
            {"select": {"indices": [1]}, "transform": {"translate": [1, 0, 0]}},
        ]
    )
    idx, targets = s.handle_targets(np.zeros((3, 3)))
    assert np.array_equal(idx, [0, 1]) and np.allclose(targets[0], [[0, 0, 0], [1, 0, 0]])


BAD = [
    ({"handles": [], "frames": 1}, "handles: expected a non-empty list"),
    ({"handels": []}, "handels: unknown key"),
    (
        {"handles": [{"select": {"box": {"min": [0, 0], "max": [1, 1, 1]}}, "fixed": True}]},
        "handles[0].select.box.min: expected 3 numbers",
    ),
    (
        {"handles": [{"select": {"box": {"min": [0, 0, 0], "max": [1, 1, float("nan")]}}, "fixed": True}]},
        "handles[0].select.box.max: contains NaN",
    ),
    (
        {"handles": [{"select": {"box": {"min": [1, 0, 0], "max": [0, 1, 1]}}, "fixed": True}]},
        "handles[0].select.box: min exceeds max",
    ),
    (
        {"handles": [{"select": {"sphere": {"center": [0, 0, 0], "radius": -1}}, "fixed": True}]},
        "handles[0].select.sphere.radius: must be > 0",
    ),
    ({"handles": [{"select": {"box": {}, "sphere": {}}, "fixed": True}]}, "handles[0].select: expected exactly one"),
    ({"handles": [{"select": {"cone": {}}, "fixed": True}]}, "handles[0].select.cone: unknown key"),
    (
        {"handles": [{"select": {"indices": [1.5]}, "fixed": True}]},
        "handles[0].select.indices: expected a non-empty list of integer",
    ),
    ({"handles": [{"select": {"indices": [1]}}]}, "handles[0]: needs exactly one of"),
    (
        {"handles": [{"select": {"indices": [1]}, "fixed": True, "transform": {"scale": 2}}]},
        "handles[0]: needs exactly one of",
    ),
    (
        {"handles": [{"select": {"indices": [1]}, "transform": {"rotate": {"axis": [0, 0, 0], "degrees": 3}}}]},
        "handles[0].transform.rotate.axis: is the zero vector",
    ),
    (
        {"handles": [{"select": {"indices": [1]}, "transform": {"rotate": {"axis": [0, 0, 1]}}}]},
        "handles[0].transform.rotate.degrees: missing",
    ),
    ({"handles": [{"select": {"indices": [1]}, "transform": {"shear": 1}}]}, "handles[0].transform.shear: unknown key"),
    ({"handles": [{"select": {"indices": [1]}, "transform": {"scale": 0}}]}, "handles[0].transform.scale: must be > 0"),
    ({"handles": [{"select": {"indices": [1]}, "fixed": "yes"}]}, "handles[0].fixed: expected true or false"),
    ({"handles": [{"select": {"indices": [1]}, "fixed": True}], "frames": 0}, "frames: expected an integer >= 1"),
    ([1, 2], "expected a mapping"),
]


@pytest.mark.parametrize("data, message", BAD)
def test_malformed_spec_names_key_and_problem(data, message):
    with pytest.raises(NerfEditError) as err:
        parse_edit_spec(data, source="e.json")
    assert str(err.value).startswith("e.json: ") and message in str(err.value)


def test_selection_errors_are_raised_against_the_points():
    empty = spec([{"select": {"sphere": {"center": [9, 9, 9], "radius": 0.1}}, "fixed": True}])
    with pytest.raises(NerfEditError, match=r"handles\[0\].select.sphere: selects no points"):
        empty.handle_targets(GRID)
    out_of_range = spec([{"select": {"indices": [0, 500]}, "fixed": True}])
    with pytest.raises(NerfEditError, match=r"handles\[0\].select.indices: index 500 out of range for 125 points"):
        out_of_range.handle_targets(GRID)


def test_load_json_and_yaml_and_paths(tmp_path):
    (tmp_path / "a.ply").write_text("x")
    (tmp_path / "b.ply").write_text("x")
    data = {"handles": [{"select": {"indices": [0]}, "fixed": True}], "deformed": "*.ply", "frames": 2}
    (tmp_path / "e.json").write_text(json.dumps(data))
    (tmp_path / "e.yaml").write_text("handles:\n  - select: {indices: [0]}\n    fixed: true\ndeformed: a.ply\n")
    from_json = load_edit_spec(tmp_path / "e.json", {"handles", "deformed"})
    assert from_json.frames == 2 and [p.name for p in from_json.paths("deformed")] == ["a.ply", "b.ply"]
    from_yaml = load_edit_spec(tmp_path / "e.yaml", {"handles", "deformed"})
    assert from_yaml.path("deformed") == (tmp_path / "a.ply").resolve()
    with pytest.raises(NerfEditError, match="deformed: unknown key"):
        load_edit_spec(tmp_path / "e.yaml")
    (tmp_path / "bad.json").write_text("{oops")
    with pytest.raises(NerfEditError, match="bad.json: cannot parse"):
        load_edit_spec(tmp_path / "bad.json")
    with pytest.raises(NerfEditError, match="missing.json: edit spec not found"):
        load_edit_spec(tmp_path / "missing.json")
    (tmp_path / "m.json").write_text(json.dumps({"deformed": "nope.ply"}))
    with pytest.raises(NerfEditError, match="deformed: file not found"):
        load_edit_spec(tmp_path / "m.json", {"deformed"}).path("deformed")


def rodrigues(axis, degrees: float) -> np.ndarray:
    """Rotation matrix by ``degrees`` about ``axis`` (written out, not scipy)."""
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    angle = math.radians(degrees)
    return np.eye(3) + math.sin(angle) * cross + (1 - math.cos(angle)) * cross @ cross


@pytest.mark.parametrize("center", [[0.5, -0.25, 1.0], None])
def test_every_frame_is_the_interpolated_similarity(center):
    """``frames = 3``: t = 0, 1/2, 1 and ``x ↦ c + (1 + (s − 1)t) R(t)(x − c) + t·translate`` with every part of the
    transform interpolated (scale too: frame 0 is the rest pose); ``c`` the rotate center, else the centroid."""
    rotate = {"axis": [1.0, 2.0, -0.5], "degrees": 100.0}
    if center is not None:
        rotate["center"] = center
    transform = {"translate": [0.3, -0.6, 0.9], "rotate": rotate, "scale": 2.5}
    s = spec([{"select": {"box": {"min": [0, -1, -1], "max": [1, 1, 1]}}, "transform": transform}], frames=3)
    idx, targets = s.handle_targets(GRID)
    points = GRID[idx]
    pivot = points.mean(0) if center is None else np.array(center)
    assert targets.shape == (3, len(idx), 3)
    for frame, t in enumerate([0.0, 0.5, 1.0]):
        scale = 1 + (2.5 - 1) * t
        expected = (
            pivot + scale * (points - pivot) @ rodrigues(rotate["axis"], t * 100.0).T + t * np.array([0.3, -0.6, 0.9])
        )
        np.testing.assert_allclose(targets[frame], expected, rtol=0, atol=1e-12, err_msg=f"frame {frame}")
    np.testing.assert_array_equal(targets[0], points)  # the rest pose exactly


SCALAR_KEYS = [
    (
        lambda v: {"select": {"sphere": {"center": [0, 0, 0], "radius": v}}, "fixed": True},
        "handles[0].select.sphere.radius",
    ),
    (
        lambda v: {"select": {"indices": [0]}, "transform": {"rotate": {"axis": [0, 0, 1], "degrees": v}}},
        "handles[0].transform.rotate.degrees",
    ),
    (lambda v: {"select": {"indices": [0]}, "transform": {"scale": v}}, "handles[0].transform.scale"),
]


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
@pytest.mark.parametrize("handle, key", SCALAR_KEYS, ids=["radius", "degrees", "scale"])
def test_non_finite_scalar_is_rejected(handle, key, value):
    with pytest.raises(NerfEditError) as err:
        parse_edit_spec({"handles": [handle(value)]}, source="e.json")
    assert str(err.value) == f"e.json: {key}: is NaN or Inf"


@pytest.mark.parametrize("text", [".nan", ".inf", "-.inf"])
def test_non_finite_scalar_in_yaml_is_rejected(tmp_path, text):
    (tmp_path / "e.yaml").write_text(f"handles:\n  - select: {{indices: [0]}}\n    transform: {{scale: {text}}}\n")
    with pytest.raises(NerfEditError, match=r"e.yaml: handles\[0\].transform.scale: is NaN or Inf"):
        load_edit_spec(tmp_path / "e.yaml")


def handle(select=None, **rest):
    return {"select": select or {"indices": [0]}, **(rest or {"fixed": True})}


EXACT = [  # (spec, the whole error message after "e.json: ")
    ({"handles": [handle(), 5]}, "handles[1]: expected a mapping, got int"),
    ([1, 2], ": expected a mapping, got list"),
    ({"handles": [handle()], "bogus": 1}, "bogus: unknown key (expected one of ['frame', 'frames', 'handles'])"),
    ({"handles": [{"fixed": True}]}, "handles[0].select: missing"),
    ({"handles": [handle({"box": {"min": [0, 0, 0]}})]}, "handles[0].select.box.max: missing"),
    (
        {"handles": [handle({"box": {"min": ["a", 0, 0], "max": [1, 1, 1]}})]},
        "handles[0].select.box.min: expected 3 numbers, got ['a', 0, 0]",
    ),
    (
        {"handles": [handle({"box": {"min": [0, 0], "max": [1, 1, 1]}})]},
        "handles[0].select.box.min: expected 3 numbers, got [0, 0]",
    ),
    ({"handles": [handle({"sphere": {"center": [0, 0, 0]}})]}, "handles[0].select.sphere.radius: missing"),
    (
        {"handles": [handle({"box": {"min": [True, 0, 0], "max": [1, 1, 1]}})]},
        "handles[0].select.box.min: expected 3 numbers, got [True, 0, 0]",
    ),
    (
        {"handles": [handle({"sphere": {"center": [0, 0], "radius": 1}})]},
        "handles[0].select.sphere.center: expected 3 numbers, got [0, 0]",
    ),
    (
        {"handles": [handle({"indices": 5})]},
        "handles[0].select.indices: expected a non-empty list of integer vertex indices",
    ),
    ({"handles": [handle({"indices": [2**63]})]}, f"handles[0].select.indices: index {2**63} out of range"),
    (
        {"handles": [handle({"indices": [-(2**63) - 1]})]},
        f"handles[0].select.indices: index {-(2**63) - 1} out of range",
    ),
    ({"handles": [handle(transform={})]}, "handles[0].transform: empty transform"),
    (
        {"handles": [handle(transform={"translate": [1, 2]})]},
        "handles[0].transform.translate: expected 3 numbers, got [1, 2]",
    ),
    (
        {"handles": [handle(transform={"rotate": {"axis": [1, 2], "degrees": 3}})]},
        "handles[0].transform.rotate.axis: expected 3 numbers, got [1, 2]",
    ),
    (
        {"handles": [handle(transform={"rotate": {"axis": [0, 0, 1], "degrees": 3, "center": [1]}})]},
        "handles[0].transform.rotate.center: expected 3 numbers, got [1]",
    ),
    (
        {"handles": [handle(transform={"rotate": {"axis": [0, 0, 1], "degrees": "ten"}})]},
        "handles[0].transform.rotate.degrees: expected a number, got 'ten'",
    ),
    ({"handles": [handle(transform={"scale": 10**400})]}, "handles[0].transform.scale: is too large"),
    ({"handles": [handle()], "frames": "2"}, "frames: expected an integer >= 1, got '2'"),
]


@pytest.mark.parametrize("data, message", EXACT)
def test_error_messages_are_exactly_source_key_problem(data, message):
    with pytest.raises(NerfEditError) as err:
        parse_edit_spec(data, allowed_keys=("handles",), source="e.json")
    assert str(err.value) == f"e.json: {message}"


def test_parse_defaults_kinds_extras_and_extreme_indices():
    parsed = parse_edit_spec({"handles": [handle({"box": {"min": [0, 0, 0], "max": [0, 0, 0]}})]})  # min = max
    assert parsed.source == "<edit spec>" and parsed.base_dir == Path(".") and not parsed.frames_given
    assert parsed.extra == {} and parsed.handles[0].selection.kind == "box"
    with pytest.raises(NerfEditError, match="^<edit spec>: frames: "):
        parse_edit_spec({"frames": 0})
    data = {"handles": [handle({"indices": [-(2**63), 2**63 - 1]})], "frames": 3, "mesh": "m.ply"}
    parsed = parse_edit_spec(data, ("handles", "mesh"))
    assert parsed.frames_given and parsed.extra == {"mesh": "m.ply"} and parsed.handles[0].selection.kind == "indices"
    assert parsed.handles[0].selection.params["indices"].tolist() == [-(2**63), 2**63 - 1]
    with pytest.raises(NerfEditError, match=r"^e\.json: handles: no handles given$"):
        parse_edit_spec({"frames": 2}, source="e.json").handle_targets(GRID)
    assert check_keys({}, ("a",), "s", "") == {}
    with pytest.raises(NerfEditError, match="^s: a: missing$"):
        check_keys({}, ("a",), "s", "", required=("a",))
    assert number(-1, "s", "k") == -1.0  # only positive=True demands > 0


def test_selection_edges_by_hand():
    ball = spec([handle({"sphere": {"center": [0, 0, 0], "radius": 0.5}})])  # the centre and its 6 grid neighbours
    assert len(ball.handle_targets(GRID)[0]) == 7  # at distance exactly 0.5: inside
    corner = spec([handle({"sphere": {"center": [1, 1, 1], "radius": 0.01}})])
    assert corner.handle_targets(GRID)[0].tolist() == [124]
    for bad, message in (
        ({"indices": [0, 125]}, r"handles\[0\]\.select\.indices: index 125 out of range for 125 points"),
        ({"box": {"min": [5, 5, 5], "max": [6, 6, 6]}}, r"handles\[0\]\.select\.box: selects no points \(of 125\)"),
    ):
        with pytest.raises(NerfEditError, match=f"^e\\.json: {message}$"):
            spec([handle(bad)]).handle_targets(GRID)


def test_integer_points_get_float_targets():
    moved = spec([handle({"indices": [0]}, transform={"translate": [0.5, 0, 0]})])
    _, targets = moved.handle_targets(np.array([[1, 2, 3], [4, 5, 6]]))
    assert targets.tolist() == [[[1.5, 2.0, 3.0]]]


def test_file_errors_name_source_and_key(tmp_path):
    (tmp_path / "a.ply").write_text("x")
    (tmp_path / "b.ply").write_text("x")
    extra = {
        "one": "a.ply",
        "gone": "zz.ply",
        "num": 5,
        "nul": "a\0b",
        "xgone": "X.ply",
        "list": ["b.ply", "a.ply"],
        "bad": ["a.ply", "c.ply"],
    }
    extra |= {"glob": "*.obj", "empty": [], "nullist": ["a\0b"]}
    s = parse_edit_spec({"handles": [handle()], **extra}, ["handles", *extra], "e.json", tmp_path)
    assert s.paths("one") == [tmp_path / "a.ply"] and s.paths("list") == [tmp_path / "b.ply", tmp_path / "a.ply"]
    for call, message in (
        (lambda: s.path("missing"), "missing: missing"),
        (lambda: s.path("num"), "num: expected a file path, got 5"),
        (lambda: s.path("gone"), f"gone: file not found: {tmp_path / 'zz.ply'}"),
        (lambda: s.paths("gone"), f"gone: file not found: {tmp_path / 'zz.ply'}"),
        (lambda: s.paths("xgone"), f"xgone: file not found: {tmp_path / 'X.ply'}"),
        (lambda: s.paths("bad"), f"bad[1]: file not found: {tmp_path / 'c.ply'}"),
        (lambda: s.paths("glob"), "glob: pattern '*.obj' matches no file"),
        (lambda: s.paths("empty"), "empty: expected a file, a glob pattern or a non-empty list of files"),
        (lambda: s.paths("num"), "num: expected a file, a glob pattern or a non-empty list of files"),
    ):
        with pytest.raises(NerfEditError) as err:
            call()
        assert str(err.value) == f"e.json: {message}"
    for call, key in ((lambda: s.path("nul"), "nul"), (lambda: s.paths("nullist"), r"nullist\[0\]")):
        with pytest.raises(NerfEditError, match=f"^e\\.json: {key}: invalid file path 'a\\\\x00b'"):
            call()


def test_json_suffix_picks_the_json_parser_and_errors_are_one_line(tmp_path):
    import yaml

    for name in ("e.json", "E.JSON"):
        (tmp_path / name).write_text("{")
        with pytest.raises(NerfEditError, match=r"cannot parse \(Expecting property name"):
            load_edit_spec(tmp_path / name)
    (tmp_path / "e.yaml").write_text("a: [")
    with pytest.raises(yaml.YAMLError) as parser:
        yaml.safe_load("a: [")
    with pytest.raises(NerfEditError) as err:
        load_edit_spec(tmp_path / "e.yaml")
    assert str(err.value) == f"{tmp_path / 'e.yaml'}: cannot parse ({parser.value})".replace("\n", " ")
    (tmp_path / "latin.json").write_bytes(b"\xff\xfe")
    with pytest.raises(NerfEditError, match="latin.json: cannot read"):
        load_edit_spec(tmp_path / "latin.json")
