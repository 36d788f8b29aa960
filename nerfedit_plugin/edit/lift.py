"""Lift: carry a surface deformation S → S' into the tet proxy T → T' (paper Eq. 3).

``Lift(proxy, rest, method)(frames (F,V,3) float64) → (proxy frames (F,N,3) float64, one FrameReport per frame)``.
Methods (:data:`LiftMethod`): ``tet-arap`` (default: volumetric ARAP, per-tet rotations, with the barycentric
constraints ``A t' = v'`` as the stiff penalty ``E_ARAP(t') + w‖A t' − v'‖²``, warm-started frame to frame;
then, if that folds a tet, the inversion-free re-lift of :mod:`nerfedit_plugin.geometry.injective`),
``closest-point`` and ``knn3`` (the paper's baselines, evaluated at the proxy vertices), ``tet-edit`` (the spec's
handles applied to the proxy, volumetric ARAP: the paper's ablation; re-lifted inversion-free, with soft handles,
when it folds) and ``direct`` (the deformer's
``deform_points`` at the proxy vertices). Every lift reports, per frame, the residual ``|A t' − v'|`` and the
inverted / degenerate tets of T'. Why a penalty, why the re-lift: docs/method.md, "The lift".
"""

from __future__ import annotations

import dataclasses
import time
from typing import Literal

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from nerfedit_plugin.edit import _lift_kernel as _kernel
from nerfedit_plugin.edit.deformer import Deformer
from nerfedit_plugin.edit.proxy import TetProxy
from nerfedit_plugin.edit.spec import EditSpec
from nerfedit_plugin.errors import NerfEditError, check_option
from nerfedit_plugin.geometry import raycast
from nerfedit_plugin.geometry.arap import ArapSolver
from nerfedit_plugin.geometry.injective import InjectiveSolver
from nerfedit_plugin.geometry.launch import launch
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.normals import turned_faces
from nerfedit_plugin.geometry.refine import bisect
from nerfedit_plugin.geometry.soft_constraints import SoftConstraints
from nerfedit_plugin.geometry.tets import tet_signed_volumes
from nerfedit_plugin.timing import Progress, Span, no_progress

LiftMethod = Literal["tet-arap", "closest-point", "knn3", "tet-edit", "direct"]

MAX_BISECTIONS = 2
"""Bisections of a tet per refinement round at most (a fit missing by 8× the target, 16× the aim, needs two)."""
AIM = 0.5
"""Once some surface vertex misses ``residual_target``, refinement aims at this share of it: a vertex's fit also
depends on the tets around its own, which its neighbours just within the target would otherwise leave coarse."""
HELPED = 0.8
"""A refinement round helped a surface vertex when it cut its residual to this share; a round that helped no vertex
is undone (proxy and lift as before it)."""
CROSSING_RADIUS = 0.05
"""Faces this close to a surface vertex the lift misses (× the bbox diagonal, in the deformed frame) are checked for
crossing others: far enough to take in the parts of the surface a crossing brings together there (the demo's
crossing faces lie within 3.1e-3 of its missed vertices), near enough to keep the test local."""
PATIENCE = 2
"""A surface vertex that this many refinement rounds did not help is refined no more: what it misses is not the
proxy's fit error (a folded surface edit, parts of the surface that cross and move apart). One round is not enough
to tell: a vertex's fit can wait for its neighbours' tets, which the same round refines."""


