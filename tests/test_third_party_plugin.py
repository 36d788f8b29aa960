"""A third-party deformer installed as its own distribution is discovered; broken entry points are skipped."""

import sys
import textwrap
from pathlib import Path

import pytest

from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.registry import DEFORMERS, discover
from nerfedit_plugin.testing import check_deformer


@pytest.fixture
def on_path(monkeypatch):
    """Prepend a folder to sys.path for one test and forget the modules it provided afterwards."""
    before = set(sys.modules)

    def add(folder: Path) -> None:
        monkeypatch.syspath_prepend(str(folder))
        for name in [n for n in sys.modules if n.startswith(("nerfedit_twist", "nerfedit_wrong"))]:
            monkeypatch.delitem(sys.modules, name)  # e.g. the copy docs/examples/twist/tests imported from the docs

    yield add
    for name in set(sys.modules) - before:
        if name.startswith("nerfedit_twist") or name.startswith("nerfedit_wrong"):
            del sys.modules[name]


def test_installed_plugin_is_discovered_and_conforms(twist_site, on_path):
    assert "twist" not in discover().names(DEFORMERS)
    on_path(twist_site)
    registry = discover()
    assert "twist" in registry.names(DEFORMERS) and "cage" in registry.names(DEFORMERS)
    plugin = registry.plugins[DEFORMERS]["twist"]
    assert (plugin.distribution, plugin.target) == ("nerfedit-twist", "nerfedit_twist:TwistConfig")
    config = registry.config_class(DEFORMERS, "twist")()
    assert Path(sys.modules["nerfedit_twist"].__file__).parent == twist_site  # the installed copy, not the docs'
    check_deformer(
        config,
        edit={"twist": {"axis": [0, 0, 1], "degrees": 90}, "frames": 2},
        identity_edit={"twist": {"axis": [0, 0, 1], "degrees": 0}},
        skip=("rigid",),
    )


def _fake_distribution(folder: Path, name: str, entry_points: str, module: str | None = None) -> None:
    """A minimal installed distribution: ``<name>-0.1.dist-info`` with METADATA and entry_points.txt."""
    info = folder / f"{name.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[{DEFORMERS}]\n{entry_points}\n")
    if module is not None:
        (folder / f"{name.replace('-', '_')}.py").write_text(textwrap.dedent(module))


def test_broken_entry_points_are_skipped_with_a_reason(tmp_path, on_path):
    _fake_distribution(tmp_path, "nerfedit-wrong-import", "ghost = nerfedit_no_such_module:GhostConfig")
    _fake_distribution(
        tmp_path,
        "nerfedit-wrong-type",
        "number = nerfedit_wrong_type:NOT_A_CONFIG\nplain = nerfedit_wrong_type:PlainConfig",
        module="""
        import dataclasses
        NOT_A_CONFIG = 42

        @dataclasses.dataclass
        class PlainConfig:
            size: int = 1
        """,
    )
    on_path(tmp_path)
    registry = discover()
    reasons = {s.name: s.reason for s in registry.skipped}
    assert "import failed" in reasons["ghost"] and "nerfedit_no_such_module" in reasons["ghost"]
    assert reasons["number"] == "expected a config dataclass, got 42"
    assert "does not subclass nerfedit_plugin.edit.deformer.DeformerConfig" in reasons["plain"]
    assert not {"ghost", "number", "plain"} & set(registry.names(DEFORMERS))
    assert "cage" in registry.names(DEFORMERS)  # the good ones are unaffected
    with pytest.raises(NerfEditError, match=r"plugin 'ghost' .* is installed but broken: import failed"):
        registry.config_class(DEFORMERS, "ghost")
