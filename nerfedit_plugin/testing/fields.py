"""Conformance kit for field plugins (group ``nerfedit.fields``), the counterpart of
:mod:`nerfedit_plugin.testing.deformers`.

A field author calls it from their own pytest module, one test case per property::

    from nerfedit_plugin.testing import parametrize_with_checks

    @parametrize_with_checks(MyFieldConfig())          # or skip=("extract",) …
    def test_conformance(check):
        check()

or all at once with ``check_field(MyFieldConfig())`` (stops at the first failure). :func:`field_checks` lists the
``(name, check)`` pairs both use, one per entry of :data:`CHECKS`; the checks of one call share one field, built on
first use by :func:`build_field`.

Checks (each a public function taking the built field or its config):
``config`` (dataclass with a docstring per field, lossless YAML round trip, ``_target`` a Field subclass with a
valid ``kind``/``data``), ``query`` (shapes, dtypes, device, finite values, colours in [0,1], densities ≥ 0,
deterministic, independent of the direction unless ``view_dependent``, ``occupied`` a bool mask or None; not for a
field with ``rendering = "primitives"``, which has no point queries: it gets no ``query`` case),
``render`` (a small render is ``(H,W,3)``, float, finite, in [0,1], deterministic and shows the field),
``checkpoint`` (save → load through the registry gives the same queries — the same renders for a primitives field;
another backend's name is refused), ``identity`` (rendering through an identity DeformationField equals the unedited
render — the renderer's contract for every backend) and ``extract`` (a SurfaceMesh inside the scene box, or a
ValueError when the level is outside the field's range).

A field made from a model file is built from the kit's coloured mesh written as a PLY, or from the file that
``model(folder)`` writes (a backend whose model files are not meshes passes ``model=``).
"""

from __future__ import annotations

import dataclasses
import functools
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.data.cameras import Cameras, look_at
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.fields.base import Field, FieldConfig
from nerfedit_plugin.fields.checkpoint import backend_name, load_field
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.render.renderer import RenderConfig, render_image
from nerfedit_plugin.testing.deformers import check_documented_round_trip, default_mesh, select_checks

BOX = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
"""Scene box of fields built from a config by the kit."""


def coloured_mesh() -> SurfaceMesh:
    """The kit's mesh for mesh-built fields: :func:`nerfedit_plugin.testing.deformers.default_mesh` scaled into
    :data:`BOX`, coloured by position."""
    mesh = default_mesh()
    v = mesh.vertices - mesh.vertices.mean(0)
    v = 0.8 * v / np.abs(v).max()
    return SurfaceMesh(v, mesh.faces, (v + 1.0) / 2.0)


def write_coloured_mesh(folder: Path) -> Path:
    """Write :func:`coloured_mesh` as ``folder/model.ply``; returns the path (the kit's default model file)."""
    path = Path(folder) / "model.ply"
    coloured_mesh().save(path)
    return path


def build_field(config: FieldConfig, model: Callable[[Path], Path] | None = None) -> Field:
    """The field the kit tests: ``config.setup(scene_bbox=BOX)`` (the backend's initial state) for a field made from
    a dataset (unless it is made from model files too and ``model`` is given), else ``from_file`` of the model file
    ``model(folder)`` writes into a temporary folder and returns (default :func:`write_coloured_mesh`). The model
    should lie in :data:`BOX` and be visible from outside it."""
    target = config._target
    if "dataset" in target.sources and (model is None or "model" not in target.sources):
        return config.setup(scene_bbox=BOX.clone())
    with tempfile.TemporaryDirectory() as folder:
        path = (write_coloured_mesh if model is None else model)(Path(folder))
        return target.from_file(path, config)


def _probe(n: int = 2000, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    points = BOX[0] - 0.2 + torch.rand(n, 3, generator=g) * (BOX[1] - BOX[0] + 0.4)
    return points, torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)


def check_config(config: Any) -> None:
    """A FieldConfig dataclass, a docstring per field, a lossless YAML round trip, a Field ``_target``."""
    name = type(config).__name__
    assert dataclasses.is_dataclass(config) and isinstance(config, FieldConfig), (
        f"{name}: a field config must be a dataclass subclassing nerfedit_plugin.fields.base.FieldConfig"
    )
    target = config._target
    assert isinstance(target, type) and issubclass(target, Field), f"{name}._target is {target!r}, not a Field"
    assert target.kind in ("density", "sdf"), f"{target.__name__}.kind must be 'density' or 'sdf', not {target.kind!r}"
    sources = set(target.sources)
    assert sources and sources <= {"dataset", "model"}, (
        f"{target.__name__}.sources must be a non-empty subset of {{'dataset', 'model'}}, not {sources}"
    )
    if "model" in sources:
        assert target.from_file.__func__ is not Field.from_file.__func__, (
            f"{target.__name__}: sources has 'model', which needs from_file()"
        )
    if "dataset" in sources:
        assert target.fit is not Field.fit, f"{target.__name__}: sources has 'dataset', which needs fit()"
    assert target.rendering in ("rays", "primitives"), (
        f"{target.__name__}.rendering must be 'rays' or 'primitives', not {target.rendering!r}"
    )
    if target.rendering == "primitives":
        assert target.render is not Field.render, f"{target.__name__}: rendering = 'primitives' needs render()"
    check_documented_round_trip(config)


