"""Shared fixtures: small real meshes and their (cached) tet proxies, the example third-party plugin installed."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from nerfedit_plugin.geometry.mesh import SurfaceMesh

FIXTURES = Path(__file__).parent / "fixtures"
TWIST = Path(__file__).resolve().parents[1] / "docs" / "examples" / "twist"


@pytest.fixture(scope="session")
def capsule() -> SurfaceMesh:
    """A capsule along z (height 2, radius 0.35), ~600 vertices: bends nicely under handle edits."""
    mesh = trimesh.creation.capsule(height=1.3, radius=0.35, count=[24, 12])
    return SurfaceMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))


@pytest.fixture(scope="session")
def twist_site(tmp_path_factory) -> Path:
    """``pip install --target`` of docs/examples/twist, offline, as a folder to put on the path (its entry point
    registers ``twist``); built from a copy (setuptools builds in-tree)."""
    root = tmp_path_factory.mktemp("third_party")
    source, site = root / "source", root / "site"
    shutil.copytree(TWIST, source, ignore=shutil.ignore_patterns("tests", "build", "*.egg-info", "__pycache__"))
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--no-deps",
            "--no-build-isolation",
            "--no-index",
            "--quiet",
            "--target",
            str(site),
            str(source),
        ],
        check=True,
        capture_output=True,
    )
    return site


@pytest.fixture(scope="session")
def proxy_cache(tmp_path_factory):
    """One proxy cache for the session: tests that edit the same mesh build its tet proxy once."""
    return tmp_path_factory.mktemp("proxy-cache")


@pytest.fixture(scope="session")
def capsule_proxy(capsule):
    """The capsule's tet proxy as ``build_proxy(capsule, ProxyConfig())`` gave it once (pytetwild 0.4.2; 957 vertices,
    4109 tets), read from ``fixtures/capsule_proxy.npz`` with the capsule embedded again. pytetwild's output differs
    from run to run, even on one thread, so a proxy built per session made tolerances on it depend on the draw; the
    builder itself is tested in ``edit/test_proxy.py``."""
    from nerfedit_plugin.edit.proxy import proxy_from_tets

    with np.load(FIXTURES / "capsule_proxy.npz") as data:
        return proxy_from_tets(data["vertices"], data["tets"], capsule, "fixtures/capsule_proxy.npz")


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    """A 32×32 Blender dataset of the pymeshlab cow (8 train, 1 val, 2 test views) for training tests."""
    from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset

    out = tmp_path_factory.mktemp("tiny-scene") / "cow"
    generate_dataset(
        GenerateConfig(out=out, mesh="sample:cow", resolution=32, n_train=8, n_val=1, n_test=2, supersample=1)
    )
    return out


FLOW_EDIT = {
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1], "max": [1, 1, -0.25]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.25], "max": [1, 1, 1]}}, "transform": {"translate": [0.15, 0, 0]}},
    ],
    "frames": 3,
}


@pytest.fixture(scope="session")
def capsule_flow(capsule, proxy_cache, tmp_path_factory):
    """Folders of the whole pipeline on the vertex-coloured capsule, made by ``nerfedit`` itself: ``data`` (24×24
    generated dataset, z-up, 2 test views), ``run`` (its exact mesh-field run) and ``edit`` (a 3-frame handle edit of
    the run, ``edit.json``; its proxy in the session's cache)."""
    import json

    from nerfedit_plugin.cli.app import main
    from nerfedit_plugin.data.synthetic import colorize

    root = tmp_path_factory.mktemp("capsule-flow")
    colorize(capsule).save(root / "capsule.ply")
    (root / "edit.json").write_text(json.dumps(FLOW_EDIT))
    for argv in (
        ["generate", "--mesh", root / "capsule.ply", "--resolution", 24, "--n-train", 4, "--n-val", 1, "--n-test", 2,
         "--supersample", 1, "--up-axis", "z", "--out", root / "data"],
        ["train", "--field", "mesh", "--data", root / "data" / "mesh.ply", "--out", root / "run"],
        ["edit", "--run", root / "run", "--edit", root / "edit.json", "--out", root / "edit",
         "--cache-dir", proxy_cache],
    ):  # fmt: skip
        assert main([str(a) for a in argv]) == 0, argv
    return root
