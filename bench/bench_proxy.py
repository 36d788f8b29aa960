"""Proxy build time (alpha-wrap cage -> decimate -> pytetwild -> clean -> embed) vs raw pytetwild on the mesh.

Anchor (docs/benchmarks.md): raw pytetwild on the undecimated mesh, same ``edge_length_fac``/``epsilon``,
``optimize=True``. On the 28k-vertex bunny it takes minutes, so by default the anchor runs on the cow and the
airplane (the same kind of run, on meshes it finishes) and the bunny gets our absolute time; ``--full`` adds the
raw bunny anchor. ``--quick`` runs the cow only.

    python bench/bench_proxy.py [--quick | --full]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nerfedit_plugin.edit.proxy import ProxyConfig, build_proxy, tetrahedralize
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.geometry.samples import sample_mesh_path
from nerfedit_plugin.geometry.tets import tet_signed_volumes


def quality(vertices: np.ndarray, tets: np.ndarray) -> str:
    volumes = np.abs(tet_signed_volumes(vertices, tets))
    return f"{len(vertices):6d} verts {len(tets):7d} tets  min/median volume {volumes.min() / np.median(volumes):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="cow only")
    mode.add_argument("--full", action="store_true", help="also raw pytetwild on the undecimated bunny (minutes)")
    args = parser.parse_args()

    import open3d  # noqa: F401,E401  one-time imports stay out of the timings

    config = ProxyConfig()
    names = ["cow"] if args.quick else ["bunny", "cow", "airplane"]
    anchored = {"cow", "airplane"} | ({"bunny"} if args.full else set())
    print(f"config: {config}")
    for name in names:
        mesh = SurfaceMesh.load(sample_mesh_path(name))
        print(f"\n== {name}: {mesh.n_vertices} vertices, {len(mesh.faces)} faces")
        start = time.perf_counter()
        proxy = build_proxy(mesh, config)
        ours = time.perf_counter() - start
        info = proxy.info
        stages = "  ".join(f"{stage} {seconds:.2f}s" for stage, seconds in info["times"].items())
        print(
            f"ours  {ours:7.2f} s  {quality(proxy.vertices, proxy.tets)}  cage {info['cage_faces']} faces, "
            f"offset {info['offset']:.4g} (margin {info['margin']:.2f}x), attempts {info['attempts']}, "
            f"dropped degenerate {info['dropped_degenerate_tets']}"
        )
        print(f"      stages: {stages}")
        if name in anchored:
            start = time.perf_counter()
            raw_vertices, raw_tets = tetrahedralize(mesh, config)
            raw = time.perf_counter() - start
            print(f"raw   {raw:7.2f} s  {quality(raw_vertices, raw_tets)}  (pytetwild on the undecimated mesh)")
            print(f"ratio raw / ours = {raw / ours:.1f}x")


if __name__ == "__main__":
    main()
