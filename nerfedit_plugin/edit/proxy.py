"""TetProxy: a tetrahedral mesh around a surface, with the surface embedded in it (tet, barycentrics).

Build (``build_proxy``): offset cage = pymeshlab alpha wrap of the surface at distance ``offset`` (watertight and
free of the self-intersections of a naive normal offset; a surface of ``wrap_cluster_faces`` triangles or more is
wrapped through its vertex clustering on cells of ``wrap_cell`` x offset, which moves it by a few hundredths of the
offset and costs the wrap a fraction of its time) -> quadric decimation to ``cage_faces`` -> pytetwild
(``optimize=True``) -> tets reoriented to positive volume, degenerate tets and unreferenced vertices dropped ->
every surface vertex located exactly (float64) in the tets. Decimation and tetwild's envelope may cut into the
offset, even inside the surface: unless every surface vertex lies in a tet, at least ``min_margin`` x offset from
the tet boundary, the offset grows and the build repeats (bounded), then fails with :class:`NerfEditError` (never
clamps). ``cached_proxy`` stores the result as ``<cache_dir>/<sha256 of mesh + parameters>.npz``.

Scale: every step runs on the mesh mapped into its :func:`unit_frame` (centred, unit bbox diagonal) and the result
is mapped back, so the build does not depend on the mesh's size or position (fTetWild segfaults on a mesh 1e-6
across; Open3D's float32 distances lose the margin far from the origin).

Determinism: the alpha wrap, the decimation and everything after pytetwild are deterministic; pytetwild is not.
fTetWild shuffles the input triangles with ``std::mt19937`` seeded by ``std::random_device`` (``sort_input_faces``
in TriangleInsertion.cpp; the switch ``not_sort_input`` is not exposed by pytetwild), so two cold builds of the same
input differ (with one thread too). Same input, same proxy holds through the cache and through
:func:`proxy_from_tets` (an edit re-run with the proxy of an earlier edit: ``nerfedit edit --proxy-from EDIT``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse

from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.geometry.mesh import SurfaceMesh, cluster_vertices, grid_cells, unit_frame
from nerfedit_plugin.geometry.refine import Refinement
from nerfedit_plugin.geometry.tets import (  # noqa: F401  (re-exported: these lived here before geometry.tets)
    DEGENERATE_VOLUME_RATIO,
    boundary_faces,
    clean_tets,
    distance_to_boundary,
    tet_signed_volumes,
)
from nerfedit_plugin.geometry.wrap import wrap_and_decimate
from nerfedit_plugin.io.atomic import atomic_path
from nerfedit_plugin.timing import Progress, Stopwatch, no_progress

PROXY_FORMAT = 2
"""Version of the build algorithm and file layout; part of the cache key (bump to invalidate old caches)."""


@dataclass
class ProxyConfig:
    """How the tetrahedral proxy around a surface mesh is built."""

    offset: float | None = None
    """Absolute cage offset in mesh units; None derives it from the camera distance or the bounding box."""
    offset_camera_fraction: float = 0.05
    """Derived offset = this x the mean camera-to-object-centre distance, when cameras are known (the paper's 5%)."""
    offset_bbox_fraction: float = 0.02
    """Derived offset = this x the bounding-box diagonal when no camera distance is known."""
    wrap_alpha_factor: float = 1.0
    """Alpha-wrap ball size as a multiple of the offset: smaller follows concavities closer (more faces, slower)."""
    cage_faces: int = 1000
    """Target face count of the decimated cage before tetrahedralisation (pytetwild is slow on dense input)."""
    edge_length_fac: float = 0.05
    """pytetwild ideal tet edge length as a fraction of the cage's bounding-box diagonal."""
    epsilon: float = 5e-3
    """pytetwild envelope: max distance of the tet boundary from the cage, relative to the bounding-box diagonal."""
    min_margin: float = 0.2
    """Every surface vertex must lie at least this x offset inside the tet boundary (decimation and tetwild's
    envelope cut into the offset); otherwise the build is retried with a larger offset."""
    max_attempts: int = 4
    """Builds to try; each retry multiplies the offset by ``offset_growth``."""
    offset_growth: float = 1.5
    """Offset multiplier between attempts."""
    wrap_cell: float = 0.25
    """Surfaces of ``wrap_cluster_faces`` triangles or more are alpha-wrapped through their vertex clustering: the
    vertices of each grid cell of this x offset merged into their mean, the triangles that keep three corners kept.
    The wrap's time grows with its input's triangles (3.4 s for the 0.9M of a 449k-vertex mesh, 0.9 s for the 98k
    of its clustering); the clustered surface lies within a cell diagonal of the surface (0.07 x offset on the
    subdivided bunny), and the margin of the result is checked on the surface itself. 0: wrap the surface as it
    is."""
    wrap_cluster_faces: int = 200_000
    """Triangle count from which the wrap input is clustered (``wrap_cell``); below it, the surface as it is."""

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise :class:`OptionError` naming the first invalid field (the CLI says ``--proxy.NAME``)."""
        positive = ["offset_camera_fraction", "offset_bbox_fraction", "wrap_alpha_factor", "edge_length_fac", "epsilon"]
        for name in positive + (["offset"] if self.offset is not None else []):
            value = getattr(self, name)
            check_option(self, name, value, bool(np.isfinite(value) and value > 0), "a positive number")
        check_option(self, "min_margin", self.min_margin, bool(0 <= self.min_margin < 1), "in [0, 1)")
        check_option(self, "cage_faces", self.cage_faces, self.cage_faces >= 8, ">= 8")
        check_option(self, "max_attempts", self.max_attempts, self.max_attempts >= 1, ">= 1")
        check_option(self, "offset_growth", self.offset_growth, bool(self.offset_growth > 1), "> 1")
        cell = self.wrap_cell
        check_option(self, "wrap_cell", cell, bool(np.isfinite(cell) and 0 <= cell <= 1), "in [0, 1]")
        faces = self.wrap_cluster_faces
        check_option(self, "wrap_cluster_faces", faces, faces >= 1, ">= 1")

    def clusters(self, mesh: SurfaceMesh) -> bool:
        """Whether the alpha wrap of ``mesh`` gets its vertex clustering (``wrap_cell``, ``wrap_cluster_faces``)."""
        return self.wrap_cell > 0 and len(mesh.faces) >= self.wrap_cluster_faces


@dataclass
class TetProxy:
    """Tet mesh (positively oriented, no zero-volume tets), the cage it fills, and the surface embedding.

    ``vertices (N,3) float64``, ``tets (K,4) int64``, ``cage`` (a SurfaceMesh), ``embed_tets (V,) int64`` (the tet of
    each surface vertex), ``embed_bary (V,4) float64`` (its barycentrics there): surface vertex ``i`` =
    ``sum_j embed_bary[i, j] * vertices[tets[embed_tets[i], j]]``.
    """

    vertices: np.ndarray
    tets: np.ndarray
    cage: SurfaceMesh
    embed_tets: np.ndarray
    embed_bary: np.ndarray
    info: dict = field(default_factory=dict)
    """Build record (JSON): offset used, attempts, margin (min surface-to-boundary distance / offset), stage
    times in seconds, dropped degenerate tets, cage face count."""

    def embedding_matrix(self, rows: np.ndarray | None = None) -> scipy.sparse.csr_matrix:
        """→ sparse ``A (V,N)`` float64 CSR, the four barycentrics of each surface vertex in its row:
        ``A @ vertices == surface`` (the paper's barycentric matrix); ``rows (R,) int64``: only those surface vertices'
        rows, ``A[rows]`` (R,N), built from their embedding alone."""
        tets, bary = self.embed_tets, self.embed_bary
        if rows is not None:
            tets, bary = tets[rows], bary[rows]
        return scipy.sparse.csr_matrix(
            (bary.ravel(), self.tets[tets].ravel(), np.arange(0, 4 * len(tets) + 1, 4)),
            shape=(len(tets), len(self.vertices)),
        )

    def refined(self, refinement: Refinement, mesh: SurfaceMesh) -> TetProxy:
        """This proxy bisected by ``refinement`` (:func:`~nerfedit_plugin.geometry.refine.bisect` of its tets), with
        ``mesh`` (the surface it embeds) located in the children of its tets; same cage, ``info["refinements"]``
        counts the refinements."""
        embed_tets, embed_bary = refinement.locate(mesh.vertices, self.embed_tets, self.embed_bary)
        info = {**self.info, "refinements": int(self.info.get("refinements", 0)) + 1}
        return TetProxy(refinement.vertices, refinement.tets, self.cage, embed_tets, embed_bary, info)

    _ARRAYS = ("vertices", "tets", "embed_tets", "embed_bary")

    def save(self, path: str | os.PathLike) -> None:
        """Write an ``.npz`` atomically."""
        with atomic_path(path) as tmp:
            np.savez(
                tmp,
                format=np.int64(PROXY_FORMAT),
                **{name: getattr(self, name) for name in self._ARRAYS},
                cage_vertices=self.cage.vertices,
                cage_faces=self.cage.faces,
                info=np.array(json.dumps(self.info)),
            )

    @classmethod
    def load(cls, path: str | os.PathLike) -> TetProxy:
        """Read a file written by :meth:`save`; a missing, foreign or corrupt file raises :class:`NerfEditError`."""
        path = Path(path)
        if not path.is_file():
            raise NerfEditError(f"{path}: tet proxy file not found")
        try:
            with np.load(path, allow_pickle=False) as data:
                if int(data["format"]) != PROXY_FORMAT:
                    raise NerfEditError(f"{path}: tet proxy format {int(data['format'])}, expected {PROXY_FORMAT}")
                arrays = {name: data[name] for name in cls._ARRAYS}
                cage = SurfaceMesh(data["cage_vertices"], data["cage_faces"])
                info = json.loads(str(data["info"]))
        except NerfEditError:
            raise
        except Exception as exc:  # zipfile, KeyError, ValueError, json errors: all mean "not a proxy file"
            raise NerfEditError(f"{path}: not a readable tet proxy file ({exc})") from exc
        proxy = cls(
            vertices=arrays["vertices"].astype(np.float64),
            tets=arrays["tets"].astype(np.int64),
            cage=cage,
            embed_tets=arrays["embed_tets"].astype(np.int64),
            embed_bary=arrays["embed_bary"].astype(np.float64),
            info=info,
        )
        proxy._check(str(path))
        return proxy

    def _check(self, where: str) -> None:
        n, k = len(self.vertices), len(self.tets)
        ok = (
            self.vertices.ndim == 2
            and self.vertices.shape[1] == 3
            and self.tets.ndim == 2
            and self.tets.shape[1] == 4
            and k > 0
            and self.tets.min() >= 0
            and self.tets.max() < n
            and self.embed_tets.ndim == 1
            and self.embed_bary.shape == (len(self.embed_tets), 4)
            and (len(self.embed_tets) == 0 or (self.embed_tets.min() >= 0 and self.embed_tets.max() < k))
        )
        if not ok:
            raise NerfEditError(f"{where}: inconsistent tet proxy arrays")


# ---- build ------------------------------------------------------------------------------------------------------


def resolve_offset(mesh: SurfaceMesh, config: ProxyConfig, camera_distance: float | None = None) -> float:
    """→ the cage offset (float, mesh units): ``config.offset``, else a fraction of ``camera_distance``, else of the
    bbox diagonal."""
    if config.offset is not None:
        return float(config.offset)
    if camera_distance is not None:
        if not (np.isfinite(camera_distance) and camera_distance > 0):
            raise NerfEditError(f"camera distance: must be a positive number, got {camera_distance!r}")
        return float(config.offset_camera_fraction * camera_distance)
    return float(config.offset_bbox_fraction * mesh.bbox_diagonal)


def _check_mesh(mesh: SurfaceMesh) -> None:
    if len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise NerfEditError("mesh: empty (no triangles); cannot build a tet proxy")
    if not mesh.bbox_diagonal > 0:
        raise NerfEditError("mesh: all vertices coincide; cannot build a tet proxy")


def _wrap_input(mesh: SurfaceMesh, size: float) -> tuple[np.ndarray, np.ndarray]:
    """The triangle soup to wrap: the mesh plus a right triangle (legs ``size``) at each unreferenced vertex.

    The alpha wrap ignores unreferenced vertices, yet the embedding must contain them; and the wrap of a bare point
    is a blob so small that tetwild's simplification deletes it, so the triangle is offset-sized."""
    stray = np.flatnonzero(~mesh.referenced())
    if len(stray) == 0:
        return mesh.vertices, mesh.faces
    points = mesh.vertices[stray]
    extra = np.concatenate([points + [size, 0.0, 0.0], points + [0.0, size, 0.0]])
    base = len(mesh.vertices)
    tris = np.stack([stray, base + np.arange(len(stray)), base + len(stray) + np.arange(len(stray))], axis=1)
    return np.concatenate([mesh.vertices, extra]), np.concatenate([mesh.faces, tris])


def build_cage(mesh: SurfaceMesh, offset: float, config: ProxyConfig, times: dict | None = None) -> SurfaceMesh:
    """Watertight cage at distance ~``offset`` outside ``mesh``: alpha wrap (of :func:`cluster_vertices` of the
    mesh, on cells of ``config.wrap_cell`` x offset, when ``config.clusters(mesh)``), then quadric decimation to
    ``config.cage_faces`` (stage times added to ``times``)."""
    clock = Stopwatch(seconds=times, digits=None)
    if config.clusters(mesh):
        with clock.stage("cluster"):
            mesh = cluster_vertices(mesh, config.wrap_cell * offset)
    vertices, faces = _wrap_input(mesh, offset)
    return wrap_and_decimate(
        vertices,
        faces,
        config.wrap_alpha_factor * offset,
        offset,
        max_faces=config.cage_faces,
        preserve_normal=True,
        clock=clock,
    )


@contextlib.contextmanager
def _python_sigint() -> Iterator[None]:
    """pytetwild resets the process's SIGINT handler to the default: install Python's again afterwards (else Ctrl-C
    kills the process without cleaning up), in the main thread."""
    import signal
    import threading

    main = threading.current_thread() is threading.main_thread()
    handler = signal.getsignal(signal.SIGINT) if main else None
    try:
        yield
    finally:
        if handler is not None:
            signal.signal(signal.SIGINT, handler)


def tetrahedralize(cage: SurfaceMesh, config: ProxyConfig) -> tuple[np.ndarray, np.ndarray]:
    """cage (a closed SurfaceMesh) → raw pytetwild tet mesh ``(vertices (N,3) float64, tets (K,4) int64)``
    (``optimize=True``; orientation as pytetwild returns it).

    Runs in a scratch folder: fTetWild drops ``__tracked_surface.stl`` into the working directory.
    """
    import tempfile

    import pytetwild

    with tempfile.TemporaryDirectory() as scratch, contextlib.chdir(scratch), _python_sigint():
        vertices, tets = pytetwild.tetrahedralize(
            cage.vertices,
            cage.faces.astype(np.int32),
            edge_length_fac=config.edge_length_fac,
            epsilon=config.epsilon,
            optimize=True,
            quiet=True,
        )
    return np.asarray(vertices, dtype=np.float64), np.asarray(tets, dtype=np.int64).reshape(-1, 4)


MARGIN_CELL = 0.25
"""Grid cell of :func:`min_distance_to_boundary` in the build, x offset."""
PRUNED_MARGIN_POINTS = 50_000
"""From this many surface vertices on, :func:`min_distance_to_boundary` evaluates the distance only where the
minimum can be."""


def min_distance_to_boundary(vertices: np.ndarray, tets: np.ndarray, points: np.ndarray, cell: float) -> float:
    """``distance_to_boundary(vertices, tets, points).min()`` (Open3D, float32), the same value bit for bit, from
    fewer queries: the distance at the centre of every grid cell (size ``cell``) holding points bounds the distance
    of its points from below and above (± the cell's half diagonal, ± 1e-5 of the coordinates' magnitude for the
    float32 rounding); only points of cells that can hold the minimum are queried."""
    from nerfedit_plugin.geometry.raycast import distance, raycasting_scene

    scene = raycasting_scene(vertices, boundary_faces(tets))
    if len(points) < PRUNED_MARGIN_POINTS:
        return float(distance(scene, points).min())
    cells, owner, low = grid_cells(points, cell)
    at_centre = distance(scene, low + (cells + 0.5) * cell).astype(np.float64)
    radius = 0.5 * np.sqrt(3.0) * cell * (1 + 1e-6)
    slack = 2e-5 * max(float(np.abs(points).max()), float(np.abs(vertices).max()), cell)
    upper = float((at_centre + radius).min()) + slack  # some point is at most this far
    maybe = at_centre - radius - slack <= upper
    return float(distance(scene, points[maybe[owner]]).min())


def embed_points(vertices: np.ndarray, tets: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact float64 point location: vertices (N,3) float64, tets (K,4) int64, points (M,3) float →
    ``(tet (M,) int64, -1 outside; bary (M,4) float64, 0 where -1)``."""
    import torch

    from nerfedit_plugin.bending.locate import TetLocator

    if len(tets) == 0:
        return np.full(len(points), -1, dtype=np.int64), np.zeros((len(points), 4))
    locator = TetLocator(torch.from_numpy(vertices), torch.from_numpy(tets), dtype=torch.float64)
    tet, bary = locator.locate(torch.from_numpy(np.ascontiguousarray(points, dtype=np.float64)))
    return tet.cpu().numpy().astype(np.int64), bary.cpu().numpy().astype(np.float64)


def embed_surface(vertices: np.ndarray, tets: np.ndarray, mesh: SurfaceMesh) -> tuple[np.ndarray, np.ndarray]:
    """:func:`embed_points` of the vertices of ``mesh`` in the tets, both mapped into the :func:`unit_frame` of
    ``mesh`` (barycentrics do not change under the similarity; the location does not depend on scale or position).
    A function of its arguments only: a proxy re-used from an edit folder gets the embedding it was built with."""
    centre, scale = unit_frame(mesh.vertices)
    return embed_points((vertices - centre) / scale, tets, (mesh.vertices - centre) / scale)


def proxy_from_tets(vertices: np.ndarray, tets: np.ndarray, mesh: SurfaceMesh, where: str) -> TetProxy:
    """A proxy built before (vertices (N,3) float, tets (K,4) int, e.g. the rest proxy of a ``deformation.npz``)
    with ``mesh`` embedded again by :func:`embed_surface`: the same arrays as the build gave. The cage is the tets'
    boundary surface. Raises :class:`NerfEditError` (naming ``where``) when a vertex of ``mesh`` lies outside."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    tets = np.ascontiguousarray(tets, dtype=np.int64)
    _check_mesh(mesh)
    embed_tets, embed_bary = embed_surface(vertices, tets, mesh)
    n_outside = int((embed_tets < 0).sum())
    if n_outside:
        raise NerfEditError(
            f"{where}: {n_outside} of {mesh.n_vertices} mesh vertices lie outside its tet proxy (another mesh?)"
        )
    cage = SurfaceMesh(vertices, boundary_faces(tets))
    return TetProxy(vertices, tets, cage, embed_tets, embed_bary, {"reused": where, "format": PROXY_FORMAT})


def build_proxy(
    mesh: SurfaceMesh,
    config: ProxyConfig | None = None,
    camera_distance: float | None = None,
    progress: Progress = no_progress,
) -> TetProxy:
    """Build the tet proxy of ``mesh`` (see the module docstring); raises :class:`NerfEditError` on bad input
    or when ``config.max_attempts`` growing offsets all leave a surface vertex outside the tets or closer than
    ``config.min_margin`` x offset to their boundary. ``config`` defaults to ``ProxyConfig()``. ``progress`` is
    told each step (cage, tetwild, clean, embed, margin; "attempt k/n: " before them on a retry).

    Every scale-sensitive step (wrap, decimation, pytetwild, embedding, margin) runs on the mesh mapped into its
    :func:`unit_frame`; the tets and the cage are mapped back (barycentrics are invariant under the similarity)."""
    config = ProxyConfig() if config is None else config
    config.validate()
    _check_mesh(mesh)
    offset = resolve_offset(mesh, config, camera_distance)
    centre, scale = unit_frame(mesh.vertices)
    unit = mesh.with_vertices((mesh.vertices - centre) / scale)
    times: dict[str, float] = {}
    label = ""  # what leads each step's name told to progress: "attempt k/n: " on retries
    # stages repeat across attempts: their times add up
    clock = Stopwatch(lambda name: progress(0, None, label + name), seconds=times, digits=None)
    for attempt in range(1, config.max_attempts + 1):
        label = f"attempt {attempt}/{config.max_attempts}: " if attempt > 1 else ""
        unit_offset = offset / scale
        progress(0, None, f"{label}cage (alpha wrap, decimation)")
        cage = build_cage(unit, unit_offset, config, times)
        with clock.stage("tetwild"):
            raw_vertices, raw_tets = tetrahedralize(cage, config)
        with clock.stage("clean"):
            unit_vertices, tets, n_dropped = clean_tets(raw_vertices, raw_tets)
            vertices = unit_vertices * scale + centre
        with clock.stage("embed"):
            embed_tets, embed_bary = embed_surface(vertices, tets, mesh)
        n_outside = int((embed_tets < 0).sum())
        if n_outside == 0:
            with clock.stage("margin"):  # Open3D's float32 distances: in the unit frame
                cell = MARGIN_CELL * unit_offset
                margin = min_distance_to_boundary(unit_vertices, tets, unit.vertices, cell) / unit_offset
            if margin >= config.min_margin:
                info = {
                    "offset": offset,
                    "attempts": attempt,
                    "margin": margin,
                    "times": times,
                    "dropped_degenerate_tets": n_dropped,
                    "cage_faces": len(cage.faces),
                    "unit_frame": {"centre": centre.tolist(), "scale": scale},
                    "format": PROXY_FORMAT,
                }
                cage = cage.with_vertices(cage.vertices * scale + centre)
                return TetProxy(vertices, tets, cage, embed_tets, embed_bary, info)
        offset *= config.offset_growth
    problem = (
        f"{n_outside} of {len(mesh.vertices)} surface vertices lie outside the tets"
        if n_outside
        else f"a surface vertex lies only {margin:.3g} x offset inside the tet boundary (proxy.min_margin "
        f"{config.min_margin})"
    )
    raise NerfEditError(
        f"proxy: after {config.max_attempts} attempts (last offset {offset / config.offset_growth:.4g}) {problem}; "
        "raise proxy.offset or proxy.cage_faces"
    )


# ---- cache ------------------------------------------------------------------------------------------------------


def proxy_cache_key(mesh: SurfaceMesh, config: ProxyConfig, camera_distance: float | None = None) -> str:
    """→ hex sha256 (64 characters) of the mesh arrays and every parameter that changes the build (the offset as
    resolved); the file name of the proxy in the cache."""
    _check_mesh(mesh)
    params = dataclasses.asdict(config)
    for name in ("offset", "offset_camera_fraction", "offset_bbox_fraction", "wrap_cell", "wrap_cluster_faces"):
        del params[name]
    if config.clusters(mesh):  # keys of the meshes wrapped as they are: as before these options
        params["wrap_cell"] = float(config.wrap_cell).hex()
    params["offset"] = resolve_offset(mesh, config, camera_distance).hex()
    params["format"] = PROXY_FORMAT
    digest = hashlib.sha256()
    for array in (mesh.vertices, mesh.faces):
        digest.update(repr((array.dtype.str, array.shape)).encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    digest.update(json.dumps(params, sort_keys=True).encode())
    return digest.hexdigest()


def stored_proxy(
    file: Path, recorded_key: object, mesh: SurfaceMesh, config: ProxyConfig, camera_distance: float | None, where: str
) -> TetProxy:
    """The proxy an earlier edit stored in ``file`` — a :meth:`TetProxy.save` file, or a ``deformation.npz`` whose rest
    tets are the proxy as built — with ``mesh`` embedded again (:func:`proxy_from_tets`). ``recorded_key`` is that
    edit's :func:`proxy_cache_key`; unless it is ``mesh``'s with ``config`` and ``camera_distance``, a
    :class:`NerfEditError` naming ``where``. pytetwild is not deterministic: this (or a warm cache) is how a re-run
    gives the same ``deformation.npz`` bit for bit."""
    if recorded_key != proxy_cache_key(mesh, config, camera_distance):
        raise NerfEditError(
            f"{where}: its proxy was built from another mesh or other proxy settings "
            "(mesh, --proxy.*, camera distance must be those of that edit; the config.yml of an edit names the "
            "edit's own proxy: pass --proxy-from None to build a new one)"
        )
    if file.name == "deformation.npz":
        from nerfedit_plugin.bending.deformation_field import DeformationField

        field = DeformationField.load(file)
        return proxy_from_tets(field.rest_vertices, field.tets, mesh, f"{where}: {file}")
    built = TetProxy.load(file)
    return proxy_from_tets(built.vertices, built.tets, mesh, f"{where}: {file}")


def cached_proxy(
    mesh: SurfaceMesh,
    config: ProxyConfig,
    cache_dir: str | os.PathLike,
    camera_distance: float | None = None,
    progress: Progress = no_progress,
) -> tuple[TetProxy, bool]:
    """``(proxy, hit)``: load ``<cache_dir>/<key>.npz`` if present and readable, else build and store it
    (``progress``: as :func:`build_proxy`'s)."""
    config.validate()
    path = Path(cache_dir) / f"{proxy_cache_key(mesh, config, camera_distance)}.npz"
    if path.is_file():
        try:
            return TetProxy.load(path), True
        except NerfEditError as exc:  # unreadable cache entry: say so once, rebuild and overwrite it
            warnings.warn(f"{exc}; rebuilding the cache entry", stacklevel=2)
    proxy = build_proxy(mesh, config, camera_distance, progress)
    proxy.save(path)
    return proxy, False
