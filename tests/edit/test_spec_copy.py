"""The spec copy in an edit folder is a spec that runs: the files a deformer read (a file, a list, a glob) are named
by absolute paths in it, so ``nerfedit edit --edit EDIT/spec`` reproduces the edit from any folder."""

import json
import os

import numpy as np
import yaml

from deformers.mesh import MeshConfig
from nerfedit_plugin.edit.job import run_edit
from nerfedit_plugin.geometry.mesh import SurfaceMesh


def test_a_copied_spec_names_the_deformer_files_absolute_and_reruns(capsule, tmp_path, proxy_cache, monkeypatch):
    spec_dir = tmp_path / "spec"
    (spec_dir / "poses").mkdir(parents=True)
    for i in range(2):
        capsule.with_vertices(capsule.vertices + [0.0, 0.0, 0.01 * (i + 1)]).save(spec_dir / "poses" / f"p{i}.ply")
    monkeypatch.chdir(tmp_path)  # the spec named relative to the working folder, as on a command line
    listed = [str(spec_dir / "poses" / f"p{i}.ply") for i in range(2)]
    specs = {
        "glob.json": ({"deformed": "poses/*.ply"}, [os.path.join(tmp_path, "spec", "poses/*.ply")]),
        "list.yaml": ({"deformed": ["poses/p0.ply", "poses/p1.ply"]}, listed),
    }
    for name, (spec, absolute) in specs.items():
        path = spec_dir / name
        path.write_text(json.dumps(spec) if name.endswith(".json") else yaml.safe_dump(spec))
        first = run_edit(capsule, MeshConfig(), os.path.relpath(path), tmp_path / name, lift="knn3",
                         cache_dir=proxy_cache)  # fmt: skip
        written = yaml.safe_load((first.out / name).read_text())
        assert (written["deformed"] if isinstance(written["deformed"], list) else [written["deformed"]]) == absolute
        monkeypatch.chdir(first.out)  # elsewhere: the copy still finds its files
        again = run_edit(capsule, MeshConfig(), name, tmp_path / f"again-{name}", lift="knn3", cache_dir=proxy_cache)
        monkeypatch.chdir(tmp_path)
        for mesh in ("deformed_mesh_0000.ply", "deformed_mesh_0001.ply"):
            np.testing.assert_array_equal(
                SurfaceMesh.load(again.out / mesh).vertices, SurfaceMesh.load(first.out / mesh).vertices
            )


def test_a_scene_spec_copy_names_its_objects_edit_files_absolute(tmp_path):
    """In a scene spec, the deformer keys of every object's and copy's ``edit`` are rewritten; other keys, absolute
    names and keys no deformer read are kept."""
    from nerfedit_plugin.edit.spec import copy_spec_file

    edit = {"deformed": "a.ply", "note": "a.ply"}
    copies = [{"edit": {"deformed": "/b.ply"}}]
    scene = {"objects": [{"name": "o", "select": {"box": {}}, "edit": edit, "copies": copies}]}
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "scene.json").write_text(json.dumps(scene))
    (tmp_path / "out").mkdir()
    copy_spec_file(tmp_path / "in" / "scene.json", tmp_path / "out", {"deformed"})
    (written,) = json.loads((tmp_path / "out" / "scene.json").read_text())["objects"]
    assert written["edit"] == {"deformed": str(tmp_path / "in" / "a.ply"), "note": "a.ply"}
    assert written["copies"][0]["edit"] == {"deformed": "/b.ply"}
