"""Property tests (hypothesis) of edit specs: every generated good spec loads and binds; every mutation of one that
is bad by construction (unknown key, missing required key, wrong type, NaN/Inf/huge number, wrong shape, empty
list, out-of-range index, truncated or garbled file) raises NerfEditError naming the file, never another exception.

Specs go through ``load_edit_spec`` (JSON and YAML) and the deformer's ``bind`` on a small icosphere, since the
deformer-specific keys are validated there.
"""

from __future__ import annotations

import copy
import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from tree_edits import nodes
from tree_edits import replaced as replace_node

from deformers.arap import ArapConfig, ArapDeformer
from deformers.cage import CageConfig, CageDeformer
from deformers.mesh import MeshConfig, MeshDeformer
from nerfedit_plugin.edit.spec import load_edit_spec, parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh

SETTINGS = dict(deadline=None, derandomize=True, suppress_health_check=list(HealthCheck), database=None)
SCALE = int(os.environ.get("NERFEDIT_PROPERTY_SCALE", "1"))  # multiply example counts for a deeper local run

_ico = trimesh.creation.icosphere(subdivisions=1)
REST = SurfaceMesh(np.asarray(_ico.vertices), np.asarray(_ico.faces))
N = REST.n_vertices
CAGE = REST.with_vertices(REST.vertices * 1.6)
HUGE = 10**400  # a JSON/YAML integer beyond float range

DEFORMERS = {"arap": (ArapConfig, ArapDeformer), "mesh": (MeshConfig, MeshDeformer), "cage": (CageConfig, CageDeformer)}

# ---- schema: kind of every node, by path pattern ("*" = any list index) -------------------------------------------
SCHEMA = {
    ("handles",): "handles",
    ("handles", "*"): "closed",
    ("handles", "*", "select"): "closed",
    ("handles", "*", "select", "box"): "closed",
    ("handles", "*", "select", "box", "min"): "vector",
    ("handles", "*", "select", "box", "max"): "vector",
    ("handles", "*", "select", "sphere"): "closed",
    ("handles", "*", "select", "sphere", "center"): "vector",
    ("handles", "*", "select", "sphere", "radius"): "positive",
    ("handles", "*", "select", "indices"): "indices",
    ("handles", "*", "fixed"): "bool",
    ("handles", "*", "transform"): "closed",
    ("handles", "*", "transform", "translate"): "vector",
    ("handles", "*", "transform", "rotate"): "closed",
    ("handles", "*", "transform", "rotate", "axis"): "vector",
    ("handles", "*", "transform", "rotate", "degrees"): "number",
    ("handles", "*", "transform", "rotate", "center"): "vector",
    ("handles", "*", "transform", "scale"): "positive",
    ("frames",): "frames",
    ("deformed",): "paths",
    ("deformed", "*"): "path",
    ("cage",): "path",
    ("deformed_cage",): "path",
}
# Deleting these always breaks a good spec (the cage's "cage" is not: it falls back to "auto").
REQUIRED = {
    ("handles",),
    ("handles", "*", "select"),
    ("handles", "*", "select", "box", "min"),
    ("handles", "*", "select", "box", "max"),
    ("handles", "*", "select", "sphere", "center"),
    ("handles", "*", "select", "sphere", "radius"),
    ("handles", "*", "fixed"),
    ("handles", "*", "transform"),
    ("handles", "*", "transform", "rotate", "axis"),
    ("handles", "*", "transform", "rotate", "degrees"),
    ("deformed",),
    ("deformed_cage",),
}
_NUMBER_BAD = ["30", None, [30], {}, True, math.nan, math.inf, -math.inf, HUGE]
BAD_VALUES = {
    "vector": [
        ["a", 0, 0],
        [0, 0],
        [0, 0, 0, 0],
        [[0, 0, 0]],
        "0 0 0",
        None,
        {},
        3.0,
        [],
        [math.nan, 0, 0],
        [0, math.inf, 0],
        [0, 0, -math.inf],
        [HUGE, 0, 0],
    ],
    "number": _NUMBER_BAD,
    "positive": _NUMBER_BAD + [0, -1, -0.5],
    "frames": [0, -1, 1.5, "2", True, None, math.nan, [2], {}],
    "bool": [1, 0, "true", None, [], {}],
    "indices": [[], "0", [1.5], [True], [-1], [N], [2**70], [HUGE], None, {}, [[0]]],
    "path": [3, None, [], {}, "", "missing.ply", "a\x00b.ply", True],
    "paths": [3, None, [], {}, "", "missing.ply", "nothing*.ply", "a\x00b.ply", ["missing.ply"]],
    "handles": [[], {}, "x", None, 1],
    "closed": [[], "x", None, 1, True],
}


