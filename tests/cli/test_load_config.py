"""``config.yml`` and ``--load-config``: every command that writes a folder records its parsed args, and re-runs from
them (flags given override them) from any folder — also from the configs nerfedit 0.1.0 wrote before the stage
layout (``tests/cli/data/v0.1.0_*.yml``, written by commit f04b349 with the commands in their first lines)."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from nerfedit_plugin.cli.app import command, main
from nerfedit_plugin.cli.common import _import, parse
from nerfedit_plugin.data.synthetic import colorize
from nerfedit_plugin.geometry.mesh import SurfaceMesh
from nerfedit_plugin.pipeline.run import open_run

DATA = Path(__file__).parent / "data"
EDIT = {  # the edit.json of tests/cli/data/v0.1.0_edit_config.yml
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1.1], "max": [1, 1, -0.6]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.6], "max": [1, 1, 1.1]}}, "transform": {"translate": [0, 0.3, 0]}},
    ],
    "frames": 1,
}


@pytest.fixture
def workdir(tmp_path, capsule, proxy_cache, monkeypatch):
    """The current folder, holding what the 0.1.0 configs name: capsule.ply, capsule_colored.ply, edit.json."""
    root = tmp_path / "work"
    root.mkdir()
    capsule.save(root / "capsule.ply")
    colorize(capsule, 0).save(root / "capsule_colored.ply")
    (root / "edit.json").write_text(json.dumps(EDIT))
    monkeypatch.setenv("NERFEDIT_CACHE", str(proxy_cache))
    monkeypatch.chdir(root)
    return root


def _config(folder: Path) -> dict:
    return yaml.safe_load((folder / "config.yml").read_text())


def _same_mesh(a: Path, b: Path) -> bool:
    a, b = SurfaceMesh.load(a), SurfaceMesh.load(b)
    return np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


def _same_pngs(a: Path, b: Path) -> bool:
    names = sorted(p.name for p in a.glob("*.png"))
    return (
        names == sorted(p.name for p in b.glob("*.png"))
        and len(names) > 0
        and all(np.array_equal(np.asarray(Image.open(a / n)), np.asarray(Image.open(b / n))) for n in names)
    )


def test_edit_reruns_from_its_config_in_another_folder(workdir, tmp_path, monkeypatch):
    assert main(["edit", "--mesh", "capsule.ply", "--edit", "edit.json", "--out", "a"]) == 0
    recorded = _config(workdir / "a")
    assert recorded["mesh"] == str(workdir / "capsule.ply") and recorded["edit"] == str(workdir / "edit.json")
    assert recorded["deformer"] == "arap" and recorded["deformer_options"]["_target"] == "deformers.arap.ArapDeformer"
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    assert main(["edit", "--load-config", str(workdir / "a" / "config.yml"), "--out", "b"]) == 0
    assert _same_mesh(workdir / "a" / "deformed_mesh.ply", elsewhere / "b" / "deformed_mesh.ply")
    again = _config(elsewhere / "b")
    assert again.pop("out") == str(elsewhere / "b") and again.pop("load_config") == str(workdir / "a" / "config.yml")
    assert recorded["proxy_from"] == str(workdir / "a") and again.pop("proxy_from") == str(elsewhere / "b")
    assert again == {k: v for k, v in recorded.items() if k not in ("out", "load_config", "proxy_from")}


def test_an_edit_reruns_bit_for_bit_from_its_config_with_an_empty_proxy_cache(workdir, tmp_path, monkeypatch):
    """pytetwild draws another proxy in every process: config.yml names the edit's own proxy (proxy_from), so the
    re-run needs no cache and gives the same deformation.npz."""
    assert main(["edit", "--mesh", "capsule.ply", "--edit", "edit.json", "--out", "a"]) == 0
    monkeypatch.setenv("NERFEDIT_CACHE", str(tmp_path / "empty-cache"))
    assert main(["edit", "--load-config", str(workdir / "a" / "config.yml"), "--out", "b"]) == 0
    assert (workdir / "b" / "deformation.npz").read_bytes() == (workdir / "a" / "deformation.npz").read_bytes()
    assert not (tmp_path / "empty-cache").exists() or not any((tmp_path / "empty-cache").iterdir())
    report = json.loads((workdir / "b" / "report.json").read_text())
    assert report["proxy"]["reused_from"] == str(workdir / "a")


def test_flags_override_the_loaded_config_and_overwrite_is_never_loaded(workdir):
    assert (
        main(
            [
                "edit",
                "--mesh",
                "capsule.ply",
                "--edit",
                "edit.json",
                "--out",
                "a",
                "--overwrite",
                "--deformer-options.max-iterations",
                "50",
            ]
        )
        == 0
    )
    assert _config(workdir / "a")["overwrite"] is True
    assert (
        main(["edit", "--load-config", "a", "--out", "b", "--lift", "knn3", "--deformer-options.tolerance", "1e-3"])
        == 0
    )
    b = _config(workdir / "b")
    assert b["lift"] == "knn3" and b["deformer_options"]["tolerance"] == 1e-3
    assert b["deformer_options"]["max_iterations"] == 50 and b["overwrite"] is False  # loaded / not loaded
    assert json.loads((workdir / "b" / "report.json").read_text())["lift"] == "knn3"
    before = (workdir / "a" / "report.json").read_text()
    assert main(["edit", "--load-config", "a/config.yml"]) == 2  # same --out, and --overwrite is not taken
    assert (workdir / "a" / "report.json").read_text() == before


def test_plugin_choice_and_its_options_come_from_the_config(workdir, capsule):
    capsule.with_vertices(capsule.vertices * [1, 1, 1.2]).save(workdir / "edited.ply")
    (workdir / "mesh_edit.json").write_text(json.dumps({"deformed": "edited.ply"}))
    assert (
        main(
            [
                "edit",
                "--mesh",
                "capsule.ply",
                "--deformer",
                "mesh",
                "--edit",
                "mesh_edit.json",
                "--out",
                "a",
                "--lift",
                "closest-point",
            ]
        )
        == 0
    )
    assert main(["edit", "--load-config", "a", "--out", "b"]) == 0
    assert json.loads((workdir / "b" / "report.json").read_text())["deformer"] == "MeshDeformer"
    assert _same_mesh(workdir / "a" / "deformed_mesh.ply", workdir / "b" / "deformed_mesh.ply")
    args = parse(command("edit"), ["--load-config", "a", "--deformer", "arap"])  # another plugin: its defaults
    assert type(args.deformer_options).__name__ == "ArapConfig" and args.lift == "closest-point"


def test_wrong_or_missing_config_is_one_line(workdir, capsys):
    assert main(["edit", "--load-config", "nope.yml", "--out", "b"]) == 2
    assert "nope.yml: no such file" in capsys.readouterr().err
    assert main(["edit", "--load-config", str(DATA / "v0.1.0_train_mesh_config.yml"), "--out", "b"]) == 2
    assert "not a config.yml of `nerfedit edit` (unknown keys: data, device, field_options)" in capsys.readouterr().err
    (workdir / "bad.yml").write_text("[1, 2")
    assert main(["train", "--load-config", "bad.yml"]) == 2
    assert "not valid YAML" in capsys.readouterr().err


def test_a_run_written_without_its_command_reruns_from_field_data_and_config(workdir):
    run = workdir / "demo_run"  # what `nerfedit demo` writes for its run: no `command` key
    run.mkdir()
    (run / "config.yml").write_text(
        yaml.safe_dump(
            {"field": "mesh", "data": "../capsule_colored.ply", "field_config": {"density": 5.0, "padding": 0.1}}
        )
    )
    args = parse(command("train"), ["--load-config", str(run), "--out", "r"])
    assert args.field == "mesh" and args.data.resolve() == workdir / "capsule_colored.ply"
    assert args.field_options.density == 5.0 and args.field_options.padding == 0.1


def test_mesh_run_render_and_generate_record_and_rerun(workdir):
    assert main(["train", "--field", "mesh", "--data", "capsule_colored.ply", "--out", "run"]) == 0
    assert (workdir / "run" / "mesh.ply").is_file()  # the mesh field's run has its mesh at once: no extract
    assert main(["edit", "--run", "run", "--edit", "edit.json", "--out", "e"]) == 0
    assert _same_mesh(workdir / "e" / "deformed_mesh.ply", _fresh_edit(workdir))
    assert main(["train", "--load-config", "run/config.yml", "--out", "run2"]) == 0
    assert _same_mesh(workdir / "run" / "mesh.ply", workdir / "run2" / "mesh.ply")
    assert _config(workdir / "run2")["command"]["data"] == str(workdir / "capsule_colored.ply")

    assert (
        main(
            [
                "generate",
                "--mesh",
                "capsule_colored.ply",
                "--keep-colors",
                "--out",
                "data",
                "--resolution",
                "8",
                "--n-train",
                "1",
                "--n-val",
                "1",
                "--n-test",
                "2",
                "--supersample",
                "1",
                "--up-axis",
                "z",
            ]
        )
        == 0
    )
    assert _config(workdir / "data")["mesh"] == str(workdir / "capsule_colored.ply")
    assert main(["generate", "--load-config", "data", "--out", "data2"]) == 0
    assert _same_pngs(workdir / "data" / "test", workdir / "data2" / "test")

    assert main(["render", "--run", "run", "--cameras", "data", "--out", "r"]) == 0
    assert _config(workdir / "r")["cameras"] == str(workdir / "data")
    assert main(["render", "--load-config", "r/config.yml", "--out", "r2"]) == 0
    assert _same_pngs(workdir / "r", workdir / "r2")


def _fresh_edit(workdir: Path) -> Path:
    assert main(["edit", "--mesh", "capsule.ply", "--edit", "edit.json", "--out", "fresh"]) == 0
    return workdir / "fresh" / "deformed_mesh.ply"


def test_configs_of_nerfedit_0_1_0_rerun(workdir, capsys):
    """Written before the stage layout (paths as given, relative to the folder the command ran in)."""
    assert main(["edit", "--load-config", str(DATA / "v0.1.0_edit_config.yml"), "--out", "old_edit"]) == 0
    assert _same_mesh(workdir / "old_edit" / "deformed_mesh.ply", _fresh_edit(workdir))
    assert main(["train", "--load-config", str(DATA / "v0.1.0_train_mesh_config.yml"), "--out", "old_run"]) == 0
    assert open_run(workdir / "old_run").backend == "mesh" and (workdir / "old_run" / "mesh.ply").is_file()
    assert main(["generate", "--load-config", str(DATA / "v0.1.0_generate_config.yml"), "--out", "old_data"]) == 0
    assert len(list((workdir / "old_data" / "train").glob("*.png"))) == 2
    assert "warning" not in capsys.readouterr().err  # the recorded _target classes import back as they are


def test_a_recorded_target_that_is_not_the_plugins_class_warns(workdir, capsys):
    assert _import("nerfedit_plugin.nope.Nope") is None
    config = _config_copy(DATA / "v0.1.0_edit_config.yml", workdir / "moved.yml", "deformers.arap.Gone")
    args = parse(command("edit"), ["--load-config", str(config), "--out", "x"])
    assert type(args.deformer_options).__name__ == "ArapConfig"
    assert "deformer_options._target deformers.arap.Gone is not deformers.arap.ArapDeformer" in capsys.readouterr().err


def _config_copy(source: Path, target: Path, new_target: str) -> Path:
    shutil.copyfile(source, target)
    target.write_text(target.read_text().replace("_target: deformers.arap.ArapDeformer", f"_target: {new_target}"))
    return target
