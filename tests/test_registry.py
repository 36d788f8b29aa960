"""Registry: built-ins are found through entry points; broken plugins are skipped with a reason, never fatal."""

import io
import sys
import textwrap

import pytest

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.registry import DEFORMERS, discover


def write_fake_plugins(tmp_path):
    """A distribution in ``tmp_path`` with a good, a broken-import and wrong-shape deformer entry points, one that
    reuses the built-in name ``arap`` and one in a group nerfedit does not read."""
    (tmp_path / "fake_plugin.py").write_text(
        textwrap.dedent(
            """
            import dataclasses
            from nerfedit_plugin.edit.deformer import Deformer, DeformerConfig

            class Shift(Deformer):
                spec_keys = frozenset()
                def bind(self, rest, edit): self.rest = rest.vertices
                def deform(self): return (self.rest + 1.0)[None]

            @dataclasses.dataclass
            class ShiftConfig(DeformerConfig):
                _target: type = dataclasses.field(default_factory=lambda: Shift)

            @dataclasses.dataclass
            class NotADeformerConfig(DeformerConfig):
                _target: type = dict

            class NoDeform(Deformer):  # deform() forgotten
                spec_keys = frozenset()
                def bind(self, rest, edit): pass

            @dataclasses.dataclass
            class NoDeformConfig(DeformerConfig):
                _target: type = dataclasses.field(default_factory=lambda: NoDeform)

            class UndecoratedConfig(DeformerConfig):  # @dataclass forgotten: DeformerConfig's _target stays
                _target = Shift

            not_a_class = 42
            """
        )
    )
    dist = tmp_path / "fake_plugin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[nerfedit.deformers]\n"
        "shift = fake_plugin:ShiftConfig\n"
        "broken = fake_plugin_missing_module:Config\n"
        "wrongtarget = fake_plugin:NotADeformerConfig\n"
        "notaclass = fake_plugin:not_a_class\n"
        "arap = fake_plugin:ShiftConfig\n"
        "nodeform = fake_plugin:NoDeformConfig\n"
        "undecorated = fake_plugin:UndecoratedConfig\n"
        "[nerfedit.deformer]\n"
        "twist = fake_plugin:ShiftConfig\n"
    )


@pytest.fixture
def fake_plugins(tmp_path, monkeypatch):
    """:func:`write_fake_plugins` installed before the built-ins on ``sys.path`` (seen first)."""
    write_fake_plugins(tmp_path)
    monkeypatch.setattr(sys, "path", [str(tmp_path), *sys.path])
    yield
    sys.modules.pop("fake_plugin", None)


def test_builtin_deformers_are_registered():
    registry = discover()
    assert {"arap", "mesh"} <= set(registry.names(DEFORMERS))
    assert registry.config_class(DEFORMERS, "mesh").__name__ == "MeshConfig"


def test_broken_plugins_are_skipped_with_reasons(fake_plugins):
    registry = discover()
    assert "shift" in registry.names(DEFORMERS)
    reasons = {s.name: s.reason for s in registry.skipped if s.distribution == "fake-plugin"}
    assert "import failed" in reasons["broken"] and "fake_plugin_missing_module" in reasons["broken"]
    assert "not a subclass of Deformer" in reasons["wrongtarget"]
    assert "expected a config dataclass" in reasons["notaclass"]
    assert "does not implement deform" in reasons["nodeform"]
    assert "UndecoratedConfig is not decorated with @dataclass" in reasons["undecorated"]
    with pytest.raises(NerfEditError, match="installed but broken: import failed"):
        registry.config_class(DEFORMERS, "broken")
    assert "'nerfedit.deformer' is not one nerfedit reads (nerfedit.deformers, " in reasons["twist"]
    with pytest.raises(NerfEditError, match="'twist' of fake-plugin is skipped: entry-point group 'nerfedit.deformer'"):
        registry.config_class(DEFORMERS, "twist")


def test_a_third_party_never_shadows_a_builtin_name(fake_plugins):
    """The fake distribution is seen first on ``sys.path``, yet ``arap`` stays the built-in and the duplicate is the
    one skipped."""
    from importlib import metadata

    arap = [ep.dist.name for ep in metadata.entry_points(group=DEFORMERS) if ep.name == "arap"]
    assert arap[0] == "fake-plugin"  # the order the registry is given
    registry = discover()
    assert registry.plugins[DEFORMERS]["arap"].distribution == "nerfedit"
    (skipped,) = [s for s in registry.skipped if s.name == "arap"]
    assert skipped.distribution == "fake-plugin" and "already registered by nerfedit" in skipped.reason


