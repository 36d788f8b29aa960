"""``nerfedit generate``: render a mesh, or a scene of several (``--objects``), into a Blender-format dataset (the
synthetic scene generator)."""

from __future__ import annotations

from nerfedit_plugin.cli.common import Command, console, recorded
from nerfedit_plugin.data.scene import generate_scene
from nerfedit_plugin.data.synthetic import GenerateConfig, generate_dataset


def generate(args: GenerateConfig) -> None:
    """The dataset's ``config.yml`` records ``args`` (the generator's config and the shared flags)."""
    args = recorded(args)
    console.print(f"dataset → {(generate_scene if args.objects else generate_dataset)(args)}")


COMMAND = Command("generate", GenerateConfig, generate, records=True)
