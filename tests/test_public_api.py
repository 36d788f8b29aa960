"""The public API (``nerfedit_plugin``'s lazy names), the declared contracts, and the 0.1.0 module aliases."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

import nerfedit_plugin
from nerfedit_plugin import Deformer, DeformerConfig, Field, SurfaceMesh


def test_import_is_cheap():
    """``import nerfedit_plugin`` loads none of the heavy libraries; the first use of a name does."""
    code = (
        "import sys, nerfedit_plugin; heavy = {'torch', 'open3d', 'numba', 'pytetwild', 'pymeshlab', 'scipy'};"
        "print(sorted(heavy & set(sys.modules)))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out


@pytest.mark.parametrize("name", nerfedit_plugin.__all__)
def test_every_public_name_resolves(name):
    assert getattr(nerfedit_plugin, name) is not None
    assert name in dir(nerfedit_plugin)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        nerfedit_plugin.nope  # noqa: B018


def test_required_methods_are_abstract():
    class Half(Deformer):
        def bind(self, rest, edit):
            pass

    with pytest.raises(TypeError, match="deform"):
        Half(DeformerConfig())
    assert Deformer.__abstractmethods__ == {"bind", "deform"}
    assert Field.__abstractmethods__ == {"query", "extract_mesh"}


def test_optional_hooks_have_declared_defaults(capsule):
    class Minimal(Deformer):
        def bind(self, rest, edit):
            self.rest = rest

        def deform(self):
            return self.rest.vertices[None].copy()

    deformer = Minimal(DeformerConfig())
    assert not Minimal.supports_points()
    with pytest.raises(NotImplementedError):
        deformer.deform_points(np.zeros((1, 3)), 0)
    assert deformer.write_artifacts(".") == []
    assert Minimal.overlays(".", 0) == []
    assert Minimal.handle_points(".", capsule) is capsule.vertices
    assert Minimal.identity_edit({}, capsule) is None and Minimal.rigid_edit({}, capsule) is None


@pytest.mark.parametrize(
    "old, new",
    [
        ("nerfedit_plugin.deformation_field", "nerfedit_plugin.bending.deformation_field"),
        ("nerfedit_plugin.editspec", "nerfedit_plugin.edit.spec"),
        ("nerfedit_plugin.testing_fields", "nerfedit_plugin.testing.fields"),
        ("deformers.skinning", "deformers.skeleton.skinning"),
        ("deformers.mean_value", "deformers.cage.mean_value"),
    ],
)
def test_old_module_paths_alias_with_a_warning(old, new):
    sys.modules.pop(old, None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = __import__(old, fromlist=["_"])
    assert module is sys.modules[new]
    assert any(issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in caught)


def test_renamed_functions_alias_with_a_warning():
    """``data.synthetic.render_views`` (a mesh into PNGs) was renamed so that it no longer shares the package's
    ``render_views`` (a field into images)."""
    from nerfedit_plugin.data import synthetic

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        old = synthetic.render_views
    assert old is synthetic.render_mesh_views
    assert any(issubclass(w.category, DeprecationWarning) and "render_mesh_views" in str(w.message) for w in caught)
    with pytest.raises(AttributeError):
        synthetic.no_such_name  # noqa: B018


def test_old_packages_reexport_what_they_held():
    from nerfedit_plugin.cli import main
    from nerfedit_plugin.edit import run_edit
    from nerfedit_plugin.testing import check_deformer

    assert main.__module__ == "nerfedit_plugin.cli.app"
    assert run_edit.__module__ == "nerfedit_plugin.edit.job"
    assert check_deformer.__module__ == "nerfedit_plugin.testing.deformers"
    assert isinstance(SurfaceMesh, type)
