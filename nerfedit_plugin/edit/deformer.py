"""The Deformer contract (entry-point group ``nerfedit.deformers``).

Life cycle: ``deformer = config.setup(); deformer.bind(rest, edit); frames = deformer.deform()``.
Required: :meth:`Deformer.bind` and :meth:`Deformer.deform`. Every optional hook is declared here with its default;
docs/plugins.md shows a whole plugin. A deformer may report the progress of a long ``bind`` or ``deform`` through
:attr:`Deformer.on_progress` (the edit job's progress display).
"""

from __future__ import annotations

import abc
import dataclasses
import hashlib
import json
import os
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Literal

import numpy as np

from nerfedit_plugin.config import InstantiateConfig
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.io.atomic import atomic_path
from nerfedit_plugin.timing import Progress, no_progress

if TYPE_CHECKING:
    from nerfedit_plugin.edit.editing import EditingBackend


@dataclasses.dataclass
class DeformerConfig(InstantiateConfig):
    """Base config of every deformer plugin (the first line of a plugin's docstring is its description in
    ``nerfedit edit --help``)."""


@dataclasses.dataclass(frozen=True)
class Overlay:
    """Geometry a deformer adds to the viewer's layers (e.g. a cage): drawn at rest and, when given, deformed."""

    layer: str
    """Layer name the user toggles (``nerfedit view --show``)."""
    rest: SurfaceMesh
    deformed: SurfaceMesh | None = None
    style: Literal["wire", "surface"] = "wire"
    """``wire``: edges in the overlay colour; ``surface``: shaded triangles, in the meshes' vertex colours if any."""


