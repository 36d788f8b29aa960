"""The ``arap`` deformer plugin passes the conformance kit, one case per property (the ARAP solver behind it:
tests/geometry/test_arap.py)."""

from deformers.arap import ArapConfig
from nerfedit_plugin.testing import parametrize_with_checks


@parametrize_with_checks(ArapConfig())
def test_conformance_kit(check):
    check()
