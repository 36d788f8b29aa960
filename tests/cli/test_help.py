"""The parse of every subcommand: plugin lists in --help, literal plugin flags, --verbose read from the parsed args."""

import json

import pytest

from nerfedit_plugin.cli.app import COMMANDS, command, main
from nerfedit_plugin.cli.common import describe, parse
from nerfedit_plugin.errors import NerfEditError
from nerfedit_plugin.registry import DEFORMERS, FIELDS, discover


def _help(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--help"])
    assert exit_.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, group, chosen, option",
    [
        (["edit"], DEFORMERS, "arap", "--deformer-options.max-iterations"),
        (["edit", "--deformer", "cage"], DEFORMERS, "cage", "--deformer-options.coordinates"),
        (["train"], FIELDS, "nerf", "--field-options.density-init"),
        (["train", "--field", "mesh"], FIELDS, "mesh", "--field-options.padding"),
    ],
)
def test_help_lists_every_plugin_with_its_description(capsys, argv, group, chosen, option):
    out = " ".join(_help(capsys, *argv).split())  # unwrap the help's line breaks
    plugins = discover(group).plugins[group]
    assert len(plugins) >= 3
    for name, plugin in plugins.items():
        marker = "*" if name == chosen else ""
        assert f"{marker} {name} {describe(plugin.config_class)}".strip() in out, name
    assert option in out and "--load-config" in out and "--verbose" in out


def test_builtin_plugins_have_a_one_line_description():
    registry = discover()
    for group in (DEFORMERS, FIELDS):
        for plugin in registry.plugins[group].values():
            line = describe(plugin.config_class)
            assert 10 < len(line) <= 110 and line.endswith("."), (plugin.name, line)
            assert plugin.config_class.__doc__.strip().startswith(line)


def test_literal_plugin_flags_still_parse():
    args = parse(
        command("edit"),
        [
            "--deformer",
            "arap",
            "--field",
            "neus",
            "--run",
            "runs/r",
            "--edit",
            "e.json",
            "--out",
            "o",
            "--deformer-options.max-iterations",
            "7",
        ],
    )
    assert (args.deformer, args.field, type(args.deformer_options).__name__) == ("arap", "neus", "ArapConfig")
    assert args.deformer_options.max_iterations == 7 and args.verbose is False and args.load_config is None
    args = parse(command("train"), ["--field=mesh", "--data", "m.ply", "--out", "r"])
    assert args.field == "mesh" and type(args.field_options).__name__ == "MeshFieldConfig"


def test_only_folder_writers_take_load_config():
    for name in COMMANDS:
        records = command(name).records
        assert records == (name in ("train", "edit", "render", "export", "generate", "demo")), name
        assert hasattr(parse(command(name), _required(name)), "load_config") == records


def _required(name: str) -> list[str]:
    return {
        "train": ["--data", "d", "--out", "o"],
        "extract": ["--run", "r"],
        "edit": ["--edit", "e", "--out", "o"],
        "render": ["--run", "r", "--cameras", "c", "--out", "o"],
        "export": ["--run", "r", "--out", "o"],
        "eval": ["--pred", "p", "--gt", "g"],
        "generate": ["--out", "o"],
        "process": ["--video", "v.mp4", "--out", "o"],
    }.get(name, [])


def test_verbose_is_read_from_the_parsed_args(tmp_path, capsys):
    (tmp_path / "edit.json").write_text(json.dumps({"handles": []}))
    argv = [
        "edit",
        "--mesh",
        str(tmp_path / "none.ply"),
        "--edit",
        str(tmp_path / "edit.json"),
        "--out",
        str(tmp_path / "o"),
    ]
    assert main(argv) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
    with pytest.raises(NerfEditError, match="mesh file not found"):
        main([*argv, "--verbose"])
    assert main([*argv, "--verbose", "--no-verbose"]) == 2  # the last flag wins, as tyro parses it


def test_unknown_command_is_one_line(capsys):
    assert main(["nope"]) == 2
    err = capsys.readouterr().err
    assert "unknown command 'nope'" in err and "edit" in err
    assert main(["--help"]) == 0 and "usage: nerfedit" in capsys.readouterr().out
