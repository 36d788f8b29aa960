"""``parametrize_with_checks``: the conformance kits as one pytest case per property (after scikit-learn's)."""

from __future__ import annotations

import dataclasses
from typing import Any

from nerfedit_plugin.edit.deformer import DeformerConfig
from nerfedit_plugin.fields.base import FieldConfig
from nerfedit_plugin.testing.deformers import deformer_checks
from nerfedit_plugin.testing.fields import field_checks


def config_id(config: Any) -> str:
    """The test-id prefix of ``config``: its class name, followed by the public fields that differ from their
    defaults, e.g. ``ArapConfig`` or ``CageConfig(coordinates='green')``."""
    changed = []
    for field in dataclasses.fields(config):
        if field.name.startswith("_") or not field.init:
            continue
        if field.default is not dataclasses.MISSING:
            default = field.default
        elif field.default_factory is not dataclasses.MISSING:
            default = field.default_factory()
        else:
            default = dataclasses.MISSING
        value = getattr(config, field.name)
        if value != default:
            changed.append(f"{field.name}={value!r}")
    name = type(config).__name__
    return f"{name}({', '.join(changed)})" if changed else name


def parametrize_with_checks(configs: Any, **kwargs: Any):
    """A ``pytest.mark.parametrize`` decorator with one case per conformance property of each config.

    ``configs`` is a :class:`DeformerConfig` or :class:`FieldConfig` instance, or a list of them;
    ``kwargs`` are those of :func:`~nerfedit_plugin.testing.deformers.check_deformer` (``rest``, ``edit``,
    ``base_dir``, ``identity_edit``, ``rigid_edit``, ``bad_edits``, ``tol``, ``rigid_tol``, ``skip``) or of
    :func:`~nerfedit_plugin.testing.fields.check_field` (``skip``, ``model``), and apply to every config. The test
    receives ``check`` (the config is bound in; other parameters are fixtures as usual); ``check()`` runs one property
    and raises ``AssertionError`` naming it. Case ids are ``<config>-<check>``, e.g. ``ArapConfig-identity``; checks
    in ``skip`` get no case.

    The decorator's arguments are evaluated when pytest collects the module, before any fixture exists: give
    run-time values (``base_dir=tmp_path`` for the files an edit names) to the call instead,
    ``check(base_dir=tmp_path)`` — keywords given to ``check`` override the decorator's. Nothing is built or bound
    at collection; the field checks of one field config share one field, built by the first case that needs it.

    pytest is imported here, so ``import nerfedit_plugin.testing`` does not need it.
    """
    import pytest

    params, ids = [], []
    for config in configs if isinstance(configs, (list, tuple)) else [configs]:
        if isinstance(config, DeformerConfig):
            checks = deformer_checks(config, **kwargs)
        elif isinstance(config, FieldConfig):
            checks = field_checks(config, **kwargs)
        else:
            raise TypeError(
                f"parametrize_with_checks: expected a DeformerConfig or FieldConfig instance (or a list "
                f"of them), got {config!r}"
            )
        prefix = config_id(config)
        for name, check in checks:
            params.append(check)
            ids.append(f"{prefix}-{name}")
    return pytest.mark.parametrize("check", params, ids=ids)
