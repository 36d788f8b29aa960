"""Conformance kit for deformer plugins (like scikit-learn's ``check_estimator``).

A plugin author calls it from their own pytest module, one test case per property::

    from nerfedit_plugin.testing import parametrize_with_checks

    @parametrize_with_checks(MyConfig())                      # built-in mesh + generic handle edit
    def test_conformance(check):
        check()

    @parametrize_with_checks(MyConfig(), edit={"twist": {...}}, identity_edit={"twist": {"degrees": 0}},
                             skip=("rigid",))
    def test_conformance_with_files(check, tmp_path):
        ...                                                   # write the files the edit names into tmp_path
        check(base_dir=tmp_path)                              # keywords given to the call override the bound ones

or all at once with ``check_deformer(MyConfig(), ...)`` (same arguments; stops at the first failure).
:func:`deformer_checks` lists the ``(name, check)`` pairs both use: one per entry of :data:`CHECKS` (name →
public function such as :func:`check_identity`, with the same leading arguments, to run one property alone).
Every check raises ``AssertionError`` naming the plugin and the property it violates. Edits are plain dicts (as
read from JSON/YAML); the kit parses them with :func:`nerfedit_plugin.edit.spec.parse_edit_spec` using the
deformer's ``spec_keys``, exactly as the CLI does.

Identity and rigid variants of ``edit`` are found in this order:

1. the ``identity_edit=`` / ``rigid_edit=`` dicts passed by the caller;
2. the Deformer's classmethod hooks ``identity_edit(edit, rest) -> dict | None`` and
   ``rigid_edit(edit, rest) -> dict | None``, declared on the base class returning ``None`` (fall back to 3.);
3. derived from ``edit["handles"]``: identity = every transform replaced by a zero translation; rigid = every
   handle (fixed ones included) given the same rigid motion about the rest bounding-box centre.

If none applies the check raises ``ValueError`` (a usage error, not a conformance failure): pass the dict or
``skip=("identity",)`` / ``skip=("rigid",)``.
"""

from __future__ import annotations

import ast
import copy
import dataclasses
import functools
import importlib
import inspect
import math
import textwrap
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from nerfedit_plugin.config import from_plain, to_plain
from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig, checked_frames, mesh_digest
from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh

KIT_SOURCE = "<conformance kit edit>"

#: rigid motion used for derived rigid edits: rotation (axis, degrees) about the bbox centre, then a translation
#: of ``RIGID_SHIFT`` × bbox diagonal.
RIGID_AXIS = (1.0, 2.0, 0.5)
RIGID_DEGREES = 35.0
RIGID_SHIFT = (0.2, -0.1, 0.15)

#: placements of :func:`check_placement`: name → (scale, offset in rest bbox diagonals along ``PLACEMENT_DIRECTION``);
#: ``x ↦ scale·x + offset``. The scales are powers of two (about 1e-4 and 1e4), so the scaled mesh is exactly the
#: mesh scaled, not a rounded copy: set-up steps that are discontinuous in their input (an alpha wrap of a symmetric
#: mesh changes under 1-ulp perturbations) then still give the scaled result.
PLACEMENTS = {
    "scaled by 2^-13": (2.0**-13, 0.0),
    "scaled by 2^13": (2.0**13, 0.0),
    "moved 1e5 diagonals away": (1.0, 1e5),
}
PLACEMENT_DIRECTION = (0.6, -0.48, 0.64)


