"""Edits at scale (docs/benchmarks.md): the ARAP head edit on the bunny and its Loop subdivisions.

``sample:bunny`` (28k vertices) and 1–3 Loop subdivisions (pymeshlab ``meshing_surface_subdivision_loop``: 112k,
449k, 1.8M; cached in /tmp), ``configs/arap_bunny_head.json``, ``nerfedit_plugin.pipeline.edit.run_edit`` with the
default ARAP deformer and lift. Each case runs in its own subprocess (peak RSS per case), first with an empty proxy
cache (cold), then again with the cache it filled (warm). Printed per row: the stage times of ``timings_s``, the
folded faces, inverted tets, peak RSS, the case's CPU time (all threads, imports included), µs per vertex (of
the stage times) and its ratio to the 112k anchor measured in the same run (the anchor runs whenever any case
does).

``--solver`` instead times the ARAP solver alone in CPU time (``time.process_time``, all threads): the bind
(``ArapSolver``), the solve with the deformer's defaults (iterations, E ÷ the reference energy :data:`REFERENCE`
− 1; at 1.8M, which has no reference, E itself), and a run without stopping test: the iterations to reach
E ≤ (1 + 10⁻³) E_ref and their CPU time (the run's CPU per iteration × iterations), for each ``--method`` of
``ArapSolver.solve`` (level by level, the methods interleaved, so both see the same machine load).

``--accuracy`` instead compares the deformer's result (its defaults, which take the multiresolution path above
``coarse_above`` vertices; the direct solve; the multiresolution path forced at ``--coarse`` vertices; the
multiresolution path polished by each ``--polish`` N fine iterations) with the converged direct solve (tolerance
1e-10 from rest, at most 3000 L-BFGS iterations; cached in /tmp): mean and max vertex distance in units of the bbox
diagonal, the path taken, the coarse size, the folded faces and the wall time of bind + deform.

``--binds`` times the skeleton (``configs/skeleton_bunny_pose.json``, bone heat) and cage
(``configs/cage_bunny_auto.json``, automatic cage, mean value coordinates) binds, each in its own subprocess: on the
mesh itself (``direct``; levels up to ``--direct-up-to``) and on the coarse level with an empty bind cache (cold)
and with the cache the cold bind filled (warm: the coarse level is read); the last frame's mean and max distance to
the direct bind's, in units of the bbox diagonal, and its largest displacement for scale.

``--mesh MESH --edit SPEC`` adds the edit of another mesh to the table (e.g. a non-subdivided marching-cubes mesh:
the demo's run extracted at 640³, ``nerfedit extract --run RUN --resolution 640``, with the demo's ``nod.json``).

Usage: ``python bench/bench_scale.py [--levels 0 1 2 3] [--mesh MESH --edit SPEC] [--solver [--method lbfgs
anderson] | --accuracy [--coarse N] [--polish N ...] | --binds [--direct-up-to L]]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EDIT = ROOT / "configs" / "arap_bunny_head.json"
ANCHOR = 1
#: converged ARAP energies of the head edit (solver at tolerance 1e-10 from rest), by subdivision level
REFERENCE = {0: 9.7475e-4, 1: 4.5282e-4, 2: 1.8885e-4}
REACH_ITERATIONS = 600
STAGES = ("load", "bind", "deform", "proxy", "lift", "write")


def level_mesh(level: int) -> Path:
    """The bunny after ``level`` Loop subdivisions as a PLY, cached in /tmp."""
    import pymeshlab

    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    path = Path(f"/tmp/nerfedit_bench_scale_bunny_{level}.ply")
    if not path.exists():
        rest = SurfaceMesh.load("sample:bunny")
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(rest.vertices, rest.faces.astype(np.int32)))
        if level:
            ms.meshing_surface_subdivision_loop(iterations=level, threshold=pymeshlab.PercentageValue(0))
        mesh = ms.current_mesh()
        SurfaceMesh(mesh.vertex_matrix().astype(np.float64), mesh.face_matrix().astype(np.int64)).save(path)
    return path


def reference_solution(level: int) -> np.ndarray:
    """The converged direct ARAP solve of the head edit on ``level`` (tolerance 1e-10 from rest), cached in /tmp."""
    from nerfedit_plugin.edit.spec import load_edit_spec
    from nerfedit_plugin.geometry.arap import ArapSolver
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    path = Path(f"/tmp/nerfedit_bench_scale_reference_{level}.npy")
    if not path.exists():
        mesh = SurfaceMesh.load(level_mesh(level))
        handles, targets = load_edit_spec(EDIT).handle_targets(mesh.vertices, mesh.faces)
        solver = ArapSolver(mesh.vertices, mesh.faces, fixed=handles)
        result = solver.solve(targets[0], max_iterations=3000, tolerance=1e-10, method="lbfgs")
        np.save(path, result.vertices)
    return np.load(path)


def accuracy_case(level: int, coarse: int, polish: list[int]) -> None:
    """The deformer against the converged direct solve on one level: prints a table row per configuration."""
    from deformers.arap import ArapConfig
    from nerfedit_plugin.edit.spec import load_edit_spec
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.geometry.normals import face_normals

    mesh = SurfaceMesh.load(level_mesh(level))
    spec = load_edit_spec(EDIT).in_world(np.eye(4))
    reference = reference_solution(level)
    rest_normals = face_normals(mesh.vertices, mesh.faces)
    configs = {
        "defaults": ArapConfig(),
        "direct": ArapConfig(multiresolution="off"),
        f"multires {coarse}": ArapConfig(multiresolution="on", coarse_vertices=coarse),
        **{f"defaults, polish {n}": ArapConfig(multiresolution="on", polish=n) for n in polish},
    }
    for name, config in configs.items():
        start = time.perf_counter()
        model = config.setup()
        model.bind(mesh, spec)
        deformed = model.deform()[0]
        seconds = time.perf_counter() - start
        error = np.linalg.norm(deformed - reference, axis=1) / mesh.bbox_diagonal
        report = model.report()
        coarse_size = report.get("coarse", {}).get("vertices", "–")
        folded = int(np.count_nonzero(np.einsum("ij,ij->i", rest_normals, face_normals(deformed, mesh.faces)) < 0))
        print(
            f"| {mesh.n_vertices} | {name} | {report['path']} | {coarse_size} | {error.mean():.2e} | "
            f"{error.max():.2e} | {folded} | {seconds:.2f} |",
            flush=True,
        )


BIND_EDITS = {"skeleton": "skeleton_bunny_pose.json", "cage": "cage_bunny_auto.json"}


def bind_case(spec: str) -> None:
    """One bind (the subprocess side): ``deformer:level:multiresolution:cache``; saves the last frame beside the
    level's mesh and prints the bind seconds, the report and the peak RSS as one JSON line."""
    from nerfedit_plugin.edit.deformer import BindCache, mesh_digest
    from nerfedit_plugin.edit.spec import load_edit_spec
    from nerfedit_plugin.geometry.mesh import SurfaceMesh
    from nerfedit_plugin.registry import DEFORMERS, discover

    name, level, multiresolution, cache = spec.split(":", 3)
    mesh = SurfaceMesh.load(level_mesh(int(level)))
    config = discover().config_class(DEFORMERS, name)(multiresolution=multiresolution)
    edit = load_edit_spec(ROOT / "configs" / BIND_EDITS[name], config._target.spec_keys).in_world(np.eye(4))
    deformer = config.setup()
    deformer.bind_cache = BindCache(cache, mesh_digest(mesh))
    start = time.perf_counter()
    deformer.bind(mesh, edit)
    seconds = time.perf_counter() - start
    np.save(f"/tmp/nerfedit_bench_scale_{name}_{level}_{multiresolution}.npy", deformer.deform()[-1])
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"seconds": seconds, "report": deformer.report(), "rss_mb": rss}))