def _same_queries(a: Field, b: Field, what: str) -> None:
    if a.rendering == "primitives":
        camera = _view(a)
        with torch.no_grad():
            same = torch.equal(render_image(a, camera, 0, RenderConfig()), render_image(b, camera, 0, RenderConfig()))
        assert same, f"{type(a).__name__}: {what} changes the render"
        return
    points, dirs = _probe()
    with torch.no_grad():
        for x, y, out in zip(a.query(points, dirs), b.query(points, dirs), ("density/sdf", "rgb")):
            assert torch.equal(x, y), f"{type(a).__name__}: {what} changes the {out} of query()"


def check_query(field: Field) -> None:
    """``query`` returns ``(M,)`` and ``(M,3)`` float tensors on the points' device, finite, rgb in [0,1],
    density ≥ 0 (density fields), the same twice (and for any direction unless ``view_dependent``); ``occupied`` is
    None or an ``(M,)`` bool mask. Nothing to check for a field with ``rendering = "primitives"`` (no point
    queries)."""
    if field.rendering == "primitives":
        return
    name = type(field).__name__
    points, dirs = _probe()
    with torch.no_grad():
        value, rgb = field.query(points, dirs)
    assert value.shape == (len(points),) and rgb.shape == (len(points), 3), (
        f"{name}.query: expected shapes (M,) and (M,3), got {tuple(value.shape)} and {tuple(rgb.shape)}"
    )
    assert value.dtype.is_floating_point and rgb.dtype.is_floating_point, f"{name}.query: outputs must be float"
    assert value.device == points.device and rgb.device == points.device, f"{name}.query: outputs on another device"
    assert torch.isfinite(value).all() and torch.isfinite(rgb).all(), f"{name}.query: non-finite outputs"
    assert rgb.min() >= 0 and rgb.max() <= 1, f"{name}.query: colours outside [0, 1]"
    if field.kind == "density":
        assert value.min() >= 0, f"{name}.query: negative density"
    _same_queries(field, field, "querying again")
    if not field.view_dependent:
        turned = torch.nn.functional.normalize(
            torch.randn(dirs.shape, generator=torch.Generator().manual_seed(1)), dim=-1
        )
        with torch.no_grad():
            assert all(torch.equal(x, y) for x, y in zip(field.query(points, dirs), field.query(points, turned))), (
                f"{name}.query: the colour depends on the direction, but view_dependent is False"
            )
    occupied = field.occupied(points)
    assert occupied is None or (occupied.dtype == torch.bool and occupied.shape == (len(points),)), (
        f"{name}.occupied: expected None or an (M,) bool mask"
    )


def check_checkpoint(field: Field) -> None:
    """``save`` then ``load_field`` (through the registry) rebuilds a field with the same queries; loading it as
    another backend is refused with a NerfEditError."""
    name = backend_name(type(field.config))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "field.pt"
        field.save(path)
        loaded = load_field(path, backend=name)
        assert type(loaded) is type(field), f"{name}: loaded a {type(loaded).__name__}"
        _same_queries(field, loaded, "a checkpoint round trip")
        try:
            load_field(path, backend=name + "-other")
        except NerfEditError:
            pass
        else:
            raise AssertionError(f"{name}: a checkpoint loaded as another backend without an error")


