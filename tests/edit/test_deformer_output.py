"""The edit job holds every deformer, a third party's too, to the output contract: a wrong shape, non-finite values
or a modified rest mesh is one NerfEditError naming the deformer class, before the lift and with nothing written;
float32 positions are widened."""

import dataclasses
import json

import numpy as np
import pytest

from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.pipeline.edit import run_edit


class Lift01(Deformer):
    """Moves every vertex up by 0.01."""

    spec_keys = frozenset()

    def bind(self, rest, edit):
        self.rest = rest

    def deform(self):
        return (self.rest.vertices + [0.0, 0.0, 0.01])[None]


class DropsAVertex(Lift01):
    def deform(self):
        return super().deform()[:, 1:]


class TwoDimensional(Lift01):
    def deform(self):
        return super().deform()[0]


class NaNs(Lift01):
    def deform(self):
        out = super().deform()
        out[0, 5] = np.nan
        return out


class MovesRest(Lift01):
    def bind(self, rest, edit):
        super().bind(rest, edit)
        rest.vertices[:, 2] += 0.1


class ReturnsList(Lift01):
    def deform(self):
        return super().deform().tolist()


class Float32(Lift01):
    def deform(self):
        return super().deform().astype(np.float32)


def config_of(deformer: type) -> DeformerConfig:
    return dataclasses.make_dataclass(
        f"{deformer.__name__}Config",
        [("_target", type, dataclasses.field(default=deformer))],
        bases=(DeformerConfig,),
    )()


@pytest.mark.parametrize(
    "deformer, message",
    [
        (DropsAVertex, r"returned shape \(1, \d+, 3\), expected \(1, \d+, 3\)"),
        (TwoDimensional, r"returned shape \(\d+, 3\), expected \(1, \d+, 3\)"),
        (NaNs, r"returned 3 non-finite values"),
        (MovesRest, r"modified the rest mesh in place"),
        (ReturnsList, r"returned list, not an array of float64 positions"),
    ],
)
def test_a_deformer_breaking_the_output_contract_is_one_error_naming_it(capsule, tmp_path, deformer, message):
    (tmp_path / "edit.json").write_text(json.dumps({}))
    mesh = capsule.with_vertices(capsule.vertices.copy())  # MovesRest writes into it
    with pytest.raises(NerfEditError, match=rf"^deformer {__name__}\.{deformer.__name__}: .*{message}"):
        run_edit(mesh, config_of(deformer), tmp_path / "edit.json", tmp_path / "out", cache_dir=tmp_path / "cache")
    assert not (tmp_path / "out").exists() and not (tmp_path / "cache").exists()  # failed before the proxy stage


def test_float32_positions_are_widened(capsule, capsule_proxy, tmp_path):
    from nerfedit_plugin.edit.proxy import ProxyConfig, proxy_cache_key
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    (tmp_path / "edit.json").write_text(json.dumps({}))
    (tmp_path / "cache").mkdir()
    capsule_proxy.save(tmp_path / "cache" / f"{proxy_cache_key(capsule, ProxyConfig())}.npz")  # no build
    run = run_edit(capsule, config_of(Float32), tmp_path / "edit.json", tmp_path / "out", lift="knn3",
                   cache_dir=tmp_path / "cache")  # fmt: skip
    assert run.report["frames"] == 1 and run.report["proxy"]["cached"]
    expected = (capsule.vertices + [0.0, 0.0, 0.01]).astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(SurfaceMesh.load(run.out / "deformed_mesh.ply").vertices, expected)
