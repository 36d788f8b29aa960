"""Edits at scale (issue 18, docs/benchmarks.md): the ARAP head edit on the bunny and its Loop subdivisions.

``sample:bunny`` (28k vertices) and 1–3 Loop subdivisions (pymeshlab ``meshing_surface_subdivision_loop``: 112k,
449k, 1.8M; cached in /tmp), ``configs/arap_bunny_head.json``, ``nerfedit_plugin.edit.job.run_edit`` with the
default ARAP deformer and lift. Each case runs in its own subprocess (peak RSS per case), first with an empty proxy
cache (cold), then again with the cache it filled (warm). Printed per row: the stage times of ``timings_s``, the
folded faces, inverted tets, peak RSS and µs per vertex, and the ratio of µs per vertex to the 112k anchor
measured in the same run (the anchor case runs whenever any case does).

Usage: ``python bench/bench_scale.py [--levels 0 1 2 3]``
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EDIT = ROOT / "configs" / "arap_bunny_head.json"
ANCHOR = 1
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


def run_case(mesh: str, cache: str) -> None:
    """One edit (the subprocess side): prints its report's figures and the peak RSS as one JSON line."""
    from deformers.arap import ArapConfig
    from nerfedit_plugin.edit.job import run_edit

    with tempfile.TemporaryDirectory() as out:
        report = run_edit(mesh, ArapConfig(), EDIT, Path(out) / "edit", cache_dir=cache).report
    frame = report["per_frame"][-1]
    print(
        json.dumps(
            {
                "vertices": report["surface"]["vertices"],
                "timings_s": report["timings_s"],
                "folded": frame["flipped_surface_faces"],
                "inverted": frame["inverted_tets"],
                "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            }
        )
    )


def measure(level: int, cache: str) -> dict:
    command = [sys.executable, __file__, "--case", str(level_mesh(level)), "--cache", cache]
    done = subprocess.run(command, check=True, capture_output=True, text=True, cwd=ROOT)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3], help="Loop subdivision levels")
    parser.add_argument("--case", help=argparse.SUPPRESS)
    parser.add_argument("--cache", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        run_case(args.case, args.cache)
        return
    rows = []
    for level in sorted(set(args.levels) | {ANCHOR}):
        with tempfile.TemporaryDirectory() as cache:
            for state in ("cold", "warm"):
                rows.append((level, state, measure(level, cache)))
    anchor = {state: r for level, state, r in rows if level == ANCHOR}
    print(
        "| vertices | cache | " + " | ".join(STAGES) + " | total s | folded | inverted | peak RSS MB | µs/vertex |"
        " ÷ 112k |"
    )
    print("|" + "---|" * (len(STAGES) + 8))
    for _level, state, r in rows:
        total = sum(r["timings_s"].values())
        per_vertex = 1e6 * total / r["vertices"]
        reference = 1e6 * sum(anchor[state]["timings_s"].values()) / anchor[state]["vertices"]
        stages = " | ".join(f"{r['timings_s'].get(s, 0.0):.2f}" for s in STAGES)
        print(
            f"| {r['vertices']} | {state} | {stages} | {total:.1f} | {r['folded']} | {r['inverted']} | "
            f"{r['rss_mb']:.0f} | {per_vertex:.1f} | {per_vertex / reference:.2f} |"
        )


if __name__ == "__main__":
    main()
