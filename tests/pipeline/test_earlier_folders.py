"""Run, edit and render folders written before the pipeline floor (tests/fixtures/earlier_layout) still open: render
from them, edit on top of them (``--base``), re-run them (``--load-config``)."""

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from nerfedit_plugin.cli.app import main
from nerfedit_plugin.pipeline.edit import EditFolder
from nerfedit_plugin.pipeline.run import open_run

EARLIER = Path(__file__).resolve().parents[1] / "fixtures" / "earlier_layout"
MADE_IN = "/tmp/gen_layout"


@pytest.fixture
def earlier(tmp_path, monkeypatch):
    """A copy of the fixture whose config.yml files name the copy's paths; the proxy cache empty."""
    root = tmp_path / "earlier"
    shutil.copytree(EARLIER, root)
    for config in root.glob("*/config.yml"):
        config.write_text(config.read_text().replace(MADE_IN, str(root)))
    monkeypatch.setenv("NERFEDIT_CACHE", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    return root


def _pixels(folder: Path) -> dict:
    return {p.name: np.asarray(Image.open(p)) for p in sorted(folder.glob("*.png"))}


def test_an_earlier_run_and_edit_open(earlier):
    run = open_run(earlier / "run")
    assert run.source == "model" and run.exact_mesh and not run.has_cameras()
    assert "source" not in yaml.safe_load((earlier / "run" / "config.yml").read_text())  # derived, not recorded
    edit = EditFolder.open(earlier / "edit")
    assert edit.run == earlier / "run" and edit.mesh is None and len(edit.deformed_meshes()) == 1


def test_an_earlier_edit_renders_as_it_did(earlier):
    args = ["--run", str(earlier / "run"), "--deformation", str(earlier / "edit" / "deformation.npz")]
    assert main(["render", *args, "--cameras", str(earlier / "cameras.json"), "--out", "again"]) == 0
    expected, got = _pixels(earlier / "render"), _pixels(Path("again"))
    assert expected.keys() == got.keys() and len(got) == 2
    assert all(np.array_equal(expected[name], got[name]) for name in expected)
    assert main(["render", "--load-config", str(earlier / "render" / "config.yml"), "--out", "reloaded"]) == 0
    assert all(np.array_equal(expected[n], image) for n, image in _pixels(Path("reloaded")).items())


def test_an_earlier_edit_reruns_from_its_config_and_is_edited_again(earlier):
    config = str(earlier / "edit" / "config.yml")
    assert main(["edit", "--load-config", config, "--proxy-from", str(earlier / "edit"), "--out", "rerun"]) == 0
    rerun, written = np.load("rerun/deformation.npz"), np.load(earlier / "edit" / "deformation.npz")
    assert sorted(rerun.files) == sorted(written.files)
    for name in ("format_version", "rest_vertices", "tets"):  # the same proxy, bit for bit
        assert np.array_equal(rerun[name], written[name]), name
    # the same solve: the fixture was written on another machine, and a solve's last bits follow the CPU's kernels
    size = np.ptp(written["rest_vertices"], axis=0).max()
    assert np.abs(rerun["deformed_vertices"] - written["deformed_vertices"]).max() <= 1e-10 * size
    more = ["--edit", str(earlier / "edit.json"), "--out", "more"]
    assert main(["edit", "--run", str(earlier / "run"), "--base", str(earlier / "edit"), *more]) == 0
    assert EditFolder.open(Path("more")).run == earlier / "run"