# ---- defaults --------------------------------------------------------------------------------------------------
def default_mesh() -> SurfaceMesh:
    """A small closed test surface: an icosphere (162 vertices) stretched into an ellipsoid along z."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2)
    return SurfaceMesh(np.asarray(sphere.vertices) * [0.4, 0.5, 1.0], np.asarray(sphere.faces))


def default_edit(rest: SurfaceMesh) -> dict:
    """A generic two-frame handle edit: pin the bottom quarter (along z), move and tilt the top quarter.

    Boxes extend far beyond the mesh in x/y (and below/above it in z), so the same edit also selects the
    vertices of a cage or proxy around ``rest``.
    """
    lo, hi = rest.vertices.min(0), rest.vertices.max(0)
    ext, big = hi - lo, 10.0 * rest.bbox_diagonal
    z_low, z_high = lo[2] + 0.25 * ext[2], hi[2] - 0.25 * ext[2]
    return {
        "handles": [
            {
                "select": {
                    "box": {"min": [lo[0] - big, lo[1] - big, lo[2] - big], "max": [hi[0] + big, hi[1] + big, z_low]}
                },
                "fixed": True,
            },
            {
                "select": {
                    "box": {"min": [lo[0] - big, lo[1] - big, z_high], "max": [hi[0] + big, hi[1] + big, hi[2] + big]}
                },
                "transform": {
                    "translate": [0.15 * ext[0], 0.0, 0.05 * ext[2]],
                    "rotate": {"axis": [0, 1, 0], "degrees": 20},
                },
            },
        ],
        "frames": 2,
    }


# ---- running a deformer ------------------------------------------------------------------------------------------
def _name(config: Any) -> str:
    return type(config).__name__


def _resolve(config: Any, rest: SurfaceMesh | None, edit: dict | None) -> tuple[SurfaceMesh, dict]:
    rest = default_mesh() if rest is None else rest
    if edit is None:
        if "handles" not in config._target.spec_keys:
            raise ValueError(
                f"{_name(config)}: its spec has no 'handles' key, so the kit has no default edit: pass edit="
            )
        edit = default_edit(rest)
    return rest, edit


def _copy_mesh(rest: SurfaceMesh) -> SurfaceMesh:
    colors = None if rest.vertex_colors is None else rest.vertex_colors.copy()
    return SurfaceMesh(rest.vertices.copy(), rest.faces.copy(), colors)


def _bind(config: Any, rest: SurfaceMesh, edit: dict, base_dir: Path | None, deformer: Deformer | None = None):
    """Parse ``edit`` as the CLI does and bind a fresh (or the given) deformer; returns ``(deformer, spec)``."""
    deformer = config.setup() if deformer is None else deformer
    spec = parse_edit_spec(copy.deepcopy(edit), type(deformer).spec_keys, KIT_SOURCE, Path(base_dir or "."))
    deformer.bind(rest, spec)
    return deformer, spec


def run_deformer(config: Any, rest: SurfaceMesh, edit: dict, base_dir: Path | None = None) -> np.ndarray:
    """``config.setup()`` → bind → deform, on a copy of ``rest``; returns the frames (no checks)."""
    deformer, _ = _bind(config, _copy_mesh(rest), edit, base_dir)
    return deformer.deform()


def _frames(config: Any, rest: SurfaceMesh, edit: dict, base_dir: Path | None, what: str) -> np.ndarray:
    """Run and check the output contract (:func:`~nerfedit_plugin.edit.deformer.checked_frames`, float64 exactly);
    ``what`` names the edit in messages."""
    mesh = _copy_mesh(rest)
    digest = mesh_digest(mesh)
    deformer, spec = _bind(config, mesh, edit, base_dir)
    out = deformer.deform()
    name = _name(config)
    try:
        checked_frames(deformer, out, mesh, spec, digest)
    except NerfEditError as exc:
        raise AssertionError(f"{name}: on the {what}: {str(exc).split(': ', 1)[1]}") from None
    assert out.dtype == np.float64, f"{name}: deform() on the {what} returned dtype {out.dtype}, expected float64"
    return out


# ---- placed edits (scale and position) --------------------------------------------------------------------------
def place_handles(edit: dict, scale: float, offset: np.ndarray) -> dict:
    """``edit`` for the rest mesh moved by ``x ↦ scale·x + offset``: handle box corners, sphere centres and rotation
    centres are moved, radii and translations scaled; indices, axes, angles and scale factors stay."""
    out = copy.deepcopy(edit)

    def point(value: Any) -> list:
        return (scale * np.asarray(value, dtype=np.float64) + offset).tolist()

    for handle in out.get("handles", []):
        select = handle.get("select", {})
        if "box" in select:
            select["box"] = {key: point(select["box"][key]) for key in ("min", "max")}
        if "sphere" in select:
            select["sphere"] = {
                "center": point(select["sphere"]["center"]),
                "radius": scale * select["sphere"]["radius"],
            }
        transform = handle.get("transform", {})
        if "translate" in transform:
            transform["translate"] = (scale * np.asarray(transform["translate"], dtype=np.float64)).tolist()
        if "center" in transform.get("rotate", {}):
            transform["rotate"]["center"] = point(transform["rotate"]["center"])
    return out


def placed_edit(config: Any, edit: dict, scale: float, offset: np.ndarray, base_dir, folder: Path) -> dict:
    """``edit`` for the rest mesh moved by ``x ↦ scale·x + offset``: the Deformer's ``placed_edit`` hook places its
    own keys, then :func:`place_handles` the handles. Keys other than ``handles``/``frames`` without the hook are a
    usage error (``ValueError``)."""
    target = config._target
    found = target.placed_edit(copy.deepcopy(edit), scale, offset, Path(base_dir or "."), folder)
    if found is None:
        own = sorted(set(edit) - {"handles", "frames"})
        if own:
            raise ValueError(
                f"{_name(config)}: the kit cannot place the edit's keys {own} ({target.__name__}.placed_edit returned "
                "None): implement the hook or pass skip=('placement',)"
            )
        found = copy.deepcopy(edit)
    return place_handles(found, scale, offset)


def placed_mesh(rest: SurfaceMesh, scale: float, offset: np.ndarray) -> SurfaceMesh:
    """``rest`` moved by ``x ↦ scale·x + offset`` (faces and colours kept)."""
    colors = None if rest.vertex_colors is None else rest.vertex_colors.copy()
    return SurfaceMesh(scale * rest.vertices + offset, rest.faces.copy(), colors)


def placed_mesh_files(value: Any, scale: float, offset: np.ndarray, base_dir: Path, folder: Path) -> Any:
    """For ``placed_edit`` hooks: the mesh files a spec value names (a file, a glob pattern or a list, relative to
    ``base_dir``) written moved by ``x ↦ scale·x + offset`` into ``folder`` under the same relative names; returns
    ``value`` (it names the placed files relative to ``folder``)."""
    for name in [value] if isinstance(value, str) else value:
        pattern = any(ch in str(name) for ch in "*?[")
        for path in sorted(Path(base_dir).glob(str(name))) if pattern else [Path(base_dir) / name]:
            target = Path(folder) / path.relative_to(base_dir)
            target.parent.mkdir(parents=True, exist_ok=True)
            placed_mesh(SurfaceMesh.load(path), scale, offset).save(target)
    return value


# ---- identity / rigid variants -----------------------------------------------------------------------------------
def _variant(config: Any, rest: SurfaceMesh, edit: dict, given: dict | None, hook: str, derive: Callable) -> dict:
    if given is not None:
        return given
    found = {"identity_edit": config._target.identity_edit, "rigid_edit": config._target.rigid_edit}[hook](
        copy.deepcopy(edit), rest
    )
    if found is None and isinstance(edit.get("handles"), list):
        found = derive(edit, rest)
    if found is None:
        raise ValueError(
            f"{_name(config)}: cannot derive the {hook.replace('_', ' ')} (no handles in the edit, and "
            f"{config._target.__name__}.{hook} returned None): pass {hook}= or skip=({hook.split('_')[0]!r},)"
        )
    return found


def identity_handles(edit: dict, rest: SurfaceMesh) -> dict:
    """``edit`` with every handle transform replaced by a zero translation (selections unchanged)."""
    out = copy.deepcopy(edit)
    for handle in out["handles"]:
        if "transform" in handle:
            handle["transform"] = {"translate": [0.0, 0.0, 0.0]}
    return out


def rigid_handles(edit: dict, rest: SurfaceMesh) -> dict:
    """``edit`` with every handle (fixed ones too) moved by one rigid motion about the rest bbox centre."""
    lo, hi = rest.vertices.min(0), rest.vertices.max(0)
    motion = {
        "translate": (np.asarray(RIGID_SHIFT) * rest.bbox_diagonal).tolist(),
        "rotate": {"axis": list(RIGID_AXIS), "degrees": RIGID_DEGREES, "center": ((lo + hi) / 2).tolist()},
    }
    out = copy.deepcopy(edit)
    for handle in out["handles"]:
        handle.pop("fixed", None)
        handle["transform"] = copy.deepcopy(motion)
    return out


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares rigid motion ``target ≈ source @ R.T + t`` (Kabsch/Procrustes); returns ``(R, t, max
    residual)``."""
    cs, ct = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((source - cs).T @ (target - ct))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    t = ct - cs @ rot.T
    return rot, t, float(np.linalg.norm(source @ rot.T + t - target, axis=1).max())