def pattern(path: tuple) -> tuple:
    return tuple("*" if isinstance(p, int) else p for p in path)


def replaced(tree, path, value):
    """``tree`` with the node at ``path`` set to ``value``, or deleted for :data:`_DELETE`."""
    return replace_node(tree, path, value, delete=value is _DELETE)


_DELETE = object()


@st.composite
def bad_mutation(draw, good: dict, schema: dict, required: set, bad_values: dict, closed: tuple = ("closed",)):
    """Mutations of ``good`` at one drawn node that are invalid by construction → [(tree, description)]."""
    candidates = []
    for path, value in nodes(good):
        kind = schema.get(pattern(path))
        if kind in bad_values:
            candidates += [("value", path, kind)]
        if pattern(path) in required:
            candidates += [("delete", path, None)]
        if kind in closed and isinstance(value, dict):
            candidates += [("unknown", path, None)]
    candidates.append(("unknown", (), None))
    op, path, kind = draw(st.sampled_from(candidates))
    where = ".".join(map(str, path))
    if op == "value":  # every bad value of the kind, so that each example covers them all
        return [(replaced(good, path, copy.deepcopy(bad)), f"{where} = {bad!r}") for bad in bad_values[kind]]
    if op == "delete":
        return [(replaced(good, path, _DELETE), f"delete {where}")]
    return [(replaced(good, path + ("bogus_key",), 1), f"unknown key under {where or 'top level'}")]


# ---- good specs ----------------------------------------------------------------------------------------------------
coord = st.floats(-2.0, 2.0, allow_nan=False)
vec3 = st.tuples(coord, coord, coord).map(list)
axis = vec3.filter(lambda v: np.linalg.norm(v) > 1e-3)


@st.composite
def selection(draw, points: np.ndarray) -> dict:
    kind = draw(st.sampled_from(["box", "sphere", "indices"]))
    anchor = points[draw(st.integers(0, len(points) - 1))]
    if kind == "box":
        lo = draw(st.tuples(*[st.floats(1e-3, 0.5)] * 3))
        hi = draw(st.tuples(*[st.floats(1e-3, 0.5)] * 3))
        return {"box": {"min": (anchor - lo).tolist(), "max": (anchor + hi).tolist()}}
    if kind == "sphere":
        return {"sphere": {"center": anchor.tolist(), "radius": draw(st.floats(1e-3, 1.0))}}
    return {"indices": draw(st.lists(st.integers(0, len(points) - 1), min_size=1, max_size=6))}


@st.composite
def transform(draw) -> dict:
    out = {}
    keys = draw(st.sets(st.sampled_from(["translate", "rotate", "scale"]), min_size=1))
    if "translate" in keys:
        out["translate"] = draw(vec3)
    if "rotate" in keys:
        rot = {"axis": draw(axis), "degrees": draw(st.one_of(st.integers(-360, 360), st.floats(-180.0, 180.0)))}
        if draw(st.booleans()):
            rot["center"] = draw(vec3)
        out["rotate"] = rot
    if "scale" in keys:
        out["scale"] = draw(st.floats(0.5, 2.0))
    return out


@st.composite
def handles(draw, points: np.ndarray) -> list:
    out = []
    for _ in range(draw(st.integers(1, 3))):
        item = {"select": draw(selection(points))}
        if draw(st.booleans()):
            item["fixed"] = True
        else:
            item["transform"] = draw(transform())
        out.append(item)
    return out


@st.composite
def good_spec(draw, deformer: str) -> dict:
    spec = {}
    if draw(st.booleans()):
        spec["frames"] = draw(st.integers(1, 3))
    if deformer == "arap":
        spec["handles"] = draw(handles(REST.vertices))
    elif deformer == "mesh":
        spec["deformed"] = draw(st.sampled_from(["deformed_0.ply", ["deformed_0.ply"], "deformed_*.ply"]))
        if spec["deformed"] == "deformed_*.ply":
            spec.pop("frames", None)  # two files: frames must be 1 or 2
    else:
        spec["cage"] = "cage.ply"
        if draw(st.booleans()):
            spec["handles"] = draw(handles(CAGE.vertices))
        else:
            spec["deformed_cage"] = "cage_deformed.ply"
    return spec


# ---- helpers -------------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """Mesh files the specs name (a deformed copy of the rest mesh, a cage around it and a moved cage)."""
    root = tmp_path_factory.mktemp("spec-props")
    REST.with_vertices(REST.vertices * 1.1).save(root / "deformed_0.ply")
    REST.with_vertices(REST.vertices * 0.9).save(root / "deformed_1.ply")
    CAGE.save(root / "cage.ply")
    CAGE.with_vertices(CAGE.vertices + [0.1, 0.0, 0.0]).save(root / "cage_deformed.ply")
    return root


