"""Bad option values and combinations are user errors: exit 2 and one line on stderr naming the option (its flag, or
its key in a ``--load-config`` file), never a traceback; the configs reject them when built, before any work."""

import os
import subprocess
import sys

import pytest
import yaml

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.edit.lift import LiftConfig
from nerfedit_plugin.errors import NerfEditError, OptionError
from nerfedit_plugin.fields.mesh_field import MeshFieldConfig
from nerfedit_plugin.fields.nerf import NerfConfig
from nerfedit_plugin.fields.neus import NeusConfig

TRAIN = ["train", "--data", "nowhere", "--out", "never"]
EDIT = ["edit", "--mesh", "sample:bone", "--edit", "nowhere.json", "--out", "never"]

CASES = [
    # the issue's case: the default occupancy grid (64) and one upsample step need a multiple of 128
    (TRAIN + ["--field", "nerf", "--field-options.resolution", "32"], "--field-options.resolution: must be a multiple"),
    (TRAIN + ["--field", "neus", "--field-options.resolution", "0"], "--field-options.resolution: must be a positive"),
    (TRAIN + ["--field-options.occupancy-resolution", "300"], "--field-options.occupancy-resolution: must be in"),
    (TRAIN + ["--field-options.features", "2"], "--field-options.features: must be at least 3"),
    (TRAIN + ["--field-options.features", "4"], "--field-options.features: must be exactly 3 with decoder rgb"),
    (
        TRAIN + ["--field-options.decoder", "mlp", "--field-options.features", "4", "--field-options.sh-degree", "5"],
        "--field-options.sh-degree: must be 0, 1 or 2",
    ),
    (TRAIN + ["--field-options.upsample-steps", "0"], "--field-options.upsample-steps: must be positive"),
    (TRAIN + ["--field-options.lr-grid", "nan"], "--field-options.lr-grid: must be a positive number"),
    (TRAIN + ["--field-options.train.batch-rays", "0"], "--field-options.train.batch-rays: must be a positive"),
    (TRAIN + ["--field-options.train.max-seconds", "-1"], "--field-options.train.max-seconds: must be a positive"),
    (TRAIN + ["--field-options.density-init", "0"], "--field-options.density-init: must be a positive number"),
    (TRAIN + ["--field", "neus", "--field-options.init-radius", "2"], "--field-options.init-radius: must be at most 1"),
    (
        TRAIN + ["--field", "neus", "--field-options.eikonal-points", "0"],
        "--field-options.eikonal-points: must be a positive integer",
    ),
    (TRAIN + ["--field", "mesh", "--field-options.density", "0"], "--field-options.density: must be a positive"),
    (TRAIN + ["--field", "mesh", "--field-options.padding", "-1"], "--field-options.padding: must be a number >= 0"),
    (EDIT + ["--lift-options.max-iterations", "0"], "--lift-options.max-iterations: must be a positive integer"),
    (EDIT + ["--lift-options.constraint-weight", "-5"], "--lift-options.constraint-weight: must be a positive"),
    (EDIT + ["--proxy.cage-faces", "2"], "--proxy.cage-faces: must be >= 8, got 2"),
    (EDIT + ["--proxy.min-margin", "nan"], "--proxy.min-margin: must be in [0, 1)"),
    (EDIT + ["--deformer-options.tolerance", "nan"], "--deformer-options.tolerance: must be a number >= 0"),
    (EDIT + ["--deformer", "cage", "--deformer-options.auto-alpha", "-1"], "--deformer-options.auto-alpha: must be >"),
    (EDIT + ["--deformer", "skeleton", "--deformer-options.heat-bones", "0"], "--deformer-options.heat-bones: must be"),
    (
        EDIT + ["--deformer", "skeleton", "--deformer-options.weight-threshold", "1"],
        "--deformer-options.weight-threshold: must be in [0, 1)",
    ),
    (["render", "--run", "r", "--cameras", "c", "--out", "o", "--supersample", "0"], "--supersample: must be"),
    (["render", "--run", "r", "--cameras", "c", "--out", "o", "--frame", "-1"], "--frame: must be >= 0"),
    (["extract", "--run", "r", "--resolution", "1"], "--resolution: must be an integer >= 2"),
    (["extract", "--run", "r", "--level", "inf"], "--level: must be a finite number"),
    (["view", "--mesh", "sample:bone", "--width", "0", "--screenshot", "x.png"], "--width: must be a positive"),
    (["view", "--mesh", "sample:bone", "--up", "0", "0", "0", "--screenshot", "x.png"], "--up: must be a non-zero"),
    (["view", "--mesh", "sample:bone", "--frame", "-2"], "--frame: must be >= 0"),
    (["eval", "--pred", "p", "--gt", "g", "--background", "2", "0", "0"], "--background: must be 3 numbers in [0, 1]"),
]


IDS = [" ".join(argv[5:] if argv[0] == "train" else argv) for argv, _ in CASES]


