"""Conformance kits for plugins, after scikit-learn's ``check_estimator``: one for deformers, one for fields."""

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
    identity_handles,
    malformed_edits,
    rigid_fit,
    rigid_handles,
    run_deformer,
)
from nerfedit_plugin.testing.fields import check_field  # noqa: F401
