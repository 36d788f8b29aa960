"""Every built-in field backend passes the field conformance kit a third-party backend would run, and the kit
catches a broken field."""

import pytest

from nerfedit_plugin.fields.mesh_field import MeshField, MeshFieldConfig
from nerfedit_plugin.registry import FIELDS, discover
from nerfedit_plugin.testing import parametrize_with_checks
from nerfedit_plugin.testing.fields import build_field, check_field, check_query

BUILT_IN = ("mesh", "nerf", "neus")
REGISTRY = discover()


def test_built_in_fields_are_registered():
    for name in BUILT_IN:
        assert name in REGISTRY.names(FIELDS), f"{name} is not registered: {REGISTRY.skipped}"


@parametrize_with_checks([REGISTRY.config_class(FIELDS, name)() for name in BUILT_IN if name in REGISTRY.names(FIELDS)])
def test_built_in_field_conforms(check):
    check()


class Oversaturated(MeshField):
    def query(self, points, directions):
        density, rgb = super().query(points, directions)
        return density, rgb * 2.0


def test_kit_catches_colours_out_of_range():
    field = build_field(MeshFieldConfig())
    broken = Oversaturated(field.config, field.scene_bbox)
    broken.load_state_dict(field.state_dict())
    with pytest.raises(AssertionError, match="colours outside"):
        check_query(broken)


def test_unknown_check_is_a_usage_error():
    with pytest.raises(ValueError, match="unknown checks"):
        check_field(MeshFieldConfig(), skip=("speed",))
