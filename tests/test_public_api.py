"""The public API (``nerfedit_plugin``'s lazy names) and the declared contracts."""

import subprocess
import sys

import numpy as np
import pytest

import nerfedit_plugin
from nerfedit_plugin import Deformer, DeformerConfig, Field


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


def test_every_deformation_the_renderer_takes_declares_the_backward_map(capsule):
    """DeformationField and SceneDeformation (and the paper's per-sample baseline in bench/) are BackwardMaps, the
    renderer's contract; an object missing a member is not."""
    from nerfedit_plugin.bending.deformation_field import DeformationField
    from nerfedit_plugin.bending.maps import BackwardMap
    from nerfedit_plugin.bending.scene_deformation import SceneDeformation

    tet = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    field = DeformationField.identity(tet, np.array([[0, 1, 2, 3]]))
    assert isinstance(field, BackwardMap) and isinstance(SceneDeformation.from_field(field), BackwardMap)

    class NoBounds:
        n_frames = 1

        def bend(self, x, frame=0, *, out=None, tets=True): ...
        def jacobian(self, tet, frame=0): ...
        def to_canonical(self, x, frame=0): ...

    assert not isinstance(NoBounds(), BackwardMap)


def test_fields_declare_how_they_render_and_what_runs_are_made_from():
    from nerfedit_plugin.fields.mesh_field import MeshField
    from nerfedit_plugin.fields.nerf import NerfField
    from nerfedit_plugin.fields.neus import NeusField

    assert Field.rendering == "rays" and Field.sources == {"dataset"} and not Field.exact_mesh
    assert (NerfField.sources, NeusField.sources, MeshField.sources) == ({"dataset"}, {"dataset"}, {"model"})
    assert MeshField.exact_mesh and all(f.rendering == "rays" for f in (NerfField, NeusField, MeshField))
    with pytest.raises(NotImplementedError, match="not made from a model file"):
        NerfField.from_file("x.ply")
    with pytest.raises(NotImplementedError, match="rendered by ray marching"):
        MeshField.render(MeshField.__new__(MeshField), None, 0, None)