# ---- the checks --------------------------------------------------------------------------------------------------
def _field_docstrings(cls: type) -> set[str]:
    """Names of the fields of ``cls`` (and its bases) followed by a string literal (attribute docstrings)."""
    documented: set[str] = set()
    for klass in cls.__mro__:
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        body = ast.parse(source).body[0].body
        for stmt, nxt in zip(body, body[1:]):
            if (
                isinstance(stmt, ast.AnnAssign)
                and isinstance(stmt.target, ast.Name)
                and isinstance(nxt, ast.Expr)
                and isinstance(nxt.value, ast.Constant)
                and isinstance(nxt.value.value, str)
                and nxt.value.value.strip()
            ):
                documented.add(stmt.target.id)
    return documented


def _resolve_dotted(path: str) -> Any:
    parts = path.split(".")
    for i in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ImportError(path)


def check_config(config: Any) -> None:
    """Config contract: a DeformerConfig dataclass with a docstring per field, ``_target`` a Deformer subclass that
    ``setup()`` builds, valid ``spec_keys``, and a lossless round trip through :func:`to_plain` (YAML-safe)."""
    name = _name(config)
    assert dataclasses.is_dataclass(config) and not isinstance(config, type), (
        f"{name}: config must be a dataclass instance"
    )
    assert isinstance(config, DeformerConfig), (
        f"{name}: config must subclass nerfedit_plugin.edit.deformer.DeformerConfig"
    )
    target = config._target
    assert isinstance(target, type) and issubclass(target, Deformer), (
        f"{name}._target is {target!r}, not a Deformer subclass"
    )
    deformer = config.setup()
    assert isinstance(deformer, target), f"{name}.setup() returned {type(deformer).__name__}, not {target.__name__}"
    keys = target.spec_keys
    assert isinstance(keys, frozenset) and all(isinstance(k, str) for k in keys), (
        f"{target.__name__}.spec_keys must be a frozenset of str, got {keys!r}"
    )
    check_documented_round_trip(config)


