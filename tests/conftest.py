"""Shared fixtures: small real meshes and their (cached) tet proxies."""

import numpy as np
import pytest
import trimesh

from nerfedit_plugin.geometry.mesh import SurfaceMesh


@pytest.fixture(scope="session")
def capsule() -> SurfaceMesh:
    """A capsule along z (height 2, radius 0.35), ~600 vertices: bends nicely under handle edits."""
    mesh = trimesh.creation.capsule(height=1.3, radius=0.35, count=[24, 12])
    return SurfaceMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))


@pytest.fixture(scope="session")
def proxy_cache(tmp_path_factory):
    """One proxy cache for the session: tests that edit the same mesh build its tet proxy once."""
    return tmp_path_factory.mktemp("proxy-cache")


@pytest.fixture(scope="session")
def capsule_proxy(capsule, proxy_cache):
    from nerfedit_plugin.edit.proxy import ProxyConfig, cached_proxy

    proxy, _ = cached_proxy(capsule, ProxyConfig(), proxy_cache)
    return proxy


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    """A 32×32 Blender dataset of the pymeshlab cow (8 train, 1 val, 2 test views) for training tests."""
    from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset

    out = tmp_path_factory.mktemp("tiny-scene") / "cow"
    generate_dataset(
        GenerateConfig(out=out, mesh="sample:cow", resolution=32, n_train=8, n_val=1, n_test=2, supersample=1)
    )
    return out