@pytest.mark.parametrize("argv, message", CASES, ids=IDS)
def test_bad_options_are_one_line_user_errors(argv, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # rejected before any work


def test_the_issue_command_exits_2_with_one_line(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "nerfedit_plugin.cli.app", "train", "--field", "nerf"]
        + ["--field-options.resolution", "32", "--data", "d", "--out", "o"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --field-options.resolution: must be a multiple of 128")


def test_load_config_names_the_key_of_the_file(tmp_path, capsys):
    config = {"data": str(tmp_path / "d"), "out": str(tmp_path / "o"), "field": "nerf"}
    config["field_options"] = {"resolution": 32}
    (tmp_path / "config.yml").write_text(yaml.safe_dump({"command": config}))
    assert main(["train", "--load-config", str(tmp_path / "config.yml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "config.yml: field_options.resolution: must be a multiple of 128" in err


@pytest.mark.parametrize("kind", [ValueError, TypeError])
def test_any_error_of_a_config_constructor_names_the_option_group(kind, tmp_path, monkeypatch, capsys):
    """The safety net: a config (e.g. a third-party plugin's) that raises ValueError or TypeError when built."""

    def reject(self):
        if self.padding == 7:
            raise kind("seven is unlucky")

    monkeypatch.setattr(MeshFieldConfig, "__post_init__", reject)
    monkeypatch.chdir(tmp_path)
    assert main(TRAIN + ["--field", "mesh", "--field-options.padding", "7"]) == 2
    err = capsys.readouterr().err
    assert err == "error: --field-options: seven is unlucky\n"


def test_the_lift_options_group_is_named_too(tmp_path, monkeypatch, capsys):
    def reject(self):
        raise ValueError("no")

    monkeypatch.setattr(LiftConfig, "__post_init__", lambda self: None if self.tolerance != 1 else reject(self))
    monkeypatch.chdir(tmp_path)
    assert main(EDIT + ["--lift-options.tolerance", "1"]) == 2
    assert capsys.readouterr().err == "error: --lift-options: no\n"


def test_configs_validate_when_built_in_python():
    with pytest.raises(OptionError, match=r"NerfConfig.resolution: must be a multiple of 128") as caught:
        NerfConfig(resolution=32)
    assert isinstance(caught.value, NerfEditError) and caught.value.option == "resolution"
    with pytest.raises(NerfEditError, match=r"NeusConfig.train.n_samples: must be a positive integer"):
        NeusConfig.tiny(train=NeusConfig().train.__class__(n_samples=0))
    # what the presets and the tests build stays valid
    NerfConfig.tiny(), NeusConfig.tiny(), NerfConfig(), NeusConfig(), MeshFieldConfig(), LiftConfig()
    NeusConfig(resolution=8, upsample_steps=(), occupancy_resolution=0)
    NerfConfig(resolution=32, upsample_steps=(), occupancy_resolution=0)


@pytest.mark.parametrize(
    "section, key, value, message",
    [
        (None, "lift", "nosuch", "lift: expected one of 'tet-arap',"),
        ("deformer_options", "max_iterations", "abc", "deformer_options.max_iterations: expected an integer"),
        ("deformer_options", "energy", "wrong", "deformer_options.energy: expected one of 'spokes_and_rims',"),
        (
            "deformer_options",
            "enrgy",
            "spokes",
            "deformer_options.enrgy: unknown key (the options are: coarse_above, coarse_vertices,",
        ),
        ("lift_options", "constraint_weight", "heavy", "lift_options.constraint_weight: expected a number"),
        ("lift_options", "injective", 1, "lift_options.injective: expected true or false, got 1"),
        ("proxy", "cage_faces", [1], "proxy.cage_faces: expected an integer, got [1]"),
    ],
)
def test_a_load_config_value_of_the_wrong_kind_or_a_stray_key_is_named(tmp_path, capsys, section, key, value, message):
    """A config.yml edited by hand: a typo'd key in any section, text for a number, a choice that does not exist are
    one line naming the key (before, a typo was ignored and a wrong type surfaced as a Python internal)."""
    config = {"mesh": "sample:bone", "edit": str(tmp_path / "e.json"), "out": str(tmp_path / "o"), "deformer": "arap"}
    if section is None:
        config[key] = value
    else:
        config[section] = {key: value}
    (tmp_path / "config.yml").write_text(yaml.safe_dump({"command": config}))
    assert main(["edit", "--load-config", str(tmp_path / "config.yml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"config.yml: {message}" in err, err
    assert not (tmp_path / "o").exists()


def test_from_plain_takes_what_to_plain_and_python_callers_give():
    """YAML 1.1 reads ``1e-6`` (no dot) as text: a float option takes it. A field that is no constructor argument
    (``init=False``, written by to_plain) loads; a union of configs tries each; numpy scalars and PathLikes pass."""
    import dataclasses
    from pathlib import Path

    import numpy as np

    from deformers.arap import ArapConfig
    from nerfedit_plugin.config import from_plain, to_plain

    assert from_plain(ArapConfig, {"tolerance": "1e-6"}).tolerance == 1e-6

    @dataclasses.dataclass
    class A:
        a: int = 1

    @dataclasses.dataclass
    class B:
        b: int = 2

    @dataclasses.dataclass
    class Plugin:
        radius: float = 1.0
        count: int = 3
        where: Path = Path("x")
        sub: A | B = dataclasses.field(default_factory=A)
        derived: float = dataclasses.field(init=False, default=0.0)

    assert from_plain(Plugin, to_plain(Plugin())) == Plugin()
    assert from_plain(Plugin, {"sub": {"b": 5}}).sub == B(5)
    loaded = from_plain(Plugin, {"radius": np.float32(0.5), "count": np.int64(4), "where": Path("y")})
    assert (loaded.radius, loaded.count, loaded.where) == (0.5, 4, Path("y"))
    with pytest.raises(OptionError, match="count: expected an integer, got True"):
        from_plain(Plugin, {"count": True})
    with pytest.raises(OptionError, match="sub: unknown key"):
        from_plain(Plugin, {"sub": {"c": 1}})