def check_documented_round_trip(config: Any) -> None:
    """What every plugin config (deformer or field) owes the CLI and ``config.yml``: a docstring under each public
    field, and a lossless, YAML-safe round trip through :func:`to_plain` / :func:`from_plain` whose ``_target``
    imports back."""
    name = _name(config)
    public = [f.name for f in dataclasses.fields(config) if not f.name.startswith("_")]
    missing = sorted(set(public) - _field_docstrings(type(config)))
    assert not missing, f"{name}: fields without a docstring (a string literal right below the field): {missing}"
    plain = to_plain(config)
    try:
        reloaded = yaml.safe_load(yaml.safe_dump(plain))
    except yaml.YAMLError as exc:
        raise AssertionError(f"{name}: to_plain(config) is not YAML-safe: {plain!r} ({exc})") from exc
    assert reloaded == plain, f"{name}: to_plain(config) does not survive a YAML round trip: {plain!r} -> {reloaded!r}"
    rebuilt = to_plain(from_plain(type(config), plain))
    assert rebuilt == plain, f"{name}: config does not round-trip through to_plain: {plain!r} -> {rebuilt!r}"
    assert _resolve_dotted(plain["_target"]) is config._target, (
        f"{name}: _target {plain['_target']!r} does not import back"
    )


def check_output(config: Any, rest: SurfaceMesh | None = None, edit: dict | None = None, *, base_dir=None) -> None:
    """Output contract on ``edit``: ndarray ``(frames, V, 3)`` float64, finite, rest mesh untouched, something moved."""
    rest, edit = _resolve(config, rest, edit)
    out = _frames(config, rest, edit, base_dir, "edit")
    moved = np.linalg.norm(out - rest.vertices, axis=2).max()
    assert moved > 1e-6 * rest.bbox_diagonal, (
        f"{_name(config)}: the edit moved nothing (pass an edit that moves something)"
    )


