"""The ``arap`` deformer: surface as-rigid-as-possible deformation driven by the edit spec's handles.

Spec: ``{"handles": [{"select": ..., "fixed": true}, {"select": ..., "transform": {...}}], "frames": n}``.
Handle vertices are placed exactly (fixed ones stay at rest, moved ones follow their transform); every other
vertex minimises the ARAP energy. One factorisation serves all frames; each frame starts from the previous one.
Every connected part of the mesh needs at least one handle vertex.

Meshes of more than ``coarse_above`` vertices (60k by default) are solved by multiresolution
(:mod:`nerfedit_plugin.geometry.multires`): exact ARAP on a vertex clustering of the surface of ``coarse_vertices``
vertices, the fine surface carried as detail in the coarse solution's local frames, the handle vertices placed
exactly; ``polish`` N then runs N fine L-BFGS iterations from the carried surface. The coarse level and the binding
are kept in the bind cache (:attr:`Deformer.bind_cache`), so the next edit of the same mesh reads them.
``report.json`` records the path taken under ``deformer_report``.

In the editor (:class:`ArapBackend`) the handles sit on mesh vertices; each preview re-solves with a solver
prefactored for the handle vertices, warm-started, a few iterations, and :meth:`ArapBackend.converge` finishes that
solve (settle on release). On the multiresolution path a drag shows the coarse level as solved
(:meth:`ArapBackend.preview_drag`, a :class:`~nerfedit_plugin.edit.editing.LiveView`: its handles on their coarse
targets) and the release the fine surface it carries.
"""

from __future__ import annotations

import dataclasses
import threading
from typing import Literal

import numpy as np

from nerfedit_plugin.edit.coarse import CoarseOptions, cached_coarse_level
from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.edit.editing import EditingBackend, EditorHandle, LiveView
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.geometry.arap import ArapResult, ArapSolver
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.multires import MultiresArap, coarse_level, rigid_fit
from nerfedit_plugin.timing import Span

PREVIEW_ITERATIONS = 2
"""ARAP local/global iterations per preview solve (each ~30–40 ms on the 28k-vertex bunny, 2 cores), plain: over two
iterations Anderson acceleration's extra local steps cost more than they gain (bunny drag: 81 vs 152 ms per move,
+53 % vs +42 % energy above the converged solve; docs/benchmarks.md)."""
RIGID_BELOW = 1e-12
"""Handle targets within this × the bbox diagonal of one rigid motion of their rest positions make a rigid frame: its
coarse solve starts from that motion (the minimum itself)."""
CONVERGE_CHUNK = 5
"""ARAP iterations between two checks that a settle-on-release is still wanted. The settle uses Anderson, not the
deformer's L-BFGS: restarted every 5 iterations, L-BFGS loses its history (bunny head edit: 66 iterations vs
Anderson's 56 to the stopping test)."""


@dataclasses.dataclass
class ArapConfig(DeformerConfig, CoarseOptions):
    """As-rigid-as-possible surface deformation (Sorkine & Alexa 2007) with handle vertices."""

    _target: type = dataclasses.field(default_factory=lambda: ArapDeformer)
    energy: Literal["spokes_and_rims", "spokes", "elements"] = "spokes_and_rims"
    """Rotation groups: per vertex over its triangles' edges (libigl's default, robust to obtuse triangles),
    per vertex over its incident edges, or per triangle."""
    max_iterations: int = 200
    """Upper bound on local/global iterations per frame."""
    tolerance: float = 1e-6
    """Stop when the relative energy decrease per iteration falls below this."""
    solver: Literal["lbfgs", "anderson"] = "lbfgs"
    """Minimiser (``ArapSolver.solve``'s ``method``): ``lbfgs``, L-BFGS on the ARAP energy with the prefactored
    system as its initial inverse Hessian, or ``anderson``, Anderson-accelerated local/global iterations. Both never
    increase the energy and cost one back-substitution per iteration. L-BFGS is as fast on small meshes and needs
    fewer iterations on large ones (from about 100k vertices), so within ``max_iterations`` it ends closer to the
    converged energy."""
    polish: int = 0
    """Multiresolution path only: after the fine surface is carried, this many L-BFGS iterations of ARAP on the fine
    mesh itself, from the carried surface, its handle vertices exact (the fine system is factorised in ``bind``).
    0 keeps the carried surface; as it grows the result approaches the direct solve's minimiser, which on a finely
    subdivided mesh is softer (its bending stiffness falls like h² against its stretching) and can fold faces the
    coarse solution does not."""

    def __post_init__(self) -> None:
        check_option(self, "max_iterations", self.max_iterations, self.max_iterations >= 1, ">= 1")
        check_option(self, "polish", self.polish, self.polish >= 0, ">= 0")
        self.check_coarse_options()
        check_option(self, "tolerance", self.tolerance, 0 <= self.tolerance < float("inf"), "a number >= 0")
        check_option(self, "solver", self.solver, self.solver in ("lbfgs", "anderson"), "'lbfgs' or 'anderson'")


