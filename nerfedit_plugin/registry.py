"""Plugin discovery through ``importlib.metadata`` entry points.

Each entry point names a config class (a dataclass subclass of the group's base config whose ``_target`` is a
concrete subclass of the group's base class). A plugin that fails to import or has the wrong shape is recorded in
``Registry.skipped`` with the reason and never stops discovery. nerfedit's own plugins register first: a third
party reusing a built-in name is the one skipped, whatever the install order. Entry points in a ``nerfedit.*``
group nerfedit does not read (``nerfedit.deformer``) are recorded as skipped too. The registry names the contract
classes by their import path, as entry points name plugins, so it depends on no stage (the contracts may use it).
"""

from __future__ import annotations

import dataclasses
import difflib
import importlib
import inspect
from dataclasses import dataclass, field
from importlib import metadata

from nerfedit_plugin.errors import NerfEditError

BUILTIN = "nerfedit"
"""The distribution of the built-in plugins."""
DEFORMERS = "nerfedit.deformers"
FIELDS = "nerfedit.fields"

#: group -> (base config class, base target class), as ``module:attr`` import paths
GROUPS: dict[str, tuple[str, str]] = {
    DEFORMERS: ("nerfedit_plugin.edit.deformer:DeformerConfig", "nerfedit_plugin.edit.deformer:Deformer"),
    FIELDS: ("nerfedit_plugin.fields.base:FieldConfig", "nerfedit_plugin.fields.base:Field"),
}


def _resolve(path: str | type) -> type:
    if isinstance(path, type):
        return path
    module, attr = path.split(":")
    return getattr(importlib.import_module(module), attr)


@dataclass(frozen=True)
class Plugin:
    group: str
    name: str
    target: str  # "module:attr" as written in the entry point
    distribution: str
    config_class: type


@dataclass(frozen=True)
class Skipped:
    group: str
    name: str
    target: str
    distribution: str
    reason: str


@dataclass
class Registry:
    plugins: dict[str, dict[str, Plugin]] = field(default_factory=dict)
    skipped: list[Skipped] = field(default_factory=list)

    def names(self, group: str) -> list[str]:
        return sorted(self.plugins.get(group, {}))

    def config_class(self, group: str, name: str) -> type:
        """The config class registered as ``name``; unknown names raise a NerfEditError listing the choices."""
        found = self.plugins.get(group, {})
        if name in found:
            return found[name].config_class
        why = next((s.reason for s in self.skipped if s.group == group and s.name == name), None)
        if why:
            raise NerfEditError(f"plugin {name!r} ({group}) is installed but broken: {why}")
        misspelt = [s for s in self.skipped if s.group not in self.plugins and s.name == name]
        stray = next((s for s in misspelt if difflib.get_close_matches(group, [s.group], cutoff=0.8)), None)
        if stray:
            raise NerfEditError(f"plugin {name!r} of {stray.distribution} is skipped: {stray.reason}")
        raise NerfEditError(
            f"unknown {group.split('.')[-1][:-1]} {name!r} (available: {', '.join(sorted(found)) or 'none'})"
        )


def _check_shape(obj: object, base_config: type, base_target: type) -> str | None:
    """None if ``obj`` is a valid config class for the group, else the reason it is not."""
    if not isinstance(obj, type) or not dataclasses.is_dataclass(obj):
        return f"expected a config dataclass, got {obj!r}"
    if not issubclass(obj, base_config):
        return f"{obj.__name__} does not subclass {base_config.__module__}.{base_config.__name__}"
    if "__dataclass_fields__" not in vars(obj):  # inherits the base's fields: its own _target is never set
        return f"{obj.__name__} is not decorated with @dataclass (it has only {base_config.__name__}'s fields)"
    try:
        target = obj()._target
    except Exception as exc:  # a config that cannot be default-constructed is unusable from the CLI
        return f"{obj.__name__}() failed: {exc!r}"
    if not isinstance(target, type) or not issubclass(target, base_target):
        return f"{obj.__name__}._target is {target!r}, not a subclass of {base_target.__name__}"
    if inspect.isabstract(target):
        return f"{target.__name__} does not implement {', '.join(sorted(target.__abstractmethods__))}"
    return None


def _builtin_first(ep: metadata.EntryPoint) -> bool:
    return ep.dist is None or ep.dist.name != BUILTIN


def discover(*groups: str, bases: dict[str, tuple[type | str, type | str]] | None = None) -> Registry:
    """Load every entry point of ``groups`` (default: all of :data:`GROUPS`); record the broken ones instead of
    raising. ``bases`` overrides the contract classes of a group (tests of the registry itself)."""
    bases = bases or GROUPS
    registry = Registry()
    for group in groups or tuple(bases):
        base_config, base_target = (_resolve(b) for b in bases[group])
        found, builtin = registry.plugins.setdefault(group, {}), set()
        for ep in sorted(metadata.entry_points(group=group), key=_builtin_first):  # stable: install order otherwise
            dist = ep.dist.name if ep.dist is not None else "?"
            if dist == BUILTIN:
                builtin.add(ep.name)
            elif ep.name in builtin and ep.name not in found:  # a broken built-in keeps its name
                registry.skipped.append(Skipped(group, ep.name, ep.value, dist, f"name of a {BUILTIN} built-in"))
                continue
            try:
                obj = ep.load()
            except Exception as exc:  # any import-time failure of a third-party plugin must not be fatal
                registry.skipped.append(Skipped(group, ep.name, ep.value, dist, f"import failed: {exc!r}"))
                continue
            reason = _check_shape(obj, base_config, base_target)
            if reason is None and ep.name in found:
                reason = f"name already registered by {found[ep.name].distribution} ({found[ep.name].target})"
            if reason:
                registry.skipped.append(Skipped(group, ep.name, ep.value, dist, reason))
            else:
                found[ep.name] = Plugin(group, ep.name, ep.value, dist, obj)
    read, known = ", ".join(GROUPS), {*GROUPS, *bases}
    for group in sorted(g for g in metadata.entry_points().groups if g.startswith("nerfedit.") and g not in known):
        for ep in metadata.entry_points(group=group):
            dist = ep.dist.name if ep.dist is not None else "?"
            reason = f"entry-point group {group!r} is not one nerfedit reads ({read})"
            registry.skipped.append(Skipped(group, ep.name, ep.value, dist, reason))
    return registry
