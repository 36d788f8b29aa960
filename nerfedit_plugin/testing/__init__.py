"""Conformance kits for plugins, after scikit-learn's ``check_estimator``: one for deformers, one for fields.

Recommended form, one pytest case per property (ids such as ``ArapConfig-identity``)::

    from nerfedit_plugin.testing import parametrize_with_checks

    @parametrize_with_checks([ArapConfig(), NerfConfig()])
    def test_conformance(check):
        check()

Both kits have the same shape: ``CHECKS`` (name → check function; here :data:`DEFORMER_CHECKS` and
:data:`FIELD_CHECKS`, ``CHECKS`` being the deformer kit's), ``deformer_checks`` / ``field_checks`` (the
``(name, check)`` pairs bound to a plugin's arguments) and ``check_deformer`` / ``check_field`` (run them all).
"""

from nerfedit_plugin.testing._parametrize import config_id, parametrize_with_checks  # noqa: F401
from nerfedit_plugin.testing.deformers import (  # noqa: F401
    CHECKS,
    check_config,
    check_deform_points,
    check_deformer,
    check_deterministic,
    check_documented_round_trip,
    check_identity,
    check_malformed,
    check_output,
    check_rigid,
    check_vertex_order,
    default_edit,
    default_mesh,
    deformer_checks,
    identity_handles,
    malformed_edits,
    rigid_fit,
    rigid_handles,
    run_deformer,
)
from nerfedit_plugin.testing.deformers import CHECKS as DEFORMER_CHECKS  # noqa: F401
from nerfedit_plugin.testing.fields import CHECKS as FIELD_CHECKS  # noqa: F401
from nerfedit_plugin.testing.fields import build_field, check_field, field_checks  # noqa: F401