def _same(a: Any, b: Any) -> bool:
    """Bitwise equal outputs, NaN equal to NaN (non-finite values are the output check's to report)."""
    floats = isinstance(a, np.ndarray) and a.dtype.kind == "f"
    return np.array_equal(a, b, equal_nan=floats)


def check_deterministic(
    config: Any, rest: SurfaceMesh | None = None, edit: dict | None = None, *, base_dir=None
) -> None:
    """Two fresh binds, and a second bind of the same instance, give bitwise identical frames."""
    rest, edit = _resolve(config, rest, edit)
    first, _ = _bind(config, _copy_mesh(rest), edit, base_dir)
    a = first.deform()
    b = run_deformer(config, rest, edit, base_dir)
    assert _same(a, b), f"{_name(config)}: two binds of the same edit differ by {np.abs(a - b).max():.3g}"
    _bind(config, _copy_mesh(rest), edit, base_dir, deformer=first)
    c = first.deform()
    assert _same(a, c), f"{_name(config)}: re-binding the same instance changed the output by {np.abs(a - c).max():.3g}"


def check_identity(
    config: Any,
    rest: SurfaceMesh | None = None,
    edit: dict | None = None,
    *,
    base_dir=None,
    identity_edit: dict | None = None,
    tol: float = 1e-6,
) -> None:
    """The identity variant of the edit returns the rest vertices (every frame, same order) within ``tol`` × bbox."""
    rest, edit = _resolve(config, rest, edit)
    variant = _variant(config, rest, edit, identity_edit, "identity_edit", identity_handles)
    out = _frames(config, rest, variant, base_dir, "identity edit")
    err = np.linalg.norm(out - rest.vertices, axis=2).max()
    assert err <= tol * rest.bbox_diagonal, (
        f"{_name(config)}: identity edit moved vertices by up to {err:.3g} (> {tol:g} × bbox {rest.bbox_diagonal:.3g})"
    )


def check_rigid(
    config: Any,
    rest: SurfaceMesh | None = None,
    edit: dict | None = None,
    *,
    base_dir=None,
    rigid_edit: dict | None = None,
    rigid_tol: float = 1e-4,
) -> None:
    """The rigid variant moves the whole mesh by one rigid motion per frame (Procrustes residual ≤ ``rigid_tol`` ×
    bbox)."""
    rest, edit = _resolve(config, rest, edit)
    variant = _variant(config, rest, edit, rigid_edit, "rigid_edit", rigid_handles)
    out = _frames(config, rest, variant, base_dir, "rigid edit")
    diag = rest.bbox_diagonal
    for f, frame in enumerate(out):
        _, _, residual = rigid_fit(rest.vertices, frame)
        assert residual <= rigid_tol * diag, (
            f"{_name(config)}: rigid edit, frame {f}: not a rigid motion of the rest mesh "
            f"(Procrustes residual {residual:.3g} > {rigid_tol:g} × bbox {diag:.3g})"
        )
    assert np.linalg.norm(out[-1] - rest.vertices, axis=1).max() > 1e-3 * diag, (
        f"{_name(config)}: rigid edit moved nothing"
    )