def binds(levels: list[int], direct_up_to: int) -> None:
    """The skeleton and cage binds per level (:func:`bind_case` in subprocesses): prints a table row per bind."""
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    print(
        "| deformer | vertices | path | bind cache | coarse vertices | bind s | peak RSS MB | mean / diag | "
        "max / diag | moved / diag |"
    )
    print("|" + "---|" * 10)
    for level in levels:
        mesh = SurfaceMesh.load(level_mesh(level))
        for name in BIND_EDITS:
            with tempfile.TemporaryDirectory() as cache:
                runs = [("direct", "off", "–")] if level <= direct_up_to else []
                runs += [("multiresolution", "on", "cold"), ("multiresolution", "on", "warm")]
                for path, multiresolution, state in runs:
                    command = [sys.executable, __file__, "--bind-case", f"{name}:{level}:{multiresolution}:{cache}"]
                    done = subprocess.run(command, check=True, capture_output=True, text=True, cwd=ROOT)
                    r = json.loads(done.stdout.strip().splitlines()[-1])
                    coarse = r["report"].get("coarse", {}).get("vertices", "–")
                    error = "– | – | –"
                    reference = Path(f"/tmp/nerfedit_bench_scale_{name}_{level}_off.npy")
                    if multiresolution == "on" and level <= direct_up_to:
                        deformed = np.load(f"/tmp/nerfedit_bench_scale_{name}_{level}_on.npy")
                        distance = np.linalg.norm(deformed - np.load(reference), axis=1) / mesh.bbox_diagonal
                        moved = np.linalg.norm(np.load(reference) - mesh.vertices, axis=1).max() / mesh.bbox_diagonal
                        error = f"{distance.mean():.1e} | {distance.max():.1e} | {moved:.3f}"
                    print(
                        f"| {name} | {mesh.n_vertices} | {path} | {state} | {coarse} | {r['seconds']:.2f} | "
                        f"{r['rss_mb']:.0f} | {error} |",
                        flush=True,
                    )


