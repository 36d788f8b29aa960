"""``nerfedit generate``: render a mesh into a Blender-format dataset (the synthetic scene generator)."""

from __future__ import annotations

from nerfedit_plugin.cli.common import Command, console, recorded
from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset


def generate(args: GenerateConfig) -> None:
    """The dataset's ``config.yml`` records ``args`` (the generator's config and the shared flags)."""
    console.print(f"dataset → {generate_dataset(recorded(args))}")


COMMAND = Command("generate", GenerateConfig, generate, records=True)
