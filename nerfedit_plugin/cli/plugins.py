"""``nerfedit plugins``: the installed deformer and field plugins, and those skipped with the reason."""

from __future__ import annotations

import dataclasses

from nerfedit_plugin.cli.common import Command, describe, print_table
from nerfedit_plugin.registry import discover


@dataclasses.dataclass
class PluginsArgs:
    """List the plugins found through entry points (with their one-line descriptions), and those skipped with the
    reason."""


def plugins(args: PluginsArgs) -> None:
    registry = discover()
    print_table(
        "nerfedit plugins",
        ("group", "name", "description", "entry point", "distribution"),
        [
            (group, p.name, describe(p.config_class), p.target, p.distribution)
            for group, found in registry.plugins.items()
            for p in found.values()
        ],
        justify="left",
        overflow="fold",
    )
    if registry.skipped:
        print_table(
            "skipped",
            ("group", "name", "entry point", "reason"),
            [(s.group, s.name, s.target, s.reason) for s in registry.skipped],
            justify="left",
            style="yellow",
        )


COMMAND = Command("plugins", PluginsArgs, plugins)
