"""``nerfedit`` CLI end to end on real files: edit outputs, atomic/overwrite behaviour, one-line errors."""

import json

import numpy as np
import pytest

from nerfedit_plugin.bending.deformation_field import DeformationField
from nerfedit_plugin.cli.app import main
from nerfedit_plugin.geometry.mesh import SurfaceMesh

EDIT = {
    "handles": [
        {"select": {"box": {"min": [-1, -1, -1.1], "max": [1, 1, -0.6]}}, "fixed": True},
        {"select": {"box": {"min": [-1, -1, 0.6], "max": [1, 1, 1.1]}}, "transform": {"translate": [0, 0.3, 0]}},
    ],
    "frames": 2,
}


@pytest.fixture
def workdir(tmp_path, capsule, monkeypatch):
    capsule.save(tmp_path / "capsule.ply")
    (tmp_path / "edit.json").write_text(json.dumps(EDIT))
    monkeypatch.setenv("NERFEDIT_CACHE", str(tmp_path / "cache"))
    return tmp_path


def edit(workdir, *extra):
    return main(
        [
            "edit",
            "--mesh",
            str(workdir / "capsule.ply"),
            "--edit",
            str(workdir / "edit.json"),
            "--out",
            str(workdir / "out"),
            *extra,
        ]
    )


def test_edit_writes_every_output(workdir, capsule):
    assert edit(workdir, "--deformer", "arap") == 0
    out = workdir / "out"
    assert {p.name for p in out.iterdir()} >= {
        "config.yml",
        "edit.json",
        "deformed_mesh_0000.ply",
        "deformed_mesh_0001.ply",
        "deformation.npz",
        "report.json",
    }
    field = DeformationField.load(out / "deformation.npz")
    assert field.n_frames == 2
    report = json.loads((out / "report.json").read_text())
    assert report["lift"] == "tet-arap" and len(report["per_frame"]) == 2 and not report["proxy"]["cached"]
    assert all(f["inverted_tets"] == 0 and f["residual_max"] < 5e-3 for f in report["per_frame"])
    moved = SurfaceMesh.load(out / "deformed_mesh_0001.ply")
    top = capsule.vertices[:, 2] > 0.6
    assert np.allclose(moved.vertices[top], capsule.vertices[top] + [0, 0.3, 0], atol=1e-6)
    assert np.array_equal(moved.faces, capsule.faces)


def test_existing_output_needs_overwrite_and_proxy_is_cached(workdir, capsule):
    assert edit(workdir) == 0
    before = (workdir / "out" / "report.json").read_text()
    assert edit(workdir) == 2  # refuses to overwrite
    assert (workdir / "out" / "report.json").read_text() == before
    assert edit(workdir, "--overwrite", "--lift", "knn3") == 0
    report = json.loads((workdir / "out" / "report.json").read_text())
    assert report["proxy"]["cached"] and report["lift"] == "knn3"


def test_bad_spec_is_one_line_error_and_writes_nothing(workdir, capsys):
    (workdir / "edit.json").write_text(json.dumps({"handles": [{"select": {"indices": [10**6]}, "fixed": True}]}))
    assert edit(workdir) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "handles[0].select.indices: index 1000000 out of range" in err
    assert not (workdir / "out").exists()
    assert not [p for p in workdir.iterdir() if p.name.startswith(".out")]  # no staging folder left behind


def test_unknown_deformer_and_missing_mesh(workdir, capsys):
    assert edit(workdir, "--deformer", "nope") == 2
    assert "unknown deformer 'nope'" in capsys.readouterr().err
    assert (
        main(
            [
                "edit",
                "--mesh",
                str(workdir / "none.ply"),
                "--edit",
                str(workdir / "edit.json"),
                "--out",
                str(workdir / "o"),
            ]
        )
        == 2
    )
    assert "none.ply: mesh file not found" in capsys.readouterr().err


def test_mesh_deformer_through_cli(workdir, capsule):
    capsule.with_vertices(capsule.vertices * [1, 1, 1.2]).save(workdir / "edited.ply")
    (workdir / "edit.json").write_text(json.dumps({"deformed": "edited.ply"}))
    assert edit(workdir, "--deformer", "mesh", "--lift", "closest-point") == 0
    assert (workdir / "out" / "deformed_mesh.ply").is_file()


def test_plugins_lists_builtins(capsys):
    assert main(["plugins"]) == 0
    out = capsys.readouterr().out
    assert "arap" in out and "mesh" in out


def test_a_corrupt_proxy_cache_entry_is_one_warning_line_and_rebuilt(workdir, capsys):
    assert edit(workdir) == 0
    (entry,) = (workdir / "cache").glob("*.npz")
    entry.write_bytes(b"not a zip")
    capsys.readouterr()
    assert edit(workdir, "--overwrite") == 0
    err = capsys.readouterr().err
    assert err.startswith(f"warning: {entry}: not a readable tet proxy file") and err.count("\n") == 1, err
    assert "rebuilding the cache entry" in err and "UserWarning" not in err
    report = json.loads((workdir / "out" / "report.json").read_text())
    assert not report["proxy"]["cached"] and np.load(entry)["tets"].shape[1] == 4