class BindCache:
    """What a deformer binds per rest mesh (a coarse level, weights, a binding), stored by content key.

    ``directory`` (None: nothing is stored, every :meth:`fetch` builds) holds one ``bind-<kind>-<key>.npz`` per
    entry, ``key`` the sha256 of ``kind``, the rest mesh's :func:`mesh_digest` ``digest`` and the JSON of the
    entry's parameters. The edit job gives each deformer the cache of its rest mesh, beside the proxy cache.
    """

    def __init__(self, directory: str | os.PathLike | None = None, digest: str = "") -> None:
        self.directory = None if directory is None else Path(directory)
        self.digest = digest

    def key(self, kind: str, params: dict) -> str:
        """→ hex sha256 of ``kind``, the mesh digest and ``params`` (JSON-able) sorted by key."""
        text = json.dumps({"kind": kind, "mesh": self.digest, "params": params}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def fetch(
        self, kind: str, params: dict, build: Callable[[], dict[str, np.ndarray]]
    ) -> tuple[dict[str, np.ndarray], bool]:
        """``(arrays, hit)``: the entry of ``kind`` with ``params`` (``name → array``, no object arrays) if stored and
        readable, else ``build()``, stored (written atomically) and returned. An unreadable entry is rebuilt with a
        warning."""
        if self.directory is None or not self.digest:
            return build(), False
        path = self.directory / f"bind-{kind}-{self.key(kind, params)}.npz"
        if path.is_file():
            try:
                with np.load(path, allow_pickle=False) as data:
                    return {name: data[name] for name in data.files}, True
            except Exception as exc:  # zipfile, ValueError: not a readable entry
                warnings.warn(f"{path}: unreadable bind cache entry ({exc}); rebuilding it", stacklevel=2)
        arrays = build()
        self.directory.mkdir(parents=True, exist_ok=True)
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as handle:
                np.savez(handle, **arrays)
        return arrays, False


class Deformer(abc.ABC):
    """Deforms a rest surface mesh according to an edit spec; output keeps vertex order and connectivity.

    ``spec_keys``: the top-level edit-spec keys (besides ``frames``) the deformer accepts; any other key is
    rejected by :func:`nerfedit_plugin.edit.spec.parse_edit_spec` before any work.
    """

    spec_keys: ClassVar[frozenset[str]] = frozenset({"handles"})

    editor: ClassVar[type[EditingBackend] | None] = None
    """The interactive editor's backend for this deformer (``nerfedit view --mesh MESH --deformer NAME``): a subclass
    of :class:`~nerfedit_plugin.edit.editing.EditingBackend` (what the handles grab, how they become this deformer's
    edit spec, how a pose is previewed, what the viewer draws). Default None: not editable in the viewer."""

    on_progress: Progress = staticmethod(no_progress)
    """``self.on_progress(done, total=None, detail="")`` (:class:`~nerfedit_plugin.timing.Progress`): how far a long
    :meth:`bind` or :meth:`deform` is (vertex blocks, solver iterations; ``total`` None for a single long call). The
    edit job sets it on the instance before :meth:`bind`; default: nobody listens. Calling it is optional."""

    bind_cache: BindCache = BindCache()
    """Where :meth:`bind` may keep what it computes per rest mesh (:meth:`BindCache.fetch`), so that the next edit of
    the same mesh reads it instead. The edit job sets it on the instance before :meth:`bind` (the proxy cache's
    folder, keyed by the rest mesh's content); default: nothing is stored."""

    def __init__(self, config: DeformerConfig) -> None:
        self.config = config

    # ---- required ------------------------------------------------------------------------------------------------
    @abc.abstractmethod
    def bind(self, rest: SurfaceMesh, edit: EditSpec) -> None:
        """All precomputation (factorisations, weights, coordinates). Validates ``edit`` against ``rest`` and raises
        :class:`nerfedit_plugin.errors.NerfEditError` naming the key on bad input."""

    @abc.abstractmethod
    def deform(self) -> np.ndarray:
        """Deformed vertex positions ``(n_frames, V, 3)`` float64, same vertex order as the rest mesh.

        ``n_frames`` is the spec's ``frames`` when it sets one, else the deformer's own count (1 for a single
        pose; the clip length for a BVH, the file count for a mesh sequence).
        """

    # ---- optional hooks --------------------------------------------------------------------------------------------
    def deform_points(self, points: np.ndarray, frame: int) -> np.ndarray:
        """Space deformers (cage, skeleton): map rest-space ``points (M,3)`` to deformed space at ``frame`` → ``(M,3)``.
        Enables ``--lift direct``. Default: not defined in space."""
        raise NotImplementedError(f"{type(self).__name__} is defined on the surface only")

    @classmethod
    def supports_points(cls) -> bool:
        """True when the deformer overrides :meth:`deform_points`."""
        return cls.deform_points is not Deformer.deform_points

    def report(self) -> dict:
        """What ``report.json`` records of the bound deformer after :meth:`deform` (JSON-able: the method it chose,
        sizes, accuracy measures), under ``"deformer_report"``. Default: nothing."""
        return {}

    def write_artifacts(self, out_dir: Path) -> list[Path]:
        """Write extra files of a bound deformer into the edit folder ``out_dir`` (cages, weights) and return their
        paths. Default: none."""
        return []

    @classmethod
    def overlays(cls, edit_dir: Path, frame: int) -> list[Overlay]:
        """What the viewer draws for an edit folder this deformer wrote (its artifacts) at ``frame``. Default: none."""
        return []

    @classmethod
    def handle_points(cls, edit_dir: Path, rest: SurfaceMesh) -> np.ndarray:
        """The points ``(P,3)`` the spec's handle selections grab, for the viewer. Default: the rest vertices."""
        return rest.vertices

    @classmethod
    def identity_edit(cls, edit: dict, rest: SurfaceMesh) -> dict | None:
        """Conformance kit: a variant of ``edit`` that must leave ``rest`` unchanged; ``None`` = let the kit derive
        one from ``edit["handles"]`` (every transform a zero translation)."""
        return None

    @classmethod
    def rigid_edit(cls, edit: dict, rest: SurfaceMesh) -> dict | None:
        """Conformance kit: a variant of ``edit`` that must move ``rest`` rigidly; ``None`` = let the kit derive one
        from ``edit["handles"]`` (every handle given one rigid motion)."""
        return None

    @classmethod
    def placed_edit(cls, edit: dict, scale: float, offset: np.ndarray, base_dir: Path, folder: Path) -> dict | None:
        """Conformance kit: ``edit`` for the rest mesh moved by ``x ↦ scale·x + offset``, its own keys placed (files
        read from ``base_dir`` are written placed into ``folder``; the kit places ``handles`` and keeps ``frames``).
        ``None`` (the default): the deformer has no keys of its own to place."""
        return None


def mesh_digest(mesh: SurfaceMesh) -> str:
    """sha256 of the mesh's vertex and face arrays: whether a deformer left its rest mesh as it was."""
    digest = hashlib.sha256()
    for array in (mesh.vertices, mesh.faces):
        digest.update(memoryview(np.ascontiguousarray(array)).cast("B"))
    return digest.hexdigest()


def checked_frames(model: Deformer, frames: object, rest: SurfaceMesh, edit: EditSpec, digest: str) -> np.ndarray:
    """``frames``, what ``model.deform()`` returned, as the contract says they are: ``(n_frames, V, 3)``, finite,
    float64 (float32 is widened), with ``rest`` as ``digest`` (:func:`mesh_digest` before :meth:`Deformer.bind`)
    recorded it. Otherwise a :class:`NerfEditError` naming the deformer class and the breach (a plugin's bad output
    would fail later, in the lift, with an error pointing elsewhere, or silently edit a moved rest mesh)."""
    who = f"deformer {type(model).__module__}.{type(model).__qualname__}"
    if mesh_digest(rest) != digest:
        raise NerfEditError(f"{who}: bind() or deform() modified the rest mesh in place (a deformer must not)")
    if not isinstance(frames, np.ndarray) or frames.dtype.kind != "f":
        what = f"an array of {frames.dtype}" if isinstance(frames, np.ndarray) else type(frames).__name__
        raise NerfEditError(f"{who}: deform() returned {what}, not an array of float64 positions")
    n_frames = edit.frames if edit.frames_given else (len(frames) if frames.ndim == 3 and len(frames) else 1)
    expected = (n_frames, rest.n_vertices, 3)
    if frames.shape != expected:
        raise NerfEditError(f"{who}: deform() returned shape {frames.shape}, expected {expected} (frames, vertices, 3)")
    if not all(np.isfinite(frame).all() for frame in frames):  # a frame at a time: no (F, V, 3) temporaries
        bad = sum(np.count_nonzero(~np.isfinite(frame)) for frame in frames)
        raise NerfEditError(f"{who}: deform() returned {bad} non-finite values (NaN or inf)")
    return np.asarray(frames, dtype=np.float64)