def check_placement(
    config: Any,
    rest: SurfaceMesh | None = None,
    edit: dict | None = None,
    *,
    base_dir=None,
    identity_edit: dict | None = None,
    rigid_edit: dict | None = None,
    tol: float = 1e-6,
    rigid_tol: float = 1e-4,
    skip: Iterable[str] = (),
) -> None:
    """Scale and position do not matter: for the rest mesh (and the edit) scaled by about 1e-4 and 1e4 and moved 1e5
    bbox diagonals from the origin (:data:`PLACEMENTS`), the identity and rigid checks hold; scaled, the edit gives
    the scaled frames of the edit (within ``rigid_tol`` × the placed bbox diagonal). (A move rounds every coordinate,
    so it is held to identity and rigidity only.) The identity and rigid checks named in ``skip`` are left out here
    too."""
    import tempfile

    rest, edit = _resolve(config, rest, edit)
    frames = _frames(config, rest, edit, base_dir, "edit")
    direction = np.asarray(PLACEMENT_DIRECTION) / np.linalg.norm(PLACEMENT_DIRECTION)
    for where, (scale, away) in PLACEMENTS.items():
        offset = away * rest.bbox_diagonal * direction
        moved = placed_mesh(rest, scale, offset)
        with tempfile.TemporaryDirectory(prefix="nerfedit-kit-") as folder:
            folder = Path(folder)
            spec, identity, rigid = (
                None if e is None else placed_edit(config, e, scale, offset, base_dir, folder)
                for e in (edit, identity_edit, rigid_edit)
            )
            try:
                if "identity" not in skip:
                    check_identity(config, moved, spec, base_dir=folder, identity_edit=identity, tol=tol)
                if "rigid" not in skip:
                    check_rigid(config, moved, spec, base_dir=folder, rigid_edit=rigid, rigid_tol=rigid_tol)
            except AssertionError as exc:
                raise AssertionError(f"{exc} [rest mesh {where}]") from None
            if away:
                continue
            out = _frames(config, moved, spec, folder, f"edit {where}")
            err = np.linalg.norm(out - (scale * frames + offset), axis=2).max()
            assert err <= rigid_tol * moved.bbox_diagonal, (
                f"{_name(config)}: the edit of the rest mesh {where} differs from the placed edit of the rest mesh by "
                f"{err:.3g} (> {rigid_tol:g} × bbox {moved.bbox_diagonal:.3g})"
            )


