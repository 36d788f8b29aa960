"""Shared fixtures: small real meshes and their (cached) tet proxies."""

import numpy as np
import pytest
import trimesh

from nerfedit_plugin.mesh import SurfaceMesh


@pytest.fixture(scope="session")
def capsule() -> SurfaceMesh:
    """A capsule along z (height 2, radius 0.35), ~600 vertices: bends nicely under handle edits."""
    mesh = trimesh.creation.capsule(height=1.3, radius=0.35, count=[24, 12])
    return SurfaceMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))


@pytest.fixture(scope="session")
def capsule_proxy(capsule, tmp_path_factory):
    from nerfedit_plugin.proxy import ProxyConfig, cached_proxy

    proxy, _ = cached_proxy(capsule, ProxyConfig(), tmp_path_factory.mktemp("proxy-cache"))
    return proxy