@dataclasses.dataclass
class LiftConfig:
    """Solver settings of the ARAP lifts (tet-arap, tet-edit)."""

    constraint_weight: float = 1000.0
    """Stiffness of the barycentric constraints relative to the ARAP energy (tet-arap)."""
    max_iterations: int = 100
    """Upper bound on ARAP local/global iterations per frame."""
    tolerance: float = 1e-6
    """Stop when the relative energy decrease falls below this."""
    injective: bool = True
    """When the ARAP lift of a frame inverts or flattens a tet, lift that frame again with the inversion-free solver
    (symmetric Dirichlet energy, flip-free Newton steps) from the last inversion-free state (the previous frame or the
    rest proxy). False keeps the ARAP lift as it is, folds included."""
    injective_max_iterations: int = 50
    """Upper bound on the Newton iterations of an inversion-free re-lift."""
    injective_tolerance: float = 1e-2
    """Stop an inversion-free re-lift when an iteration lowers its energy by less than this fraction."""
    residual_target: float = 2e-3
    """tet-arap: where the lifted proxy misses a surface vertex by more than this × the rest bbox diagonal (the
    piecewise-affine fit is too coarse there), the tets holding the vertices that miss :data:`AIM` × this are
    bisected (once per factor 4 of excess) and every frame is lifted again, warm-started from the previous lift;
    repeated while some vertex misses and the last round helped some vertex (:data:`HELPED`, :data:`PATIENCE`)."""
    refine_rounds: int = 3
    """tet-arap: refine-and-lift-again rounds at most (each bisects the marked tets up to :data:`MAX_BISECTIONS`
    times); 0 keeps the proxy as built."""
    max_constraints: int = 100_000
    """Surface vertices (a count) whose barycentric constraints the lift fits at most: a surface with more is
    subsampled, evenly over the proxy tets that hold it and at least one vertex per such tet
    (:func:`surface_sample`); the reported residuals still cover every surface vertex. 0: every surface vertex."""

    def __post_init__(self) -> None:
        weight, iterations, tolerance = self.constraint_weight, self.max_iterations, self.tolerance
        check_option(self, "constraint_weight", weight, 0 < weight < np.inf, "a positive number")
        check_option(self, "max_iterations", iterations, iterations >= 1, "a positive integer")
        check_option(self, "tolerance", tolerance, 0 <= tolerance < np.inf, "a number >= 0")
        check_option(self, "injective", self.injective, isinstance(self.injective, bool), "true or false")
        newton, stop = self.injective_max_iterations, self.injective_tolerance
        check_option(self, "injective_max_iterations", newton, newton >= 1, "a positive integer")
        check_option(self, "injective_tolerance", stop, 0 <= stop < np.inf, "a number >= 0")
        check_option(self, "max_constraints", self.max_constraints, self.max_constraints >= 0, "an integer >= 0")
        target, rounds = self.residual_target, self.refine_rounds
        check_option(self, "residual_target", target, 0 < target < np.inf, "a positive number")
        check_option(self, "refine_rounds", rounds, rounds >= 0, "an integer >= 0")


@dataclasses.dataclass
class FrameReport:
    """Quality of one lifted frame (distances relative to the rest surface's bbox diagonal)."""

    residual_max: float
    residual_rms: float
    inverted_tets: int
    degenerate_tets: int
    flipped_surface_faces: int
    """Surface triangles whose normal turned by more than 90° (a folded edit folds the proxy too)."""
    crossing_surface_faces: int | None
    """tet-arap, frames whose lift misses ``residual_target`` somewhere: surface triangles near the vertices it misses
    that cross another one and did not at rest (the edit pushes the surface through itself; no map of space follows
    it there). None where not checked (other lifts, frames within the target)."""
    iterations: int
    seconds: float


def knn3_displacements(rest: np.ndarray, moved: np.ndarray, points: np.ndarray) -> np.ndarray:
    """rest (V,3) float64, moved (V,3) float64, points (M,3) float64 → (M,3) float64: at each point, the
    inverse-distance blend of the displacements ``moved − rest`` of its 3 nearest ``rest`` points."""
    dist, idx = cKDTree(rest).query(points, k=3)
    weights = 1.0 / np.maximum(dist, 1e-12)
    weights /= weights.sum(1, keepdims=True)
    return np.einsum("mk,mkd->md", weights, (moved - rest)[idx])


def closest_point_displacements(rest: SurfaceMesh, moved: np.ndarray, points: np.ndarray) -> np.ndarray:
    """rest SurfaceMesh (V vertices), moved (V,3) float64, points (M,3) float64 → (M,3) float64: at each point, the
    displacement of the closest point of the rest surface (barycentric blend of its triangle's displacements)."""
    triangle, bary = raycast.closest_points(raycast.raycasting_scene(rest.vertices, rest.faces), points)
    tri = rest.faces[triangle]
    return np.einsum("mk,mkd->md", bary, (moved - rest.vertices)[tri])