def _edge_to_pair_ratio(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Median edge length over the median distance between random vertex pairs (small ⇔ edges join neighbours)."""
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    rng = np.random.default_rng(0)
    pairs = rng.integers(0, len(vertices), size=(4 * len(edges), 2))
    lengths = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    spread = np.linalg.norm(vertices[pairs[:, 0]] - vertices[pairs[:, 1]], axis=1)
    return float(np.median(lengths) / max(np.median(spread), 1e-300))


def check_vertex_order(
    config: Any, rest: SurfaceMesh | None = None, edit: dict | None = None, *, base_dir=None
) -> None:
    """Row i of every output frame is the image of rest vertex i: the rest faces still join nearby points.

    (Identity and rigid checks test the order exactly; this one covers the general edit, where a reordering
    shows up as edges as long as random vertex pairs.)
    """
    rest, edit = _resolve(config, rest, edit)
    base = _edge_to_pair_ratio(rest.vertices, rest.faces)
    if base > 0.5:  # mesh too coarse for the statistic to separate neighbours from random pairs
        return
    out = _frames(config, rest, edit, base_dir, "edit")
    limit = min(0.5, 3.0 * base)
    for f, frame in enumerate(out):
        ratio = _edge_to_pair_ratio(frame, rest.faces)
        assert ratio <= limit, (
            f"{_name(config)}: frame {f}: the rest faces join far-apart output points (median edge / median pair "
            f"distance {ratio:.2f}, rest {base:.2f}): is the vertex order preserved?"
        )


def _numeric_leaves(obj: Any, path: tuple = ()) -> list[tuple]:
    if isinstance(obj, dict):
        return [leaf for k, v in obj.items() for leaf in _numeric_leaves(v, path + (k,))]
    if isinstance(obj, list):
        return [leaf for i, v in enumerate(obj) for leaf in _numeric_leaves(v, path + (i,))]
    return [path] if isinstance(obj, (int, float)) and not isinstance(obj, bool) else []


def _replaced(edit: dict, path: tuple, value: Any) -> dict:
    out = copy.deepcopy(edit)
    node = out
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return out


def malformed_edits(edit: dict, rest: SurfaceMesh, spec_keys: Iterable[str], base_dir=None) -> list[tuple[str, dict]]:
    """Broken variants of a valid ``edit`` that every deformer must reject: ``[(description, spec), ...]``."""
    cases = [("unknown top-level key", {**copy.deepcopy(edit), "nerfedit_kit_unknown_key": 1})]
    leaves = _numeric_leaves(edit)
    for path in dict.fromkeys([leaves[0], leaves[len(leaves) // 2], leaves[-1]]) if leaves else ():
        cases.append((f"NaN at {'.'.join(map(str, path))}", _replaced(edit, path, math.nan)))
    if "handles" in spec_keys and isinstance(edit.get("handles"), list):
        for index in (10**9, -1):
            bad = copy.deepcopy(edit)
            bad["handles"].append({"select": {"indices": [index]}, "fixed": True})
            cases.append((f"out-of-range handle index {index}", bad))
    base = Path(base_dir or ".")
    for key, value in edit.items():
        if isinstance(value, str) and (base / value).is_file():
            cases.append((f"missing file for {key!r}", {**copy.deepcopy(edit), key: "nerfedit-kit-missing-file.ply"}))
    return cases


def check_malformed(
    config: Any,
    rest: SurfaceMesh | None = None,
    edit: dict | None = None,
    *,
    base_dir=None,
    bad_edits: Iterable[dict] = (),
) -> None:
    """Parsing + ``bind`` raise :class:`NerfEditError` (not another exception, not silence) for every variant from
    :func:`malformed_edits` and every spec in ``bad_edits``."""
    rest, edit = _resolve(config, rest, edit)
    cases = malformed_edits(edit, rest, config._target.spec_keys, base_dir)
    cases += [(f"bad_edits[{i}]", bad) for i, bad in enumerate(bad_edits)]
    for what, bad in cases:
        try:
            _bind(config, _copy_mesh(rest), bad, base_dir)
        except NerfEditError as exc:
            assert str(exc).strip(), f"{_name(config)}: {what}: NerfEditError with an empty message"
            continue
        except Exception as exc:
            raise AssertionError(f"{_name(config)}: {what}: raised {exc!r}, expected NerfEditError") from exc
        raise AssertionError(f"{_name(config)}: {what}: accepted (expected NerfEditError from parsing or bind)")


def check_deform_points(
    config: Any, rest: SurfaceMesh | None = None, edit: dict | None = None, *, base_dir=None, tol: float = 1e-6
) -> None:
    """Where ``supports_points()``: ``deform_points(rest vertices, f)`` equals ``deform()[f]`` within ``tol`` × bbox,
    and arbitrary points give finite ``(M, 3)`` float64 without being modified."""
    rest, edit = _resolve(config, rest, edit)
    if not config._target.supports_points():
        return
    name = _name(config)
    deformer, spec = _bind(config, _copy_mesh(rest), edit, base_dir)
    out = deformer.deform()
    lo, hi = rest.vertices.min(0), rest.vertices.max(0)
    probe = np.random.default_rng(0).uniform(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo), size=(64, 3))
    for f in range(len(out)):
        points = rest.vertices.copy()
        mapped = deformer.deform_points(points, f)
        assert np.array_equal(points, rest.vertices), f"{name}: deform_points modified its input"
        assert isinstance(mapped, np.ndarray) and mapped.shape == points.shape and mapped.dtype == np.float64, (
            f"{name}: deform_points returned {getattr(mapped, 'shape', type(mapped))} {getattr(mapped, 'dtype', '')}, "
            f"expected {points.shape} float64"
        )
        err = np.linalg.norm(mapped - out[f], axis=1).max()
        assert err <= tol * rest.bbox_diagonal, (
            f"{name}: frame {f}: deform_points(rest) differs from deform() by {err:.3g}"
        )
        moved = deformer.deform_points(probe.copy(), f)
        assert moved.shape == probe.shape and np.isfinite(moved).all(), (
            f"{name}: frame {f}: deform_points on points around the mesh gave shape {moved.shape} or non-finite values"
        )


CHECKS: dict[str, Callable] = {
    "config": check_config,
    "output": check_output,
    "deterministic": check_deterministic,
    "identity": check_identity,
    "rigid": check_rigid,
    "vertex_order": check_vertex_order,
    "malformed": check_malformed,
    "points": check_deform_points,
    "placement": check_placement,
}


#: the keyword arguments of :func:`check_deformer` each check takes besides ``rest``, ``edit`` and ``base_dir``
#: (``config`` takes the config alone)
OPTIONS: dict[str, tuple[str, ...]] = {
    "identity": ("identity_edit", "tol"),
    "rigid": ("rigid_edit", "rigid_tol"),
    "malformed": ("bad_edits",),
    "points": ("tol",),
    "placement": ("identity_edit", "rigid_edit", "tol", "rigid_tol", "skip"),
}


def select_checks(checks: Iterable[str], skip: Iterable[str]) -> list[str]:
    """The names in ``checks`` (in order) not in ``skip``; a name in ``skip`` that is not a check is a usage error
    (``ValueError``). Shared by both kits."""
    checks, skip = list(checks), set(skip)
    unknown = skip - set(checks)
    if unknown:
        raise ValueError(f"unknown checks in skip: {sorted(unknown)} (known: {checks})")
    return [name for name in checks if name not in skip]


def run_check(
    name: str,
    config: Any,
    rest: SurfaceMesh | None = None,
    edit: dict | None = None,
    *,
    base_dir=None,
    identity_edit: dict | None = None,
    rigid_edit: dict | None = None,
    bad_edits: Iterable[dict] = (),
    tol: float = 1e-6,
    rigid_tol: float = 1e-4,
    skip: Iterable[str] = (),
) -> None:
    """Run the check ``name`` of :data:`CHECKS` with :func:`check_deformer`'s arguments (it takes those it uses;
    ``skip`` tells ``placement`` which checks it must not repeat)."""
    if name == "config":
        CHECKS[name](config)
        return
    given = {
        "identity_edit": identity_edit,
        "rigid_edit": rigid_edit,
        "bad_edits": list(bad_edits),
        "tol": tol,
        "rigid_tol": rigid_tol,
        "skip": tuple(skip),
    }
    CHECKS[name](config, rest, edit, base_dir=base_dir, **{key: given[key] for key in OPTIONS.get(name, ())})


def deformer_checks(
    config: Any,
    rest: SurfaceMesh | None = None,
    edit: dict | None = None,
    *,
    base_dir=None,
    identity_edit: dict | None = None,
    rigid_edit: dict | None = None,
    bad_edits: Iterable[dict] = (),
    tol: float = 1e-6,
    rigid_tol: float = 1e-4,
    skip: Iterable[str] = (),
) -> list[tuple[str, functools.partial]]:
    """``[(name, check), ...]`` for every check in :data:`CHECKS` not named in ``skip`` (arguments as
    :func:`check_deformer`): ``check()`` runs that one property on ``config``. Each ``check`` is a
    :func:`functools.partial` of :func:`run_check` with every argument bound by keyword, so keywords given to the call
    override them (``check(base_dir=tmp_path)``). Nothing runs until a check is called."""
    bound = {
        "rest": rest,
        "edit": edit,
        "base_dir": base_dir,
        "identity_edit": identity_edit,
        "rigid_edit": rigid_edit,
        "bad_edits": tuple(bad_edits),
        "tol": tol,
        "rigid_tol": rigid_tol,
        "skip": tuple(skip),
    }
    return [(name, functools.partial(run_check, name, config, **bound)) for name in select_checks(CHECKS, skip)]


def check_deformer(
    config: Any,
    rest: SurfaceMesh | None = None,
    edit: dict | None = None,
    *,
    base_dir=None,
    identity_edit: dict | None = None,
    rigid_edit: dict | None = None,
    bad_edits: Iterable[dict] = (),
    tol: float = 1e-6,
    rigid_tol: float = 1e-4,
    skip: Iterable[str] = (),
) -> None:
    """Run every check in :data:`CHECKS` except those named in ``skip``; raises AssertionError on the first failure.

    ``rest`` defaults to :func:`default_mesh`, ``edit`` (a valid spec dict that moves something; file paths
    relative to ``base_dir``) to :func:`default_edit`. ``tol`` bounds identity and ``deform_points`` errors,
    ``rigid_tol`` the Procrustes residual, both relative to the rest bounding-box diagonal.
    """
    for _, check in deformer_checks(
        config,
        rest,
        edit,
        base_dir=base_dir,
        identity_edit=identity_edit,
        rigid_edit=rigid_edit,
        bad_edits=bad_edits,
        tol=tol,
        rigid_tol=rigid_tol,
        skip=skip,
    ):
        check()