def test_a_broken_builtin_keeps_its_name(fake_plugins, tmp_path, monkeypatch):
    """A built-in that fails to import is skipped, and a third party's plugin of that name is skipped too, rather than
    standing in for it (here the distribution ``fake-builtin`` plays nerfedit)."""
    from nerfedit_plugin import registry as registry_module

    dist = tmp_path / "fake_builtin-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-builtin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[nerfedit.deformers]\nshift = fake_builtin_missing_module:Config\n")
    monkeypatch.setattr(registry_module, "BUILTIN", "fake-builtin")
    registry = discover()
    assert "shift" not in registry.names(DEFORMERS)
    reasons = {(s.distribution, s.name): s.reason for s in registry.skipped}
    assert "import failed" in reasons["fake-builtin", "shift"]
    assert reasons["fake-plugin", "shift"] == "name of a fake-builtin built-in"
    with pytest.raises(NerfEditError, match="'shift' .* is installed but broken: import failed"):
        registry.config_class(DEFORMERS, "shift")


def test_unknown_plugin_lists_choices():
    with pytest.raises(NerfEditError, match=r"unknown deformer 'nope' \(available: .*arap.*mesh"):
        discover().config_class(DEFORMERS, "nope")


def test_registered_plugin_works(fake_plugins):
    import numpy as np

    from nerfedit_plugin.edit.spec import parse_edit_spec
    from nerfedit_plugin.geometry.mesh import SurfaceMesh

    deformer = discover().config_class(DEFORMERS, "shift")().setup()
    rest = SurfaceMesh(np.eye(3), np.array([[0, 1, 2]]))
    deformer.bind(rest, parse_edit_spec({}, allowed_keys=()))
    assert np.allclose(deformer.deform()[0], np.eye(3) + 1)


def test_plugins_command_lists_each_builtin_with_its_description(monkeypatch):
    """``nerfedit plugins``: one row per built-in (group, name, the first line of its config class's docstring, entry
    point, distribution), every built-in and nothing skipped; piped, each row is one line whatever the width."""
    from rich.console import Console

    from deformers.arap import ArapConfig
    from deformers.cage import CageConfig
    from deformers.mesh import MeshConfig
    from deformers.skeleton import SkeletonConfig
    from deformers.transfer import TransferConfig
    from nerfedit_plugin.cli import common
    from nerfedit_plugin.cli.app import main
    from nerfedit_plugin.fields.mesh_field import MeshFieldConfig
    from nerfedit_plugin.fields.nerf import NerfConfig
    from nerfedit_plugin.fields.neus import NeusConfig
    from nerfedit_plugin.fields.splats.field import SplatsConfig

    piped = Console(file=io.StringIO(), width=40, force_terminal=False)  # not a terminal: rows are not folded to 40
    monkeypatch.setattr(common, "console", piped)
    assert main(["plugins"]) == 0
    out = piped.file.getvalue()
    assert piped._width == 40  # printing did not change the console
    rows = {
        tuple(cell.strip() for cell in line.strip().strip("│").split("│"))
        for line in out.splitlines()
        if line.startswith("│")
    }
    expected = {
        ("nerfedit.deformers", "arap", "deformers.arap:ArapConfig", ArapConfig),
        ("nerfedit.deformers", "cage", "deformers.cage:CageConfig", CageConfig),
        ("nerfedit.deformers", "mesh", "deformers.mesh:MeshConfig", MeshConfig),
        ("nerfedit.deformers", "skeleton", "deformers.skeleton:SkeletonConfig", SkeletonConfig),
        ("nerfedit.deformers", "transfer", "deformers.transfer:TransferConfig", TransferConfig),
        ("nerfedit.fields", "mesh", "nerfedit_plugin.fields.mesh_field:MeshFieldConfig", MeshFieldConfig),
        ("nerfedit.fields", "nerf", "nerfedit_plugin.fields.nerf:NerfConfig", NerfConfig),
        ("nerfedit.fields", "neus", "nerfedit_plugin.fields.neus:NeusConfig", NeusConfig),
        ("nerfedit.fields", "splats", "nerfedit_plugin.fields.splats.field:SplatsConfig", SplatsConfig),
    }
    descriptions = {}
    for group, name, target, config in expected:
        doc = config.__doc__.strip().splitlines()[0]
        assert len(doc) > 20 and not doc.startswith(config.__name__), (name, doc)  # a written docstring
        descriptions[group, name] = (group, name, doc, target, "nerfedit")
    assert rows == set(descriptions.values())
    assert "skipped" not in out