def surface_sample(tets_of: np.ndarray, indices: np.ndarray, budget: int) -> np.ndarray:
    """tets_of (V,) int64 the proxy tet holding each surface vertex, indices (S,) int64 of the surface vertices,
    budget → the sorted indices kept: all when ``S ≤ budget`` or ``budget`` is 0; else up to ``k`` vertices of each
    tet that holds some (every ``⌊count / k⌋``-th in index order), ``k`` the largest that keeps the total within the
    budget and at least 1 — every occupied tet keeps a constraint, so the sample is at most ``max(budget, occupied
    tets)`` whatever the surface's size."""
    if budget == 0 or len(indices) <= budget:
        return indices
    if not np.all(indices[1:] > indices[:-1]):
        indices = np.unique(indices)
    tets = np.ascontiguousarray(tets_of[indices], dtype=np.int64)
    counts = np.bincount(tets)
    occupied = counts[counts > 0]
    low, high = 1, int(occupied.max())
    while low < high:  # the largest k with Σ min(count, k) ≤ budget
        k = (low + high + 1) // 2
        low, high = (k, high) if np.minimum(occupied, k).sum() <= budget else (low, k - 1)
    keep = np.empty(len(tets), dtype=bool)
    _kernel.sample_mask(tets, np.maximum(counts // low, 1), low, keep)
    return indices[keep]


class Lift:
    """Binds a lift method to a proxy once (factorisations, trees), then lifts frames."""

    def __init__(
        self,
        proxy: TetProxy,
        rest: SurfaceMesh,
        method: LiftMethod = "tet-arap",
        config: LiftConfig | None = None,
        *,
        deformer: Deformer | None = None,
        edit: EditSpec | None = None,
        progress: Progress = no_progress,
    ) -> None:
        config = LiftConfig() if config is None else config
        self.rest, self.method, self.config = rest, method, config
        self.deformer, self.edit = deformer, edit
        self.progress = progress
        """Told of the factorisations and, per frame and refinement round, of the solver's iterations (``__call__``:
        ``max_iterations`` units per frame and round for the ARAP lifts, else 1; a lift that needs fewer rounds
        jumps to the end)."""
        self.scale = rest.bbox_diagonal
        """The rest surface's bbox diagonal: the unit of the reports' distances."""
        self.everywhere = np.flatnonzero(rest.referenced())
        """The surface vertices (those of a face): the residuals reported (a stray vertex, which no deformer is bound
        to move with its neighbours, would pull the proxy apart)."""
        self.surface = surface_sample(proxy.embed_tets, self.everywhere, config.max_constraints)
        """The surface vertices constraining the lift (all of :attr:`everywhere`, or a subsample of at most about
        ``config.max_constraints``): its constraints, refinement and crossing checks."""
        if method == "direct" and (deformer is None or not deformer.supports_points()):
            name = type(deformer).__name__ if deformer is not None else "no deformer"
            raise NerfEditError(f"--lift direct: {name} has no deform_points (use tet-arap)")
        if method == "tet-edit" and (edit is None or not edit.handles):
            raise NerfEditError("--lift tet-edit: the edit spec must have handles to apply to the proxy")
        self.refinements = 0  # bisections of the proxy done (self.proxy is the refined one)
        if method in ("tet-arap", "tet-edit"):
            progress(0, None, f"factorising ({len(proxy.tets)} tets)")
        self._bind(proxy)

    def _bind(self, proxy: TetProxy) -> None:
        """Set up the lift on ``proxy``: the embedding, and for the ARAP lifts the factored solver."""
        self.proxy = proxy
        self.embedding = proxy.embedding_matrix(self.surface)
        self.rest_volumes = tet_signed_volumes(proxy.vertices, proxy.tets)
        self.injective: InjectiveSolver | None = None  # built on the first fold
        if self.method == "tet-arap":  # the ARAP lift and the re-lift share the embedding's CᵀC
            weight = self.config.constraint_weight
            self._soft = SoftConstraints(self.embedding)
            self.solver = ArapSolver(
                proxy.vertices, proxy.tets, energy="elements", constraints=self._soft, constraint_weight=weight
            )
        elif self.method == "tet-edit":
            fixed, self.handle_targets = self.edit.handle_targets(proxy.vertices)
            self.solver = ArapSolver(proxy.vertices, proxy.tets, energy="elements", fixed=fixed)
            rows = np.arange(len(fixed))
            selection = sp.csr_matrix((np.ones(len(fixed)), (rows, fixed)), shape=(len(fixed), len(proxy.vertices)))
            self._soft = SoftConstraints(selection)

    def frame(
        self, index: int, surface: np.ndarray, previous: np.ndarray | None, span: Span | None = None
    ) -> tuple[np.ndarray, int]:
        """Frame ``index``: surface (V,3) float64, previous proxy frame (N,3) float64 or None (warm start) →
        (deformed proxy vertices (N,3) float64, ARAP iteration count; 0 for the direct methods). ``span``: the
        frame's part of the progress bar (told each ARAP iteration)."""
        method, proxy = self.method, self.proxy
        if method == "knn3":
            return proxy.vertices + knn3_displacements(self.rest.vertices, surface, proxy.vertices), 0
        if method == "closest-point":
            return proxy.vertices + closest_point_displacements(self.rest, surface, proxy.vertices), 0
        if method == "direct":
            return np.asarray(self.deformer.deform_points(proxy.vertices, index), dtype=np.float64), 0
        kwargs = dict(max_iterations=self.config.max_iterations, tolerance=self.config.tolerance)
        if span is not None:
            kwargs["callback"] = span.iterations()
        if method == "tet-edit":
            targets = self.handle_targets[index]
            result = self.solver.solve(fixed_positions=targets, initial=previous, **kwargs)
        else:
            targets = surface[self.surface]
            initial = previous
            if initial is None:
                rest = self.rest.vertices[self.surface]
                initial = proxy.vertices + knn3_displacements(rest, targets, proxy.vertices)
            result = self.solver.solve(constraint_targets=targets, initial=initial, **kwargs)
        if not self.config.injective or self.folds(result.vertices) == 0:
            return result.vertices, result.iterations
        if span is not None:
            span.at(detail="inversion-free re-lift")
        return self.unfolded(targets, previous, result.iterations)

    def folds(self, deformed: np.ndarray) -> int:
        """deformed proxy (N,3) float64 → the number of its tets that are inverted or degenerate (signed volume at
        most 1e-9 × the mean rest volume: the report's threshold)."""
        tiny = 1e-9 * np.abs(self.rest_volumes).mean()
        return int(np.count_nonzero(tet_signed_volumes(deformed, self.proxy.tets) <= tiny))

    def unfolded(self, targets: np.ndarray, previous: np.ndarray | None, iterations: int) -> tuple[np.ndarray, int]:
        """The inversion-free lift of a frame whose ARAP lift folds: targets (m,3) float64 (surface vertices for
        tet-arap, handle vertices for tet-edit, both soft with the ARAP lift's weight), started from ``previous``
        (N,3) float64 if it folds nothing, else from the rest proxy → (proxy vertices (N,3) float64, ARAP plus Newton
        iteration count)."""
        if self.injective is None:
            proxy = self.proxy
            weight = self.config.constraint_weight
            self.injective = InjectiveSolver(proxy.vertices, proxy.tets, self._soft, weight)
        start = previous if previous is not None and self.folds(previous) == 0 else self.proxy.vertices
        config = self.config
        result = self.injective.solve(
            start, targets, max_iterations=config.injective_max_iterations, tolerance=config.injective_tolerance
        )
        return result.vertices, iterations + result.iterations

    def report(
        self, deformed: np.ndarray, surface: np.ndarray, iterations: int, seconds: float, flipped: int | None = None
    ) -> FrameReport:
        """deformed proxy (N,3) float64, surface (V,3) float64 → the frame's :class:`FrameReport` (residual
        ``|A t' − v'|`` per surface vertex, relative to the rest bbox diagonal; inverted / degenerate tets by signed
        volume; surface faces turned by more than 90°: :meth:`flipped_faces`, unless given as ``flipped``)."""
        residual = self.misfit(deformed, surface)
        volumes = tet_signed_volumes(deformed, self.proxy.tets)
        tiny = 1e-9 * np.abs(self.rest_volumes).mean()
        return FrameReport(
            residual_max=float(residual.max()),
            residual_rms=float(np.sqrt(np.mean(residual**2))),
            inverted_tets=int(np.count_nonzero(volumes < -tiny)),
            degenerate_tets=int(np.count_nonzero(np.abs(volumes) <= tiny)),
            flipped_surface_faces=self.flipped_faces(surface) if flipped is None else flipped,
            crossing_surface_faces=None,
            iterations=iterations,
            seconds=seconds,
        )

    def flipped_faces(self, surface: np.ndarray) -> int:
        """surface frame (V,3) float64 → the number of its triangles whose normal turned by more than 90° from rest."""
        return int(np.count_nonzero(turned_faces(self.rest.vertices, surface, self.rest.faces)))

    def misfit(self, deformed: np.ndarray, surface: np.ndarray) -> np.ndarray:
        """deformed proxy (N,3), surface frame (V,3) float64 → (S,) float64: ``|A t' − v'|`` at each surface vertex
        (``self.surface``), relative to the rest bbox diagonal."""
        return _row_norms(self.embedding @ deformed - surface[self.surface]) / self.scale

    def residuals(self, lifted: np.ndarray, frames: np.ndarray) -> np.ndarray:
        """lifted proxy frames (F,N,3), surface frames (F,V,3) float64 → (S,) float64: each surface vertex's worst
        :meth:`misfit` over the frames."""
        return np.max([self.misfit(x, v) for x, v in zip(lifted, frames)], axis=0)

    def bisections_needed(self, residual: np.ndarray, active: np.ndarray | None = None) -> np.ndarray:
        """residual (S,), active (S,) bool (default all: the vertices not given up) → (S,) int64: per surface vertex,
        the bisections of its tet expected to bring it within :data:`AIM` × ``residual_target``: ⌈log₄(residual /
        aim)⌉, 0 where it is within (a linear fit's error falls as h², by about 4 per halving) and where not active;
        all 0 while every active vertex is within the target (a vertex given up does not keep the others refining)."""
        active = np.ones(len(residual), dtype=bool) if active is None else active
        if not (residual[active] > self.config.residual_target).any():
            return np.zeros(len(residual), dtype=np.int64)
        excess = np.maximum(residual / (AIM * self.config.residual_target), 1.0)
        return np.where(active, np.ceil(np.log(excess) / np.log(4.0)), 0).astype(np.int64)

    def _lift(
        self, frames: np.ndarray, starts: np.ndarray | None, bar: tuple[int, int, str]
    ) -> tuple[np.ndarray, list[FrameReport]]:
        """Lift every frame (warm-started from the previous one, or from ``starts``); ``bar``: (units done before,
        total units, label) of the progress."""
        out, reports, previous = [], [], None
        units = self._units()
        for index, surface in enumerate(frames):
            start = time.perf_counter()
            label = f"{bar[2]}frame {index + 1}/{len(frames)}"
            span = Span(self.progress, bar[0] + index * units, units, bar[1], label)
            span.at(0)
            deformed, iterations = self.frame(index, surface, previous if starts is None else starts[index], span)
            span.end(f"{iterations} iteration{'s' * (iterations != 1)}" if iterations else "")
            seconds = time.perf_counter() - start
            reports.append(self.report(deformed, surface, iterations, seconds, self._flipped[index]))
            out.append(deformed)
            previous = deformed
        return np.stack(out), reports

    def __call__(self, frames: np.ndarray) -> tuple[np.ndarray, list[FrameReport]]:
        """Lift surface frames ``(F,V,3)`` float → proxy frames ``(F,N,3)`` float64 and one report per frame (its
        iterations and seconds summed over the refinement rounds). Frames are warm-started from the previous frame;
        after a refinement (tet-arap), from their own lift prolonged onto the refined proxy, now ``self.proxy``."""
        frames = np.asarray(frames, dtype=np.float64)
        self._flipped = [self.flipped_faces(surface) for surface in frames]  # of the frames alone: once for every round
        rounds = self.config.refine_rounds if self.method == "tet-arap" else 0
        per_pass = len(frames) * self._units()
        total = (1 + rounds) * per_pass
        lifted, reports = self._lift(frames, None, (0, total, ""))
        residual = self.residuals(lifted, frames) if self.method == "tet-arap" else None
        misses = np.zeros(len(self.surface), dtype=np.int64)  # rounds that refined a vertex without helping it
        for round_ in range(1, rounds + 1):
            need = np.minimum(self.bisections_needed(residual, misses < PATIENCE), MAX_BISECTIONS)
            if not need.any():
                break
            label = f"refinement {round_}/{rounds} · "
            self.progress(round_ * per_pass, total, f"{label}bisecting, factorising")
            kept = (self.proxy, self.refinements, lifted, reports)
            proxy = self.proxy
            for level in range(int(need.max())):
                marked = np.zeros(len(proxy.tets), dtype=bool)
                marked[proxy.embed_tets[self.surface[need > level]]] = True
                refinement = bisect(proxy.vertices, proxy.tets, marked)
                proxy = proxy.refined(refinement, self.rest)
                lifted = np.stack([refinement.prolong(x) for x in lifted])
                self.refinements += 1
            self._bind(proxy)
            lifted, again = self._lift(frames, lifted, (round_ * per_pass, total, label))
            reports = [
                dataclasses.replace(new, iterations=old.iterations + new.iterations, seconds=old.seconds + new.seconds)
                for old, new in zip(reports, again)
            ]
            residual, before = self.residuals(lifted, frames), residual
            improved = (need > 0) & (residual <= HELPED * before)
            if not improved.any():  # the round helped no vertex: keep the proxy and lift it had
                proxy, self.refinements, lifted, reports = kept
                self.progress((round_ + 1) * per_pass, total, f"{label}no gain: back to the proxy before")
                self._bind(proxy)
                break
            misses += (need > 0) & ~improved  # PATIENCE misses: not the fit's error there, no finer proxy helps
        if len(self.surface) < len(self.everywhere):  # fitted on a subsample: report every surface vertex
            reports = [self._everywhere(*args) for args in zip(reports, lifted, frames)]
        if self.method == "tet-arap":
            reports = [self._check_crossings(*args) for args in zip(reports, lifted, frames)]
        self.progress(total, total, f"{len(frames)} frame(s), {self.refinements} bisection(s)")
        return lifted, reports

    def _everywhere(self, report: FrameReport, deformed: np.ndarray, surface: np.ndarray) -> FrameReport:
        """The report of a frame (lifted proxy (N,3), surface (V,3)) with its residuals over every surface vertex."""
        proxy, rows = self.proxy, self.everywhere
        residual = np.empty(len(rows))
        launch(
            _kernel.embedded_distances, rows, proxy.embed_tets, proxy.embed_bary, proxy.tets,
            np.ascontiguousarray(deformed, dtype=np.float64), np.ascontiguousarray(surface, dtype=np.float64), residual,
        )  # fmt: skip
        residual /= self.scale
        return dataclasses.replace(
            report, residual_max=float(residual.max()), residual_rms=float(np.sqrt(np.mean(residual**2)))
        )

    def _check_crossings(self, report: FrameReport, deformed: np.ndarray, surface: np.ndarray) -> FrameReport:
        """The report of a frame (lifted proxy (N,3), surface (V,3)) with ``crossing_surface_faces`` counted if its
        residual misses the target: among the faces whose corners lie within :data:`CROSSING_RADIUS` × the bbox
        diagonal of a vertex it misses, those crossing another face of that neighbourhood that did not cross one of it
        at rest (per face, not per pair; the test runs on the neighbourhood only: on a whole 900k-face mesh it takes
        3.4 s)."""
        if report.residual_max <= self.config.residual_target:
            return report
        missed = surface[self.surface[self.misfit(deformed, surface) > self.config.residual_target]]
        if len(missed) == 0:  # a residual that is not a number: nothing to look at
            return report
        radius = CROSSING_RADIUS * self.scale
        candidates = np.flatnonzero(
            np.all((surface >= missed.min(0) - radius) & (surface <= missed.max(0) + radius), axis=1)
        )
        distance, _ = cKDTree(missed).query(surface[candidates], distance_upper_bound=radius)
        flagged = np.zeros(len(surface), dtype=bool)
        flagged[candidates[np.isfinite(distance)]] = True
        rest, _ = self.rest.submesh(flagged)  # the faces with every corner flagged, corners renumbered
        moved = rest.with_vertices(surface[flagged])
        crossing = moved.self_intersecting_faces() & ~rest.self_intersecting_faces()
        return dataclasses.replace(report, crossing_surface_faces=int(np.count_nonzero(crossing)))

    def _units(self) -> int:
        """Progress units of one frame's lift: ``max_iterations`` for the ARAP lifts, else 1."""
        return self.config.max_iterations if self.method in ("tet-arap", "tet-edit") else 1


def _row_norms(d: np.ndarray) -> np.ndarray:
    """(M,3) float64 → (M,) float64 Euclidean row norms, without ``np.linalg.norm``'s temporaries."""
    return np.sqrt(np.einsum("ij,ij->i", d, d))