def _cube_tets(low: np.ndarray, high: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The box ``[low, high]`` as 6 positively oriented Kuhn tets."""
    from nerfedit_plugin.geometry.tets import kuhn_grid, orient_tets

    vertices, tets = kuhn_grid(1, low, high)
    return vertices, orient_tets(vertices, tets)


def _view(field: Field, size: int = 24) -> Cameras:
    """A camera outside the scene box looking at its centre."""
    box = field.scene_bbox.detach().cpu().double().numpy()
    centre, half = box.mean(0), (box[1] - box[0]) / 2
    eye = torch.from_numpy(centre + 3.0 * np.linalg.norm(half) * np.array([0.6, -0.5, 0.62]))
    c2w = look_at(eye[None], torch.from_numpy(centre)[None]).to(field.scene_bbox.device)
    return Cameras.from_fov(c2w, size, size, 0.7)


def check_render(field: Field, size: int = 24) -> None:
    """``render_image`` of a camera looking at the scene box: ``(H,W,3)`` float on the field's device, finite, in
    [0, 1], the same twice, and not the background alone (the kit's model is in view)."""
    name = type(field).__name__
    camera = _view(field, size)
    config = RenderConfig(n_samples=64, background=(1.0, 1.0, 1.0))
    with torch.no_grad():
        image = render_image(field, camera, 0, config)
        again = render_image(field, camera, 0, config)
    assert tuple(image.shape) == (size, size, 3), f"{name}: render shape {tuple(image.shape)}, not {(size, size, 3)}"
    assert image.dtype.is_floating_point and image.device == field.scene_bbox.device, (
        f"{name}: the render must be a float tensor on the field's device"
    )
    assert torch.isfinite(image).all() and image.min() >= 0 and image.max() <= 1, f"{name}: render outside [0, 1]"
    assert torch.equal(image, again), f"{name}: two renders of the same camera differ"
    assert (image < 1 - 1e-3).any(), f"{name}: the render shows nothing but the background"


def check_identity(field: Field, size: int = 24) -> None:
    """Rendering through an identity DeformationField (a box proxy around part of the scene) equals the unedited
    render of the same camera."""
    box = field.scene_bbox.detach().cpu().double().numpy()
    centre, half = box.mean(0), (box[1] - box[0]) / 2
    vertices, tets = _cube_tets(centre - 0.6 * half, centre + 0.3 * half)
    identity = DeformationField.identity(vertices, tets)
    camera = _view(field, size)
    config = RenderConfig(n_samples=64)
    with torch.no_grad():
        plain = render_image(field, camera, 0, config)
        bent = render_image(field, camera, 0, config, deformation=identity)
    error = float((plain - bent).abs().max())
    assert error < 1e-4, f"{type(field).__name__}: the identity deformation changes the render (max error {error:.2e})"


def check_extract(field: Field, resolution: int = 24) -> None:
    """``extract_mesh`` returns a SurfaceMesh with faces and vertices within the scene box, or raises ValueError
    (no surface at the level)."""
    try:
        mesh = field.extract_mesh(resolution)
    except ValueError:
        return
    name = type(field).__name__
    assert isinstance(mesh, SurfaceMesh) and len(mesh.faces) > 0, f"{name}.extract_mesh: expected a SurfaceMesh"
    box = field.scene_bbox.detach().cpu().double().numpy()
    slack = 1e-6 * np.linalg.norm(box[1] - box[0])
    assert (mesh.vertices >= box[0] - slack).all() and (mesh.vertices <= box[1] + slack).all(), (
        f"{name}.extract_mesh: vertices outside the scene box"
    )


CHECKS: dict[str, Callable] = {
    "config": check_config,
    "query": check_query,
    "render": check_render,
    "checkpoint": check_checkpoint,
    "identity": check_identity,
    "extract": check_extract,
}
"""Check name → function: ``config`` takes the config, the others the field :func:`build_field` makes of it."""


def run_check(
    name: str,
    config: FieldConfig,
    field: Callable[[], Field] | None = None,
    model: Callable[[Path], Path] | None = None,
) -> None:
    """Run the check ``name`` of :data:`CHECKS` on ``config`` (``config``) or on ``field()`` (default: a new
    :func:`build_field` of ``config`` and ``model``)."""
    if name == "config":
        CHECKS[name](config)
    else:
        CHECKS[name](build_field(config, model) if field is None else field())


def field_checks(
    config: FieldConfig, *, skip: Iterable[str] = (), model: Callable[[Path], Path] | None = None
) -> list[tuple[str, functools.partial]]:
    """``[(name, check), ...]`` for every check in :data:`CHECKS` not named in ``skip`` (nor ``query`` for a
    field with ``rendering = "primitives"``): ``check()`` runs that one property. The checks of one call share one
    field, built by :func:`build_field` (of ``model``'s file for a field made from a model) when the first of them
    needs it (not here: nothing runs until a check is called)."""
    build = functools.partial(build_field, config) if model is None else functools.partial(build_field, config, model)
    field = functools.cache(build)
    names = select_checks(CHECKS, skip)
    if getattr(config._target, "rendering", "rays") == "primitives":
        names = [name for name in names if name != "query"]
    return [(name, functools.partial(run_check, name, config, field=field)) for name in names]


def check_field(config: FieldConfig, *, skip: Iterable[str] = (), model: Callable[[Path], Path] | None = None) -> None:
    """Run every check on ``config`` and the field :func:`build_field` makes of it, except those in ``skip``."""
    for _, check in field_checks(config, skip=skip, model=model):
        check()