class ArapBackend(EditingBackend):
    """Handles on the mesh's vertices; ``iterations`` per preview solve."""

    def __init__(self, rest: SurfaceMesh, config: ArapConfig, keys: dict, iterations: int = PREVIEW_ITERATIONS):
        self.points, self.faces = rest.vertices, rest.faces
        super().__init__(rest, config, keys)
        self.iterations = iterations
        self.lock = threading.Lock()
        """Held by each solve: a settle on release (a worker thread) and the next drag's previews share the solver."""
        self._solver: tuple[bytes, ArapSolver | MultiresArap] | None = None
        self.level = coarse_level(rest, config.coarse_vertices) if config.binds_coarse(rest) else None
        """The coarse level a large mesh is edited on (:meth:`CoarseOptions.binds_coarse`): each preview solves it,
        shown as itself during a drag (:meth:`preview_drag`) and as the fine surface it carries otherwise; None:
        previews solve the mesh itself."""
        self._coarse: np.ndarray | None = None  # the coarse positions of the last preview (multiresolution)
        self._split: tuple | None = None  # (key, fixed, moving) coarse handle points of the live view

    def check_handle(self, indices: np.ndarray, fixed: bool) -> None:
        if len(indices) == len(self.points):
            raise NerfEditError(
                f"mark: the selection covers the whole mesh ({len(indices)} vertices), nothing would be left to deform;"
                " deselect part of it"
            )

    def note(self, handles: tuple[EditorHandle, ...]) -> str:
        if any(not h.fixed for h in handles) and not any(h.fixed for h in handles):
            return (
                "; no fixed handle: the whole mesh moves rigidly with the moving handle (ARAP's minimum is the rigid"
                " motion) — mark a fixed handle to anchor it"
            )
        return ""

    def posed_points(self, deformed: np.ndarray) -> np.ndarray:
        return deformed

    def solver(self, indices: np.ndarray) -> ArapSolver | MultiresArap:
        """The ARAP solver factored for these handle vertices, of the mesh or of its coarse level (kept until they
        change)."""
        key = indices.tobytes()
        if self._solver is None or self._solver[0] != key:
            if self.level is None:
                solver = ArapSolver(self.points, self.faces, energy=self.config.energy, fixed=indices)
            else:
                solver = MultiresArap(self.level, self.rest, indices, energy=self.config.energy)
                self._coarse = None
            self._solver = (key, solver)
        return self._solver[1]

    def _problem(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> tuple:
        """→ (the solver of the level solved, its targets, its current positions, the fine handles and targets)."""
        indices, targets = spec.handle_targets(self.points, self.faces)
        solver = self.solver(indices)
        if self.level is None:
            return solver, targets[frame], deformed, indices, targets[frame]
        coarse = self.level.coarse.vertices if self._coarse is None else self._coarse
        return solver.solver, solver.coarse_targets(targets[frame][None])[0], coarse, indices, targets[frame]

    def _shown(self, positions: np.ndarray, indices: np.ndarray, targets: np.ndarray) -> np.ndarray:
        """The solved level's positions → the mesh's: themselves, or the fine surface the coarse level carries
        (:meth:`MultiresArap.surface`)."""
        if self.level is None:
            return positions
        self._coarse = positions
        return self._solver[1].surface(positions, targets)[0]

    def _solve(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> tuple:
        """The preview solve of the level solved (:attr:`iterations`, warm-started) → ``(result, fine handles, their
        targets)``; the caller holds :attr:`lock`."""
        solver, targets, start, indices, fine_targets = self._problem(spec, frame, deformed)
        result = solver.solve(
            targets, initial=start, max_iterations=self.iterations, tolerance=self.config.tolerance, anderson=0
        )
        self.last_iterations = result.iterations
        return result, indices, fine_targets

    def preview(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray:
        with self.lock:
            result, indices, fine_targets = self._solve(spec, frame, deformed)
            return self._shown(result.vertices, indices, fine_targets)

    def preview_drag(self, spec: EditSpec, frame: int, deformed: np.ndarray) -> np.ndarray | LiveView:
        """The mesh itself as :meth:`preview` poses it, or, on the multiresolution path, the same coarse solve shown
        as the coarse level (:meth:`MultiresArap.coarse_surface`; its handles :attr:`MultiresArap.fixed` exactly
        on their coarse targets, moving where a moving handle's vertex lies in their cluster) without carrying the
        fine surface: :meth:`converge` carries it on release, from the same coarse positions as after the same
        :meth:`preview` calls."""
        if self.level is None:
            return self.preview(spec, frame, deformed)
        with self.lock:
            result, _, _ = self._solve(spec, frame, deformed)
            self._coarse = result.vertices
            multires = self._solver[1]
            fixed, moving = self._coarse_handles(spec, multires)
            return LiveView(multires.coarse_surface(result.vertices), self.level.coarse.faces, fixed, moving)

    def _coarse_handles(self, spec: EditSpec, multires: MultiresArap) -> tuple[np.ndarray, np.ndarray]:
        """The coarse handles (:attr:`MultiresArap.fixed`) split into ``(fixed, moving)``: moving those whose cluster
        holds a vertex of a moving handle of ``spec`` (kept while the solver and the handles' selections are the
        same objects)."""
        key = (multires, *(h.selection for h in spec.handles))
        if self._split is not None and len(self._split[0]) == len(key):
            if all(a is b for a, b in zip(self._split[0], key)):
                return self._split[1], self._split[2]
        moved = [
            h.selection.indices(self.points, spec.source, self.faces) for h in spec.handles if h.transform is not None
        ]
        clusters = np.unique(self.level.owner[np.concatenate(moved)]) if moved else np.zeros(0, dtype=np.int64)
        held = np.isin(multires.fixed, clusters)
        self._split = (key, multires.fixed[~held], multires.fixed[held])
        return self._split[1], self._split[2]

    def converge(self, spec, frame, deformed, wanted):
        with self.lock:
            solver, targets, x, indices, fine_targets = self._problem(spec, frame, deformed)
            before = solver.energy(x)
        total = 0
        while total < self.config.max_iterations:
            if not wanted():
                return None
            with self.lock:
                chunk = dict(max_iterations=CONVERGE_CHUNK, tolerance=self.config.tolerance)
                result = solver.solve(targets, initial=x, **chunk)
            x, total = result.vertices, total + result.iterations
            if result.converged:
                break
        with self.lock:
            shown = self._shown(x, indices, fine_targets)
        return shown, before, solver.energy(x), total


class ArapDeformer(Deformer):
    """Moves the handles of the edit spec and lets the rest of the surface follow as rigidly as possible."""

    spec_keys = frozenset({"handles"})
    editor = ArapBackend
    config: ArapConfig

    def bind(self, rest: SurfaceMesh, edit: EditSpec) -> None:
        self.rest = rest
        # validates the spec before any factorising
        self.handles, self.targets = edit.handle_targets(rest.vertices, rest.faces)
        config = self.config
        self.results: list[ArapResult] = []
        self.frame_reports: list[dict] = []
        self.level, self.level_cached = None, False
        try:
            if not config.binds_coarse(rest):
                self.on_progress(0, None, "factorising")
                self.solver = ArapSolver(rest.vertices, rest.faces, energy=config.energy, fixed=self.handles)
                return
            self.on_progress(0, None, "coarse level")
            self.level, self.level_cached = cached_coarse_level(self.bind_cache, rest, config.coarse_vertices)
            self.on_progress(0, None, f"factorising the coarse level ({self.level.coarse.n_vertices} vertices)")
            self.multires = MultiresArap(self.level, rest, self.handles, energy=config.energy)
            if config.polish:
                self.on_progress(0, None, f"factorising the mesh for the polish ({rest.n_vertices} vertices)")
                self.solver = ArapSolver(rest.vertices, rest.faces, energy=config.energy, fixed=self.handles)
        except NerfEditError as exc:
            raise NerfEditError(f"{edit.source}: handles: {exc}") from exc
        self.coarse_targets = self.multires.coarse_targets(self.targets)

    def deform(self) -> np.ndarray:
        """Solve every frame, warm-starting from the previous one; ``results`` keeps each frame's statistics (of the
        coarse solve on the multiresolution path). Progress: ``max_iterations`` units per frame, one per iteration (a
        frame that converges jumps to its end)."""
        frames, previous, self.results, self.frame_reports = [], None, [], []
        per_frame, n = self.config.max_iterations, len(self.targets)
        options = dict(max_iterations=self.config.max_iterations, tolerance=self.config.tolerance)
        options["method"] = self.config.solver
        for f, targets in enumerate(self.targets):
            span = Span(self.on_progress, f * per_frame, per_frame, n * per_frame, f"frame {f + 1}/{n}")
            if self.level is None:
                result = self.solver.solve(targets, initial=previous, callback=span.iterations(), **options)
                positions = result.vertices
                self.frame_reports.append(self._frame_report(result))
            else:
                start, coarse_targets = previous, self.coarse_targets[f]
                rotation, shift, misfit = rigid_fit(self.rest.vertices[self.handles], targets)
                if misfit <= RIGID_BELOW * self.rest.bbox_diagonal:  # a rigid frame: its minimum is that motion
                    start = self.level.coarse.vertices @ rotation.T + shift
                    coarse_targets = start[self.multires.fixed]
                result = self.multires.solve(coarse_targets, initial=start, callback=span.iterations(), **options)
                positions, gap = self.multires.surface(result.vertices, targets)
                self.frame_reports.append(self._frame_report(result, gap / self.rest.bbox_diagonal))
                if self.config.polish:
                    polish = dict(options, max_iterations=self.config.polish, method="lbfgs")
                    polished = self.solver.solve(targets, initial=positions, **polish)
                    positions = polished.vertices
                    self.frame_reports[-1]["polish"] = self._frame_report(polished)
            span.end(f"{result.iterations} iteration{'s' * (result.iterations != 1)}")
            self.results.append(result)
            frames.append(positions)
            previous = result.vertices
        return np.stack(frames)

    @staticmethod
    def _frame_report(result: ArapResult, handle_gap: float | None = None) -> dict:
        report = {"iterations": result.iterations, "energy": result.energies[-1], "converged": result.converged}
        if handle_gap is not None:
            report["handle_gap"] = handle_gap
        return report

    def report(self) -> dict:
        """``path`` (``direct`` or ``multiresolution``), ``threshold_vertices`` (``coarse_above``), per frame
        the solve's ``iterations``, ``energy`` (ARAP energy of the solved level), ``converged``; multiresolution
        adds ``coarse`` (``vertices``, ``faces``, ``handles``: its fixed vertices, ``cached``: read from the bind
        cache), ``detail_mean`` / ``detail_max`` (distance of the fine vertices to the coarse surface) and per frame
        ``handle_gap`` (the largest distance of a carried handle vertex to its target before it is placed there),
        distances relative to the rest bbox diagonal, and with ``polish`` the fine iterations' ``polish``
        (``iterations``, ``energy`` of the fine mesh, ``converged``)."""
        report = {
            "path": "direct" if self.level is None else "multiresolution",
            "threshold_vertices": self.config.coarse_above,
            "per_frame": self.frame_reports,
        }
        if self.level is not None:
            coarse = self.level.coarse
            report["coarse"] = {
                "vertices": coarse.n_vertices,
                "faces": len(coarse.faces),
                "handles": len(self.multires.fixed),
                "cached": self.level_cached,
            }
            report["detail_mean"], report["detail_max"] = (float(x) for x in self.level.detail)
        return report
