"""The twist plugin's own tests: nerfedit's conformance kit plus the twist's defining property."""

import numpy as np
from nerfedit_twist import TwistConfig

from nerfedit_plugin.edit.spec import parse_edit_spec
from nerfedit_plugin.testing import default_mesh, parametrize_with_checks

EDIT = {"twist": {"axis": [0, 0, 1], "degrees": 90}, "frames": 2}


# One case per property of nerfedit's conformance kit (TwistConfig-output, TwistConfig-identity, ...). A twist is
# never a rigid motion, so there is no rigid variant of the edit to check.
@parametrize_with_checks(
    TwistConfig(), edit=EDIT, identity_edit={"twist": {"axis": [0, 0, 1], "degrees": 0}}, skip=("rigid",)
)
def test_conformance_kit(check):
    check()


def test_top_turns_by_degrees_bottom_stays():
    rest = default_mesh()
    deformer = TwistConfig().setup()
    deformer.bind(rest, parse_edit_spec(EDIT, deformer.spec_keys))
    out = deformer.deform()[-1]
    z = rest.vertices[:, 2]
    bottom, _top = z == z.min(), z == z.max()
    assert np.allclose(out[bottom], rest.vertices[bottom])
    probe = np.array([[1.0, 0.0, z.max()]])  # a point level with the top turns a quarter about z
    assert np.allclose(deformer.deform_points(probe, 1), [[0.0, 1.0, z.max()]])
    assert np.allclose(np.linalg.norm(out[:, :2], axis=1), np.linalg.norm(rest.vertices[:, :2], axis=1))