def run_case(mesh: str, cache: str, edit: str) -> None:
    """One edit (the subprocess side): prints its report's figures and the peak RSS as one JSON line."""
    from deformers.arap import ArapConfig
    from nerfedit_plugin.pipeline.edit import run_edit

    with tempfile.TemporaryDirectory() as out:
        report = run_edit(mesh, ArapConfig(), edit, Path(out) / "edit", cache_dir=cache).report
    frame = report["per_frame"][-1]
    print(
        json.dumps(
            {
                "vertices": report["surface"]["vertices"],
                "timings_s": report["timings_s"],
                "folded": frame["flipped_surface_faces"],
                "inverted": frame["inverted_tets"],
                "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                "cpu_s": time.process_time(),
            }
        )
    )


def measure(mesh: Path, edit: Path, cache: str) -> dict:
    command = [sys.executable, __file__, "--case", str(mesh), "--cache", cache, "--edit", str(edit)]
    done = subprocess.run(command, check=True, capture_output=True, text=True, cwd=ROOT)
    return json.loads(done.stdout.strip().splitlines()[-1])


def solver_case(level: int, methods: list[str]) -> None:
    """The ARAP solver alone on one level: prints a table row (CPU seconds) per method."""
    from deformers.arap import ArapConfig
    from nerfedit_plugin.edit.spec import load_edit_spec
    from nerfedit_plugin.geometry.arap import ArapSolver
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    mesh = SurfaceMesh.load(level_mesh(level))
    handles, targets = load_edit_spec(EDIT).handle_targets(mesh.vertices, mesh.faces)
    start = time.process_time()
    solver = ArapSolver(mesh.vertices, mesh.faces, fixed=handles)
    bind = time.process_time() - start
    config, reference = ArapConfig(), REFERENCE.get(level)
    for method in methods:
        start = time.process_time()
        result = solver.solve(
            targets[0], max_iterations=config.max_iterations, tolerance=config.tolerance, method=method
        )
        deform = time.process_time() - start
        assert np.array_equal(result.vertices[handles], targets[0])
        if reference is None:  # no converged energy known (1.8M: hours): E itself, no run to it
            energy, reach, per_iteration = f"E = {result.energies[-1]:.6e}", "– | –", deform / result.iterations
        else:
            start = time.process_time()
            long = solver.solve(targets[0], max_iterations=REACH_ITERATIONS, tolerance=0.0, method=method)
            per_iteration = (time.process_time() - start) / max(long.iterations, 1)
            reached = np.flatnonzero(np.array(long.energies) <= (1 + 1e-3) * reference)
            reach = f"{reached[0]} | {reached[0] * per_iteration:.1f}" if len(reached) else f"> {long.iterations} | –"
            energy = f"{result.energies[-1] / reference - 1:.1e}"
        print(
            f"| {len(mesh.vertices)} | {method} | {bind:.2f} | {deform:.2f} | {result.iterations} | {energy} | "
            f"{reach} | {1e3 * per_iteration:.0f} |",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3], help="Loop subdivision levels")
    parser.add_argument("--solver", action="store_true", help="time the ARAP solver alone (CPU time)")
    parser.add_argument(
        "--method", nargs="+", default=["lbfgs", "anderson"], choices=["lbfgs", "anderson"], help="with --solver"
    )
    parser.add_argument("--accuracy", action="store_true", help="against the converged direct solve (levels 0-2)")
    parser.add_argument("--coarse", type=int, default=10_000, help="with --accuracy: coarse vertices of the forced row")
    parser.add_argument(
        "--polish", type=int, nargs="*", default=[], help="with --accuracy: rows polished by these fine iterations"
    )
    parser.add_argument("--binds", action="store_true", help="time the skeleton and cage binds")
    parser.add_argument("--direct-up-to", type=int, default=2, help="with --binds: the last level bound directly too")
    parser.add_argument("--bind-case", help=argparse.SUPPRESS)
    parser.add_argument("--mesh", help="also edit this mesh (e.g. a field's marching-cubes extract) with --edit")
    parser.add_argument("--edit", default=str(EDIT), help="with --mesh: its edit spec")
    parser.add_argument("--case", help=argparse.SUPPRESS)
    parser.add_argument("--cache", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        run_case(args.case, args.cache, args.edit)
        return
    if args.bind_case:
        bind_case(args.bind_case)
        return
    if args.binds:
        binds(args.levels, args.direct_up_to)
        return
    if args.accuracy:
        print("| vertices | config | path | coarse vertices | mean / diag | max / diag | folded | bind + deform s |")
        print("|" + "---|" * 8)
        for level in args.levels:
            accuracy_case(level, args.coarse, args.polish)
        return
    if args.solver:
        print(
            "| vertices | method | bind CPU s | deform CPU s | iterations | E/E_ref − 1 | iterations to 1e-3 | "
            "CPU s to 1e-3 | ms/iteration |"
        )
        print("|" + "---|" * 9)
        for level in args.levels:
            solver_case(level, args.method)
        return
    cases = [(level, level_mesh(level), EDIT) for level in sorted(set(args.levels) | {ANCHOR})]
    if args.mesh:
        cases.append(("mesh", Path(args.mesh), Path(args.edit)))
    rows = []
    for label, mesh, edit in cases:
        with tempfile.TemporaryDirectory() as cache:
            for state in ("cold", "warm"):
                rows.append((label, state, measure(mesh, edit, cache)))
    anchor = {state: r for label, state, r in rows if label == ANCHOR}
    print(
        "| vertices | cache | "
        + " | ".join(STAGES)
        + " | total s | folded | inverted | peak RSS MB | CPU s | µs/vertex |"
        " ÷ 112k |"
    )
    print("|" + "---|" * (len(STAGES) + 9))
    for _level, state, r in rows:
        total = sum(r["timings_s"].values())
        per_vertex = 1e6 * total / r["vertices"]
        reference = 1e6 * sum(anchor[state]["timings_s"].values()) / anchor[state]["vertices"]
        stages = " | ".join(f"{r['timings_s'].get(s, 0.0):.2f}" for s in STAGES)
        print(
            f"| {r['vertices']} | {state} | {stages} | {total:.1f} | {r['folded']} | {r['inverted']} | "
            f"{r['rss_mb']:.0f} | {r['cpu_s']:.1f} | {per_vertex:.1f} | {per_vertex / reference:.2f} |"
        )


if __name__ == "__main__":
    main()