def dump(data, suffix: str) -> str:
    return json.dumps(data) if suffix == ".json" else yaml.safe_dump(data)


def write_spec(workdir: Path, text: str | bytes, suffix: str) -> Path:
    fd, name = tempfile.mkstemp(suffix=suffix, prefix="edit", dir=workdir)
    path = Path(name)
    with open(fd, "wb") as f:
        f.write(text.encode() if isinstance(text, str) else text)
    return path


def load_and_bind(path: Path, deformer: str):
    config_cls, deformer_cls = DEFORMERS[deformer]
    spec = load_edit_spec(path, deformer_cls.spec_keys)
    config_cls().setup().bind(REST, spec)
    return spec


def check_error(exc: NerfEditError, path: Path, workdir: Path) -> None:
    """The message names the spec file (or, for a bad mesh file it names, that file) on one line."""
    message = str(exc)
    assert str(path) in message or str(workdir) in message, message


# ---- properties ----------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".json", ".yaml"])
@pytest.mark.parametrize("deformer", sorted(DEFORMERS))
@settings(max_examples=20 * SCALE, **SETTINGS)
@given(data=st.data())
def test_good_specs_load_and_bind(workdir, deformer, suffix, data):
    spec = data.draw(good_spec(deformer))
    path = write_spec(workdir, dump(spec, suffix), suffix)
    parsed = load_and_bind(path, deformer)
    assert parsed.frames == spec.get("frames", 1)
    assert parsed.source == str(path)


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
@pytest.mark.parametrize("deformer", sorted(DEFORMERS))
@settings(max_examples=40 * SCALE, **SETTINGS)
@given(data=st.data())
def test_bad_specs_raise_nerfediterror_naming_the_file(workdir, deformer, suffix, data):
    good = data.draw(good_spec(deformer))
    for bad, what in data.draw(bad_mutation(good, SCHEMA, REQUIRED, BAD_VALUES)):
        path = write_spec(workdir, dump(bad, suffix), suffix)
        with pytest.raises(NerfEditError) as info:
            load_and_bind(path, deformer)
            pytest.fail(f"accepted a bad spec ({what}): {bad}")
        check_error(info.value, path, workdir)


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
@settings(max_examples=100 * SCALE, **SETTINGS)
@given(data=st.data())
def test_garbled_files_never_crash(workdir, suffix, data):
    """Truncated or byte-garbled files: either still a valid spec, or NerfEditError naming the file."""
    deformer = data.draw(st.sampled_from(sorted(DEFORMERS)))
    raw = dump(data.draw(good_spec(deformer)), suffix).encode()
    cut = data.draw(st.integers(0, len(raw)))
    if data.draw(st.booleans()):
        raw = raw[:cut]  # truncated
    else:
        raw = raw[:cut] + data.draw(st.binary(min_size=1, max_size=4)) + raw[cut + 1 :]
    path = write_spec(workdir, raw, suffix)
    try:
        load_and_bind(path, deformer)
    except NerfEditError as exc:
        check_error(exc, path, workdir)


json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.just(HUGE)
    | st.floats()
    | st.text(max_size=8)
    | st.sampled_from(["box", "sphere", "indices", "min", "max", "center", "radius", "handles", "select"]),
    lambda children: (
        st.lists(children, max_size=4)
        | st.dictionaries(
            st.sampled_from(["handles", "select", "box", "sphere", "indices", "fixed", "transform", "frames", "x"])
            | st.sampled_from(["min", "max", "center", "radius", "translate", "rotate", "scale", "axis", "degrees"]),
            children,
            max_size=4,
        )
    ),
    max_leaves=20,
)


@settings(max_examples=300 * SCALE, **SETTINGS)
@given(data=json_values, good=handles(REST.vertices))
def test_arbitrary_data_parses_or_raises_nerfediterror(data, good):
    """Random JSON-like trees (also spliced into a good handle list) as a spec: parsed, or NerfEditError naming the
    source; a parsed spec's handles resolve against the mesh or raise NerfEditError."""
    for candidate in (data, {"handles": data}, {"handles": good + [data]}, {"handles": [{"select": data}]}):
        try:
            spec = parse_edit_spec(candidate, ArapDeformer.spec_keys, source="SPEC")
            spec.handle_targets(REST.vertices)
        except NerfEditError as exc:
            assert str(exc).startswith("SPEC: "), str(exc)
